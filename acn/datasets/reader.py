"""Read collected datasets back (through ``LeRobotDataset``) as transition arrays.

``load_paired(paths)`` checks that every dataset is a paired ``acn-collect`` dataset with the
same channels, rates and action mode, concatenates them (episode ids made unique across
files), and skips rows with non-finite values (counted in ``skipped_nonfinite``).

``state_difference`` / ``transition_residual`` difference states with wrapped angles, and
``percentile_filter`` is the paper's 70th-percentile filter as a reading option.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from acn.datasets import schema
from acn.datasets.metadata import AcnMetadata, DatasetCard
from acn.errors import UserError
from acn.jsonfile import read_json
from acn.sim import plausible
from acn.sim.state import ACTION_DIM, ACTION_NAMES, STATE_DIM, STATE_NAMES, WRAPPED_INDEX, wrap_angle

os.environ.setdefault("HF_HUB_OFFLINE", "1")


# What must agree between datasets that are fitted together: (field as a message names it, its value).
MUST_MATCH: tuple[tuple[str, Callable[[DatasetCard], object]], ...] = (
    ("direction (source -> target)", lambda card: card.acn.direction),
    ("robot", lambda card: card.robot_type),
    ("--control-hz", lambda card: card.acn.control_hz),
    ("--physics-hz", lambda card: round(card.acn.physics_hz, 6)),
    ("--action-mode", lambda card: card.acn.action_mode),
    ("--kp", lambda card: card.acn.kp),
    ("--kd", lambda card: card.acn.kd),
    ("--torque-limit", lambda card: card.acn.torque_limit),
    ("state channels", lambda card: card.acn.state_names),
    ("joint names", lambda card: card.acn.action_names),
)


def refuse_mixed(cards: list[DatasetCard]) -> None:
    """One line naming both datasets and the field where datasets fitted together disagree."""
    first = cards[0]
    for card in cards[1:]:
        for what, value in MUST_MATCH:
            if value(card) != value(first):
                raise UserError(f"{card.path} and {first.path} do not belong together: {what} {value(card)!r:.60} vs "
                                f"{value(first)!r:.60}")


def read_card(path: str | Path) -> DatasetCard:
    """The ``acn`` block of a dataset's ``meta/info.json``, read and checked once (a one-line
    ``UserError`` if it is not an acn dataset or the block is malformed), with LeRobot's robot type."""
    info = read_json(Path(path) / "meta" / "info.json", f"{path} is not a LeRobot dataset (no meta/info.json)")
    if not isinstance(info, dict) or schema.ACN_KEY not in info:
        raise UserError(f"{path} was not written by acn-collect (no '{schema.ACN_KEY}' block in meta/info.json)")
    robot = info.get("robot_type")
    return DatasetCard(Path(path), robot if isinstance(robot, str) else None,
                       AcnMetadata.from_json(info[schema.ACN_KEY], path))


_WIDTH = {schema.STATE: (STATE_DIM,), schema.NEXT_STATE: (STATE_DIM,), schema.ACTION: (ACTION_DIM,),
          schema.EFFORT: (ACTION_DIM,), schema.ACTION_HYBRID: (len(schema.HYBRID_NAMES), 3 * ACTION_DIM)}  # 36: format 1
INDEX_COLUMNS = ("episode_index", "frame_index", "timestamp")


