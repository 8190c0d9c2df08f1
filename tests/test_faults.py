"""Faults under the real commands: a full disk at a chosen write, a SIGKILL at a chosen write or
rename, two runs into one output, a stopped study. The faults are injected by ``faultfs.c``
(built here, loaded with LD_PRELOAD into a command run as a subprocess): the command, lerobot,
pyarrow and torch write as they always do, and the operating system answers ENOSPC or kills.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

COMMANDS = {"collect": "collect_main", "fit": "fit_main", "diagnose": "diagnose_main"}
TINY = {
    "collect": ["--source", "pybullet", "--target", "mujoco", "--episodes", "2", "--seconds", "2"],
    "fit": ["DS", "--epochs", "1", "--rounds", "0", "--no-oracles", "--eval-episodes", "0"],
    "diagnose": ["DS", "--model", "mujoco", "--side", "source", "--effects", "joint_damping"],
}
OVERWRITE = {"collect": ["--overwrite"], "fit": ["--overwrite"], "diagnose": []}  # its own files are replaced
OUTPUTS = {"collect": ["--out", "OUT"], "fit": ["--out", "OUT"],
           "diagnose": ["--json", "OUT.json", "--report", "OUT.html", "--save-model", "OUT.model.json"]}


@pytest.fixture(scope="session")
def faultfs(tmp_path_factory) -> Path:
    cc = shutil.which("cc") or shutil.which("gcc")
    if cc is None:
        pytest.skip("no C compiler to build the fault injector")
    so = tmp_path_factory.mktemp("faultfs") / "faultfs.so"
    subprocess.run([cc, "-shared", "-fPIC", "-O1", "-o", str(so), str(Path(__file__).with_name("faultfs.c")), "-ldl"],
                   check=True)
    return so


def command(tool: str, *args: str, cwd: Path, faultfs: Path | None = None, wait: bool = True,
            **faults: object) -> subprocess.CompletedProcess | subprocess.Popen:
    """``acn-TOOL ARGS`` as a subprocess in ``cwd``, with the faults of faultfs.c under ``cwd``
    (``write_at=3`` sets FAULT_WRITE_AT=3); its own session, so its helpers can be found."""
    env = {**os.environ, "HF_HUB_OFFLINE": "1"}
    if faultfs is not None:
        env.update(LD_PRELOAD=str(faultfs), FAULT_DIR=str(cwd),
                   **{f"FAULT_{k.upper()}": str(v) for k, v in faults.items()})
    argv = [sys.executable, "-c", f"import sys; from acn.cli import {COMMANDS.get(tool, tool + '_main')}; "
            f"sys.exit({COMMANDS.get(tool, tool + '_main')}(sys.argv[1:]))", *args]
    p = subprocess.Popen(argv, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True)
    if not wait:
        return p
    out, err = p.communicate(timeout=200)
    return subprocess.CompletedProcess(argv, p.returncode, out, err)


def tree(path: Path) -> dict[str, bytes]:
    """Every file under ``path`` (or ``path`` itself), by relative name."""
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.is_file())
    return {str(p.relative_to(path.parent)): p.read_bytes() for p in files}


def hidden(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if p.name.startswith("."))


def helpers_of(session: int) -> list[int]:
    """Live processes of a session (the killed command's workers, forkserver, resource tracker)."""
    pids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[3]) == session and fields[0] != "Z":
                pids.append(int(d.name))
    return pids


def wait_until_gone(session: int, seconds: float = 30.0) -> list[int]:
    end = time.monotonic() + seconds
    while helpers_of(session) and time.monotonic() < end:
        time.sleep(0.2)
    return helpers_of(session)


def one_line(stderr: str) -> str:
    """The one error line a command ended with (its progress lines before it aside)."""
    errors = [line for line in stderr.splitlines() if ": error: " in line]
    assert len(errors) == 1 and stderr.rstrip().endswith(errors[0]) and "Traceback" not in stderr, stderr
    return errors[0]


@pytest.fixture(scope="session")
def before_fault(tmp_path_factory, faultfs) -> dict[str, tuple[Path, int]]:
    """For each command, a folder holding its output (and the dataset it reads), and the writes
    a run of it over that output makes there (counted by faultfs)."""
    import acn.cli

    made: dict[str, tuple[Path, int]] = {}
    root = tmp_path_factory.mktemp("before_fault")
    ds = root / "DS"
    assert acn.cli.collect_main([*TINY["collect"], "--out", str(ds)]) == 0
    for tool in COMMANDS:
        folder = root / tool
        folder.mkdir()
        if tool != "collect":
            shutil.copytree(ds, folder / "DS")
        args = [*TINY[tool], *OUTPUTS[tool]]
        in_folder = [str(folder / a) if a in ("DS", "OUT") or a.startswith("OUT.") else a for a in args]
        assert getattr(acn.cli, COMMANDS[tool])(in_folder) == 0  # the output a fault must not lose
        count = folder.parent / f"{tool}.count"
        again = command(tool, *args, *OVERWRITE[tool], cwd=folder, faultfs=faultfs, count_file=count)
        assert again.returncode == 0, again.stderr
        writes = sum(int(line.split()[0]) for line in count.read_text().splitlines())
        made[tool] = (folder, writes)
    return made


