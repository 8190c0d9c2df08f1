"""Consistency checks of robot logs (acn.measurements.checks): units, signs, frames, conventions.

Logs from ``tests/robot_log.py`` (MuJoCo stepped directly, sensor noise), corrupted the way
logs from other code are: each corruption must be named, a consistent log must give nothing.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pytest
from robot_log import LogSpec, simulate, welded_payload
from test_import import CONTROL

from acn.measurements.checks import LAG_Z, check, lag
from acn.measurements.data import load_measurements
from acn.sim.robot import STANCE
from acn.sim.rotations import rpy_to_matrices, rpy_to_quat
from acn.sim.state import GROUPS, JOINT_NAMES, STATE_NAMES


@pytest.fixture(scope="module")
def rows():
    return simulate(LogSpec(seconds=2.0, episodes=2, seed=7, noise=1.0))


def _episodes(c: dict) -> list:
    s = np.column_stack([c[n] for n in STATE_NAMES])
    a = np.column_stack([c[f"action.{j}"] for j in JOINT_NAMES])
    return [(s[c["episode_index"] == e], a[c["episode_index"] == e][:-1]) for e in np.unique(c["episode_index"])]


def _yawed(c: dict, angle: float = 1.2) -> None:
    """The whole log turned about the vertical (same physics): body and world frames now differ."""
    x, y = c["base_pos_x"].copy(), c["base_pos_y"].copy()
    c["base_pos_x"], c["base_pos_y"] = np.cos(angle) * x - np.sin(angle) * y, np.sin(angle) * x + np.cos(angle) * y
    c["base_yaw"] = c["base_yaw"] + angle


def _in_world(c: dict, group: str) -> None:
    rot = rpy_to_matrices(np.column_stack([c[n] for n in GROUPS["base_rpy"]]))
    v = np.einsum("nij,nj->ni", rot, np.column_stack([c[n] for n in GROUPS[group]]))
    for k, n in enumerate(GROUPS[group]):
        c[n] = v[:, k]


def _scale(names, factor):
    def change(c):
        for n in names:
            c[n] = c[n] * factor
    return change


def _swap(a: str, b: str):
    def change(c):
        c[a], c[b] = c[b].copy(), c[a].copy()
    return change


def _offsets(c):
    for k, j in enumerate(JOINT_NAMES):
        c[f"action.{j}"] = c[f"action.{j}"] - STANCE[k]


def _shift(name, value):
    def change(c):
        c[name] = c[name] + value
    return change


def _held(names, every: int):
    """A sensor ``every`` times slower than the log: its reading held for ``every`` rows."""
    def change(c):
        for n in names:
            c[n] = c[n][np.arange(len(c[n])) // every * every]
    return change


def _low_passed(names, tau: float, dt: float = 1 / 50):
    """Readings low-pass filtered by the logger (first order, time constant ``tau`` s, per episode)."""
    def change(c):
        alpha = dt / (tau + dt)
        for n in names:
            v = c[n].copy()
            for t in range(1, len(v)):
                if c["episode_index"][t] == c["episode_index"][t - 1]:
                    v[t] = v[t - 1] + alpha * (c[n][t] - v[t - 1])
            c[n] = v
    return change


def _late(names):
    """Readings one row late (a sensor read before the positions, in the previous cycle)."""
    def change(c):
        for n in names:
            c[n] = np.r_[c[n][:1], c[n][:-1]]
    return change


def _level_in_degrees(c):
    """A trunk level within ~1.6 degrees (roll and pitch, and their rates, a tenth of the log's),
    its Euler angles logged in degrees: read as rad they stay within +-pi/2."""
    for n in ("base_roll", "base_pitch", "base_angvel_x", "base_angvel_y"):
        c[n] = c[n] * 0.1
    for n in GROUPS["base_rpy"]:
        c[n] = c[n] * 180 / np.pi
    assert np.abs(c["base_pitch"]).max() < np.pi / 2


CALVES = [f"{j}_{k}" for j in JOINT_NAMES if "calf" in j for k in ("pos", "vel")] + \
    [f"action.{j}" for j in JOINT_NAMES if "calf" in j]

CORRUPTIONS = {
    "joint speeds in deg/s": (_scale(GROUPS["joint_vel"], 180 / np.pi), "every joint_vel channel", "deg/s"),
    "two velocity columns swapped": (_swap("FR_thigh_vel", "FL_thigh_vel"), "FR_thigh_vel follows", "mixed up"),
    "angular velocity in the world frame": (lambda c: (_yawed(c), _in_world(c, "base_angvel")), "base_angvel",
                                            "--angvel-frame world"),
    "linear velocity in the world frame": (lambda c: (_yawed(c), _in_world(c, "base_linvel")), "base_linvel",
                                           "--linvel-frame world"),
    "calf angles of the opposite sign": (_scale(CALVES, -1), "calf_pos", "opposite sign"),
    "trunk height in mm": (_scale(["base_pos_z"], 1000), "base_pos_z", "mm?"),
    "ground 5 cm below z = 0": (_shift("base_pos_z", 0.05), "above the ground", "another zero"),
    "gravity removed from the accelerometer": (_shift("imu_acc_z", -9.81), "accelerometer", "gravity removed"),
    "actions as offsets from the stance": (_offsets, "action.FR_thigh", "offsets from a nominal pose"),
    "contact forces instead of flags": (_scale(GROUPS["contact"], 80.0), "contact", "0/1 flags"),
    "an IMU at half the log's rate": (_held(GROUPS["imu_acc"] + GROUPS["base_angvel"], 2),
                                      "base_angvel, imu_acc repeat the previous row's values exactly",
                                      "slower than the log"),
    "joint velocities low-pass filtered": (_low_passed(GROUPS["joint_vel"], 0.02), "the readings of every joint_vel "
                                           "channel lag the motion", "derives them from the positions"),
    "a gyroscope one row late": (_late(GROUPS["base_angvel"]), "every base_angvel channel lag the motion",
                                 "read at another time"),
    "trunk angles in degrees": (_scale(GROUPS["base_rpy"], 180 / np.pi), "base_pitch reaches", "degrees?"),
    "a level trunk's angles in degrees": (_level_in_degrees, "Euler angles read as DEGREES", "degrees?"),
}


def test_consistent_logs_have_no_findings(rows):
    assert check(_episodes(rows), 1 / 50) == []
    turned = {k: v.copy() for k, v in rows.items()}
    _yawed(turned)
    assert check(_episodes(turned), 1 / 50) == []
    fast = simulate(LogSpec(seconds=1.0, episodes=1, seed=8, noise=3.0, control_hz=200))
    assert check(_episodes(fast), 1 / 200) == []


def test_a_lag_is_read_from_the_integrated_readings_not_from_the_pd_response():
    """Under twice the attitude feedback at 200 Hz the joints move fast between rows: a lag
    estimated from the PD response (the central rate of the angles over four rows against the
    reading) reads 12.9 ms on this consistent log and would name it. Integrating the readings over
    the span reads ~1 ms, and a real 10 ms low-pass filter 10 ms."""
    spec = LogSpec(seconds=5.0, episodes=2, seed=100, noise=1.0, feedback=2.0, control_hz=200)
    consistent = _episodes(simulate(spec))
    for group in ("joint_vel", "base_angvel"):
        tau, _ = lag(consistent, 1 / 200, group)
        assert abs(tau) < 0.002, (group, tau)
    assert "velocity_lag" not in {f.check for f in check(consistent, 1 / 200)}
    filtered = _episodes(simulate(replace(spec, velocity_filter=0.01)))
    tau, z = lag(filtered, 1 / 200, "joint_vel")
    assert abs(tau - 0.01) < 0.001 and z > LAG_Z, (tau, z)
    assert [f.channels for f in check(filtered, 1 / 200) if f.check == "velocity_lag"] == [GROUPS["joint_vel"]]


def test_a_hopping_robot_that_pitches_in_flight_has_a_consistent_accelerometer():
    """Level while its legs push (large specific force), pitched up to 0.87 rad while it flies: the
    accelerometer's mean over the rows near level reads 13.0 m/s^2 up, which a check on those rows
    alone would name. Gravity as the logged roll and pitch turn it into the trunk frame, over
    every row, is what it matches."""
    hop = simulate(LogSpec(seconds=4.0, episodes=2, seed=105, controller="hop", gait_speed=1.2))
    assert np.abs(hop["base_pitch"]).max() > 0.5
    assert check(_episodes(hop), 1 / 50) == []


def test_a_robot_that_falls_onto_its_back_is_not_a_convention_error():
    # The open-loop pace gait flips the robot within 2 s (benchmarks/diagnose_cases.py's "nominal
    # (pace)" log): the trunk then lies 6 cm high for most rows, in the right units and frame.
    fallen = simulate(LogSpec(seconds=6.0, episodes=1, seed=708, controller="pace"))
    assert np.median(fallen["base_pos_z"]) < 0.08 and abs(fallen["base_roll"][-1]) > 3.0  # on its back
    assert check(_episodes(fallen), 1 / 50) == []


def test_a_robot_that_collapses_folding_its_legs_past_their_limits_has_the_right_zero():
    # A 3.5 kg payload behind the trunk's centre under a feedback controller (benchmarks/
    # diagnose_cases.py's "payload 3.5 kg" log with --feedback 1): the robot collapses and its
    # calves fold past the URDF's -2.70 rad in most rows. Joint ranges and targets are checked
    # while the robot is upright, where a joint with its median inside its range is a joint pressed
    # past a soft limit, not a convention (checked over every row, this log would read "another
    # zero?" and "offsets from a nominal pose").
    collapsed = simulate(LogSpec(seconds=4.0, episodes=1, seed=2, noise=1.0, feedback=1.0,
                                 spec_edit=welded_payload(3.5, [-0.1, 0.0, 0.1])))
    calves = np.column_stack([collapsed[f"{leg}_calf_pos"] for leg in ("FR", "FL", "RR", "RL")])
    assert collapsed["base_pos_z"][-1] < 0.1 and (calves < -2.75).mean(0).max() > 0.5
    assert check(_episodes(collapsed), 1 / 50) == []


@pytest.mark.parametrize("name", list(CORRUPTIONS))
def test_each_corruption_is_named(rows, name):
    change, where, what = CORRUPTIONS[name]
    c = {k: v.copy() for k, v in rows.items()}
    change(c)
    found = [f.message for f in check(_episodes(c), 1 / 50)]
    assert any(where in m and what in m for m in found), found


def test_import_converts_a_quaternion_and_world_velocities_and_records_findings(tmp_path, rows, acn):
    c = {k: v.copy() for k, v in rows.items()}
    _yawed(c)
    want = np.column_stack([c[n] for n in STATE_NAMES])
    _in_world(c, "base_linvel")
    x, y, z, w = rpy_to_quat(np.column_stack([c.pop(n) for n in GROUPS["base_rpy"]]).T)
    c.update(base_quat_w=w, base_quat_x=x, base_quat_y=y, base_quat_z=z)
    pacsv.write_csv(pa.table(c), tmp_path / "log.csv")
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "ok"), "--linvel-frame", "world", *CONTROL)
    assert r.returncode == 0 and "check (" not in r.stdout, r.stdout + r.stderr
    m = load_measurements(tmp_path / "ok")
    ep0 = want[c["episode_index"] == 0][:-1]
    np.testing.assert_allclose(m.state[: len(ep0)], ep0, atol=2e-5)  # float32 storage
    # Without the frame flag: imported as it is, the finding printed and kept in the metadata.
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "as_is"), *CONTROL)
    assert r.returncode == 0 and "check (velocities): base_linvel" in r.stdout and "--linvel-frame world" in r.stdout
    info = json.loads((tmp_path / "as_is" / "meta" / "info.json").read_text())["acn"]["import"]
    assert info["checks"] and info["checks"][0]["channels"] == list(GROUPS["base_linvel"])
    assert "orders its quaternion x, y, z, w" in r.stdout  # a finding on a quaternion log: the order is suspect too
    # A quaternion in x, y, z, w order under the w, x, y, z names: the checks see it, and the order is named.
    c.update(base_quat_w=x, base_quat_x=y, base_quat_y=z, base_quat_z=w)
    pacsv.write_csv(pa.table(c), tmp_path / "xyzw.csv")
    r = acn("import", str(tmp_path / "xyzw.csv"), "--out", str(tmp_path / "xyzw"), "--linvel-frame", "world", *CONTROL)
    assert r.returncode == 0 and "check (" in r.stdout and "map base_quat_w to its last component" in r.stdout, r.stdout


def test_timestamps_in_ms_and_bad_quaternions_are_refused_in_one_line(tmp_path, rows, acn):
    c = {k: v.copy() for k, v in rows.items()}
    c["timestamp"] = c["timestamp"] * 1000
    pacsv.write_csv(pa.table(c), tmp_path / "ms.csv")
    q = {k: v.copy() for k, v in rows.items() if k not in GROUPS["base_rpy"]}
    q.update(base_quat_w=np.full(len(q["timestamp"]), 2.0), base_quat_x=0 * q["timestamp"],
             base_quat_y=0 * q["timestamp"], base_quat_z=0 * q["timestamp"])
    pacsv.write_csv(pa.table(q), tmp_path / "quat.csv")
    for log, message in (("ms.csv", "timestamps in ms"), ("quat.csv", "not a unit quaternion")):
        r = acn("import", str(tmp_path / log), "--out", str(tmp_path / "ds"), *CONTROL)
        assert r.returncode == 2 and message in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
        assert not (tmp_path / "ds").exists()


def test_a_physical_effect_the_checks_see_is_left_to_the_diagnosis():
    """Encoder zeros off by 2-7 degrees put stance feet off the ground: the finding says it may be
    the catalogue's encoder_offset, and a diagnosis that names it does not call the data broken."""
    from acn.diagnosis.pipeline import findings_note

    offsets = np.array([0.05, -0.08, 0.1, -0.04, 0.06, -0.12, 0.03, 0.09, -0.07, -0.1, 0.04, 0.08])
    found = check(_episodes(simulate(LogSpec(seconds=4.0, episodes=2, seed=9, noise=1.0, encoder_offset=offsets))),
                  1 / 50)
    assert [f.check for f in found] == ["stance_feet"] and "encoder_offset" in found[0].may_be, found
    assert "encoder_offset" in found[0].message
    assert "fix the data first" not in findings_note(found, ("encoder_offset",))
    assert "what encoder_offset does too" in findings_note(found, ("encoder_offset",))
    assert "fix the data first" in findings_note(found, ("joint_damping",))
    assert findings_note([], ()) == ""
