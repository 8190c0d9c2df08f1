"""A robot log (CSV, Parquet or JSON-lines table) -> a measurement dataset (``acn-import``).

The log has one row per control step: ``episode_index`` (optional, default 0), ``timestamp``
(s), state channels named as in ``acn.sim.state`` (``base_pos_x``, ..., ``FR_hip_pos``,
..., ``imu_acc_z``), actions as ``action.<joint>`` and, if logged, applied torques as
``effort.<joint>``. The trunk's orientation may come as a quaternion instead of Euler angles
(``base_quat_w``, ``base_quat_x``, ``base_quat_y``, ``base_quat_z``), its velocities in the world
frame instead of the body frame (``ImportConfig.linvel_frame`` / ``angvel_frame``): both are
converted. A map file renames and scales other columns onto these names:

    {"FR_hip_pos": "q0", "FR_thigh_pos": {"column": "q1_deg", "scale": 0.0174533, "offset": 0.0},
     "FR_contact": {"column": "foot_force_0", "threshold": 20.0}}

(value = scale * column + offset; a contact channel with a ``threshold`` becomes the 0/1 flag
value > threshold, for a log of foot forces). Channels the log lacks are stored as NaN and listed in the
metadata (``missing_channels``); joint positions and actions are the minimum. A hybrid
(MIT-style) command, ``action_vel.<joint>`` (rad/s) and ``action_torque.<joint>`` (N m) beside the
position target, and gains sent with each command (``action_kp.<joint>``, ``action_kd.<joint>``)
are stored with the actions (``action.hybrid``: kp, kd, dq_des and tau_ff),
and the model's PD runs them as sent (``_hybrid_actions``, ``SimConfig.hybrid``).

Several logs (a file per run, the same columns) are read one after the other, each file's
episodes apart (``read_logs``). A CSV is read as loggers and spreadsheets leave it
(``read_table``): comment lines before the header, decimal commas, a row cut off or garbled (set
aside and counted), text among numbers (read as NaN and counted).

Transitions: s_{t+1} is the next row of the same episode. A row with a non-finite value, or a
time step that differs from the control period by more than ``dt_tolerance`` of it, ends a
segment: the episode is split there (never bridged), and the cut rows and splits are counted.
The spread of the time steps is reported; where many splits come from a loop whose period
jitters by a few per cent, the report suggests the tolerance that keeps the episodes whole
(the model simulates every step for the control period; jitter of +-10 % is noise to it).
Each segment of n rows gives n - 1 transitions and becomes one dataset episode. A log whose
median time step is not the control period is refused (timestamps in ms, a wrong rate).

The written episodes are checked for consistency (``acn.measurements.checks``: units, signs,
frames, conventions); the findings are returned, and recorded in the metadata
(``acn.import.checks``).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType

import numpy as np

from acn.datasets import schema
from acn.datasets.metadata import AcnMetadata, ImportInfo, Simulator
from acn.measurements import checks, naming
from acn.errors import UserError
from acn.jsonfile import read_json
from acn.sim import plausible
from acn.sim.actuation import position_targets
from acn.sim.backends.base import IMU_ACC_KINDS, joint_gains, physics_hz_for
from acn.sim.collector import FALL_RULE, Episode, Trace, fallen
from acn.sim.robot import ModelParams, per_joint
from acn.sim.rotations import quat_to_rpy, rpy_to_matrices
from acn.sim.state import ACTION_NAMES, FOOT_NAMES, GROUPS, NUM_JOINTS, SLICES, STATE_NAMES

ACTION_COLUMNS = tuple(f"action.{j}" for j in ACTION_NAMES)
EFFORT_COLUMNS = tuple(f"effort.{j}" for j in ACTION_NAMES)
# A hybrid (MIT-style) command beside the position target: a velocity target, rad/s, and a
# feedforward torque, N m; the motor runs kp (q_des - q) + kd (dq_des - qd) + tau_ff.
TARGET_VEL_COLUMNS = tuple(f"action_vel.{j}" for j in ACTION_NAMES)
FEEDFORWARD_COLUMNS = tuple(f"action_torque.{j}" for j in ACTION_NAMES)
# Gains sent with each command (N m/rad, N m s/rad), as controllers that switch their legs between
# stance and swing gains do; the motor runs kp_t (q_des - q) + kd_t (dq_des - qd) + tau_ff.
KP_COLUMNS = tuple(f"action_kp.{j}" for j in ACTION_NAMES)
KD_COLUMNS = tuple(f"action_kd.{j}" for j in ACTION_NAMES)
HYBRID_COLUMNS = {"action_vel": TARGET_VEL_COLUMNS, "action_torque": FEEDFORWARD_COLUMNS, "action_kp": KP_COLUMNS,
                  "action_kd": KD_COLUMNS}
QUAT_COLUMNS = ("base_quat_w", "base_quat_x", "base_quat_y", "base_quat_z")  # the trunk's orientation, world
INDEX_COLUMNS = ("episode_index", "timestamp")
COMMAND_COLUMNS = (*ACTION_COLUMNS, *(c for columns in HYBRID_COLUMNS.values() for c in columns))  # what is sent
KNOWN_COLUMNS = (*INDEX_COLUMNS, *STATE_NAMES, *QUAT_COLUMNS, *COMMAND_COLUMNS, *EFFORT_COLUMNS)
FRAMES = ("body", "world")
MAP_ENTRY_KEYS = ("column", "scale", "offset", "threshold")
_DECIMAL_COMMA = re.compile(r"^[-+]?\d+,\d+([eE][-+]?\d+)?$")
_DECIMAL_POINT = re.compile(r"^[-+]?\d*\.\d+([eE][-+]?\d+)?$")
MOSTLY_NUMBERS = 0.9  # a text column with this share of numbers is a column of numbers with some text (read_table)
HDF5 = (".h5", ".hdf5", ".hdf")  # HDF5 logs, read by acn.measurements.arrays (as .npz archives are)
COMPRESSED = (".gz", ".bz2", ".zst")  # a log.csv.gz is read as its CSV (pyarrow decompresses by extension)
MALFORMED_MAX = 0.1  # a CSV with this share of rows of the wrong number of fields or more is refused (read_table)
JITTER_MAX = 0.25  # a time-step spread up to this share of the period is taken as jitter (ImportReport.tolerance_hint)


@dataclass
class ImportConfig:
    """Control settings of the logged robot (recorded in the metadata) and import options."""

    control_hz: int
    kp: float | tuple[float, ...]  # N m/rad: every joint, or 12 in JOINT_NAMES order
    kd: float | tuple[float, ...]  # N m s/rad
    torque_limit: float
    action_mode: str = "position"
    physics_hz: int | None = None  # None: the multiple of control_hz nearest 1 kHz (``physics_hz_for``)
    dt_tolerance: float = 0.1  # fraction of the control period a time step may deviate
    linvel_frame: str = "body"  # the frame the log's base_linvel is in (world: rotated into the body frame)
    angvel_frame: str = "body"  # the same for base_angvel
    leg_order: tuple[str, ...] = FOOT_NAMES  # the legs as the log orders them (legged_gym: FL, FR, RL, RR)
    shift_actions: int = 0  # rows: each state takes the command logged this many rows later in its episode
    imu_acc: str | None = None  # the accelerometer reads the "mean" over the control step or at the "instant" of
    # the row (``SimConfig.imu_acc``); None: not stated, acn-diagnose judges it from the log


def _implausible(state: np.ndarray, present: np.ndarray, action: np.ndarray, effort: np.ndarray | None,
                 action_mode: str) -> tuple[np.ndarray, str]:
    """Rows with a value no A1 can produce (``acn.sim.plausible``), and the first such value."""
    parts = [(state[:, present], plausible.STATE_BOUND[present], tuple(np.array(STATE_NAMES)[present])),
             (action, plausible.action_bound(action_mode, action.shape[1]), plausible.action_names(action.shape[1]))]
    if effort is not None:
        parts.append((effort, plausible.EFFORT_BOUND, tuple(f"effort.{j}" for j in ACTION_NAMES)))
    rows = np.zeros(len(state), dtype=bool)
    examples: list[tuple[int, str, float]] = []
    for values, bound, names in parts:
        rows |= plausible.beyond(values, bound)
        if (first := plausible.first_beyond(values, bound, names)) is not None:
            examples.append(first)
    row, name, value = min(examples) if examples else (0, "", 0.0)
    return rows, f"{name} = {value:.3g} in row {row + 1}" if examples else ""


@dataclass
class ImportReport:
    rows: int
    transitions: int
    episodes: int
    cut_nonfinite: int
    time_breaks: int
    dropped_short: int
    missing: list[str]
    findings: list[checks.Finding]
    step_spread: float = 0.0  # 99th percentile of |time step / control period - 1| within episodes
    hybrid: list[str] = field(default_factory=list)  # the kinds of hybrid command columns (stored with the actions)
    quaternion: bool = False  # the trunk's orientation came from base_quat_* (converted to Euler angles)
    partial_effort: list[str] = field(default_factory=list)  # effort.* columns of fewer than 12 joints: not stored
    unused: list[str] = field(default_factory=list)  # the log's columns no channel reads
    suggested_map: dict[str, str | dict] = field(default_factory=dict)  # unused columns named like channels it lacks
    map_notes: list[str] = field(default_factory=list)  # what the draft map read from the data (a quaternion's order)
    malformed: list[str] = field(default_factory=list)  # CSV lines set aside ("file:line" of several files; read_table)
    text_rows: int = 0     # rows with text among numbers, read as NaN (cut where a channel reads it)
    text_example: str = ""
    cut_implausible: int = 0  # rows with a value no A1 can produce (``acn.sim.plausible``)
    implausible_example: str = ""  # the first such value, "column = value in row N"

    def quaternion_hint(self) -> str | None:
        """A line where the orientation came from a quaternion and a check finds the trunk's
        motion or pose inconsistent: a quaternion in x, y, z, w order read as w, x, y, z turns a
        level trunk at heading 0 into one at heading pi, still level, so only the velocities and
        the feet show it."""
        if not self.quaternion or not any(f.check in ("velocities", "stance_feet", "pose") for f in self.findings):
            return None
        return ("the orientation came from base_quat_w, _x, _y, _z: if the log orders its quaternion x, y, z, w "
                "(scipy, ROS, Eigen's coeffs), map base_quat_w to its last component and x, y, z to the first three")

    def tolerance_hint(self, tolerance: float) -> str | None:
        """A line suggesting a wider ``--dt-tolerance`` where the splits come from a control loop
        whose period varies a little (jitter), not from lost rows: more than 1 % of the time steps
        split while 99 % of them lie within ``JITTER_MAX`` of the period."""
        if self.time_breaks <= 0.01 * self.rows or not tolerance < self.step_spread <= JITTER_MAX:
            return None
        wider = math.ceil(round(self.step_spread * 120, 3)) / 100  # 20 % above the spread, in whole per cent
        return (f"the control loop's period varies: 99 % of the time steps are within "
                f"{100 * self.step_spread:.0f} % of it, and {self.time_breaks} split the episodes; if that is the "
                f"loop's jitter, not lost rows, --dt-tolerance {wider:g} keeps them whole")


@dataclass
class LogTable:
    """A log's numeric columns as float arrays, and the CSV rows set aside for their number of fields."""

    columns: dict[str, np.ndarray]
    malformed: list[str] = field(default_factory=list)  # the file's line numbers (1 = the first line; "file:line"
    # where several files are read)
    text_rows: int = 0     # rows with text in a column of numbers (read as NaN: ``_mostly_numbers``)
    text_example: str = ""  # the first such cell, as 'column' = 'text'


