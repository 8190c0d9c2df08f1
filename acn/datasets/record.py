"""Run a collection and write it as one dataset: ``record(config, out)``.

Episodes are split into small blocks; each block is a call of the pure function
``collect_episodes(config, indices)`` (in this process for one worker, in a process pool
otherwise; the same call could be sent to Ray). The writer consumes blocks in episode order,
so the dataset does not depend on the number of workers.

Ctrl-C or SIGTERM stops the collection: the finished episodes are committed as a valid
dataset (or nothing is written if none finished) and ``Interrupted`` is raised.
"""

from __future__ import annotations

import math
import multiprocessing as mp
import signal
import sys
from dataclasses import asdict
from functools import partial
from pathlib import Path
from typing import Callable

from acn.datasets import schema
from acn.datasets.writer import DatasetWriter
from acn.toolkit.backends import simulator_version
from acn.toolkit.collector import FALL_RULE, CollectConfig, Episode, PairedRollout, collect_episodes
from acn.toolkit.state import ACTION_NAMES, STATE_NAMES


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
        "model_params": {k: (v.tolist() if hasattr(v, "tolist") else v) for k, v in asdict(sim.params).items()},
        "policy": cfg.policy, "seed": cfg.seed, "seconds": cfg.seconds, "episodes_requested": cfg.episodes,
        "init_noise": asdict(cfg.init_noise),
        "corrector": cfg.corrector,
        "state_names": list(STATE_NAMES), "action_names": list(ACTION_NAMES),
        "fall_rule": FALL_RULE,
    }


def _blocks(n: int, workers: int) -> list[list[int]]:
    size = max(1, math.ceil(n / (workers * 4))) if workers > 1 else n
    return [list(range(i, min(i + size, n))) for i in range(0, n, size)]


def _worker_init() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent decides what an interrupt does


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt


def record(cfg: CollectConfig, out: str | Path, workers: int = 1, overwrite: bool = False,
           on_episode: Callable[[Episode], None] | None = None) -> Path:
    """Collect ``cfg.episodes`` episodes and write them to ``out``; returns the dataset path."""
    cfg.validate()
    if workers < 1:
        raise ValueError(f"--workers must be >= 1, got {workers}")
    task = f"{cfg.policy} ({cfg.source}" + (f" -> {cfg.target})" if cfg.target else ")")
    writer = DatasetWriter(out, fps=int(round(1.0 / cfg.sim.control_dt)), paired=cfg.paired, task=task,
                           acn_meta=collection_metadata(cfg), overwrite=overwrite)
    previous = signal.signal(signal.SIGTERM, _raise_interrupt)
    pool = None
    try:
        if workers == 1:
            rollout = PairedRollout(cfg)
            results = ([rollout.episode(i)] for i in range(cfg.episodes))
        else:
            ctx = mp.get_context("spawn")
            pool = ctx.Pool(min(workers, cfg.episodes), initializer=_worker_init)
            results = pool.imap(partial(collect_episodes, cfg), _blocks(cfg.episodes, workers))
        for block in results:
            for ep in block:
                writer.write(ep)
                if on_episode:
                    on_episode(ep)
        if workers == 1:
            rollout.close()
    except KeyboardInterrupt:
        if pool is not None:
            pool.terminate()
        path = _commit_quietly(writer) if writer.num_episodes else None
        if path is None:
            writer.abort()
        raise Interrupted(path, writer.num_episodes) from None
    except BaseException:
        if pool is not None:
            pool.terminate()
        writer.abort()
        raise
    finally:
        if pool is not None:
            pool.close()
        signal.signal(signal.SIGTERM, previous)
    return _commit_quietly(writer)


def _commit_quietly(writer: DatasetWriter) -> Path:
    """Commit with SIGINT/SIGTERM held off, so a second Ctrl-C cannot tear the rename."""
    old_int = signal.signal(signal.SIGINT, signal.SIG_IGN)
    old_term = signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        return writer.commit()
    finally:
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)


if sys.platform == "win32":  # pragma: no cover
    raise ImportError("acn.datasets.record needs POSIX signals")
