"""acn-import's draft map: log columns named like the schema's per-joint channels in other words."""

from __future__ import annotations

import numpy as np
import pytest

from acn.measurements.naming import CHANNELS, arrays_read, channel_of, contact_threshold, foot_force_of, suggest_map, words


@pytest.mark.parametrize("name, channel", [
    ("FR_hip_joint", "FR_hip_pos"),              # ROS joint names: the column holds the angle
    ("FR_hip_dq", "FR_hip_vel"),
    ("front_left_knee_position", "FL_calf_pos"),
    ("RH_HFE_vel", "RR_thigh_vel"),              # ANYmal's leg and joint names
    ("LH_HAA_tau", "effort.RL_hip"),
    ("q_des_FL_calf", "action.FL_calf"),
    ("FR_thigh_cmd", "action.FR_thigh"),
    ("dq_des.RR_calf", "action_vel.RR_calf"),
    ("actions_RL_calf", "action.RL_calf"),      # a plural: an HDF5 log's /actions (T, 12), robomimic's name
    ("joint_targets.FL_hip", "action.FL_hip"),
    ("kp_RL_thigh", "action_kp.RL_thigh"),
    ("motorTorqueFrontRightHip", "effort.FR_hip"),  # camel case
    ("rearLeftCalfQ", "RL_calf_pos"),
])
def test_a_column_named_in_other_words_is_matched_to_its_channel(name, channel):
    assert channel_of(name) == channel, words(name)


@pytest.mark.parametrize("name", [
    "q[3]",             # a numbered joint: its order is the user's to state
    "FR_hip",           # no quantity
    "FR_FL_hip_pos",    # two legs
    "FR_hip_knee_pos",  # two joints
    "FR_hip_tau_ff",    # a feedforward torque: a command or the action of a torque-mode log
])
def test_an_ambiguous_column_is_not_matched(name):
    assert channel_of(name) is None


def test_a_channel_two_columns_describe_is_left_to_the_user():
    columns = ["FR_hip_dq", "FR_hip_qd_filtered", "FL_hip_dq"]
    assert suggest_map(columns, ["FR_hip_vel", "FL_hip_vel", "RR_hip_vel"]) == {"FL_hip_vel": "FL_hip_dq"}


@pytest.mark.parametrize("name, channel", [
    ("gyro_x", "base_angvel_x"),
    ("imu.angular_velocity.z", "base_angvel_z"),
    ("linear_acceleration.y", "imu_acc_y"),
    ("accelerometerZ", "imu_acc_z"),
    ("orientation.w", "base_quat_w"),
    ("imu_quaternion_x", "base_quat_x"),
    ("roll", "base_roll"),
    ("rpy_z", "base_yaw"),
    ("base_vel_x", "base_linvel_x"),
    ("trunk_position_z", "base_pos_z"),
    ("FL_foot_contact", "FL_contact"),
])
def test_a_trunk_or_contact_column_named_in_other_words_is_matched(name, channel):
    assert channel_of(name) == channel, words(name)


@pytest.mark.parametrize("name", [
    "cmd_vel_x",      # the velocity a locomotion policy is commanded, not the trunk's
    "foot_pos_x",     # a foot's, not the trunk's
    "yaw_rate",       # a rate, not the angle (and no axis)
    "pos_xy",
    "acc_x_y",
    "FR_foot_force",  # a force: a contact flag needs its threshold
])
def test_an_ambiguous_trunk_column_is_not_matched(name):
    assert channel_of(name) is None