def read_columns(path: str | Path, keys: list[str], optional: tuple[str, ...] = ()) -> tuple[dict[str, np.ndarray], int]:
    """``keys`` (and those of ``optional`` present) of a dataset as float64 arrays, read through
    ``LeRobotDataset``, and its fps. A broken file, a missing column or one of the wrong width is
    a one-line ``UserError`` (the libraries' own error logging is silenced while reading)."""
    import pyarrow.parquet as pq
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    path = Path(path)
    for f in sorted(path.rglob("*.parquet")):
        try:
            pq.ParquetFile(f).metadata
        except Exception as e:  # noqa: BLE001 - pyarrow raises several kinds on a broken file
            raise UserError(f"{f} is not a readable Parquet file: {str(e).splitlines()[0]}") from None
    logging.disable(logging.CRITICAL)
    try:
        ds = LeRobotDataset(f"acn/{path.name}", root=path)
        present = set(ds.hf_dataset.column_names)
        if missing := [k for k in keys if k not in present]:
            raise UserError(f"{path} has no column {missing[0]!r}")
        wanted = list(keys) + [k for k in optional if k in present]
        cols = ds.hf_dataset.with_format("numpy", columns=wanted)[:]
        out = {k: np.asarray(cols[k], dtype=np.float64) for k in wanted}
        fps = int(ds.meta.fps)
    except UserError:
        raise
    except Exception as e:  # noqa: BLE001 - lerobot raises many kinds on a broken dataset
        raise UserError(f"cannot read {path} as a LeRobot dataset: {e}".splitlines()[0]) from None
    finally:
        logging.disable(logging.NOTSET)
    for k, v in out.items():
        widths = _WIDTH.get(k.removeprefix(schema.TARGET_PREFIX))
        if not (v.ndim == 2 and v.shape[1] in widths if widths else v.ndim == 1):
            raise UserError(f"{path}: column {k!r} has shape {v.shape[1:]}, expected {(widths[0],) if widths else ()}")
    return out, fps


def state_difference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a - b for state vectors (..., STATE_DIM), angles differenced on the circle."""
    d = a - b
    d[..., WRAPPED_INDEX] = wrap_angle(d[..., WRAPPED_INDEX])
    return d


@dataclass
class PairedTransitions:
    """N paired transitions (float64 arrays); rows are frames of one or more datasets."""

    state: np.ndarray         # (N, 43) s_t in the source
    action: np.ndarray        # (N, 12) a_t (policy on the source state)
    next_state: np.ndarray    # (N, 43) s_{t+1} in the source
    target_state: np.ndarray  # (N, 43) s_t in the target
    target_action: np.ndarray  # (N, 12) what the target received
    target_next_state: np.ndarray  # (N, 43)
    episode: np.ndarray       # (N,) int, unique across the datasets read
    info: AcnMetadata         # the first dataset's ``acn`` block
    sources: list[str] = field(default_factory=list)
    skipped_nonfinite: int = 0

    def __len__(self) -> int:
        return len(self.state)

    def residual(self) -> np.ndarray:
        """delta_s_{t+1} = (s'_src - s_src) - (s'_tgt - s_tgt), (N, 43), angles wrapped."""
        return state_difference(state_difference(self.next_state, self.state),
                                state_difference(self.target_next_state, self.target_state))

    def gap(self, channels: np.ndarray | None = None) -> np.ndarray:
        """||s_src - s_tgt||_2 per row over ``channels`` (default: all)."""
        d = state_difference(self.state, self.target_state)
        return np.linalg.norm(d if channels is None else d[:, channels], axis=1)

    def subset(self, mask: np.ndarray) -> "PairedTransitions":
        return PairedTransitions(
            self.state[mask], self.action[mask], self.next_state[mask], self.target_state[mask],
            self.target_action[mask], self.target_next_state[mask], self.episode[mask], self.info,
            self.sources, self.skipped_nonfinite)


def percentile_filter(gap: np.ndarray, percentile: float = 70.0) -> np.ndarray:
    """The paper's filter: keep rows whose source-target gap is below its ``percentile``."""
    if not 0 < percentile <= 100:
        raise UserError(f"filter percentile must be in (0, 100], got {percentile}")
    if percentile == 100:
        return np.ones(len(gap), dtype=bool)
    return gap < np.percentile(gap, percentile)


def refuse_implausible(path: Path, episode: np.ndarray, parts: list[tuple[str, np.ndarray, object, tuple]]) -> None:
    """One line naming the episode and column of the first value no A1 can produce
    (``acn.sim.plausible``) in ``parts``: (what, values, bound, column names) each."""
    for what, values, bound, names in parts:
        first = plausible.first_beyond(values, bound, names)
        if first is not None:
            row, name, value = first
            raise UserError(f"{path}: episode {int(episode[row])} has {what} {name} = {value:.3g}, which no A1 can "
                            "produce (acn-import cuts such rows; the bounds are in acn.sim.plausible)")


