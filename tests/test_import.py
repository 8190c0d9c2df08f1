"""acn-import: robot logs (CSV/Parquet/JSON lines) from code outside acn-collect become measurement datasets."""

from __future__ import annotations

import gzip
import json

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq
import pytest
from conftest import load
from robot_log import LogSpec, simulate, write_log

from acn.measurements.importer import resolve_columns
from acn.measurements.data import fill_derived, load_measurements
from acn.sim.state import GROUPS, JOINT_NAMES, SLICES, STATE_NAMES

CONTROL = ["--control-hz", "50", "--kp", "60", "--kd", "1.5", "--torque-limit", "33.5"]


@pytest.fixture(scope="module")
def log_rows():
    return simulate(LogSpec(seconds=1.0, episodes=2, seed=5))


def test_csv_with_renamed_scaled_columns_and_a_missing_channel(tmp_path, log_rows, acn):
    """Degrees under other names are mapped back; the IMU is not logged: stored NaN, listed, not compared."""
    spec = LogSpec(seconds=1.0, episodes=2, seed=5, drop=GROUPS["imu_acc"],
                   rename={f"{j}_pos": (f"q{k}_deg", np.pi / 180) for k, j in enumerate(JOINT_NAMES)})
    mapping = write_log(tmp_path / "log.csv", spec)
    (tmp_path / "map.json").write_text(json.dumps(mapping))
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "ds"), "--map", str(tmp_path / "map.json"),
            *CONTROL)
    assert r.returncode == 0, r.stderr
    assert "imu_acc_x" in r.stdout and "98 transitions" in r.stdout  # 2 episodes x (50 rows - 1)
    ds = load(tmp_path / "ds")
    assert ds.num_frames == 98 and ds.num_episodes == 2
    m = load_measurements(tmp_path / "ds")
    assert m.missing == list(GROUPS["imu_acc"])
    assert np.isnan(m.state[:, [STATE_NAMES.index(c) for c in GROUPS["imu_acc"]]]).all()
    first = slice(0, 49)
    q = m.state[first][:, [STATE_NAMES.index(f"{j}_pos") for j in JOINT_NAMES]]
    want = np.column_stack([log_rows[f"{j}_pos"][:49] for j in JOINT_NAMES])
    np.testing.assert_allclose(q, want, atol=1e-5)  # float32 storage
    np.testing.assert_allclose(m.next_state[:48], m.state[1:49])  # s_{t+1} is the next row
    info = ds.meta.info["acn"]
    assert info["kp"] == 60 and info["control_hz"] == 50 and info["source"]["simulator"] == "log"


def test_a_jittery_control_loop_gets_the_tolerance_that_keeps_its_episodes_whole(tmp_path, acn):
    """Steps of 17-23 ms in a 50 Hz log: many split at the default 10 %, and the report says which
    tolerance keeps them whole; with it, nothing is split."""
    write_log(tmp_path / "log.csv", LogSpec(seconds=1.0, episodes=2, seed=5, jitter=0.15))
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "split"), *CONTROL)
    assert r.returncode == 0, r.stderr
    breaks = int(r.stdout.split("split at ")[1].split()[0])
    assert breaks > 5 and "99 % of the time steps are within 15 % of it" in r.stdout, r.stdout
    assert "--dt-tolerance 0.18 keeps them whole" in r.stdout, r.stdout
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "whole"), *CONTROL, "--dt-tolerance", "0.18")
    assert r.returncode == 0 and "split at 0 wrong time step(s)" in r.stdout, r.stdout
    assert "keeps them whole" not in r.stdout
    assert load(tmp_path / "whole").num_episodes == 2
    assert load(tmp_path / "whole").meta.info["acn"]["import"]["time_step_spread"] == pytest.approx(0.15, abs=1e-3)


def test_a_control_rate_that_does_not_divide_1_khz_gets_the_nearest_physics_rate(tmp_path, acn):
    """A 60 Hz log (PyBullet's 240 Hz physics, four steps per action): without --physics-hz the model
    steps at 1020 Hz (17 per action) and the import says so; a rate given that is not a multiple of
    the control rate is one line and exit 2."""
    write_log(tmp_path / "log.csv", LogSpec(seconds=1.0, episodes=1, seed=5, control_hz=60, physics_hz=240))
    control = ["--control-hz", "60", *CONTROL[2:]]
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "d"), *control)
    assert r.returncode == 0 and "simulates it at 1020 Hz" in r.stdout, r.stdout + r.stderr
    info = load(tmp_path / "d").meta.info["acn"]
    assert info["substeps"] == 17 and info["physics_dt"] == pytest.approx(1 / 1020)
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "e"), *control, "--physics-hz", "1000")
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "acn-import: error: --physics-hz (1000) must be a multiple of --control-hz (60)"], r.stderr
    assert not (tmp_path / "e").exists()


