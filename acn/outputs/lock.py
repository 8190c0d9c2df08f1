"""One writer per output: a lock on the path, held from the first check to the end of the run.

The lock is ``flock`` on ``.NAME.lock`` beside the output, holding who took it (the command, its
pid, when). The kernel drops a ``flock`` when its process dies, however it dies, so the lock of a
killed run is simply free and the next run takes it over; the file itself is removed when the run
releases it (and, after a kill, by the next run that takes it or writes beside it). Claims are
counted per process: the command line claims its outputs before any work, and the library's
writers claim the same paths again without blocking themselves. Two runs into different paths
never block each other.
"""

from __future__ import annotations

import fcntl
import json
import os
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from acn.errors import UserError

LOCK_SUFFIX = ".lock"


class OutputBusy(UserError):
    """Another live run is writing the output."""


@dataclass(frozen=True)
class Holder:
    """Who holds a lock, as its lock file says."""

    command: str
    pid: int
    started: float  # seconds since the epoch

    def describe(self) -> str:
        return f"{self.command} (pid {self.pid}, since {time.strftime('%H:%M:%S', time.localtime(self.started))})"


@dataclass
class _Claim:
    fd: int
    path: Path     # the lock file
    owner: int     # the pid that took it: a forked child never releases its parent's lock
    count: int = 1


_claims: dict[Path, _Claim] = {}
_program: str | None = None


def set_program(name: str) -> None:
    """The command named in a lock this process takes (the CLI sets it; default: argv[0]'s name)."""
    global _program
    _program = name


def lock_path(out: Path) -> Path:
    return out.parent / f".{out.name}{LOCK_SUFFIX}"


def _key(out: str | Path) -> Path:
    return Path(os.path.abspath(os.path.expanduser(out)))


def _take(path: Path) -> int | None:
    """An fd holding ``path``'s lock, or None while another process holds it. A lock file
    removed by its releaser between our open and our lock is a dead inode: open again."""
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            return None
        except BaseException:
            os.close(fd)
            raise
        try:
            same = os.stat(path).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)


def _holder(path: Path) -> Holder | None:
    try:
        d = json.loads(path.read_text())
        return Holder(str(d["command"]), int(d["pid"]), float(d["started"]))
    except (OSError, ValueError, KeyError, TypeError):
        return None


def claim(out: str | Path) -> None:
    """Hold ``out``'s lock in this process (counted); ``OutputBusy`` in one line where another
    live run holds it."""
    key = _key(out)
    held = _claims.get(key)
    if held is not None and held.owner == os.getpid():
        held.count += 1
        return
    path = lock_path(key)
    fd = _take(path)
    if fd is None:
        holder = _holder(path)
        who = holder.describe() if holder else "another run"
        raise OutputBusy(f"{out} is being written by {who}: wait for it to end, or write elsewhere")
    command = _program or Path(sys.argv[0]).name or "python"
    try:  # who holds it, for the refusal of a second run; the lock holds without it (a full disk)
        os.ftruncate(fd, 0)
        os.write(fd, json.dumps({"command": command, "pid": os.getpid(), "started": time.time()}).encode())
    except OSError:
        pass
    _claims[key] = _Claim(fd, path, os.getpid())


def release(out: str | Path) -> None:
    """Give back one claim of ``out``; the last one removes the lock file and drops the lock."""
    key = _key(out)
    held = _claims.get(key)
    if held is None or held.owner != os.getpid():
        return
    held.count -= 1
    if held.count == 0:
        del _claims[key]
        _drop(held)


def release_all() -> None:
    """Give back every claim of this process (the CLI does, when a command ends)."""
    for key in list(_claims):
        held = _claims.pop(key)
        if held.owner == os.getpid():
            _drop(held)


def _drop(held: _Claim) -> None:
    try:
        os.unlink(held.path)  # while still held: a process that opens it now finds a dead inode
    except FileNotFoundError:
        pass
    os.close(held.fd)


def holds(out: str | Path) -> bool:
    """Whether this process holds ``out``'s lock (a run writing two outputs side by side holds both)."""
    held = _claims.get(_key(out))
    return held is not None and held.owner == os.getpid()


@contextmanager
def held_if_free(out: Path) -> Iterator[bool]:
    """``out``'s lock for the block where no other process holds it (True), else False; a stale
    lock file is removed on the way out."""
    try:
        claim(out)
    except OutputBusy:
        yield False
        return
    try:
        yield True
    finally:
        release(out)