def read_table(path: Path) -> LogTable:
    """Columns of a CSV, Parquet, JSON-lines, HDF5 or NumPy .npz file (CSV and JSON lines also
    compressed, ``COMPRESSED``; HDF5's layouts and .npz: ``acn.measurements.arrays``) as float
    arrays (non-numeric columns are skipped; date-time columns become seconds since the epoch;
    nested records are flattened, their columns named "outer.inner"). A CSV's separator is read from its header: comma,
    semicolon or tab; ``#`` comment lines before the header are skipped; column names are stripped
    of surrounding spaces and quotes. A CSV row with another number of fields than the header (a
    last line cut off where the logger stopped mid-write, a line garbled by two writers) is set
    aside and counted (``LogTable.malformed``), unless ``MALFORMED_MAX`` of the rows or more are:
    then the file is refused (another separator or format)."""
    import pyarrow as pa

    if path.is_dir():
        raise UserError(f"{path} is a directory, not a log file (give the files in it: {path}/*.csv)")
    if not path.is_file():
        raise UserError(f"log file {path} does not exist")
    suffixes = [x.lower() for x in path.suffixes]
    compressed = bool(suffixes) and suffixes[-1] in COMPRESSED  # read through pyarrow's detection by extension
    suffix = suffixes[-2] if compressed and len(suffixes) > 1 else path.suffix.lower()
    malformed: list[tuple[int, int, int]] = []  # line, fields expected, fields found
    try:
        if suffix == ".csv":
            table = _read_csv(path, malformed)
        elif suffix in (".parquet", ".pq"):
            import pyarrow.parquet as pq

            table = pq.read_table(path)
        elif suffix in (".jsonl", ".ndjson"):
            import pyarrow.json as pajson

            table = pajson.read_json(path)
        elif suffix in HDF5 and not compressed:
            from acn.measurements.arrays import read_hdf5

            table = pa.table(read_hdf5(path))
        elif suffix == ".npz" and not compressed:
            from acn.measurements.arrays import read_npz

            table = pa.table(read_npz(path))
        else:
            raise UserError(f"{path}: a log must be a .csv, .parquet, .jsonl (one JSON object per line), HDF5 "
                            f"({', '.join(HDF5)}) or NumPy .npz file, .csv and .jsonl also compressed "
                            f"({', '.join(COMPRESSED)})")
        while any(pa.types.is_struct(c.type) for c in table.columns):  # {"imu": {"acc_x": ...}} -> imu.acc_x
            table = table.flatten()
    except (pa.ArrowInvalid, OSError) as e:
        raise UserError(f"cannot read {path}: {str(e).splitlines()[0]}") from None
    if malformed and len(malformed) >= MALFORMED_MAX * (len(malformed) + table.num_rows):
        line, want, got = malformed[0]
        raise UserError(f"cannot read {path}: {len(malformed)} of its {len(malformed) + table.num_rows} rows have "
                        f"another number of fields than its header (line {line}: {got}, the header {want}); "
                        "is the separator comma, semicolon or tab throughout?")
    if table.num_rows == 0:
        raise UserError(f"{path} has no data rows (only a header: {', '.join(table.column_names[:4])}"
                        f"{', ...' if table.num_columns > 4 else ''})")
    out, text_rows, example = {}, None, ""
    names = [n.strip().strip('"').strip() for n in table.column_names]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise UserError(f"{path} has more than one column named {', '.join(map(repr, twice))}: rename them")
    for name, col in zip(names, table.columns):
        if pa.types.is_list(col.type) or pa.types.is_fixed_size_list(col.type) or pa.types.is_large_list(col.type):
            out.update(_list_columns(name, col))
        elif pa.types.is_timestamp(col.type):  # a date-time: seconds since the epoch
            unit = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}[col.type.unit]
            out[name] = col.cast(pa.int64()).to_numpy(zero_copy_only=False).astype(np.float64) * unit
        elif pa.types.is_integer(col.type) or pa.types.is_floating(col.type) or pa.types.is_boolean(col.type):
            out[name] = col.to_numpy(zero_copy_only=False).astype(np.float64)
        elif (pa.types.is_string(col.type) or pa.types.is_large_string(col.type)) and (
                read := _mostly_numbers(col.to_pylist())) is not None:
            out[name], text = read
            example = example or f"{name!r} = {col[int(np.flatnonzero(text)[0])].as_py()!r}"
            text_rows = text if text_rows is None else text_rows | text
    return LogTable(out, [str(line) for line, _, _ in malformed], 0 if text_rows is None else int(text_rows.sum()),
                    example)


