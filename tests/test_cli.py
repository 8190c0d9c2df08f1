"""Command-line behaviour: help, a one-line error and exit status 2 for every bad input."""

from __future__ import annotations

import subprocess
import sys

import pytest


def run(*args: str, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "acn.cli", *args], capture_output=True, text=True, cwd=cwd,
                          timeout=300)


def test_help():
    r = run("--help")
    assert r.returncode == 0 and "--target" in r.stdout and "--workers" in r.stdout


@pytest.mark.parametrize("args, message", [
    (["--policy", "moonwalk"], "invalid choice"),
    (["--source", "gazebo"], "neither a backend"),
    (["--target", "isaac"], "neither a backend"),
    (["--episodes", "0"], ">= 1"),
    (["--episodes", "two"], "whole number"),
    (["--seconds", "nan"], "finite number"),
    (["--seconds", "inf"], "finite number"),
    (["--seconds", "-3"], "> 0"),
    (["--seed", "-1"], ">= 0"),
    (["--workers", "0"], ">= 1"),
    (["--control-hz", "300", "--physics-hz", "1000"], "multiple of --control-hz"),
    (["--corrector", "/nonexistent/model"], "does not exist"),
])
def test_bad_input_is_one_line_and_exit_2(tmp_path, args, message):
    r = run("--out", str(tmp_path / "out"), *args)
    assert r.returncode == 2, r.stderr
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0], r.stderr
    assert "Traceback" not in r.stderr
    assert not (tmp_path / "out").exists()


def test_existing_output_directory_is_refused(tmp_path):
    (tmp_path / "out").mkdir()
    r = run("--out", str(tmp_path / "out"), "--seconds", "0.1", "--episodes", "1")
    assert r.returncode == 2 and "exists" in r.stderr and len(r.stderr.strip().splitlines()) == 1


def test_collect_end_to_end(tmp_path):
    r = run("--target", "mujoco", "--episodes", "2", "--seconds", "0.2", "--workers", "2", "--out",
            str(tmp_path / "ok"))
    assert r.returncode == 0, r.stderr
    assert "wrote 2 episode(s)" in r.stdout and "LeRobotDataset" in r.stdout
