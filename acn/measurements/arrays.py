"""Robot logs stored as named arrays, HDF5 (``read_hdf5``) and NumPy archives (``read_npz``), as
one table of columns for ``acn-import``.

A NumPy archive (``np.savez``) is one table: each array one row per control step, its name the
column's (``q`` (T, 12) gives ``q[0]`` ... ``q[11]``); object arrays are refused, never unpickled.

Loggers write HDF5 in two common layouts; both are read:

- **one table**: every dataset holds one row per control step (``/timestamp`` (T,), ``/q`` (T, 12),
  ``/imu/gyro`` (T, 3));
- **one group per episode**, numbered, with the same datasets in each (``/episode_0/q``,
  ``/episode_1/q``; robomimic's ``/data/demo_0/obs/...``): read one after the other, in the
  numbers' order (``episode_2`` before ``episode_10``), ``episode_index`` set from it.

A dataset's column is its path below the table's group joined by dots (``imu.gyro``, as nested
Parquet records read; a group ``action`` with datasets ``FR_hip`` ... gives ``action.FR_hip``,
the schema's own name); a (T, k) dataset gives k columns ``name[0]`` ... ``name[k-1]`` (as Parquet
arrays); a compound dataset one column per field (``name.field``). Datasets that are not numbers,
that have more than two dimensions (camera images) or another number of rows than the table
(a gain, a robot name) are left out; ``--map`` then maps the columns as for any log.
"""

from __future__ import annotations

import re
import zipfile
from collections import Counter
from pathlib import Path

import numpy as np

from acn.errors import UserError

NUMBERED = re.compile(r"(\D*)(\d+)(\D*)")  # episode_0, demo_12, run3, 000: an episode group's name


def read_hdf5(path: Path) -> dict[str, np.ndarray]:
    """The log's columns as float arrays of equal length (module docstring); ``UserError`` where
    no table can be read (``h5py``'s errors are ``OSError``: the caller's message)."""
    import h5py

    with h5py.File(path, "r") as f:
        if f.attrs.get("PYTABLES_FORMAT_VERSION") is not None or _pandas(f):
            raise UserError(f"{path} was written by pandas (HDFStore): write it as a table, "
                            "pd.read_hdf(path, key).to_parquet('log.parquet'), and import that")
        found = _episodes(f)
        if found is not None:
            return _concatenated(path, found)
        table = _table(f)
        if table is None:
            raise UserError(f"{path} holds no dataset of numbers with one row per step (1-D or 2-D)")
        return table


def read_npz(path: Path) -> dict[str, np.ndarray]:
    """A NumPy archive's arrays as columns (module docstring): those with the number of rows most
    of them share; ``UserError`` for object arrays (reading them would unpickle) or no table."""
    if not zipfile.is_zipfile(path):
        raise UserError(f"cannot read {path}: not a NumPy .npz archive (np.savez writes a zip of .npy arrays)")
    try:
        with np.load(path, allow_pickle=False) as archive:
            columns: dict[str, np.ndarray] = {}
            for name in archive.files:
                _add(columns, name, archive[name])
    except ValueError as e:
        if "pickle" in str(e):
            raise UserError(f"{path} holds object arrays, which are read only by unpickling (never done): "
                            "save numbers (np.savez with float or int arrays)") from None
        raise UserError(f"cannot read {path}: {str(e).splitlines()[0]}") from None
    table = _rows(columns)
    if table is None:
        raise UserError(f"{path} holds no array of numbers with one row per step (1-D or 2-D)")
    return table


def _add(out: dict[str, np.ndarray], name: str, a: np.ndarray) -> None:
    """``a`` as columns of ``out`` if it is numbers in one or two dimensions (module docstring)."""
    if a.dtype.kind not in "biuf" or a.ndim not in (1, 2) or a.shape[0] == 0:
        return
    a = a.astype(np.float64)
    if a.ndim == 1:
        out[name] = a
    else:
        out.update({f"{name}[{i}]": a[:, i] for i in range(a.shape[1])})


def _rows(columns: dict[str, np.ndarray]) -> dict[str, np.ndarray] | None:
    """The columns that have the table's number of rows: the one most of them share (a (12,) gain
    beside (T,) arrays is left out). None where no column has 2 rows."""
    columns = {k: v for k, v in columns.items() if len(v) >= 2}
    if not columns:
        return None
    rows = Counter(len(v) for v in columns.values()).most_common(1)[0][0]
    return {k: v for k, v in columns.items() if len(v) == rows}


def _pandas(f) -> bool:
    return any("pandas_type" in obj.attrs for obj in f.values())


def _columns(group) -> dict[str, np.ndarray]:
    """Every numeric 1-D or 2-D dataset below ``group`` as columns (module docstring), any length."""
    import h5py

    out: dict[str, np.ndarray] = {}

    def visit(name: str, obj) -> None:
        if not isinstance(obj, h5py.Dataset) or obj.ndim == 0:
            return
        column = name.replace("/", ".")
        if obj.dtype.names:  # a compound dataset: a record per row
            data = obj[()]
            for field in obj.dtype.names:
                _add(out, f"{column}.{field}", np.asarray(data[field]))
        elif obj.ndim <= 2:  # images (3-D and more) are not read at all
            _add(out, column, obj[()])

    group.visititems(visit)
    return out


def _table(group) -> dict[str, np.ndarray] | None:
    """The columns below ``group`` that have the table's number of rows (``_rows``)."""
    return _rows(_columns(group))


def _episodes(f) -> list[tuple[str, dict[str, np.ndarray]]] | None:
    """The episode groups (module docstring): the first group, breadth first, whose subgroups
    include numbered ones with a table each (same prefix and suffix around the number), in the
    numbers' order. None: the file is one table."""
    import h5py

    queue = [f]
    while queue:
        group = queue.pop(0)
        subgroups = [(k, v) for k, v in group.items() if isinstance(v, h5py.Group)]
        numbered: dict[tuple[str, str], list[tuple[int, str, h5py.Group]]] = {}
        for name, sub in subgroups:
            m = NUMBERED.fullmatch(name)
            if m:
                numbered.setdefault((m.group(1), m.group(3)), []).append((int(m.group(2)), name, sub))
        if numbered:
            runs = max(numbered.values(), key=len)
            tables = [(name, _table(sub)) for _, name, sub in sorted(runs, key=lambda r: r[0])]
            tables = [(name, t) for name, t in tables if t is not None]
            if tables:
                return [(f"{group.name.rstrip('/')}/{name}", t) for name, t in tables]
        queue.extend(v for _, v in subgroups)
    return None


def _concatenated(path: Path, episodes: list[tuple[str, dict[str, np.ndarray]]]) -> dict[str, np.ndarray]:
    """The episodes' tables one after the other, ``episode_index`` their order; they must have the
    same columns."""
    first_name, first = episodes[0]
    for name, t in episodes[1:]:
        if set(t) != set(first):
            lacks, adds = sorted(set(first) - set(t)), sorted(set(t) - set(first))
            differ = [f"it {verb} {', '.join(names[:4])}" for verb, names in (("lacks", lacks), ("adds", adds))
                      if names]
            raise UserError(f"{path}: episode group {name} has other datasets than {first_name}: {'; '.join(differ)}"
                            "; every episode must log the same ones")
    out = {k: np.concatenate([t[k] for _, t in episodes]) for k in first}
    out["episode_index"] = np.concatenate([np.full(len(next(iter(t.values()))), float(i))
                                           for i, (_, t) in enumerate(episodes)])
    return out
