"""A robot log (CSV or Parquet table) -> a measurement dataset (``acn-import``).

The log has one row per control step: ``episode_index`` (optional, default 0), ``timestamp``
(s), state channels named as in ``acn.toolkit.state`` (``base_pos_x``, ..., ``FR_hip_pos``,
..., ``imu_acc_z``), actions as ``action.<joint>`` and, if logged, applied torques as
``effort.<joint>``. A map file renames and scales other columns onto these names:

    {"FR_hip_pos": "q0", "FR_thigh_pos": {"column": "q1_deg", "scale": 0.0174533, "offset": 0.0}}

(value = scale * column + offset). Channels the log lacks are stored as NaN and listed in the
metadata (``missing_channels``); joint positions and actions are the minimum.

Transitions: s_{t+1} is the next row of the same episode. A row with a non-finite value, or a
time step that differs from the control period by more than ``dt_tolerance`` of it, ends a
segment: the episode is split there (never bridged), and the cut rows and splits are counted.
Each segment of n rows gives n - 1 transitions and becomes one dataset episode.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from acn.datasets import schema
from acn.errors import UserError
from acn.jsonfile import read_json
from acn.toolkit.collector import FALL_RULE, Episode, Trace, fallen
from acn.toolkit.robot import ModelParams
from acn.toolkit.state import ACTION_NAMES, GROUPS, STATE_NAMES

ACTION_COLUMNS = tuple(f"action.{j}" for j in ACTION_NAMES)
EFFORT_COLUMNS = tuple(f"effort.{j}" for j in ACTION_NAMES)
INDEX_COLUMNS = ("episode_index", "timestamp")
KNOWN_COLUMNS = (*INDEX_COLUMNS, *STATE_NAMES, *ACTION_COLUMNS, *EFFORT_COLUMNS)
MAP_ENTRY_KEYS = ("column", "scale", "offset")


@dataclass
class ImportConfig:
    """Control settings of the logged robot (recorded in the metadata) and import options."""

    control_hz: int
    kp: float
    kd: float
    torque_limit: float
    action_mode: str = "position"
    physics_hz: int = 1000
    dt_tolerance: float = 0.1  # fraction of the control period a time step may deviate


@dataclass
class ImportReport:
    rows: int
    transitions: int
    episodes: int
    cut_nonfinite: int
    time_breaks: int
    dropped_short: int
    missing: list[str]


def read_table(path: Path) -> dict[str, np.ndarray]:
    """Columns of a CSV or Parquet file as float arrays (non-numeric columns are skipped)."""
    import pyarrow as pa

    if not path.is_file():
        raise UserError(f"log file {path} does not exist")
    suffix = path.suffix.lower()
    try:
        if suffix == ".csv":
            import pyarrow.csv as pacsv

            table = pacsv.read_csv(path)
        elif suffix in (".parquet", ".pq"):
            import pyarrow.parquet as pq

            table = pq.read_table(path)
        else:
            raise UserError(f"{path}: a log must be a .csv or .parquet file")
    except (pa.ArrowInvalid, OSError) as e:
        raise UserError(f"cannot read {path}: {str(e).splitlines()[0]}") from None
    out = {}
    for name, col in zip(table.column_names, table.columns):
        if pa.types.is_integer(col.type) or pa.types.is_floating(col.type) or pa.types.is_boolean(col.type):
            out[name] = col.to_numpy(zero_copy_only=False).astype(np.float64)
    return out


def read_map(path: Path | None) -> dict:
    if path is None:
        return {}
    mapping = read_json(path, f"map file {path} does not exist")
    if not isinstance(mapping, dict):
        raise UserError(f"{path}: a map is a JSON object  name -> column or {{column, scale, offset}}")
    return mapping


def resolve_columns(table: dict[str, np.ndarray], mapping: dict) -> dict[str, np.ndarray]:
    """Our column names -> values: mapped columns (scaled), then columns already named ours."""
    out: dict[str, np.ndarray] = {}
    for name, entry in mapping.items():
        if name not in KNOWN_COLUMNS:
            raise UserError(f"map: {name!r} is not a channel of this toolkit (e.g. FR_hip_pos, action.FR_hip, "
                            f"effort.FR_hip, timestamp)")
        if isinstance(entry, str):
            entry = {"column": entry}
        if not isinstance(entry, dict) or "column" not in entry or any(k not in MAP_ENTRY_KEYS for k in entry):
            raise UserError(f"map: {name!r} must be a column name or {{\"column\": ..., \"scale\": ..., \"offset\": ...}}")
        column = entry["column"]
        if column not in table:
            raise UserError(f"map: the log has no numeric column {column!r} (for {name})")
        scale, offset = entry.get("scale", 1.0), entry.get("offset", 0.0)
        if not all(isinstance(x, (int, float)) and np.isfinite(x) for x in (scale, offset)):
            raise UserError(f"map: scale and offset of {name!r} must be finite numbers")
        out[name] = scale * table[column] + offset
    for name in KNOWN_COLUMNS:
        if name not in out and name in table:
            out[name] = table[name]
    return out


def _segments(episode: np.ndarray, timestamp: np.ndarray, good: np.ndarray, period: float, tol: float):
    """Consecutive runs of good rows with the right time step; yields (rows, end reason)."""
    n = len(episode)
    start = None
    for i in range(n + 1):
        ends_here = i == n or not good[i] or (start is not None and episode[i] != episode[i - 1])
        gap = (not ends_here and start is not None
               and abs(timestamp[i] - timestamp[i - 1] - period) > tol * period)
        if start is not None and (ends_here or gap):
            reason = ("log_end" if i == n or episode[i] != episode[i - 1]
                      else "split_nonfinite" if not good[i] else "split_time_gap")
            yield np.arange(start, i), reason
            start = None
        if start is None and i < n and good[i]:
            start = i


def import_log(log: str | Path, out: str | Path, cfg: ImportConfig, map_path: str | Path | None = None,
               overwrite: bool = False) -> tuple[Path, ImportReport]:
    """Convert ``log`` into a measurement dataset at ``out`` (all or nothing)."""
    from acn.datasets.writer import DatasetWriter

    log = Path(log)
    if cfg.physics_hz % cfg.control_hz:
        raise UserError(f"--physics-hz ({cfg.physics_hz}) must be a multiple of --control-hz ({cfg.control_hz})")
    cols = resolve_columns(read_table(log), read_map(Path(map_path) if map_path else None))
    n = len(next(iter(cols.values()))) if cols else 0
    if "timestamp" not in cols:
        raise UserError(f"{log} has no timestamp column (s); map one with --map")
    joint_pos = [c for c in GROUPS["joint_pos"] if c not in cols]
    actions = [c for c in ACTION_COLUMNS if c not in cols]
    if joint_pos or actions:
        raise UserError(f"{log} lacks joint positions or actions, the minimum a measurement needs: "
                        f"missing {', '.join(joint_pos + actions)}")
    if n < 2:
        raise UserError(f"{log} has fewer than 2 rows")
    missing = [c for c in STATE_NAMES if c not in cols]
    state = np.column_stack([cols.get(c, np.full(n, np.nan)) for c in STATE_NAMES])
    action = np.column_stack([cols[c] for c in ACTION_COLUMNS])
    has_effort = all(c in cols for c in EFFORT_COLUMNS)
    effort = np.column_stack([cols[c] for c in EFFORT_COLUMNS]) if has_effort else np.full((n, 12), np.nan)
    episode = cols.get("episode_index", np.zeros(n))
    timestamp = cols["timestamp"]
    present = ~np.isin(np.arange(len(STATE_NAMES)), [STATE_NAMES.index(c) for c in missing])
    good = np.isfinite(state[:, present]).all(1) & np.isfinite(action).all(1) & np.isfinite(timestamp) \
        & np.isfinite(episode)
    if has_effort:
        good &= np.isfinite(effort).all(1)

    period = 1.0 / cfg.control_hz
    meta = {
        "format_version": schema.FORMAT_VERSION, "paired": False,
        "source": {"simulator": "log", "version": None, "file": log.name}, "target": None,
        "physics_dt": 1.0 / cfg.physics_hz, "substeps": cfg.physics_hz // cfg.control_hz,
        "control_hz": float(cfg.control_hz), "action_mode": cfg.action_mode, "kp": cfg.kp, "kd": cfg.kd,
        "torque_limit": cfg.torque_limit, "model_params": ModelParams().as_json(), "policy": "log",
        "seed": None, "corrector": None, "state_names": list(STATE_NAMES), "action_names": list(ACTION_NAMES),
        "fall_rule": FALL_RULE, "missing_channels": missing, "effort_logged": has_effort,
    }
    writer = DatasetWriter(out, fps=cfg.control_hz, paired=False, task=f"log {log.name}", acn_meta=meta,
                           overwrite=overwrite)
    dropped = transitions = 0
    reasons: dict[str, int] = {}
    try:
        for rows, reason in _segments(episode, timestamp, good, period, cfg.dt_tolerance):
            reasons[reason] = reasons.get(reason, 0) + 1
            if len(rows) < 2:
                dropped += 1
                continue
            now, nxt = rows[:-1], rows[1:]
            trace = Trace(state[now], action[now], effort[now], state[nxt],
                          np.array([_fallen(s) for s in state[nxt]], dtype=bool))
            writer.write(Episode(writer.num_episodes, timestamp[now] - timestamp[now[0]], trace, None, reason))
            transitions += len(now)
        report = ImportReport(rows=n, transitions=transitions, episodes=writer.num_episodes,
                              cut_nonfinite=int((~good).sum()), time_breaks=reasons.get("split_time_gap", 0),
                              dropped_short=dropped, missing=missing)
        writer.meta.info[schema.ACN_KEY]["import"] = {"file": log.name, "rows": n, "transitions": transitions,
                          "rows_cut_nonfinite": report.cut_nonfinite, "time_step_breaks": report.time_breaks,
                          "segments_too_short": dropped, "dt_tolerance": cfg.dt_tolerance}
        if writer.num_episodes == 0:
            raise UserError(f"{log}: no two consecutive good rows at {cfg.control_hz} Hz: nothing to import "
                            f"({report.cut_nonfinite} non-finite rows, {report.time_breaks} time-step breaks)")
        path = writer.commit()
    except BaseException:
        writer.abort()
        raise
    return path, report


def _fallen(state: np.ndarray) -> bool:
    """The fall rule where the log has the trunk pose; False where it has not."""
    return bool(np.isfinite(state[:6]).all() and fallen(state))