@pytest.mark.xdist_group("full_disk")  # one process builds the outputs they share
@pytest.mark.parametrize("tool", list(COMMANDS))
@pytest.mark.parametrize("where", ["first", "middle", "last"])
def test_a_full_disk_at_any_write_keeps_the_old_output(tmp_path, faultfs, before_fault, tool, where):
    folder, writes = before_fault[tool]
    here = tmp_path / tool
    shutil.copytree(folder, here)
    outputs = [here / p for p in OUTPUTS[tool][1::2]]
    old = {str(p): tree(p) for p in outputs}
    at = {"first": 1, "middle": max(1, writes // 2), "last": writes}[where]
    args = [*TINY[tool], *OUTPUTS[tool], *OVERWRITE[tool], "--seed", "1"]
    r = command(tool, *args, cwd=here, faultfs=faultfs, write_at=at)
    assert r.returncode == 1, r.stderr
    line = one_line(r.stderr)
    assert "no space left on the disk" in line and "as it was" in line, line
    assert {str(p): tree(p) for p in outputs} == old
    assert hidden(here) == []


def test_a_collection_its_disk_cannot_hold_is_refused_before_it_runs(acn, tmp_path):
    r = acn("collect", "--episodes", "1000000", "--seconds", "1000", "--out", str(tmp_path / "big"))
    assert r.returncode == 2 and "free" in one_line(r.stderr) and "collection needs about" in r.stderr
    assert list(tmp_path.iterdir()) == []


def test_two_collections_into_one_out_started_together_one_writes(tmp_path):
    args = ["--source", "mujoco", "--episodes", "3", "--seconds", "4", "--out", "conc"]
    runs = [command("collect", *args, "--seed", str(seed), cwd=tmp_path, wait=False) for seed in (1, 2)]
    results = [(p.wait(timeout=200), p.stdout.read(), p.stderr.read()) for p in runs]
    codes = sorted(code for code, _, _ in results)
    assert codes == [0, 2], results
    _, _, refused = next(r for r in results if r[0] == 2)
    line = one_line(refused)
    assert "is being written by acn-collect (pid" in line or "exists (use --overwrite" in line, line
    from acn.datasets.reader import read_card

    assert len(read_card(tmp_path / "conc").acn.episodes) == 3
    assert hidden(tmp_path) == []


@pytest.mark.parametrize("when", ["during episodes", "before the final move", "after the final move"])
def test_a_killed_collection_leaves_a_dataset_or_nothing_and_no_helper(acn, tmp_path, faultfs, when):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    args = ["--source", "pybullet", "--target", "mujoco", "--episodes", "4", "--seconds", "1"]
    out = tmp_path / "DS"
    killed = [*args, "--workers", "2"]  # helper processes that must end with it
    if when == "during episodes":
        faults = {"kill_write_at": 40}
    else:
        assert acn("collect", *args, "--out", str(out)).returncode == 0
        faults = {"kill_rename": 1, **({"kill_after": 1} if when.startswith("after") else {})}
        killed += ["--overwrite", "--seed", "1"]
    p = command("collect", *killed, "--out", "DS", cwd=tmp_path, faultfs=faultfs, wait=False, **faults)
    p.wait(timeout=200)
    assert p.returncode == -signal.SIGKILL, p.stderr.read()
    assert wait_until_gone(p.pid) == []
    if out.exists():
        assert len(LeRobotDataset("acn/DS", root=out)) > 0
    again = acn("collect", *args, "--out", str(out), "--overwrite")
    assert again.returncode == 0, again.stderr
    assert "removed what runs that were killed left in" in again.stderr
    assert hidden(tmp_path) == []


def test_a_killed_study_stops_its_stage_command(tmp_path):
    """The study's process dies (SIGKILL: nothing of it runs after); its stage's acn-collect
    sees that, stops as on Ctrl-C, and ends with nothing half-written."""
    (tmp_path / "logs").mkdir()
    stage = ("from pathlib import Path; from acn.transfer.study import Step; "
             f"Step('collect', 'acn-collect', ['--source', 'mujoco', '--episodes', '200', '--seconds', '4', "
             f"'--out', 'DS']).run(Path({str(tmp_path)!r}))")
    study = subprocess.Popen([sys.executable, "-c", stage], cwd=tmp_path, start_new_session=True,
                             env={**os.environ, "HF_HUB_OFFLINE": "1"})
    log = tmp_path / "logs" / "collect.log"
    end = time.monotonic() + 120
    while "episode 1/" not in (log.read_text() if log.exists() else "") and time.monotonic() < end:
        time.sleep(0.2)
    study.send_signal(signal.SIGKILL)
    study.wait()
    assert wait_until_gone(study.pid, 90) == []
    assert "interrupted" in log.read_text()
    assert hidden(tmp_path) == []
