"""The one mechanism every output is written by (acn.outputs): the lock, the leftovers of dead
runs, the move into place, the write errors. Fast: no simulator, other processes where a test
needs a second run."""

from __future__ import annotations

import errno
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from acn.errors import UserError
from acn.outputs.kinds import Output
from acn.outputs.leftovers import clear_beside
from acn.outputs.lock import OutputBusy, claim, lock_path, release
from acn.outputs.writing import Layout, WriteFailed, Writing, write_errno, write_files

STUDY_LIKE = Output("test output", directory=True, recognise=lambda p: (p / "mine").is_file())


@pytest.fixture
def other_run(tmp_path):
    """Start another process that claims a path and waits; yields a function path -> its pid."""
    started: list[subprocess.Popen] = []

    def start(path: Path) -> int:
        code = ("import sys, time; from acn.outputs.lock import claim, set_program; set_program('acn-other'); "
                "claim(sys.argv[1]); print('held', flush=True); time.sleep(60)")
        p = subprocess.Popen([sys.executable, "-c", code, str(path)], stdout=subprocess.PIPE, text=True)
        assert p.stdout.readline().strip() == "held"
        started.append(p)
        return p.pid

    yield start
    for p in started:
        p.kill()
        p.wait()


def dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_a_second_run_into_a_held_output_is_refused_naming_the_holder(acn, tmp_path, other_run):
    pid = other_run(tmp_path / "DS")
    r = acn("collect", "--episodes", "1", "--seconds", "0.2", "--out", str(tmp_path / "DS"))
    assert r.returncode == 2
    assert f"is being written by acn-other (pid {pid}, since " in r.stderr and len(r.stderr.splitlines()) == 1
    assert not (tmp_path / "DS").exists()
    # another path beside it is not blocked
    assert acn("collect", "--episodes", "1", "--seconds", "0.2", "--out", str(tmp_path / "other")).returncode == 0


def test_a_dead_runs_lock_is_taken_over_and_removed(tmp_path):
    out = tmp_path / "DS"
    lock_path(out).write_text(json.dumps({"command": "acn-collect", "pid": dead_pid(), "started": time.time()}))
    claim(out)
    release(out)
    assert list(tmp_path.iterdir()) == []


def test_claims_in_one_process_are_counted(tmp_path):
    out = tmp_path / "f.json"
    claim(out)
    claim(out)
    release(out)
    assert lock_path(out).exists()
    release(out)
    assert not lock_path(out).exists()


def test_leftovers_of_dead_runs_go_and_a_live_runs_stay(tmp_path, other_run):
    dead = dead_pid()
    (tmp_path / f".DS.partial-{dead}").mkdir()                 # a killed collection into DS
    (tmp_path / f".other.partial-{dead}").write_text("x")      # a killed write of a file beside it
    (tmp_path / ".gone.lock").write_text("{}")                 # a killed run's lock
    live = other_run(tmp_path / "busy")
    (tmp_path / f".busy.partial-{live}").mkdir()               # a live run's work: never touched
    (tmp_path / f".busy.partial-{dead}").mkdir()               # dead pid, but busy's lock is held: kept
    old = tmp_path / f".model.partial-{dead}.old"              # killed between the two renames
    old.mkdir()
    (old / "mine").write_text("the previous output")
    cleared = clear_beside(tmp_path / "DS")
    assert sorted(cleared.removed) == sorted([f".DS.partial-{dead}", f".other.partial-{dead}", ".gone.lock"])
    assert cleared.restored == (str(tmp_path / "model"),)
    assert (tmp_path / "model" / "mine").read_text() == "the previous output"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        [".busy.lock", f".busy.partial-{live}", f".busy.partial-{dead}", "model"])
    assert str(tmp_path) in cleared.line() and "put back" in cleared.line()