def read_logs(paths: list[Path]) -> LogTable:
    """``read_table`` of each file, one after the other: a logger that writes a file per run. The
    files must have the same columns; each file's episodes stay apart from the others' (its
    ``episode_index`` values, or 0 where it has none, shifted past those of the files before)."""
    if len(paths) == 1:
        return read_table(paths[0])
    tables = [read_table(p) for p in paths]
    first = set(tables[0].columns)
    for p, t in zip(paths[1:], tables[1:]):
        if set(t.columns) != first:
            lacks, adds = sorted(first - set(t.columns)), sorted(set(t.columns) - first)
            differ = [f"it {verb} {', '.join(names[:4])}"
                      for verb, names in (("lacks", lacks), ("adds", adds)) if names]
            raise UserError(f"{p} has other columns than {paths[0]}: {'; '.join(differ)}; several logs are read one "
                            "after the other and must have the same columns")
    episodes, after = [], 0.0
    for t in tables:
        n = len(next(iter(t.columns.values()))) if t.columns else 0
        e = t.columns.get("episode_index", np.zeros(n))
        low = float(np.nanmin(e)) if np.isfinite(e).any() else 0.0
        episodes.append(e - low + after)
        after = float(np.nanmax(episodes[-1])) + 1.0 if np.isfinite(e).any() else after + 1.0
    columns = {c: np.concatenate([t.columns[c] for t in tables]) for c in tables[0].columns}
    columns["episode_index"] = np.concatenate(episodes)
    return LogTable(columns, [f"{p.name}:{line}" for p, t in zip(paths, tables) for line in t.malformed],
                    sum(t.text_rows for t in tables), next((t.text_example for t in tables if t.text_example), ""))