def load_paired(paths: list[str | Path]) -> PairedTransitions:
    """Read paired datasets written by ``acn-collect`` (see module docstring)."""
    if not paths:
        raise UserError("no dataset given")
    paths = [Path(p) for p in paths]
    cards = [read_card(p) for p in paths]
    for card in cards:
        if not card.acn.paired:
            raise UserError(f"{card.path} is not a paired dataset (recorded without --target)")
    refuse_mixed(cards)
    parts, episode_offset, skipped = [], 0, 0
    for path, card in zip(paths, cards):
        keys = [schema.STATE, schema.ACTION, schema.NEXT_STATE, schema.target_key(schema.STATE),
                schema.target_key(schema.ACTION), schema.target_key(schema.NEXT_STATE)]
        cols, _ = read_columns(path, keys + ["episode_index"])
        arrays = [cols[k] for k in keys]
        mode = card.acn.action_mode
        refuse_implausible(path, cols["episode_index"], [
            (f"{side}state", cols[side + schema.STATE], plausible.STATE_BOUND, STATE_NAMES)
            for side in ("", schema.TARGET_PREFIX)] + [
            (f"{side}action", cols[side + schema.ACTION], plausible.action_bound(mode, ACTION_DIM), ACTION_NAMES)
            for side in ("", schema.TARGET_PREFIX)])
        episode = np.asarray(cols["episode_index"], dtype=np.int64) + episode_offset
        finite = np.all([np.isfinite(a).all(axis=1) for a in arrays], axis=0)
        if len(finite) and not finite.any():
            raise UserError(f"{path}: every row has a non-finite state or action (NaN or inf): nothing to read")
        skipped += int((~finite).sum())
        parts.append([a[finite] for a in arrays] + [episode[finite]])
        episode_offset = int(episode.max()) + 1 if len(episode) else episode_offset
    cat = [np.concatenate([p[i] for p in parts]) for i in range(7)]
    return PairedTransitions(*cat, info=cards[0].acn, sources=[str(p) for p in paths], skipped_nonfinite=skipped)


@dataclass
class RecordedFrames:
    """Every row of one dataset, paired or not (measurements only), in file order (float64).

    ``target_*`` are None for an unpaired dataset. Rows keep non-finite values (a viewer shows
    them as gaps); ``episode`` and ``frame`` are the dataset's ``episode_index`` / ``frame_index``.
    """

    path: Path
    info: AcnMetadata         # the dataset's ``acn`` block
    fps: int
    episode: np.ndarray       # (N,) int
    frame: np.ndarray         # (N,) int, index within the episode
    timestamp: np.ndarray     # (N,) s from the episode start
    state: np.ndarray         # (N, 43) s_t of the source (or the measured robot)
    action: np.ndarray        # (N, 12) a_t
    target_state: np.ndarray | None = None   # (N, 43)
    target_action: np.ndarray | None = None  # (N, 12)

    @property
    def paired(self) -> bool:
        return self.target_state is not None

    @property
    def episodes(self) -> list[int]:
        return sorted({int(e) for e in np.unique(self.episode)})

    def rows(self, episode: int) -> np.ndarray:
        """Row indices of one episode, in frame order."""
        idx = np.flatnonzero(self.episode == episode)
        return idx[np.argsort(self.frame[idx], kind="stable")]


def load_frames(path: str | Path) -> RecordedFrames:
    """Read one ``acn-collect`` dataset, paired or not, through ``LeRobotDataset``."""
    path = Path(path)
    acn = read_card(path).acn
    paired = acn.paired
    keys = [schema.STATE, schema.ACTION] + ([schema.target_key(schema.STATE), schema.target_key(schema.ACTION)]
                                            if paired else [])
    cols, fps = read_columns(path, keys + list(INDEX_COLUMNS))
    return RecordedFrames(path, acn, fps, cols["episode_index"].astype(np.int64),
                          cols["frame_index"].astype(np.int64), cols["timestamp"], *[cols[k] for k in keys])
