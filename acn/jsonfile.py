"""Reading a JSON file a user gave: a one-line ``UserError`` when it is missing or unreadable."""

from __future__ import annotations

import json
from pathlib import Path

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
