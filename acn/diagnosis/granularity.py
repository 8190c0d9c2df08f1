"""How finely a joint parameter is fitted: one number shared by all joints (``shared``), one per
joint type (``type``: hip, thigh, calf), one per leg (``leg``) or one per joint (``joint``),
coarsest first. The configuration (``problem.DiagnoseConfig.finest``) and the fits
(``fitting.FreeParameters``) both speak of them."""

from __future__ import annotations

import numpy as np

from acn.sim.state import FOOT_NAMES, JOINT_NAMES, NUM_JOINTS

GRANULARITIES = ("shared", "type", "leg", "joint")
GROUP_OF_JOINT = {  # granularity -> (12,) the group each joint's value belongs to
    "shared": np.zeros(NUM_JOINTS, dtype=int),
    "type": np.tile(np.arange(3), 4),
    "leg": np.repeat(np.arange(4), 3),
    "joint": np.arange(NUM_JOINTS),
}
GROUP_LABELS = {"shared": ("all",), "type": ("hip", "thigh", "calf"), "leg": FOOT_NAMES, "joint": JOINT_NAMES}


def finer(granularity: str, held: str) -> bool:
    """Whether ``granularity`` is finer than ``held`` (False where nothing is held: ``held`` "")."""
    return bool(held) and GRANULARITIES.index(granularity) > GRANULARITIES.index(held)
