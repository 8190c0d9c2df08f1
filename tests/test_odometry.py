"""Leg odometry: a log without motion capture (no trunk position or linear velocity) is
completed from the joints and the IMU, and diagnosed like a full one."""

from __future__ import annotations

import numpy as np
import pytest
from robot_log import LogSpec, write_log

from acn.measurements.importer import ImportConfig, import_log
from acn.measurements.data import fill_derived, load_measurements
from acn.measurements.odometry import Odometry, standing_sink
from acn.sim import frames
from acn.sim.state import GROUPS, SLICES, STATE_NAMES

NO_MOCAP = tuple(GROUPS["base_pos"] + GROUPS["base_linvel"])


def _errors(estimated: np.ndarray, true: np.ndarray) -> tuple[float, float]:
    """(median |height error| m, median |velocity error| m/s) of (height, velocity) pairs."""
    (h, v, _), (th, tv) = estimated, true
    return float(np.median(np.abs(h - th))), float(np.median(np.linalg.norm(v - tv, axis=1)))


def test_odometry_recovers_the_trunk_from_the_joints_imu_and_contacts(tmp_path):
    """PyBullet trot after its first second, from the joints, the IMU and the contact flags: the
    height to the micrometre, the velocity with a median error of 2.5 cm/s (measured; a flagged
    foot that drags as it lifts off moves, up to 0.5 m/s); without the flags, the feet near the
    ground are taken: 9 cm/s (a swing foot just above the ground moves) against a spread of
    0.42 m/s."""
    from acn.datasets.record import record
    from acn.sim.collector import CollectConfig

    path = record(CollectConfig(source="pybullet", target=None, policy="trot", episodes=1, seconds=3.0, seed=3),
                  tmp_path / "trot")
    m = load_measurements(path)
    states = m.state[m.frame >= 50]
    odometry = Odometry()
    true = (states[:, SLICES["base_pos"].start + 2], states[:, SLICES["base_linvel"]])
    spread = float(np.linalg.norm(states[:, SLICES["base_linvel"]].std(0)))
    height, velocity = _errors(odometry.estimate(states), true)
    assert height < 0.001 and velocity < 0.05, (height, velocity)
    blind = states.copy()
    blind[:, SLICES["contact"]] = np.nan
    height, velocity = _errors(odometry.estimate(blind), true)
    assert height < 0.005 and velocity < 0.5 * spread, (height, velocity, spread)


def test_a_fallen_robot_rests_on_its_trunk(tmp_path):
    """The lowest point of any collision geom touches the ground, not only a foot: a robot that
    fell on its back (the feet up) gets the trunk's height from the trunk's box. Only feet sink
    into the model's ground: the trunk resting on the floor does not start a foot's sink per point
    deep (that would put it 4x the standing sink, 5.1 mm, too low)."""
    write_log(tmp_path / "log.csv", LogSpec(controller="pace", seconds=4.0, episodes=1, seed=5))
    path, _ = import_log(tmp_path / "log.csv", tmp_path / "log", ImportConfig(50, 60.0, 1.5, 33.5))
    m = load_measurements(path)
    fallen = m.state[:, SLICES["base_pos"].start + 2] < 0.15
    assert fallen.sum() >= 20  # this controller topples the robot
    states = m.state[fallen]
    true = (states[:, SLICES["base_pos"].start + 2], states[:, SLICES["base_linvel"]])
    height, velocity = _errors(Odometry().estimate(states), true)
    assert height < 0.005 and velocity < 0.05, (height, velocity)
    contact = [STATE_NAMES.index(n) for n in GROUPS["contact"]]
    on_its_back = states[states[:, contact].sum(axis=1) == 0]
    assert len(on_its_back) >= 20
    sunk, _, share = Odometry().estimate(on_its_back, standing_sink("mujoco"))
    below = np.median(on_its_back[:, SLICES["base_pos"].start + 2] - sunk)
    assert np.all(share == 0.0) and abs(below) < 0.001, below


