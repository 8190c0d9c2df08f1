"""MuJoCo implementation of ``Backend``: the A1 URDF compiled through ``mujoco.MjSpec``.

The spec adds what a URDF lacks: a free joint on the trunk, a floor, and 12 actuators that
realise the control law of ``acn.sim.actuation`` inside MuJoCo, so the same model can be
stepped with ``mj_step`` or re-simulated in batches with ``mujoco.rollout``:

- position mode: ``tau = s kp (ctrl - q - offset) - s kd qdot`` (gain s kp, affine bias
  (-s kp offset, -s kp, -s kd)), force-limited to +-s limit, with s the motor strength;
- torque mode: ``tau = s ctrl``, ctrl-limited to +-limit;
- position mode with a dead band (backlash), or either mode with a torque-speed line
  (``torque_speed``), which no affine actuator can express: plain motors (``tau = ctrl``), the
  torque computed by ``Actuation.torque`` every physics step;
- hybrid commands (``SimConfig.hybrid``): four actuators per joint, whose 48 controls are
  ``Actuation.commands``' (P, G, D, F; F carries the velocity target's term kd_scale kd_t v_t): a
  motor ``s kp_scale P``, an affine gain ``G (-s kp_scale (q + offset))``, one ``D (-s kd_scale
  qdot)`` and a motor ``s F``, their sum limited to +-s limit
  at the joint (``actfrcrange``); with a dead band the first motors carry the torque and the 36
  others take their controls with no force.

The physical parameters of ``ModelParams`` are written into the spec: joint damping,
frictionloss and armature, the payload combined into the trunk's inertia, geom friction and
the contact's time constant (``solref``).
One ``jointactuatorfrc`` sensor per joint gives the applied torque in ``mujoco.rollout``'s sensor data.

Euler integration, like PyBullet's semi-implicit step, and only robot-floor contacts
(PyBullet does not collide a robot with itself by default).
"""

from __future__ import annotations

import mujoco
import numpy as np

from acn.sim import frames
from acn.sim.actuation import Actuation
from acn.sim.backends.base import Backend, SimConfig, SimulationDiverged
from acn.sim.robot import GRAVITY, TRUNK_LINK, URDF_FOOT_LINK, URDF_JOINT, combine_point_mass, urdf_path
from acn.sim.rotations import quat_to_matrix, quat_to_rpy, rpy_to_quat
from acn.sim.state import FOOT_NAMES, JOINT_NAMES, SLICES, STATE_DIM


def _add_payload(body, m_p: float, p: np.ndarray) -> None:
    """Combine a point mass into ``body``'s inertial as the URDF gives it (mass, ipos, fullinertia)."""
    f = np.asarray(body.fullinertia, float)
    if np.isnan(f[0]):  # diagonal inertia in the frame iquat
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, np.asarray(body.iquat, float))
        rot = rot.reshape(3, 3)
        inertia = rot @ np.diag(np.asarray(body.inertia, float)) @ rot.T
    else:
        inertia = np.array([[f[0], f[3], f[4]], [f[3], f[1], f[5]], [f[4], f[5], f[2]]])
    mass, com, full = combine_point_mass(body.mass, np.asarray(body.ipos, float), inertia, m_p, p)
    body.mass, body.ipos, body.iquat = mass, com, [1.0, 0.0, 0.0, 0.0]
    body.fullinertia = [full[0, 0], full[1, 1], full[2, 2], full[0, 1], full[0, 2], full[1, 2]]


