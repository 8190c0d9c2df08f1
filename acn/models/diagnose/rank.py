"""Which effect is missing: fit every candidate, judge each on held-out rows.

For every catalogue effect: fit its parameters (``fitting``) on a sample of fit rows, at its
default granularity, added to the current model; then re-simulate held-out "judge" rows with
and without it. A candidate's evidence:

- ``explained``: the share of the STRUCTURED error (error minus the noise floor) it removes,
  0..1, on held-out rows;
- ``significant``: the held-out improvement is larger than 3 standard errors of its
  row-to-row variation (blocks of consecutive rows, so correlated rows do not count twice) and
  at least 2 % of the error;
- ``score``: the share of the whole held-out error it removes, minus a small price per fitted
  parameter (ties go to the simpler effect); it orders candidates as ``explained`` does, and
  still orders them when the error is all noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acn.models.diagnose.fitting import EffectFit, default_granularity, fit_effect
from acn.models.diagnose.problem import DiagnoseConfig, Problem
from acn.toolkit.effects import Model, get_effect

PRICE_PER_PARAMETER = 0.003  # explained share a parameter has to earn
SIGNIFICANCE_Z = 3.0
MIN_IMPROVEMENT = 0.02       # of the current error (MSE)
BLOCK = 10                   # rows per block in the significance test


@dataclass
class Judgement:
    """Held-out comparison of a model with and without an effect."""

    mse_before: float
    mse_after: float
    explained: float     # of the structured error, 0..1
    removed: float       # of the whole error (MSE), may be < 0
    z: float             # improvement / its standard error
    significant: bool


@dataclass
class Candidate:
    fit: EffectFit
    judgement: Judgement
    score: float

    @property
    def name(self) -> str:
        return self.fit.effect.name


def judge(problem: Problem, before: Model, after: Model, rows: np.ndarray, floor_mse: float,
          before_residual: np.ndarray | None = None) -> Judgement:
    """Compare ``before`` and ``after`` on ``rows`` (see module docstring)."""
    rb = before_residual if before_residual is not None else problem.residual_of(before.sim_config(problem.control), rows)
    ra = problem.residual_of(after.sim_config(problem.control), rows)
    ok = np.isfinite(rb).all(1)
    ra = np.where(np.isfinite(ra), ra, 10.0)
    eb, ea = (rb[ok] ** 2).mean(1), (ra[ok] ** 2).mean(1)
    mse_b, mse_a = float(eb.mean()), float(ea.mean())
    diff = eb - ea
    blocks = diff[: len(diff) // BLOCK * BLOCK].reshape(-1, BLOCK).mean(1) if len(diff) >= 2 * BLOCK else diff
    se = float(blocks.std(ddof=1) / np.sqrt(len(blocks))) if len(blocks) > 1 else np.inf
    z = float(diff.mean() / se) if se > 0 else (np.inf if diff.mean() > 0 else 0.0)
    structured = mse_b - floor_mse
    explained = float(np.clip((mse_b - mse_a) / structured, 0.0, 1.0)) if structured > 0 else 0.0
    removed = 1.0 - mse_a / mse_b if mse_b > 0 else 0.0
    return Judgement(mse_b, mse_a, explained, removed, z,
                     bool(z >= SIGNIFICANCE_Z and (mse_b - mse_a) >= MIN_IMPROVEMENT * mse_b))


def rank(problem: Problem, model: Model, cfg: DiagnoseConfig, floor_mse: float, progress=None) -> list[Candidate]:
    """Every candidate effect fitted and judged against ``model``; best first."""
    fit_rows = problem.sample(problem.fit_rows, cfg.rank_rows, salt=3)
    judge_rows = problem.sample(problem.held_rows, cfg.judge_rows, salt=4)
    base_residual = problem.residual_of(model.sim_config(problem.control), judge_rows)
    out = []
    for i, name in enumerate(cfg.candidates):
        if progress:
            progress(f"fitting {name}", i / len(cfg.candidates))
        effect = get_effect(name)
        fit = fit_effect(problem, model, effect, default_granularity(effect), fit_rows, max_iter=cfg.rank_iterations)
        j = judge(problem, model, fit.model, judge_rows, floor_mse, base_residual)
        out.append(Candidate(fit, j, j.removed - PRICE_PER_PARAMETER * len(fit.x)))
    out.sort(key=lambda c: (-c.score, len(c.fit.x)))
    return out
