"""Held-out judgement: how much better one model predicts the held-out rows than another.

The figures every rule of the selection (``policy``) reads: the share of the one-step error a
model removes, its paired z over blocks of consecutive rows (rows of one trajectory share their
errors, so they must not count twice), the share of the error above the noise floor it explains,
and the share of the open-loop error it removes at the check's horizon. Whether an improvement
is significant is the policy's to say: it hands ``judgement`` its rule.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from acn.diagnosis.compare import Comparison
from acn.diagnosis.fitting import DIVERGED_RESIDUAL
from acn.diagnosis.problem import DiagnoseConfig, Problem
from acn.sim.effects import Model

BLOCK = 10  # consecutive rows per block of the paired z (their residuals are correlated)

Significance = Callable[[float, float], bool]  # (gain: share of the reference error removed, paired z) -> significant


@dataclass
class Judgement:
    """Held-out comparison of a model with and without an effect."""

    mse_before: float
    mse_after: float
    removed: float       # share of the whole error (MSE) removed, may be < 0
    z: float             # improvement / its standard error
    significant: bool
    residual_after: np.ndarray  # (N, C) held-out residuals with the effect
    by_longest: bool = False     # significant by its longest-horizon gain, not at one step (``policy.uneven``)

    @property
    def row_errors(self) -> np.ndarray:
        """(N,) each held-out row's mean squared residual with the effect: what ``paired_z`` compares."""
        return (self.residual_after ** 2).mean(1)

    def explained(self, floor_mse: float) -> float:
        """Share 0..1 of the structured error (MSE above ``floor_mse``) removed."""
        return explained_share(self.mse_before, self.mse_after, floor_mse)


def explained_share(mse_before: float, mse_after: float, floor_mse: float) -> float:
    structured = mse_before - floor_mse
    return float(np.clip((mse_before - mse_after) / structured, 0.0, 1.0)) if structured > 0 else 0.0


def structured_share(mse: float, floor_mse: float) -> float:
    """The share of an error ``mse`` above the noise floor ``floor_mse``, 0..1 (0 where there is no error)."""
    return float(np.clip(1.0 - floor_mse / mse, 0.0, 1.0)) if mse > 0 else 0.0


def paired_z(diff: np.ndarray) -> float:
    """mean / standard error of ``diff`` over blocks of consecutive rows."""
    blocks = diff[: len(diff) // BLOCK * BLOCK].reshape(-1, BLOCK).mean(1) if len(diff) >= 2 * BLOCK else diff
    se = float(blocks.std(ddof=1) / np.sqrt(len(blocks))) if len(blocks) > 1 else np.inf
    return float(diff.mean() / se) if se > 0 else (np.inf if diff.mean() > 0 else 0.0)


def judgement(before_residual: np.ndarray, after_residual: np.ndarray, significant: Significance,
              reference_mse: float | None = None) -> Judgement:
    """The residuals ``after_residual`` (N, C) against ``before_residual`` on the same rows: rows
    whose before residual is not finite are left out, an after one that blew up counts
    ``DIVERGED_RESIDUAL``. ``significant`` judges the gain, the improvement as a share of
    ``reference_mse`` (default: the error before; a finer granularity of the same effect must
    improve on the error before the effect), at the paired z."""
    ok = np.isfinite(before_residual).all(1)
    ra = np.where(np.isfinite(after_residual), after_residual, DIVERGED_RESIDUAL)
    eb, ea = (before_residual[ok] ** 2).mean(1), (ra[ok] ** 2).mean(1)
    mse_b, mse_a = float(eb.mean()), float(ea.mean())
    z = paired_z(eb - ea)
    removed = 1.0 - mse_a / mse_b if mse_b > 0 else 0.0
    gain = (mse_b - mse_a) / (reference_mse or mse_b) if mse_b > 0 else 0.0
    return Judgement(mse_b, mse_a, removed, z, significant(gain, z), ra)


def judge(problem: Problem, after: Model, rows: np.ndarray, before_residual: np.ndarray, significant: Significance,
          reference_mse: float | None = None) -> Judgement:
    """``after`` re-simulated on ``rows`` against the residuals ``before_residual`` of the current
    model there (``judgement``)."""
    return judgement(before_residual, problem.residual_of(after.sim_config(problem.control), rows), significant,
                     reference_mse)


def open_loop_gain(before: np.ndarray, after: np.ndarray) -> float:
    """Share of the open-loop MSE of residuals ``before`` (N, C) that ``after`` removes, on the
    rows ``before`` predicted (a prediction that blew up after counts ``DIVERGED_RESIDUAL``, as in
    ``judgement``)."""
    ok = np.isfinite(before).all(1)
    mse = float(np.mean(before[ok] ** 2)) if ok.any() else 0.0
    return 1.0 - float(np.mean(np.where(np.isfinite(after[ok]), after[ok], DIVERGED_RESIDUAL) ** 2)) / mse \
        if mse > 0 else 0.0


@dataclass
class LongestHorizon:
    """The open-loop check at the longest horizon of ``cfg`` against ``model``: the same held-out
    start rows for every candidate, and ``model``'s residuals from them simulated once, on first
    use (a ranking asks for it up to three times)."""

    problem: Problem
    model: Model
    cfg: DiagnoseConfig
    _base: np.ndarray | None = field(default=None, repr=False)

    @property
    def steps(self) -> int:
        """The check's horizon (``compare.informative_horizon``; the longest before it is known)."""
        return (self.problem.check_horizon if self.problem is not None else None) or max(self.cfg.horizons)

    def gain(self, candidate: Model) -> float:
        """Share of ``model``'s open-loop error at the longest horizon that ``candidate`` removes."""
        starts = self.problem.rollout_starts(self.steps, self.cfg.rollout_starts)
        if self._base is None:
            self._base = self.problem.residual_of(self.model.sim_config(self.problem.control), starts, self.steps)
        after = self.problem.residual_of(candidate.sim_config(self.problem.control), starts, self.steps)
        return open_loop_gain(self._base, after)


def removed_at(before: Comparison, after: Comparison, h: int) -> float:
    """Share of ``before``'s open-loop error (mean square over channels) at horizon ``h`` that
    ``after`` removes."""
    b, a = (np.mean(c.channel_error[h] ** 2) for c in (before, after))
    return 1.0 - float(a / b) if b > 0 else 0.0


def longest_removed(before: Comparison, after: Comparison) -> float | None:
    """Share of ``before``'s open-loop error at the check's horizon (> 1; ``Comparison.check``) that
    ``after`` removes (None with one-step horizons only)."""
    return removed_at(before, after, before.check) if before.check > 1 else None


def improvement_between(new_errors: np.ndarray, old_errors: np.ndarray, old: Comparison, new: Comparison) -> dict:
    """How much better a model that compares as ``new`` (its held-out rows' one-step errors
    ``new_errors``, ``Judgement.row_errors``) predicts than one that compares as ``old`` (errors
    ``old_errors`` on the same rows): the share of the old one-step error it removes, its paired z
    (blocks of rows), the share of the old open-loop error at the longest horizon it removes, and
    at each open-loop horizon compared (``horizons_removed``: steps -> share)."""
    horizons = {h: removed_at(old, new, h) for h in sorted(old.channel_error) if h > 1}
    return {"one_step_removed": 1.0 - float(new_errors.mean() / old_errors.mean()) if old_errors.mean() > 0 else 0.0,
            "z": paired_z(old_errors - new_errors), "longest_horizon_removed": longest_removed(old, new),
            "horizons_removed": horizons}
