"""Shared fixtures: small real collections (real PyBullet, real MuJoCo, real lerobot)."""

from __future__ import annotations

import atexit
import os
import shutil
import signal
import subprocess
import tempfile

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")
# One OpenBLAS and one OpenMP thread per test process (set before numpy and torch load; children inherit
# them): `make test` runs two processes on two cores, and a thread per core in each spins against the other
# process. numpy's least squares in the data checks: 8 s a diagnosis with two threads, 0.1 s with one; torch's
# training loops likewise (test_fit: 51 s with one thread, 90 s with two; test_ppo 36 s, 69). Where a test needs
# threads it asks for them (--train-threads; MuJoCo's rollouts keep theirs).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

from hypothesis import settings  # noqa: E402
from hypothesis.configuration import set_hypothesis_home_dir  # noqa: E402

from acn.sim.collector import CollectConfig, collect_episodes  # noqa: E402

_HYPOTHESIS_HOME = tempfile.mkdtemp(prefix="acn-hypothesis-")  # no .hypothesis/ in the tree, none left in /tmp
atexit.register(shutil.rmtree, _HYPOTHESIS_HOME, ignore_errors=True)
set_hypothesis_home_dir(_HYPOTHESIS_HOME)
settings.register_profile("acn", database=None)
settings.load_profile("acn")


@pytest.fixture(scope="session", autouse=True)
def _outside_the_tree(tmp_path_factory):
    """Run every test from a temporary directory: anything a library writes into the working
    directory stays out of the repository."""
    before = os.getcwd()
    os.chdir(tmp_path_factory.mktemp("cwd"))
    yield
    os.chdir(before)


@pytest.fixture
def interruptible():
    """Children this test starts can be interrupted with SIGINT, as from a terminal: a process
    started with SIGINT ignored keeps ignoring it (Python installs no KeyboardInterrupt handler),
    and a test worker may run with it ignored. Here SIGINT is Python's default handler, which a
    child's exec turns back into the default action."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.fixture(scope="session")
def small_config() -> CollectConfig:
    return CollectConfig(source="pybullet", target="mujoco", policy="trot", episodes=2, seconds=1.0, seed=3)


@pytest.fixture(scope="session")
def small_episodes(small_config):
    return collect_episodes(small_config, list(range(small_config.episodes)))


@pytest.fixture(scope="session")
def small_dataset(tmp_path_factory, small_config):
    from acn.datasets.record import record

    return record(small_config, tmp_path_factory.mktemp("data") / "paired")


@pytest.fixture
def acn(capsys):
    """Run an acn command line in this process: (exit status, stdout, stderr)."""
    import acn.cli

    def run(tool: str, *args: str) -> subprocess.CompletedProcess:
        try:
            code = getattr(acn.cli, f"{tool}_main")(list(args))
        except SystemExit as e:  # argparse's own errors
            code = e.code
        out = capsys.readouterr()
        return subprocess.CompletedProcess(args, code, out.out, out.err)

    return run


def load(root):
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    return LeRobotDataset(f"acn/{root.name}", root=root)
