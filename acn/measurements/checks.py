"""Is a robot log self-consistent? Units, signs, frames and conventions, before any model.

A log written by other code can use the schema's names but not its conventions: joint speeds
in deg/s, the trunk's velocity in the world frame, an accelerometer with gravity removed,
actions as offsets from a nominal pose, another zero for the joint angles. Compared with such
data, a model "finds" a physical effect that is a unit error. Each check compares channels
that must agree by the schema's definitions (``acn.sim.state``), never with a model:

- ``velocities``: a velocity against the rate of change of its position over windows of about
  40 ms (the logged velocity averaged over the same window, so both are the same quantity):
  its scale (1; 57.3 for deg/s; -1 for a flipped sign), its correlation, another joint whose
  rate it follows (columns mixed up), and for the trunk whether the WORLD frame fits better
  than the body frame;
- ``pose``: joint angles inside the A1's joint ranges (URDF), the trunk upright, its height;
- ``stance_feet``: feet the log marks as touching the ground (or the lowest foot) at ground
  height, by forward kinematics of the trunk pose and joint angles;
- ``leg_order``: whether the legs, read in another order, put the stance feet on the ground far
  better (legged_gym and Isaac Gym order the A1's legs FL, FR, RL, RR; ours is FR, FL, RR, RL);
- ``accelerometer``: its mean reads +9.81 m/s^2 on z for a level trunk (gravity included);
- ``contacts``: 0/1 flags; ``actions``: position targets near the joint angles they drive;
- ``velocity_lag``: joint velocities and the gyroscope against the central rate of change of
  their positions: a reading that lags the motion (a low-pass filter in the robot's software or
  driver, or a reading taken earlier than the positions) differs from the rate by -lag x the
  acceleration;
- ``repeats``: a sensor group whose readings equal the previous row's exactly, for one to
  ``REPEAT_RUN`` rows of a signal that moves before and after (a message that did not arrive and
  was logged again, or a sensor slower than the log; longer runs are a robot at rest).

Findings are warnings, one line each with the fix where one is known: ``acn-import`` prints
them and records them in the dataset's metadata; ``acn-diagnose`` repeats them.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from acn.sim.rotations import rpy_rate_to_body, rpy_to_matrices
from acn.sim.state import FOOT_NAMES, GROUPS, JOINT_NAMES, SLICES, STATE_NAMES, wrap_angle

if TYPE_CHECKING:
    from acn.measurements.data import Measurements

WINDOW_S = 0.04        # s, the window a velocity is compared over (position noise / window = rate noise)
DEG = 180.0 / np.pi    # a deg/s velocity is DEG x the rate of change of a rad position
MIN_ROWS = 20          # fewer finite windows than this: the check is skipped
START_ROWS = 25        # rows that count as where an episode starts (0.5 s at 50 Hz)
GRAVITY = 9.81
# Stance feet by forward kinematics on consistent logs (both simulators, robot_log.py at up to 3x
# its typical sensor noise): median height within +-0.3 cm, 10-90 % range at most 2.2 cm.
STANCE_MEDIAN, STANCE_SPREAD = 0.015, 0.04  # m
REPEAT_RUN = 3         # at most this many rows equal to the one before count as repeated readings
REPEAT_SHARE = 0.01    # a sensor group with more repeated rows than this is a finding
MOVING = 1e-5          # SI units: a signal that changes less than this after a run is at rest (float32 steps)
LAG_MIN = 0.004        # s: a velocity lagging (or leading) its position's motion by more is a finding (consistent
                       # logs: -3.2..4.5 ms under twice the attitude feedback at 3x noise, 0..1.9 without it;
                       # acn-collect: 1.6..1.8 ms; README)
LAG_BACK = 0.04        # s: action changes this far before a span can still bend the motion inside it (a latency)
LAG_BINS = 8           # bins of those action changes the lag regression takes out
LAG_Z = 8.0            # ... where the lag is this many standard errors from zero
LEG_ORDER_GAIN = 0.5   # another leg order is named where its stance feet spread at most this share of the log's
LEG_ORDER_FROM = 0.015 # m: other orders are tried where the log's spreads the stance feet more (consistent: 0.6-2.2)
SENSOR_GROUPS = ("base_pos", "base_rpy", "joint_pos", "base_linvel", "base_angvel", "joint_vel", "imu_acc")


@dataclass(frozen=True)
class Finding:
    """One inconsistency: which check, which channels, what looks wrong (and the fix)."""

    check: str
    channels: tuple[str, ...]
    message: str
    may_be: tuple[str, ...] = ()  # catalogue effects (acn.sim.effects) that cause this finding too

    def to_json(self) -> dict:
        return {"check": self.check, "channels": list(self.channels), "message": self.message,
                "may_be": list(self.may_be)}


Episode = tuple[np.ndarray, np.ndarray]  # (states (n + 1, 43), actions (n, 12)): consecutive control steps


def check(episodes: list[Episode], dt: float, action_mode: str = "position") -> list[Finding]:
    """Every check on ``episodes`` (NaN columns are channels the log lacks), ``dt`` the control
    period in s. Returns the findings, empty when the log is consistent."""
    episodes = _usable(episodes)
    if not episodes:
        return []
    states = np.concatenate([s for s, _ in episodes])
    out = _units(episodes, dt)
    out += velocity_lag(episodes, dt, {c for f in out for c in f.channels})  # a lag is not blamed for a unit
    order = leg_order(states)
    out += order or stance_feet(states)  # the legs' order explains where the stance feet are
    tilt_named = any(set(GROUPS["base_rpy"]) & set(f.channels) for f in out)  # degrees, another convention
    out += accelerometer(states, trust_tilt=not tilt_named) + contacts(states)
    if action_mode == "position":
        out += actions(episodes)
    return out + repeats(episodes)


def _usable(episodes: list[Episode]) -> list[Episode]:
    """``episodes`` of at least two states, as float arrays."""
    return [(np.asarray(s, float), np.asarray(a, float)) for s, a in episodes if len(s) >= 2]


def _units(episodes: list[Episode], dt: float) -> list[Finding]:
    """The pose and velocity findings (units, signs, frames), which ``velocity_lag`` does not
    blame for a lag; a velocity is not blamed for its position's unit either."""
    out = pose(episodes)
    return out + velocities(episodes, dt, {c for f in out for c in f.channels})