def _mostly_numbers(cells: list) -> tuple[np.ndarray, np.ndarray] | None:
    """A text column most of whose cells are numbers (``MOSTLY_NUMBERS``; a header the logger wrote
    again after a restart, a "-" or "n/a" for a lost reading, make the CSV reader read the whole
    column as text): the numbers, NaN elsewhere, and where its text was. None for a column of
    text (a mode, a name), which is skipped."""
    values, text = np.full(len(cells), np.nan), np.zeros(len(cells), bool)
    for i, cell in enumerate(cells):
        if cell is None or not cell.strip():
            continue
        try:
            values[i] = float(cell)
        except ValueError:
            text[i] = True
    filled = int(np.isfinite(values).sum() + text.sum())
    return (values, text) if text.any() and filled and np.isfinite(values).sum() >= MOSTLY_NUMBERS * filled else None


def _read_csv(path: Path, malformed: list[tuple[int, int, int]]):
    """The CSV as a table, its rows of another number of fields than the header appended to
    ``malformed`` (line, expected, found) and skipped. Parsed on one thread: only then does
    pyarrow know a bad row's line."""
    import pyarrow.csv as pacsv

    comments, separator, decimal = _preamble(path)

    def set_aside(row) -> str:
        malformed.append((row.number if row.number is not None else -1, row.expected_columns, row.actual_columns))
        return "skip"

    return pacsv.read_csv(path, read_options=pacsv.ReadOptions(skip_rows=comments, use_threads=False),
                          parse_options=pacsv.ParseOptions(delimiter=separator, invalid_row_handler=set_aside),
                          convert_options=pacsv.ConvertOptions(decimal_point=decimal))


def _list_columns(name: str, col) -> dict[str, np.ndarray]:
    """A column of equally long lists of numbers (a Parquet array per row, e.g. 12 joint angles)
    as one column per element, ``name[0]``, ``name[1]``, ... (to map: ``{"FR_hip_pos": "q[0]"}``);
    other list columns are skipped like other non-numeric columns."""
    import pyarrow as pa

    value_type = col.type.value_type
    if not (pa.types.is_integer(value_type) or pa.types.is_floating(value_type)):
        return {}
    rows = col.to_pylist()
    lengths = {len(r) for r in rows if r is not None}
    if len(lengths) != 1:
        return {}
    width = lengths.pop()
    values = np.array([[np.nan] * width if r is None else [np.nan if v is None else v for v in r] for r in rows],
                      dtype=np.float64)
    return {f"{name}[{i}]": values[:, i] for i in range(width)}