def test_joint_columns_named_in_other_words_get_a_draft_map(tmp_path, acn):
    """A log whose joints are named as ROS names them (``FR_hip_joint`` for the angle, ``FR_hip_dq``
    for the velocity) lacks the schema's joint positions: the one-line error carries a --map file
    built from the names, which imports it; columns no channel reads are listed."""
    table = simulate(LogSpec(seconds=1.0, episodes=1, seed=5))
    renamed = {(k.replace("_pos", "_joint") if k.endswith("_pos") and k[:2] in ("FR", "FL", "RR", "RL")
                else k.replace("_vel", "_dq") if k.endswith("_vel") and k[:2] in ("FR", "FL", "RR", "RL") else k): v
               for k, v in table.items()}
    renamed["motor_temperature"] = np.full(len(table["timestamp"]), 40.0)
    pacsv.write_csv(pa.table(renamed), str(tmp_path / "log.csv"))
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "ds"), *CONTROL)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "columns named like them, as a --map file" in lines[0], r.stderr
    draft = json.loads(lines[0].split("(check units and leg order): ", 1)[1])
    assert draft["FR_hip_pos"] == "FR_hip_joint" and draft["RL_calf_vel"] == "RL_calf_dq" and len(draft) == 24
    assert not (tmp_path / "ds").exists()
    (tmp_path / "map.json").write_text(json.dumps(draft))
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "ds"), "--map", str(tmp_path / "map.json"),
            *CONTROL)
    assert r.returncode == 0 and "columns no channel reads (1): motor_temperature" in r.stdout, r.stdout + r.stderr
    assert "not in the log" not in r.stdout  # every channel found
    m = load_measurements(tmp_path / "ds")
    np.testing.assert_allclose(m.state[:10, SLICES["joint_vel"]],
                               np.column_stack([table[f"{j}_vel"][:10] for j in JOINT_NAMES]), atol=1e-5)


def test_a_log_with_its_time_in_ms_under_another_name_gets_a_draft_map(tmp_path, acn):
    """``time_ms`` and ``trial`` instead of ``timestamp`` and ``episode_index``: the one-line error
    carries a map with the scale to seconds, which imports the log whole."""
    table = simulate(LogSpec(seconds=1.0, episodes=2, seed=5))
    table["time_ms"], table["trial"] = table.pop("timestamp") * 1000.0, table.pop("episode_index")
    pacsv.write_csv(pa.table(table), str(tmp_path / "log.csv"))
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "ds"), *CONTROL)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "no timestamp column" in lines[0], r.stderr
    draft = json.loads(lines[0].split("as a --map file: ", 1)[1][:-1])
    assert draft == {"timestamp": {"column": "time_ms", "scale": 1e-3}, "episode_index": "trial"}
    (tmp_path / "map.json").write_text(json.dumps(draft))
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "ds"), "--map", str(tmp_path / "map.json"),
            *CONTROL)
    assert r.returncode == 0 and "2 episode(s)" in r.stdout and "split at 0" in r.stdout, r.stdout + r.stderr


def test_foot_forces_get_a_draft_map_to_contact_flags(tmp_path, acn):
    """A log of foot forces instead of contact flags: the draft map turns each into a flag above
    the threshold its readings split at, which gives the robot's own flags back."""
    table = simulate(LogSpec(seconds=2.0, episodes=1, seed=5))
    rng = np.random.default_rng(1)
    flags = {leg: table.pop(f"{leg}_contact") for leg in ("FR", "FL", "RR", "RL")}
    for leg, on in flags.items():
        table[f"{leg}_foot_force"] = np.where(on > 0.5, rng.uniform(30.0, 80.0, len(on)), 0.0) + rng.normal(0, 2, len(on))
    pacsv.write_csv(pa.table(table), str(tmp_path / "log.csv"))
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "a"), *CONTROL)
    line = next(x for x in r.stdout.splitlines() if x.startswith("columns named like channels the log lacks"))
    draft = json.loads(line.split("import again with it): ", 1)[1])
    assert set(draft) == {f"{leg}_contact" for leg in flags} and draft["RL_contact"]["column"] == "RL_foot_force"
    (tmp_path / "map.json").write_text(json.dumps(draft))
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "b"), "--map", str(tmp_path / "map.json"),
            *CONTROL)
    assert r.returncode == 0, r.stderr
    m = load_measurements(tmp_path / "b")
    got = m.state[:, SLICES["contact"]]
    want = np.column_stack(list(flags.values()))[: len(got)]
    assert (got == want).mean() > 0.99


def test_the_draft_map_names_one_orientation(tmp_path):
    """A log with its orientation as ``orientation.w/x/y/z`` and no Euler angles gets the
    quaternion drafted (and no Euler angle, although ``roll`` is there too); a log with the
    schema's Euler angles gets no quaternion drafted."""
    from acn.measurements.importer import ImportConfig, import_log
    from acn.sim.rotations import rpy_to_quat

    table = simulate(LogSpec(seconds=1.0, episodes=1, seed=5))
    x, y, z, w = rpy_to_quat(np.stack([table["base_roll"], table["base_pitch"], table["base_yaw"]]))
    quat = {"orientation.w": w, "orientation.x": x, "orientation.y": y, "orientation.z": z}
    cfg = ImportConfig(50, 60.0, 1.5, 33.5)
    without = {k: v for k, v in table.items() if k not in ("base_roll", "base_pitch", "base_yaw")}
    pacsv.write_csv(pa.table({**without, **quat, "roll": table["base_roll"]}), str(tmp_path / "q.csv"))
    _, report = import_log(tmp_path / "q.csv", tmp_path / "q", cfg)
    assert {k: v for k, v in report.suggested_map.items() if "quat" in k or k.startswith("base_r")} == {
        f"base_quat_{a}": f"orientation.{a}" for a in "wxyz"}
    pacsv.write_csv(pa.table({**table, **quat}), str(tmp_path / "e.csv"))
    _, report = import_log(tmp_path / "e.csv", tmp_path / "e", cfg)
    assert report.suggested_map == {} and sorted(report.unused) == sorted(quat)


