"""Draft ``--map`` entries for a log whose columns use other names than the schema's (``acn-import``).

A column is matched to one of the schema's channels by the words in its name: for a joint, the
leg (``FR``, ``front_right``, ``RF``, ...), the joint (``hip`` / ``abad`` / ``HAA``, ``thigh`` /
``HFE``, ``calf`` / ``knee`` / ``KFE``) and the quantity (angle, velocity, command, torque, gains);
for the trunk, one axis and one quantity (``gyro_x``, ``angular_velocity.z``, ``acc_y``,
``orientation.w``, ``roll``, ``base_vel_x``); for a foot, its leg and ``contact`` (or a force,
with a threshold drawn from its readings: ``contact_threshold``). Only a column
that names one of each, and the only such column for that channel, is proposed (a column named
by its joint alone, ``FR_hip_joint``, is taken for the angle); units and frames are not guessed
(a map entry's ``scale`` converts units). The elements of an array column (``q[0]`` ... ``q[11]``,
``gyro[0]`` ... ``gyro[2]``) are read in the schema's order (``ARRAY_ORDER``), which the user
must confirm (legged_gym orders its legs FL, FR, RL, RR: ``--leg-order``).
"""

from __future__ import annotations

import re
from typing import Callable

import numpy as np

from acn.sim.state import FOOT_NAMES, JOINT_NAMES, STATE_NAMES

_LEGS = {  # the schema's leg -> word sets any one of which names it
    "FR": ({"fr"}, {"rf"}, {"front", "right"}),
    "FL": ({"fl"}, {"lf"}, {"front", "left"}),
    "RR": ({"rr"}, {"rh"}, {"hr"}, {"rear", "right"}, {"hind", "right"}, {"back", "right"}),
    "RL": ({"rl"}, {"lh"}, {"hl"}, {"rear", "left"}, {"hind", "left"}, {"back", "left"}),
}
_JOINTS = {"hip": {"hip", "abad", "abduction", "haa"}, "thigh": {"thigh", "hfe", "upper"},
           "calf": {"calf", "knee", "kfe", "shank", "lower"}}
_COMMAND = {"action", "actions", "cmd", "cmds", "command", "commands", "target", "targets", "des", "desired", "ref",
            "setpoint", "setpoints", "ff", "feedforward"}
_QUANTITY = {"pos": {"pos", "position", "q", "angle", "jpos", "qpos"},
             "vel": {"vel", "velocity", "dq", "qd", "qdot", "speed", "jvel", "qvel"},
             "torque": {"effort", "tau", "torque", "trq"},
             "kp": {"kp", "stiffness"}, "kd": {"kd", "damping"}}
# (command?, quantity) -> the schema's column for a joint
_CHANNEL = {(False, "pos"): "{j}_pos", (False, "vel"): "{j}_vel", (False, "torque"): "effort.{j}",
            (True, "pos"): "action.{j}", (True, None): "action.{j}", (True, "vel"): "action_vel.{j}",
            (True, "kp"): "action_kp.{j}", (True, "kd"): "action_kd.{j}",  # gains are sent: named either way
            (False, "kp"): "action_kp.{j}", (False, "kd"): "action_kd.{j}"}


def words(name: str) -> set[str]:
    """Lower-case words of a column name: split at non-letters-or-digits, camel case and digits
    (``FR_hip_joint_pos`` -> fr, hip, joint, pos; ``qDes`` -> q, des)."""
    spaced = re.sub(r"(?<=[a-z])(?=[A-Z])|(?<=[A-Za-z])(?=[0-9])|(?<=[0-9])(?=[A-Za-z])", " ", name)
    return {w.lower() for w in re.split(r"[^A-Za-z0-9]+", spaced) if w}


def _legs(w: set[str]) -> list[str]:
    """The schema's legs the words ``w`` name (any one of a leg's word sets)."""
    return [g for g, options in _LEGS.items() if any(o <= w for o in options)]


def _one(found: list[str]) -> str | None:
    return found[0] if len(found) == 1 else None


