"""Robot logs written by code outside acn-collect, for testing the diagnosis as a user would.

MuJoCo is stepped directly (no acn backend), the PD loop and the command delay are our own,
the controllers are not acn's built-in policies, physics can be changed with any ``MjSpec``
edit (catalogue effects or effects outside the catalogue), sensor noise can be added, and the
columns can be renamed and scaled. The log is a CSV table with one row per control step.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import mujoco
import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv

from acn.sim.robot import STANCE, URDF_JOINT, urdf_path
from acn.sim.state import FOOT_NAMES, GROUPS, JOINT_NAMES, SLICES, STATE_NAMES

G = 9.81
GLITCH = 30.0  # a glitch's size, multiple of NOISE
NOISE = {"base_pos": 0.002, "base_rpy": 0.004, "joint_pos": 0.002, "base_linvel": 0.03, "base_angvel": 0.03,
         "joint_vel": 0.08, "imu_acc": 0.15}  # typical sensor noise (std) per channel group, SI units


@dataclass
class LogSpec:
    seconds: float = 4.0
    episodes: int = 2
    seed: int = 0
    controller: str = "sines"            # "sines": random smooth joint targets; "pace": lateral-pair gait;
    # "hop": every leg folds and pushes together at 2-2.6 Hz (the trunk leaves the ground)
    gait_speed: float = 1.0              # the pace's and the hop's frequency and amplitudes times this (faster legs)
    control_hz: int = 50
    physics_hz: int = 1000
    kp: float | tuple[float, ...] = 60.0  # N m/rad: every joint, or 12 in JOINT_NAMES order
    kd: float | tuple[float, ...] = 1.5
    torque_limit: float = 33.5
    latency_steps: int = 0               # physics steps a command arrives late
    action_smoothing: float = 0.0        # b: the controller sends b x its previous sent target + (1 - b) x the
    # action it logs (an exponential moving average once per control step, after the log; position targets)
    command_lag: float = 0.0             # s, time constant of a first-order low-pass on the command the motor
    # follows (after the delay, every physics step, every stream of a hybrid command): a driver's bandwidth
    strength: float | np.ndarray = 1.0   # torque produced / commanded: every joint, or 12 in JOINT_NAMES order
    gains: tuple[float, float] = (1.0, 1.0)  # the PD really runs with (kp, kd) times these
    deadband: float = 0.0                # rad, total width of a dead band on the PD error
    dc_motor: tuple[float, float] | None = None  # (saturation N m, no-load speed rad/s): each motor's torque
    # bounded by its torque-speed line, [clip(sat (-1 - qd / w), -limit, 0), clip(sat (1 - qd / w), 0, limit)]
    # (Isaac Lab's DCMotor), before the strength
    encoder_offset: np.ndarray | None = None  # (12,) rad, the PD and the log read q + offset
    spec_edit: Callable[[mujoco.MjSpec], None] | None = None
    marker: tuple[float, ...] | None = None  # (x, y, z) m [, roll, pitch rad]: the trunk logged as a
    # motion-capture body at that place in the trunk frame, tilted so (extrinsic XYZ)
    noise: float = 0.0                   # multiple of NOISE
    glitches: float = 0.0                # share of rows in which one reading (not a contact flag) is off by
    # GLITCH x its group's NOISE, either sign: a corrupted sensor packet
    jitter: float = 0.0                  # the control period varies by up to +- this share (whole physics steps,
                                         # uniform), as a control loop on a busy computer does
    jitter_logged: bool = True           # the timestamps show each step's real start (else the loop's nominal clock)
    velocity_filter: float = 0.0         # s, time constant of a first-order low-pass the robot applies to the
                                         # joint velocities it logs (and its controller reads), every physics step
    stale: float = 0.0                   # share of rows whose readings repeat the previous row's (a message
    # that did not arrive; the controller acts on the repeated reading too)
    feedback: float = 0.0                # gain multiple of an attitude feedback (``_level``) the controller adds,
    # on the measured (noisy) roll, pitch and gyro: the log's actions then depend on its sensor noise
    feedforward: bool = False            # the controller sends (q_des, dq_des, tau_ff) and the motor runs
                                         # kp (q_des - q) + kd (dq_des - qd) + tau_ff (an MIT-style hybrid
                                         # command); logged as action.*, action_vel.*, action_torque.*
    stance_gains: tuple[float, float] | None = None  # (kp, kd) multiples the controller sends a leg in the
    # stance half of a gait clock (diagonal pairs in antiphase), the nominal gains in the swing half, as
    # controllers that switch gains by gait phase do; logged as action_kp.*, action_kd.* (gains per row)
    stance_torque: bool = False          # an MPC-style controller on the same clock: legs in stance get kp 0 and a
    # feedforward torque it computes from its (noisy) readings, kp (q_target - q) (the virtual stiffness an MPC's
    # force plan stands for), legs in swing the nominal PD; logged as action_kp.*, action_kd.*, action_torque.*
    gait_period: float = 0.5             # s, that clock's period
    torque_control: bool = False         # the controller runs the PD itself, on the MEASURED (noisy) joint
    # angles and speeds, once per control step, and sends torques: the log's actions are N m
    # (acn-import --action-mode torque); the motor applies them held, through latency and strength
    accelerometer: str = "mean"          # "mean": the specific force over the control period (the schema's);
    # "sensor": MuJoCo's accelerometer at the trunk origin, read at the row's instant (the last physics step)
    rename: dict[str, tuple[str, float]] = field(default_factory=dict)  # ours -> (column, scale)
    drop: tuple[str, ...] = ()           # channels left out of the log


def welded_payload(mass: float, pos: list[float], inertia: float = 1e-3) -> Callable[[mujoco.MjSpec], None]:
    """A ``LogSpec.spec_edit``: a separate body of ``mass`` kg welded to the trunk at ``pos`` (m, trunk
    frame), its centre of mass at its origin, ``inertia`` kg m^2 about each axis (acn's ``payload``
    combines such a mass into the trunk's inertia). ``ipos`` must be set: MjSpec leaves it unset,
    and MuJoCo 4.0 then puts the centre of mass at ``pos`` in the body's own frame, twice ``pos``
    from the trunk (a payload would sit at twice the offset it states)."""
    def edit(spec: mujoco.MjSpec) -> None:
        body = spec.body("trunk").add_body(name="payload", pos=pos)
        body.ipos, body.iquat = [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]
        body.mass, body.inertia, body.explicitinertial = mass, [inertia] * 3, True
    return edit


def _spec(s: LogSpec) -> mujoco.MjSpec:
    spec = mujoco.MjSpec.from_file(urdf_path())
    spec.option.timestep = 1.0 / s.physics_hz
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_EULER
    spec.body("trunk").add_freejoint(name="root")
    for g in spec.geoms:
        g.contype, g.conaffinity = 1, 0
    spec.worldbody.add_geom(name="floor", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1], contype=0, conaffinity=1)
    for j in JOINT_NAMES:
        spec.joint(URDF_JOINT[j]).actfrclimited = mujoco.mjtLimited.mjLIMITED_FALSE
        spec.add_actuator(name=j, target=URDF_JOINT[j], trntype=mujoco.mjtTrn.mjTRN_JOINT).gainprm[0] = 1.0
    if s.accelerometer == "sensor":
        spec.body("trunk").add_site(name="imu")
        spec.add_sensor(name="imu_acc", type=mujoco.mjtSensor.mjSENS_ACCELEROMETER, objtype=mujoco.mjtObj.mjOBJ_SITE,
                        objname="imu")
    if s.spec_edit:
        s.spec_edit(spec)
    return spec


def _targets(s: LogSpec, rng: np.random.Generator):
    if s.controller == "sines":
        freq = rng.uniform(0.4, 4.0, (3, 12))
        amp = rng.uniform(0.03, 0.12, (3, 12)) * np.tile([0.6, 1.0, 1.0], 4)
        phase = rng.uniform(0, 2 * np.pi, (3, 12))
        return lambda t: STANCE + (amp * np.sin(2 * np.pi * freq * t + phase)).sum(0)
    if s.controller == "pace":  # left and right pairs alternate (acn's trot uses diagonals)
        f, g = rng.uniform(1.6, 2.2) * s.gait_speed, s.gait_speed

        def pace(t: float) -> np.ndarray:
            out = STANCE.copy()
            for leg, off in ((0, 0.0), (2, 0.0), (1, np.pi), (3, np.pi)):  # FR+RR vs FL+RL
                ph = 2 * np.pi * f * t + off
                out[3 * leg + 1] += 0.25 * g * np.cos(ph)
                out[3 * leg + 2] -= 0.5 * g * max(np.sin(ph), 0.0)
            return out
        return pace
    if s.controller == "hop":  # every leg folds and pushes together: the trunk bounces, motors near their limits
        f = rng.uniform(2.0, 2.6) * s.gait_speed
        fold = np.tile([0.0, 0.35, -0.7], 4) * s.gait_speed
        return lambda t: STANCE + fold * 0.5 * (1.0 - np.cos(2 * np.pi * f * t))
    raise ValueError(s.controller)


def _level(measured: np.ndarray, gain: float) -> np.ndarray:
    """(12,) joint target offsets that level the trunk, from a measured state (43,): each leg
    extends by e = -0.13 gain (roll + 0.1 roll rate) on the left (+ on the right) + 0.18 gain
    (pitch + 0.1 pitch rate) at the front (- at the rear), m (half the hip spans, so a tilt is
    levelled in about one step), by opening the knee (calf + e / 0.143 rad, the leg's length
    changing 0.143 m per rad of calf at the stance) and turning the thigh back by half that."""
    roll, pitch = measured[SLICES["base_rpy"]][:2]
    wx, wy = measured[SLICES["base_angvel"]][:2]
    out = np.zeros(12)
    for leg, (left, front) in enumerate(((-1, 1), (1, 1), (-1, -1), (1, -1))):   # FR, FL, RR, RL
        e = gain * (-0.13 * left * (roll + 0.1 * wx) + 0.18 * front * (pitch + 0.1 * wy))
        out[3 * leg + 2] += e / 0.143
        out[3 * leg + 1] -= 0.5 * e / 0.143
    return out


def _rpy(quat_wxyz: np.ndarray) -> np.ndarray:
    w, x, y, z = quat_wxyz
    return np.array([np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)),
                     np.arcsin(np.clip(2 * (w * y - z * x), -1, 1)),
                     np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))])


def _as_marker(state: np.ndarray, rot: np.ndarray, marker: np.ndarray) -> np.ndarray:
    """The trunk channels of ``state`` as a body at ``marker`` (x, y, z [, roll, pitch]) reads them."""
    d = marker[:3]
    tilt = marker[3:5] if len(marker) > 3 else np.zeros(2)
    cr, sr, cp, sp = np.cos(tilt[0]), np.sin(tilt[0]), np.cos(tilt[1]), np.sin(tilt[1])
    r_o = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]]) @ np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, (rot @ r_o).ravel())
    pos, rpy, lin, ang, imu = (SLICES[g] for g in ("base_pos", "base_rpy", "base_linvel", "base_angvel", "imu_acc"))
    v, w, acc = state[lin], state[ang], state[imu]
    out = state.copy()
    out[pos] = state[pos] + rot @ d
    out[rpy] = _rpy(quat)
    out[lin] = r_o.T @ (v + np.cross(w, d))
    out[ang] = r_o.T @ w
    out[imu] = r_o.T @ acc
    return out


def simulate(s: LogSpec) -> dict[str, np.ndarray]:
    """Rows of every episode, as our channel names -> values (plus episode_index, timestamp, actions)."""
    if s.torque_control and s.feedforward:
        raise ValueError("torque_control and feedforward are two kinds of command: choose one")
    if s.stance_torque and (s.feedforward or s.stance_gains):
        raise ValueError("stance_torque sends its own gains and feedforward: not with feedforward or stance_gains")
    if s.torque_control and (s.gains != (1.0, 1.0) or s.deadband or s.stance_gains or s.stance_torque):
        raise ValueError("torque_control: the PD gains and dead band are the controller's, logged in its torques")
    m = _spec(s).compile()
    d = mujoco.MjData(m)
    qadr = np.array([m.jnt_qposadr[m.joint(URDF_JOINT[j]).id] for j in JOINT_NAMES])
    dadr = np.array([m.jnt_dofadr[m.joint(URDF_JOINT[j]).id] for j in JOINT_NAMES])
    floor = m.geom("floor").id
    feet = [m.body(f"{f}_toe").id if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"{f}_toe") >= 0
            else m.body(f"{f}_lower").id for f in FOOT_NAMES]
    foot_of_body = np.full(m.nbody, -1)  # body id -> foot index (-1: not a foot)
    foot_of_body[feet] = np.arange(len(feet))
    offset = np.zeros(12) if s.encoder_offset is None else np.asarray(s.encoder_offset, float)
    kp, kd = np.broadcast_to(np.asarray(s.kp, float), 12), np.broadcast_to(np.asarray(s.kd, float), 12)
    leg_phase = np.repeat([0.0, 0.5, 0.5, 0.0], 3)  # FR, FL, RR, RL: the diagonal pairs in antiphase
    sub = s.physics_hz // s.control_hz
    rng = np.random.default_rng(s.seed)
    noise = _noise(s)                    # (rows, 43): drawn up front, so the controller sees what is logged
    stale = np.random.default_rng(s.seed + 2000).random(len(noise)) < s.stale
    spread = int(round(s.jitter * sub))
    periods = sub + np.random.default_rng(s.seed + 4000).integers(-spread, spread + 1, len(noise))  # physics steps
    logged = None
    rows: dict[str, list] = {k: [] for k in ("episode_index", "timestamp", *STATE_NAMES,
                                             *(f"action.{j}" for j in JOINT_NAMES))}
    if s.feedforward:
        rows.update({f"action_{kind}.{j}": [] for kind in ("vel", "torque") for j in JOINT_NAMES})
    if s.stance_gains or s.stance_torque:
        rows.update({f"action_{kind}.{j}": [] for kind in ("kp", "kd") for j in JOINT_NAMES})
    if s.stance_torque:
        rows.update({f"action_torque.{j}": [] for j in JOINT_NAMES})
    for ep in range(s.episodes):
        target = _targets(s, rng)
        mujoco.mj_resetData(m, d)
        d.qpos[2] = 0.32
        d.qpos[3:7] = [1, 0, 0, 0]
        d.qpos[qadr] = STANCE + rng.uniform(-0.03, 0.03, 12) - offset
        mujoco.mj_forward(m, d)
        # (q_des, dq_des, tau_ff, kp, kd): a command waits this many physics steps
        queue = [np.stack([STANCE, np.zeros(12), np.zeros(12), kp, kd])] * s.latency_steps
        lagged = None  # the command the motor follows through its low-pass (command_lag)
        follow = 1.0 - np.exp(-1.0 / (s.command_lag * s.physics_hz)) if s.command_lag else None
        ff_phase = rng.uniform(0, 2 * np.pi, 12) if s.feedforward else None
        v_prev = d.qvel[0:3].copy()
        touching = np.ones(4)
        qd_logged = d.qvel[dadr].copy()  # the low-passed joint velocities (velocity_filter)
        clock, last = 0, 1.0 / s.control_hz  # physics steps since the episode started; the last period, s
        for k in range(int(s.seconds * s.control_hz)):
            rot = d.xmat[m.body("trunk").id].reshape(3, 3)
            acc = rot.T @ ((d.qvel[0:3] - v_prev) / last + np.array([0, 0, G]))
            if s.accelerometer == "sensor":
                acc = d.sensor("imu_acc").data.copy()
            state = np.concatenate([d.qpos[0:3], _rpy(d.qpos[3:7]), d.qpos[qadr] + offset, rot.T @ d.qvel[0:3],
                                    d.qvel[3:6], qd_logged, touching, acc])
            if s.marker is not None:
                state = _as_marker(state, rot, np.asarray(s.marker, float))
            row = len(rows["timestamp"])
            state = logged if stale[row] and k > 0 else state + noise[row]
            logged = state
            a = target(k / s.control_hz)
            dq_des, tau_ff = np.zeros(12), np.zeros(12)
            if s.feedforward:  # the targets' own rate, and a slow torque about a per-type bias (N m)
                dq_des = (target(k / s.control_hz + 1e-3) - target(k / s.control_hz - 1e-3)) / 2e-3
                tau_ff = np.tile([0.5, 1.5, -2.5], 4) + 2.0 * np.sin(np.pi * k / s.control_hz + ff_phase)
            kp_t, kd_t = kp, kd
            if s.stance_gains:
                stance = (k / s.control_hz / s.gait_period + leg_phase) % 1.0 < 0.5
                kp_t, kd_t = np.where(stance, s.stance_gains[0] * kp, kp), np.where(stance, s.stance_gains[1] * kd, kd)
            if s.feedback:
                a = a + _level(state, s.feedback)
            if s.stance_torque:  # stance legs: no position loop, the controller's torque from its readings
                stance = (k / s.control_hz / s.gait_period + leg_phase) % 1.0 < 0.5
                tau_ff = np.where(stance, kp * (a - state[SLICES["joint_pos"]]), 0.0)
                kp_t = np.where(stance, 0.0, kp)
            if s.torque_control:  # the PD on the readings, in the controller: the action is its torque
                q_read, qd_read = state[SLICES["joint_pos"]], state[SLICES["joint_vel"]]
                a = kp * (a - q_read) - kd * qd_read  # unclipped: the motor limits it
            for name, v in zip(STATE_NAMES, state):
                rows[name].append(v)
            for j, v in zip(JOINT_NAMES, a):
                rows[f"action.{j}"].append(v)
            if s.feedforward:
                for j, v, f in zip(JOINT_NAMES, dq_des, tau_ff):
                    rows[f"action_vel.{j}"].append(v)
                    rows[f"action_torque.{j}"].append(f)
            if s.stance_gains or s.stance_torque:
                for j, p_, d_ in zip(JOINT_NAMES, kp_t, kd_t):
                    rows[f"action_kp.{j}"].append(p_)
                    rows[f"action_kd.{j}"].append(d_)
            if s.stance_torque:
                for j, f in zip(JOINT_NAMES, tau_ff):
                    rows[f"action_torque.{j}"].append(f)
            rows["episode_index"].append(ep)
            rows["timestamp"].append(clock / s.physics_hz if s.jitter_logged else k / s.control_hz)
            v_prev = d.qvel[0:3].copy()
            touching = np.zeros(4)
            if s.action_smoothing:  # what the motors get; the log keeps the action as the controller chose it
                a = a if k == 0 else s.action_smoothing * smoothed + (1.0 - s.action_smoothing) * a
                smoothed = a
            clock += periods[row]
            last = periods[row] / s.physics_hz
            for _ in range(periods[row]):
                queue.append(np.stack([a, dq_des, tau_ff, kp_t, kd_t]))
                sent = queue.pop(0)
                lagged = sent if lagged is None or follow is None else lagged + follow * (sent - lagged)
                cmd, cmd_vel, cmd_ff, cmd_kp, cmd_kd = lagged
                q, qd = d.qpos[qadr] + offset, d.qvel[dadr]
                if s.torque_control:
                    tau = np.clip(cmd, -s.torque_limit, s.torque_limit)
                else:
                    err = cmd - q
                    if s.deadband:
                        err = np.sign(err) * np.maximum(np.abs(err) - s.deadband / 2, 0.0)
                    tau = np.clip(s.gains[0] * cmd_kp * err + s.gains[1] * cmd_kd * (cmd_vel - qd) + cmd_ff,
                                  -s.torque_limit, s.torque_limit)
                if s.dc_motor:
                    sat, no_load = s.dc_motor
                    tau = np.clip(tau, np.clip(sat * (-1.0 - qd / no_load), -s.torque_limit, 0.0),
                                  np.clip(sat * (1.0 - qd / no_load), 0.0, s.torque_limit))
                d.ctrl[:] = s.strength * tau
                mujoco.mj_step(m, d)
                qd_logged += (d.qvel[dadr] - qd_logged) / (1.0 + s.velocity_filter * s.physics_hz)
                pairs = d.contact.geom[: d.ncon]  # (ncon, 2) geom ids; a foot touches where it meets the floor
                on_floor = (pairs == floor).any(axis=1)
                foot = foot_of_body[m.geom_bodyid[pairs[on_floor]]]
                touching[foot[foot >= 0]] = 1.0
    return {k: np.asarray(v, dtype=float) for k, v in rows.items()}


def _noise(s: LogSpec) -> np.ndarray:
    """(rows, 43) sensor noise of every logged state, per channel group ``NOISE`` x ``s.noise``."""
    rows = s.episodes * int(s.seconds * s.control_hz)
    out = np.zeros((rows, len(STATE_NAMES)))
    if s.noise:
        noise_rng = np.random.default_rng(s.seed + 1000)
        for g, sd in NOISE.items():
            for name in GROUPS[g]:
                out[:, STATE_NAMES.index(name)] = noise_rng.normal(0, sd * s.noise, rows)
    if s.glitches:
        rng = np.random.default_rng(s.seed + 3000)
        channels = [(STATE_NAMES.index(n), sd) for g, sd in NOISE.items() for n in GROUPS[g]]
        for r in np.flatnonzero(rng.random(rows) < s.glitches):
            c, sd = channels[rng.integers(len(channels))]
            out[r, c] += rng.choice((-1.0, 1.0)) * GLITCH * sd
    return out


def write_log(path, s: LogSpec) -> dict:
    """Simulate and write the CSV; returns the map a user would pass to ``acn-import --map``."""
    cols = simulate(s)
    mapping = {}
    table = {}
    for name, values in cols.items():
        if name in s.drop:
            continue
        if name in s.rename:
            column, scale = s.rename[name]
            table[column] = values / scale
            mapping[name] = {"column": column, "scale": scale, "offset": 0.0}
        else:
            table[name] = values
    pacsv.write_csv(pa.table(table), str(path))
    return mapping
