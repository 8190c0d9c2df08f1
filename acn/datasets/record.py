"""Run a collection and write it as one dataset: ``record(config, out)``.

Simulation runs in ``workers`` child processes, each building its simulators once and
streaming finished episodes back; the parent only writes, in episode order, so the dataset
does not depend on the number of workers and writing overlaps simulation. Each child runs
``PairedRollout.episode`` over its share of indices; ``collect_episodes(config, indices)`` is
the same work as one pure call, which Ray runs instead with ``ray=RayConfig(...)``
(``acn.sim.parallel.episodes_on_ray``: one task per episode, consumed in episode order by
the same writer loop, so the dataset is byte-identical to a local one with the same seed).
``shards=K`` (Ray only) writes K datasets in parallel and merges them (``acn.datasets.shards``).

Ctrl-C or SIGTERM stops the collection and raises ``Interrupted``. Into a new ``out``, the
finished episodes are committed as a valid dataset (nothing is written if none finished). Over
an existing dataset (``overwrite``), nothing of the interrupted run is kept: the dataset there
stays as it was, since only a complete collection replaces it.
"""

from __future__ import annotations

import multiprocessing as mp
import queue
import signal
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator, Sequence

from acn.datasets import schema
from acn.datasets.writer import DatasetWriter
from acn.errors import UserError
from acn.sim.backends import simulator_version
from acn.sim.collector import FALL_RULE, CollectConfig, Episode, LoadCorrector, rollout_for
from acn.sim.state import ACTION_NAMES, STATE_NAMES

if TYPE_CHECKING:  # pragma: no cover
    from acn.sim.parallel import RayConfig

# Children are forked from a clean server process that has imported the simulators once.
_CTX = mp.get_context("forkserver")
_CTX.set_forkserver_preload(["acn.sim.collector", "acn.sim.backends.pybullet_backend",
                             "acn.sim.backends.mujoco_backend"])


class Interrupted(Exception):
    """The collection was stopped by a signal; ``path`` holds the finished episodes, if any."""

    def __init__(self, path: Path | None, episodes: int) -> None:
        super().__init__(f"interrupted after {episodes} finished episode(s)")
        self.path, self.episodes = path, episodes


def collection_metadata(cfg: CollectConfig) -> dict:
    """The ``acn`` block of ``meta/info.json`` for this collection."""
    sim = cfg.sim
    return {
        "format_version": schema.FORMAT_VERSION,
        "paired": cfg.paired,
        "source": {"simulator": cfg.source, "version": simulator_version(cfg.source)},
        "target": ({"simulator": cfg.target, "version": simulator_version(cfg.target)} if cfg.target else None),
        "physics_dt": sim.physics_dt, "substeps": sim.substeps, "control_hz": round(1.0 / sim.control_dt, 9),
        "action_mode": sim.action_mode, "kp": sim.kp, "kd": sim.kd, "torque_limit": sim.torque_limit,
        "imu_acc": sim.imu_acc, "model_params": sim.params.as_json(),
        "policy": cfg.policy, "seed": cfg.seed, "seconds": cfg.seconds, "episodes_requested": cfg.episodes,
        "init_noise": asdict(cfg.init_noise),
        "corrector": cfg.corrector,
        "state_names": list(STATE_NAMES), "action_names": list(ACTION_NAMES),
        "fall_rule": FALL_RULE,
    }


def config_from_metadata(acn: dict, **overrides) -> CollectConfig:
    """The collection config a dataset was recorded with (inverse of ``collection_metadata``)."""
    from acn.sim.collector import InitNoise
    from acn.sim.robot import ModelParams

    sim = schema.control_config(acn, params=ModelParams.from_json(acn["model_params"]))
    kw = dict(source=acn["source"]["simulator"], target=(acn["target"] or {}).get("simulator"), policy=acn["policy"],
              episodes=acn["episodes_requested"], seconds=acn["seconds"], seed=acn["seed"], sim=sim,
              init_noise=InitNoise(**acn["init_noise"]), corrector=None)
    kw.update(overrides)
    return CollectConfig(**kw)


