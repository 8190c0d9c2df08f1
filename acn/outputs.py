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

Writing itself goes through ``acn.atomic`` (build beside, rename at the end), so a run that
fails or is interrupted leaves the previous output as it was.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from acn.errors import UserError


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


def _resolved(path: Path) -> Path:
    return Path(os.path.abspath(os.path.expanduser(path)))


def _holds(directory: Path, path: Path) -> bool:
    """``directory`` is ``path`` or one of its ancestors (both resolved)."""
    return directory == path or directory in path.parents


def check_output(path: str | Path | None, kind: Output, flag: str = "--out", overwrite: bool = False,
                 inputs: Sequence[str | Path] = ()) -> Path | None:
    """Refuse ``path`` for ``kind`` (see the module docstring), or return it as a ``Path``
    (None stays None: the option was not given)."""
    if path is None:
        return None
    if str(path).strip() == "":
        raise UserError(f"{flag} is empty: give a {kind.what} path")
    given = Path(path)
    out = _resolved(given)
    here, home = _resolved(Path.cwd()), _resolved(Path.home())
    if out == Path(out.anchor) or out == home or _holds(out, here):
        where = "the file system's root" if out == Path(out.anchor) else \
            ("the home directory" if out == home else "the working directory or one holding it")
        raise UserError(f"{flag} {given} is {where}; give a {kind.what} path of its own")
    for i in inputs:
        if i is None:
            continue
        source = _resolved(Path(i))
        if _holds(out, source) or _holds(source, out):
            how = "is" if out == source else ("holds" if _holds(out, source) else "is inside")
            raise UserError(f"{flag} {given} {how} the input {i}; write the output elsewhere")
    parent = out.parent
    if not parent.is_dir():
        raise UserError(f"{flag} {given}: its directory {parent} does not exist (create it first)")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise UserError(f"{flag} {given}: its directory {parent} is not writable")
    if kind.directory:
        if out.exists() and not out.is_dir():
            raise UserError(f"{flag} {given} is a file, not a {kind.what}")
        if out.is_dir():
            if not overwrite:
                raise UserError(f"{flag} {given} exists (use --overwrite to replace it)")
            if any(out.iterdir()) and not kind.recognise(out):
                raise UserError(f"{flag} {given} holds files that are not a {kind.what} this toolkit wrote; "
                                "--overwrite replaces only those: choose another path")
    else:
        if out.is_dir():
            raise UserError(f"{flag} {given} is a directory; give a file name")
        if out.exists() and not kind.recognise(out):
            raise UserError(f"{flag} {given} exists and is not a {kind.what} this toolkit wrote; "
                            "choose another path")
    return given


def refuse_foreign(path: Path, kind: Output, overwrite: bool) -> None:
    """The library's own guard before it writes ``path`` (the CLI checks more, earlier): an
    existing ``path`` is replaced only with ``overwrite`` and only where it is the toolkit's own."""
    if not path.exists():
        return
    if kind.directory and not overwrite:
        raise UserError(f"{kind.what} {path} exists (use --overwrite to replace it)")
    if path.is_dir() != kind.directory or not (kind.recognise(path) or (kind.directory and not any(path.iterdir()))):
        raise UserError(f"{path} is not a {kind.what} this toolkit wrote; refusing to replace it")


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
