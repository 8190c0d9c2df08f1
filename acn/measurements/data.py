"""Measurements: recorded transitions of one robot (or one simulator) in the documented schema.

``load_measurements(path, side)`` reads any of our datasets through ``LeRobotDataset``: an
``acn-import``-ed robot log, an unpaired ``acn-collect`` dataset, or either side of a paired
one. Channels a log lacks are NaN and listed in ``missing``. The control settings the robot
ran with (rates, gains, torque limit, action mode) come from the dataset's ``acn`` metadata,
so a diagnosis needs nothing else.

Rows of one episode are consecutive control steps: row t + 1's state is row t's next state.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from acn.datasets import schema
from acn.datasets.metadata import AcnMetadata
from acn.datasets.reader import read_card, read_columns, refuse_implausible
from acn.errors import UserError
from acn.sim import plausible
from acn.sim.actuation import position_targets
from acn.sim.backends import SimConfig
from acn.sim.state import ACTION_DIM, GROUPS, SLICES, STATE_NAMES

if TYPE_CHECKING:
    from acn.measurements.odometry import EstimatedHeight

os.environ.setdefault("HF_HUB_OFFLINE", "1")

SIDES = ("source", "target")
REQUIRED_GROUPS = ("joint_pos",)  # with the actions: the least a diagnosis can work from


@dataclass
class Measurements:
    """N transitions (float64); ``state`` and ``next_state`` hold NaN in missing channels."""

    state: np.ndarray        # (N, 43) s_t
    action: np.ndarray       # (N, 12) a_t; (N, 60) a hybrid command (``SimConfig.hybrid``)
    next_state: np.ndarray   # (N, 43) s_{t+1}
    effort: np.ndarray       # (N, 12) applied joint torque, N m (NaN if not logged)
    episode: np.ndarray      # (N,) int, rows of one episode are consecutive control steps
    frame: np.ndarray        # (N,) int, control step within the episode
    control: SimConfig       # the settings the robot was driven with (nominal physical parameters)
    info: AcnMetadata        # the dataset's ``acn`` block
    description: str = ""
    missing: list[str] = field(default_factory=list)   # channels the log lacks
    height: EstimatedHeight | None = None  # how estimated trunk heights depend on the started model's ground

    def __len__(self) -> int:
        return len(self.state)

    @property
    def targets(self) -> np.ndarray:
        """(N, 12) the joint targets (or torques) of the actions. For hybrid commands the target at
        which the PD gives the command's torque (``acn.sim.actuation.position_targets``)."""
        return position_targets(self.action, self.state[:, SLICES["joint_pos"]])

    @property
    def available(self) -> np.ndarray:
        """(43,) bool: channels that were measured."""
        return np.array([n not in self.missing for n in STATE_NAMES])

    def with_neighbours(self, rows: np.ndarray, lag: int) -> np.ndarray:
        """Mask of ``rows`` whose rows ``lag`` control steps before and after are in the same
        episode (call it on whole measurements, as ``previous_actions``)."""
        ok = np.ones(len(rows), dtype=bool)
        for shift in (-lag, lag):
            other = np.clip(rows + shift, 0, len(self) - 1)
            ok &= (rows + shift >= 0) & (rows + shift < len(self)) & (self.episode[other] == self.episode[rows]) & \
                (self.frame[other] == self.frame[rows] + shift)
        return ok

    def subset(self, rows: np.ndarray) -> "Measurements":
        return Measurements(self.state[rows], self.action[rows], self.next_state[rows], self.effort[rows],
                            self.episode[rows], self.frame[rows], self.control, self.info, self.description,
                            self.missing, None if self.height is None else self.height.subset(rows))

    def reading_accelerometer(self, kind: str) -> "Measurements":
        """These measurements with the accelerometer read as ``kind`` (``SimConfig.imu_acc``): how
        models predict it and leg odometry fuses it (``fill_derived``)."""
        return self if self.control.imu_acc == kind else replace(self, control=replace(self.control, imu_acc=kind))

    def without(self, channels: list[str]) -> "Measurements":
        """A copy in which ``channels`` count as not logged (NaN, listed in ``missing``): readings
        the data checks do not trust, derived like missing ones by ``fill_derived``."""
        new = [c for c in channels if c not in self.missing]
        if not new:
            return self
        cols = [STATE_NAMES.index(c) for c in new]
        state, next_state = self.state.copy(), self.next_state.copy()
        state[:, cols] = next_state[:, cols] = np.nan
        return Measurements(state, self.action, next_state, self.effort, self.episode, self.frame, self.control,
                            self.info, self.description, [*self.missing, *new], self.height)

    def starts(self, rows: np.ndarray, backend: str, configs: SimConfig | list[SimConfig],
               model: np.ndarray | None = None) -> np.ndarray:
        """States ``rows`` as a simulator of ``backend`` built from ``configs[model[i]]`` (``model``
        default all 0) starts from them: a copy, where the trunk's height was estimated, estimated
        for that model (``EstimatedHeight.starts``: its ground's sink, encoder offsets, trunk frame)."""
        states = self.state[rows]
        if self.height is None:
            return states.copy()
        configs = [configs] if isinstance(configs, SimConfig) else configs
        return self.height.starts(states, rows, backend, configs,
                                  np.zeros(len(rows), int) if model is None else np.asarray(model))

    def previous_actions(self, rows: np.ndarray, count: int, targets: bool = False) -> np.ndarray:
        """(len(rows), count, 12 or 60): the actions of the ``count`` steps before each row, oldest
        first (``targets``: their ``targets``, 12).

        Before an episode's first row its first action is repeated. Call it on whole
        measurements (rows of an episode consecutive), not on a ``subset``.
        """
        action = self.targets if targets else self.action
        out = np.empty((len(rows), count, action.shape[1]))
        for j in range(count):  # j = 0 is the oldest: ``count`` steps back
            back = count - j
            src = np.maximum(rows - np.minimum(self.frame[rows], back), 0)  # clamped to the episode's start
            out[:, j] = action[src]
        return out

    def windows(self, horizon: int) -> np.ndarray:
        """Rows t from which ``horizon`` consecutive transitions of one episode exist."""
        n = len(self)
        if horizon <= 1:
            return np.arange(n)
        end = np.arange(n) + horizon - 1
        ok = end < n
        ok[ok] = (self.episode[end[ok]] == self.episode[ok]) & (self.frame[end[ok]] - self.frame[ok] == horizon - 1)
        return np.flatnonzero(ok)


