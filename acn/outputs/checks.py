"""Where a command may write: the one check of an output path, made before any work.

The toolkit only ever replaces what it wrote itself. Each kind of output (a dataset, a
corrector, a PPO run, a diagnosis JSON, a report, ...) is an ``Output``: what it is called and
how to recognise one the toolkit wrote. ``check_output`` refuses, in one ``UserError`` line:

- an empty path, ``.``, ``/``, the home directory, and any directory that holds the working
  directory (replacing them would delete what the user is working in);
- a path that is an input of the same command, a directory that holds one, or a path inside one;
- a path whose parent directory is missing or not writable;
- for a directory output: a file; an existing directory without ``overwrite``; with
  ``overwrite``, a directory that holds anything but the toolkit's own output of the same kind
  (an empty directory holds nothing to lose);
- for a file output: a directory, and an existing file that is not the toolkit's own output of
  the same kind.

The path is claimed (``acn.outputs.lock``) before anything there is looked at, so two runs
into one path cannot both pass; ``check_space`` refuses an output its disk cannot hold.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Sequence

from acn.errors import UserError
from acn.outputs.kinds import Output
from acn.outputs.lock import claim, release


def _resolved(path: Path) -> Path:
    return Path(os.path.abspath(os.path.expanduser(path)))


def _holds(directory: Path, path: Path) -> bool:
    """``directory`` is ``path`` or one of its ancestors (both resolved)."""
    return directory == path or directory in path.parents


def check_output(path: str | Path | None, kind: Output, flag: str | None = "--out", overwrite: bool = False,
                 inputs: Sequence[str | Path] = ()) -> Path | None:
    """Claim ``path``'s lock for this run and refuse ``path`` for ``kind`` (see the module
    docstring), or return it as a ``Path`` (None stays None: the option was not given).
    ``flag`` names the option in messages; None (a library writer) names the kind instead."""
    if path is None:
        return None
    name = flag or kind.what
    if str(path).strip() == "":
        raise UserError(f"{name} is empty: give a {kind.what} path")
    given = Path(path)
    out = _resolved(given)
    here, home = _resolved(Path.cwd()), _resolved(Path.home())
    if out == Path(out.anchor) or out == home or _holds(out, here):
        where = "the file system's root" if out == Path(out.anchor) else \
            ("the home directory" if out == home else "the working directory or one holding it")
        raise UserError(f"{name} {given} is {where}; give a {kind.what} path of its own")
    for i in inputs:
        if i is None:
            continue
        source = _resolved(Path(i))
        if _holds(out, source) or _holds(source, out):
            how = "is" if out == source else ("holds" if _holds(out, source) else "is inside")
            raise UserError(f"{name} {given} {how} the input {i}; write the output elsewhere")
    parent = out.parent
    if not parent.is_dir():
        raise UserError(f"{name} {given}: its directory {parent} does not exist (create it first)")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UserError(f"{name} {given}: its directory {parent} is not writable")
    claim(out)  # what is there is looked at only under the lock: another run may be writing it
    try:
        _refuse_existing(given, out, kind, name, overwrite)
    except BaseException:
        release(out)
        raise
    return given


def _refuse_existing(given: Path, out: Path, kind: Output, name: str, overwrite: bool) -> None:
    if kind.directory:
        if out.exists() and not out.is_dir():
            raise UserError(f"{name} {given} is a file, not a {kind.what}")
        if out.is_dir():
            if not overwrite:
                raise UserError(f"{name} {given} exists (use --overwrite to replace it)")
            if any(out.iterdir()) and not kind.recognise(out):
                raise UserError(f"{name} {given} holds files that are not a {kind.what} this toolkit wrote; "
                                "--overwrite replaces only those: choose another path")
    else:
        if out.is_dir():
            raise UserError(f"{name} {given} is a directory; give a file name")
        if out.exists() and not kind.recognise(out):
            raise UserError(f"{name} {given} exists and is not a {kind.what} this toolkit wrote; "
                            "choose another path")


def check_space(path: str | Path, needed: int, what: str, flag: str = "--out") -> None:
    """Refuse, before the work, an output of about ``needed`` bytes that its disk cannot hold
    (the previous output stays until the new one is complete, so it does not count as free)."""
    free = shutil.disk_usage(_resolved(Path(path)).parent).free
    if needed > free:
        raise UserError(f"{flag} {path}: the {what} needs about {_size(needed)} and its disk has {_size(free)} free; "
                        "free some space or write elsewhere")


def _size(n: float) -> str:
    for unit in ("bytes", "kB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} TB"


def check_input_dir(path: Path | None, what: str) -> Path | None:
    """An input directory that exists; one line naming what it is where it is a file or missing
    (None stays None: the option was not given)."""
    if path is None:
        return None
    if path.is_file():
        raise UserError(f"{path} is a file, not a {what}")
    if not path.is_dir():
        raise UserError(f"{what} {path} does not exist")
    return path
