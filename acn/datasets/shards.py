"""``--shards K``: K datasets written in parallel on Ray, merged into one by lerobot's aggregation.

The collection indices 0..N-1 are split into K contiguous ranges. Shard k is written by one
Ray task pinned to the driver's node (the shards and ``out`` share its disk; the writer is the
part that needs it), which runs the writer loop (``acn.datasets.stream.write_stream``) for its
range: its episodes are simulated as Ray tasks anywhere in the cluster and written in order by
the shard's own writer. Then ``lerobot.datasets.aggregate.aggregate_datasets`` merges the
shards, in order, into a hidden directory beside ``out`` that is moved into place whole
(``acn.outputs.writing.Writing``, claimed before the first shard starts), and the
``acn`` block of ``meta/info.json`` (the collection's metadata and every episode with its
collection index, in order) is rebuilt from the shards'. Frame values equal an unsharded collection's; the files
do not (lerobot rewrites the rows with pandas and aggregates the shards' statistics).

Ctrl-C or SIGTERM: every shard task is cancelled, each commits the episodes it finished (as an
unsharded collection does), and those are merged: a valid dataset of the finished episodes, or
nothing.
"""

from __future__ import annotations

import contextlib
import io
import shutil
import signal
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from acn.datasets import schema
from acn.datasets.metadata import AcnMetadata
from acn.datasets.reader import read_card
from acn.datasets.stream import Interrupted, commit_quietly, raise_interrupt, write_stream
from acn.outputs.leftovers import temporary_beside
from acn.outputs.writing import Writing
from acn.sim import parallel
from acn.sim.collector import CollectConfig
from acn.sim.parallel import RayConfig, import_ray, remote, task_error

CANCEL_WAIT_S = 120.0  # after an interrupt, how long the shards get to commit what they finished


@dataclass
class ShardEpisode:
    """An episode of the merged dataset as its metadata lists it (for progress callbacks)."""

    index: int     # collection index
    length: int    # frames
    end: str

    def __len__(self) -> int:
        return self.length


def _write_shard(cfg: CollectConfig, indices: list[int], path: str, ray_config: RayConfig, progress,
                 load_corrector=None) -> int:
    """Ray task: write the shard of ``indices`` at ``path``, each written episode reported to
    the ``progress`` queue; returns its finished episodes."""
    def report(ep) -> None:
        progress.put((ep.index, len(ep), ep.end))

    try:
        with parallel.ray_session(ray_config):
            write_stream(cfg, path, parallel.episodes_on_ray(cfg, indices, load_corrector=load_corrector), [],
                         overwrite=False, on_episode=report)
    except Interrupted as e:
        return e.episodes
    return len(indices)


def merged_acn_metadata(blocks: list[AcnMetadata]) -> AcnMetadata:
    """The ``acn`` block of the merged dataset from the shards' blocks, in shard order."""
    episodes = [entry for block in blocks for entry in block.episodes]
    empty = [entry for block in blocks for entry in block.empty_episodes or ()]
    return replace(blocks[0], episodes=tuple(replace(entry, episode_index=i) for i, entry in enumerate(episodes)),
                   empty_episodes=tuple(empty) or None)


class _Merge:
    """Merges committed shards into ``output`` on ``commit()`` (all or nothing, as ``DatasetWriter``)."""

    def __init__(self, shards: list[Path], output: Writing) -> None:
        self.shards, self.output = shards, output

    def commit(self) -> Path:
        from lerobot.datasets.aggregate import aggregate_datasets
        from lerobot.datasets.utils import load_info, write_info

        tmp = self.output.path
        try:
            with contextlib.redirect_stderr(io.StringIO()):  # lerobot's progress bars
                aggregate_datasets([f"acn/{p.name}" for p in self.shards], f"acn/{self.output.out.name}",
                                   roots=self.shards, aggr_root=tmp)
            info = load_info(tmp)
            info[schema.ACN_KEY] = merged_acn_metadata([read_card(p).acn for p in self.shards]).to_json()
            write_info(info, tmp)
        except BaseException as e:
            raise self.output.fail(e) from None
        return self.output.commit()


def record_shards(cfg: CollectConfig, out: str | Path, shards: int, ray_config: RayConfig, overwrite: bool = False,
                  on_episode: Callable[[ShardEpisode], None] | None = None, load_corrector=None) -> Path:
    """Collect ``cfg.episodes`` episodes as ``shards`` datasets on Ray and merge them into ``out``.
    Needs an open ``ray_session``; ``on_episode`` sees each episode as its shard writes it."""
    from ray.util.queue import Queue
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    ray = import_ray()
    output = Writing(out, schema.DATASET, overwrite)
    out = output.out
    replacing = output.replaces  # interrupted, the dataset there stays as it was
    ranges = [r.tolist() for r in np.array_split(np.arange(cfg.episodes), min(shards, cfg.episodes))]
    work = temporary_beside(out, "shards")
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    paths = [work / f"shard-{k:03d}" for k in range(len(ranges))]
    here = NodeAffinitySchedulingStrategy(ray.get_runtime_context().get_node_id(), soft=False)
    task = remote(ray, "shard", _write_shard, num_cpus=0, max_retries=0)
    previous_int, previous = signal.getsignal(signal.SIGINT), signal.signal(signal.SIGTERM, raise_interrupt)
    refs: list = []
    progress = Queue(actor_options={"num_cpus": 0})

    def report() -> None:
        while not progress.empty():
            entry = ShardEpisode(*progress.get())
            if on_episode:
                on_episode(entry)

    try:
        refs = [task.options(scheduling_strategy=here).remote(cfg, r, str(p), ray_config, progress, load_corrector)
                for r, p in zip(ranges, paths)]
        running = list(refs)
        while running:
            _, running = ray.wait(running, num_returns=len(running), timeout=0.5)
            report()
        try:
            ray.get(refs)
        except ray.exceptions.RayTaskError as e:
            raise task_error(ray, e) from None
        report()
        path = commit_quietly(_Merge(paths, output), cfg)
    except KeyboardInterrupt:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C must not tear the merge
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        for ref in refs:
            ray.cancel(ref)  # the shard's writer loop commits its finished episodes
        ray.wait(refs, num_returns=len(refs), timeout=CANCEL_WAIT_S)
        done = [p for p in paths if (p / "meta" / "info.json").is_file()]
        path = commit_quietly(_Merge(done, output), cfg) if done and not replacing else None
        if path is None:
            output.abort()
        raise Interrupted(path, len(read_card(path).acn.episodes) if path else 0) from None
    except BaseException as e:
        for ref in refs:
            ray.cancel(ref, force=True)
        raise output.fail(e) from None
    finally:
        signal.signal(signal.SIGTERM, previous)
        signal.signal(signal.SIGINT, previous_int)
        shutil.rmtree(work, ignore_errors=True)
        progress.shutdown()
    return path