def test_a_quaternion_array_is_drafted_in_the_order_its_data_show(tmp_path, log_rows):
    """A Parquet log with the trunk's orientation as one quaternion array (Unitree's SDK: w
    first) and no Euler angles gets it drafted in that order, with a note saying the data told it,
    and imports with the draft to the log's own angles; written w last at a heading near 0 the
    data do not tell the order: nothing is drafted and the note asks for it."""
    from acn.measurements.importer import ImportConfig, import_log
    from acn.sim.rotations import rpy_to_quat

    euler = ("base_roll", "base_pitch", "base_yaw")
    x, y, z, w = rpy_to_quat(np.stack([log_rows[c] for c in euler]))
    assert np.abs(log_rows["base_yaw"]).max() < 0.5  # the case where w last cannot be told from w first
    table = {k: v for k, v in log_rows.items() if k not in euler}
    cfg = ImportConfig(50, 60.0, 1.5, 33.5)
    for order, parts in (("wxyz", (w, x, y, z)), ("xyzw", (x, y, z, w))):
        pq.write_table(pa.table({**table, "quat": pa.array(list(np.column_stack(parts)), pa.list_(pa.float64()))}),
                       str(tmp_path / f"{order}.parquet"))
        _, report = import_log(tmp_path / f"{order}.parquet", tmp_path / f"{order}_draft", cfg)
        drafted = {k: v for k, v in report.suggested_map.items() if k.startswith("base_quat")}
        (note,) = report.map_notes
        if order == "xyzw":
            assert drafted == {} and "an order the data do not tell" in note, note
            continue
        assert drafted == {f"base_quat_{a}": f"quat[{i}]" for i, a in enumerate("wxyz")}
        assert "in wxyz order" in note and "told by the data" in note, note
        (tmp_path / "map.json").write_text(json.dumps(drafted))
        _, report = import_log(tmp_path / f"{order}.parquet", tmp_path / order, cfg, map_path=tmp_path / "map.json")
        assert report.quaternion and report.map_notes == []
        m = load_measurements(tmp_path / order)
        assert np.allclose(m.state[:49, [STATE_NAMES.index(c) for c in euler]],  # the first episode
                           np.column_stack([log_rows[c] for c in euler])[:49], atol=1e-6)


def test_a_hybrid_command_is_stored_whole(tmp_path, acn):
    """An MIT-style command (q_des, dq_des, tau_ff, PD gains per joint type) is stored whole: the
    actions are 60 wide (q_des, kp, kd, dq_des, tau_ff), and the target the checks read is the
    one that drives the PD the same way; a partial set of columns is refused in one line."""
    kp, kd = (100.0, 80.0, 50.0) * 4, (2.0, 1.5, 1.0) * 4
    write_log(tmp_path / "log.csv", LogSpec(seconds=1.0, episodes=2, seed=5, feedforward=True, kp=kp, kd=kd))
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "ds"), "--control-hz", "50",
            "--kp", "100,80,50", "--kd", "2,1.5,1", "--torque-limit", "33.5")
    assert r.returncode == 0 and "a hybrid command (action_vel, action_torque): stored with" in r.stdout, \
        r.stdout + r.stderr
    table = pacsv.read_csv(str(tmp_path / "log.csv")).to_pydict()
    first = slice(0, 49)
    cols = lambda kind: np.column_stack([table[f"{kind}.{j}"][first] for j in JOINT_NAMES])  # noqa: E731
    want = cols("action") + (np.array(kd) * cols("action_vel") + cols("action_torque")) / np.array(kp)
    m = load_measurements(tmp_path / "ds")
    np.testing.assert_allclose(m.targets[first], want, atol=1e-5)
    np.testing.assert_allclose(m.action[first, 36:], np.hstack([cols("action_vel"), cols("action_torque")]), atol=1e-5)
    assert m.control.hybrid and m.action.shape[1] == 60
    assert np.abs(want - cols("action")).max() > 0.05  # the feedforward matters
    assert load(tmp_path / "ds").meta.info["acn"]["import"]["hybrid_command"] == ["action_vel", "action_torque"]
    table.pop("action_torque.RL_calf")
    pacsv.write_csv(pa.table(table), str(tmp_path / "partial.csv"))
    r = acn("import", str(tmp_path / "partial.csv"), "--out", str(tmp_path / "p"), *CONTROL)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "action_torque.RL_calf" in r.stderr
    assert not (tmp_path / "p").exists()


def test_a_dataset_with_the_36_wide_hybrid_layout_is_still_read(tmp_path):
    """``action.hybrid`` 36 wide (kp, kd and one feedforward kd dq_des + tau_ff, no velocity target
    of its own), as datasets on users' disks may store it, is read as a velocity target of 0 with
    that feedforward: the same target and the same PD at nominal gains."""
    from acn.measurements.importer import ImportConfig, import_log

    write_log(tmp_path / "log.csv", LogSpec(seconds=1.0, episodes=1, seed=5, feedforward=True))
    path = import_log(tmp_path / "log.csv", tmp_path / "ds", ImportConfig(50, 60.0, 1.5, 33.5))[0]
    now = load_measurements(path)
    for f in sorted(path.rglob("data/**/*.parquet")):  # rewrite the data and features 36 wide
        t = pq.read_table(f)
        h = np.array(t.column("action.hybrid").to_pylist())
        old = np.hstack([h[:, :24], h[:, 12:24] * h[:, 24:36] + h[:, 36:]]).astype(np.float32)
        typ = pa.list_(pa.float32(), 36)
        t = t.set_column(t.schema.get_field_index("action.hybrid"), pa.field("action.hybrid", typ),
                         pa.array(list(old), type=typ))
        pq.write_table(t, f)
    info = json.loads((path / "meta" / "info.json").read_text())
    names = info["features"]["action.hybrid"]["names"]
    info["features"]["action.hybrid"].update(shape=[36], names=names[:24] + names[36:])
    (path / "meta" / "info.json").write_text(json.dumps(info))
    then = load_measurements(path)
    assert then.action.shape == now.action.shape == (len(now), 60)
    assert (then.action[:, 36:48] == 0).all() and np.abs(now.action[:, 36:48]).max() > 1.0
    np.testing.assert_allclose(then.targets, now.targets, atol=1e-5)
    np.testing.assert_allclose(then.action[:, 48:], now.action[:, 24:36] * now.action[:, 36:48] + now.action[:, 48:],
                               atol=1e-4)