def _preamble(path: Path) -> tuple[int, str, str]:
    """The number of lines before a CSV's header (``#`` comments and blank lines a logger writes
    first), its separator (whichever of comma, semicolon and tab the header has most of) and its
    decimal point: a comma where the separator is not one and the first row writes its numbers
    so (``0,25;1,5``: a spreadsheet in a European locale)."""
    import pyarrow as pa

    with pa.input_stream(str(path), compression="detect") as f:  # the first MiB holds the header and a row
        head = f.read(1 << 20)
        if b"\0" in head or head[:4096].decode("utf-8-sig", errors="replace").count("\ufffd") > 8:
            raise UserError(f"{path} is not a text CSV file (binary data in its first bytes)")
        lines = iter(head.decode("utf-8-sig", errors="replace").splitlines())
        lines = (line.strip() for line in lines)
        for skipped, line in enumerate(lines):
            if line and not line.startswith("#"):
                separator = max((",", ";", "\t"), key=line.count)
                row = next(lines, "").split(separator)
                comma = separator != "," and any(_DECIMAL_COMMA.match(c.strip()) for c in row) and not any(
                    _DECIMAL_POINT.match(c.strip()) for c in row)
                return skipped, separator, "," if comma else "."
    return 0, ",", "."


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
            raise UserError(f"map: {name!r} must be a column name or {{\"column\": ..., \"scale\": ..., \"offset\": ...}}"
                            + (" (a contact channel may also take \"threshold\")" if name in GROUPS["contact"] else ""))
        column = entry["column"]
        if not isinstance(column, str):
            raise UserError(f"map: the \"column\" of {name!r} must be a column name, got {json.dumps(column)}")
        if column not in table:
            raise UserError(f"map: the log has no numeric column {column!r} (for {name})")
        scale, offset = entry.get("scale", 1.0), entry.get("offset", 0.0)
        if not all(isinstance(x, (int, float)) and np.isfinite(x) for x in (scale, offset)):
            raise UserError(f"map: scale and offset of {name!r} must be finite numbers")
        out[name] = scale * table[column] + offset
        if "threshold" in entry:
            threshold = entry["threshold"]
            if name not in GROUPS["contact"]:
                raise UserError(f"map: \"threshold\" turns a force into a contact flag; {name!r} is not a contact channel")
            if not isinstance(threshold, (int, float)) or not np.isfinite(threshold):
                raise UserError(f"map: the threshold of {name!r} must be a finite number")
            value = out[name]
            out[name] = np.where(np.isfinite(value), (value > threshold).astype(np.float64), np.nan)
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


