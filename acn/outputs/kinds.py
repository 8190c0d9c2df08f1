"""Kinds of output: what each is called and how to recognise one this toolkit wrote."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable


@dataclass(frozen=True)
class Output:
    """A kind of output: ``what`` it is called in messages, whether it is a ``directory``, and
    ``recognise(path)``: True where ``path`` is one the toolkit wrote (so it may be replaced)."""

    what: str
    directory: bool
    recognise: Callable[[Path], bool]


def json_object(path: Path) -> dict | None:
    """The JSON object in ``path`` (a small file), or None where it holds anything else."""
    try:
        if path.stat().st_size > 64 << 20:
            return None
        value = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return value if isinstance(value, dict) else None


def json_with_format(fmt: str) -> Callable[[Path], bool]:
    """A recogniser: a JSON object whose ``"format"`` is of ``fmt``'s family (``acn-diagnosis/1``
    recognises any ``acn-diagnosis/N``)."""
    family = fmt.split("/")[0] + "/"

    def recognise(path: Path) -> bool:
        d = json_object(path) if path.is_file() else None
        return d is not None and str(d.get("format", "")).startswith(family)

    return recognise