def test_gains_sent_with_each_command_are_stored_with_the_actions(tmp_path, acn):
    """A controller that switches its legs between swing and stance gains sends them with every
    command (action_kp.*, action_kd.*): they are stored beside the targets (action.hybrid) and the
    measurements' actions are 60 wide (targets, kp, kd, velocity targets, feedforward), which the model's PD uses
    step by step; gains of one kind for some joints only, or a negative gain, are refused in one
    line."""
    write_log(tmp_path / "log.csv", LogSpec(seconds=1.0, episodes=2, seed=5, stance_gains=(0.5, 1.5), noise=1.0))
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "ds"), *CONTROL)
    assert r.returncode == 0 and "a hybrid command (action_kp, action_kd): stored with" in r.stdout, \
        r.stdout + r.stderr
    table = pacsv.read_csv(str(tmp_path / "log.csv")).to_pydict()
    first = slice(0, 49)
    cols = lambda kind: np.column_stack([table[f"{kind}.{j}"][first] for j in JOINT_NAMES])  # noqa: E731
    kp_t, kd_t = cols("action_kp"), cols("action_kd")
    assert set(np.unique(kp_t)) == {30.0, 60.0} and set(np.unique(kd_t)) == {1.5, 2.25}  # swing, stance
    m = load_measurements(tmp_path / "ds")
    assert m.control.hybrid and m.action.shape[1] == 60
    np.testing.assert_allclose(m.action[first], np.hstack([cols("action"), kp_t, kd_t, 0 * kp_t, 0 * kp_t]), atol=1e-5)
    assert load(tmp_path / "ds").meta.info["acn"]["hybrid_actions"] is True
    for dropped, message in ((["action_kp.FR_hip"], "action_kp.FR_hip"), ([], "negative")):
        bad = {k: v for k, v in table.items() if k not in dropped}
        if not dropped:
            bad["action_kd.RL_calf"] = [-1.0] * len(bad["action_kd.RL_calf"])
        pacsv.write_csv(pa.table(bad), str(tmp_path / "bad.csv"))
        r = acn("import", str(tmp_path / "bad.csv"), "--out", str(tmp_path / "bad"), *CONTROL)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and message in r.stderr, r.stderr
        assert not (tmp_path / "bad").exists()


def test_legs_in_legged_gym_order_are_named_and_imported_with_leg_order(tmp_path, acn):
    """A log whose legs come in legged_gym's order (FL, FR, RL, RR) under the schema's names: the
    data check names the order, and --leg-order imports it in ours."""
    spec = LogSpec(seconds=2.0, episodes=2, seed=7, noise=1.0)
    rows = simulate(spec)
    theirs = {"FR": "FL", "FL": "FR", "RR": "RL", "RL": "RR"}  # the log's FR columns hold the FL leg, ...
    swapped = {}
    for name, values in rows.items():
        leg = next((g for g in theirs if name.startswith(g + "_") or name.startswith("action." + g + "_")), None)
        swapped[name if leg is None else name.replace(leg + "_", theirs[leg] + "_", 1)] = values
    pacsv.write_csv(pa.table(swapped), str(tmp_path / "log.csv"))
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "as_is"), *CONTROL)
    assert r.returncode == 0 and "check (leg_order)" in r.stdout and "--leg-order FL,FR,RL,RR" in r.stdout, r.stdout
    assert "check (stance_feet)" not in r.stdout  # the order explains where the feet are
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "ds"), *CONTROL, "--leg-order", "FL,FR,RL,RR")
    assert r.returncode == 0 and "check (" not in r.stdout, r.stdout
    m = load_measurements(tmp_path / "ds")
    q = np.column_stack([rows[f"{j}_pos"][:49] for j in JOINT_NAMES])
    np.testing.assert_allclose(m.state[:49, [STATE_NAMES.index(f"{j}_pos") for j in JOINT_NAMES]], q, atol=1e-5)
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "bad"), *CONTROL, "--leg-order", "FL,FR,RL")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "FR, FL, RR and RL" in r.stderr


def test_bad_rows_split_episodes_and_are_counted(tmp_path, log_rows, acn):
    cols = {k: v.copy() for k, v in log_rows.items()}
    cols["timestamp"][10:] += 0.013  # one time step of 33 ms instead of 20 ms
    cols["FR_hip_pos"][30] = np.nan
    cols.pop("FL_hip_vel")
    pq.write_table(pa.table(cols), tmp_path / "log.parquet")
    r = acn("import", str(tmp_path / "log.parquet"), "--out", str(tmp_path / "ds"), *CONTROL)
    assert r.returncode == 0, r.stderr
    assert "cut 1 row(s) with non-finite values" in r.stdout and "split at 1 wrong time step(s)" in r.stdout
    m = load_measurements(tmp_path / "ds")
    # episode 0 (50 rows) -> [0..9], [10..29], [31..49]; episode 1 -> one segment
    assert sorted(np.bincount(m.episode).tolist()) == sorted([9, 19, 18, 49])
    assert m.missing == ["FL_hip_vel"]
    filled, derived = fill_derived(m)
    assert derived == ["FL_hip_vel"] and np.isfinite(filled.state).all()
    true = log_rows["FL_hip_vel"][:9]
    assert np.abs(filled.state[:9, STATE_NAMES.index("FL_hip_vel")] - true).mean() < 0.5 * np.abs(true).mean() + 0.05


