"""All-or-nothing outputs: a file or a directory is built beside its destination, then renamed.

``write_file`` is the one way the toolkit writes a file a user named; ``temporary_beside`` +
``move_into_place`` the one way it writes a directory. The old output stays in place until the
new one is complete, and a failure removes the temporary (no ``.partial`` survives it).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

PARTIAL = ".partial-"  # the mark of a temporary: ``.NAME.partial-PID`` beside NAME


def temporary_beside(out: Path) -> Path:
    """A fresh hidden path next to ``out`` (a stale one of this process is removed first)."""
    out = Path(out)
    tmp = out.parent / f".{out.name}{PARTIAL}{os.getpid()}"
    if tmp.is_dir():
        shutil.rmtree(tmp, ignore_errors=True)
    else:
        tmp.unlink(missing_ok=True)
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


def write_file(path: str | Path, data: str | bytes) -> Path:
    """Write ``data`` to ``path`` whole or not at all; returns the path as given."""
    path = Path(path)
    tmp = temporary_beside(path)
    try:
        if isinstance(data, bytes):
            tmp.write_bytes(data)
        else:
            tmp.write_text(data)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path
