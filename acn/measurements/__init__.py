"""Measurements: robot logs from other code brought into the toolkit (``acn-import``) and read as
transitions for a model comparison.

``importer.py`` turns a CSV, Parquet, JSON-lines, HDF5 or NumPy log (``arrays.py``) into a
measurement dataset, with ``naming.py`` drafting a column map; ``checks.py`` asks whether a log is
self-consistent (units, signs, frames, lags) before any model; ``odometry.py`` estimates the
trunk's position and velocity from the legs where a log has no motion capture; ``data.py`` reads a
dataset back as ``Measurements``.
"""

from acn.measurements.data import Measurements, fill_derived, load_measurements

__all__ = ["Measurements", "fill_derived", "load_measurements"]