@pytest.mark.parametrize("change, message", [
    (lambda c: c.pop("action.FR_hip"), "action.FR_hip"),
    (lambda c: c.pop("RL_calf_pos"), "RL_calf_pos"),
    (lambda c: c.pop("timestamp"), "timestamp"),
])
def test_logs_without_the_minimum_are_refused(tmp_path, log_rows, change, message, acn):
    cols = {k: v.copy() for k, v in log_rows.items()}
    change(cols)
    pacsv.write_csv(pa.table(cols), tmp_path / "log.csv")
    r = acn("import", str(tmp_path / "log.csv"), "--out", str(tmp_path / "ds"), *CONTROL)
    assert r.returncode == 2 and message in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert not (tmp_path / "ds").exists()


def test_import_errors_are_one_line(tmp_path, log_rows, acn):
    pacsv.write_csv(pa.table(log_rows), tmp_path / "log.csv")
    (tmp_path / "bad.json").write_text('{"FR_knee_pos": "q0"}')
    (tmp_path / "log.txt").write_text("x")
    (tmp_path / "threshold.json").write_text('{"FR_hip_pos": {"column": "FR_hip_pos", "threshold": 0.1}}')
    for args, message in [
        ([str(tmp_path / "nope.csv")], "does not exist"),
        ([str(tmp_path / "log.txt")], ".csv, .parquet, .jsonl (one JSON object per line), HDF5"),
        ([str(tmp_path / "log.csv"), "--map", str(tmp_path / "bad.json")], "not a channel"),
        ([str(tmp_path / "log.csv"), "--map", str(tmp_path / "threshold.json")], "not a contact channel"),
        ([str(tmp_path / "log.csv"), "--control-hz", "0"], ">= 1"),
        ([str(tmp_path / "log.csv"), "--control-hz", "25"], "rate looks like 50 Hz"),  # every step is a wrong one
    ]:
        extra = [] if "--control-hz" in args else CONTROL
        ctl = CONTROL[2:] if "--control-hz" in args else []
        r = acn("import", *args, "--out", str(tmp_path / "ds"), *extra, *ctl)
        assert r.returncode == 2 and message in r.stderr and len(r.stderr.strip().splitlines()) == 1, (args, r.stderr)
        assert not (tmp_path / "ds").exists()


def test_foot_forces_become_contact_flags_through_a_threshold(log_rows):
    """A log of foot forces (N) maps onto the 0/1 contact flags with "threshold"; a lost reading stays NaN."""
    rng = np.random.default_rng(0)
    flags = np.column_stack([log_rows[c] for c in GROUPS["contact"]])
    table = {f"force{i}": flags[:, i] * rng.uniform(25, 60, len(flags)) + rng.uniform(0, 3, len(flags)) for i in range(4)}
    table["force0"][3] = np.nan
    mapping = {c: {"column": f"force{i}", "threshold": 10.0} for i, c in enumerate(GROUPS["contact"])}
    cols = resolve_columns(table, mapping)
    got = np.column_stack([cols[c] for c in GROUPS["contact"]])
    assert np.isnan(got[3, 0]) and np.isfinite(np.delete(got, 3, axis=0)).all()
    ok = np.isfinite(got)
    np.testing.assert_array_equal(got[ok], flags[ok])
    assert 0 < flags.mean() < 1  # both stance and swing are in the log


def _write_variant(path, rows: dict, how: str) -> None:
    """``rows`` as other logging code writes them."""
    if how == "semicolons":
        pacsv.write_csv(pa.table(rows), str(path), pacsv.WriteOptions(delimiter=";"))
    elif how == "empty mocap columns":  # a logger without motion capture writes NaN columns for it
        pq.write_table(pa.table({k: (np.full_like(v, np.nan) if k in GROUPS["base_pos"] + GROUPS["base_linvel"] else v)
                                 for k, v in rows.items()}), str(path))
    elif how == "date-time stamps":
        stamps = (1.7e9 + rows["timestamp"] + 10 * rows["episode_index"]) * 1e6
        pq.write_table(pa.table({**rows, "timestamp": pa.array(stamps.astype(np.int64), pa.timestamp("us"))}), str(path))
    elif how == "JSON lines":
        path.write_text("".join(json.dumps(r) + "\n" for r in pa.table(rows).to_pylist()))
    elif how == "gzip-compressed, after comments":
        with gzip.open(path, "wt") as f:
            f.write("# logged by walker 2.1\n" + "\n".join(_csv_lines(rows)) + "\n")
    else:
        path.write_text(_csv_text(rows, how), encoding="utf-8-sig" if how == "comments, BOM, CRLF" else "utf-8",
                        newline="")


def _csv_lines(rows: dict) -> list[str]:
    """``rows`` as the lines of a CSV, header first, names unquoted."""
    sink = pa.BufferOutputStream()
    pacsv.write_csv(pa.table(rows), sink, pacsv.WriteOptions(quoting_style="none"))
    return sink.getvalue().to_pybytes().decode().splitlines()