def import_log(log: str | Path | list[str | Path], out: str | Path, cfg: ImportConfig,
               map_path: str | Path | None = None, overwrite: bool = False) -> tuple[Path, ImportReport]:
    """Convert ``log`` (a file, or several one after the other: ``read_logs``) into a measurement
    dataset at ``out`` (all or nothing)."""
    from acn.datasets.schema import least_bytes
    from acn.datasets.writer import DatasetWriter
    from acn.outputs.checks import check_space

    logs = [Path(p) for p in log] if isinstance(log, (list, tuple)) else [Path(log)]
    log = logs[0] if len(logs) == 1 else Path(f"{logs[0]} (+ {len(logs) - 1} more)")  # as messages name it
    cfg = replace(cfg, physics_hz=physics_hz_for(cfg.control_hz, cfg.physics_hz))
    for name, frame in (("--linvel-frame", cfg.linvel_frame), ("--angvel-frame", cfg.angvel_frame)):
        if frame not in FRAMES:
            raise UserError(f"{name} must be one of {', '.join(FRAMES)}, got {frame!r}")
    if cfg.imu_acc is not None and cfg.imu_acc not in IMU_ACC_KINDS:
        raise UserError(f"--imu-acc must be one of {', '.join(IMU_ACC_KINDS)} (or not given), got {cfg.imu_acc!r}")
    if sorted(cfg.leg_order) != sorted(FOOT_NAMES):
        raise UserError(f"--leg-order must name each of {', '.join(FOOT_NAMES)} once, got {', '.join(cfg.leg_order)}")
    read_log = read_logs(logs)
    table = read_log.columns
    mapping = read_map(Path(map_path) if map_path else None)
    cols = resolve_columns(table, mapping)
    read = {naming.map_column(e) for e in mapping.values()} | set(KNOWN_COLUMNS)
    unused = [c for c in table if c not in read]
    suggested, map_notes = _draft_map(table, unused, cols)
    quaternion = any(c in cols for c in QUAT_COLUMNS)
    # a channel the logger wrote as an empty (all-NaN) column is a channel it did not log
    cols = {k: v for k, v in cols.items() if k in INDEX_COLUMNS or np.isfinite(v).any()}
    cols = _shift_actions(_reorder_legs(_orientation(cols), tuple(cfg.leg_order)), cfg.shift_actions)
    n = len(next(iter(cols.values()))) if cols else 0
    if "timestamp" not in cols:
        like = (f" (columns named like the channels it lacks, as a --map file: {json.dumps(suggested)})"
                + "".join(f"; {note}" for note in map_notes)) if "timestamp" in suggested else ""
        raise UserError(f"{log} has no timestamp column (s); map one with --map{like}")
    joint_pos = [c for c in GROUPS["joint_pos"] if c not in cols]
    actions = [c for c in ACTION_COLUMNS if c not in cols]
    if joint_pos or actions:
        arrays = sorted({k.split("[")[0] for k in table if k.endswith("]") and "[" in k})
        hint = (f" (its array columns are read one element each, {arrays[0]}[0], {arrays[0]}[1], ...: map them, "
                f'e.g. {{"FR_hip_pos": "{arrays[0]}[0]"}})') if arrays else ""
        if set(suggested) & set(joint_pos + actions):
            hint += (f"; columns named like them, as a --map file (check units and leg order{naming.arrays_read(suggested)}"
                     f"): {json.dumps(suggested)}")
        raise UserError(f"{log} lacks joint positions or actions, the minimum a measurement needs: "
                        f"missing {', '.join(joint_pos + actions)}{hint}")
    if n < 2:
        raise UserError(f"{log} has fewer than 2 rows")
    missing = [c for c in STATE_NAMES if c not in cols]
    state = _to_body_frame(np.column_stack([cols.get(c, np.full(n, np.nan)) for c in STATE_NAMES]), cfg)
    action, hybrid = _hybrid_actions(np.column_stack([cols[c] for c in ACTION_COLUMNS]), cols, cfg)
    has_effort = all(c in cols for c in EFFORT_COLUMNS)
    partial_effort = [c for c in EFFORT_COLUMNS if c in cols] if not has_effort else []
    effort = np.column_stack([cols[c] for c in EFFORT_COLUMNS]) if has_effort else np.full((n, 12), np.nan)
    episode = cols.get("episode_index", np.zeros(n))
    timestamp = cols["timestamp"]
    present = ~np.isin(np.arange(len(STATE_NAMES)), [STATE_NAMES.index(c) for c in missing])
    good = np.isfinite(state[:, present]).all(1) & np.isfinite(action).all(1) & np.isfinite(timestamp) \
        & np.isfinite(episode)
    if has_effort:
        good &= np.isfinite(effort).all(1)
    absurd, absurd_example = _implausible(state, present, action, effort if has_effort else None, cfg.action_mode)
    absurd &= good
    good &= ~absurd

    period = 1.0 / cfg.control_hz
    _check_contiguous(episode)
    steps = _time_steps(episode, timestamp)
    _check_time_step(steps, period, cfg.dt_tolerance, timestamp)
    spread = float(np.percentile(np.abs(steps / period - 1.0), 99)) if len(steps) else 0.0
    meta = AcnMetadata(
        format_version=schema.FORMAT_VERSION, paired=False,
        source=Simulator(simulator="log", version=None, file=logs[0].name,
                         files=tuple(p.name for p in logs) if len(logs) > 1 else None), target=None,
        physics_dt=1.0 / cfg.physics_hz, substeps=cfg.physics_hz // cfg.control_hz,
        control_hz=float(cfg.control_hz), action_mode=cfg.action_mode,
        kp=joint_gains(cfg.kp), kd=joint_gains(cfg.kd),
        torque_limit=float(cfg.torque_limit), imu_acc=cfg.imu_acc,
        model_params=MappingProxyType(ModelParams().as_json()), policy="log",
        seed=None, corrector=None, state_names=STATE_NAMES, action_names=ACTION_NAMES,
        fall_rule=FALL_RULE, missing_channels=tuple(missing), effort_logged=has_effort,
        hybrid_actions=action.shape[1] > NUM_JOINTS,
    )
    check_space(out, least_bytes(n, paired=False, hybrid=bool(meta.hybrid_actions)), "import")
    writer = DatasetWriter(out, fps=cfg.control_hz, paired=False, task=f"log {log.name}", acn_meta=meta,
                           overwrite=overwrite)
    dropped = transitions = 0
    reasons: dict[str, int] = {}
    written: list[checks.Episode] = []
    try:
        for rows, reason in _segments(episode, timestamp, good, period, cfg.dt_tolerance):
            reasons[reason] = reasons.get(reason, 0) + 1
            if len(rows) < 2:
                dropped += 1
                continue
            now, nxt = rows[:-1], rows[1:]
            written.append((state[rows], position_targets(action[now], state[now][:, SLICES["joint_pos"]])))
            trace = Trace(state[now], action[now], effort[now], state[nxt],
                          np.array([_fallen(s) for s in state[nxt]], dtype=bool))
            writer.write(Episode(writer.num_episodes, timestamp[now] - timestamp[now[0]], trace, None, reason))
            transitions += len(now)
        report = ImportReport(rows=n, transitions=transitions, episodes=writer.num_episodes,
                              cut_nonfinite=int((~good).sum() - absurd.sum()), cut_implausible=int(absurd.sum()),
                              implausible_example=absurd_example, time_breaks=reasons.get("split_time_gap", 0),
                              dropped_short=dropped, missing=missing,
                              findings=checks.check(written, period, cfg.action_mode), step_spread=spread,
                              hybrid=hybrid, quaternion=quaternion, partial_effort=partial_effort, unused=unused,
                              suggested_map=suggested, map_notes=map_notes, malformed=read_log.malformed,
                              text_rows=read_log.text_rows, text_example=read_log.text_example)
        writer.acn = replace(writer.acn, import_info=ImportInfo(
            file=logs[0].name, files=tuple(p.name for p in logs), rows=n, transitions=transitions,
            rows_cut_nonfinite=report.cut_nonfinite, rows_cut_implausible=report.cut_implausible,
            rows_malformed=len(report.malformed), rows_with_text=report.text_rows,
            time_step_breaks=report.time_breaks, time_step_spread=round(spread, 4), hybrid_command=tuple(hybrid),
            segments_too_short=dropped, dt_tolerance=cfg.dt_tolerance, linvel_frame=cfg.linvel_frame,
            angvel_frame=cfg.angvel_frame, leg_order=tuple(cfg.leg_order), shift_actions=cfg.shift_actions,
            checks=tuple(MappingProxyType(f.to_json()) for f in report.findings)))
        if writer.num_episodes == 0:
            raise UserError(f"{log}: no two consecutive good rows at {cfg.control_hz} Hz: nothing to import "
                            f"({report.cut_nonfinite} non-finite rows, {report.cut_implausible} with values no A1 can "
                            f"produce, {report.time_breaks} time-step breaks)")
        path = writer.commit()
    except BaseException as e:
        raise writer.fail(e) from None
    return path, report


