"""Compare a model with measurements: teacher-forced one-step and open-loop k-step errors.

One step: set the model to each measured state (with the actions that preceded it), apply the
measured action, compare with the next measured state. k steps: from a measured state, apply
the k measured actions open loop, compare with the measured state k steps later. Always the
recorded actions of whatever controller produced the data, never a built-in policy.

Errors are normalised RMS on held-out rows (``problem`` module): per channel, per channel group
and one headline number, the one-step RMS over every compared channel.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acn.diagnosis.noise import noise_floor
from acn.diagnosis.problem import DiagnoseConfig, Problem
from acn.sim.effects import Model
from acn.sim.state import GROUPS


@dataclass
class Comparison:
    """How far a model's predictions are from the measurements (held-out rows)."""

    model: Model
    error: dict[int, dict[str, float]]        # horizon -> channel group -> normalised RMS
    channel_error: dict[int, np.ndarray]      # horizon -> (C,) normalised RMS per channel
    rows: np.ndarray                          # the one-step rows compared
    residual: np.ndarray                      # (N, C) normalised one-step residuals on those rows
    predicted: np.ndarray                     # (N, 43) one-step predictions on those rows
    diverged: int                             # rows whose re-simulation blew up (left out)
    check_horizon: int | None = None          # the open-loop check's (``informative_horizon``; None: the longest)

    @property
    def check(self) -> int:
        """The horizon of the open-loop check."""
        return self.check_horizon or max(self.channel_error)

    @property
    def headline(self) -> float:
        """One-step normalised RMS over all compared channels (the documented headline error)."""
        return float(np.sqrt(np.mean(self.residual ** 2)))


def group_errors(problem: Problem, residual: np.ndarray) -> dict[str, float]:
    groups = np.array(problem.group_of_channel())
    return {g: float(np.sqrt(np.mean(residual[:, groups == g] ** 2))) for g in GROUPS if (groups == g).any()}


def compare(problem: Problem, model: Model, cfg: DiagnoseConfig) -> Comparison:
    """Errors of ``model`` at every horizon of ``cfg`` (see module docstring)."""
    sim = model.sim_config(problem.control)
    corrector = _corrector(model)
    rows = problem.sample(problem.held_rows, cfg.compare_rows, salt=1)
    predicted = problem.predict(sim, rows, 1, corrector=corrector)
    residual = problem.residual(predicted, rows)
    ok = np.isfinite(residual).all(1)
    error = {1: group_errors(problem, residual[ok])}
    channel_error = {1: np.sqrt(np.mean(residual[ok] ** 2, axis=0))}
    for h in cfg.horizons:
        if h == 1:
            continue
        r = problem.residual_of(sim, problem.rollout_starts(h, cfg.rollout_starts), h)
        r = r[np.isfinite(r).all(1)]
        error[h] = group_errors(problem, r)
        channel_error[h] = np.sqrt(np.mean(r ** 2, axis=0))
    return Comparison(model, error, channel_error, rows[ok], residual[ok], predicted[ok], int((~ok).sum()),
                      problem.check_horizon)


def informative_horizon(c: Comparison) -> int:
    """The open-loop check's horizon: the longest of ``c``'s horizons at which the model as given
    predicts better than "nothing moves" (normalised RMS over every channel below 1), else the
    shortest above one step. Past it the replay has diverged and an effect's gain there measures
    the divergence, not the physics: a robot logged in torque control is replayed without
    feedback, and at 200 Hz its 25-step (0.5 s) error is 3.4-6.5 even for the right model, where
    position-controlled logs stay at 0.11-0.67 (their replayed PD holds the joints)."""
    longer = sorted(h for h in c.channel_error if h > 1)
    if not longer:
        return 1
    within = [h for h in longer if float(np.sqrt(np.mean(c.channel_error[h] ** 2))) < 1.0]
    return max(within) if within else longer[0]


def floor_of(problem: Problem, model: Model, rows: np.ndarray, residual: np.ndarray, fit_rows: int = 3000) -> np.ndarray:
    """(C,) noise-floor MSE per channel: what the ``noise`` regressions leave of ``model``'s
    residuals ``residual`` on ``rows``, learned from its residuals on a sample of fit rows."""
    fit = problem.sample(problem.fit_rows, fit_rows, salt=2)
    r_fit = problem.residual_of(model.sim_config(problem.control), fit)
    ok = np.isfinite(r_fit).all(1)
    keep = np.isfinite(residual).all(1)
    return noise_floor(problem.data, problem.channel_names, fit[ok], r_fit[ok], rows[keep], residual[keep],
                       problem.unit)


def _corrector(model: Model):
    if not model.corrector:
        return None
    from acn.corrector.corrector import Corrector

    return Corrector.load(model.corrector)