def test_a_runs_own_locks_beside_its_output_are_not_leftovers(tmp_path):
    """A run writing two files side by side (acn-diagnose: --json and --report) holds both locks:
    clearing beside one leaves the other's lock as it is and says nothing of it."""
    claim(tmp_path / "d.json")
    claim(tmp_path / "d.html")
    try:
        assert clear_beside(tmp_path / "d.json").removed == ()
        assert lock_path(tmp_path / "d.html").exists()
    finally:
        release(tmp_path / "d.html")
        release(tmp_path / "d.json")
    assert list(tmp_path.iterdir()) == []


def test_an_output_is_replaced_whole_and_a_failure_keeps_the_old(tmp_path):
    out = tmp_path / "out"
    with Writing(out, STUDY_LIKE) as w:
        w.path.mkdir()
        (w.path / "mine").write_text("1")
    with pytest.raises(RuntimeError):
        with Writing(out, STUDY_LIKE, overwrite=True) as w:
            w.path.mkdir()
            (w.path / "mine").write_text("2")
            raise RuntimeError("the run failed")
    assert (out / "mine").read_text() == "1" and sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    with Writing(out, STUDY_LIKE, overwrite=True) as w:
        w.path.mkdir()
        (w.path / "mine").write_text("2")
    assert (out / "mine").read_text() == "2" and sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_a_write_error_is_one_line_naming_the_path_and_the_cause(tmp_path):
    with pytest.raises(WriteFailed, match=r"cannot write .*out: no space left on the disk; nothing was written"):
        with Writing(tmp_path / "out", STUDY_LIKE):
            raise OSError(errno.ENOSPC, "No space left on device")
    assert list(tmp_path.iterdir()) == []


def test_write_errors_are_found_inside_a_librarys_own_exception():
    assert write_errno(OSError(errno.EROFS, "Read-only file system")) == errno.EROFS
    assert write_errno(RuntimeError("Error while serializing: IoError(Os { code: 28, kind: StorageFull, "
                                    "message: \"No space left on device\" })")) == errno.ENOSPC
    try:
        try:
            raise OSError(errno.EDQUOT, "Disk quota exceeded")
        except OSError as e:
            raise ValueError("writing the table failed") from e
    except ValueError as wrapped:
        assert write_errno(wrapped) == errno.EDQUOT
    assert write_errno(ValueError("a bad value")) is None
    assert write_errno(FileNotFoundError(errno.ENOENT, "missing")) is None


def test_files_of_one_run_are_written_all_or_none(tmp_path):
    a, b = tmp_path / "a.txt", tmp_path / "b"
    b.mkdir()  # a directory where a file is asked for: the second write fails
    with pytest.raises(OSError):
        write_files([(a, "new", None), (b, "new", None)])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["b"]
    write_files([(a, "one", None), (tmp_path / "c.txt", "two", None)])
    assert a.read_text() == "one" and (tmp_path / "c.txt").read_text() == "two"


def test_an_output_written_in_place_replaces_an_old_one_first_and_keeps_a_failed_one(tmp_path):
    out = tmp_path / "study"
    out.mkdir()
    (out / "mine").write_text("old")
    with pytest.raises(UserError, match="exists"):
        Writing(out, STUDY_LIKE, layout=Layout.IN_PLACE)
    with pytest.raises(RuntimeError):
        with Writing(out, STUDY_LIKE, overwrite=True, layout=Layout.IN_PLACE) as w:
            assert w.path == out and not out.exists()
            out.mkdir()
            (out / "mine").write_text("half")
            raise RuntimeError("a stage failed")
    assert (out / "mine").read_text() == "half"  # left for a look
    assert sorted(p.name for p in tmp_path.iterdir()) == ["study"]


def test_a_busy_output_is_refused_by_the_library_too(tmp_path, other_run):
    other_run(tmp_path / "out")
    with pytest.raises(OutputBusy, match="acn-other"):
        Writing(tmp_path / "out", STUDY_LIKE)
    assert os.path.exists(lock_path(tmp_path / "out"))  # the other run's lock is left alone