def load_measurements(path: str | Path, side: str = "source") -> Measurements:
    """Read measurements from a dataset (see module docstring); ``side`` for paired datasets."""
    if side not in SIDES:
        raise UserError(f"side must be one of {', '.join(SIDES)}, got {side!r}")
    path = Path(path)
    acn = read_card(path).acn
    if side == "target" and not acn.paired:
        raise UserError(f"{path} is not paired: it has no target side")
    key = (lambda k: k) if side == "source" else schema.target_key
    hybrid = bool(acn.hybrid_actions) and side == "source"
    cols, _ = read_columns(path, [key(schema.STATE), key(schema.ACTION), key(schema.NEXT_STATE)]
                           + ["episode_index", "frame_index"] + [schema.ACTION_HYBRID] * hybrid,
                           optional=(key(schema.EFFORT),))
    state, action, next_state = cols[key(schema.STATE)], cols[key(schema.ACTION)], cols[key(schema.NEXT_STATE)]
    if hybrid:  # the actions carry the gains, velocity targets and feedforward sent with them (SimConfig.hybrid)
        sent = cols[schema.ACTION_HYBRID]
        if sent.shape[1] == 3 * ACTION_DIM:  # format 1: kp, kd, kd dq_des + tau_ff (the velocity target folded in)
            sent = np.concatenate([sent[:, :2 * ACTION_DIM], np.zeros_like(sent[:, :ACTION_DIM]),
                                   sent[:, 2 * ACTION_DIM:]], axis=1)
        if not (np.isfinite(sent).all() and (sent[:, :2 * ACTION_DIM] >= 0).all()):
            raise UserError(f"{path} has gains in {schema.ACTION_HYBRID} that are negative or not finite")
        action = np.concatenate([action, sent], axis=1)
    effort = cols.get(key(schema.EFFORT), np.full_like(action, np.nan))
    missing = list(acn.missing_channels or ())
    lacking = [g for g in REQUIRED_GROUPS if all(n in missing for n in GROUPS[g])]
    if lacking:
        raise UserError(f"{path} has no {' or '.join(lacking)} channels: a diagnosis needs joint positions and actions")
    if not np.isfinite(action).all():
        row = int(np.argwhere(~np.isfinite(action))[0][0])
        raise UserError(f"{path}: episode {int(cols['episode_index'][row])} has non-finite actions")
    if not np.isfinite(state[:, [i for i, n in enumerate(STATE_NAMES) if n not in missing]]).any():
        raise UserError(f"{path}: every state is non-finite (NaN or inf): nothing to compare")
    refuse_implausible(path, cols["episode_index"], [
        ("state", state, plausible.STATE_BOUND, STATE_NAMES), ("next state", next_state, plausible.STATE_BOUND, STATE_NAMES),
        ("action", action, plausible.action_bound(acn.action_mode, action.shape[1]),
         plausible.action_names(action.shape[1]))])
    control = acn.sim_config(hybrid=hybrid)
    simulator = acn.source if side == "source" else acn.target
    who = simulator.simulator if simulator else side
    return Measurements(state, action, next_state, effort, cols["episode_index"].astype(np.int64),
                        cols["frame_index"].astype(np.int64), control, acn,
                        description=f"{path.name} ({who}{', ' + side + ' side' if acn.paired else ''})",
                        missing=missing)


