"""acn-view: the .rrd read back with Rerun's own dataframe API holds what the dataset holds.

Real data (the session's small paired PyBullet -> MuJoCo dataset, MuJoCo measurements with a
hidden effect, an imported robot log lacking channels), real MuJoCo kinematics and
re-simulation, real Rerun files; the corrector is a real frozen ``Corrector`` (fresh, so
F = 0, or with a constant correction).
"""

from __future__ import annotations

import contextlib
import io

import mujoco
import numpy as np
import pytest
import rerun as rr
import torch

from acn.sim.state import FOOT_NAMES, GROUPS, JOINT_NAMES, STATE_NAMES
from conftest import load

LINKS = ("trunk", *(f"{leg}_{part}" for leg in FOOT_NAMES for part in ("hip", "upper", "lower")))


def make_corrector(directory, bias: float = 0.0, **config_changes):
    """A frozen corrector with F(s, a) = bias on every joint, saved to ``directory``; then
    ``config_changes`` are written into its config.json (to make foreign correctors)."""
    import json

    from acn.corrector.card import CorrectorCard
    from acn.corrector.corrector import Corrector
    from acn.weights import CONFIG

    model = Corrector(CorrectorCard.untrained("mujoco-jacobian", hidden=16, layers=1))
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
    from acn.sim.backends import SimConfig
    from acn.sim.backends.mujoco_backend import build_spec

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
    from acn.corrector.corrector import Corrector
    from acn.viz.trajectories import corrected_target, recorded_episode

    frames = load_frames(small_dataset)
    episode = recorded_episode(frames, 0)
    corrected = corrected_target(frames, episode, Corrector.load(make_corrector(tmp_path / "c", bias=0.1)))
    target = episode.trajectory("target").state
    np.testing.assert_allclose(corrected.state[0], target[0], atol=1e-6)  # same start
    assert np.abs(corrected.state[10:, 6:18] - target[10:, 6:18]).max() > 0.05  # a + 0.1 moves the joints


def test_a_corrector_fitted_on_top_of_effects_runs_on_a_target_with_them(small_dataset, tmp_path):
    """acn-fit --model: the view re-simulates the target the corrector was fitted for (here a
    zero correction on a ground with a 0.06 s time constant: the robot sinks about 12 mm)."""
    from acn.datasets.reader import load_frames
    from acn.corrector.corrector import Corrector
    from acn.viz.trajectories import corrected_target, recorded_episode

    effects = [{"name": "ground_softness", "params": {"timeconst": 0.06}}]
    corrector = Corrector.load(make_corrector(tmp_path / "c", training_data={"target_effects": effects}))
    frames = load_frames(small_dataset)
    episode = recorded_episode(frames, 0)
    corrected = corrected_target(frames, episode, corrector)
    assert corrected.label == "mujoco + ground_softness(timeconst=0.06) corrected", corrected.label
    sink = episode.trajectory("target").state[20:, 2] - corrected.state[20:, 2]  # trunk height, m
    assert 0.005 < float(np.median(sink)) < 0.02, np.median(sink)


def test_unpaired_dataset_and_default_output(tmp_path, monkeypatch):
    from acn.datasets.record import record
    from acn.sim.collector import CollectConfig
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
    from acn.sim.robot import STANDING_HEIGHT
    from acn.sim.state import SLICES
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


def test_bad_input_is_one_line_and_exit_2(small_dataset, tmp_path, capsys):
    assert "is not a LeRobot dataset" in _view_error(capsys, str(tmp_path))
    assert "does not exist" in _view_error(capsys, str(tmp_path / "missing"))
    assert "episode 5 does not exist" in _view_error(capsys, str(small_dataset), "--episodes", "0,5")
    assert "comma-separated" in _view_error(capsys, str(small_dataset), "--episodes", "first")
    other = make_corrector(tmp_path / "other", input_channels=["base_pos_z", "wheel_speed"])
    assert "other state channels" in _view_error(capsys, str(small_dataset), "--corrector", str(other))
    torque = make_corrector(tmp_path / "torque", training_data={"action_mode": "torque"})
    assert "torque-mode" in _view_error(capsys, str(small_dataset), "--corrector", str(torque))
    assert "not a corrector directory" in _view_error(capsys, str(small_dataset), "--corrector", str(tmp_path))
    assert not list(tmp_path.glob("*.rrd")) and not list(tmp_path.glob(".*partial*"))