def channel_of(name: str) -> str | None:
    """The schema's channel a column name describes, or None where it is ambiguous
    (``FR_hip_dq`` -> ``FR_hip_vel``; ``q_des_FL_calf`` -> ``action.FL_calf``; ``gyro_x`` ->
    ``base_angvel_x``; ``FR_foot_contact`` -> ``FR_contact``)."""
    w = words(name)
    legs = _legs(w)
    joints = [j for j, options in _JOINTS.items() if options & w]
    if not legs and not joints:
        return _index_channel(w) or _trunk_channel(w)
    leg, joint = _one(legs), _one(joints)
    if leg is not None and not joints and "contact" in w and not _COMMAND & w:
        return f"{leg}_contact"
    if leg is None or joint is None:
        return None
    command = bool(_COMMAND & w)
    quantities = [q for q, options in _QUANTITY.items() if options & w]
    if len(quantities) > 1 and command and "pos" in quantities:  # q_des + vel: a velocity target
        quantities.remove("pos")
    if len(quantities) > 1:
        return None
    if not quantities and not command and "joint" in w:  # a column named by its joint alone holds its angle
        quantities = ["pos"]
    pattern = _CHANNEL.get((command, quantities[0] if quantities else None))
    return pattern.format(j=f"{leg}_{joint}") if pattern else None


_TIME = {"time", "timestamp", "stamp", "t"}      # a row's time (its unit is checked on import)
_EPISODE = {"episode", "episodes", "trial", "run"}  # which episode a row belongs to
_TIME_UNITS = {"ms": 1e-3, "us": 1e-6, "ns": 1e-9}  # a timestamp's unit named in its column, to seconds
_INDEX_OTHER = {"s", "sec", "secs", "seconds", "header", "ros", "index", "idx", "id", "number", "num", "wall",
                *_TIME_UNITS}


def _index_channel(w: set[str]) -> str | None:
    """``timestamp`` or ``episode_index`` from a name made of only such words (``time_s``,
    ``header.stamp``, ``episode_id``); ``step_time_ms`` and the like are left out."""
    for channel, options in (("timestamp", _TIME), ("episode_index", _EPISODE)):
        if options & w and w <= options | _INDEX_OTHER:
            return channel
    return None


_TRUNK = {  # the trunk's quantities (measured, not commanded) -> word sets that name them
    "quat": {"quat", "quaternion", "orientation", "orient"},
    "angvel": {"gyro", "gyroscope", "angvel", "omega"},
    "acc": {"acc", "accel", "accelerometer", "acceleration", "linacc"},
    "linvel": {"vel", "velocity", "linvel"},
    "pos": {"pos", "position", "base", "trunk", "body"},
}
_ANGULAR = {"angular", "ang", "rot", "rate"}
_NOT_TRUNK = {"foot", "feet", "toe", "leg", "joint", "motor", "force"}  # words of other bodies' quantities


def _trunk_channel(w: set[str]) -> str | None:
    """A trunk channel (position, Euler angle, quaternion, velocities, accelerometer) from words
    naming one axis and one quantity; commanded values (``cmd_vel_x``) are not measurements."""
    if _COMMAND & w or _NOT_TRUNK & w:
        return None
    angles = [a for a in ("roll", "pitch", "yaw") if a in w]
    axes = [a for a in ("x", "y", "z") if a in w]
    if {"rpy", "euler"} & w and len(axes) == 1 and not angles:  # rpy_x: the roll
        angles = [("roll", "pitch", "yaw")[("x", "y", "z").index(axes[0])]]
        axes = []
    if angles:
        moving = _ANGULAR | _TRUNK["angvel"] | _TRUNK["linvel"] | {"dot", "speed"}
        return f"base_{angles[0]}" if len(angles) == 1 and not axes and not moving & w else None
    if "w" in w and _TRUNK["quat"] & w and not axes:
        return "base_quat_w"
    if len(axes) != 1:
        return None
    kinds = [k for k, options in _TRUNK.items() if options & w]
    if "linvel" in kinds and _ANGULAR & w:  # angular_velocity_x
        kinds = [k for k in kinds if k != "linvel"] + ["angvel"]
    kinds = [k for k in dict.fromkeys(kinds) if k != "pos"] or kinds  # "base_vel_x": the velocity
    if len(kinds) != 1:
        return None
    return {"quat": "base_quat_{a}", "angvel": "base_angvel_{a}", "acc": "imu_acc_{a}", "linvel": "base_linvel_{a}",
            "pos": "base_pos_{a}"}[kinds[0]].format(a=axes[0])


