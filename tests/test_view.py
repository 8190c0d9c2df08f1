"""acn-view: the .rrd read back with Rerun's own dataframe API holds what the dataset holds.

Real data (the session's small paired PyBullet -> MuJoCo dataset), real MuJoCo kinematics,
real Rerun files; the corrector is a real frozen ``Corrector`` (fresh, so F = 0, or with a
constant correction).
"""

from __future__ import annotations

import contextlib
import io

import mujoco
import numpy as np
import pytest
import rerun as rr
import torch

from acn.toolkit.state import FOOT_NAMES, GROUPS, JOINT_NAMES, STATE_NAMES
from conftest import load

LINKS = ("trunk", *(f"{leg}_{part}" for leg in FOOT_NAMES for part in ("hip", "upper", "lower")))


def make_corrector(directory, bias: float = 0.0, **config_changes):
    """A frozen corrector with F(s, a) = bias on every joint, saved to ``directory``; then
    ``config_changes`` are written into its config.json (to make foreign correctors)."""
    import json

    from acn.models.corrector import CONFIG, Corrector, default_config

    model = Corrector(default_config("mujoco-jacobian", hidden=16, layers=1))
    with torch.no_grad():
        model.net.action_net[-1].bias.fill_(bias)
    directory.mkdir()
    model.save(directory)
    config = json.loads((directory / CONFIG).read_text())
    (directory / CONFIG).write_text(json.dumps({**config, **config_changes}))
    return directory


def column(table, entity: str, component: str) -> list:
    """One row value per row (the first instance; None where the row has none)."""
    return [v[0] if v else None for v in table.column(f"{entity}:{component}").to_pylist()]


def series(table, entity: str) -> np.ndarray:
    return np.array([np.nan if v is None else v for v in column(table, entity, "Scalars:scalars")], dtype=float)


def episode_columns(dataset, episode: int) -> dict[str, np.ndarray]:
    rows = load(dataset).hf_dataset.with_format("numpy")[:]
    keep = rows["episode_index"] == episode
    return {k: np.asarray(v)[keep] for k, v in rows.items()}


@pytest.fixture(scope="module")
def saved(small_dataset, tmp_path_factory):
    """``acn-view DATASET --corrector ZERO --save view.rrd`` through the command's entry point."""
    from acn.cli import view_main

    tmp = tmp_path_factory.mktemp("view")
    corrector = make_corrector(tmp / "zero")
    out = tmp / "view.rrd"
    stdout = io.StringIO()
    with contextlib.redirect_stdout(stdout):
        assert view_main([str(small_dataset), "--corrector", str(corrector), "--save", str(out)]) == 0
    assert stdout.getvalue().strip().splitlines()[-1] == f"rerun {out}"
    return out


@pytest.fixture(scope="module")
def recording(saved):
    return rr.dataframe.load_recording(saved)


def test_every_entity_of_the_layout_is_there(recording):
    entities = {c.entity_path for c in recording.schema().component_columns()}
    for ep in ("/episode_000", "/episode_001"):
        for traj in ("source", "target", "corrected"):
            assert {f"{ep}/robots/{traj}/links/{link}" for link in LINKS} <= entities
            assert {f"{ep}/robots/{traj}/contacts", f"{ep}/robots/{traj}/trunk_path"} <= entities
            assert {f"{ep}/joints/{j}/{traj}" for j in JOINT_NAMES} <= entities
            assert {f"{ep}/gait/{traj}/{f}" for f in FOOT_NAMES} <= entities
        for traj in ("target", "corrected"):
            assert {f"{ep}/divergence/{traj}/{g}" for g in GROUPS} <= entities
        assert f"{ep}/divergence/source/base_pos" not in entities  # the reference has no divergence
    assert [c.name for c in recording.schema().index_columns()] == ["frame", "sim_time"]