def build_spec(config: SimConfig) -> mujoco.MjSpec:
    """The A1 model as an ``MjSpec`` (public: outside code may edit and compile it)."""
    cfg, prm = config, config.params
    act = Actuation.from_config(cfg)
    spec = mujoco.MjSpec.from_file(urdf_path())
    spec.option.timestep = cfg.physics_dt
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    spec.option.gravity = [0.0, 0.0, -GRAVITY]
    # A blow-up must surface as a non-finite state, not as MuJoCo's silent reset to qpos0.
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET

    trunk = spec.body(TRUNK_LINK)
    trunk.add_freejoint(name="root")
    if prm.payload_mass > 0:
        _add_payload(trunk, prm.payload_mass, prm.payload_com)
    solref = [prm.ground_timeconst, 1.0]  # the contact's time constant, critically damped
    for geom in spec.geoms:  # robot geoms touch the floor only
        geom.contype, geom.conaffinity = 1, 0
        geom.friction[0] = prm.ground_friction
        geom.solref = solref
    for foot in FOOT_NAMES:
        spec.body(URDF_FOOT_LINK[foot]).geoms[0].name = f"{foot}_foot"
    spec.worldbody.add_geom(
        name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1],
        contype=0, conaffinity=1, friction=[prm.ground_friction, 0.005, 0.0001], solref=solref,
    )
    native_hybrid = act.hybrid and act.native
    for k, jname in enumerate(JOINT_NAMES):
        joint = spec.joint(URDF_JOINT[jname])
        joint.damping[0] = float(prm.joint_damping[k])  # MuJoCo 4: polynomial coefficients, [0] linear
        joint.frictionloss = float(prm.joint_friction[k])
        joint.armature = float(prm.armature[k])
        a = spec.add_actuator(name=jname, target=URDF_JOINT[jname], trntype=mujoco.mjtTrn.mjTRN_JOINT)
        s, lim = float(act.strength[k]), float(act.limit[k])
        a.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        if native_hybrid:  # four actuators per joint (below), limited together at the joint
            joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_TRUE
            joint.actfrcrange = [-s * lim, s * lim]
            a.gainprm[0] = s * float(act.kp_scale[k])
            continue
        joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_FALSE  # the control law limits torque
        a.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        a.forcerange = [-s * lim, s * lim]
        if cfg.action_mode == "position" and act.native:
            kp, kd = s * float(act.kp[k]), s * float(act.kd[k])
            a.gainprm[0] = kp
            a.biastype = mujoco.mjtBias.mjBIAS_AFFINE
            a.biasprm[:3] = [-kp * float(act.offset[k]), -kp, -kd]
        elif cfg.action_mode == "torque" and act.native:
            a.gainprm[0] = s
            a.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
            a.ctrlrange = [-lim, lim]
        else:  # the torque is computed by Actuation.torque each physics step
            a.gainprm[0] = 1.0
    if act.hybrid:  # the controls G (kp_t), D (kd_t) and F (feedforward) of each joint, after the 12 of P
        for part in ("kp", "kd", "feedforward"):
            for k, jname in enumerate(JOINT_NAMES):
                a = spec.add_actuator(name=f"{jname}_{part}", target=URDF_JOINT[jname],
                                      trntype=mujoco.mjtTrn.mjTRN_JOINT)
                a.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
                s = float(act.strength[k])
                if not native_hybrid:  # Actuation.torque has used them: no force of their own
                    a.gainprm[0] = 0.0
                elif part == "kp":  # G (-s kp_scale (q + offset))
                    a.gaintype = mujoco.mjtGain.mjGAIN_AFFINE
                    a.gainprm[:3] = [-s * float(act.kp_scale[k] * act.offset[k]), -s * float(act.kp_scale[k]), 0.0]
                elif part == "kd":  # D (-s kd_scale qdot)
                    a.gaintype = mujoco.mjtGain.mjGAIN_AFFINE
                    a.gainprm[:3] = [0.0, 0.0, -s * float(act.kd_scale[k])]
                else:               # s F
                    a.gainprm[0] = s
    for jname in JOINT_NAMES:
        spec.add_sensor(name=f"{jname}_torque", type=mujoco.mjtSensor.mjSENS_JOINTACTFRC,
                        objtype=mujoco.mjtObj.mjOBJ_JOINT, objname=URDF_JOINT[jname])
    return spec


