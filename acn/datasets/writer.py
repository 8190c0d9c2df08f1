"""Write collected episodes into a LeRobot v3.0 dataset, all or nothing.

Layout and metadata are lerobot's own: ``LeRobotDatasetMetadata`` creates ``meta/info.json``
and keeps ``meta/episodes``, ``meta/tasks.parquet`` and ``meta/stats.json`` (episode stats from
lerobot's ``compute_episode_stats``). Only the frame rows are written here, straight to
``data/chunk-XXX/file-YYY.parquet`` with pyarrow in the schema lerobot derives from the
features. Reason: ``LeRobotDataset.save_episode`` runs a per-row ``datasets.map`` to embed
images, about 1 ms per frame even with no image, which cost more than simulating the frame.
``tests/test_dataset.py`` checks that ``LeRobotDataset`` loads the result identically to a
dataset written through ``add_frame`` / ``save_episode``.

The dataset is one ``acn.outputs.writing.Writing``: its path claimed for the run, built in a
hidden directory beside the destination and moved into place whole by ``commit``; an
interrupted or failed collection never leaves a half-written dataset, and ``fail`` turns a write
error into one line.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from acn.datasets import schema
from acn.datasets.metadata import AcnMetadata, EmptyEpisode, EpisodeEntry
from acn.errors import UserError
from acn.outputs.writing import Writing

from acn.sim.collector import Episode, Trace
from acn.sim.state import ACTION_DIM

os.environ.setdefault("HF_HUB_OFFLINE", "1")


def episode_columns(ep: Episode, paired: bool) -> dict[str, np.ndarray]:
    """The per-frame feature columns of one episode (no index columns); an action 60 wide
    (targets, kp, kd, velocity targets, feedforward: ``SimConfig.hybrid``) goes into ``action`` and
    ``action.hybrid``."""
    cols: dict[str, np.ndarray] = {}

    def put(tr: Trace, prefix: str) -> None:
        cols[prefix + schema.STATE] = tr.state.astype(np.float32)
        cols[prefix + schema.ACTION] = tr.action[:, :ACTION_DIM].astype(np.float32)
        if tr.action.shape[1] > ACTION_DIM:
            cols[prefix + schema.ACTION_HYBRID] = tr.action[:, ACTION_DIM:].astype(np.float32)
        cols[prefix + schema.EFFORT] = tr.effort.astype(np.float32)
        cols[prefix + schema.NEXT_STATE] = tr.next_state.astype(np.float32)
        cols[prefix + schema.NEXT_FALLEN] = tr.fallen.astype(bool)

    put(ep.source, "")
    if paired:
        put(ep.target, schema.TARGET_PREFIX)
    done = np.zeros(len(ep), dtype=bool)
    done[-1] = True
    cols[schema.DONE] = done
    return cols


def _arrow_column(values: np.ndarray, typ: pa.DataType) -> pa.Array:
    if pa.types.is_fixed_size_list(typ):
        flat = pa.array(np.ascontiguousarray(values).reshape(-1), type=typ.value_type)
        return pa.FixedSizeListArray.from_arrays(flat, typ.list_size)
    return pa.array(values, type=typ)


def _sort_stats(root: Path) -> None:
    """Rewrite ``meta/stats.json`` with sorted keys: lerobot builds it from a set, whose order
    differs between processes, so the same data would give files that differ byte for byte."""
    import json

    from lerobot.datasets.utils import STATS_PATH, write_json

    path = root / STATS_PATH
    if path.is_file():
        stats = json.loads(path.read_text())
        write_json({k: dict(sorted(v.items())) if isinstance(v, dict) else v for k, v in sorted(stats.items())}, path)


class DatasetWriter:
    """Writes ``Episode`` objects into a new dataset at ``root`` (see module docstring).

    ``acn`` is the ``acn`` block written on ``commit``, with the episodes written listed in it;
    a writer of an import may replace it (``dataclasses.replace``) with what the import cut."""

    def __init__(self, root: str | Path, fps: int, paired: bool, task: str, acn_meta: AcnMetadata,
                 overwrite: bool = False) -> None:
        from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
        from lerobot.datasets.utils import get_hf_features_from_features

        self.root = Path(root).absolute()
        self.output = Writing(self.root, schema.DATASET, overwrite)
        self._tmp = self.output.path
        self.paired, self.task = paired, task
        try:
            self.meta = LeRobotDatasetMetadata.create(
                repo_id=f"acn/{self.root.name}", fps=fps,
                features=schema.features(paired, hybrid=bool(acn_meta.hybrid_actions)),
                robot_type=schema.ROBOT_TYPE, root=self._tmp, use_videos=False,
            )
        except BaseException as e:
            raise self.output.fail(e) from None
        self.acn = acn_meta
        self._episodes: list[EpisodeEntry] = []
        self._empty: list[EmptyEpisode] = []
        self._arrow_schema = get_hf_features_from_features(self.meta.features).arrow_schema
        self._writer: pq.ParquetWriter | None = None
        self._file = (0, 0)  # (chunk, file) being written
        self._file_frames = 0
        self.num_episodes = 0
        self.num_frames = 0

    def write(self, ep: Episode) -> None:
        """Append one episode; an episode with no frame is only listed in the metadata."""
        from lerobot.datasets.compute_stats import compute_episode_stats

        n = len(ep)
        if n == 0:
            self._empty.append(EmptyEpisode(collection_index=ep.index, end=ep.end))
            return
        self.meta.save_episode_tasks([self.task])
        cols = episode_columns(ep, self.paired)
        cols.update({
            "timestamp": (np.arange(n) / self.meta.fps).astype(np.float32),  # as lerobot's add_frame
            "frame_index": np.arange(n, dtype=np.int64),
            "episode_index": np.full(n, self.num_episodes, dtype=np.int64),
            "index": np.arange(self.num_frames, self.num_frames + n, dtype=np.int64),
            "task_index": np.full(n, self.meta.get_task_index(self.task), dtype=np.int64),
        })
        location = self._write_rows(cols, n)
        with warnings.catch_warnings():  # lerobot warns that it casts bool flags to uint8 for histograms
            warnings.simplefilter("ignore", RuntimeWarning)
            stats = compute_episode_stats(cols, self.meta.features)
        self.meta.save_episode(self.num_episodes, n, [self.task], stats, location)
        self._episodes.append(EpisodeEntry(episode_index=self.num_episodes, length=n, end=ep.end,
                                           collection_index=ep.index))
        self.num_episodes += 1
        self.num_frames += n

    def _write_rows(self, cols: dict[str, np.ndarray], n: int) -> dict:
        from lerobot.datasets.utils import update_chunk_file_indices

        table = pa.Table.from_arrays(
            [_arrow_column(cols[f.name], f.type) for f in self._arrow_schema], schema=self._arrow_schema)
        if self._writer is not None:
            size_mb = self._writer_bytes() / 2**20
            if size_mb + size_mb / max(self._file_frames, 1) * n >= self.meta.data_files_size_in_mb:
                self._writer.close()
                self._writer = None
                self._file = update_chunk_file_indices(*self._file, self.meta.chunks_size)
                self._file_frames = 0
        if self._writer is None:
            path = self._tmp / self.meta.data_path.format(chunk_index=self._file[0], file_index=self._file[1])
            path.parent.mkdir(parents=True, exist_ok=True)
            self._writer = pq.ParquetWriter(path, schema=self._arrow_schema, compression="snappy",
                                            use_dictionary=True)
            self._path = path
        self._writer.write_table(table)
        self._file_frames += n
        return {"data/chunk_index": self._file[0], "data/file_index": self._file[1],
                "dataset_from_index": self.num_frames, "dataset_to_index": self.num_frames + n}

    def _writer_bytes(self) -> int:
        return self._path.stat().st_size if self._path.exists() else 0

    def commit(self) -> Path:
        """Close the files and move the dataset into place; returns its path."""
        from lerobot.datasets.utils import write_info

        if self.num_episodes == 0:
            self.abort()
            raise UserError("every episode ended before its first step (the simulator blew up): nothing written")
        try:
            if self._writer is not None:
                self._writer.close()
                self._writer = None
            self.meta._close_writer()  # flushes the buffered episode metadata
            self.meta.info[schema.ACN_KEY] = replace(self.acn, episodes=tuple(self._episodes),
                                                     empty_episodes=tuple(self._empty) or None).to_json()
            write_info(self.meta.info, self._tmp)
            _sort_stats(self._tmp)
        except BaseException as e:
            raise self.fail(e) from None
        return self.output.commit()

    def abort(self) -> None:
        """Discard everything written so far."""
        self._close_quietly()
        self.output.abort()

    def fail(self, error: BaseException) -> BaseException:
        """Discard everything written so far; the exception to raise for ``error`` (a write error
        becomes one line: ``acn.outputs.writing.WriteFailed``)."""
        self._close_quietly()
        return self.output.fail(error)

    def _close_quietly(self) -> None:
        """Close the files before they are deleted; where a flush fails (a full disk), drop what
        lerobot still buffers, so that it does not try again when it is garbage-collected."""
        writers = [self._writer, None]
        self._writer = None
        try:
            self.meta._close_writer()
        except Exception:  # noqa: BLE001 - best effort before deleting
            self.meta.metadata_buffer.clear()
            writers[1], self.meta.writer = getattr(self.meta, "writer", None), None
        for writer in writers:
            try:
                if writer is not None:
                    writer.close()
            except Exception:  # noqa: BLE001
                pass