def test_a_flagged_foot_above_the_lowest_point_does_not_carry_the_robot(tmp_path):
    """A falling robot's contact flag lags its foot's lift-off: posed on that foot, another point
    would start centimetres inside the ground (36-38 mm too low on this log, 11 rows over 5 mm).
    Flagged feet further than ``STANCE_BAND`` above the lowest point are not taken (max 22 mm: rows
    in flight)."""
    write_log(tmp_path / "log.csv", LogSpec(controller="pace", seconds=4.0, episodes=1, seed=5))
    path, _ = import_log(tmp_path / "log.csv", tmp_path / "log", ImportConfig(50, 60.0, 1.5, 33.5))
    states = load_measurements(path).state
    states = states[states[:, SLICES["contact"]].sum(axis=1) > 0]
    error = Odometry().estimate(states, standing_sink("mujoco"))[0] - states[:, SLICES["base_pos"].start + 2]
    assert len(states) >= 50 and np.max(np.abs(error)) < 0.025 and np.sum(np.abs(error) > 0.005) <= 4, error


def test_the_feet_sink_by_the_load_the_accelerometer_measures(tmp_path):
    """The feet sink in proportion to the ground's vertical force, which the accelerometer gives
    (a foot pushing off carries less than a standing share, a landing more): on a noise-free log
    of the benchmark's random controller the estimated height is closer to the true one than with
    the standing load everywhere (the accelerometer left out: 0.78 mm median error, 0.37 with it)."""
    write_log(tmp_path / "log.csv", LogSpec(controller="sines", seconds=6.0, episodes=1, seed=3))
    path, _ = import_log(tmp_path / "log.csv", tmp_path / "log", ImportConfig(50, 60.0, 1.5, 33.5))
    states = load_measurements(path).state
    states = states[states[:, SLICES["contact"]].sum(axis=1) >= 2]
    assert len(states) >= 200
    blind = states.copy()
    blind[:, SLICES["imu_acc"]] = np.nan
    true = states[:, SLICES["base_pos"].start + 2]
    err = {name: np.median(np.abs(Odometry().estimate(s, standing_sink("mujoco"))[0] - true))
           for name, s in (("measured load", states), ("standing load", blind))}
    assert err["measured load"] < 0.6 * err["standing load"] and err["measured load"] < 0.0005, err


@pytest.fixture(scope="module")
def no_mocap_log(tmp_path_factory):
    """A noisy log from code outside acn-collect with 15 ms latency, without the trunk's position
    and linear velocity, and the same log with them."""
    root = tmp_path_factory.mktemp("no_mocap")
    out = {}
    for name, drop in (("full", ()), ("blind", NO_MOCAP)):
        write_log(root / f"{name}.csv", LogSpec(noise=1.0, seed=3, latency_steps=15, drop=drop))
        out[name], report = import_log(root / f"{name}.csv", root / name, ImportConfig(50, 60.0, 1.5, 33.5))
        assert sorted(report.missing) == sorted(drop) and not report.findings
    return out


def test_a_log_without_motion_capture_is_completed_and_never_compared_on_the_estimates(no_mocap_log):
    from acn.diagnosis.problem import DiagnoseConfig, prepare
    from acn.sim.effects import Model

    blind, derived = fill_derived(load_measurements(no_mocap_log["blind"]))
    assert sorted(derived) == sorted(NO_MOCAP) and not blind.missing
    assert np.isfinite(blind.state).all() and np.isfinite(blind.next_state).all()
    full = load_measurements(no_mocap_log["full"])
    z = SLICES["base_pos"].start + 2
    standing = full.state[:, z] > 0.15
    assert np.median(np.abs(blind.state[standing, z] - full.state[standing, z])) < 0.01
    # x, y integrate the estimated velocity: row t + 1 starts where row t's next state ended
    linked = np.flatnonzero((full.episode[1:] == full.episode[:-1]))
    assert np.allclose(blind.state[linked + 1, 0:2], blind.next_state[linked, 0:2])
    problem = prepare(load_measurements(no_mocap_log["blind"]), Model.parse("mujoco"), DiagnoseConfig(horizons=(1,)))
    assert not set(problem.channel_names) & set(NO_MOCAP)  # estimates start the model; they are not evidence
    # MuJoCo's soft feet sink under the robot's weight: the trunk a model starts from sits that deep
    sink = standing_sink("mujoco")
    assert 0.0005 < sink < 0.005 and standing_sink("pybullet") < 0.0002, (sink, standing_sink("pybullet"))
    lowered = blind.state[:, z] - problem.data.state[:, z]
    assert np.all(lowered >= 0) and sink - 1e-9 <= np.median(lowered[standing]) <= 4 * sink + 1e-9  # 0: in flight