def _simulate(cfg: CollectConfig, indices: list[int], results, load_corrector: LoadCorrector | None) -> None:
    """Child process: run ``indices`` with one set of simulators, send each episode back."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides what an interrupt does
    try:
        rollout = rollout_for(cfg, load_corrector)
        for i in indices:
            results.put(rollout.episode(i))
        rollout.close()
    except Exception as e:  # noqa: BLE001 - reported to the parent, which raises it
        results.put(e)


def _episodes_in_order(cfg: CollectConfig, indices: Sequence[int], workers: int, procs: list,
                       load_corrector: LoadCorrector | None) -> Iterator[Episode]:
    results = _CTX.Queue()
    for w in range(workers):
        p = _CTX.Process(target=_simulate, args=(cfg, list(indices[w::workers]), results, load_corrector),
                         daemon=True)
        p.start()
        procs.append(p)
    pending: dict[int, Episode] = {}
    for next_index in indices:
        while next_index not in pending:
            try:
                item = results.get(timeout=1.0)
            except queue.Empty:
                if not any(p.is_alive() for p in procs) and results.empty():
                    codes = [p.exitcode for p in procs]
                    raise RuntimeError(f"a simulation worker died (exit codes {codes})") from None
                continue
            if isinstance(item, Exception):
                raise item
            pending[item.index] = item
        yield pending.pop(next_index)


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


def record(cfg: CollectConfig, out: str | Path, workers: int = 1, overwrite: bool = False,
           on_episode: Callable[[Episode], None] | None = None, ray: "RayConfig | None" = None,
           shards: int = 1, indices: Sequence[int] | None = None, load_corrector: LoadCorrector | None = None
           ) -> Path:
    """Collect ``cfg.episodes`` episodes and write them to ``out``; returns the dataset path.

    ``ray``: simulate on Ray (a local instance or a cluster) instead of ``workers`` processes;
    ``shards``: with ``ray``, K writers in parallel merged into one dataset (``on_episode`` then
    sees a ``ShardEpisode`` as each shard writes it, shards interleaved). ``indices``: the
    collection indices to run (default all ``cfg.episodes``; a shard runs a contiguous part).
    ``load_corrector``: turns ``cfg.corrector`` into the corrector object where the episodes run
    (``acn.corrector.Corrector.load``; needed when ``cfg.corrector`` is set).
    """
    cfg.validate()
    if cfg.corrector and load_corrector is None:
        raise ValueError(f"cfg.corrector names {cfg.corrector!r} but no load_corrector was given "
                         "(e.g. acn.corrector.Corrector.load)")
    if workers < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")
    if shards < 1:
        raise ValueError(f"--shards must be >= 1, got {shards}")
    indices = range(cfg.episodes) if indices is None else indices
    if ray is not None:
        from acn.sim import parallel

        with parallel.ray_session(ray):
            if shards > 1:
                from acn.datasets.shards import record_shards

                return record_shards(cfg, out, shards, ray, overwrite=overwrite, on_episode=on_episode,
                                     load_corrector=load_corrector)
            return _record(cfg, out, parallel.episodes_on_ray(cfg, indices, load_corrector=load_corrector), [],
                           overwrite, on_episode)
    if shards > 1:
        raise UserError("--shards needs --ray (the shards are written by Ray tasks)")
    workers = min(workers, len(indices))
    procs: list = []
    return _record(cfg, out, _episodes_in_order(cfg, indices, workers, procs, load_corrector), procs, overwrite,
                   on_episode)


def _record(cfg: CollectConfig, out: str | Path, episodes: Iterator[Episode], procs: list, overwrite: bool,
            on_episode: Callable[[Episode], None] | None) -> Path:
    """The writer loop: ``episodes`` (in order, from processes or Ray) into one dataset at ``out``."""
    task = f"{cfg.policy} ({cfg.source}" + (f" -> {cfg.target})" if cfg.target else ")")
    replacing = Path(out).exists()  # interrupted, the dataset there stays as it was
    writer = DatasetWriter(out, fps=int(round(1.0 / cfg.sim.control_dt)), paired=cfg.paired, task=task,
                           acn_meta=collection_metadata(cfg), overwrite=overwrite)
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    try:
        for ep in episodes:
            writer.write(ep)
            if on_episode:
                on_episode(ep)
    except KeyboardInterrupt:
        _stop(procs)
        path = _commit_quietly(writer, cfg) if writer.num_episodes and not replacing else None
        if path is None:
            writer.abort()
        episodes.close()  # after the commit: the finished episodes are safe whatever closing does
        raise Interrupted(path, writer.num_episodes) from None
    except BaseException:
        _stop(procs)
        episodes.close()
        writer.abort()
        raise
    finally:
        signal.signal(signal.SIGTERM, previous)
    for p in procs:
        p.join()
    return _commit_quietly(writer, cfg)


def _stop(procs: list) -> None:
    for p in procs:
        if p.is_alive():
            p.terminate()
    for p in procs:
        p.join()


def _commit_quietly(writer: DatasetWriter, cfg: CollectConfig) -> Path:
    """Commit with SIGINT/SIGTERM held off, so a second Ctrl-C cannot tear the rename; then the
    answer to hidden effects goes beside the dataset (a stale answer from an overwritten one goes)."""
    from acn.sim.hidden import ANSWER, answer_path, write_answer

    old_int = signal.signal(signal.SIGINT, signal.SIG_IGN)
    old_term = signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        path = writer.commit()
        if cfg.hidden_effects:
            write_answer(path, cfg.hidden_effects, cfg.seed)
        elif ANSWER.recognise(answer_path(path)):  # a stale answer of the dataset this one replaced
            answer_path(path).unlink()
        return path
    finally:
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)

