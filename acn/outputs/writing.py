"""Writing an output whole or not at all: ``Writing``, and ``write_file`` / ``replacing`` for files.

``Writing(out, kind, overwrite)`` claims ``out`` (``acn.outputs.lock``), checks it
(``check_output``), removes what dead runs left beside it (``acn.outputs.leftovers``), and gives
the writer ``path`` to build in. ``commit()`` moves the output into place whole, with Ctrl-C and
SIGTERM held off: over an old output the two directories are swapped in one system call where the
file system can (``renameat2``'s ``RENAME_EXCHANGE``), so at every instant ``out`` is the old
output or the new one. ``abort()`` removes what was built. ``fail(error)`` aborts and turns a
write error into ``WriteFailed``: one line with the path and the cause.

Where an output is written (``Layout``):

- ``BESIDE``: built at ``.NAME.partial-PID``, moved in whole (datasets, correctors, files);
- ``RESUMABLE``: written where it is when it is new or resumed, so a killed run can go on from
  its checkpoint; over an existing one it is built beside and moved in whole (a PPO run);
- ``IN_PLACE``: written where it is, since it records paths inside itself; an existing one is
  removed first, and a failed run leaves what it wrote for a look (the transfer study).
"""

from __future__ import annotations

import ctypes
import enum
import errno
import logging
import os
import re
import shutil
import signal
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Sequence

from acn.outputs.checks import check_output
from acn.outputs.kinds import Output
from acn.outputs.leftovers import OLD, clear_beside, temporary_beside
from acn.outputs.lock import claim, release

log = logging.getLogger("acn.outputs")

# The causes of a failed write a user can act on, as the line says them.
WRITE_ERRORS = {
    errno.ENOSPC: "no space left on the disk",
    errno.EDQUOT: "the disk quota is used up",
    errno.EROFS: "the file system is read-only",
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.EFBIG: "the file is larger than the file system or a limit allows",
    errno.EIO: "an input/output error (the disk or the network file system failed)",
}
_ERRNO_IN_TEXT = re.compile(r"(?:\[Errno |os error |errno[ =:]*)(\d+)", re.IGNORECASE)


class WriteFailed(Exception):
    """A write error (the disk, the file system, a permission): one line, the partial removed."""


class Layout(enum.Enum):
    BESIDE = "beside"
    RESUMABLE = "resumable"
    IN_PLACE = "in place"


def write_errno(error: BaseException) -> int | None:
    """The errno of a write error in ``error`` or what caused it (pyarrow, safetensors and torch
    wrap the operating system's error in their own, sometimes only in the message), else None."""
    seen: set[int] = set()
    e: BaseException | None = error
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OSError) and e.errno in WRITE_ERRORS:
            return e.errno
        if "No space left on device" in str(e):
            return errno.ENOSPC
        for m in _ERRNO_IN_TEXT.finditer(str(e)):
            if int(m[1]) in WRITE_ERRORS:
                return int(m[1])
        e = e.__cause__ or e.__context__
    return None


