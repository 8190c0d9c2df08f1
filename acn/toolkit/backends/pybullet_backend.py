"""PyBullet implementation of ``Backend``: one private physics client per instance (DIRECT)."""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
from functools import partial

import numpy as np


@contextlib.contextmanager
def _quiet_stdio():
    """Silence C-level stdout/stderr: pybullet prints its build time on import, argv on connect."""
    sys.stdout.flush()
    sys.stderr.flush()
    saved = [os.dup(1), os.dup(2)]
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.dup2(devnull, 2)
    try:
        yield
    finally:
        ctypes.CDLL(None).fflush(None)  # C's buffered output goes to /dev/null, not to our caller
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)


with _quiet_stdio():
    import pybullet
import pybullet_data  # noqa: E402

from acn.toolkit.backends.base import Backend, pd_torque
from acn.toolkit.rotations import cross
from acn.toolkit.robot import GRAVITY, TRUNK_LINK, URDF_FOOT_LINK, URDF_JOINT, urdf_path
from acn.toolkit.state import FOOT_NAMES, JOINT_NAMES


class _Client:
    """pybullet's functions bound to one physics client. Unlike ``BulletClient`` it binds each
    function once (BulletClient builds a partial on every call: measurable at 20k calls/s)."""

    def __init__(self) -> None:
        with _quiet_stdio():
            self.id = pybullet.connect(pybullet.DIRECT)

    def __getattr__(self, name: str):
        fn = partial(getattr(pybullet, name), physicsClientId=self.id)
        setattr(self, name, fn)
        return fn


class PyBulletBackend(Backend):
    """The A1 in PyBullet.

    PyBullet reports and sets the base at its centre of mass; this backend converts to and
    from the trunk link origin so that both backends describe the same point. Default
    velocity motors are disabled (force 0) so that only our control law drives the joints;
    joint friction, when set, is a velocity motor with target 0 and max force = friction.
    """

    name = "pybullet"

    def _build(self) -> None:
        self._client = _Client()
        self._client.setAdditionalSearchPath(pybullet_data.getDataPath())
        self._load_world()

    def _restore_initial(self) -> None:
        # restoreState() is not enough: solver caches survive it and make an episode depend on
        # the ones before it (measured: 5e-6 after 20 steps). A rebuilt world is deterministic.
        self._client.resetSimulation()
        self._load_world()

    def _load_world(self) -> None:
        cfg, prm, c = self.config, self.config.params, self._client
        c.setGravity(0, 0, -GRAVITY)
        c.setPhysicsEngineParameter(fixedTimeStep=cfg.physics_dt, numSubSteps=0)
        self._plane = c.loadURDF("plane.urdf")
        self._robot = c.loadURDF(urdf_path(), [0, 0, 0.5], flags=pybullet.URDF_USE_INERTIA_FROM_FILE | pybullet.URDF_IGNORE_VISUAL_SHAPES)
        joints = [c.getJointInfo(self._robot, i) for i in range(c.getNumJoints(self._robot))]
        by_name = {j[1].decode(): j[0] for j in joints}
        links = {j[12].decode(): j[0] for j in joints}
        self._joints = [by_name[URDF_JOINT[j]] for j in JOINT_NAMES]
        self._feet = np.array([links[URDF_FOOT_LINK[f]] for f in FOOT_NAMES])
        assert TRUNK_LINK == c.getBodyInfo(self._robot)[0].decode()

        # Nominal physics: no body damping, the parameters of ModelParams, ground friction.
        c.changeDynamics(self._plane, -1, lateralFriction=1.0)
        for link in [-1, *range(len(joints))]:
            c.changeDynamics(self._robot, link, linearDamping=0.0, angularDamping=0.0)
        for f in self._feet:
            c.changeDynamics(self._robot, int(f), lateralFriction=prm.ground_friction)
        for k, j in enumerate(self._joints):
            c.changeDynamics(self._robot, j, jointDamping=float(prm.joint_damping[k]))
        if prm.payload_mass:
            mass = c.getDynamicsInfo(self._robot, -1)[0]
            c.changeDynamics(self._robot, -1, mass=mass + prm.payload_mass)
        c.setJointMotorControlArray(self._robot, self._joints, pybullet.VELOCITY_CONTROL,
                                    targetVelocities=[0.0] * 12, forces=list(prm.joint_friction))

        # Trunk link origin relative to the centre-of-mass frame PyBullet uses for the base.
        info = c.getDynamicsInfo(self._robot, -1)
        self._com_in_link = (info[3], info[4])
        self._link_in_com = c.invertTransform(*self._com_in_link)

    def _read_dynamics(self):
        c, r = self._client, self._robot
        com_pos, com_orn = c.getBasePositionAndOrientation(r)
        v_com, w = c.getBaseVelocity(r)
        pos, orn = c.multiplyTransforms(com_pos, com_orn, *self._link_in_com)
        pos, v_com, w = np.array(pos), np.array(v_com), np.array(w)
        v = v_com + cross(w, pos - np.array(com_pos))
        q, qd = self._joint_state()
        return pos, np.array(orn), v, w, q, qd

    def _joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        js = self._client.getJointStates(self._robot, self._joints)
        return np.array([s[0] for s in js]), np.array([s[1] for s in js])

    def _write_dynamics(self, pos, quat, v_world, w_world, q, qd) -> None:
        c, r = self._client, self._robot
        com_pos, com_orn = c.multiplyTransforms(list(pos), list(quat), *self._com_in_link)
        v_com = v_world + cross(w_world, np.array(com_pos) - pos)
        c.resetBasePositionAndOrientation(r, com_pos, com_orn)
        c.resetBaseVelocity(r, list(v_com), list(w_world))
        for k, j in enumerate(self._joints):
            c.resetJointState(r, j, float(q[k]), float(qd[k]))

    def _read_contacts(self) -> np.ndarray:
        pts = self._client.getContactPoints(bodyA=self._robot, bodyB=self._plane)
        touching = {p[3] for p in pts if p[9] > 0.0}
        return np.array([1.0 if f in touching else 0.0 for f in self._feet])

    def _advance(self, action: np.ndarray) -> np.ndarray:
        cfg, r, joints, c = self.config, self._robot, self._joints, self._client
        total = np.zeros(12)
        tau = self._clip_torque(action)
        for _ in range(cfg.substeps):
            if cfg.action_mode == "position":
                q, qd = self._joint_state()
                tau = pd_torque(action, q, qd, cfg)
            c.setJointMotorControlArray(r, joints, pybullet.TORQUE_CONTROL, forces=tau)
            c.stepSimulation()
            total += tau
        return total / cfg.substeps

    def close(self) -> None:
        if getattr(self, "_client", None) is not None:
            try:
                self._client.disconnect()
            except pybullet.error:
                pass
            self._client = None
