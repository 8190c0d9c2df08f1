"""MuJoCo implementation of ``Backend``: the A1 URDF compiled through ``mujoco.MjSpec``.

The spec adds what a URDF lacks: a free joint on the trunk, a floor, and 12 actuators that
realise the control law of ``acn.toolkit.backends.base`` inside MuJoCo, so the same model
can be stepped with ``mj_step(nstep=...)`` or re-simulated in batches with ``mujoco.rollout``:

- position mode: ``tau = kp * (ctrl - q) - kd * qdot`` (gain kp, affine bias (0, -kp, -kd)),
  force-limited to +-torque_limit;
- torque mode: ``tau = ctrl``, ctrl-limited to +-torque_limit.

Euler integration, like PyBullet's semi-implicit step, and only robot-floor contacts
(PyBullet does not collide a robot with itself by default).
"""

from __future__ import annotations

import mujoco
import numpy as np

from acn.toolkit.backends.base import Backend, SimConfig, SimulationDiverged
from acn.toolkit.robot import GRAVITY, TRUNK_LINK, URDF_FOOT_LINK, URDF_JOINT, urdf_path
from acn.toolkit.state import FOOT_NAMES, JOINT_NAMES


def build_spec(config: SimConfig) -> mujoco.MjSpec:
    """The nominal A1 model as an ``MjSpec`` (public: outside code may edit and compile it)."""
    cfg, prm = config, config.params
    spec = mujoco.MjSpec.from_file(urdf_path())
    spec.option.timestep = cfg.physics_dt
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    spec.option.gravity = [0.0, 0.0, -GRAVITY]
    # A blow-up must surface as a non-finite state, not as MuJoCo's silent reset to qpos0.
    spec.option.disableflags |= mujoco.mjtDisableBit.mjDSBL_AUTORESET

    trunk = spec.body(TRUNK_LINK)
    trunk.add_freejoint(name="root")
    trunk.mass += prm.payload_mass
    for geom in spec.geoms:  # robot geoms touch the floor only
        geom.contype, geom.conaffinity = 1, 0
        geom.friction[0] = prm.ground_friction
    for foot in FOOT_NAMES:
        spec.body(URDF_FOOT_LINK[foot]).geoms[0].name = f"{foot}_foot"
    spec.worldbody.add_geom(
        name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1],
        contype=0, conaffinity=1, friction=[prm.ground_friction, 0.005, 0.0001],
    )
    for k, jname in enumerate(JOINT_NAMES):
        joint = spec.joint(URDF_JOINT[jname])
        joint.damping[0] = float(prm.joint_damping[k])  # MuJoCo 4: polynomial coefficients, [0] linear
        joint.frictionloss = float(prm.joint_friction[k])
        joint.actfrclimited = mujoco.mjtLimited.mjLIMITED_FALSE  # the control law limits torque
        act = spec.add_actuator(name=jname, target=URDF_JOINT[jname], trntype=mujoco.mjtTrn.mjTRN_JOINT)
        lim = cfg.torque_limit
        act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.forcerange = [-lim, lim]
        if cfg.action_mode == "position":
            act.gainprm[0] = cfg.kp
            act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
            act.biasprm[:3] = [0.0, -cfg.kp, -cfg.kd]
            act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        else:
            act.gainprm[0] = 1.0
            act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
            act.ctrlrange = [-lim, lim]
    return spec


class MuJoCoBackend(Backend):
    """The A1 in MuJoCo; ``model`` and ``data`` are public for outside tools (rollout, sysid)."""

    name = "mujoco"

    def _build(self) -> None:
        self.spec = build_spec(self.config)
        self.model = self.spec.compile()
        self.data = mujoco.MjData(self.model)
        m = self.model
        jids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, URDF_JOINT[j]) for j in JOINT_NAMES]
        self._qadr = np.array([m.jnt_qposadr[j] for j in jids])
        self._dadr = np.array([m.jnt_dofadr[j] for j in jids])
        self._floor = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "floor")
        self._foot_of_geom = np.full(m.ngeom, -1)  # geom id -> foot index, -1 if not a foot
        for k, f in enumerate(FOOT_NAMES):
            self._foot_of_geom[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"{f}_foot")] = k

    # ----- batch re-simulation (mujoco.rollout works on MuJoCo's full physics state) --------
    PHYSICS = mujoco.mjtState.mjSTATE_FULLPHYSICS

    def physics_state(self, state: np.ndarray) -> np.ndarray:
        """MuJoCo's full physics state vector for one of our state vectors."""
        self.set_state(state)
        out = np.empty(mujoco.mj_stateSize(self.model, self.PHYSICS))
        mujoco.mj_getState(self.model, self.data, out, self.PHYSICS)
        return out

    def state_from_physics(self, physics: np.ndarray) -> np.ndarray:
        """Our state vector for a MuJoCo physics state (sensor channels: the last reading)."""
        mujoco.mj_setState(self.model, self.data, physics, self.PHYSICS)
        self._state = None
        return self._compose_state(*self._read_dynamics())

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

    def _advance(self, action: np.ndarray) -> np.ndarray:
        m, d = self.model, self.data
        d.ctrl[:] = action
        total = np.zeros(12)
        bad = d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number
        for _ in range(self.config.substeps):
            mujoco.mj_step(m, d)
            np.add(total, d.actuator_force, out=total)
        if d.warning[mujoco.mjtWarning.mjWARN_BADQACC].number > bad:
            raise SimulationDiverged("MuJoCo reported a non-finite or huge acceleration")
        return total / self.config.substeps
