"""The Unitree A1 description both simulators are built from.

Source: ``pybullet_data/a1/a1.urdf`` (shipped with pybullet). PyBullet loads it directly;
MuJoCo compiles the same file through ``mujoco.MjSpec``. Everything a backend needs to
build the model (file, joint map, stance, gains, nominal physical parameters) is here, so
the two backends cannot drift apart.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from acn.toolkit.state import FOOT_NAMES, JOINT_NAMES, NUM_JOINTS

# Our joint names -> the URDF's joint names (the URDF says upper/lower for thigh/calf).
URDF_JOINT: dict[str, str] = {
    j: j.replace("_thigh", "_upper_joint").replace("_calf", "_lower_joint").replace("_hip", "_hip_joint")
    for j in JOINT_NAMES
}
URDF_FOOT_LINK: dict[str, str] = {f: f"{f}_toe" for f in FOOT_NAMES}
TRUNK_LINK = "trunk"

# Stance (rad): hip 0, thigh 0.8, calf -1.6 for every leg; feet straight under the hips.
STANCE = np.tile(np.array([0.0, 0.8, -1.6]), 4)
# Trunk height (m) at which the stance feet (sphere radius 0.02 m) just touch flat ground:
# 0.2*cos(0.8) + 0.2*cos(-0.8) + 0.02 = 0.2987 m, rounded up by 1.3 mm.
STANDING_HEIGHT = 0.30
GRAVITY = 9.81  # m/s^2, along -z of the world frame


def urdf_path() -> str:
    """Absolute path of the A1 URDF inside the installed ``pybullet_data``."""
    import pybullet_data

    path = os.path.join(pybullet_data.getDataPath(), "a1", "a1.urdf")
    if not os.path.exists(path):
        raise FileNotFoundError(f"A1 URDF not found at {path}; is pybullet installed?")
    return path


@dataclass
class ModelParams:
    """Physical parameters written into a simulator when its model is built.

    Nominal values reproduce the URDF (which has no joint damping or friction) on rigid
    ground of friction 1. Physical effects (``acn.toolkit.effects``) change these values;
    each backend writes all of them, so both simulators see the same description.
    """

    joint_damping: np.ndarray = field(default_factory=lambda: np.zeros(NUM_JOINTS))   # N m s/rad
    joint_friction: np.ndarray = field(default_factory=lambda: np.zeros(NUM_JOINTS))  # N m (Coulomb)
    payload_mass: float = 0.0   # kg added to the trunk at its centre of mass
    ground_friction: float = 1.0  # sliding friction coefficient, foot-ground

    def __post_init__(self) -> None:
        self.joint_damping = np.broadcast_to(np.asarray(self.joint_damping, float), (NUM_JOINTS,)).copy()
        self.joint_friction = np.broadcast_to(np.asarray(self.joint_friction, float), (NUM_JOINTS,)).copy()