def test_joint_series_equal_the_dataset_columns(recording, small_dataset):
    cols = episode_columns(small_dataset, 1)
    t = recording.view(index="frame", contents="/episode_001/joints/FR_thigh/**").select().read_all()
    np.testing.assert_array_equal(t.column("frame").to_numpy(), cols["frame_index"])
    np.testing.assert_allclose(t.column("sim_time").to_numpy().astype("int64") / 1e9, cols["timestamp"], atol=1e-6)
    k = STATE_NAMES.index("FR_thigh_pos")
    for traj, key in (("source", "observation.state"), ("target", "target.observation.state")):
        logged = series(t, f"/episode_001/joints/FR_thigh/{traj}")
        np.testing.assert_array_equal(logged, cols[key][:, k].astype(np.float64))


def test_link_transforms_equal_mujoco_forward_kinematics(recording, small_dataset):
    from acn.toolkit.backends import SimConfig
    from acn.toolkit.backends.mujoco_backend import build_spec

    frame = 17
    state = episode_columns(small_dataset, 0)["target.observation.state"][frame].astype(np.float64)
    model = build_spec(SimConfig()).compile()
    data = mujoco.MjData(model)
    data.qpos[:3] = state[0:3]
    mujoco.mju_euler2Quat(data.qpos[3:7], state[3:6], "XYZ")  # extrinsic roll, pitch, yaw
    for j, name in enumerate(JOINT_NAMES):
        urdf = name.replace("_thigh", "_upper_joint").replace("_calf", "_lower_joint").replace("_hip", "_hip_joint")
        data.qpos[model.jnt_qposadr[model.joint(urdf).id]] = state[6 + j]
    mujoco.mj_kinematics(model, data)
    t = recording.view(index="frame", contents="/episode_000/robots/target/links/**").filter_range_sequence(
        frame, frame).select().read_all()
    for link in LINKS:
        entity = f"/episode_000/robots/target/links/{link}"
        translation = np.array(column(t, entity, "Transform3D:translation")[0])
        x, y, z, w = column(t, entity, "Transform3D:quaternion")[0]
        body = model.body(link).id
        np.testing.assert_allclose(translation, data.xpos[body], atol=1e-6, err_msg=link)
        quat = np.array([w, x, y, z])
        assert min(np.abs(quat - data.xquat[body]).max(), np.abs(quat + data.xquat[body]).max()) < 1e-6, link


def test_the_robot_stands_on_the_floor_right_way_up(recording):
    t = recording.view(index="frame", contents="/episode_000/robots/source/**").select().read_all()
    trunk_z = np.array([p[2] for p in column(t, "/episode_000/robots/source/links/trunk", "Transform3D:translation")])
    feet = np.concatenate([np.asarray(v).reshape(-1, 3) for v in
                           t.column("/episode_000/robots/source/contacts:Points3D:positions").to_pylist() if v])
    assert len(feet) > 0
    np.testing.assert_allclose(feet[:, 2], 0.02, atol=0.01)  # foot spheres (r = 2 cm) touch z = 0
    assert np.all(trunk_z > 0.2)
    x, y, z, w = column(t, "/episode_000/robots/source/links/trunk", "Transform3D:quaternion")[0]
    assert 1 - 2 * (x * x + y * y) > 0.95  # the trunk's z axis points up


def test_corrected_target_with_zero_correction_is_the_recorded_target(recording):
    t = recording.view(index="frame", contents="/episode_000/joints/**").select().read_all()
    for joint in JOINT_NAMES:
        target = series(t, f"/episode_000/joints/{joint}/target")
        corrected = series(t, f"/episode_000/joints/{joint}/corrected")
        np.testing.assert_allclose(corrected, target, atol=1e-4)  # re-simulated from the float32 start


def test_the_corrector_runs_in_closed_loop(small_dataset, tmp_path):
    from acn.datasets.reader import load_frames
    from acn.models.corrector import Corrector
    from acn.viz.trajectories import corrected_target, recorded_episode

    frames = load_frames(small_dataset)
    episode = recorded_episode(frames, 0)
    corrected = corrected_target(frames, episode, Corrector.load(make_corrector(tmp_path / "c", bias=0.1)))
    target = episode.trajectory("target").state
    np.testing.assert_allclose(corrected.state[0], target[0], atol=1e-6)  # same start
    assert np.abs(corrected.state[10:, 6:18] - target[10:, 6:18]).max() > 0.05  # a + 0.1 moves the joints