def _orientation(cols: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Euler angles from a quaternion where the log has one (``QUAT_COLUMNS``) instead."""
    quat = [c for c in QUAT_COLUMNS if c in cols]
    if not quat:
        return cols
    if len(quat) < 4:
        raise UserError(f"a quaternion needs all of {', '.join(QUAT_COLUMNS)}; the log has only {', '.join(quat)}")
    if any(c in cols for c in GROUPS["base_rpy"]):
        raise UserError("the log has both Euler angles (base_roll, ...) and a quaternion (base_quat_*): give one")
    w, x, y, z = (cols[c] for c in QUAT_COLUMNS)
    norm = np.sqrt(w * w + x * x + y * y + z * z)
    med = float(np.nanmedian(norm)) if np.isfinite(norm).any() else float("nan")
    if not abs(med - 1.0) <= 0.1:
        raise UserError(f"base_quat_* is not a unit quaternion (median norm {med:.3g}): are the right columns mapped?")
    out = {k: v for k, v in cols.items() if k not in QUAT_COLUMNS}
    for name, values in zip(GROUPS["base_rpy"], quat_to_rpy(np.stack([x, y, z, w]) / norm)):
        out[name] = values
    return out


def _to_body_frame(state: np.ndarray, cfg: ImportConfig) -> np.ndarray:
    """The trunk's velocities rotated from the world frame into the body frame, where the log has
    them in the world frame (``cfg.linvel_frame`` / ``angvel_frame``)."""
    groups = [g for g, frame in (("base_linvel", cfg.linvel_frame), ("base_angvel", cfg.angvel_frame))
              if frame == "world"]
    if not groups:
        return state
    if not np.isfinite(state[:, SLICES["base_rpy"]]).any():
        raise UserError("velocities in the world frame need the trunk's orientation (base_roll, ... or base_quat_*)")
    rot = rpy_to_matrices(state[:, SLICES["base_rpy"]])  # body -> world
    out = state.copy()
    for g in groups:
        out[:, SLICES[g]] = np.einsum("nji,nj->ni", rot, state[:, SLICES[g]])  # R^T v
    return out


def _hybrid_actions(action: np.ndarray, cols: dict[str, np.ndarray], cfg: ImportConfig) -> tuple[np.ndarray, list[str]]:
    """The actions for the model's PD law from a hybrid command, and which kinds
    (``HYBRID_COLUMNS``) the log had (each kind all 12 joints or none).

    The motor runs kp (q_des - q) + kd (dq_des - qd) + tau_ff: the actions are (N, 60), q_des,
    kp_t, kd_t (each row's where logged, else the imported gains), dq_des and tau_ff (0 where not
    logged), which the model's PD runs as such (``SimConfig.hybrid``; a row may have kp_t = 0, a
    pure torque or damping command). Exact, with each gain scale on what its gain multiplies and
    the dead band on q_des - q (folding the feedforward into the target, q_des + f / kp, made a
    ``pd_gains`` fit scale it and the dead band act on it; a feedforward kd_t dq_des + tau_ff
    made the kd scale miss the velocity target)."""
    extra = {}
    for kind, columns in HYBRID_COLUMNS.items():
        have = [c for c in columns if c in cols]
        if not have:
            continue
        if len(have) < len(columns):
            raise UserError(f"a hybrid command's {kind} needs all 12 joints; the log has {len(have)}: "
                            f"missing {', '.join(c for c in columns if c not in cols)}")
        extra[kind] = np.column_stack([cols[c] for c in columns])
    if not extra:
        return action, []
    kinds = ", ".join(f"{k}.*" for k in extra)
    if cfg.action_mode != "position":
        raise UserError(f"{kinds} columns complete a position target (q_des); with --action-mode "
                        f"{cfg.action_mode} the actions are already torques: leave them out")
    n = len(action)
    kp = np.broadcast_to(extra.get("action_kp", per_joint(cfg.kp)), (n, NUM_JOINTS))
    kd = np.broadcast_to(extra.get("action_kd", per_joint(cfg.kd)), (n, NUM_JOINTS))
    velocity = np.broadcast_to(extra.get("action_vel", 0.0), (n, NUM_JOINTS))
    torque = np.broadcast_to(extra.get("action_torque", 0.0), (n, NUM_JOINTS))
    with np.errstate(invalid="ignore"):  # rows with a non-finite value are cut later
        if (kp < 0).any() or (kd < 0).any():
            raise UserError(f"{kinds}: a gain sent with a command is negative")
    return np.concatenate([action, kp, kd, velocity, torque], axis=1), list(extra)


def _draft_map(table: dict[str, np.ndarray], unused: list[str],
               cols: dict[str, np.ndarray]) -> tuple[dict[str, str | dict], list[str]]:
    """A draft ``--map`` for the channels ``cols`` lacks from the ``unused`` columns of the log
    (``acn.measurements.naming``), and notes on what it read from the data: by their names; contact
    flags from foot forces, each with the threshold that splits its readings into swing and stance
    (``naming.contact_threshold``); one orientation, the one the log has, else a whole quaternion,
    else a quaternion array (``quat[0]`` ... ``quat[3]``) in the order its data show
    (``naming.quaternion_order``; a note says so, or asks for the order where the data do not tell)."""
    draft = naming.suggest_map(unused, [c for c in naming.CHANNELS if c not in cols])
    forces = naming.suggest_map(unused, [c for c in GROUPS["contact"] if c not in cols and c not in draft],
                                describe=naming.contact_of_force)
    for channel, column in forces.items():
        if (threshold := naming.contact_threshold(table[column])) is not None:
            draft[channel] = {"column": column, "threshold": round(threshold, 3)}
    euler, quat = GROUPS["base_rpy"], QUAT_COLUMNS
    notes = []
    oriented = any(c in cols or c in draft for c in (*euler, *quat))
    if not oriented and len(arrays := naming.quaternion_arrays(table, unused)) == 1:
        (base, order), = arrays.items()
        notes.append(naming.quaternion_note(base, order))
        if order is not None:
            draft.update({f"base_quat_{a}": f"{base}[{order.index(a)}]" for a in "wxyz"})
    drop = quat if any(c in cols for c in euler) else euler if any(c in cols for c in quat) or \
        all(c in draft for c in quat) else ()
    return {k: v for k, v in draft.items() if k not in drop}, notes


def _reorder_legs(cols: dict[str, np.ndarray], order: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Columns renamed from the log's leg order to the schema's: what the log (or its map) names
    leg ``FOOT_NAMES[i]`` (joints, actions, efforts, contact) is leg ``order[i]``."""
    if order == FOOT_NAMES:
        return cols
    rename = {}
    for mine, theirs in zip(FOOT_NAMES, order):
        rename[f"{mine}_contact"] = f"{theirs}_contact"
        for joint in ("hip", "thigh", "calf"):
            for pattern in ("{}_pos", "{}_vel", "action.{}", "effort.{}", *(f"{kind}.{{}}" for kind in HYBRID_COLUMNS)):
                rename[pattern.format(f"{mine}_{joint}")] = pattern.format(f"{theirs}_{joint}")
    return {rename.get(name, name): values for name, values in cols.items()}


