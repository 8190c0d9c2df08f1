"""Draft ``--map`` entries for a log whose joint columns use other names (``acn-import --suggest-map``).

A column is matched to one of the schema's per-joint channels by the words in its name: the leg
(``FR``, ``front_right``, ``RF``, ...), the joint (``hip`` / ``abad`` / ``HAA``, ``thigh`` /
``HFE``, ``calf`` / ``knee`` / ``KFE``) and the quantity (angle, velocity, command, torque, gains).
Only a column that names one leg, one joint and one quantity, and the only such column for that
channel, is proposed (a column named by its joint alone, ``FR_hip_joint``, is taken for the
angle); units are not guessed (a map entry's ``scale`` converts them). Numbered
joints (``q[0]`` ... ``q[11]``) carry no words: their order is the user's to state.
"""

from __future__ import annotations

import re

from acn.toolkit.state import JOINT_NAMES

_LEGS = {  # the schema's leg -> word sets any one of which names it
    "FR": ({"fr"}, {"rf"}, {"front", "right"}),
    "FL": ({"fl"}, {"lf"}, {"front", "left"}),
    "RR": ({"rr"}, {"rh"}, {"hr"}, {"rear", "right"}, {"hind", "right"}, {"back", "right"}),
    "RL": ({"rl"}, {"lh"}, {"hl"}, {"rear", "left"}, {"hind", "left"}, {"back", "left"}),
}
_JOINTS = {"hip": {"hip", "abad", "abduction", "haa"}, "thigh": {"thigh", "hfe", "upper"},
           "calf": {"calf", "knee", "kfe", "shank", "lower"}}
_COMMAND = {"action", "cmd", "command", "target", "des", "desired", "ref", "setpoint", "ff", "feedforward"}
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


def _one(found: list[str]) -> str | None:
    return found[0] if len(found) == 1 else None


def channel_of(name: str) -> str | None:
    """The schema's per-joint channel a column name describes, or None where it names no single
    leg, joint and quantity (``FR_hip_dq`` -> ``FR_hip_vel``; ``q_des_FL_calf`` -> ``action.FL_calf``)."""
    w = words(name)
    leg = _one([g for g, options in _LEGS.items() if any(o <= w for o in options)])
    joint = _one([j for j, options in _JOINTS.items() if options & w])
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


def suggest_map(columns: list[str], wanted: list[str]) -> dict[str, str]:
    """Draft map entries {channel: column} for the ``wanted`` channels from the log's ``columns``:
    each channel with exactly one column that describes it (``channel_of``)."""
    found: dict[str, list[str]] = {}
    for c in columns:
        channel = channel_of(c)
        if channel in wanted:
            found.setdefault(channel, []).append(c)
    return {ch: cs[0] for ch in wanted if len(cs := found.get(ch, [])) == 1}


PER_JOINT = tuple(f"{j}_{q}" for q in ("pos", "vel") for j in JOINT_NAMES) + tuple(
    f"{k}.{j}" for k in ("action", "effort", "action_vel", "action_kp", "action_kd") for j in JOINT_NAMES)
