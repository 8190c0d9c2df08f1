"""What a collected dataset contains: LeRobot features and the ``acn`` metadata block.

Per frame (one control step t of one episode):

=============================  ======================================================
``observation.state``          s_t of the source simulator (``acn.sim.state`` names)
``action``                     a_t sent to the source (joint targets or torques)
``observation.effort``         mean applied joint torque over the step in the source, N m
``next.observation.state``     s_{t+1} of the source (so the last transition is complete)
``next.fallen``                s_{t+1} of the source meets the fall rule
``next.done``                  this is the last frame of the episode
``action.hybrid``              kp, kd, a velocity target and a feedforward torque (N m/rad,
                               N m s/rad, rad/s, N m; 12 each) sent with ``action`` as a hybrid
                               (MIT-style) command (``acn.hybrid_actions``; imported logs only;
                               36 wide, kp, kd and kd dq_des + tau_ff, before format 2)
``target.*``                   the same four columns and ``target.next.fallen`` for the
                               target simulator (paired datasets only); ``target.action``
                               differs from ``action`` only when a corrector is applied
=============================  ======================================================

``meta/info.json`` gets an ``acn`` block (``ACN_KEY``): simulators and versions, rates, action
mode, gains, policy, seed, channel names, the fall rule and how each episode ended.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from acn.outputs import Output, json_object
from acn.sim.state import ACTION_DIM, ACTION_NAMES, HYBRID_NAMES, STATE_DIM, STATE_NAMES

if TYPE_CHECKING:
    from acn.sim.backends import SimConfig

ACN_KEY = "acn"
FORMAT_VERSION = 2  # 2: action.hybrid with the velocity target (48 wide, was 36)
ROBOT_TYPE = "unitree_a1"
TARGET_PREFIX = "target."

STATE = "observation.state"
ACTION = "action"
EFFORT = "observation.effort"
NEXT_STATE = "next.observation.state"
NEXT_FALLEN = "next.fallen"
DONE = "next.done"
ACTION_HYBRID = "action.hybrid"
PER_SIMULATOR = (STATE, ACTION, EFFORT, NEXT_STATE, NEXT_FALLEN)


def is_dataset(path: Path) -> bool:
    """``path`` is a dataset this toolkit wrote: its ``meta/info.json`` has an ``acn`` block."""
    info = json_object(Path(path) / "meta" / "info.json")
    return info is not None and isinstance(info.get(ACN_KEY), dict)


DATASET = Output("dataset directory", directory=True, recognise=is_dataset)


def target_key(key: str) -> str:
    return TARGET_PREFIX + key


def features(paired: bool, hybrid: bool = False) -> dict[str, dict]:
    """LeRobot feature spec (float32 vectors with channel names, bool flags); ``hybrid``: with
    ``action.hybrid`` (unpaired only)."""
    state = {"dtype": "float32", "shape": (STATE_DIM,), "names": list(STATE_NAMES)}
    joint = {"dtype": "float32", "shape": (ACTION_DIM,), "names": list(ACTION_NAMES)}
    flag = {"dtype": "bool", "shape": (1,), "names": None}
    per_sim = {STATE: state, ACTION: joint, EFFORT: joint, NEXT_STATE: state, NEXT_FALLEN: flag}
    out = dict(per_sim)
    if paired:
        out.update({target_key(k): v for k, v in per_sim.items()})
    out[DONE] = flag
    if hybrid:
        out[ACTION_HYBRID] = {"dtype": "float32", "shape": (len(HYBRID_NAMES),), "names": list(HYBRID_NAMES)}
    return out


def _number(positive: bool):
    def ok(v) -> bool:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and v == v and abs(v) != float("inf") \
            and (v > 0 if positive else v >= 0)
    return ok


def _gains(v) -> bool:
    """A PD gain: a number >= 0 for every joint, or a list of 12 (one per joint)."""
    values = v if isinstance(v, list) and len(v) == ACTION_DIM else [v]
    return all(_number(False)(x) for x in values)


def _simulator(v) -> bool:
    return isinstance(v, dict) and isinstance(v.get("simulator"), str)


# Keys of the ``acn`` block every reader relies on, and what each must be.
REQUIRED = {
    "paired": (lambda v: isinstance(v, bool), "true or false"),
    "source": (_simulator, 'an object with a "simulator" name'),
    "target": (lambda v: v is None or _simulator(v), 'null or an object with a "simulator" name'),
    "physics_dt": (_number(True), "a number > 0 (s)"),
    "substeps": (lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= 1, "a whole number >= 1"),
    "control_hz": (_number(True), "a number > 0 (Hz)"),
    "action_mode": (lambda v: v in ("position", "torque"), '"position" or "torque"'),
    "kp": (_gains, f"a number >= 0 or a list of {ACTION_DIM} (one per joint)"),
    "kd": (_gains, f"a number >= 0 or a list of {ACTION_DIM} (one per joint)"),
    "torque_limit": (_number(True), "a number > 0 (N m)"),
    "model_params": (lambda v: isinstance(v, dict), "an object"),
    "policy": (lambda v: isinstance(v, str), "a name"),
    "state_names": (lambda v: v == list(STATE_NAMES), f"this toolkit's {STATE_DIM} state channel names"),
    "action_names": (lambda v: v == list(ACTION_NAMES), f"this toolkit's {ACTION_DIM} joint names"),
}
OPTIONAL = {
    "hybrid_actions": (lambda v: isinstance(v, bool), "true or false"),
    "missing_channels": (lambda v: isinstance(v, list) and all(n in STATE_NAMES for n in v),
                         "a list of state channel names"),
    # what the accelerometer averages over (``SimConfig.imu_acc``); absent or null: not stated (acn-diagnose judges it)
    "imu_acc": (lambda v: v is None or v in ("mean", "instant"), 'null, "mean" or "instant"'),
}


def acn_block_problem(acn) -> str | None:
    """What is wrong with a dataset's ``acn`` block, as a phrase after the dataset's path
    ("DIR has no 'kp' in ..."), or None if every reader can use it."""
    if not isinstance(acn, dict):
        return f"has an '{ACN_KEY}' block that is not an object"
    for key, (ok, what) in REQUIRED.items():
        if key == "state_names" and acn.get(key) != list(STATE_NAMES):
            return "has different state channels than this toolkit"
        if key not in acn:
            return f"has no {key!r} in its '{ACN_KEY}' block (meta/info.json)"
        if not ok(acn[key]):
            return f"has '{ACN_KEY}.{key}' = {acn[key]!r:.60} in meta/info.json; it must be {what}"
    for key, (ok, what) in OPTIONAL.items():
        if key in acn and not ok(acn[key]):
            return f"has '{ACN_KEY}.{key}' = {acn[key]!r:.60} in meta/info.json; it must be {what}"
    if acn.get("hybrid_actions") and acn["action_mode"] != "position":
        return (f"has '{ACN_KEY}.hybrid_actions' with action mode {acn['action_mode']!r}: hybrid commands need "
                "position mode")
    if abs(acn["physics_dt"] * acn["substeps"] * acn["control_hz"] - 1.0) > 1e-6:
        return (f"has inconsistent rates in meta/info.json: physics_dt {acn['physics_dt']} s x substeps "
                f"{acn['substeps']} is not one control period (control_hz {acn['control_hz']})")
    return None


def control_config(acn: dict, **extra) -> SimConfig:
    """The simulator settings an ``acn`` block records (rates, action mode, gains, torque limit,
    what the accelerometer reads; an unstated reading is the schema's mean), plus ``extra``
    ``SimConfig`` fields."""
    from acn.sim.backends import SimConfig  # at run time only: readers of the schema need no simulator

    return SimConfig(physics_dt=acn["physics_dt"], substeps=acn["substeps"], action_mode=acn["action_mode"],
                     kp=acn["kp"], kd=acn["kd"], torque_limit=acn["torque_limit"],
                     imu_acc=acn.get("imu_acc") or "mean", **extra)