def _shift_actions(cols: dict[str, np.ndarray], rows: int) -> dict[str, np.ndarray]:
    """The command columns (actions and a hybrid command's parts) moved ``rows`` rows up within
    each episode: row t takes row t + rows' command. Rows left without one get NaN, so the import
    cuts them (a logger that writes the last action sent with the new observation: ``rows`` 1)."""
    if not rows or not cols:
        return cols
    n = len(next(iter(cols.values())))
    episode = cols.get("episode_index", np.zeros(n))
    source = np.arange(n) + rows
    valid = (source >= 0) & (source < n)
    valid[valid] &= episode[source[valid]] == episode[valid]
    out = dict(cols)
    for name in COMMAND_COLUMNS:
        if name in cols:
            out[name] = np.full(n, np.nan)
            out[name][valid] = cols[name][source[valid]]
    return out


def _time_steps(episode: np.ndarray, timestamp: np.ndarray) -> np.ndarray:
    """The finite time steps between consecutive rows of one episode, s."""
    return np.diff(timestamp)[(np.diff(episode) == 0) & np.isfinite(np.diff(timestamp))]


def _check_contiguous(episode: np.ndarray) -> None:
    """Refuse a log whose episodes' rows are interleaved (several robots or environments logged
    side by side, sorted by time): each episode must be one block of rows."""
    ep = episode[np.isfinite(episode)]
    blocks = int(np.count_nonzero(np.diff(ep))) + 1 if len(ep) else 0
    if blocks > len(np.unique(ep)):
        raise UserError(f"the rows of an episode are not together: episode_index returns to an earlier value "
                        f"({blocks} runs of rows for {len(np.unique(ep))} episodes); sort the log by "
                        "episode_index, then timestamp")


def _check_time_step(steps: np.ndarray, period: float, tol: float, timestamp: np.ndarray) -> None:
    """Refuse a log whose median time step is not the control period (one line: the likely cause)."""
    if not len(steps):
        return
    med = float(np.median(steps))
    if abs(med - period) <= tol * period:
        return
    ratio = med / period
    unit = next((u for u, f in (("ms", 1e3), ("us", 1e6), ("ns", 1e9)) if abs(ratio / f - 1) <= tol), None)
    t = timestamp[np.isfinite(timestamp)]  # float32 timestamps far from zero step in coarse increments
    top = float(np.abs(t).max()) if len(t) else 0.0
    # (whole microseconds are float32 numbers too: a step of a unit's size is that unit)
    if not unit and len(t) and np.array_equal(t, t.astype(np.float32)) and np.spacing(np.float32(top)) > 0.05 * period:
        raise UserError(f"the timestamps are float32 numbers: near {top:.6g} s they can only step by "
                        f"{float(np.spacing(np.float32(top))):.3g} s, too coarse for {1 / period:g} Hz; write "
                        "them as float64, or as seconds since the log's start")
    hint = (f"timestamps in {unit}? map timestamp with \"scale\": {1 / {'ms': 1e3, 'us': 1e6, 'ns': 1e9}[unit]:g}"
            if unit else f"is --control-hz right? the log's rate looks like {1 / med:.4g} Hz" if med > 0
            else "timestamps must increase within an episode")
    raise UserError(f"the log's median time step is {med:.6g}, not the control period 1/--control-hz = {period:.6g} s: "
                    f"{hint}")


def _fallen(state: np.ndarray) -> bool:
    """The fall rule where the log has the trunk pose; False where it has not."""
    return bool(np.isfinite(state[:6]).all() and fallen(state))
