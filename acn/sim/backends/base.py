"""One interface for a simulated A1; PyBullet and MuJoCo implement the few parts that differ.

A backend owns one simulator instance (no global simulator state). The shared part here
turns raw simulator readings into the documented state vector (``acn.sim.state``),
computes the IMU, validates actions and detects blow-ups. Each backend implements only:

- ``_build()``            build the model from ``SimConfig`` (parameters set at build time),
- ``_restore_initial()``  bring the simulator back to the state right after building,
- ``_read_dynamics()``    trunk-origin pose and velocities in the world frame, joints,
- ``_write_dynamics()``   the inverse,
- ``_read_contacts()``    which feet touch the ground,
- ``_advance(commands)``  run ``substeps`` physics steps, step k under ``commands[k]`` (the
                          action after the latency of the signal path), return the mean
                          applied joint torque over them.

Control law (identical in both backends, ``acn.sim.actuation``). Nominal ``position`` mode:
at every physics step ``tau = clip(kp * (q_target - q) - kd * qdot, -limit, limit)``, with one
gain for every joint or one per joint (``JointGains``). ``torque``
mode: the action is a joint torque, clipped to the same limit and held over the control step.
Physical effects in ``SimConfig.params`` change this law (latency, gains, strength, limits,
encoder offsets, dead band) the same way in both backends.

The accelerometer (``imu_acc``) reads the trunk origin's specific force, body frame. By default
(``SimConfig.imu_acc`` "mean", the dataset schema's) it is the MEAN over the control step that
ends at the state, (v_end - v_start) / control_dt + g; "instant" reads it over the last physics
step only, as MuJoCo's ``accelerometer`` sensor and an IMU sampled at the log's instant do.

Joint angles in the state are encoder READINGS (true angle + ``encoder_offset``): ``set_state``
subtracts the offset before writing the simulator, ``get_state`` adds it back. Likewise the
trunk's channels are read in the frame ``base_frame_offset`` (``acn.sim.frames``; nominal:
the trunk link frame itself), as a motion-capture rigid body or a tilted IMU reports them.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import ClassVar, Literal

import numpy as np

from acn.errors import UserError
from acn.sim import frames
from acn.sim.actuation import HYBRID_PARTS, Actuation, history_window
from acn.sim.robot import GRAVITY, STANCE, STANDING_HEIGHT, ModelParams, per_joint
from acn.sim.rotations import quat_to_matrix, quat_to_rpy, rpy_to_quat
from acn.sim.state import ACTION_DIM, DYNAMIC_GROUPS, FOOT_NAMES, NUM_JOINTS, SLICES, STATE_DIM

ActionMode = Literal["position", "torque"]
ACTION_MODES: tuple[str, ...] = ("position", "torque")
IMU_ACC_KINDS: tuple[str, ...] = ("mean", "instant")  # what the accelerometer averages over (module docstring)
JointGains = float | tuple[float, ...]  # one value for every joint, or 12 in ``JOINT_NAMES`` order


def joint_gains(value) -> JointGains:
    """A number stays a number; 12 values become a tuple of floats (one number if all are equal)."""
    if isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool):
        return float(value)
    values = tuple(float(v) for v in np.asarray(value, dtype=float).ravel())
    if len(values) != NUM_JOINTS:
        raise ValueError(f"gains are one number or {NUM_JOINTS} (one per joint), got {len(values)}")
    return values[0] if len(set(values)) == 1 else values


BACKENDS: tuple[str, ...] = ("pybullet", "mujoco")


def simulator_version(name: str) -> str:
    """Installed version of the named simulator package."""
    from importlib.metadata import version

    if name not in BACKENDS:
        raise ValueError(f"unknown simulator {name!r}; choose from {', '.join(BACKENDS)}")
    return version(name)  # the distribution is named like the backend


class SimulationDiverged(RuntimeError):
    """The simulator produced a non-finite or physically absurd state."""


MAX_PHYSICS_DT = 0.01      # s, the coarsest physics step a backend takes
PHYSICS_HZ = 1000          # Hz, the physics rate a model steps at unless told otherwise


@dataclass
class SimConfig:
    """How a simulated A1 is built and driven. Both backends read the same config."""

    physics_dt: float = 0.001     # s, one physics step (1 kHz)
    substeps: int = 20            # physics steps per control step (50 Hz control)
    action_mode: ActionMode = "position"
    kp: JointGains = 60.0         # N m/rad, position-mode PD stiffness (every joint, or per joint)
    kd: JointGains = 1.5          # N m s/rad, position-mode PD damping (every joint, or per joint)
    torque_limit: float = 33.5    # N m, applied to every joint in both modes
    params: ModelParams = field(default_factory=ModelParams)
    # Hybrid (MIT-style) commands (position mode; ``acn.sim.actuation``): an action is 60
    # numbers, the 12 targets, kp, kd, velocity targets and feedforward torques sent together
    # (``HYBRID_PARTS``; kp, kd above are then only recorded, not used by the law).
    hybrid: bool = False
    imu_acc: str = "mean"  # the accelerometer's reading: "mean" over the control step or "instant" (module docstring)

    def __post_init__(self) -> None:
        self.kp, self.kd = joint_gains(self.kp), joint_gains(self.kd)

    @property
    def control_dt(self) -> float:
        return self.physics_dt * self.substeps

    @property
    def action_dim(self) -> int:
        """Numbers per action: 12 targets or torques; 60 with the gains, velocity targets and
        feedforward torques (``hybrid``)."""
        return len(HYBRID_PARTS) * ACTION_DIM if self.hybrid else ACTION_DIM

    def validate(self) -> None:
        if self.action_mode not in ACTION_MODES:
            raise ValueError(f"action mode must be one of {ACTION_MODES}, got {self.action_mode!r}")
        if self.hybrid and self.action_mode != "position":
            raise ValueError("a hybrid command completes a position target: hybrid needs position mode")
        if not (0 < self.physics_dt <= MAX_PHYSICS_DT):
            raise ValueError(f"physics_dt must be in (0, {MAX_PHYSICS_DT}] s, got {self.physics_dt}")
        if self.substeps < 1:
            raise ValueError(f"substeps must be >= 1, got {self.substeps}")
        if self.imu_acc not in IMU_ACC_KINDS:
            raise ValueError(f"imu_acc must be one of {IMU_ACC_KINDS}, got {self.imu_acc!r}")
        if (per_joint(self.kp) < 0).any() or (per_joint(self.kd) < 0).any() or not self.torque_limit > 0:
            raise ValueError("kp and kd must be >= 0 and torque_limit > 0")


def pd_torque(target: np.ndarray, q: np.ndarray, qd: np.ndarray, cfg: SimConfig) -> np.ndarray:
    """The position-mode control law, N m (see module docstring); ``target`` (..., 12), or 60 wide
    with the gains, velocity target and feedforward sent with it (``SimConfig.hybrid``)."""
    if target.shape[-1] == len(HYBRID_PARTS) * NUM_JOINTS:
        target, kp, kd, v, tau = np.split(target, len(HYBRID_PARTS), axis=-1)
    else:
        kp, kd, v, tau = per_joint(cfg.kp), per_joint(cfg.kd), 0.0, 0.0
    return np.clip(kp * (target - q) + kd * (v - qd) + tau, -cfg.torque_limit, cfg.torque_limit)


def physics_hz_for(control_hz: int, physics_hz: int | None = None) -> int:
    """The physics rate for a control rate: ``physics_hz`` where given (a multiple of the control
    rate, else a one-line error), otherwise the multiple of the control rate nearest ``PHYSICS_HZ``
    (1020 Hz at 60 Hz: PyBullet's 240 Hz logs are often controlled at 60 Hz)."""
    if physics_hz is None:
        return control_hz * max(1, round(PHYSICS_HZ / control_hz))
    if physics_hz % control_hz:
        raise UserError(f"--physics-hz ({physics_hz}) must be a multiple of --control-hz ({control_hz})")
    return physics_hz


# A state is "absurd" (the simulator blew up) beyond these bounds.
MAX_ABS_LINVEL = 50.0      # m/s
MAX_ABS_JOINT_VEL = 500.0  # rad/s
MAX_ABS_POSITION = 1e3     # m
_DYNAMIC = np.r_[tuple(SLICES[g] for g in DYNAMIC_GROUPS)]  # the channels set_state writes into the simulator


def default_state(base_xy: tuple[float, float] = (0.0, 0.0), yaw: float = 0.0) -> np.ndarray:
    """Standing still in the stance, feet on the ground, state-vector layout."""
    s = np.zeros(STATE_DIM)
    s[SLICES["base_pos"]] = (base_xy[0], base_xy[1], STANDING_HEIGHT)
    s[SLICES["base_rpy"]] = (0.0, 0.0, yaw)
    s[SLICES["joint_pos"]] = STANCE
    s[SLICES["contact"]] = 1.0
    s[SLICES["imu_acc"]] = (0.0, 0.0, GRAVITY)
    return s


class Backend(ABC):
    """A simulated A1. ``reset`` / ``get_state`` / ``set_state`` / ``step``; see module doc."""

    name: ClassVar[str]

    def __init__(self, config: SimConfig | None = None) -> None:
        self.config = config or SimConfig()
        self.config.validate()
        self.actuation = Actuation.from_config(self.config)
        self._frame = self.config.params.base_frame_offset  # where the trunk's channels are read
        self._build()
        self._history: np.ndarray | None = None  # previous actions (oldest first) for the latency and lag
        self._linvel_world = np.zeros(3)
        self._contact = np.zeros(len(FOOT_NAMES))
        self._imu_acc = np.array([0.0, 0.0, GRAVITY])
        self._state: np.ndarray | None = None  # cached state vector, valid until the simulator moves

    # ----- public interface -------------------------------------------------------------
    @property
    def version(self) -> str:
        """Installed version of the simulator package."""
        return simulator_version(self.name)

    def reset(self, state: np.ndarray | None = None) -> np.ndarray:
        """Restore the freshly built simulator, then set ``state`` (default: standing)."""
        self._restore_initial()
        self.set_state(default_state() if state is None else state)
        return self.get_state()

    def get_state(self) -> np.ndarray:
        """The current state vector (layout and frames: ``acn.sim.state``)."""
        if self._state is None:
            self._state = self._compose_state(*self._read_dynamics())
        return self._state.copy()

    def _compose_state(self, pos, quat, v_world, w_world, q, qd) -> np.ndarray:
        rot = quat_to_matrix(quat)
        s = np.empty(STATE_DIM)
        s[SLICES["base_pos"]] = pos
        s[SLICES["base_rpy"]] = quat_to_rpy(quat)
        s[SLICES["joint_pos"]] = q + self.actuation.offset
        s[SLICES["base_linvel"]] = rot.T @ v_world
        s[SLICES["base_angvel"]] = rot.T @ w_world
        s[SLICES["joint_vel"]] = qd
        s[SLICES["contact"]] = self._contact
        s[SLICES["imu_acc"]] = self._imu_acc
        return frames.state_in_frame(s[None], self._frame)[0] if self._frame.any() else s

    def set_state(self, state: np.ndarray, previous_actions: np.ndarray | None = None) -> None:
        """Write the dynamic channels into the simulator; keep the sensor channels as readings.

        A sensor channel may be NaN (a log without contact flags or accelerometer); it is
        reported as given until the next ``step`` replaces it.

        ``previous_actions`` (n, 12), oldest first: the actions before this state, which a
        model with latency still applies early in the next step. Without them the robot is
        taken to have received the next action all along.
        """
        s = np.asarray(state, dtype=np.float64)
        if s.shape != (STATE_DIM,) or not np.all(np.isfinite(s[_DYNAMIC])):
            raise ValueError(f"state must be a vector of shape ({STATE_DIM},), finite in its dynamic channels")
        width = self.config.action_dim
        self._history = None if previous_actions is None else np.asarray(previous_actions, float).reshape(-1, width)
        trunk = frames.state_in_trunk(s[None], self._frame)[0] if self._frame.any() else s  # in the trunk link frame
        quat = rpy_to_quat(trunk[SLICES["base_rpy"]])
        rot = quat_to_matrix(quat)
        v_world = rot @ trunk[SLICES["base_linvel"]]
        self._write_dynamics(
            trunk[SLICES["base_pos"]], quat, v_world, rot @ trunk[SLICES["base_angvel"]],
            s[SLICES["joint_pos"]] - self.actuation.offset, s[SLICES["joint_vel"]],
        )
        self._linvel_world = v_world
        self._contact = s[SLICES["contact"]].copy()
        self._imu_acc = trunk[SLICES["imu_acc"]].copy()  # kept in the trunk frame, read in _compose_state
        self._state = None

    def step(self, action: np.ndarray) -> np.ndarray:
        """Advance one control step under ``action`` (12,), or (60,) with the gains sent with it
        (``SimConfig.hybrid``); return mean applied torque (12,), N m.

        Raises ``SimulationDiverged`` if the simulator produced an absurd state.
        """
        a = np.asarray(action, dtype=np.float64)
        width = self.config.action_dim
        if a.shape != (width,) or not np.all(np.isfinite(a)):
            raise ValueError(f"action must be a finite vector of shape ({width},)")
        self._state = None
        commands = self._commands(a)
        v_before, dt = self._linvel_world, self.config.control_dt
        if self.config.imu_acc == "instant" and len(commands) > 1:  # the accelerometer reads the last physics step
            tau = self._advance(commands[:-1]) * (len(commands) - 1)
            v_before, dt = self._read_dynamics()[2], self.config.physics_dt
            tau = (tau + self._advance(commands[-1:])) / len(commands)
        else:
            tau = self._advance(commands)
        dyn = self._read_dynamics()
        pos, quat, v_world, w_world, q, qd = dyn
        self._check_sane(pos, v_world, w_world, q, qd)
        acc_world = (v_world - v_before) / dt
        acc_world[2] += GRAVITY
        self._imu_acc = quat_to_matrix(quat).T @ acc_world
        self._linvel_world = v_world
        self._contact = self._read_contacts()
        self._state = self._compose_state(*dyn)
        return tau

    def close(self) -> None:
        """Release the simulator (safe to call twice)."""

    def __enter__(self) -> "Backend":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ----- shared helpers ---------------------------------------------------------------
    def _commands(self, action: np.ndarray) -> np.ndarray:
        """(substeps, width) per-physics-step commands for ``action`` (``Actuation.commands``);
        remembers it for the latency and the lag."""
        hist = self.actuation.history
        if not self.actuation.delayed and not self.actuation.hybrid:
            return np.broadcast_to(action, (self.config.substeps, ACTION_DIM))
        window = history_window(action[None, None], None if self._history is None else self._history[None], hist)[0]
        self._history = window[1:]
        return self.actuation.commands(window)

    @staticmethod
    def _check_sane(pos, v_world, w_world, q, qd) -> None:
        if not (np.isfinite(pos).all() and np.isfinite(v_world).all() and np.isfinite(w_world).all()
                and np.isfinite(q).all() and np.isfinite(qd).all()):
            raise SimulationDiverged("non-finite state")
        if (np.abs(pos).max() > MAX_ABS_POSITION or np.abs(v_world).max() > MAX_ABS_LINVEL
                or np.abs(qd).max() > MAX_ABS_JOINT_VEL):
            raise SimulationDiverged("absurd state (position, speed or joint velocity out of bounds)")

    # ----- what each simulator implements ----------------------------------------------
    @abstractmethod
    def _build(self) -> None: ...

    @abstractmethod
    def _restore_initial(self) -> None: ...

    @abstractmethod
    def _read_dynamics(self) -> tuple[np.ndarray, ...]:
        """(trunk origin pos (3) world, quat xyzw (4), lin vel (3) world, ang vel (3) world,
        joint pos (12), joint vel (12)), all float64 in ``JOINT_NAMES`` order."""

    @abstractmethod
    def _write_dynamics(self, pos, quat, v_world, w_world, q, qd) -> None: ...

    @abstractmethod
    def _read_contacts(self) -> np.ndarray:
        """(4,) 0/1 per foot in ``FOOT_NAMES`` order."""

    @abstractmethod
    def _advance(self, commands: np.ndarray) -> np.ndarray:
        """Run ``substeps`` physics steps, step k under ``commands[k]`` (12,); mean applied torque."""


__all__ = ["Backend", "SimConfig", "SimulationDiverged", "pd_torque", "default_state",
           "ACTION_MODES", "NUM_JOINTS"]