class PhysicsLayout:
    """Our state vectors <-> MuJoCo full physics states, many rows at once (no MjData).

    A physics state is ``[time, qpos (19), qvel (18)]`` (``mjSTATE_FULLPHYSICS``): trunk
    origin position and quaternion (w, x, y, z) in the world, joint angles, trunk linear velocity
    (world frame) and angular velocity (body frame), joint velocities. Joint angles in our
    states are encoder readings: the true angle is ``reading - offset``; the trunk's channels
    are read in the frame ``frame`` (``ModelParams.base_frame_offset``, ``acn.sim.frames``).
    """

    def __init__(self, model: mujoco.MjModel) -> None:
        jids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, URDF_JOINT[j]) for j in JOINT_NAMES]
        self.qadr = np.array([model.jnt_qposadr[j] for j in jids])
        self.dadr = np.array([model.jnt_dofadr[j] for j in jids])
        self.nq, self.nv = model.nq, model.nv
        self.size = mujoco.mj_stateSize(model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        if self.size != 1 + self.nq + self.nv:
            raise RuntimeError(f"unexpected MuJoCo physics state size {self.size}")

    def to_physics(self, states: np.ndarray, offset: np.ndarray, frame: np.ndarray | None = None) -> np.ndarray:
        """(N, 43) states, (N, 12) or (12,) encoder offsets, (N, 6) measured frames (default: the
        trunk's) -> (N, size) physics states."""
        s = np.asarray(states, dtype=np.float64) if frame is None else frames.state_in_trunk(states, frame)
        out = np.zeros((len(s), self.size))
        qpos, qvel = out[:, 1:1 + self.nq], out[:, 1 + self.nq:]
        quat = np.stack(rpy_to_quat(s[:, SLICES["base_rpy"]].T), axis=1)  # (N, 4) x, y, z, w
        rot = np.moveaxis(np.array(quat_to_matrix(quat.T)), -1, 0)       # (N, 3, 3) body -> world
        qpos[:, 0:3] = s[:, SLICES["base_pos"]]
        qpos[:, 3:7] = quat[:, [3, 0, 1, 2]]
        qpos[:, self.qadr] = s[:, SLICES["joint_pos"]] - offset
        qvel[:, 0:3] = np.einsum("nij,nj->ni", rot, s[:, SLICES["base_linvel"]])
        qvel[:, 3:6] = s[:, SLICES["base_angvel"]]
        qvel[:, self.dadr] = s[:, SLICES["joint_vel"]]
        return out

    def to_states(self, physics: np.ndarray, before: np.ndarray, offset: np.ndarray, dt: float,
                  frame: np.ndarray | None = None) -> np.ndarray:
        """(N, size) physics states at the end of a control step -> (N, 43) states (read in
        ``frame`` (N, 6) where given).

        ``before``: the physics states ``dt`` s earlier (for the accelerometer, the mean specific
        force over that time: one control step, or the last physics step, ``SimConfig.imu_acc``).
        Contacts are not part of a physics state: they come back NaN.
        """
        qpos, qvel = physics[:, 1:1 + self.nq], physics[:, 1 + self.nq:]
        quat = qpos[:, [4, 5, 6, 3]]  # x, y, z, w
        rot = np.moveaxis(np.array(quat_to_matrix(quat.T)), -1, 0)
        v_world = qvel[:, 0:3]
        acc = (v_world - before[:, 1 + self.nq:1 + self.nq + 3]) / dt
        acc[:, 2] += GRAVITY
        out = np.empty((len(physics), STATE_DIM))
        out[:, SLICES["base_pos"]] = qpos[:, 0:3]
        out[:, SLICES["base_rpy"]] = np.stack(quat_to_rpy(quat.T), axis=1)
        out[:, SLICES["joint_pos"]] = qpos[:, self.qadr] + offset
        out[:, SLICES["base_linvel"]] = np.einsum("nji,nj->ni", rot, v_world)
        out[:, SLICES["base_angvel"]] = qvel[:, 3:6]
        out[:, SLICES["joint_vel"]] = qvel[:, self.dadr]
        out[:, SLICES["contact"]] = np.nan
        out[:, SLICES["imu_acc"]] = np.einsum("nji,nj->ni", rot, acc)
        return out if frame is None else frames.state_in_frame(out, frame)


class MuJoCoBackend(Backend):
    """The A1 in MuJoCo; ``model`` and ``data`` are public for outside tools (rollout, sysid)."""

    name = "mujoco"

    def _build(self) -> None:
        self.spec = build_spec(self.config)
        self.model = self.spec.compile()
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.layout = PhysicsLayout(m)
        self._qadr, self._dadr = self.layout.qadr, self.layout.dadr
        self._floor = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor")
        self._foot_of_geom = np.full(m.ngeom, -1)  # geom id -> foot index, -1 if not a foot
        for k, f in enumerate(FOOT_NAMES):
            self._foot_of_geom[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"{f}_foot")] = k

    def _restore_initial(self) -> None:
        mujoco.mj_resetData(self.model, self.data)

    def _read_dynamics(self):
        d = self.data
        w, x, y, z = d.qpos[3:7]
        quat = np.array([x, y, z, w])
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, d.qpos[3:7])
        w_world = rot.reshape(3, 3) @ d.qvel[3:6]
        return (d.qpos[0:3].copy(), quat, d.qvel[0:3].copy(), w_world,
                d.qpos[self._qadr].copy(), d.qvel[self._dadr].copy())

    def _write_dynamics(self, pos, quat, v_world, w_world, q, qd) -> None:
        d = self.data
        d.qpos[0:3] = pos
        d.qpos[3:7] = (quat[3], quat[0], quat[1], quat[2])
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, d.qpos[3:7])
        d.qvel[0:3] = v_world
        d.qvel[3:6] = rot.reshape(3, 3).T @ w_world
        d.qpos[self._qadr] = q
        d.qvel[self._dadr] = qd
        d.qacc_warmstart[:] = 0.0
        mujoco.mj_forward(self.model, d)

    def _read_contacts(self) -> np.ndarray:
        geom = self.data.contact.geom[: self.data.ncon]
        other = np.where(geom[:, 0] == self._floor, geom[:, 1], geom[:, 0])[(geom == self._floor).any(axis=1)]
        foot = self._foot_of_geom[other]
        out = np.zeros(len(FOOT_NAMES))
        out[foot[foot >= 0]] = 1.0
        return out

    def _advance(self, commands: np.ndarray) -> np.ndarray:
        m, d, act = self.model, self.data, self.actuation
        total = np.zeros(12)
        bad = d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number
        for command in commands:
            if act.native:
                d.ctrl[:] = command
            else:
                d.ctrl[:12] = act.torque(command, d.qpos[self._qadr], d.qvel[self._dadr])
            mujoco.mj_step(m, d)
            np.add(total, d.qfrc_actuator[self._dadr], out=total)
        if d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number > bad:
            raise SimulationDiverged("MuJoCo reported a non-finite or huge acceleration")
        return total / len(commands)