# ----- the diagnosis view (--model, --diagnosis) -------------------------------------------------
DAMPING = 0.5  # N m s/rad, the hidden effect and the model's


def diagnosis_json() -> dict:
    """An ``acn-diagnose --json`` result with the documented keys the view reads."""
    return {"verdict": "effect", "reason": "joint_damping explains 97% of the error above the noise floor",
            "where": {"summary": "At one step the model is worst in joint_vel; the error grows with joint speed."},
            "ranking": [{"name": "joint_damping", "explained": 0.97, "significant": True},
                        {"name": "armature", "explained": 0.1, "significant": False}],
            "added": [{"name": "joint_damping", "headline_before": 0.21, "headline_after": 0.01}],
            "decisions": [{"rule": "greedy", "outcome": "joint_damping added", "reported": True,
                           "sentence": "joint_damping added (shared): explains 97% of the error above the noise floor"},
                          {"rule": "greedy", "outcome": "armature added", "reported": False,
                           "sentence": "armature added in another chain"}],
            "data_checks": [{"check": "contacts", "channels": ["FR_contact"],
                             "message": "FR_contact should be 0/1 flags (1: touching the ground) but reach 80"}],
            "limits": [{"effect": "joint_friction", "parameter": "value", "unit": "N m", "limit": 0.25,
                        "realistic_missable": "0.1..0.25", "inert": False,
                        "one_joint": {"effect": "joint_friction", "parameter": "value", "unit": "N m", "limit": 0.9,
                                      "realistic_missable": "all of it", "inert": False, "joint": "FR_hip"}},
                       {"effect": "armature", "parameter": "value", "unit": "kg m^2", "limit": 0.002,
                        "realistic_missable": "none", "inert": False}]}


@pytest.fixture(scope="module")
def hidden(tmp_path_factory):
    """MuJoCo measurements with hidden joint damping, the model with that effect, its diagnosis,
    and ``acn-view MEASURED --model MODEL.json --diagnosis D.json --save`` of them."""
    import json

    from acn.cli import view_main
    from acn.datasets.record import record
    from acn.sim.collector import CollectConfig
    from acn.sim.effects import AppliedEffect, Model, get_effect

    tmp = tmp_path_factory.mktemp("diagnosis")
    damping = AppliedEffect(get_effect("joint_damping"), {"value": np.full(12, DAMPING)})
    data = record(CollectConfig(source="mujoco", target=None, policy="excite", episodes=1, seconds=1.0, seed=1,
                                hidden_effects=[damping]), tmp / "hidden")
    model = Model("mujoco", [damping]).save(tmp / "hidden.model.json")
    (tmp / "hidden.diagnosis.json").write_text(json.dumps(diagnosis_json()))
    out = tmp / "hidden.rrd"
    with contextlib.redirect_stdout(io.StringIO()):
        assert view_main([str(data), "--model", str(model), "--diagnosis", str(tmp / "hidden.diagnosis.json"),
                          "--save", str(out)]) == 0
    return data, model, rr.dataframe.load_recording(out)