_FORCE = {"force", "grf", "load"}  # a foot's force sensor: a contact flag above a threshold


def foot_force_of(name: str) -> str | None:
    """The leg whose foot force a column name describes (``FR_foot_force``, ``footForce[0]`` as
    ``footForce_FR`` by ``elements``), or None."""
    w = words(name)
    legs = _legs(w)
    if len(legs) != 1 or not _FORCE & w or _COMMAND & w or any(o & w for o in _JOINTS.values()):
        return None
    return legs[0]


def contact_threshold(force: np.ndarray) -> float | None:
    """The force that splits a foot's readings into swing and stance: the middle of the widest gap
    between the means of the two groups that leave the least variance within them (Otsu), or None
    where the readings do not fall into two groups (either under 5 % of the rows, or the groups'
    means closer than 3 of their pooled standard deviations)."""
    v = np.sort(force[np.isfinite(force)])
    n = len(v)
    if n < 20:
        return None
    k = np.arange(1, n)
    csum = np.cumsum(v)
    lo_mean, hi_mean = csum[:-1] / k, (csum[-1] - csum[:-1]) / (n - k)
    between = k * (n - k) * (hi_mean - lo_mean) ** 2  # Otsu: maximise the between-group variance
    ok = (k >= 0.05 * n) & (k <= 0.95 * n)
    if not ok.any():
        return None
    i = int(np.argmax(np.where(ok, between, -1.0)))
    low, high = v[: i + 1], v[i + 1:]
    spread = np.sqrt((low.var() * len(low) + high.var() * len(high)) / n)
    if high.mean() - low.mean() < 3.0 * spread:
        return None
    between_means = v[(v >= low.mean()) & (v <= high.mean())]  # Otsu's split leans into the wider group:
    j = int(np.argmax(np.diff(between_means)))                  # the widest gap between the means instead
    return float(0.5 * (between_means[j] + between_means[j + 1]))


def contact_of_force(name: str) -> str | None:
    """The contact flag a foot-force column can give (``foot_force_of``), or None."""
    leg = foot_force_of(name)
    return f"{leg}_contact" if leg is not None else None


def suggest_map(columns: list[str], wanted: list[str],
                describe: Callable[[str], str | None] = channel_of) -> dict[str, str | dict]:
    """Draft map entries {channel: column} for the ``wanted`` channels from the log's ``columns``:
    each channel with exactly one column that ``describe`` reads as it (``channel_of``; array
    elements by ``elements``); a timestamp in ms, us or ns by its name gets the ``scale`` to seconds."""
    found: dict[str, list[str]] = {}
    for c, described in [(c, c) for c in columns] + elements(columns):
        channel = describe(described)
        if channel in wanted:
            found.setdefault(channel, []).append(c)
    out: dict[str, str | dict] = {ch: cs[0] for ch in wanted if len(cs := found.get(ch, [])) == 1}
    if "timestamp" in out and (unit := [_TIME_UNITS[u] for u in _TIME_UNITS if u in words(out["timestamp"])]):
        out["timestamp"] = {"column": out["timestamp"], "scale": unit[0]}
    return out


def map_column(entry: str | dict) -> str:
    """The log's column a ``--map`` entry reads (a column name, or ``{"column": ..., ...}``)."""
    return entry if isinstance(entry, str) else entry["column"]


ARRAY_ORDER = "the schema's order: joints FR, FL, RR, RL x hip, thigh, calf (as Unitree's SDK), axes x, y, z"


def arrays_read(suggested: dict[str, str]) -> str:
    """"; arrays read in ..." where a draft map reads array elements (their order is assumed), else ""."""
    columns = [map_column(entry) for entry in suggested.values()]
    return f"; arrays read in {ARRAY_ORDER}" if any(c.endswith("]") for c in columns) else ""


def array_columns(columns: list[str]) -> dict[str, list[int]]:
    """The array columns among ``columns``, read one element each (``q[0]``, ``q[1]``, ...): base name -> indices."""
    arrays: dict[str, list[int]] = {}
    for c in columns:
        if (m := re.fullmatch(r"(.+)\[(\d+)\]", c)) is not None:
            arrays.setdefault(m.group(1), []).append(int(m.group(2)))
    return arrays


