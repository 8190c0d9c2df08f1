"""The diagnosis problem: measurements, which channels to compare, how to scale them, which
rows fit and which rows judge, and one call that re-simulates rows under a model.

Errors are normalised per channel so that channels in different units can be ranked: a
channel's error at horizon k is divided by the spread (std) of its measured k-step change, so
1.0 means "as wrong as predicting that nothing moves". Rows are split by episode (by time
blocks when there are too few episodes) into FIT rows, on which parameters are estimated, and
HELD-OUT rows, on which every reported error and every explained share is computed.

One diagnosis STEP is ``DiagnoseConfig.step_seconds`` of control steps (0.02 s: one control
step at 50 Hz and below, four at 200 Hz), and horizons count these steps. At a high control
rate one control step moves the robot less than its sensor noise: a 200 Hz log with sensor
noise and joint damping 0.5 had the trunk's frame, armature and encoder offsets each remove
55-61 % of the one-control-step error (they reshape how the noise in the measured start state
propagates) against damping's 38 %, and `--auto` added offsets before damping. A prediction
over 0.02 s of the logged actions lets the physics act as long as at 50 Hz.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from acn.measurements import checks
from acn.measurements.data import Measurements, fill_derived
from acn.datasets.reader import state_difference
from acn.diagnosis.granularity import GRANULARITIES
from acn.errors import UserError
from acn.sim.actuation import LAG_MEMORY, position_targets
from acn.sim.backends import SimConfig
from acn.sim.effects import EFFECT_NAMES, Model
from acn.sim.resim import Resimulator
from acn.sim.state import ACTION_DIM, GROUPS, SLICES, STATE_NAMES

# Channel groups a model is compared on (contacts are binary readings, not predicted).
COMPARED_GROUPS = ("base_pos", "base_rpy", "joint_pos", "base_linvel", "base_angvel", "joint_vel", "imu_acc")
MAX_LATENCY = 0.06  # s, the catalogue's upper bound of actuator_latency
MAX_LAG = 0.06      # s, of actuator_lag (its low-pass remembers LAG_MEMORY time constants of actions)
MAX_LAG_HISTORY = 32  # previous actions a row carries for the lag at most (fast control rates; an older
# action's weight goes to the oldest carried, ``acn.sim.resim``); the latency's are always carried


def carried_actions(control_dt: float) -> int:
    """How many previous actions each row carries: what the longest latency and lag reach back
    to, the lag's part at most ``MAX_LAG_HISTORY``."""
    latency = int(math.ceil(MAX_LATENCY / control_dt)) + 1
    lag = int(math.ceil((MAX_LATENCY + LAG_MEMORY * MAX_LAG) / control_dt)) + 1
    return max(latency, min(lag, MAX_LAG_HISTORY))


