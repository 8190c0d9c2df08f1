"""The joint control law and its signal path, the same in every backend.

From the action a_t to the torque on each joint, per physics step (all per joint):

1. **latency** L and **lag** T: the command in force during a physics step is the
   zero-order-held action stream delayed by L, then followed through a first-order low-pass of
   time constant T (a driver's bandwidth), averaged over that step (so it is continuous in L and
   T; a whole number of physics steps of latency without lag gives exactly the action sent that
   many steps earlier). The low-pass remembers ``LAG_MEMORY`` T of actions; the weight of older
   ones (at most exp(-LAG_MEMORY)) goes to the oldest action remembered;
2. **reading**: the encoder reads ``q + encoder_offset``; the PD acts on the reading;
3. **position mode**: ``e = deadband(command - reading, backlash / 2)``,
   ``tau_cmd = clip(kp_scale kp e - kd_scale kd qdot, -limit, limit)``;
   **torque mode**: ``tau_cmd = clip(command, -limit, limit)``;
   **torque-speed line** (``torque_speed`` k, N m s/rad): the motor's torque in the direction the
   joint moves falls with its speed, ``tau_cmd`` is clipped to
   ``[clip(-limit - k qdot, -limit, 0), clip(limit - k qdot, 0, limit)]`` (a DC motor whose back-EMF
   eats the supply voltage: the stall torque is the limit, the no-load speed limit / k; braking
   keeps the full limit; Isaac Lab's ``DCMotor`` with its saturation at the limit);
4. **motor strength**: the joint receives ``strength * tau_cmd``.

**Hybrid (MIT-style) commands** (``SimConfig.hybrid``: gains and a feedforward sent with every
target, by a controller that switches its legs between stance and swing gains, an MPC that sends
stance legs pure torques with kp 0, ...): the action is 60 numbers (``HYBRID_PARTS``), the target
u, kp_t, kd_t, a velocity target v_t and a feedforward torque tau_t (12 each), and step 3 reads
``tau_cmd = clip(kp_scale kp_t e + kd_scale kd_t (v_t - qdot) + tau_t, ...)``: the gain scales
act on what each gain multiplies, the dead band on e = u - reading, not on the feedforward.
Latency delays the streams together, so a physics step's command is the average of the laws in
force during it: ``kp_scale (P - G reading) - kd_scale D qdot + F`` with P = mean(kp_t u), G =
mean(kp_t), D = mean(kd_t), F = mean(kd_scale kd_t v_t + tau_t) (``commands`` returns (P, G, D,
F), 48 columns; the dead band acts on P / G - reading).

With nominal parameters this is exactly ``SimConfig``'s PD law. MuJoCo realises steps 2-4 with
native actuator parameters when there is no dead band and no torque-speed line
(``Actuation.native``); otherwise, and in PyBullet, ``torque`` is evaluated in Python every
physics step. Latency and lag are always realised by the command sequence (``commands``), so a
re-simulation from a recorded state only needs the recorded previous actions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from acn.sim.robot import per_joint
from acn.sim.state import NUM_JOINTS


HYBRID_PARTS = ("target", "kp", "kd", "velocity", "torque")  # a hybrid command: rad, N m/rad, N m s/rad, rad/s, N m
LAG_MEMORY = 5.0  # time constants of actions the lag's low-pass remembers (older ones: exp(-5) = 0.7 % of the weight)


def _lagged_integral(x: np.ndarray, delay: float, lag: float) -> np.ndarray:
    """G(x) = integral to x of the step response F of the signal path, s: F(x) = 0 before the
    delay, 1 - exp(-(x - delay) / lag) after it (1 at once without lag)."""
    x = np.maximum(np.asarray(x, float) - delay, 0.0)
    if lag <= 0:
        return x
    return x - lag * -np.expm1(-x / lag)


def position_targets(actions: np.ndarray, q: np.ndarray) -> np.ndarray:
    """(..., 12) position targets of actions: 12-wide ones as they are; of 60-wide hybrid commands
    (u, kp, kd, v, tau; module docstring) the target at which the command's own PD gives its
    torque at rest, u + (kd v + tau) / kp, and the joint angle ``q`` where kp is 0 (no position
    loop). What the data checks and the candidate terms read as "the target"."""
    if actions.shape[-1] == NUM_JOINTS:
        return actions
    u, kp, kd, v, tau = np.split(actions, len(HYBRID_PARTS), axis=-1)
    f = kd * v + tau
    return np.where(kp > 0, u + np.divide(f, kp, out=np.zeros_like(f), where=kp > 0), q)


def history_window(actions: np.ndarray, previous: np.ndarray | None, need: int) -> np.ndarray:
    """(N, need + K, width): ``need`` previous actions then the K actions of each of N rows (the
    window ``Actuation.commands`` reads). Unknown earlier actions are taken equal to the oldest
    one known (or to the first action)."""
    n, width = len(actions), actions.shape[-1]
    prev = np.empty((n, 0, width)) if previous is None else np.asarray(previous, float).reshape(n, -1, width)
    if prev.shape[1] < need:
        fill = prev[:, :1] if prev.shape[1] else actions[:, :1]
        prev = np.concatenate([np.repeat(fill, need - prev.shape[1], axis=1), prev], axis=1)
    return np.concatenate([prev[:, prev.shape[1] - need:], actions], axis=1)


@dataclass(frozen=True)
class Actuation:
    """The resolved control law of one model; per-joint (12,) arrays, see module docstring."""

    mode: str               # "position" or "torque"
    kp: np.ndarray          # N m/rad, gains after kp_scale
    kd: np.ndarray          # N m s/rad, after kd_scale
    limit: np.ndarray       # N m, commanded-torque limit
    strength: np.ndarray    # produced / commanded torque
    offset: np.ndarray      # rad, encoder reading - true joint angle
    deadband: np.ndarray    # rad, half-width of the dead band (backlash / 2)
    latency: float          # s
    physics_dt: float       # s
    substeps: int
    hybrid: bool = False  # hybrid commands: gains and feedforward come with each target (module docstring)
    kp_scale: np.ndarray | float = 1.0  # multiplies the kp a hybrid command sends (``kp`` above includes it)
    kd_scale: np.ndarray | float = 1.0  # the same for kd, on -qdot and on the velocity target
    speed_slope: np.ndarray | float = 0.0  # N m s/rad, the torque-speed line's slope (module docstring)
    lag: float = 0.0        # s, time constant of the low-pass on the commands (module docstring)

    @classmethod
    def from_config(cls, config) -> "Actuation":
        """From a ``SimConfig`` (control settings + ``ModelParams``)."""
        p = config.params
        limit = config.torque_limit if p.torque_limit is None else p.torque_limit
        ones = np.ones(NUM_JOINTS)
        return cls(mode=config.action_mode, kp=per_joint(config.kp) * p.kp_scale, kd=per_joint(config.kd) * p.kd_scale,
                   limit=limit * ones, strength=p.motor_strength.copy(), offset=p.encoder_offset.copy(),
                   deadband=p.backlash / 2.0, latency=float(p.latency), physics_dt=config.physics_dt,
                   substeps=config.substeps, hybrid=config.hybrid, kp_scale=p.kp_scale.copy(),
                   kd_scale=p.kd_scale.copy(), speed_slope=p.torque_speed.copy(),
                   lag=float(p.lag))

    @property
    def command_width(self) -> int:
        """Numbers per physics-step command (``commands``): 12, or 48 (P, G, D, F) for hybrid ones."""
        return 4 * NUM_JOINTS if self.hybrid else NUM_JOINTS

    @property
    def speed_limited(self) -> bool:
        """True if some joint's torque is bounded by a torque-speed line (slope > 0)."""
        return bool(np.any(np.asarray(self.speed_slope) > 0))

    @property
    def native(self) -> bool:
        """True if MuJoCo's affine actuators can realise the law (no dead band, no torque-speed line)."""
        if self.speed_limited:
            return False
        return self.mode == "torque" or not np.any(self.deadband > 0)

    @property
    def reads_joints(self) -> bool:
        """True if the torque depends on the joint angle or velocity (position mode, or a
        torque-speed line)."""
        return self.mode == "position" or self.speed_limited

    @property
    def delayed(self) -> bool:
        """True if a command reaches the motors other than as sent (latency or lag)."""
        return self.latency > 0 or self.lag > 0

    @property
    def history(self) -> int:
        """How many previous actions the latency and the lag reach back to (0 without them)."""
        control_dt = self.physics_dt * self.substeps
        reach = self.latency + LAG_MEMORY * self.lag
        return int(math.ceil(reach / control_dt - 1e-9)) if reach > 0 else 0

    # ----- step 1: which command is in force during each physics step ----------------------
    def command_weights(self) -> np.ndarray:
        """W (substeps, history + 1): command during physics step k = sum_h W[k, h] a_{t - H + h}.

        Column H is the current action a_t, column 0 the oldest one needed (it stands for every
        action before it too: each row sums to 1). The step response F of the signal path
        (``_lagged_integral``) gives the share of a_{t-H+h}, held over [c_lo, c_hi), in the command
        at time x as F(x - c_lo) - F(x - c_hi); W is its mean over the physics step.
        """
        n, dt, hist = self.substeps, self.physics_dt, self.history
        control_dt = n * dt
        lo, hi = np.arange(n)[:, None] * dt, np.arange(1, n + 1)[:, None] * dt  # physics step k, s from t
        held = (np.arange(hist + 1)[None, :] - hist) * control_dt  # when a_{t-H+h} started to be held
        def g(x: np.ndarray) -> np.ndarray:
            return _lagged_integral(x, self.latency, self.lag)

        w = (g(hi - held) - g(lo - held) - g(hi - held - control_dt) + g(lo - held - control_dt)) / dt
        w[:, 0] = 1.0 - w[:, 1:].sum(axis=1)  # the oldest action also stands for the ones before it
        return w

    def commands(self, actions: np.ndarray) -> np.ndarray:
        """Per-physics-step commands for consecutive control steps.

        ``actions`` (..., history + K, 12), or 60 wide (hybrid): the ``history`` previous actions,
        then the K actions to apply. Returns (..., K * substeps, 12), or for hybrid commands
        (..., K * substeps, 48): (P, G, D, F) of the module docstring.
        """
        if self.hybrid:
            u, kp, kd, v, tau = np.split(actions, len(HYBRID_PARTS), axis=-1)
            actions = np.concatenate([kp * u, kp, kd, self.kd_scale * kd * v + tau], axis=-1)
        hist = self.history
        if not self.delayed:
            return np.repeat(actions, self.substeps, axis=-2)
        w = self.command_weights()
        k = actions.shape[-2] - hist
        windows = np.stack([actions[..., i:i + hist + 1, :] for i in range(k)], axis=-3)  # (..., K, H+1, width)
        cmd = np.einsum("sh,...khj->...ksj", w, windows)
        return cmd.reshape(*actions.shape[:-2], k * self.substeps, actions.shape[-1])

    # ----- steps 2-4: the torque a joint receives -------------------------------------------
    def torque(self, command: np.ndarray, q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        """Joint torque (..., 12), N m, from the command (``commands``) and the TRUE joint angle
        and velocity."""
        lo, hi = self.torque_range(qd)
        if self.mode == "torque":
            return self.strength * np.clip(command, lo, hi)
        if self.hybrid:  # kp_t e = P - G reading, with the dead band on e = P / G - reading
            p, g, d, f = np.split(command, 4, axis=-1)
            reading = q + self.offset
            if self.deadband.any():  # where G = 0 there is no position loop
                e = np.divide(p, g, out=np.array(np.broadcast_to(reading, p.shape)), where=g > 0) - reading
                stiff = g * np.sign(e) * np.maximum(np.abs(e) - self.deadband, 0.0)
            else:
                stiff = p - g * reading
            return self.strength * np.clip(self.kp_scale * stiff - self.kd_scale * d * qd + f, lo, hi)
        e = command - (q + self.offset)
        if self.deadband.any():
            e = np.sign(e) * np.maximum(np.abs(e) - self.deadband, 0.0)
        return self.strength * np.clip(self.kp * e - self.kd * qd, lo, hi)

    def torque_range(self, qd: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """The commanded torque's bounds (N m) at joint velocity ``qd`` (rad/s): the limit, narrowed
        in the direction of motion by the torque-speed line (module docstring)."""
        if qd is None or not self.speed_limited:
            return -self.limit, self.limit
        drop = np.asarray(self.speed_slope) * qd
        return np.clip(-self.limit - drop, -self.limit, 0.0), np.clip(self.limit - drop, 0.0, self.limit)