def elements(columns: list[str]) -> list[tuple[str, str]]:
    """(column, the name it would have) for the elements of array columns (``q[0]`` ... ``q[11]``,
    ``gyro[0]`` ... ``gyro[2]``, ``contact[0]`` ... ``contact[3]``), read in ``ARRAY_ORDER``: 12
    elements are the joints, 4 the feet, 3 the axes (roll, pitch, yaw for ``rpy``). A quaternion's
    order differs between libraries (w first or last): not read."""
    arrays = array_columns(columns)
    parts = {12: JOINT_NAMES, 4: FOOT_NAMES, 3: ("x", "y", "z")}
    out = []
    for base, index in arrays.items():
        names = parts.get(len(index))
        if names is None or sorted(index) != list(range(len(index))) or len(index) == 4 and _TRUNK["quat"] & words(base):
            continue
        out += [(f"{base}[{i}]", f"{base}_{names[i]}") for i in index]
    return out


QUAT_ORDERS = {"wxyz": "w first: MuJoCo, Unitree's SDK, Eigen's constructor",
               "xyzw": "w last: ROS, scipy, Eigen's coeffs()"}
LEVEL = 0.3  # |x|, |y| of a trunk's quaternion within 35 degrees of level (sin(35 deg / 2)), at the 90th percentile


def quaternion_order(q: np.ndarray) -> str | None:
    """The order of a 4-element array column (``q`` (rows, 4)) that holds the trunk's unit
    quaternion, read from the data: a legged robot's trunk stays near level, so its x and y
    components stay small (``LEVEL``) while w and z swing with the heading. "wxyz" where elements
    1 and 2 are the small ones, "xyzw" where 0 and 1 are; None where it cannot tell (a heading
    near 0 in one order reads as a heading near pi in the other: elements 0, 1 and 2 all small),
    where the trunk is not near level, or where the rows are not unit quaternions."""
    q = np.asarray(q, float)
    q = q[np.isfinite(q).all(axis=1)]
    if len(q) < 10 or not unit_quaternions(q):
        return None
    small = {i for i in range(4) if np.percentile(np.abs(q[:, i]), 90) < LEVEL}
    first, last = {1, 2} <= small, {0, 1} <= small
    return "wxyz" if first and not last else "xyzw" if last and not first else None


def quaternion_arrays(table: dict[str, np.ndarray], columns: list[str]) -> dict[str, str | None]:
    """The 4-element array columns among ``columns`` (``quat[0]`` ... ``quat[3]``) whose rows are
    unit quaternions, by base name -> their order (``quaternion_order``; None: not told by the data)."""
    out = {}
    for base, index in array_columns(columns).items():
        if sorted(index) != [0, 1, 2, 3]:
            continue
        q = np.stack([np.asarray(table[f"{base}[{i}]"], float) for i in range(4)], axis=1)
        if unit_quaternions(q[np.isfinite(q).all(axis=1)]):
            out[base] = quaternion_order(q)
    return out


def unit_quaternions(q: np.ndarray) -> bool:
    """Whether rows ``q`` (rows, 4) are unit quaternions: the median norm within 0.01 of 1 (a
    sensor's noise moves single rows off it)."""
    return len(q) > 0 and bool(np.median(np.abs(np.linalg.norm(q, axis=1) - 1.0)) < 0.01)


def quaternion_note(base: str, order: str | None) -> str:
    """What the draft map does with a quaternion array: mapped in the order the data show, or left to the user."""
    if order is not None:
        return (f"{base}[0..3] read as the trunk's quaternion in {order} order ({QUAT_ORDERS[order]}), told by the "
                "data: its x and y stay small, as a trunk near level")
    return (f"{base}[0..3] look like the trunk's quaternion, in an order the data do not tell (the heading stays near "
            f"0 or pi, or the trunk is not near level): map base_quat_w, _x, _y, _z to its elements in the order the "
            f"logger writes ({'; '.join(QUAT_ORDERS.values())})")


CHANNELS = ("timestamp", "episode_index") + STATE_NAMES + tuple(f"base_quat_{a}" for a in "wxyz") + tuple(
    f"{k}.{j}" for k in ("action", "effort", "action_vel", "action_kp", "action_kd") for j in JOINT_NAMES)