def _runs(m: Measurements) -> list[tuple[int, int]]:
    """Row ranges [a, b) of consecutive transitions of one episode."""
    linked = (m.episode[1:] == m.episode[:-1]) & (m.frame[1:] == m.frame[:-1] + 1)
    starts = np.concatenate([[0], np.flatnonzero(~linked) + 1, [len(m)]])
    return list(zip(starts[:-1].tolist(), starts[1:].tolist()))


def from_measurements(m: Measurements) -> list[Finding]:
    """``check`` on ``acn.measurements.data.Measurements`` (rows of an episode consecutive)."""
    return check(_episodes(m), m.control.control_dt, m.control.action_mode)


def _episodes(m: Measurements) -> list[Episode]:
    """``m``'s runs of consecutive transitions as (states, actions)."""
    return [(np.vstack([m.state[a:b], m.next_state[b - 1:b]]), m.targets[a:b]) for a, b in _runs(m)]


def distrusted(m: Measurements) -> list[str]:
    """Channels of ``m`` that a ``DERIVED`` check finds untrustworthy (``velocity_lag``): the
    diagnosis derives them from the positions, as if they were not logged."""
    episodes = _usable(_episodes(m))
    if not episodes:
        return []
    dt = m.control.control_dt
    suspect = {c for f in _units(episodes, dt) for c in f.channels}  # as ``check``
    return [c for f in velocity_lag(episodes, dt, suspect) for c in f.channels]


def repeated_transitions(m: Measurements, groups=SENSOR_GROUPS) -> tuple[np.ndarray, np.ndarray]:
    """(N,) masks: row t's start state, and its next state, repeat a reading of ``groups``
    (``repeated``)."""
    start, end = np.zeros(len(m), dtype=bool), np.zeros(len(m), dtype=bool)
    for a, b in _runs(m):
        states = np.vstack([m.state[a:b], m.next_state[b - 1:b]])
        rep = np.zeros(len(states), dtype=bool)
        for g in groups:
            rep |= repeated(states, g)
        start[a:b], end[a:b] = rep[:-1], rep[1:]
    return start, end


# ----- velocities against the rate of change of positions -------------------------------------
def _window(s: np.ndarray, k: int, T: float, logged: slice, position, rotate: bool = False):
    """For each window [t, t + k] of one episode's states ``s`` (t = 0 .. n - k - 1; T = k control
    periods, s): (the logged velocity averaged over it (trapezoid), the rate of change of the
    position over it). ``position(a, b, T)`` gives the rate from the states at both ends; with
    ``rotate`` the logged (body-frame) vectors are rotated into the world frame before averaging."""
    v = s[:, logged]
    if rotate:
        v = np.einsum("nij,nj->ni", rpy_to_matrices(s[:, SLICES["base_rpy"]]), v)
    c = np.vstack([np.zeros((1, v.shape[1])), np.cumsum(v, axis=0)])
    total = c[k + 1:] - c[:-k - 1]                      # sum of v_t .. v_{t+k}
    return (total - 0.5 * v[:-k] - 0.5 * v[k:]) / k, position(s[:-k], s[k:], T)


def _windows(episodes: list[Episode], dt: float, logged: slice, position, rotate: bool = False):
    """``_window`` for every window of k control steps (about ``WINDOW_S``) of every episode,
    rows where both are finite, or None where fewer than ``MIN_ROWS``."""
    k = max(1, round(WINDOW_S / dt))
    xs, ys = [], []
    for s, _ in episodes:
        if len(s) <= k:
            continue
        x, y = _window(s, k, k * dt, logged, position, rotate)
        xs.append(x)
        ys.append(y)
    if not xs:
        return None
    x, y = np.concatenate(xs), np.concatenate(ys)
    ok = np.isfinite(x).all(1) & np.isfinite(y).all(1)
    return (x[ok], y[ok]) if ok.sum() >= MIN_ROWS else None