def load_measurement_sets(paths: list[str | Path], side: str = "source") -> Measurements:
    """Several datasets of one robot as one set of measurements (one dataset: ``load_measurements``).

    Each keeps its episodes (renumbered after the previous dataset's); they must share the control
    settings (rates, gains, torque limit, action mode) and the action layout, since one model with
    one controller re-simulates them all. Metadata is the first dataset's; a channel missing in any
    of them is missing in all."""
    parts = [load_measurements(p, side=side) for p in paths]
    if len(parts) == 1:
        return parts[0]
    first = parts[0]
    for path, m in zip(paths[1:], parts[1:]):
        a, b = first.info, m.info
        same = (a.action_mode == b.action_mode and np.isclose(a.control_hz, b.control_hz)
                and a.substeps == b.substeps and np.isclose(a.physics_dt, b.physics_dt)
                and np.allclose(a.kp, b.kp) and np.allclose(a.kd, b.kd) and np.isclose(a.torque_limit, b.torque_limit)
                and m.action.shape[1] == first.action.shape[1])
        if not same:
            raise UserError(f"{path} was recorded with other control settings (rates, gains, torque limit or action "
                            f"mode) than {paths[0]}: diagnose them separately")
    missing = sorted({c for m in parts for c in m.missing}, key=STATE_NAMES.index)
    offsets = np.cumsum([0] + [int(m.episode.max()) + 1 for m in parts[:-1]])

    def join(name: str) -> np.ndarray:
        return np.concatenate([getattr(m, name) for m in parts])

    state, next_state = join("state"), join("next_state")
    for arr in (state, next_state):
        arr[:, [STATE_NAMES.index(c) for c in missing]] = np.nan
    return replace(first, state=state, action=join("action"), next_state=next_state, effort=join("effort"),
                   episode=np.concatenate([m.episode + k for m, k in zip(parts, offsets)]), frame=join("frame"),
                   description=" + ".join(m.description for m in parts), missing=missing)


