"""Run a collection and write it as one dataset: ``record(config, out)``.

Simulation runs in ``workers`` child processes, each building its simulators once and
streaming finished episodes back; the parent only writes, in episode order, so the dataset
does not depend on the number of workers and writing overlaps simulation. Each child runs
``PairedRollout.episode`` over its share of indices; ``collect_episodes(config, indices)`` is
the same work as one pure call, which Ray runs instead with ``ray=RayConfig(...)``
(``acn.sim.parallel.episodes_on_ray``: one task per episode, consumed in episode order by
the same writer loop, so the dataset is byte-identical to a local one with the same seed).
``shards=K`` (Ray only) writes K datasets in parallel and merges them (``acn.datasets.shards``).

Ctrl-C or SIGTERM stops the collection and raises ``acn.datasets.stream.Interrupted``. Into a new ``out``, the
finished episodes are committed as a valid dataset (nothing is written if none finished). Over
an existing dataset (``overwrite``), nothing of the interrupted run is kept: the dataset there
stays as it was, since only a complete collection replaces it. The writer loop that does this is
``acn.datasets.stream.write_stream``, which the shards run too.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import signal
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator, Sequence

from acn.datasets.shards import record_shards
from acn.datasets.stream import write_stream
from acn.errors import UserError
from acn.lifetime import end_with
from acn.sim.collector import CollectConfig, Episode, LoadCorrector, rollout_for

if TYPE_CHECKING:  # pragma: no cover
    from acn.sim.parallel import RayConfig

# Children are forked from a clean server process that has imported the simulators once.
_CTX = mp.get_context("forkserver")
_CTX.set_forkserver_preload(["acn.sim.collector", "acn.sim.backends.pybullet_backend",
                             "acn.sim.backends.mujoco_backend"])


def _simulate(cfg: CollectConfig, indices: list[int], results, load_corrector: LoadCorrector | None,
              run: int) -> None:
    """Child process: run ``indices`` with one set of simulators, send each episode back; ends
    when the collection's process ``run`` ends, however it ends."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides what an interrupt does
    end_with(run)
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
        p = _CTX.Process(target=_simulate, args=(cfg, list(indices[w::workers]), results, load_corrector, os.getpid()),
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


def record(cfg: CollectConfig, out: str | Path, workers: int = 1, overwrite: bool = False,
           on_episode: Callable[[Episode], None] | None = None, ray: "RayConfig | None" = None,
           shards: int = 1, indices: Sequence[int] | None = None, load_corrector: LoadCorrector | None = None
           ) -> Path:
    """Collect ``cfg.episodes`` episodes and write them to ``out``; returns the dataset path.

    ``ray``: simulate on Ray (a local instance or a cluster) instead of ``workers`` processes;
    ``shards``: with ``ray``, K writers in parallel merged into one dataset (``on_episode`` then
    sees a ``ShardEpisode`` as each shard writes it, shards interleaved). ``indices``: the
    collection indices to run (default all ``cfg.episodes``).
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
                return record_shards(cfg, out, shards, ray, overwrite=overwrite, on_episode=on_episode,
                                     load_corrector=load_corrector)
            return write_stream(cfg, out, parallel.episodes_on_ray(cfg, indices, load_corrector=load_corrector), [],
                                overwrite, on_episode)
    if shards > 1:
        raise UserError("--shards needs --ray (the shards are written by Ray tasks)")
    workers = min(workers, len(indices))
    procs: list = []
    return write_stream(cfg, out, _episodes_in_order(cfg, indices, workers, procs, load_corrector), procs, overwrite,
                        on_episode)