def test_array_columns_are_read_in_the_schemas_order():
    """Array columns (a Parquet log's 12 joint angles per row, read as ``q[0]`` ... ``q[11]``) are
    drafted in the schema's order, which is Unitree's SDK's; a quaternion's order differs between
    libraries and is not drafted."""
    columns = ([f"q[{i}]" for i in range(12)] + [f"tau_est[{i}]" for i in range(12)] + [f"q_des[{i}]" for i in range(12)]
               + [f"imu_gyro[{i}]" for i in range(3)] + [f"imu_rpy[{i}]" for i in range(3)]
               + [f"imu_quat[{i}]" for i in range(4)] + [f"foot_contact[{i}]" for i in range(4)] + ["dq[0]", "dq[1]"])
    draft = suggest_map(columns, list(CHANNELS))
    assert draft["FR_hip_pos"] == "q[0]" and draft["FL_calf_pos"] == "q[5]" and draft["RL_calf_pos"] == "q[11]"
    assert draft["effort.RR_thigh"] == "tau_est[7]" and draft["action.FL_hip"] == "q_des[3]"
    assert draft["base_angvel_z"] == "imu_gyro[2]" and draft["base_pitch"] == "imu_rpy[1]"
    assert draft["RL_contact"] == "foot_contact[3]"
    assert not any(c.startswith(("imu_quat", "dq")) for c in draft.values())  # quaternion order; 2 of 12 joints
    assert "arrays read in the schema's order" in arrays_read(draft) and arrays_read({"FR_hip_pos": "a"}) == ""


def test_time_and_episode_columns_are_matched_and_a_named_unit_scaled():
    assert [channel_of(n) for n in ("time", "header.stamp", "time_s", "episode_id", "trial")] == \
        ["timestamp", "timestamp", "timestamp", "episode_index", "episode_index"]
    assert channel_of("step_time_since_contact") is None
    assert suggest_map(["time_ms", "run"], ["timestamp", "episode_index"]) == {
        "timestamp": {"column": "time_ms", "scale": 1e-3}, "episode_index": "run"}


def test_a_foot_force_gets_the_threshold_that_splits_swing_from_stance():
    """Foot forces (N, or a sensor's raw counts) become contact flags above a threshold drawn
    from the readings: between the swing and stance groups; none where they form one group."""
    rng = np.random.default_rng(0)
    stance = rng.random(400) < 0.6
    force = np.where(stance, rng.uniform(30.0, 90.0, 400), 0.0) + rng.normal(0.0, 2.0, 400)
    t = contact_threshold(force)
    assert t is not None and 5.0 < t < 30.0 and ((force > t) == stance).mean() > 0.99
    assert contact_threshold(rng.normal(50.0, 5.0, 400)) is None   # always on the ground
    assert contact_threshold(np.full(10, 3.0)) is None
    assert [foot_force_of(n) for n in ("FR_foot_force", "footForce_RL", "grf_LF", "FR_hip_force", "force_x")] == \
        ["FR", "RL", "FL", None, None]


def test_a_quaternion_arrays_order_is_read_from_a_trunk_near_level():
    """A trunk near level keeps its quaternion's x and y small while w and z swing with the
    heading: elements 1, 2 small is w first, 0, 1 small is w last; a heading that stays near 0 in
    w-last order reads as a heading near pi in w-first order, so the data do not tell; rows that
    are not unit quaternions, or a trunk tumbling, are not read."""
    from acn.measurements.naming import quaternion_order
    from acn.sim.rotations import rpy_to_quat

    rng = np.random.default_rng(0)
    n = 400
    tilt = rng.uniform(-0.25, 0.25, (2, n))
    turning = np.stack([*tilt, rng.uniform(-np.pi, np.pi, n)])
    straight = np.stack([*tilt, rng.uniform(-0.1, 0.1, n)])
    x, y, z, w = rpy_to_quat(turning)
    assert quaternion_order(np.column_stack([w, x, y, z])) == "wxyz"
    assert quaternion_order(np.column_stack([x, y, z, w])) == "xyzw"
    x, y, z, w = rpy_to_quat(straight)
    assert quaternion_order(np.column_stack([w, x, y, z])) == "wxyz"
    assert quaternion_order(np.column_stack([x, y, z, w])) is None  # = w first at a heading near pi
    assert quaternion_order(2.0 * np.column_stack([w, x, y, z])) is None
    tumbling = rng.normal(size=(n, 4))
    assert quaternion_order(tumbling / np.linalg.norm(tumbling, axis=1, keepdims=True)) is None