@dataclass
class DiagnoseConfig:
    """Every knob of ``acn-diagnose``; row counts trade time for statistical power."""

    horizons: tuple[int, ...] = (1, 5, 25)   # steps of open-loop prediction (one step: ``step_seconds``)
    step_seconds: float | None = 0.02  # s of control steps (rounded, >= 1) per diagnosis step; None: one control step
    compare_rows: int = 20_000     # held-out rows re-simulated for the one-step error table
    rollout_starts: int = 200      # held-out starts per longer horizon
    rank_rows: int = 400           # fit rows used to fit every candidate that promises an effect
    screen_rows: int = 150         # of those, the rows every candidate is fitted on first (``policy.rank``)
    rank_iterations: int = 3       # optimiser iterations per candidate when ranking (the added one gets more)
    judge_rows: int = 1_500        # held-out rows that judge a candidate
    fit_rows: int = 1_500          # fit rows for an added effect's final fit
    candidates: tuple[str, ...] = EFFECT_NAMES
    auto_max: int = 4              # at most this many effects added by --auto
    auto_seconds: float | None = 300.0  # --auto starts no new step of its search after this many s of the
    # diagnosis, and says what it left untried (``policy.adding.out_of_time``); None: no bound
    auto_alternatives: int = 1     # --auto also starts from the next this many candidates (``policy.other_starts``)
    finest: str = "joint"          # the finest granularity an added per-joint effect may get (``policy.choose_fit``)
    threads: int | None = None
    seed: int = 0

    def validate(self) -> None:
        if self.step_seconds is not None and not (math.isfinite(self.step_seconds) and self.step_seconds > 0):
            raise UserError(f"step_seconds must be a positive number of seconds (or None), got {self.step_seconds}")
        if not self.horizons or min(self.horizons) < 1:
            raise UserError("horizons must be whole numbers >= 1")
        for name in ("compare_rows", "rollout_starts", "rank_rows", "screen_rows", "judge_rows", "fit_rows"):
            if getattr(self, name) < 8:
                raise UserError(f"{name} must be >= 8")
        if self.auto_max < 1:
            raise UserError("auto_max must be >= 1")
        if self.auto_seconds is not None and not (math.isfinite(self.auto_seconds) and self.auto_seconds > 0):
            raise UserError(f"auto_seconds must be a positive number of seconds (or None), got {self.auto_seconds}")
        if self.auto_alternatives < 0:
            raise UserError("auto_alternatives must be >= 0")
        if self.finest not in GRANULARITIES:
            raise UserError(f"finest must be one of {', '.join(GRANULARITIES)}, got {self.finest!r}")

    def unit(self, control_dt: float) -> int:
        """Control steps per diagnosis step at a control period of ``control_dt`` s."""
        return 1 if self.step_seconds is None else max(1, int(math.floor(self.step_seconds / control_dt + 0.5)))