def _soft_ground(spec):
    for g in spec.geoms:   # every contact softer: MuJoCo's solref time constant 0.05 s (nominal 0.02)
        g.solref = [0.05, 1.0]


def test_without_motion_capture_each_model_starts_from_its_own_estimate(tmp_path):
    """The estimated height puts the feet as deep as the started model's ground carries them.
    On a log whose ground is soft (the feet sink 8-11 mm, nominal MuJoCo 1.3 mm), a model with
    that ground starts lower by the difference: started at the nominal sink, the soft model's
    trunk would fall through its first step, and a diagnosis would rank base_frame_offset first
    (that it ranks ground_softness first and fits it: benchmarks/diagnose_scenarios.py). Models
    with encoder offsets or another trunk frame get their own estimates too."""
    from dataclasses import replace

    from acn.sim.robot import ModelParams

    write_log(tmp_path / "log.csv", LogSpec(noise=1.0, seed=104, seconds=6.0, drop=NO_MOCAP, spec_edit=_soft_ground))
    path, _ = import_log(tmp_path / "log.csv", tmp_path / "log", ImportConfig(50, 60.0, 1.5, 33.5))
    data = load_measurements(path)
    blind, _ = fill_derived(data, "mujoco")
    rows = np.arange(len(blind))
    soft = replace(data.control, params=ModelParams(ground_timeconst=0.05))
    lower = blind.starts(rows, "mujoco", data.control) - blind.starts(rows, "mujoco", soft)
    z = SLICES["base_pos"].start + 2
    deeper = standing_sink("mujoco", soft.params) - standing_sink("mujoco")
    assert 0.005 < deeper < 0.01 and np.allclose(np.delete(lower, z, axis=1), 0.0), deeper
    assert np.allclose(lower[:, z], deeper * blind.height.share) and np.median(lower[:, z]) > deeper / 2
    assert np.array_equal(blind.starts(rows, "mujoco", data.control), blind.state)  # the nominal model: as estimated
    # a model reading the joints with offsets starts on the feet its true angles put lowest
    offsets = replace(data.control, params=ModelParams(encoder_offset=0.05))
    true = blind.state.copy()
    true[:, SLICES["joint_pos"]] -= 0.05
    estimate = Odometry().estimate(true, standing_sink("mujoco"))[0]
    assert np.allclose(blind.starts(rows, "mujoco", offsets)[:, z], estimate)
    # a model reading the trunk in a frame 6 cm above the link starts its link where the odometry put it
    frame = np.array([0.0, 0.0, 0.06, 0.0, 0.0, 0.0])
    framed = blind.starts(rows, "mujoco", replace(data.control, params=ModelParams(base_frame_offset=frame)))
    link = frames.state_in_trunk(framed, frame)
    assert np.allclose(link, blind.state) and not np.allclose(framed[:, z], blind.state[:, z])
    # a measured velocity (a reading in the frame, not an estimate of the link's) is converted as usual
    from acn.measurements.odometry import EstimatedHeight

    tilted = np.array([0.0, 0.0, 0.06, 0.05, -0.04, 0.0])
    position_only = EstimatedHeight(blind.height.share, blind.height.sink, tuple(range(3)))
    cfg = replace(data.control, params=ModelParams(base_frame_offset=tilted))
    v = SLICES["base_linvel"]
    started = position_only.starts(blind.state, rows, "mujoco", [cfg], np.zeros(len(rows), int))
    started = frames.state_in_trunk(started, tilted)
    assert np.allclose(started[:, v], frames.state_in_trunk(blind.state, tilted)[:, v])
    assert np.allclose(started[:, 0:2], blind.state[:, 0:2]) and not np.allclose(started[:, v], blind.state[:, v])