def _joint_rate(a: np.ndarray, b: np.ndarray, T: float) -> np.ndarray:
    """The joint angles' rate of change between states ``a`` and ``b``, T s apart (rad/s)."""
    return (b - a)[:, SLICES["joint_pos"]] / T


def _body_rate(a: np.ndarray, b: np.ndarray, T: float) -> np.ndarray:
    """The trunk's angular velocity in its own frame from the Euler angles of states ``a`` and
    ``b``, T s apart, taken at the middle (rad/s)."""
    d = wrap_angle((b - a)[:, SLICES["base_rpy"]])
    return rpy_rate_to_body(a[:, SLICES["base_rpy"]] + d / 2, d / T)


def _scale(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """Least-squares scale b of x ~ b y (through zero) and the correlation of x and y."""
    yy = float((y * y).sum())
    if yy <= 0 or x.std() == 0 or y.std() == 0:
        return float("nan"), 0.0
    return float((x * y).sum() / yy), float(np.corrcoef(x, y)[0, 1])


def _scale_problem(b: float, r: float) -> tuple[str, str] | None:
    """(kind, text) when a velocity that follows its position's rate (|r| >= 0.5) has the wrong
    scale. The windows are wide (noise in the rate attenuates b, transients at slow control
    rates move it by up to ~0.6x): deg/s within 2x of 57.3, other units only beyond 3x."""
    if abs(r) < 0.5 or not np.isfinite(b) or 1 / 3 <= b <= 3:
        return None
    if DEG / 2 <= b <= DEG * 2:
        return "deg", 'deg/s? map it with "scale": 0.0174533'
    if 1 / (2 * DEG) <= b <= 2 / DEG:
        return "per_deg", "the position in degrees?"
    if -3 <= b <= -1 / 3:
        return "sign", 'the opposite sign: map it with "scale": -1'
    if abs(r) < 0.8:  # another factor is only claimed where the two clearly move together
        return None
    return "scale", f'another unit? ("scale": {1 / b:.3g} would match)'


def _merge(check: str, per_channel: list[tuple[str, str, str, float]], what: str) -> list[Finding]:
    """Findings per kind: channels sharing one problem become one line."""
    out = []
    for kind in dict.fromkeys(k for _, k, _, _ in per_channel):
        rows = [(c, t, v) for c, k, t, v in per_channel if k == kind]
        names = tuple(c for c, _, _ in rows)
        vals = np.array([v for _, _, v in rows])
        value = f"{vals[0]:.3g}" if len(rows) == 1 else f"{vals.min():.3g}..{vals.max():.3g}"
        out.append(Finding(check, names, f"{_names(names)} {what.format(value=value)}: {rows[0][1]}"))
    return out


def _names(names: tuple[str, ...]) -> str:
    for g, members in GROUPS.items():
        if set(members) == set(names):
            return f"every {g} channel"
    return ", ".join(names) if len(names) <= 4 else f"{', '.join(names[:3])} and {len(names) - 3} more"


def velocities(episodes: list[Episode], dt: float, suspect: set[str] = frozenset()) -> list[Finding]:
    """Velocities against the rate of change of positions (``suspect`` positions: skipped)."""
    out: list[Finding] = []
    # Joints: each velocity against the rate of every joint angle (a mixed-up column follows another).
    w = _windows(episodes, dt, SLICES["joint_vel"], _joint_rate)
    if w is not None:
        x, y = w
        problems, unrelated, mixed = [], [], []
        for i, j in enumerate(JOINT_NAMES):
            if f"{j}_pos" in suspect:
                continue
            b, r = _scale(x[:, i], y[:, i])
            corr = np.array([_scale(x[:, i], y[:, k])[1] for k in range(len(JOINT_NAMES))])
            best = int(np.argmax(corr))
            if best != i and corr[best] >= 0.8 and corr[best] > abs(r) + 0.1:
                mixed.append(Finding("velocities", (f"{j}_vel",), f"{j}_vel follows the rate of change of "
                                     f"{JOINT_NAMES[best]}_pos (correlation {corr[best]:.2f}), not of {j}_pos "
                                     f"({r:.2f}): columns mixed up?"))
            elif p := _scale_problem(b, r):
                problems.append((f"{j}_vel", *p, b))
            elif abs(r) < 0.5 and y[:, i].std() > 0.2:  # the joint moves, its velocity does not follow
                unrelated.append((f"{j}_vel", "unrelated", "is it this joint's velocity in rad/s?", r))
        out += _merge("velocities", problems, "{value} x the rate of change of the joint angle") + mixed
        out += _merge("velocities", unrelated, "does not follow the rate of change of the joint angle (correlation {value})")
    if not suspect & set(GROUPS["base_rpy"]) and (degrees := _euler_in_degrees(episodes, dt)):
        return out + [degrees]  # every trunk rate below reads the Euler angles
    # Trunk: body frame (the schema) against world frame, then the scale in the better one.
    rpy = SLICES["base_rpy"]

    def world_rate(a, b, T):
        return (b - a)[:, SLICES["base_pos"]] / T

    def world_angular(a, b, T):
        return np.einsum("nij,nj->ni", rpy_to_matrices(a[:, rpy] + wrap_angle((b - a)[:, rpy]) / 2), _body_rate(a, b, T))

    for group, positions, body, world in (
            # linear: the position's rate is in the world frame; the logged body vectors are rotated into it
            ("base_linvel", ("base_pos", "base_rpy"), _windows(episodes, dt, SLICES["base_linvel"], world_rate, rotate=True),
             _windows(episodes, dt, SLICES["base_linvel"], world_rate)),
            # angular: the Euler angles' rate gives the body-frame rate; the world one rotates it
            ("base_angvel", ("base_rpy",), _windows(episodes, dt, SLICES["base_angvel"], _body_rate),
             _windows(episodes, dt, SLICES["base_angvel"], world_angular))):
        if body is None or world is None or any(suspect & set(GROUPS[g]) for g in positions):
            continue
        e_body = float(np.sqrt(((body[0] - body[1]) ** 2).mean()))
        e_world = float(np.sqrt(((world[0] - world[1]) ** 2).mean()))
        unit = "m/s" if group == "base_linvel" else "rad/s"
        if e_world < 0.5 * e_body and e_body > 0.05:
            flag = "--linvel-frame" if group == "base_linvel" else "--angvel-frame"
            out.append(Finding("velocities", GROUPS[group], f"{group} matches the trunk's motion in the WORLD frame "
                               f"(RMS difference {e_world:.3g} {unit}) better than in the body frame the schema uses "
                               f"({e_body:.3g} {unit}): re-import with {flag} world"))
            continue
        x, y = body
        problems = []
        for k, name in enumerate(GROUPS[group]):
            b, r = _scale(x[:, k], y[:, k])
            if p := _scale_problem(b, r):
                problems.append((name, *p, b))
        out += _merge("velocities", problems, "{value} x the trunk's rate of motion")
    return out


def _euler_in_degrees(episodes: list[Episode], dt: float) -> Finding | None:
    """The trunk's Euler angles logged in degrees. A robot level within a few degrees has them
    within +-pi/2 read as rad, so ``pose`` cannot tell; their rate of change, read so, garbles
    into the other axes. The finding where the gyroscope matches the rate of the angles read as
    degrees on the axis that turns most (within 2x in scale, correlation >= 0.8), with a fifth of
    the RMS difference of reading them as rad."""
    rpy = SLICES["base_rpy"]
    in_rad = []
    for s, a in episodes:
        s = s.copy()
        s[:, rpy] /= DEG
        in_rad.append((s, a))
    as_logged = _windows(episodes, dt, SLICES["base_angvel"], _body_rate)
    as_degrees = _windows(in_rad, dt, SLICES["base_angvel"], _body_rate)
    if as_logged is None or as_degrees is None:
        return None
    x, y = as_degrees
    most = int(np.argmax(y.std(0)))  # the axis that turns most, rad/s
    b, r = _scale(x[:, most], y[:, most])
    if not (y[:, most].std() > 0.05 and 0.5 <= b <= 2 and r >= 0.8):
        return None
    e_deg = float(np.sqrt(((x - y) ** 2).mean()))
    e_rad = float(np.sqrt(((as_logged[0] - as_logged[1]) ** 2).mean()))
    if not e_deg < 0.2 * e_rad:
        return None
    return Finding("velocities", GROUPS["base_rpy"], f"base_angvel matches the rate of change of the Euler angles "
                   f"read as DEGREES (RMS difference {e_deg:.3g} rad/s) better than read as rad ({e_rad:.3g} rad/s): "
                   'degrees? map base_roll, base_pitch and base_yaw with "scale": 0.0174533')


def lag(episodes: list[Episode], dt: float, group: str) -> tuple[float, float]:
    """(lag in s, its z) of ``group``'s velocity readings (joint_vel or base_angvel) behind the
    motion of their positions, from the readings integrated over a span of k rows (about
    ``WINDOW_S``, the windows of ``velocities``): a reading low-passed with time constant tau obeys v = v_read + tau dv_read/dt,
    so over [t, t + k]

        p_{t+k} - p_t - trapezoid(v_read_t .. v_read_{t+k}) = tau (v_read_{t+k} - v_read_t)

    exactly but for the trapezoid's error (a reading taken tau earlier obeys it to first
    order), and tau is the least-squares slope. The gyroscope's span is the Euler angles' change
    turned into body rates at its middle. Further regressors: the action changes whose bend can
    fall inside the span (``LAG_BACK`` back for a latency; every joint's, since a leg's motion
    and the trunk's follow every joint's command), in ``LAG_BINS`` bins: each new action bends
    the motion at its row (or a latency after it) and the trapezoid misses the bend.
    Integrated over whole rows, the readings' noise adds no bias, the feedback through actions
    that carry it little, and neither does the PD's own response within a span much: a
    derivative of the positions over several rows instead (the central rate against the reading,
    on the acceleration) read 4-8 ms under twice the attitude feedback at 50 Hz, 16 ms at 200
    Hz, and a 10 ms filter as 11-18 ms (README). One regression per channel; tau is their
    inverse-variance mean, its variance taken k times larger (neighbouring spans share k - 1
    rows). (nan, 0) where too few rows."""
    k = max(1, round(WINDOW_S / dt))                  # the windows of ``velocities``
    span = k * dt
    lo, hi = -int(np.ceil(LAG_BACK / dt - 1e-9)), k  # action changes u_l - u_{l-1} for t + lo <= l < t + hi
    edges = np.unique(np.round(np.linspace(lo, hi, min(LAG_BINS, hi - lo) + 1)).astype(int))
    position = _joint_rate if group == "joint_vel" else _body_rate
    xs, ys, us = [], [], []
    for s, u in episodes:
        t = np.arange(-lo + 1, len(s) - k)
        if len(t) < 1:
            continue
        mean, rate = _window(s, k, span, SLICES[group], position)
        v = s[:, SLICES[group]]
        ys.append(span * (rate[t] - mean[t]))           # the position's change - the readings' trapezoid
        xs.append(v[t + k] - v[t])
        # the changes within each bin sum to the difference of the actions at its edges
        us.append(np.stack([u[t + e1 - 1] - u[t + e0 - 1] for e0, e1 in zip(edges[:-1], edges[1:])], axis=1))
    if not xs:
        return float("nan"), 0.0
    x, y, du = np.concatenate(xs), np.concatenate(ys), np.concatenate(us)  # (n, c), (n, c), (n, bins, 12)
    ok = np.isfinite(x).all(1) & np.isfinite(y).all(1) & np.isfinite(du).all((1, 2))
    x, y, du = x[ok], y[ok], du[ok].reshape(int(ok.sum()), du.shape[1] * du.shape[2])
    if len(x) < MIN_ROWS + du.shape[1]:
        return float("nan"), 0.0
    taus, inverse_var = [], []
    for c in range(y.shape[1]):
        design = np.column_stack([x[:, c], du])
        coef, *_ = np.linalg.lstsq(design, y[:, c], rcond=None)
        resid = y[:, c] - design @ coef
        var = k * np.linalg.pinv(design.T @ design)[0, 0] * (resid @ resid) / max(len(resid) - design.shape[1], 1)
        if var > 0:
            taus.append(coef[0])
            inverse_var.append(1.0 / var)
    if not taus:
        return float("nan"), 0.0
    w = np.array(inverse_var)
    tau, se = float(np.dot(w, taus) / w.sum()), float(1.0 / np.sqrt(w.sum()))
    return tau, tau / se


def velocity_lag(episodes: list[Episode], dt: float, suspect: set[str] = frozenset()) -> list[Finding]:
    """A finding per velocity group (joint_vel, base_angvel) whose readings lag or lead the motion
    of their positions (``lag``) by more than ``LAG_MIN``, ``LAG_Z`` standard errors from zero.
    The diagnosis derives those velocities from the positions instead
    (``DERIVED``): a model compared with a filtered velocity reads the filter's lag as inertia
    or friction."""
    out = []
    for group, position in (("joint_vel", "joint_pos"), ("base_angvel", "base_rpy")):
        if suspect & set(GROUPS[position]) or suspect & set(GROUPS[group]):
            continue
        tau, z = lag(episodes, dt, group)
        if np.isfinite(tau) and abs(tau) > LAG_MIN and abs(z) > LAG_Z:
            out.append(Finding("velocity_lag", GROUPS[group], f"the readings of {_names(GROUPS[group])} "
                               f"{'lag' if tau > 0 else 'lead'} the motion of their positions by {1e3 * abs(tau):.0f} "
                               f"ms (z {abs(z):.0f}): low-pass filtered, read at another time than the positions, or "
                               "differenced from them (a backward difference lags half a step)? the diagnosis derives "
                               "them from the positions instead"))
    return out


# ----- pose ------------------------------------------------------------------------------------
def _upright(episodes: list[Episode]) -> np.ndarray:
    """(N,) the episodes' rows whose trunk does not meet the fall rule
    (``acn.sim.collector.FALL_RULE``; an unlogged height or tilt counts as upright); every row
    where most episodes do not start upright by it (a height in other units or from another zero,
    or angles in degrees, would read as fallen) or fewer than ``MIN_ROWS`` rows are."""
    from acn.sim.collector import FALL_HEIGHT, FALL_TILT_SQ

    def up(s: np.ndarray) -> np.ndarray:
        z, roll, pitch = (s[:, STATE_NAMES.index(n)] for n in ("base_pos_z", "base_roll", "base_pitch"))
        with np.errstate(invalid="ignore"):
            return ~((z < FALL_HEIGHT) | (roll * roll + pitch * pitch >= FALL_TILT_SQ))

    rows = np.concatenate([up(s) for s, _ in episodes])
    starts = np.array([up(s[:1])[0] for s, _ in episodes if len(s)])
    trusted = starts.mean() > 0.5 and rows.sum() >= MIN_ROWS
    return rows if trusted else np.ones(len(rows), dtype=bool)


def pose(episodes: list[Episode]) -> list[Finding]:
    """Joint angles in the A1's ranges (while the robot is upright: one that collapses folds its
    legs past the URDF's limits; most rows, or the median, outside), the trunk upright and its
    height where episodes start."""
    from acn.sim.robot import STANDING_HEIGHT, joint_limits

    states = np.concatenate([s for s, _ in episodes])
    out: list[Finding] = []
    q = states[_upright(episodes), SLICES["joint_pos"]]
    limits = joint_limits()
    problems = []
    for i, j in enumerate(JOINT_NAMES):
        v = q[:, i][np.isfinite(q[:, i])]
        if len(v) < MIN_ROWS:
            continue
        lo, hi = limits[i] + [-0.05, 0.05]
        inside = lambda x: ((x >= lo) & (x <= hi)).mean()  # noqa: E731
        if inside(v) >= 0.95:
            continue
        share, med = 1 - inside(v), float(np.median(v))
        if inside(v / DEG) >= 0.95:
            problems.append((f"{j}_pos", "deg", 'degrees? map it with "scale": 0.0174533', med))
        elif inside(-v) >= 0.95:
            problems.append((f"{j}_pos", "sign", 'the opposite sign convention? map it with "scale": -1', med))
        elif lo <= med <= hi and share < 0.5:
            # Not a convention: a wrong zero, unit or sign moves every row. MuJoCo's joint limits
            # are soft, and a robot thrown about presses joints past them, in the model as in a
            # simulated log (by up to 1 rad in 6-22 % of the upright rows under a twice-too-stiff
            # attitude feedback); a wrong zero that moves only some rows out moves the feet
            # (stance_feet).
            continue
        else:
            problems.append((f"{j}_pos", "range", f"outside the A1's range in {share:.0%} of rows: another zero? "
                             'map it with an "offset"', med))
    out += _merge("pose", problems, "(median {value}) lies outside the A1's joint range (URDF)")
    # Tilt where episodes start (a robot may fall over later; a convention error tilts it from the start).
    cols = [STATE_NAMES.index("base_roll"), STATE_NAMES.index("base_pitch")]
    first = np.array([s[0, cols] for s, _ in episodes])
    first = first[np.isfinite(first).all(1)]
    if len(first) and (np.abs(first) > 0.8).any(1).mean() > 0.5:
        r, p = np.median(np.abs(first), axis=0)
        out.append(Finding("pose", GROUPS["base_rpy"], f"the trunk is tilted by more than 0.8 rad where most episodes "
                           f"start (median |roll| {r:.2f}, |pitch| {p:.2f} rad): the schema's orientation is extrinsic "
                           "XYZ Euler angles in rad (from a quaternion: which column is w?)"))
    # The schema's pitch (the middle of extrinsic XYZ Euler angles) lies within +-pi/2: beyond it in
    # more than a few rows, the angles are in degrees (a level robot's few degrees read as rad) or
    # in another convention.
    pitch = states[:, STATE_NAMES.index("base_pitch")]
    pitch = pitch[np.isfinite(pitch)]
    if len(pitch) >= MIN_ROWS and (beyond := float((np.abs(pitch) > np.pi / 2 + 0.05).mean())) > 0.01:
        hint = 'degrees? map base_roll, base_pitch and base_yaw with "scale": 0.0174533' \
            if (np.abs(pitch / DEG) <= np.pi / 2).all() else "another Euler convention?"
        out.append(Finding("pose", GROUPS["base_rpy"], f"base_pitch reaches {np.abs(pitch).max():.3g}, beyond the "
                           f"+-pi/2 rad of the schema's extrinsic XYZ Euler angles, in {beyond:.0%} of rows: {hint}"))
    # Height where episodes start, too: a robot that falls onto its back lies with the trunk 6 cm
    # high for most of a log, in the right units and frame.
    iz = STATE_NAMES.index("base_pos_z")
    starts = [z[np.isfinite(z)][:START_ROWS] for z in (s[:, iz] for s, _ in episodes)]
    starts = [float(np.median(z)) for z in starts if len(z)]
    if np.isfinite(states[:, iz]).sum() >= MIN_ROWS and not 0.08 <= (med := float(np.median(starts))) <= 0.6:
        hint = 'mm? map it with "scale": 0.001' if 0.08 <= med / 1000 <= 0.6 else \
            f"the schema's base_pos_z is the trunk origin's height above the ground (the A1 stands at {STANDING_HEIGHT} m)"
        out.append(Finding("pose", ("base_pos_z",), f"base_pos_z is {med:.4g} m where episodes start (median): {hint}"))
    return out


def stance_feet(states: np.ndarray, most: int = 4000) -> list[Finding]:
    """Feet marked touching (or, without contact flags, the lowest foot) at ground height."""
    from acn.sim.stance import Stance

    stance = Stance(states, most)
    if len(stance.s) < MIN_ROWS:
        return []
    h = stance.carrying(np.zeros(6))  # m, the trunk as logged
    basis = "the log marks as touching the ground" if stance.marked else "lowest in each row"
    med, lo, hi = (float(v) for v in np.percentile(h, [50, 10, 90]))
    if abs(med) <= STANCE_MEDIAN and hi - lo <= STANCE_SPREAD:
        return []
    sink = med < 0  # below the ground: soft ground lets the feet sink (1.3 mm on MuJoCo's nominal contact)
    return [Finding("stance_feet", GROUPS["base_pos"] + GROUPS["joint_pos"],
                    f"the feet {basis} are {med * 100:.1f} cm above the ground by forward kinematics (10-90 %: "
                    f"{lo * 100:.1f}..{hi * 100:.1f} cm): the ground is not at z = 0, the trunk origin is not the A1's, "
                    "the joint angles have another zero or sign, or the legs another order (ours: FR, FL, RR, RL); "
                    "or the trunk is measured in another frame (effect base_frame_offset: a marker, PyBullet's centre "
                    "of mass); or, physics, the joint encoders' zeros are off by a few degrees (effect encoder_offset)"
                    + (", or the feet sink into soft ground (effect ground_softness)" if sink else ""),
                    may_be=("encoder_offset", "base_frame_offset") + (("ground_softness",) if sink else ()))]


def relabel_legs(states: np.ndarray, order: tuple[str, ...]) -> np.ndarray:
    """(n, 43) states whose legs were logged in ``order`` (the leg whose joints and contact flag
    sit where the schema has ``FOOT_NAMES[i]`` is really ``order[i]``), in the schema's order."""
    out = np.array(states, dtype=np.float64)
    for i, leg in enumerate(order):
        k = FOOT_NAMES.index(leg)
        for g in ("joint_pos", "joint_vel"):
            base = SLICES[g].start
            out[:, base + 3 * k: base + 3 * k + 3] = states[:, base + 3 * i: base + 3 * i + 3]
        out[:, SLICES["contact"].start + k] = states[:, SLICES["contact"].start + i]
    return out


def leg_order(states: np.ndarray, most: int = 2000) -> list[Finding]:
    """A finding where the legs read in another order (any of the 23) put the feet that carry the
    robot on the ground far better: the 10-90 % spread of their heights by forward kinematics
    within the stance thresholds, and at most ``LEG_ORDER_GAIN`` of the spread in the log's
    order and of the next best order's (on consistent logs the schema's order spreads 0.7-1 cm,
    the next best 2.8-8 cm). Where the log's order spreads less than ``LEG_ORDER_FROM`` it is
    taken as right without trying the others (0.1-0.4 s)."""
    import itertools

    from acn.sim.stance import Stance

    def spread(order) -> tuple[float, float]:
        stance = Stance(relabel_legs(states, order), most)
        if len(stance.s) < MIN_ROWS:
            return float("nan"), float("nan")
        lo, med, hi = np.percentile(stance.carrying(np.zeros(6)), [10, 50, 90])
        return float(hi - lo), float(med)

    logged = spread(FOOT_NAMES)[0]
    if not np.isfinite(logged) or logged <= LEG_ORDER_FROM:  # the log's order fits
        return []
    tried = sorted((spread(o) + (o,) for o in itertools.permutations(FOOT_NAMES) if o != FOOT_NAMES),
                   key=lambda r: r[0])
    (best, med, order), second = tried[0], tried[1][0]
    if not (best <= STANCE_SPREAD and abs(med) <= STANCE_MEDIAN and best <= LEG_ORDER_GAIN * min(logged, second)):
        return []
    names = ",".join(order)
    hint = " (legged_gym and Isaac Gym use this order)" if order == ("FL", "FR", "RL", "RR") else ""
    return [Finding("leg_order", GROUPS["joint_pos"] + GROUPS["joint_vel"] + GROUPS["contact"],
                    f"the legs look logged in the order {', '.join(order)}{hint}: read so, the feet that carry the "
                    f"robot spread {100 * best:.1f} cm around the ground by forward kinematics, against "
                    f"{100 * logged:.1f} cm in the schema's order (FR, FL, RR, RL): import with --leg-order {names}")]


# ----- sensors and actions ---------------------------------------------------------------------
def accelerometer(states: np.ndarray, trust_tilt: bool = True) -> list[Finding]:
    """The accelerometer's mean against the mean of gravity in the trunk frame that the logged roll
    and pitch give (``trust_tilt`` False: the Euler angles are named wrong, the trunk taken level).

    Over a log the trunk's acceleration averages out, so the specific force averages to gravity
    as the trunk sees it, whatever the trunk does: a robot lying on its back reads -9.81 up, a
    hopping one that pitches 0.2 rad reads about 2 m/s^2 forward. Only the rows near level
    counted before, and a hopping robot, level while its legs push and pitched while they fly,
    read 12.5-13 m/s^2 up on them: a finding on a consistent log."""
    acc = states[:, SLICES["imu_acc"]]
    rpy = states[:, SLICES["base_rpy"]].copy()
    rpy[:, 2] = 0.0  # yaw does not turn gravity in the trunk frame
    if not (trust_tilt and np.isfinite(rpy).all(1).mean() > 0.5):
        rpy[:] = 0.0
    keep = np.isfinite(acc).all(1) & np.isfinite(rpy).all(1)
    acc, rpy = acc[keep], rpy[keep]
    if len(acc) < MIN_ROWS:
        return []
    mean = acc.mean(0)
    expected = GRAVITY * rpy_to_matrices(rpy)[:, 2, :].mean(0)  # world up in the trunk frame: R^T e_z
    if np.linalg.norm(mean - expected) < 2.5:
        return []
    if np.linalg.norm(mean + expected) < 2.5:
        hint = 'its sign is flipped: map each with "scale": -1'
    elif np.linalg.norm(mean - expected / GRAVITY) < 0.25:
        hint = 'in g? map each with "scale": 9.81'
    elif np.linalg.norm(mean) < 2:
        hint = "gravity removed? the schema's accelerometer includes it (specific force)"
    else:
        hint = "another unit or frame?"
    return [Finding("accelerometer", GROUPS["imu_acc"], f"the accelerometer's mean is ({mean[0]:.2f}, {mean[1]:.2f}, "
                    f"{mean[2]:.2f}) m/s^2, not about the ({expected[0]:.2f}, {expected[1]:.2f}, {expected[2]:.2f}) "
                    f"gravity gives the trunk at its logged roll and pitch: {hint}")]


def contacts(states: np.ndarray) -> list[Finding]:
    c = states[:, SLICES["contact"]]
    bad = [(GROUPS["contact"][i], float(np.nanmax(np.abs(c[:, i]))))
           for i in range(c.shape[1]) if np.isfinite(c[:, i]).any()
           and (np.abs(c[:, i][np.isfinite(c[:, i])] - 0.5) > 0.51).mean() > 0.01]
    if not bad:
        return []
    names = tuple(n for n, _ in bad)
    return [Finding("contacts", names, f"{_names(names)} should be 0/1 flags (1: touching the ground) but reach "
                    f"{max(v for _, v in bad):.3g}: forces? map them with \"threshold\": a force between swing and stance")]


def repeated(states: np.ndarray, group: str) -> np.ndarray:
    """(n,) True where ``group``'s readings in consecutive ``states`` (n, 43) of one episode equal
    the previous row's exactly, in a run of at most ``REPEAT_RUN`` such rows after which the
    signal moves again (by more than ``MOVING``): a reading that did not arrive. Longer runs, and
    changes within float32's resolution, are a robot at rest."""
    x = states[:, SLICES[group]]
    same = np.r_[False, (x[1:] == x[:-1]).all(1) & np.isfinite(x[1:]).all(1)]
    edges = np.diff(np.r_[0, same.astype(np.int8), 0])
    out = np.zeros(len(x), dtype=bool)
    for a, b in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):  # runs same[a:b]
        if b - a <= REPEAT_RUN and b < len(x) and np.abs(x[b] - x[a]).max() > MOVING:
            out[a:b] = True
    return out