@dataclass
class Problem:
    """Measurements prepared for re-simulation (see module docstring)."""

    data: Measurements
    control: SimConfig
    backend: str
    channels: np.ndarray            # indices (into the state) of compared channels
    scale: dict[int, np.ndarray]    # horizon -> (C,) spread of the measured change
    fit_rows: np.ndarray            # rows whose transitions estimate parameters
    held_rows: np.ndarray           # rows on which errors are reported
    history: int                    # previous actions carried per row
    derived: list[str] = field(default_factory=list)
    threads: int | None = None
    seed: int = 0
    unit: int = 1                   # control steps per diagnosis step (``DiagnoseConfig.step_seconds``)
    check_horizon: int | None = None  # the open-loop check's horizon (``informative_horizon``; None: the longest)

    @property
    def channel_names(self) -> list[str]:
        return [STATE_NAMES[c] for c in self.channels]

    def group_of_channel(self) -> list[str]:
        return [next(g for g in GROUPS if n in GROUPS[g]) for n in self.channel_names]

    # ----- re-simulation -----------------------------------------------------------------
    def steps(self, horizon: int) -> int:
        """Control steps in ``horizon`` diagnosis steps."""
        return horizon * self.unit

    def actions(self, rows: np.ndarray, horizon: int = 1) -> np.ndarray:
        """(N, steps, 12) the measured actions of ``horizon`` diagnosis steps from each row."""
        return self.data.action[rows[:, None] + np.arange(self.steps(horizon))[None]]

    def predict(self, configs: SimConfig | list[SimConfig], rows: np.ndarray, horizon: int = 1,
                model_of_row: np.ndarray | None = None, corrector=None, shift: int = 0) -> np.ndarray:
        """Predicted state (N, 43) ``horizon`` diagnosis steps after measured s_t, under the measured
        actions (``corrector``, at one step: each action corrected from the measured state it follows;
        ``shift``: the actions, and those before them, of ``shift`` rows later, ``acn.diagnosis.pairing``)."""
        d = self.data
        actions = self.actions(rows + shift, horizon)
        if corrector is not None and horizon == 1:
            for i in range(self.unit):
                actions[:, i] = corrected(corrector, d.state[rows + i], actions[:, i])
        with Resimulator(self.backend, configs, threads=self.threads) as sim:
            pred = sim.run(self.starts(sim, rows, configs, model_of_row, shift), actions,
                           d.previous_actions(rows + shift, self.history), model=model_of_row)
        return pred.state[:, -1]

    @property
    def velocities_from_step(self) -> bool:
        """Whether rows start from the model's own joint velocities (``starts``): they were derived."""
        return set(GROUPS["joint_vel"]) <= set(self.derived)

    def starts(self, sim: Resimulator, rows: np.ndarray, configs: SimConfig | list[SimConfig],
               model_of_row: np.ndarray | None = None, shift: int = 0) -> np.ndarray:
        """(N, 43) the states the model starts ``rows`` from: the measured ones (``Measurements.starts``),
        where joint velocities were derived from the angles (``velocities_from_step``), with the joint
        velocities the model reaches at t from the measured state at t - 1 under the measured action
        (``sim``, one control step; a row without the step before keeps the derived ones).

        A central difference (q_{t+1} - q_{t-1}) / 2 dt holds the angle a row is compared with: with
        the acceleration switching at each control step it reads the velocity at t plus a quarter
        of the next step's change of velocity less a quarter of the last one's, so the fitted model
        must accelerate as the mean of two steps, a sluggish joint (armature 56 % high, a lag read as
        a latency). The step from t - 1 reads the angles up to t only (its central difference at
        t - 1 reaches q_t). Noise-free, under the true model, the one-step error of the angles falls
        to a third (0.00034 rad against 0.00103; ``tests/test_diagnose.py``). Shooting the velocity
        at t - 1 to reach the measured angles at t (a damped Newton step per leg, four more
        simulations) lowered it by at most 10 % more (0.00031), and not at all with less damping."""
        d = self.data
        out = d.starts(rows, self.backend, configs, model_of_row)
        if not self.velocities_from_step:
            return out
        rows = np.asarray(rows)
        ok = np.isin(rows - 1, d.windows(2))  # the row before is the step before, in the same episode
        ok[ok] &= np.isfinite(d.state[rows[ok] - 1][:, _dynamic()]).all(1)
        if not ok.any():
            return out
        prev, model = rows[ok] - 1, None if model_of_row is None else np.asarray(model_of_row)[ok]
        step = sim.run(d.starts(prev, self.backend, configs, model), d.action[prev + shift][:, None],
                       d.previous_actions(prev + shift, self.history), model=model).state[:, -1]
        jv = SLICES["joint_vel"]
        out[ok, jv] = np.where(np.isfinite(step[:, jv]), step[:, jv], out[ok, jv])
        return out

    def measured(self, rows: np.ndarray, horizon: int = 1) -> np.ndarray:
        return self.data.next_state[rows + self.steps(horizon) - 1]

    def residual(self, predicted: np.ndarray, rows: np.ndarray, horizon: int = 1) -> np.ndarray:
        """Normalised (measured - predicted) over the compared channels, (N, C); NaN if diverged."""
        d = state_difference(self.measured(rows, horizon), predicted)[:, self.channels]
        return d / self.scale[horizon]

    def residual_of(self, configs, rows: np.ndarray, horizon: int = 1, model_of_row=None, shift: int = 0) -> np.ndarray:
        return self.residual(self.predict(configs, rows, horizon, model_of_row, shift=shift), rows, horizon)

    def rollout_starts(self, horizon: int, count: int) -> np.ndarray:
        """Held-out rows that start ``horizon`` consecutive steps (at most ``count``; the same
        rows for every model, so errors at that horizon compare pairwise)."""
        return self.sample(np.intersect1d(self.held_rows, self.data.windows(self.steps(horizon))), count, salt=horizon)

    def sample(self, rows: np.ndarray, count: int, salt: int = 0) -> np.ndarray:
        """At most ``count`` of ``rows``, spread evenly over them (deterministic)."""
        if len(rows) <= count:
            return rows
        rng = np.random.default_rng([self.seed, salt])
        return np.sort(rng.choice(rows, count, replace=False))