def one_step(data, model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Independently: the model set to every measured state, the measured action applied.
    Returns (frame of the prediction, measured s_{t+1}, predicted s_{t+1})."""
    from acn.measurements.data import load_measurements
    from acn.sim.effects import Model
    from acn.sim.resim import Resimulator

    m = load_measurements(data)
    model = Model.load(model)
    with Resimulator(model.backend, model.sim_config(m.control)) as sim:
        pred = sim.run(m.state, m.action, m.previous_actions(np.arange(len(m)), 4))
    assert not pred.diverged.any()
    return m.frame + 1, m.next_state, pred.state[:, 0]


def test_the_model_joint_series_is_its_one_step_prediction(hidden):
    data, model, recording = hidden
    frame, measured, predicted = one_step(data, model)
    t = recording.view(index="frame", contents="/episode_000/joints/**").select().read_all()
    logged_frames = t.column("frame").to_numpy()
    assert set(frame) <= set(logged_frames) and 0 in logged_frames  # measured from frame 0, the model from 1
    at = np.searchsorted(logged_frames, frame)
    for j, joint in enumerate(JOINT_NAMES):
        k = STATE_NAMES.index(f"{joint}_pos")
        np.testing.assert_allclose(series(t, f"/episode_000/joints/{joint}/model")[at], predicted[:, k],
                                   atol=1e-9, err_msg=joint)
        assert np.isnan(series(t, f"/episode_000/joints/{joint}/model")[0])  # no prediction of frame 0
    # the model's robot is drawn too, without contacts (they are not predicted)
    entities = {c.entity_path for c in recording.schema().component_columns()}
    assert {f"/episode_000/robots/model/links/{link}" for link in LINKS} <= entities
    assert "/episode_000/robots/model/contacts" not in entities and "/episode_000/gait/model/FR" not in entities
    assert "/episode_000/divergence/model/joint_pos" in entities


def test_residuals_per_joint_are_measured_minus_predicted(hidden):
    data, model, recording = hidden
    frame, measured, predicted = one_step(data, model)
    t = recording.view(index="frame", contents="/episode_000/residual/**").select().read_all()
    at = np.searchsorted(t.column("frame").to_numpy(), frame)
    for group in ("joint_pos", "joint_vel"):
        for j, joint in enumerate(JOINT_NAMES):
            k = STATE_NAMES.index(f"{joint}_{group.split('_')[1]}")
            np.testing.assert_allclose(series(t, f"/episode_000/residual/{group}/{joint}")[at],
                                       measured[:, k] - predicted[:, k], atol=1e-9, err_msg=f"{group} {joint}")


def test_the_error_falls_when_the_hidden_effect_is_added(hidden):
    _, _, recording = hidden
    t = recording.view(index="frame", contents="/episode_000/effects/**").select().read_all()
    nominal = series(t, "/episode_000/effects/0_nominal")
    damped = series(t, "/episode_000/effects/1_joint_damping")
    assert np.isfinite(nominal[1:]).all() and np.isfinite(damped[1:]).all()
    rms = lambda x: np.sqrt(np.nanmean(x ** 2))  # noqa: E731
    assert rms(nominal) > 0.05  # the nominal model misses the damping
    assert rms(damped) < 0.01 * rms(nominal)  # the right effect at the right value: float32 storage is left
    text = recording.view(index=None, contents="/episode_000/diagnosis").select_static().read_all()
    doc = column(text, "/episode_000/diagnosis", "TextDocument:text")[0]
    assert "verdict **effect**" in doc and "the error grows with joint speed" in doc
    assert "| 1 | joint_damping | 97% | yes |" in doc and f"{rms(nominal):.4f}" in doc
    assert "**Data checks**" in doc and "- FR_contact should be 0/1 flags" in doc
    # how it decided: the decisions the diagnosis reports, not the other searches'
    assert "1. joint_damping added (shared): explains 97%" in doc and "another chain" not in doc
    # --limits: what the log could miss, the effects whose whole realistic range it shows left out
    assert "- joint_friction value: shown from 0.25 N m, realistic values it could miss: 0.1..0.25" in doc
    assert "armature" not in doc.split("**What this log could miss**")[1]
    # --limits-per-joint: on the one joint the log shows least
    assert "- joint_friction value on FR_hip: shown from 0.9 N m, realistic values it could miss: all of it" in doc


def test_an_imported_log_lacking_channels_is_compared_on_what_it_has(tmp_path):
    """No IMU, no trunk linear velocity, no joint velocities: velocities are derived to start the
    nominal model, and only measured channels get residuals."""
    from robot_log import LogSpec, write_log

    from acn.cli import import_main, view_main

    dropped = GROUPS["imu_acc"] + GROUPS["base_linvel"] + GROUPS["joint_vel"]
    write_log(tmp_path / "log.csv", LogSpec(seconds=1.0, episodes=1, seed=2, drop=dropped))
    with contextlib.redirect_stdout(io.StringIO()):
        assert import_main([str(tmp_path / "log.csv"), "--out", str(tmp_path / "log"), "--control-hz", "50",
                            "--kp", "60", "--kd", "1.5", "--torque-limit", "33.5"]) == 0
        assert view_main([str(tmp_path / "log"), "--model", "mujoco", "--save", str(tmp_path / "log.rrd")]) == 0
    rec = rr.dataframe.load_recording(tmp_path / "log.rrd")
    entities = {c.entity_path for c in rec.schema().component_columns()}
    assert {f"/episode_000/residual/joint_pos/{j}" for j in JOINT_NAMES} <= entities
    assert not any("/residual/joint_vel/" in e for e in entities)
    assert "/episode_000/joints/FR_calf/model" in entities and "/episode_000/effects/0_nominal" in entities
    t = rec.view(index="frame", contents="/episode_000/effects/**").select().read_all()
    assert np.isfinite(series(t, "/episode_000/effects/0_nominal")[1:]).all()
    doc = column(rec.view(index=None, contents="/episode_000/diagnosis").select_static().read_all(),
                 "/episode_000/diagnosis", "TextDocument:text")[0]
    assert "Not measured, not compared: imu_acc (all 3)" in doc and "joint_vel (all 12)" in doc


def test_a_log_without_trunk_orientation_cannot_be_predicted_one_line(tmp_path, capsys):
    """Without the trunk's position leg odometry estimates it (``test_odometry``); without its
    orientation nothing can: one line."""
    from robot_log import LogSpec, write_log

    from acn.cli import import_main

    no_trunk = GROUPS["base_pos"] + GROUPS["base_rpy"]
    write_log(tmp_path / "log.csv", LogSpec(seconds=0.5, episodes=1, seed=2, drop=no_trunk))
    assert import_main([str(tmp_path / "log.csv"), "--out", str(tmp_path / "log"), "--control-hz", "50", "--kp", "60",
                        "--kd", "1.5", "--torque-limit", "33.5"]) == 0
    capsys.readouterr()
    assert "needs the trunk's orientation" in _view_error(capsys, str(tmp_path / "log"), "--model", "mujoco")


def test_bad_model_or_diagnosis_is_one_line_and_exit_2(small_dataset, tmp_path, capsys):
    import json

    def write(name: str, content) -> str:
        (tmp_path / name).write_text(content if isinstance(content, str) else json.dumps(content))
        return str(tmp_path / name)

    ds = str(small_dataset)
    unknown_key = write("extra.json", {"backend": "mujoco", "effects": [], "friction": 1})
    assert "unknown key(s) 'friction'" in _view_error(capsys, ds, "--model", unknown_key)
    bullet = write("bullet.json", {"backend": "bullet"})
    assert "unknown backend 'bullet'" in _view_error(capsys, ds, "--model", bullet)
    assert "neither a backend" in _view_error(capsys, ds, "--model", "drake")
    assert "does not exist" in _view_error(capsys, ds, "--model", str(tmp_path / "none.json"))
    good = write("good.json", {"backend": "mujoco"})
    assert "--diagnosis needs --model" in _view_error(capsys, ds, "--diagnosis", write("d.json", diagnosis_json()))
    for bad in ("{not json", {"verdict": "maybe", "reason": "", "ranking": [], "where": {"summary": ""}},
                {**diagnosis_json(), "ranking": [{"name": "armature"}]}, [1, 2]):
        message = _view_error(capsys, ds, "--model", good, "--diagnosis", write("bad.json", bad))
        assert "is not valid JSON" in message or "is not an acn-diagnose --json result" in message, message
    assert "does not exist" in _view_error(capsys, ds, "--model", good, "--diagnosis", str(tmp_path / "no.json"))
    assert not list(tmp_path.glob("*.rrd")) and not list(tmp_path.glob(".*partial*"))
