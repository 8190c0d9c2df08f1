"""Collected datasets: exact round trip through LeRobotDataset, equivalence with lerobot's own
writer, metadata, determinism, and all-or-nothing writing."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import load

from acn.datasets import schema
from acn.datasets.metadata import AcnMetadata, collection_metadata
from acn.datasets.record import record
from acn.datasets.writer import DatasetWriter, episode_columns
from acn.sim.collector import CollectConfig
from acn.sim.state import ACTION_NAMES, STATE_NAMES


def test_round_trip_gives_the_exact_values_the_collector_produced(small_dataset, small_episodes):
    ds = load(small_dataset)
    assert ds.num_episodes == len(small_episodes)
    assert ds.num_frames == sum(len(e) for e in small_episodes)
    frames = ds.hf_dataset.with_format("numpy")[:]
    start = 0
    for i, ep in enumerate(small_episodes):
        rows = slice(start, start + len(ep))
        cols = episode_columns(ep, paired=True)
        for key, want in cols.items():
            got = np.asarray(frames[key][rows])
            np.testing.assert_array_equal(got.reshape(want.shape), want, err_msg=key)
        assert np.all(frames["episode_index"][rows] == i)
        start += len(ep)
    item = ds[3]  # torch access through __getitem__ too
    np.testing.assert_array_equal(item["target.next.observation.state"].numpy(),
                                  small_episodes[0].target.next_state[3].astype(np.float32))


def test_next_state_is_the_following_frames_state(small_episodes):
    for ep in small_episodes:
        for tr in (ep.source, ep.target):
            np.testing.assert_array_equal(tr.next_state[:-1], tr.state[1:])


def test_metadata_names_simulators_rates_and_channels(small_dataset):
    info = json.loads((small_dataset / "meta" / "info.json").read_text())
    assert info["codebase_version"] == "v3.0"
    assert info["features"]["observation.state"]["names"] == list(STATE_NAMES)
    assert info["features"]["target.action"]["names"] == list(ACTION_NAMES)
    acn = info[schema.ACN_KEY]
    assert acn["paired"] is True
    assert acn["source"]["simulator"] == "pybullet" and acn["source"]["version"]
    assert acn["target"]["simulator"] == "mujoco" and acn["target"]["version"]
    assert acn["control_hz"] == 50 and acn["physics_dt"] == 0.001 and acn["substeps"] == 20
    assert acn["action_mode"] == "position" and acn["policy"] == "trot" and acn["seed"] == 3
    assert acn["state_names"] == list(STATE_NAMES)
    assert [e["end"] for e in acn["episodes"]] == ["time_limit", "time_limit"]
    assert info["fps"] == 50


def test_typed_metadata_writes_back_the_blocks_json_unchanged(small_dataset):
    info = json.loads((small_dataset / "meta" / "info.json").read_text())
    meta = AcnMetadata.from_json(info[schema.ACN_KEY], small_dataset)
    assert meta.direction == "pybullet -> mujoco" and meta.episodes[1].collection_index == 1
    assert json.dumps(meta.to_json()) == json.dumps(info[schema.ACN_KEY])  # the same keys in the same order


def test_parquet_files_load_with_the_datasets_library(small_dataset):
    import datasets

    d = datasets.load_dataset("parquet", data_files=str(small_dataset / "data" / "*" / "*.parquet"), split="train")
    assert len(d) == 100
    assert len(d[0]["observation.state"]) == len(STATE_NAMES)


def test_fast_writer_loads_identically_to_lerobots_own_writer(tmp_path, small_config, small_episodes):
    """Our writer vs LeRobotDataset.add_frame/save_episode on the same episodes."""
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    ours = DatasetWriter(tmp_path / "ours", fps=50, paired=True, task="trot",
                         acn_meta=collection_metadata(small_config))
    for ep in small_episodes:
        ours.write(ep)
    ours.commit()

    theirs = LeRobotDataset.create("acn/theirs", fps=50, features=schema.features(True), root=tmp_path / "theirs",
                                   robot_type=schema.ROBOT_TYPE, use_videos=False)
    for ep in small_episodes:
        cols = episode_columns(ep, paired=True)
        for i in range(len(ep)):
            frame = {k: (v[i:i + 1] if v.ndim == 1 else v[i]) for k, v in cols.items()}
            theirs.add_frame({**frame, "task": "trot"})
        theirs.save_episode()
    theirs.finalize()

    a, b = load(tmp_path / "ours"), load(tmp_path / "theirs")
    assert (a.num_episodes, a.num_frames) == (b.num_episodes, b.num_frames)
    assert a.features == b.features
    for idx in range(a.num_frames):
        ia, ib = a[idx], b[idx]
        assert ia.keys() == ib.keys()
        for k in ia:
            if hasattr(ia[k], "numpy"):
                np.testing.assert_array_equal(ia[k].numpy(), ib[k].numpy(), err_msg=k)
            else:
                assert ia[k] == ib[k], k
    for key, stats in b.meta.stats.items():
        for name, value in stats.items():
            np.testing.assert_allclose(a.meta.stats[key][name], value, rtol=1e-6, err_msg=f"{key}/{name}")
    ea, eb = a.meta.episodes, b.meta.episodes
    for col in ("episode_index", "length", "dataset_from_index", "dataset_to_index", "data/chunk_index",
                "data/file_index", "tasks"):
        assert ea[col] == eb[col], col


def _parquet_rows(root: Path):
    import pyarrow.parquet as pq

    return [pq.read_table(p).to_pylist() for p in sorted((root / "data").rglob("*.parquet"))]


def test_same_seed_same_data_whatever_the_number_of_workers(tmp_path):
    cfg = CollectConfig(target="mujoco", policy="random", episodes=3, seconds=0.4, seed=11)
    one = record(cfg, tmp_path / "w1", workers=1)
    two = record(cfg, tmp_path / "w2", workers=2)
    again = record(cfg, tmp_path / "w1b", workers=1)
    assert _parquet_rows(one) == _parquet_rows(two) == _parquet_rows(again)
    other = record(CollectConfig(target="mujoco", policy="random", episodes=3, seconds=0.4, seed=12),
                   tmp_path / "s12")
    assert _parquet_rows(other) != _parquet_rows(one)


def test_source_alone_records_measurements(tmp_path):
    path = record(CollectConfig(source="mujoco", target=None, policy="excite", episodes=1, seconds=0.5),
                  tmp_path / "meas")
    ds = load(path)
    assert not any(k.startswith(schema.TARGET_PREFIX) for k in ds.features)
    assert json.loads((path / "meta" / "info.json").read_text())["acn"]["paired"] is False


def test_falls_end_the_episode_and_are_marked(tmp_path):
    """A weak PD cannot hold the A1 up: it falls, the episode is kept and marked."""
    from acn.sim.backends import SimConfig

    cfg = CollectConfig(target="mujoco", policy="stand", episodes=1, seconds=3.0, sim=SimConfig(kp=2.0, kd=0.1))
    path = record(cfg, tmp_path / "falls")
    ds = load(path)
    frames = ds.hf_dataset.with_format("numpy")[:]
    end = json.loads((path / "meta" / "info.json").read_text())["acn"]["episodes"][0]["end"]
    assert end in ("source_fell", "target_fell")
    assert ds.num_frames < 150
    assert bool(frames["next.done"][-1]) and not frames["next.done"][:-1].any()
    assert bool(frames["next.fallen"][-1]) or bool(frames["target.next.fallen"][-1])


def test_a_blow_up_cuts_the_episode_and_keeps_the_dataset_valid(tmp_path):
    from acn.sim.backends import SimConfig

    cfg = CollectConfig(target="mujoco", policy="trot", episodes=2, seconds=0.5,
                        sim=SimConfig(physics_dt=0.005, substeps=4, kp=300.0, kd=0.0, torque_limit=1e7))
    path = record(cfg, tmp_path / "blowup")  # an explicit stiff PD at 200 Hz: MuJoCo blows up
    meta = json.loads((path / "meta" / "info.json").read_text())["acn"]
    assert [e["end"] for e in meta["episodes"]] == ["target_diverged", "target_diverged"]
    ds = load(path)
    assert 0 < ds.num_frames < 2 * 25
    frames = ds.hf_dataset.with_format("numpy")[:]
    assert np.isfinite(frames["target.next.observation.state"]).all()


def test_nothing_is_written_when_every_episode_blows_up_at_once(tmp_path):
    from acn.errors import UserError
    from acn.sim.backends import SimConfig

    cfg = CollectConfig(target="mujoco", policy="trot", episodes=1, seconds=0.5,
                        sim=SimConfig(physics_dt=0.005, substeps=4, kp=1500.0, kd=0.0, torque_limit=1e7))
    with pytest.raises(UserError, match="nothing"):
        record(cfg, tmp_path / "empty")
    assert not list(tmp_path.iterdir())


def test_existing_output_is_refused_and_overwrite_replaces_it(tmp_path, small_config):
    out = tmp_path / "x"
    out.mkdir()
    from acn.errors import UserError

    with pytest.raises(UserError, match="exists"):
        record(small_config, out)
    path = record(CollectConfig(target="mujoco", episodes=1, seconds=0.1), out, overwrite=True)
    assert load(path).num_episodes == 1
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left


def _collect_cmd(out: Path, episodes: int) -> list[str]:
    return [sys.executable, "-m", "acn.cli", "--target", "mujoco", "--episodes", str(episodes), "--seconds", "1",
            "--out", str(out)]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_interrupt_keeps_finished_episodes_as_a_valid_dataset(tmp_path, sig, interruptible):
    out = tmp_path / "interrupted"
    proc = subprocess.Popen(_collect_cmd(out, 200), stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "PYTHONUNBUFFERED": "1"})
    for line in proc.stderr:  # wait for the second finished episode
        if line.startswith("episode 2/"):
            break
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    ds = load(out)
    assert 2 <= ds.num_episodes < 200
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_interrupt_before_any_episode_leaves_nothing(tmp_path):
    out = tmp_path / "nothing"
    proc = subprocess.Popen(_collect_cmd(out, 5), stderr=subprocess.PIPE, text=True)
    time.sleep(0.5)  # still importing or simulating the first episode
    proc.send_signal(signal.SIGTERM)
    proc.communicate(timeout=120)
    assert proc.returncode != 0
    assert not out.exists()
    assert not list(tmp_path.iterdir())
