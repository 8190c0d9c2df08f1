"""No traceback for any argument: every command's options drawn from its own parser.

Property-based (hypothesis): for each command, a handful of its options (the required ones
always) get values drawn by kind: numbers at the edges (0, negative, inf, nan, 1e308, text),
paths that are missing, a file, a directory with a file in it, or unreadable, choices outside
the list, odd strings. Every run must end with exit status 0, 2 or 130 and print no traceback.
The drawn values keep any run that passes the checks tiny (at most one episode of one second, a
one-step PPO run). ``--ray`` is left out: it starts a Ray instance (``tests/test_ray.py``).
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import acn.cli

COMMANDS = ("collect", "fit", "ppo", "view", "import", "diagnose")
NUMBERS = ("0", "-1", "1", "0.5", "inf", "-inf", "nan", "1e308", "-1e308", "abc", "")
TEXTS = ("", "x", "a,b", "1,2,3", "nan", "1e308", "x=1", "0", "mujoco", "random", "..", "é")
PATH_KINDS = ("missing", "file", "dir", "unreadable", "empty")
LEFT_OUT = {"--ray", "--ray-cpus", "--help"}
# Put first, so that a drawn option overrides it: a collection that passes every check stays one short episode.
TINY = {"collect": ["--episodes=1", "--seconds=0.1"]}


def _paths(root: Path) -> dict[str, str]:
    """One path of each kind under ``root``."""
    (root / "file.csv").write_text("t,q\n0,1\n")
    (root / "dir").mkdir()
    (root / "dir" / "keep.txt").write_text("x")
    (root / "locked").write_text("{}")
    os.chmod(root / "locked", 0)
    return {"missing": str(root / "missing"), "file": str(root / "file.csv"), "dir": str(root / "dir"),
            "unreadable": str(root / "locked"), "empty": ""}


def _is_path(action: argparse.Action) -> bool:
    return action.type in (Path, acn.cli._out_path) or (action.metavar or "").endswith((".json", ".html", ".rrd")) \
        or action.dest in ("corrector", "explain_corrector", "model", "map_file", "diagnosis", "eval")


def _value(action: argparse.Action):
    """A strategy for one value of ``action``: a path kind (drawn as a name), a choice or a number/text."""
    if _is_path(action):
        return st.sampled_from(PATH_KINDS).map(lambda k: ("path", k))
    if action.choices:
        return st.sampled_from([*map(str, action.choices), "bogus"]).map(lambda v: ("text", v))
    if action.type is not None and action.type is not str:
        return st.sampled_from(NUMBERS).map(lambda v: ("text", v))
    return st.sampled_from(TEXTS).map(lambda v: ("text", v))


@st.composite
def command_lines(draw, name: str):
    """(name, [(option or None, value or None), ...]) drawn from the command's parser."""
    parser = getattr(acn.cli, f"{name}_parser")()
    actions = [a for a in parser._actions if not (set(a.option_strings) & LEFT_OUT)]  # noqa: SLF001
    required = [a for a in actions if a.required or not a.option_strings]
    optional = [a for a in actions if a not in required]
    chosen = required + draw(st.lists(st.sampled_from(optional), max_size=4, unique_by=lambda a: a.dest)) \
        if optional else required
    parts = []
    for a in chosen:
        flag = a.option_strings[0] if a.option_strings else None
        if a.nargs == 0:  # store_true / store_false
            parts.append((flag, None))
        elif isinstance(a, argparse._MutuallyExclusiveGroup):  # noqa: SLF001 - never an action
            continue
        else:
            parts.append((flag, draw(_value(a))))
    # acn-ppo: one of --timesteps / --eval is required; draw which
    if name == "ppo" and not any(f in ("--timesteps", "--eval") for f, _ in parts):
        parts.append(draw(st.sampled_from([("--timesteps", ("text", "1")), ("--eval", ("path", "dir"))])))
    return parts


def _argv(parts, paths: dict[str, str]) -> list[str]:
    argv: list[str] = []
    for flag, value in parts:
        text = None if value is None else (paths[value[1]] if value[0] == "path" else value[1])
        if flag is None:
            argv.append(text)
        elif text is None:
            argv.append(flag)
        else:
            argv.append(f"{flag}={text}")  # "--x=-1": a value that starts with "-" stays a value
    return argv


@pytest.mark.timeout(600)
@pytest.mark.parametrize("name", COMMANDS)
def test_no_argument_gives_a_traceback(name, capsys):
    @settings(max_examples=20, deadline=None, derandomize=True,
              suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
    @given(parts=command_lines(name))
    def run(parts):
        with tempfile.TemporaryDirectory() as tmp:
            here = os.getcwd()
            os.chdir(tmp)
            try:
                argv = TINY.get(name, []) + _argv(parts, _paths(Path(tmp)))
                try:
                    code = getattr(acn.cli, f"{name}_main")(argv)
                except SystemExit as e:
                    code = e.code
            finally:
                os.chdir(here)
                os.chmod(Path(tmp) / "locked", 0o600)
        err = capsys.readouterr().err
        assert code in (0, 2, 130), (argv, code, err[-2000:])
        assert "Traceback" not in err, (argv, err[-2000:])

    run()