def test_unpaired_dataset_and_default_output(tmp_path, monkeypatch):
    from acn.datasets.record import record
    from acn.toolkit.collector import CollectConfig
    from acn.viz.view import ViewConfig, view

    meas = record(CollectConfig(target=None, episodes=1, seconds=0.3, seed=2), tmp_path / "meas")
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    out = view(ViewConfig(dataset=meas))  # no display, no --save: a .rrd beside the dataset
    assert out == tmp_path / "meas.rrd" and out.is_file()
    rec = rr.dataframe.load_recording(out)
    entities = {c.entity_path for c in rec.schema().component_columns()}
    assert "/episode_000/robots/measured/links/trunk" in entities
    assert "/episode_000/joints/RL_calf/measured" in entities
    assert not any("/divergence/" in e for e in entities)
    t = rec.view(index="frame", contents="/episode_000/joints/RL_calf/measured").select().read_all()
    k = STATE_NAMES.index("RL_calf_pos")
    np.testing.assert_array_equal(series(t, "/episode_000/joints/RL_calf/measured"),
                                  episode_columns(meas, 0)["observation.state"][:, k].astype(np.float64))


def test_a_log_without_trunk_pose_or_sensors_still_shows_its_legs(small_dataset, tmp_path):
    from acn.datasets.reader import load_frames
    from acn.toolkit.robot import STANDING_HEIGHT
    from acn.toolkit.state import SLICES
    from acn.viz.trajectories import EpisodeView, Trajectory
    from acn.viz.view import write_rrd

    frames = load_frames(small_dataset)
    rows = frames.rows(0)
    state = frames.state[rows].copy()
    for group in ("base_pos", "base_rpy", "base_linvel", "imu_acc"):
        state[:, SLICES[group]] = np.nan  # what an imported robot log may lack
    state[5, SLICES["joint_pos"]] = np.nan  # one bad row: left out of the 3D view
    episode = EpisodeView(0, frames.timestamp[rows], [Trajectory("measured", "log (measured)", state,
                                                                 frames.frame[rows])], "measured")
    rec = rr.dataframe.load_recording(write_rrd([episode], tmp_path / "log.rrd"))
    t = rec.view(index="frame", contents="/episode_000/robots/measured/links/**").select().read_all()
    trunk = np.array(column(t, "/episode_000/robots/measured/links/trunk", "Transform3D:translation"))
    np.testing.assert_allclose(trunk, [[0, 0, STANDING_HEIGHT]] * (len(rows) - 1), atol=1e-6)
    assert 5 not in t.column("frame").to_pylist()


def _view_error(capsys, *argv: str) -> str:
    from acn.cli import view_main

    code = view_main(list(argv))
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


def test_bad_input_is_one_line_and_exit_2(small_dataset, tmp_path, capsys, monkeypatch):
    import json

    assert "is not a LeRobot dataset" in _view_error(capsys, str(tmp_path))
    assert "is not a dataset directory" in _view_error(capsys, str(tmp_path / "missing"))
    assert "episode 5 does not exist" in _view_error(capsys, str(small_dataset), "--episodes", "0,5")
    assert "comma-separated" in _view_error(capsys, str(small_dataset), "--episodes", "first")
    other = make_corrector(tmp_path / "other", input_channels=["base_pos_z", "wheel_speed"])
    assert "other state channels" in _view_error(capsys, str(small_dataset), "--corrector", str(other))
    torque = make_corrector(tmp_path / "torque", training_data={"action_mode": "torque"})
    assert "torque-mode" in _view_error(capsys, str(small_dataset), "--corrector", str(torque))
    assert "not a corrector directory" in _view_error(capsys, str(small_dataset), "--corrector", str(tmp_path))
    (tmp_path / "model.json").write_text(json.dumps({}))
    monkeypatch.setattr("acn.viz.view._diagnosis_available", lambda: False)
    assert _view_error(capsys, str(small_dataset), "--model", str(tmp_path / "model.json")).endswith(
        "--model needs acn-diagnose (not available yet)")
    assert not list(tmp_path.glob("*.rrd")) and not list(tmp_path.glob(".*partial*"))
