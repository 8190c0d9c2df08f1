"""What dead runs left beside an output, found and removed by the next run that writes there.

A run builds its output at ``.NAME.partial-PID`` (and, while it replaces an old one on a file
system that cannot swap two directories at once, keeps the old at ``.NAME.partial-PID.old`` for
an instant). A run that was killed leaves these behind, with its ``.NAME.lock``. A leftover is
removed only where its run is certainly over: its pid is not alive *and* nobody holds NAME's
lock (a run on another machine sharing the disk holds the lock; a pid says nothing there). An
old output found without its NAME (the run died between the two renames) is put back as NAME:
it is the complete previous output.
"""

from __future__ import annotations

import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

from acn.outputs.lock import LOCK_SUFFIX, held_if_free, holds

PARTIAL = ".partial-"
OLD = "old"
_LEFTOVER = re.compile(r"^\.(?P<name>.+)\.partial-(?P<pid>\d+)(?:\.(?P<part>[a-z]+))?$")
_LOCK = re.compile(r"^\.(?P<name>.+)" + re.escape(LOCK_SUFFIX) + "$")


def temporary_beside(out: Path, part: str = "") -> Path:
    """This process's hidden path next to ``out`` (``part``: a second one, e.g. ``old``)."""
    return out.parent / f".{out.name}{PARTIAL}{os.getpid()}{'.' + part if part else ''}"


def alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


@dataclass(frozen=True)
class Cleared:
    """What one look beside an output removed or put back."""

    where: Path
    removed: tuple[str, ...] = ()
    restored: tuple[str, ...] = ()

    def line(self) -> str | None:
        """One line saying what happened, or None where nothing was there."""
        parts = []
        if self.removed:
            parts.append(f"removed what runs that were killed left in {self.where}: {', '.join(self.removed)}")
        if self.restored:
            parts.append(f"put back {', '.join(self.restored)}, the output a killed run was replacing")
        return "; ".join(parts) or None


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def clear_beside(out: Path) -> Cleared:
    """Remove the leftovers of dead runs in ``out``'s directory (module docstring)."""
    removed: list[str] = []
    restored: list[str] = []
    try:
        entries = sorted(out.parent.iterdir())
    except OSError:
        return Cleared(out.parent)
    for entry in entries:
        if m := _LEFTOVER.match(entry.name):
            if int(m["pid"]) == os.getpid() or alive(int(m["pid"])):
                continue
            target = entry.parent / m["name"]
            with held_if_free(target) as free:
                if not free or not os.path.lexists(entry):
                    continue
                if m["part"] == OLD and not os.path.lexists(target):
                    entry.rename(target)
                    restored.append(str(target))
                else:
                    _remove(entry)
                    removed.append(entry.name)
        elif (m := _LOCK.match(entry.name)) and m["name"] != out.name and not holds(entry.parent / m["name"]):
            with held_if_free(entry.parent / m["name"]) as free:
                if free:  # released on the way out: the stale lock file goes with it
                    removed.append(entry.name)
    return Cleared(out.parent, tuple(removed), tuple(restored))
