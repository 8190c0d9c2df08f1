"""One dataset from an ordered stream of episodes, interruptibly: ``write_stream``.

The writer loop under ``acn.datasets.record`` (episodes from local processes or from Ray) and
under each shard of ``acn.datasets.shards``. Ctrl-C or SIGTERM stops it and raises
``Interrupted``: into a new ``out``, the finished episodes are committed as a valid dataset
(nothing is written if none finished); over an existing dataset, nothing of the interrupted run
is kept, since only a complete collection replaces it. ``commit_quietly`` is the commit both use,
with the signals held off.
"""

from __future__ import annotations

import signal
from pathlib import Path
from typing import Callable, Iterator, Protocol

from acn.datasets.metadata import collection_metadata
from acn.datasets.writer import DatasetWriter
from acn.sim.collector import CollectConfig, Episode


class Interrupted(Exception):
    """The collection was stopped by a signal; ``path`` holds the finished episodes, if any."""

    def __init__(self, path: Path | None, episodes: int) -> None:
        super().__init__(f"interrupted after {episodes} finished episode(s)")
        self.path, self.episodes = path, episodes


class Committable(Protocol):
    """What ``commit_quietly`` commits: a ``DatasetWriter`` or a merge of shards."""

    def commit(self) -> Path: ...


def raise_interrupt(signum, frame) -> None:
    """A SIGTERM handler: SIGTERM stops a collection as Ctrl-C does."""
    raise KeyboardInterrupt


def write_stream(cfg: CollectConfig, out: str | Path, episodes: Iterator[Episode], procs: list, overwrite: bool,
                 on_episode: Callable[[Episode], None] | None) -> Path:
    """The writer loop: ``episodes`` (in order, from processes or Ray) into one dataset at ``out``;
    ``procs``: the processes simulating them, stopped on an interrupt or an error."""
    task = f"{cfg.policy} ({cfg.source}" + (f" -> {cfg.target})" if cfg.target else ")")
    writer = DatasetWriter(out, fps=int(round(1.0 / cfg.sim.control_dt)), paired=cfg.paired, task=task,
                           acn_meta=collection_metadata(cfg), overwrite=overwrite)
    replacing = writer.output.replaces  # interrupted, the dataset there stays as it was
    previous = signal.signal(signal.SIGTERM, raise_interrupt)
    try:
        for ep in episodes:
            writer.write(ep)
            if on_episode:
                on_episode(ep)
    except KeyboardInterrupt:
        _stop(procs)
        path = commit_quietly(writer, cfg) if writer.num_episodes and not replacing else None
        if path is None:
            writer.abort()
        episodes.close()  # after the commit: the finished episodes are safe whatever closing does
        raise Interrupted(path, writer.num_episodes) from None
    except BaseException as e:
        _stop(procs)
        episodes.close()
        raise writer.fail(e) from None
    finally:
        signal.signal(signal.SIGTERM, previous)
    for p in procs:
        p.join()
    return commit_quietly(writer, cfg)


def _stop(procs: list) -> None:
    for p in procs:
        if p.is_alive():
            p.terminate()
    for p in procs:
        p.join()


def commit_quietly(writer: Committable, cfg: CollectConfig) -> Path:
    """Commit with SIGINT/SIGTERM held off, so a second Ctrl-C cannot tear the rename; then the
    answer to hidden effects goes beside the dataset (a stale answer from an overwritten one goes)."""
    from acn.sim.hidden import ANSWER, answer_path, write_answer

    old_int = signal.signal(signal.SIGINT, signal.SIG_IGN)
    old_term = signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        path = writer.commit()
        if cfg.hidden_effects:
            write_answer(path, cfg.source, cfg.hidden_effects, cfg.seed)
        elif ANSWER.recognise(answer_path(path)):  # a stale answer of the dataset this one replaced
            answer_path(path).unlink()
        return path
    finally:
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)