def test_the_smoother_bridges_slipping_feet_with_the_accelerometer():
    """Per-sample leg estimates with noise and a foot that drags for 5 samples: fused with the
    accelerometer's changes, the outliers are gone; without an accelerometer, a robust smoother
    of the legs alone still halves the error."""
    from acn.measurements.odometry import smooth_velocity

    rng = np.random.default_rng(0)
    dt, t = 0.02, np.arange(250) * 0.02
    true = np.stack([0.4 * np.sin(2 * t), 0.2 * np.cos(3 * t), 0.05 * np.sin(7 * t)], axis=1)   # m/s
    legs = true + rng.normal(0, 0.05, true.shape)
    legs[100:105, 0] += 0.6                                                                       # a dragging foot
    change = np.vstack([np.zeros((1, 3)), np.diff(true, axis=0)]) + rng.normal(0, dt * 0.2, true.shape)
    raw = np.abs(legs - true).mean()
    fused = np.abs(smooth_velocity(legs, change, dt) - true)
    assert fused.mean() < 0.3 * raw and fused[100:105, 0].max() < 0.05, (raw, fused.mean(), fused[100:105, 0].max())
    alone = np.abs(smooth_velocity(legs, None, dt) - true).mean()
    assert alone < 0.7 * raw, (raw, alone)


def test_acn_import_says_how_the_missing_trunk_will_be_estimated(tmp_path, capsys):
    from acn.cli import import_main

    write_log(tmp_path / "log.csv", LogSpec(seconds=0.5, episodes=1, seed=2, drop=NO_MOCAP))
    assert import_main([str(tmp_path / "log.csv"), "--out", str(tmp_path / "log"), "--control-hz", "50", "--kp", "60",
                        "--kd", "1.5", "--torque-limit", "33.5"]) == 0
    out = capsys.readouterr().out
    assert "estimates of them: base_pos by leg odometry, base_linvel by leg odometry" in out, out


def test_an_accelerometer_read_at_each_instant_is_fused_by_the_trapezoid_rule(tmp_path):
    """Samples of a known acceleration at each instant: the trapezoid rule gives the velocity's
    change to 1.3e-4 of its size where the mean rule errs by 2 %; the change is trusted less by
    dt |a_k - a_(k-1)| / sqrt(12) (``velocity_change``'s spread; exact, so 0, for the mean). On a noise-free
    log of MuJoCo's sensor without motion capture, the odometry that fuses it as read at each
    instant (``--imu-acc instant``) estimates the trunk's velocity better than the one that takes
    it for the mean over the step (median 6.4 against 8.4 cm/s, measured; 7.2 without the
    spread)."""
    from acn.measurements.odometry import velocity_change
    from acn.sim.robot import GRAVITY

    dt, t = 0.02, np.arange(100) * 0.02
    rot = np.repeat(np.eye(3)[None], len(t), axis=0)
    force = np.stack([3 * 2 * np.cos(2 * t), np.zeros_like(t), np.full_like(t, GRAVITY)], axis=1)  # v_x = 3 sin 2t
    true = np.diff(3 * np.sin(2 * t))
    (instant, spread), (mean, exact) = (velocity_change(force, rot, dt, kind) for kind in ("instant", "mean"))
    instant, mean = instant[1:], mean[1:]
    scale = np.abs(true).max()
    assert np.abs(instant[:, 0] - true).max() < 1e-3 * scale < 0.1 * np.abs(mean[:, 0] - true).max()
    assert np.allclose(instant[:, 1:], 0.0) and np.allclose(mean[:, 1:], 0.0)
    assert np.allclose(spread[1:, 0], dt * np.abs(np.diff(force[:, 0])) / np.sqrt(12.0))
    assert np.allclose(spread[:, 1:], 0.0)
    assert not exact.any()

    write_log(tmp_path / "log.csv", LogSpec(controller="sines", seconds=6.0, episodes=2, seed=101, noise=0.0,
                                            accelerometer="sensor"))
    errors = {}
    for kind in ("instant", "mean"):
        path, _ = import_log(tmp_path / "log.csv", tmp_path / kind, ImportConfig(50, 60.0, 1.5, 33.5, imu_acc=kind))
        m = load_measurements(path)
        filled, _ = fill_derived(m.without(list(NO_MOCAP)))
        standing = (m.state[:, 2] > 0.15) & (m.frame >= 10)
        lin = SLICES["base_linvel"]
        errors[kind] = float(np.median(np.linalg.norm(filled.state[standing, lin] - m.state[standing, lin], axis=1)))
    assert errors["instant"] < 0.85 * errors["mean"], errors  # measured 0.064 against 0.084
