"""JSON files: reading one a user gave (a one-line ``UserError`` when it is missing or unreadable),
and ``strict_json``, what the toolkit writes (no NaN or infinity, which strict readers refuse)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from acn.errors import UserError


def read_json(path: str | Path, missing: str):
    """The JSON document at ``path``; ``UserError(missing)`` if it is not a file, and one naming
    the file and the parse error if it is not UTF-8 JSON."""
    p = Path(path)
    if not p.is_file():
        raise UserError(missing)
    try:
        return json.loads(p.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise UserError(f"{p} is not valid JSON: {e}") from None


def strict_json(o):
    """``o`` as strict JSON values: numpy numbers and arrays as plain ones, non-finite floats as None."""
    if isinstance(o, dict):
        return {k: strict_json(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [strict_json(v) for v in o]
    if isinstance(o, np.ndarray):
        return strict_json(o.tolist())
    if isinstance(o, np.bool_):
        return bool(o)
    if isinstance(o, (float, np.floating)):
        return float(o) if math.isfinite(o) else None
    if isinstance(o, np.integer):
        return int(o)
    return o