def corrected(corrector, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """``actions`` (N, 12 or 60) corrected from ``states`` (N, 43) by a corrector of position
    targets. A hybrid command's q_des moves by the correction of its target (``position_targets``);
    its gains, velocity target and feedforward stay as sent."""
    if actions.shape[1] == ACTION_DIM:
        return corrector.correct(states, actions)
    targets = position_targets(actions, states[:, SLICES["joint_pos"]])
    out = actions.copy()
    out[:, :ACTION_DIM] += corrector.correct(states, targets) - targets
    return out


def prepare(data: Measurements, model: Model, cfg: DiagnoseConfig) -> Problem:
    """Check the measurements, derive missing velocities (and those that lag their positions,
    ``checks.distrusted``), choose channels, scales and the split."""
    cfg.validate()
    data, derived = fill_derived(data.without(checks.distrusted(data)), model.backend)
    finite = np.isfinite(data.state[:, _dynamic()]).all(1) & np.isfinite(data.next_state[:, _dynamic()]).all(1)
    if finite.sum() < 16:
        raise UserError(f"{data.description}: fewer than 16 complete transitions to compare")
    available = data.available
    channels = np.array([STATE_NAMES.index(n) for g in COMPARED_GROUPS for n in GROUPS[g]
                         if available[STATE_NAMES.index(n)] and n not in derived])
    unit = cfg.unit(data.control.control_dt)
    scale = {}
    for h in sorted(set(cfg.horizons) | {1}):
        starts = data.windows(h * unit)
        if len(starts) < 8:
            raise UserError(f"horizon {h}: fewer than 8 runs of {h * unit} consecutive control steps "
                            "in the measurements")
        change = state_difference(data.next_state[starts + h * unit - 1], data.state[starts])[:, channels]
        spread = np.nanstd(change, axis=0)
        scale[h] = np.where(spread > 1e-9, spread, 1.0)
    held = _held_out_mask(data, cfg.seed)
    ok = np.zeros(len(data), dtype=bool)  # a complete start state and a measured state one step (unit) later
    one_step = data.windows(unit)
    ok[one_step] = finite[one_step] & np.isfinite(data.next_state[one_step + unit - 1][:, channels]).all(1)
    ok &= _fresh(data, one_step, unit, derived, ok)
    history = carried_actions(data.control.control_dt)
    fit_rows, held_rows = np.flatnonzero(ok & ~held), np.flatnonzero(ok & held)
    if min(len(fit_rows), len(held_rows)) < 8:
        raise UserError(f"{data.description}: too few complete transitions to fit on some and judge on others "
                        f"({len(fit_rows)} / {len(held_rows)}); record longer or more episodes")
    return Problem(data=data, control=data.control, backend=model.backend, channels=channels, scale=scale,
                   fit_rows=fit_rows, held_rows=held_rows, history=history,
                   derived=derived, threads=cfg.threads, seed=cfg.seed, unit=unit)


def _fresh(data: Measurements, one_step: np.ndarray, unit: int, derived: list[str], ok: np.ndarray) -> np.ndarray:
    """(N,) False for steps that start or end on a repeated reading (``checks.repeated``: a
    message that did not arrive, logged again), whose transition is not the one the actions
    drove; all True where leaving them out would drop more than half of the steps (a sensor
    slower than the log repeats every other row: its finding says so)."""
    groups = [g for g in checks.SENSOR_GROUPS if not set(GROUPS[g]) & set(derived)]
    start, end = checks.repeated_transitions(data, groups)
    fresh = np.zeros(len(data), dtype=bool)
    fresh[one_step] = ~start[one_step] & ~end[one_step + unit - 1]
    return fresh if (fresh & ok).sum() >= 0.5 * ok.sum() else np.ones(len(data), dtype=bool)


def _dynamic() -> np.ndarray:
    return np.concatenate([np.arange(SLICES[g].start, SLICES[g].stop)
                           for g in ("base_pos", "base_rpy", "joint_pos", "base_linvel", "base_angvel", "joint_vel")])


def _held_out_mask(data: Measurements, seed: int) -> np.ndarray:
    """Half the episodes held out; with fewer than 4 episodes, alternate blocks of time instead
    (2 s, shorter when the episodes are: at least 4 blocks)."""
    episodes = np.unique(data.episode)
    if len(episodes) >= 4:
        rng = np.random.default_rng(seed)
        held = rng.permutation(episodes)[: len(episodes) // 2]
        return np.isin(data.episode, held)
    longest = int(np.bincount(data.episode - data.episode.min()).max())
    block = max(1, min(int(round(2.0 / data.control.control_dt)), longest // 4))
    return (data.frame // block) % 2 == 1
