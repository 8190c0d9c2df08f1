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
mode, gains, policy, seed, channel names, the fall rule and how each episode ended; its typed
form, read and written, is ``acn.datasets.metadata.AcnMetadata``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from acn.outputs.kinds import Output, json_object
from acn.sim.state import ACTION_DIM, ACTION_NAMES, HYBRID_NAMES, STATE_DIM, STATE_NAMES

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


# The least a dataset takes on disk, for refusing a collection its disk cannot hold before it runs:
# half the frame's raw bytes (simulated floats hardly compress; the half leaves room for columns
# that do) and lerobot's metadata files.
INDEX_BYTES = 4 + 4 * 8          # timestamp (float32), frame, episode, global and task index (int64)
META_BYTES = 64_000


def least_bytes(frames: int, paired: bool, hybrid: bool = False) -> int:
    """A lower bound of the bytes a dataset of ``frames`` frames takes (see ``META_BYTES``)."""
    size = {"float32": 4, "bool": 1}
    row = INDEX_BYTES + sum(size[f["dtype"]] * int(np.prod(f["shape"])) for f in features(paired, hybrid).values())
    return int(META_BYTES + 0.5 * row * frames)


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
