"""PyBullet implementation of ``Backend``: one private physics client per instance (DIRECT)."""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
import tempfile
import xml.etree.ElementTree as ET
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

from acn.sim.backends.base import Backend
from acn.sim.robot import (GRAVITY, GROUND_TIMECONST, TRUNK_LINK, URDF_FOOT_LINK, URDF_JOINT, ModelParams,
                              combine_point_mass, urdf_path)
from acn.sim.rotations import cross
from acn.sim.state import FOOT_NAMES, JOINT_NAMES


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


def _inertia_tensor(inertial: ET.Element) -> np.ndarray:
    i = {k: float(v) for k, v in inertial.find("inertia").attrib.items()}
    return np.array([[i["ixx"], i["ixy"], i["ixz"]], [i["ixy"], i["iyy"], i["iyz"]], [i["ixz"], i["iyz"], i["izz"]]])


def _set_inertia(inertial: ET.Element, tensor: np.ndarray) -> None:
    names = {"ixx": (0, 0), "ixy": (0, 1), "ixz": (0, 2), "iyy": (1, 1), "iyz": (1, 2), "izz": (2, 2)}
    inertial.find("inertia").attrib.update({k: repr(float(tensor[ij])) for k, ij in names.items()})


def urdf_with_inertials(params: ModelParams) -> str | None:
    """The A1 URDF text with the payload and rotor inertias written in, or None if nominal.

    PyBullet has no joint armature: the rotor is added to the child link as a thin disc of
    inertia ``armature`` about the joint axis (and half of it about the two other axes, which
    keeps the tensor physical; unlike a true reflected inertia it also couples to the trunk's
    rotation). The payload is combined into the trunk's inertial (mass, origin, tensor). The
    inertial origins of the A1's links carry no rotation, so tensors are in the link frame.
    """
    if params.payload_mass <= 0 and not np.any(params.armature):
        return None
    root = ET.parse(urdf_path()).getroot()
    links = {link.get("name"): link for link in root.findall("link")}
    base = os.path.dirname(urdf_path())
    for mesh in root.iter("mesh"):  # the rewritten file lives elsewhere: absolute mesh paths
        mesh.set("filename", os.path.join(base, mesh.get("filename")))
    if params.payload_mass > 0:
        inertial = links[TRUNK_LINK].find("inertial")
        origin = inertial.find("origin")
        com = np.array([float(x) for x in origin.get("xyz").split()])
        mass, com, tensor = combine_point_mass(float(inertial.find("mass").get("value")), com,
                                               _inertia_tensor(inertial), params.payload_mass, params.payload_com)
        inertial.find("mass").set("value", repr(float(mass)))
        origin.set("xyz", " ".join(repr(float(x)) for x in com))
        _set_inertia(inertial, tensor)
    joints = {j.get("name"): j for j in root.findall("joint")}  # not those inside <transmission>
    for k, name in enumerate(JOINT_NAMES):
        if params.armature[k]:
            joint = joints[URDF_JOINT[name]]
            axis = np.array([float(x) for x in joint.find("axis").get("xyz").split()])
            inertial = links[joint.find("child").get("link")].find("inertial")
            _set_inertia(inertial, _inertia_tensor(inertial) + params.armature[k] * (np.eye(3) + np.outer(axis, axis)) / 2)
    return ET.tostring(root, encoding="unicode")


# m, how deep MuJoCo's contact at the nominal time constant lets the standing A1 sink (1.32 mm
# measured; the sink grows as the time constant squared up to ~0.06 s: 11.8 mm there).
MUJOCO_NOMINAL_SINK = 1.32e-3


def soft_contact(timeconst: float, robot_mass: float) -> tuple[float, float]:
    """PyBullet foot ``contactStiffness`` (N/m) and ``contactDamping`` (N s/m) for a ground of
    MuJoCo time constant ``timeconst`` (s): the stiffness that lets the standing robot sink as
    deep as MuJoCo's contact does (each foot carrying a quarter of the weight), critically
    damped for a quarter of the mass. An approximation, as the armature's rotor disc is."""
    load = robot_mass * GRAVITY / 4.0
    stiffness = load / (MUJOCO_NOMINAL_SINK * (timeconst / GROUND_TIMECONST) ** 2)
    return stiffness, 2.0 * np.sqrt(stiffness * robot_mass / 4.0)


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
        self._urdf, self._own_urdf = urdf_path(), False
        text = urdf_with_inertials(self.config.params)
        if text is not None:
            fd, self._urdf = tempfile.mkstemp(prefix="acn_a1_", suffix=".urdf")
            with os.fdopen(fd, "w") as f:
                f.write(text)
            self._own_urdf = True
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
        self._robot = c.loadURDF(self._urdf, [0, 0, 0.5], flags=pybullet.URDF_USE_INERTIA_FROM_FILE | pybullet.URDF_IGNORE_VISUAL_SHAPES)
        joints = [c.getJointInfo(self._robot, i) for i in range(c.getNumJoints(self._robot))]
        by_name = {j[1].decode(): j[0] for j in joints}
        links = {j[12].decode(): j[0] for j in joints}
        self._joints = [by_name[URDF_JOINT[j]] for j in JOINT_NAMES]
        self._feet = np.array([links[URDF_FOOT_LINK[f]] for f in FOOT_NAMES])
        assert TRUNK_LINK == c.getBodyInfo(self._robot)[0].decode()

        # Nominal physics: no body damping, the parameters of ModelParams, ground friction (the
        # payload and the rotors are in the URDF's inertials already: urdf_with_inertials).
        c.changeDynamics(self._plane, -1, lateralFriction=1.0)
        for link in [-1, *range(len(joints))]:
            c.changeDynamics(self._robot, link, linearDamping=0.0, angularDamping=0.0)
        for f in self._feet:
            c.changeDynamics(self._robot, int(f), lateralFriction=prm.ground_friction)
        if prm.ground_timeconst != GROUND_TIMECONST:  # nominal: PyBullet's own rigid contact
            mass = sum(c.getDynamicsInfo(self._robot, link)[0] for link in [-1, *range(len(joints))])
            stiffness, damping = soft_contact(prm.ground_timeconst, mass)
            for f in self._feet:
                c.changeDynamics(self._robot, int(f), contactStiffness=stiffness, contactDamping=damping)
        for k, j in enumerate(self._joints):
            c.changeDynamics(self._robot, j, jointDamping=float(prm.joint_damping[k]))
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

    def _advance(self, commands: np.ndarray) -> np.ndarray:
        r, joints, c, act = self._robot, self._joints, self._client, self.actuation
        total = np.zeros(12)
        q = qd = None  # torque mode needs no joint reading (without a torque-speed line)
        for command in commands:
            if act.reads_joints:
                q, qd = self._joint_state()
            tau = act.torque(command, q, qd)
            c.setJointMotorControlArray(r, joints, pybullet.TORQUE_CONTROL, forces=tau)
            c.stepSimulation()
            total += tau
        return total / len(commands)

    def close(self) -> None:
        if getattr(self, "_client", None) is not None:
            try:
                self._client.disconnect()
            except pybullet.error:
                pass
            self._client = None
        if getattr(self, "_own_urdf", False):
            os.unlink(self._urdf)
            self._own_urdf = False
