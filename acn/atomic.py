"""All-or-nothing directories: build in a hidden temporary beside the destination, then rename."""

from __future__ import annotations

import os
import shutil
from pathlib import Path


def temporary_beside(out: Path) -> Path:
    """A fresh hidden directory path next to ``out`` (removed first if a stale one exists)."""
    tmp = out.parent / f".{out.name}.partial-{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    return tmp


def move_into_place(tmp: Path, out: Path) -> Path:
    """Rename ``tmp`` to ``out``, replacing an existing ``out`` only once ``tmp`` is complete."""
    old = None
    if out.exists():
        old = out.parent / f".{out.name}.old-{os.getpid()}"
        out.rename(old)
    tmp.rename(out)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
    return out
