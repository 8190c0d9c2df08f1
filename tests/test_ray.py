"""Ray (the optional extra): collection equal to local workers byte for byte, shards merged into
one dataset, re-simulation batches on Ray equal to local, interrupts, and the error without Ray.

One local Ray instance with 2 CPUs serves the whole module (started once, shut down at the end,
its files in a temporary directory); the interrupt tests' subprocesses join it by address."""

from __future__ import annotations

import hashlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import load

pytest.importorskip("ray")
pytestmark = pytest.mark.xdist_group("ray")  # `make test` runs tests on 2 workers: one Ray instance, on one of them

from acn.datasets.record import record  # noqa: E402
from acn.sim import parallel  # noqa: E402
from acn.sim.backends import SimConfig  # noqa: E402
from acn.sim.collector import CollectConfig, collect_episodes  # noqa: E402
from acn.sim.resim import Resimulator  # noqa: E402

RAY = parallel.RayConfig(cpus=2)
CONFIG = CollectConfig(target="mujoco", policy="random", episodes=4, seconds=0.4, seed=11)


def _ray_processes(temp_dir: str) -> list[str]:
    """Command lines of live processes that belong to the Ray instance in ``temp_dir``."""
    out = []
    for proc in Path("/proc").iterdir():
        try:
            cmd = (proc / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:
            continue
        if temp_dir in cmd:
            out.append(cmd)
    return out


def test_this_module_runs_on_one_test_process(request):
    """`make test` (--dist loadgroup) keeps an xdist_group on one worker; pytest 9.2 ignores the
    groups silently (pyproject keeps it below 9.2), and two Ray instances would start at once."""
    if getattr(request.config.option, "loadgroup", False):  # a pytest-xdist worker under --dist loadgroup
        assert request.node.nodeid.endswith("@ray"), request.node.nodeid


@pytest.fixture(scope="module")
def ray_address():
    """A local Ray instance (2 CPUs) for the module; yields its address."""
    before = set(Path(tempfile.gettempdir()).glob("acn-ray-*"))
    with parallel.ray_session(RAY) as ray:
        new = set(Path(tempfile.gettempdir()).glob("acn-ray-*")) - before
        address = ray.get_runtime_context().gcs_address
        # this session's: another process on the machine may start a Ray instance meanwhile (the
        # other test worker would, were xdist_group ignored); ours run with --gcs-address=<ours>
        ours = [t for t in new if any(f"--gcs-address={address}" in c for c in _ray_processes(str(t)))] or sorted(new)
        assert len(ours) == 1, f"expected one new Ray temp dir, found {sorted(map(str, new))}"
        temp_dir = str(ours[0])
        yield address
    deadline = time.time() + 20
    while _ray_processes(temp_dir) and time.time() < deadline:
        time.sleep(0.5)
    assert not _ray_processes(temp_dir), "Ray processes left running"
    assert not Path(temp_dir).exists()


@pytest.fixture(scope="module")
def local_dataset(tmp_path_factory):
    return record(CONFIG, tmp_path_factory.mktemp("local") / "w2", workers=2)


def _files(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def test_ray_collection_equals_workers_byte_for_byte(ray_address, local_dataset, tmp_path):
    on_ray = record(CONFIG, tmp_path / "w2", ray=RAY)
    local, remote = _files(local_dataset), _files(on_ray)
    assert "meta/info.json" in local and any(k.startswith("data/") for k in local)
    assert local == remote  # every file: data, info.json (acn block included), episodes, stats, tasks


def test_shards_merge_into_one_dataset_with_every_episode_once(ray_address, local_dataset, tmp_path):
    seen: list[int] = []
    path = record(CONFIG, tmp_path / "sharded", ray=RAY, shards=2, on_episode=lambda ep: seen.append(ep.index))
    assert sorted(seen) == [0, 1, 2, 3]
    ds, ref = load(path), load(local_dataset)
    assert ds.num_episodes == 4 and ds.num_frames == ref.num_frames
    a, b = ds.hf_dataset.with_format("numpy")[:], ref.hf_dataset.with_format("numpy")[:]
    for key in b:
        assert np.array_equal(np.stack(a[key]), np.stack(b[key])), key
    acn = json.loads((path / "meta" / "info.json").read_text())["acn"]
    assert [e["collection_index"] for e in acn["episodes"]] == [0, 1, 2, 3]
    assert [e["episode_index"] for e in acn["episodes"]] == [0, 1, 2, 3]
    assert acn == json.loads((local_dataset / "meta" / "info.json").read_text())["acn"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no shard or temporary left


@pytest.fixture(scope="module")
def rows():
    ep = collect_episodes(CollectConfig(target="mujoco", policy="random", episodes=1, seconds=1.0, seed=5), [0])[0]
    return ep.target.state, ep.target.action


def test_control_jacobian_on_ray_equals_local(ray_address, rows):
    from acn.corrector.sensitivity import control_jacobian

    states, actions = rows
    channels = ["base_pos_z", "FR_thigh_pos", "RL_calf_vel"]
    with Resimulator("mujoco", SimConfig()) as sim:
        local = control_jacobian(sim, states, actions, channels)
    with parallel.ray_executor(min_chunk_steps=100) as executor, Resimulator("mujoco", SimConfig()) as sim:
        remote = control_jacobian(sim, states, actions, channels)
        assert executor.batches == 1  # it did run on Ray
    assert np.isfinite(local).all()
    assert np.array_equal(local, remote)


@pytest.mark.parametrize("backend", ["mujoco", "pybullet"])
def test_resimulator_batch_on_ray_equals_local(ray_address, rows, backend):
    """Three models (latency; a dead band MuJoCo cannot express natively), K steps, previous
    actions, rows interleaved between models: bit for bit."""
    from acn.sim.robot import ModelParams

    states, actions = rows
    n, k = len(states) - 3, 3
    acts = np.stack([actions[i:i + k] for i in range(n)])
    previous = np.stack([actions[max(i - 2, 0):i] if i >= 2 else np.repeat(actions[:1], 2, axis=0) for i in range(n)])
    configs = [SimConfig(), SimConfig(params=ModelParams(latency=0.012)), SimConfig(params=ModelParams(backlash=0.02))]
    model = np.arange(n) % 3
    with Resimulator(backend, configs) as sim:
        local = sim.run(states[:n], acts, previous, model=model)
    with parallel.ray_executor(min_chunk_steps=20) as executor, Resimulator(backend, configs) as sim:
        remote = sim.run(states[:n], acts, previous, model=model)
        # PyBullet stays local: its result depends on the rows simulated before (contact warm start)
        assert executor.batches == (1 if backend == "mujoco" else 0)
    for field in ("state", "effort", "diverged"):
        assert np.array_equal(getattr(local, field), getattr(remote, field), equal_nan=True), field


def test_small_batches_stay_local(ray_address, rows):
    states, actions = rows
    with parallel.ray_executor() as executor, Resimulator("mujoco", SimConfig()) as sim:
        sim.run(states[:10], actions[:10])
        assert executor.batches == 0


def _collect(out: Path, episodes: int, address: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "acn.cli", "--target", "mujoco", "--episodes", str(episodes), "--seconds", "1",
           "--out", str(out), f"--ray={address}"]
    return subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})


def test_interrupt_keeps_finished_episodes_as_a_valid_dataset(ray_address, tmp_path, interruptible):
    out = tmp_path / "interrupted"
    proc = _collect(out, 200, ray_address)
    for line in proc.stderr:  # wait for the second finished episode
        if line.startswith("episode 2/"):
            break
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert "kept" in err
    ds = load(out)
    assert 2 <= ds.num_episodes < 200
    acn = json.loads((out / "meta" / "info.json").read_text())["acn"]
    assert [e["collection_index"] for e in acn["episodes"]] == list(range(ds.num_episodes))
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_interrupt_before_any_episode_leaves_nothing(ray_address, tmp_path):
    out = tmp_path / "nothing"
    proc = _collect(out, 5, ray_address)
    time.sleep(1.0)  # still importing or connecting
    proc.send_signal(signal.SIGTERM)
    proc.communicate(timeout=120)
    assert proc.returncode != 0
    assert not out.exists()
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("command", ["collect", "fit", "diagnose"])
def test_ray_flag_without_ray_installed_is_one_line_error(monkeypatch, capsys, local_dataset, tmp_path, command):
    from acn import cli

    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` now raises ImportError
    argv = {"collect": ["--episodes", "1", "--out", str(tmp_path / "x"), "--ray"],
            "fit": [str(local_dataset), "--out", str(tmp_path / "m"), "--ray"],
            "diagnose": [str(local_dataset), "--ray"]}[command]
    code = getattr(cli, f"{command}_main")(argv)
    err = capsys.readouterr().err.strip()
    assert code == 2
    assert len(err.splitlines()) == 1 and "pip install -e '.[ray]'" in err, err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("args, message", [
    (["--shards", "2"], "--shards needs --ray"),
    (["--ray-cpus", "2"], "--ray-cpus needs --ray"),
    (["--ray=127.0.0.1:1", "--ray-cpus", "2"], "--ray-cpus sets up a local Ray instance"),
    (["--ray", "--workers", "2"], "--workers sets this machine's processes"),
])
def test_ray_argument_mistakes_are_one_line_errors(capsys, tmp_path, args, message):
    from acn.cli import collect_main

    code = collect_main(["--episodes", "1", "--out", str(tmp_path / "x"), *args])
    err = capsys.readouterr().err.strip()
    assert code == 2 and len(err.splitlines()) == 1 and message in err, err
    assert not list(tmp_path.iterdir())


def test_the_transfer_studys_independent_steps_run_as_ray_tasks_in_order(ray_address, tmp_path):
    """acn-transfer --ray: each group of steps is one Ray task running the toolkit's commands; the
    results and logs come back in the groups' order."""
    from acn.transfer.study import Step, on_ray

    groups = [[Step("first", "acn-diagnose", ["--list-effects"])],
              [Step("second", "acn-diagnose", ["--list-effects"]), Step("third", "acn-ppo", ["--help"])]]
    results = on_ray(groups, tmp_path, RAY, envs=1)
    assert [r.name for r in results] == ["first", "second", "third"] and all(r.seconds > 0 for r in results)
    log = (tmp_path / "logs" / "second.log").read_text()
    assert log.startswith("$ acn-diagnose --list-effects") and "joint_damping" in log
    assert "--train" in (tmp_path / "logs" / "third.log").read_text()