def repeats(episodes: list[Episode]) -> list[Finding]:
    """One finding naming the sensor groups whose readings repeat the previous row's
    (``repeated``) in more than ``REPEAT_SHARE`` of the rows."""
    rows = sum(len(s) for s, _ in episodes)
    share = {g: sum(int(repeated(s, g).sum()) for s, _ in episodes) / max(rows, 1) for g in SENSOR_GROUPS}
    bad = [g for g in SENSOR_GROUPS if share[g] > REPEAT_SHARE]
    if not bad:
        return []
    lo, hi = min(share[g] for g in bad), max(share[g] for g in bad)
    how = f"{lo:.0%}" if round(lo, 2) == round(hi, 2) else f"{lo:.0%}-{hi:.0%}"
    what = ", ".join(bad) if len(bad) < len(SENSOR_GROUPS) else "every sensor group"
    return [Finding("repeats", tuple(c for g in bad for c in GROUPS[g]),
                    f"{what} repeat{'s' if len(bad) == 1 else ''} the previous row's values exactly in {how} of the "
                    "rows (runs of 1-3 in a moving signal): readings that did not arrive, or a sensor slower than the "
                    "log; the diagnosis leaves out the steps that start or end on them")]


LEFT_OUT = ("repeats",)  # checks whose rows the diagnosis leaves out (acn.diagnosis.problem), so their
# findings do not make a verdict's data suspect
DERIVED = ("velocity_lag",)  # checks whose channels the diagnosis derives from positions instead, likewise


def actions(episodes: list[Episode]) -> list[Finding]:
    """Position actions are PD targets in rad: near the joint angles they drive (while the robot
    is upright: a collapsed robot's joints lie far from its targets)."""
    gap = np.concatenate([a - s[:-1, SLICES["joint_pos"]] for s, a in episodes])
    gap = gap[_upright([(s[:-1], a) for s, a in episodes])]
    problems = []
    for i, j in enumerate(JOINT_NAMES):
        g = gap[:, i][np.isfinite(gap[:, i])]
        if len(g) >= MIN_ROWS and abs(med := float(np.median(g))) > 0.5:
            problems.append((f"action.{j}", "far", 'position actions are absolute PD targets in rad: offsets from a '
                             'nominal pose (map them with an "offset") or another unit?', med))
    return _merge("actions", problems, "differs from its joint angle by a median of {value} rad")
