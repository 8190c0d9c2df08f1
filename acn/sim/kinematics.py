"""Link poses of recorded states by MuJoCo forward kinematics (``mj_kinematics``).

The model is the nominal A1 of ``acn.sim.backends.mujoco_backend.build_spec``. MuJoCo's
URDF import keeps one body per moving URDF link with the link's own frame (fixed links such
as the toes and the IMU are merged into their parents), so a body's ``xpos`` / ``xquat`` IS
the world pose of the URDF link of the same name, where the URDF's visual meshes attach.

Only the trunk pose and the joint angles of a state matter: ``base_pos`` (trunk origin,
world, m), ``base_rpy`` (extrinsic XYZ, rad) and ``<joint>_pos`` (rad).
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from acn.sim.backends.base import SimConfig
from acn.sim.robot import URDF_JOINT
from acn.sim.rotations import rpy_to_quat
from acn.sim.state import FOOT_NAMES, JOINT_NAMES, SLICES

FOOT_RADIUS = 0.02  # m, the URDF's toe spheres


@dataclass
class LinkPoses:
    """World poses of ``links`` and feet over T frames (float64)."""

    links: tuple[str, ...]
    translation: np.ndarray  # (T, L, 3) link origin, world, m
    quaternion: np.ndarray   # (T, L, 4) link orientation, world, (x, y, z, w)
    foot: np.ndarray         # (T, 4, 3) foot sphere centres in FOOT_NAMES order, world, m


class RobotKinematics:
    """Forward kinematics of the A1 (one private ``MjData``; not thread-safe)."""

    def __init__(self) -> None:
        from acn.sim.backends.mujoco_backend import build_spec

        self.model = build_spec(SimConfig()).compile()
        self.data = mujoco.MjData(self.model)
        m = self.model
        body = mujoco.mjtObj.mjOBJ_BODY
        self.links: tuple[str, ...] = tuple(mujoco.mj_id2name(m, body, b) for b in range(1, m.nbody))
        self._bodies = np.arange(1, m.nbody)
        self._qadr = np.array([m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, URDF_JOINT[j])]
                               for j in JOINT_NAMES])
        # The toe links are merged into the calves: a foot is the sphere geom ``<foot>_foot``.
        self.foot_geoms = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"{f}_foot")
                                    for f in FOOT_NAMES])  # geom ids of the foot spheres

    def qpos(self, states: np.ndarray) -> np.ndarray:
        """MuJoCo ``qpos`` rows (T, nq) for state vectors (T, 43)."""
        s = np.asarray(states, dtype=np.float64)
        q = np.tile(self.model.qpos0, (len(s), 1))
        q[:, 0:3] = s[:, SLICES["base_pos"]]
        x, y, z, w = rpy_to_quat(s[:, SLICES["base_rpy"]].T)  # vectorised over columns
        q[:, 3:7] = np.stack([w, x, y, z], axis=1)               # MuJoCo: scalar first
        q[:, self._qadr] = s[:, SLICES["joint_pos"]]
        return q

    def poses(self, states: np.ndarray) -> LinkPoses:
        """Link and foot poses for state vectors (T, 43); one ``mj_kinematics`` per frame."""
        qpos = self.qpos(states)
        m, d = self.model, self.data
        n = len(qpos)
        xpos = np.empty((n, m.nbody, 3))
        xquat = np.empty((n, m.nbody, 4))
        gpos = np.empty((n, m.ngeom, 3))
        d_qpos, d_xpos, d_xquat, d_gpos = d.qpos, d.xpos, d.xquat, d.geom_xpos  # views, held once
        kinematics = mujoco.mj_kinematics
        for i in range(n):
            d_qpos[:] = qpos[i]
            kinematics(m, d)
            xpos[i] = d_xpos
            xquat[i] = d_xquat
            gpos[i] = d_gpos
        quat = xquat[:, self._bodies][..., [1, 2, 3, 0]]  # to (x, y, z, w)
        return LinkPoses(self.links, xpos[:, self._bodies], quat, gpos[:, self.foot_geoms])