class Writing:
    """One output being written (see the module docstring); ``path`` is where to build it."""

    def __init__(self, out: str | Path, kind: Output | None, overwrite: bool = False,
                 layout: Layout = Layout.BESIDE, resume: bool = False) -> None:
        self.out = Path(os.path.abspath(out))
        self.kind, self.layout = kind, layout
        self.out.parent.mkdir(parents=True, exist_ok=True)
        claim(self.out)
        try:
            if kind is not None and not resume:
                check_output(self.out, kind, flag=None, overwrite=overwrite)
                release(self.out)  # check_output claims too: one claim is this writing's
            self.replaces = self.out.exists() and not resume
            if line := clear_beside(self.out).line():
                log.warning(line)
            in_place = layout is Layout.IN_PLACE or (layout is Layout.RESUMABLE and not self.replaces)
            if layout is Layout.IN_PLACE and self.replaces:
                _remove(self.out)
                self.replaces = False
            self.path = self.out if in_place else temporary_beside(self.out)
            if not in_place:
                _remove(self.path)
        except BaseException:
            release(self.out)
            raise
        self.done = False

    @property
    def in_place(self) -> bool:
        return self.path == self.out

    def commit(self) -> Path:
        """Move the output into place whole (signals held off); returns ``out``."""
        with _signals_held():
            try:
                if not self.in_place:
                    _move_into_place(self.path, self.out)
            except BaseException as e:
                raise self.fail(e) from None
            self._finish()
        return self.out

    def abort(self) -> None:
        """Remove what was built beside (an output written in place stays, for a resume or a look)."""
        try:
            if not self.in_place:
                _remove(self.path)
        finally:
            self._finish()

    def fail(self, error: BaseException) -> BaseException:
        """Abort, and the exception to raise for ``error``: ``WriteFailed`` for a write error."""
        self.abort()
        code = write_errno(error)
        if code is None or isinstance(error, WriteFailed):
            return error
        if self.in_place:
            kept = f"what the run wrote so far is in {self.out}"
        elif self.replaces:
            kept = f"nothing of this run was kept; {self.out.name} is as it was"
        else:
            kept = "nothing was written"
        return WriteFailed(f"cannot write {self.out}: {WRITE_ERRORS[code]}; {kept}")

    def _finish(self) -> None:
        if not self.done:
            self.done = True
            release(self.out)

    def __enter__(self) -> "Writing":
        return self

    def __exit__(self, kind, error, tb) -> bool:
        if error is None:
            self.commit()
            return False
        failure = self.fail(error)
        if failure is not error:
            raise failure from None
        return False


@contextmanager
def replacing(path: str | Path, kind: Output | None = None) -> Iterator[Path]:
    """A temporary path beside ``path`` for a library that writes the file itself (a Rerun
    recording, a figure): moved to ``path`` when the block ends, removed if the block raises."""
    with Writing(path, kind) as w:
        yield w.path


def write_file(path: str | Path, data: str | bytes, kind: Output | None = None) -> Path:
    """Write ``data`` to ``path`` whole or not at all; returns the path as given. ``kind``: a
    file a user named, replaced only where it is the toolkit's own of that kind."""
    return write_files([(path, data, kind)])[0]


def write_files(files: Sequence[tuple[str | Path, str | bytes, Output | None]]) -> list[Path]:
    """The files of one run, ``(path, data, kind)`` each, written all or none: each is built
    beside its path, and they are moved in only once every one is written."""
    for path, _, _ in files:  # the moves at the end must not fail: a directory in the way fails now
        if Path(path).is_dir():
            raise IsADirectoryError(errno.EISDIR, "a directory is in the way of the file", str(path))
    writings: list[Writing] = []
    try:
        for path, data, kind in files:
            writings.append(Writing(path, kind))
            if isinstance(data, bytes):
                writings[-1].path.write_bytes(data)
            else:
                writings[-1].path.write_text(data)
    except BaseException as e:
        failures = [w.fail(e) for w in writings]
        raise (failures[-1] if failures else e) from None
    with _signals_held():
        for w in writings:
            w.commit()
    return [Path(path) for path, _, _ in files]


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    elif os.path.lexists(path):
        path.unlink()


@contextmanager
def _signals_held() -> Iterator[None]:
    """Ctrl-C and SIGTERM wait until the block ends (a second Ctrl-C cannot tear a move)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old_int = signal.signal(signal.SIGINT, signal.SIG_IGN)
    old_term = signal.signal(signal.SIGTERM, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old_int)
        signal.signal(signal.SIGTERM, old_term)


_AT_FDCWD, _RENAME_EXCHANGE = -100, 2


def _exchange(a: Path, b: Path) -> bool:
    """Swap ``a`` and ``b`` in one step (Linux ``renameat2``); False where the file system or the
    C library cannot."""
    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except (AttributeError, OSError):
        return False
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP, errno.ENOTSUP):
        return False
    raise OSError(code, os.strerror(code), str(b))


def _move_into_place(tmp: Path, out: Path) -> None:
    """``tmp`` becomes ``out``; an existing directory ``out`` is replaced by a directory only now,
    whole (a file never replaces a directory, nor a directory a file)."""
    if not (tmp.is_dir() and out.is_dir() and not out.is_symlink()):
        os.replace(tmp, out)
        return
    if _exchange(tmp, out):  # ``tmp`` now holds the old output
        _remove(tmp)
        return
    old = temporary_beside(out, OLD)  # killed between the renames, the next run puts it back
    os.rename(out, old)
    os.rename(tmp, out)
    _remove(old)
