"""All-or-nothing outputs: a file or a directory is built beside its destination, then renamed.

``write_file`` is the one way the toolkit writes a file a user named (``replacing`` where a
library writes the file itself); ``temporary_beside`` + ``move_into_place`` the one way it
writes a directory. The old output stays in place until the
new one is complete, and a failure removes the temporary (no ``.partial`` survives it).
"""

from __future__ import annotations

import os
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

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


@contextmanager
def replacing(path: str | Path) -> Iterator[Path]:
    """A temporary path beside ``path`` for a library that writes the file itself (a Rerun
    recording, a figure): renamed to ``path`` when the block ends, removed if the block raises."""
    path = Path(path)
    tmp = temporary_beside(path)
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def write_file(path: str | Path, data: str | bytes) -> Path:
    """Write ``data`` to ``path`` whole or not at all; returns the path as given."""
    with replacing(path) as tmp:
        if isinstance(data, bytes):
            tmp.write_bytes(data)
        else:
            tmp.write_text(data)
    return Path(path)
