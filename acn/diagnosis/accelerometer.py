"""Does the logged accelerometer read the mean over the control step, or one instant?

The schema's ``imu_acc`` is the trunk's MEAN specific force over the control step before the row
(what ``acn-collect`` writes: ``SimConfig.imu_acc`` "mean"). A sensor read at the row's INSTANT
reads the last moment instead: MuJoCo's ``accelerometer`` sensor (the last physics step), an IMU
the control loop samples without averaging over the period. While a foot lands the two differ by
several m/s^2 (12 m/s^2 for a 3 cm drop, ``tests/test_backends.py``), so a model compared with
the wrong reading leaves a structured accelerometer error that no physical effect explains
(a noise-free log written with MuJoCo's sensor comes out ``unexplained`` under the true model
when read as the mean, ``imu_acc`` 25 times the median group's error).

``read_accelerometer`` first asks the log itself, without a model (``integration``): the trunk's
world velocity changes over a control step by dt x the mean reading exactly, and by about the
trapezoid of the step's two instant readings. So per row and world axis,

    v_(t+1) - v_t - dt a_(t+1)  =  gamma  dt (a_t - a_(t+1)) / 2  +  noise     (a: R imu_acc - g)

has gamma = 0 for a mean reading and about 1 for an instant one (less where a landing foot acts
between two samples). It is fitted by a Huber regression with a Newey-West standard error over
consecutive rows, against:

- the LOGGED velocity where it is measured (motion capture, or the robot's own estimate). It
  decides where gamma lies ``INTEGRATION_Z`` standard errors or more from 1/2. Measured on the
  logs of ``benchmarks/diagnose_cases.py`` (the 15 of the first set at typical noise and the 11
  of ``--other`` at twice typical, 4 x 10 s, each written with the mean and with MuJoCo's
  sensor): -0.11 to 0.15 for the mean reading, 0.79 to 1.12 for the sensor, all 52 decided
  right (|z| 4.5 to 35). A velocity the robot's estimator integrated from this accelerometer
  integrates it as that estimator does, not as the sensor reads; so where the legs' velocity
  (below) clearly says otherwise, the model judges instead and the report says why;
- else the LEGS' per-sample velocity (``Odometry.estimate``: stance feet at rest; the
  accelerometer is not in it, unlike the fused odometry, which assumes a reading). It is biased
  where feet land, sink and slip, mostly towards the mean reading: on the same logs without
  motion capture -0.46 to 0.39 for the mean reading and 0.38 to 1.16 for the sensor, and 0.39 +-
  0.02 on a 2 x 10 s pace log with the sensor. So from the legs only a clear "instant"
  decides: 22 of the 26 sensor logs (undecided: armature, armature 0.01, soft ground, pace);
  the rest goes to the model.

Where the integration does not decide (a log without a usable velocity, a 200 Hz log whose two
readings differ by less than the noise), the model decides: it re-simulates its one step from
the judging rows with both readings and keeps "instant" where that at least halves the
accelerometer's mean squared error (``INSTANT_SHARE``) and predicts it better in clearly more
rows than not (a sign test, ``INSTANT_Z``); otherwise the schema's mean, also where sensor noise
hides the difference (then either reading predicts as well). Row by row, not by a paired z of
the errors: the difference sits in the rows where a foot lands, and a gait with few landings (a
pace that tips over) had the instant reading's error at 0.7 % of the mean one's with a paired z
of 3.2. This judgement is only as good as the model and the start states: an instant reading
shifts the mean one by about half a step, as a phase error of the model does (a mean log with
kp x 0.7 had the instant reading better in 67 % of the rows, 76 % of the error), and a start
state with sensor noise or estimated by odometry spoils the instant prediction most (a pace log
with MuJoCo's sensor, typical noise, no motion capture: 42 % of the rows, 136 % of the error).
On a log of MuJoCo Menagerie's A1 (joint damping 1-2, friction 0.2, armature 0.01, no
derivative gain; noise-free) with the MEAN reading, the nominal model read the instant one better
in 60 % of the rows (73 % of the error); with the effects ``--auto`` added, in 0.7 % (45 times
the error). So where the model judged, the diagnosis judges again under its final model when it
added effects, and runs again with the other reading where the two judgements differ
(``pipeline.diagnose``). A dataset that states its reading (``acn-import --imu-acc``,
``acn-collect``) is taken at its word.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from acn.measurements.odometry import Odometry, world_acceleration
from acn.diagnosis.problem import Problem
from acn.sim.backends import IMU_ACC_KINDS
from acn.sim.effects import Model
from acn.sim.rotations import rpy_to_matrices
from acn.sim.state import GROUPS, SLICES

INSTANT_SHARE = 0.5  # the instant reading must leave at most this share of the mean one's accelerometer MSE ...
INSTANT_Z = 5.0      # ... and be better in this many binomial standard errors more than half the rows
INTEGRATION_Z = 4.0  # the integration decides where its gamma lies this many standard errors from 1/2
INTEGRATION_ROWS = 5_000  # at most this many rows integrated (a random sample of a longer log)


@dataclass
class Accelerometer:
    """How the diagnosis reads the logged accelerometer."""

    kind: str                     # "mean" (over the control step) or "instant" (``SimConfig.imu_acc``)
    stated: bool                  # the dataset says so; else judged here
    share: float | None = None    # judged: the instant reading's accelerometer MSE / the mean one's
    better: float | None = None   # judged: share of the rows whose accelerometer the instant reading predicts better
    again: bool = False           # judged again under the model with the effects added (``pipeline.diagnose``)
    integration: "Integration | None" = None  # judged: the model-free test (decided where ``decides``)

    @property
    def by_model(self) -> bool:
        """Judged by re-simulating the model (the integration did not decide)."""
        return not self.stated and not (self.integration and self.integration.decides)

    def describe(self) -> str:
        """One line for the report ("" where it is the schema's mean)."""
        if self.stated:
            return "" if self.kind == "mean" else \
                "the accelerometer is read at each row's instant (as the dataset states)"
        if not self.by_model:
            i = self.integration
            return "" if self.kind == "mean" else \
                (f"the accelerometer reads like a sensor sampled at each row's instant, not the mean over the "
                 f"control step (integrated against the {i.velocity} velocity, it gives the velocity's change "
                 f"by the trapezoid of two instants: gamma {i.gamma:.2f} +- {i.stderr:.2f}, 0 for the mean, 1 for "
                 f"instants): compared so; acn-import --imu-acc instant states it")
        model = "the model with the effects added" if self.again else "the model"
        i, line = self.integration, ""
        if self.kind == "instant":
            line = (f"the accelerometer reads like a sensor sampled at each row's instant, not the mean over the "
                    f"control step (read so, {model} predicts it better in {self.better:.0%} of the rows, with "
                    f"{self.share:.0%} of the mean squared error): compared so; acn-import --imu-acc instant states it")
        elif self.again:
            line = (f"the accelerometer reads as the mean over the control step (the schema's) under the model with "
                    f"the effects added (read at each instant, {self.better:.0%} of the rows predicted better, "
                    f"{self.share:.0%} of the mean squared error): compared so; acn-import --imu-acc mean states it")
        if i is not None and i.velocity == "logged" and i.clear and not i.decides:  # it and the legs' disagree
            doubt = (f"the logged trunk velocity integrates the accelerometer as {i.kind} readings would (gamma "
                     f"{i.gamma:.2f} +- {i.stderr:.2f}), the legs' as {i.legs.kind} ones ({i.legs.gamma:.2f} +- "
                     f"{i.legs.stderr:.2f}): is the logged velocity estimated from this accelerometer? The model "
                     f"judged the reading ({self.kind})")
            line = f"{doubt}; {line}" if line else doubt
        return line

    def to_json(self) -> dict:
        i = self.integration
        return {"kind": self.kind, "stated": self.stated, "instant_share": self.share, "instant_better": self.better,
                "judged_again": self.again,
                "integration": None if i is None else i.to_json()}


@dataclass
class Integration:
    """The model-free test (module docstring): gamma 0 for a mean reading, about 1 for instants."""

    gamma: float
    stderr: float
    velocity: str    # "logged" or "legs'" (estimated)
    rows: int
    legs: "Integration | None" = None  # with a logged velocity: the same test against the legs'

    @property
    def clear(self) -> bool:
        """gamma lies ``INTEGRATION_Z`` standard errors or more from 1/2."""
        return bool(np.isfinite(self.gamma) and abs(self.gamma - 0.5) >= INTEGRATION_Z * self.stderr)

    @property
    def decides(self) -> bool:
        """Clear; from the legs' velocity only for "instant" (its bias leans towards the mean);
        from a logged one where the legs' does not decide otherwise."""
        if self.velocity != "logged":
            return self.clear and self.kind == "instant"
        return self.clear and not (self.legs is not None and self.legs.decides and self.legs.kind != self.kind)

    @property
    def kind(self) -> str:
        return "instant" if self.gamma > 0.5 else "mean"

    def to_json(self) -> dict:
        return {"gamma": self.gamma, "stderr": self.stderr, "velocity": self.velocity, "rows": self.rows,
                "decides": self.decides, "legs": None if self.legs is None else self.legs.to_json()}


def integration(problem: Problem, seed: int = 0) -> Integration | None:
    """The integration test (module docstring) on ``problem``'s rows, against the logged trunk
    velocity where it is measured, checked against the legs' (else the legs' alone); None where
    neither can be had."""
    data = problem.data
    rows = np.arange(len(data))
    if len(rows) > INTEGRATION_ROWS:
        rows = np.sort(np.random.default_rng(seed).choice(rows, INTEGRATION_ROWS, replace=False))
    state, after = data.state[rows], data.next_state[rows]
    dt = problem.control.control_dt
    legs = None
    needed = np.r_[SLICES["base_rpy"], SLICES["joint_pos"], SLICES["joint_vel"], SLICES["base_angvel"]]
    fine = np.isfinite(state[:, needed]).all(1) & np.isfinite(after[:, needed]).all(1)
    if fine.sum() >= 8:
        odometry = Odometry()  # stance feet at rest: the accelerometer is not in it
        legs = fit_gamma(odometry.estimate(state[fine])[1], odometry.estimate(after[fine])[1],
                         state[fine], after[fine], rows[fine], dt, "legs'")
    if set(GROUPS["base_linvel"]) & (set(problem.derived) | set(data.missing)):
        return legs
    logged = fit_gamma(state[:, SLICES["base_linvel"]], after[:, SLICES["base_linvel"]], state, after, rows, dt,
                       "logged")
    if logged is None:
        return legs
    return replace(logged, legs=legs)


def fit_gamma(velocity: np.ndarray, next_velocity: np.ndarray, state: np.ndarray, after: np.ndarray,
              rows: np.ndarray, dt: float, source: str) -> Integration | None:
    """gamma of the rows ``rows`` (their states and next states, trunk-frame velocities at each,
    m/s) by a Huber regression with a Newey-West standard error; None without 8 usable rows."""
    def world(s: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        rot = rpy_to_matrices(s[:, SLICES["base_rpy"]])
        return np.einsum("nij,nj->ni", rot, v), world_acceleration(s[:, SLICES["imu_acc"]], rot)

    (v0, a0), (v1, a1) = world(state, velocity), world(after, next_velocity)
    y, h = v1 - v0 - dt * a1, 0.5 * dt * (a0 - a1)    # (R, 3) each
    ok = np.isfinite(y).all(1) & np.isfinite(h).all(1)
    y, h, rows = y[ok], h[ok], rows[ok]
    if len(y) < 8 or not np.any(h):
        return None
    w = np.ones_like(y)
    for _ in range(20):  # Huber IRLS, 1.5 robust standard deviations
        gamma = float(np.sum(w * h * y) / np.sum(w * h * h))
        e = y - gamma * h
        scale = 1.4826 * np.median(np.abs(e)) + 1e-12
        w = np.minimum(1.0, 1.5 * scale / np.maximum(np.abs(e), 1e-12))
    # Newey-West (Bartlett, 4 lags) over consecutive rows: a velocity ends one row and starts the next
    score = np.sum(w * e * h, axis=1)
    var = float(np.sum(score * score))
    for lag in range(1, 5):
        near = rows[lag:] == rows[:-lag] + lag
        var += 2.0 * (1.0 - lag / 5.0) * float(np.sum(score[lag:][near] * score[:-lag][near]))
    stderr = float(np.sqrt(max(var, 0.0)) / np.sum(w * h * h))
    return Integration(gamma, stderr, source, int(len(y)))


def read_accelerometer(problem: Problem, model: Model, rows: np.ndarray) -> Accelerometer:
    """How to read ``problem``'s accelerometer (module docstring): as the dataset states, else as
    the integration decides, else as ``model`` re-simulated from ``rows`` predicts it best."""
    stated = problem.data.info.imu_acc
    if stated in IMU_ACC_KINDS:
        return Accelerometer(stated, stated=True)
    columns = np.flatnonzero(np.array(problem.group_of_channel()) == "imu_acc")
    if not len(columns) or len(rows) < 8 or problem.control.substeps < 2:
        return Accelerometer("mean", stated=False)  # not compared, or one physics step per control step: the same
    test = integration(problem, seed=problem.seed)
    if test is not None and test.decides:
        return Accelerometer(test.kind, stated=False, integration=test)
    return replace(predicted_better(problem, model, rows), integration=test)


def predicted_better(problem: Problem, model: Model, rows: np.ndarray) -> Accelerometer:
    """The reading ``model``, re-simulated one step from ``rows`` with each, predicts clearly
    better ("instant" at ``INSTANT_SHARE`` and ``INSTANT_Z``), else the schema's mean."""
    columns = np.flatnonzero(np.array(problem.group_of_channel()) == "imu_acc")
    config = model.sim_config(problem.control)
    err = {}
    for kind in IMU_ACC_KINDS:
        with np.errstate(over="ignore", invalid="ignore"):
            r = problem.residual_of(replace(config, imu_acc=kind), rows)[:, columns]
        err[kind] = np.mean(r ** 2, axis=1)
    fine = np.isfinite(err["mean"]) & np.isfinite(err["instant"])
    if fine.sum() < 8 or err["mean"][fine].mean() <= 0:
        return Accelerometer("mean", stated=False)
    share = float(err["instant"][fine].mean() / err["mean"][fine].mean())
    better = float(np.mean(err["instant"][fine] < err["mean"][fine]))
    clear = share <= INSTANT_SHARE and better >= 0.5 + INSTANT_Z * 0.5 / np.sqrt(fine.sum())
    return Accelerometer("instant" if clear else "mean", stated=False, share=share, better=better)