def fill_derived(m: Measurements, backend: str | None = None) -> tuple[Measurements, list[str]]:
    """Measurements whose missing VELOCITY channels are derived from positions (central
    differences along each episode, one-sided at its ends, angles wrapped), and whose missing
    trunk position (a log without motion capture) is estimated by leg odometry
    (``acn.measurements.odometry``: height and, if missing too, linear velocity from the stance
    feet), so that a simulator can start from them. Returns the filled copy and the names of the
    derived channels (never compared with a prediction). Missing joint angles or trunk
    orientation cannot be derived: a ``UserError`` names them. ``backend``: the simulator that
    will start from the result (odometry puts the feet as deep into its ground as they sink
    standing; None: a rigid ground).
    """
    from acn.sim.rotations import rpy_rate_to_body, rpy_to_matrices
    from acn.sim.state import wrap_angle

    absent = [n for g in ("base_rpy", "joint_pos") for n in GROUPS[g] if n in m.missing]
    if absent:
        raise UserError(f"re-simulating needs the trunk's orientation and the joint angles; the measurements "
                        f"lack {', '.join(absent)}")
    no_position = any(n in m.missing for n in GROUPS["base_pos"])
    derived = [n for g in ("base_linvel", "base_angvel", "joint_vel") for n in GROUPS[g]
               if n in m.missing and not (no_position and g == "base_linvel")]  # odometry's, below
    if not derived and not no_position:
        return m, []
    dt = m.control.control_dt
    n = len(m)
    linked = np.zeros(n, dtype=bool)  # row t - 1 is the step before row t
    linked[1:] = (m.episode[1:] == m.episode[:-1]) & (m.frame[1:] == m.frame[:-1] + 1)
    before = np.where(linked[:, None], np.roll(m.state, 1, axis=0), m.state)
    span = np.where(linked, 2.0, 1.0)[:, None] * dt

    def rates(a: np.ndarray, b: np.ndarray, dt_: np.ndarray, at: np.ndarray) -> dict[str, np.ndarray]:
        d = (b - a) / dt_
        d[:, SLICES["base_rpy"]] = wrap_angle(b[:, SLICES["base_rpy"]] - a[:, SLICES["base_rpy"]]) / dt_
        rot = rpy_to_matrices(at[:, SLICES["base_rpy"]])
        return {"joint_vel": d[:, SLICES["joint_pos"]],
                "base_linvel": np.einsum("nji,nj->ni", rot, d[:, SLICES["base_pos"]]),
                "base_angvel": rpy_rate_to_body(at[:, SLICES["base_rpy"]], d[:, SLICES["base_rpy"]])}

    now = rates(before, m.next_state, span, m.state)
    nxt = rates(m.state, m.next_state, np.full((n, 1), dt), m.next_state)  # backward, at t + 1
    follows = np.zeros(n, dtype=bool)  # row t + 1 exists: its central value is the better s_{t+1}
    follows[:-1] = linked[1:]
    state, next_state = m.state.copy(), m.next_state.copy()
    for g in ("joint_vel", "base_linvel", "base_angvel"):
        for k, name in enumerate(GROUPS[g]):
            if name in derived:
                c = SLICES[g].start + k
                state[:, c] = now[g][:, k]
                next_state[:, c] = np.where(follows, np.roll(now[g][:, k], -1), nxt[g][:, k])
    if no_position:
        from acn.measurements.odometry import fill_trunk, standing_sink

        sink = standing_sink(backend, physics_dt=m.control.physics_dt) if backend else 0.0
        state, next_state, estimated, height = fill_trunk(state, next_state, linked, dt, m.missing, sink,
                                                          m.control.imu_acc)
        derived = derived + estimated
    out = Measurements(state, m.action, next_state, m.effort, m.episode, m.frame, m.control, m.info,
                       m.description, [c for c in m.missing if c not in derived], height if no_position else m.height)
    return out, derived

