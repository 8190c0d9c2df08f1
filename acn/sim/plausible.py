"""Values no A1 can produce: the bounds past which a reading or a command is not physics.

An A1's joints move within about -2.7..4.2 rad, at up to about 21 rad/s, under at most 33.5 N m;
its trunk walks at a few m/s. Each bound below sits an order of magnitude or more past that, so
nothing a real robot (or a simulator that has not blown up) records comes near it, while a
corrupted value (a float written as 1e308, an unset 3.4e38, a wrong unit by 1e6) is caught:

=================  ==========  =========================================================
channel group      |value| <=  why
=================  ==========  =========================================================
base_pos           1e3 m       a trunk 1 km from the origin is a logging error
base_roll, pitch   4 pi rad    Euler angles; two turns either way
base_yaw           1e4 rad     a yaw unwrapped over a long walk keeps growing
joint_pos          4 pi rad    two turns past the joint's range
base_linvel        50 m/s      about 15x the fastest quadruped
base_angvel        500 rad/s   a gyroscope saturates near 35 rad/s
joint_vel          500 rad/s   about 24x the motor's top speed
contact            10          a flag (0 or 1) or a force read as one
imu_acc            1e3 m/s^2   about 100 g
effort             1e3 N m     about 30x the torque limit
action (position)  4 pi rad    a joint target
action (torque)    1e3 N m     a joint torque
action.hybrid      kp 1e4, kd 1e3, velocity 500 rad/s, torque 1e3 N m
=================  ==========  =========================================================

``acn-import`` cuts rows beyond them (as it cuts non-finite rows) and counts them; the
dataset readers refuse a dataset whose actions are beyond them, naming the episode and column.
"""

from __future__ import annotations

import numpy as np

from acn.sim.state import ACTION_NAMES, GROUPS, HYBRID_NAMES

_GROUP_BOUND = {"base_pos": 1e3, "base_rpy": 4 * np.pi, "joint_pos": 4 * np.pi, "base_linvel": 50.0,
                "base_angvel": 500.0, "joint_vel": 500.0, "contact": 10.0, "imu_acc": 1e3}
STATE_BOUND = np.array([1e4 if n == "base_yaw" else _GROUP_BOUND[g] for g, names in GROUPS.items() for n in names])
EFFORT_BOUND = 1e3
ACTION_BOUND = {"position": 4 * np.pi, "torque": 1e3}
HYBRID_BOUND = np.repeat([1e4, 1e3, 500.0, 1e3], len(ACTION_NAMES))  # kp, kd, velocity target, feedforward


def past(values: np.ndarray, bound: np.ndarray | float) -> np.ndarray:
    """Which values lie past ``bound`` in magnitude (an infinity does; NaN, a missing value, does not)."""
    with np.errstate(invalid="ignore"):
        return np.abs(np.asarray(values, dtype=np.float64)) > bound


def beyond(values: np.ndarray, bound: np.ndarray | float) -> np.ndarray:
    """(N,) rows with a value past ``bound`` in any column."""
    return past(values, bound).any(axis=-1)


def first_beyond(values: np.ndarray, bound: np.ndarray | float, names: tuple[str, ...]) -> tuple[int, str, float] | None:
    """(row, column name, value) of the first value past ``bound``, or None."""
    bad = past(values, bound)
    if not bad.any():
        return None
    row, col = np.argwhere(bad)[0]
    return int(row), names[int(col)], float(np.asarray(values)[row, col])


def action_bound(action_mode: str, width: int) -> np.ndarray:
    """The bound of each column of an action ``width`` wide (joint commands, then the hybrid's)."""
    joint = np.full(len(ACTION_NAMES), ACTION_BOUND[action_mode])
    return np.concatenate([joint, HYBRID_BOUND])[:width]


def action_names(width: int) -> tuple[str, ...]:
    return (ACTION_NAMES + HYBRID_NAMES)[:width]