def _csv_text(rows: dict, how: str) -> str:
    """``rows`` as a CSV some logger wrote: after ``#`` comments with a byte-order mark and CRLF line
    ends; in a European spreadsheet's format (semicolons, decimal commas); or stopped mid-line."""
    lines = _csv_lines(rows)
    if how == "comments, BOM, CRLF":
        return "\r\n".join(["# logged by walker 2.1", "# kp 60 kd 1.5", "", *lines]) + "\r\n"
    if how == "decimal commas":
        return "\n".join(lines[0].replace(",", ";") if i == 0 else line.replace(",", ";").replace(".", ",")
                         for i, line in enumerate(lines)) + "\n"
    if how == "a header written again":  # the logger restarted between the episodes, appending
        return "\n".join([*lines[:51], lines[0], *lines[51:]]) + "\n"
    assert how == "a last line cut off"
    return "\n".join([*lines[:-1], lines[-1][: len(lines[-1]) // 2]])


@pytest.mark.parametrize("how, suffix", [("semicolons", "csv"), ("empty mocap columns", "parquet"),
                                         ("date-time stamps", "parquet"), ("comments, BOM, CRLF", "csv"),
                                         ("decimal commas", "csv"), ("a last line cut off", "csv"),
                                         ("a header written again", "csv"), ("JSON lines", "jsonl"),
                                         ("gzip-compressed, after comments", "csv.gz")])
def test_logs_as_other_code_writes_them_import(tmp_path, log_rows, acn, how, suffix):
    """Each imports whole, to the logged values (float32 storage); a last row cut off mid-line is
    set aside, named by its line, and the rest imported; a header written again is read as a row
    of missing values, said, and cut."""
    _write_variant(tmp_path / f"log.{suffix}", log_rows, how)
    r = acn("import", str(tmp_path / f"log.{suffix}"), "--out", str(tmp_path / "ds"), *CONTROL)
    cut, again = how == "a last line cut off", how == "a header written again"
    assert r.returncode == 0 and f"{97 if cut else 98} transitions in 2 episode(s)" in r.stdout, r.stdout + r.stderr
    assert ("set aside 1 row(s) with another number of fields than the header (line(s) 101)" in r.stdout) == cut
    assert ("1 row(s) with text among the numbers (first: 'episode_index' = 'episode_index'" in r.stdout) == again
    assert ("cut 1 row(s) with non-finite values" in r.stdout) == again
    m = load_measurements(tmp_path / "ds")
    assert m.missing == (list(GROUPS["base_pos"] + GROUPS["base_linvel"]) if how == "empty mocap columns" else [])
    q = m.state[:49, SLICES["joint_pos"]]
    np.testing.assert_allclose(q, np.column_stack([log_rows[f"{j}_pos"][:49] for j in JOINT_NAMES]), atol=1e-5)


def test_a_csv_of_many_rows_of_another_width_is_refused_a_garbled_row_set_aside(tmp_path, log_rows, acn):
    """A third of the rows one field longer than the header (another format, not a cut-off row) is
    refused with one line naming the first; one garbled row inside an episode is set aside and
    splits the episode there."""
    lines = _csv_lines(log_rows)
    wide = [lines[0]] + [f"{line},1" if i % 3 == 0 else line for i, line in enumerate(lines[1:])]
    (tmp_path / "wide.csv").write_text("\n".join(wide) + "\n")
    r = acn("import", str(tmp_path / "wide.csv"), "--out", str(tmp_path / "w"), *CONTROL)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "34 of its 100 rows have another number of fields than its header (line 2: 58" in r.stderr, r.stderr
    assert not (tmp_path / "w").exists()
    garbled = list(lines)
    garbled[21] = garbled[21][: len(garbled[21]) // 3]
    (tmp_path / "garbled.csv").write_text("\n".join(garbled) + "\n")
    r = acn("import", str(tmp_path / "garbled.csv"), "--out", str(tmp_path / "g"), *CONTROL)
    assert r.returncode == 0 and "line(s) 22)" in r.stdout and "split at 1 wrong time step(s)" in r.stdout, r.stdout
    episodes = np.bincount(load_measurements(tmp_path / "g").episode)
    assert sorted(episodes.tolist()) == [19, 28, 49]  # rows 0-19 and 21-49 of episode 0; episode 1


def test_a_log_other_code_got_wrong_gets_one_line_naming_the_cause(tmp_path, log_rows, acn):
    order = np.argsort(log_rows["timestamp"], kind="stable")  # two robots' rows side by side, sorted by time
    interleaved = {k: v[order] for k, v in log_rows.items()}
    f32 = {**log_rows, "timestamp": (1.7e9 + log_rows["timestamp"]).astype(np.float32)}
    cases = [
        (pa.table(interleaved), "sort the log by episode_index, then timestamp"),
        (pa.table({k: v[:0] for k, v in log_rows.items()}), "no data rows"),
        (pa.table(f32), "the timestamps are float32 numbers"),
        # whole microseconds are float32 numbers too: named as microseconds, not float32
        (pa.table({**log_rows, "timestamp": (log_rows["timestamp"] * 1e6).astype(np.int64)}),
         'timestamps in us? map timestamp with "scale": 1e-06'),
    ]
    for k, (table, message) in enumerate(cases):
        pq.write_table(table, str(tmp_path / f"{k}.parquet"))
        r = acn("import", str(tmp_path / f"{k}.parquet"), "--out", str(tmp_path / f"ds{k}"), *CONTROL)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and message in r.stderr, r.stderr
        assert not (tmp_path / f"ds{k}").exists()
    pq.write_table(pa.table(log_rows), str(tmp_path / "log.parquet"))
    (tmp_path / "map.json").write_text(json.dumps({"FR_hip_pos": {"column": ["q", 0]}}))
    r = acn("import", str(tmp_path / "log.parquet"), "--out", str(tmp_path / "m"), *CONTROL, "--map",
            str(tmp_path / "map.json"))
    assert r.returncode == 2 and 'the "column" of \'FR_hip_pos\' must be a column name' in r.stderr, r.stderr


def test_array_columns_duplicate_names_and_partial_efforts(tmp_path, log_rows, acn):
    """A Parquet column of 12 joint angles per row is read one element each (q[0] ...) and mapped
    (the error's draft map reads it in the schema's order); two columns of one name are refused; efforts of some joints only are named and not stored."""
    joints = [f"{j}_pos" for j in JOINT_NAMES]
    q = np.column_stack([log_rows[n] for n in joints])
    table = {k: v for k, v in log_rows.items() if k not in joints}
    pq.write_table(pa.table({**table, "q": pa.array(list(q), pa.list_(pa.float64()))}), str(tmp_path / "log.parquet"))
    r = acn("import", str(tmp_path / "log.parquet"), "--out", str(tmp_path / "no_map"), *CONTROL)
    assert r.returncode == 2 and '{"FR_hip_pos": "q[0]"}' in r.stderr, r.stderr
    # the draft map reads the array in the schema's order (Unitree's), and says so
    draft = json.loads(r.stderr.strip().split("; arrays read in the schema's order", 1)[1].split("): ", 1)[1])
    assert draft == {n: f"q[{i}]" for i, n in enumerate(joints)}
    (tmp_path / "map.json").write_text(json.dumps(draft))
    r = acn("import", str(tmp_path / "log.parquet"), "--out", str(tmp_path / "ds"), *CONTROL, "--map",
            str(tmp_path / "map.json"))
    assert r.returncode == 0, r.stderr
    np.testing.assert_allclose(load_measurements(tmp_path / "ds").state[:49, [STATE_NAMES.index(n) for n in joints]],
                               q[:49], atol=1e-5)
    (tmp_path / "dup.csv").write_text("timestamp,timestamp\n0,0\n")
    r = acn("import", str(tmp_path / "dup.csv"), "--out", str(tmp_path / "dup"), *CONTROL)
    assert r.returncode == 2 and "more than one column named 'timestamp'" in r.stderr, r.stderr
    some = {**log_rows, **{f"effort.{j}": np.zeros_like(log_rows["timestamp"]) for j in JOINT_NAMES[:3]}}
    pq.write_table(pa.table(some), str(tmp_path / "efforts.parquet"))
    r = acn("import", str(tmp_path / "efforts.parquet"), "--out", str(tmp_path / "e"), *CONTROL)
    assert r.returncode == 0 and "efforts of 3 of 12 joints" in r.stdout, r.stdout


def test_a_column_of_numbers_with_some_text_is_read_as_numbers_a_column_of_text_is_not():
    """"-" for a lost reading, a header written again: NaN there, the rest numbers; a mode column
    of words stays text (skipped)."""
    from acn.measurements.importer import _mostly_numbers

    values, text = _mostly_numbers(["0.5"] * 18 + ["-", "1e-3", None])
    assert text.tolist() == [False] * 18 + [True, False, False]
    np.testing.assert_array_equal(values[[0, 19]], [0.5, 1e-3])
    assert np.isnan(values[[18, 20]]).all()
    assert _mostly_numbers(["walk", "walk", "trot", "1"]) is None
    assert _mostly_numbers(["0.5", "0.25"]) is None  # numbers throughout: the reader's own job


def test_a_log_written_as_one_file_per_run_imports_as_one_dataset(tmp_path, log_rows, acn):
    """Two runs in two files without episode_index: one dataset, each file its own episode, the
    same rows as the one-file log; a file with other columns is refused in one line."""
    runs = []
    for e in (0, 1):
        rows = log_rows["episode_index"] == e
        runs.append(tmp_path / f"run{e}.csv")
        pacsv.write_csv(pa.table({k: v[rows] for k, v in log_rows.items() if k != "episode_index"}), runs[-1])
    r = acn("import", *map(str, runs), "--out", str(tmp_path / "ds"), *CONTROL)
    assert r.returncode == 0 and "98 transitions in 2 episode(s)" in r.stdout, r.stdout + r.stderr
    m = load_measurements(tmp_path / "ds")
    want = np.column_stack([log_rows[f"{j}_pos"] for j in JOINT_NAMES])
    np.testing.assert_allclose(m.state[:, SLICES["joint_pos"]], np.delete(want, [49, 99], axis=0), atol=1e-5)
    assert load(tmp_path / "ds").meta.info["acn"]["source"]["files"] == ["run0.csv", "run1.csv"]
    pacsv.write_csv(pa.table(log_rows), tmp_path / "other.csv")  # it has episode_index
    r = acn("import", str(runs[0]), str(tmp_path / "other.csv"), "--out", str(tmp_path / "no"), *CONTROL)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "other.csv has other columns than" in r.stderr and "it adds episode_index" in r.stderr, r.stderr
    assert not (tmp_path / "no").exists()


def test_nested_json_lines_are_flattened_and_get_a_draft_map(tmp_path, log_rows, acn):
    """A JSON-lines log with nested records ({"imu": {"acc": {"x": ...}}}) and an array of joint
    angles: flattened to imu.acc.x and q[0] ..., named in the draft map, and with it imported to the
    logged values."""
    records = []
    for r in pa.table(log_rows).to_pylist():
        imu = {axis: r.pop(f"imu_acc_{axis}") for axis in "xyz"}
        q = [r.pop(f"{j}_pos") for j in JOINT_NAMES]
        records.append({**r, "imu": {"acc": imu}, "q": q})
    (tmp_path / "log.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    r = acn("import", str(tmp_path / "log.jsonl"), "--out", str(tmp_path / "no_map"), *CONTROL)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    draft = json.loads(r.stderr.strip().split("axes x, y, z): ", 1)[1])
    assert draft["imu_acc_x"] == "imu.acc.x" and draft["FR_hip_pos"] == "q[0]", draft
    (tmp_path / "map.json").write_text(json.dumps(draft))
    r = acn("import", str(tmp_path / "log.jsonl"), "--out", str(tmp_path / "ds"), *CONTROL, "--map",
            str(tmp_path / "map.json"))
    assert r.returncode == 0 and "98 transitions in 2 episode(s)" in r.stdout, r.stdout + r.stderr
    m = load_measurements(tmp_path / "ds")
    assert m.missing == []
    acc = m.state[:49, [STATE_NAMES.index(f"imu_acc_{axis}") for axis in "xyz"]]
    np.testing.assert_allclose(acc, np.column_stack([log_rows[f"imu_acc_{a}"][:49] for a in "xyz"]), atol=1e-4)


def test_hdf5_and_npz_logs_import(tmp_path, log_rows, acn):
    """HDF5 as loggers write it: one table (2-D joint angles, actions in a group named as the
    schema, a gain and a camera image left out), or numbered episode groups read in their numbers'
    order (demo_2 before demo_10, whatever the file's order); a NumPy archive as one table; all to
    the logged values. Episode groups with other datasets, a file pandas wrote, an archive of
    object arrays (never unpickled) and files that are neither are refused in one line."""
    import h5py

    q = np.column_stack([log_rows[f"{j}_pos"] for j in JOINT_NAMES])
    flat = {k: v for k, v in log_rows.items() if not k.endswith("_pos") or k in GROUPS["base_pos"]}
    with h5py.File(tmp_path / "table.h5", "w") as f:
        for k, v in flat.items():
            f.create_dataset(k.replace("action.", "action/"), data=v)
        f["q"] = q
        f["kp"] = np.full(12, 60.0)  # not a column: another number of rows
        f["camera"] = np.zeros((len(q), 4, 4), np.uint8)  # an image: not read
    r = acn("import", str(tmp_path / "table.h5"), "--out", str(tmp_path / "no_map"), *CONTROL)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert '"FR_hip_pos": "q[0]"' in r.stderr, r.stderr  # the draft map names the array's elements
    (tmp_path / "map.json").write_text(json.dumps({f"{j}_pos": f"q[{k}]" for k, j in enumerate(JOINT_NAMES)}))
    r = acn("import", str(tmp_path / "table.h5"), "--out", str(tmp_path / "table"), *CONTROL,
            "--map", str(tmp_path / "map.json"))
    assert r.returncode == 0 and "98 transitions in 2 episode(s)" in r.stdout, r.stdout + r.stderr
    want = np.delete(q, [49, 99], axis=0)  # each episode's last row is only a next state
    np.testing.assert_allclose(load_measurements(tmp_path / "table").state[:, SLICES["joint_pos"]], want, atol=1e-5)

    with h5py.File(tmp_path / "episodes.hdf5", "w") as f:
        for e, name in ((1, "demo_10"), (0, "demo_2")):
            rows = log_rows["episode_index"] == e
            for k, v in log_rows.items():
                if k != "episode_index":
                    f.create_dataset(f"data/{name}/{k.replace('action.', 'action/')}", data=v[rows])
        f["data/total"] = np.array([100])
    r = acn("import", str(tmp_path / "episodes.hdf5"), "--out", str(tmp_path / "episodes"), *CONTROL)
    assert r.returncode == 0 and "98 transitions in 2 episode(s)" in r.stdout, r.stdout + r.stderr
    m = load_measurements(tmp_path / "episodes")
    np.testing.assert_allclose(m.state[:, SLICES["joint_pos"]], want, atol=1e-5)

    with h5py.File(tmp_path / "episodes.hdf5", "a") as f:
        del f["data/demo_10/timestamp"]
    r = acn("import", str(tmp_path / "episodes.hdf5"), "--out", str(tmp_path / "no"), *CONTROL)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "episode group /data/demo_10 has other datasets than /data/demo_2: it lacks timestamp" in r.stderr, r.stderr
    with h5py.File(tmp_path / "pandas.h5", "w") as f:  # HDFStore's layout: a group per frame, marked
        f.create_group("log").attrs["pandas_type"] = "frame"
        f["log/block0_values"] = np.zeros((3, 2))
    r = acn("import", str(tmp_path / "pandas.h5"), "--out", str(tmp_path / "no"), *CONTROL)
    assert r.returncode == 2 and "written by pandas" in r.stderr and "to_parquet" in r.stderr, r.stderr
    np.savez(tmp_path / "arrays.npz", q=q, **{k.replace(".", "_"): v for k, v in flat.items()})  # np.savez's names
    npz_map = {f"{j}_pos": f"q[{k}]" for k, j in enumerate(JOINT_NAMES)} | {
        f"action.{j}": f"action_{j}" for j in JOINT_NAMES}
    (tmp_path / "npz_map.json").write_text(json.dumps(npz_map))
    r = acn("import", str(tmp_path / "arrays.npz"), "--out", str(tmp_path / "npz"), *CONTROL,
            "--map", str(tmp_path / "npz_map.json"))
    assert r.returncode == 0 and "98 transitions in 2 episode(s)" in r.stdout, r.stdout + r.stderr
    np.testing.assert_allclose(load_measurements(tmp_path / "npz").state[:, SLICES["joint_pos"]], want, atol=1e-5)
    np.savez(tmp_path / "objects.npz", q=q, names=np.array([{"a": 1}] * len(q), dtype=object))
    (tmp_path / "text.npz").write_text("timestamp\n0\n")
    for name, message in (("objects.npz", "never done"), ("text.npz", "not a NumPy .npz archive")):
        r = acn("import", str(tmp_path / name), "--out", str(tmp_path / "no"), *CONTROL)
        assert r.returncode == 2 and message in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr
    (tmp_path / "text.h5").write_text("timestamp,FR_hip_pos\n0,0\n")
    r = acn("import", str(tmp_path / "text.h5"), "--out", str(tmp_path / "no"), *CONTROL)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "cannot read" in r.stderr, r.stderr
    assert not (tmp_path / "no").exists()
