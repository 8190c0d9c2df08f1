"""What a collected dataset contains: LeRobot features and the ``acn`` metadata block.

Per frame (one control step t of one episode):

=============================  ======================================================
``observation.state``          s_t of the source simulator (``acn.toolkit.state`` names)
``action``                     a_t sent to the source (joint targets or torques)
``observation.effort``         mean applied joint torque over the step in the source, N m
``next.observation.state``     s_{t+1} of the source (so the last transition is complete)
``next.fallen``                s_{t+1} of the source meets the fall rule
``next.done``                  this is the last frame of the episode
``target.*``                   the same four columns and ``target.next.fallen`` for the
                               target simulator (paired datasets only); ``target.action``
                               differs from ``action`` only when a corrector is applied
=============================  ======================================================

``meta/info.json`` gets an ``acn`` block (``ACN_KEY``): simulators and versions, rates, action
mode, gains, policy, seed, channel names, the fall rule and how each episode ended.
"""

from __future__ import annotations

from acn.toolkit.state import ACTION_DIM, ACTION_NAMES, STATE_DIM, STATE_NAMES

ACN_KEY = "acn"
FORMAT_VERSION = 1
ROBOT_TYPE = "unitree_a1"
TARGET_PREFIX = "target."

STATE = "observation.state"
ACTION = "action"
EFFORT = "observation.effort"
NEXT_STATE = "next.observation.state"
NEXT_FALLEN = "next.fallen"
DONE = "next.done"
PER_SIMULATOR = (STATE, ACTION, EFFORT, NEXT_STATE, NEXT_FALLEN)


def target_key(key: str) -> str:
    return TARGET_PREFIX + key


def features(paired: bool) -> dict[str, dict]:
    """LeRobot feature spec (float32 vectors with channel names, bool flags)."""
    state = {"dtype": "float32", "shape": (STATE_DIM,), "names": list(STATE_NAMES)}
    joint = {"dtype": "float32", "shape": (ACTION_DIM,), "names": list(ACTION_NAMES)}
    flag = {"dtype": "bool", "shape": (1,), "names": None}
    per_sim = {STATE: state, ACTION: joint, EFFORT: joint, NEXT_STATE: state, NEXT_FALLEN: flag}
    out = dict(per_sim)
    if paired:
        out.update({target_key(k): v for k, v in per_sim.items()})
    out[DONE] = flag
    return out
