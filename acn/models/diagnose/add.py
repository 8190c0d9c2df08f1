"""Add an effect to the model and watch the error fall.

``add_effect`` fits the effect at the granularity the data support (shared by all joints, per
joint type, per leg, per joint: a finer one must beat the coarser one significantly on
held-out rows), refits on more rows, and compares the model before and after at every
horizon. ``auto`` repeats rank -> add while the best candidate's held-out improvement is
larger than the noise (significant, ``rank.judge``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acn.models.diagnose.compare import Comparison, compare
from acn.models.diagnose.fitting import EffectFit, default_granularity, fit_effect
from acn.models.diagnose.problem import DiagnoseConfig, Problem
from acn.models.diagnose.rank import Candidate, Judgement, judge, rank
from acn.toolkit.effects import Model, get_effect

AUTO_MIN_EXPLAINED = 0.05  # --auto stops when the best candidate explains less of what is left


@dataclass
class Added:
    """One effect added to the model: the fit and the error before and after."""

    fit: EffectFit
    judgement: Judgement
    before: Comparison
    after: Comparison

    @property
    def name(self) -> str:
        return self.fit.effect.name


def _granularities(effect) -> list[str]:
    if not effect.per_joint:
        return ["shared"]
    if default_granularity(effect) == "joint":
        return ["joint"]
    return ["shared", "type", "leg", "joint"]


def choose_fit(problem: Problem, model: Model, name: str, cfg: DiagnoseConfig, floor_mse: float,
               start: EffectFit | None = None) -> tuple[EffectFit, Judgement]:
    """The effect fitted at the coarsest granularity no finer one significantly beats."""
    effect = get_effect(name)
    rows = problem.sample(problem.fit_rows, cfg.rank_rows, salt=3)
    judge_rows = problem.sample(problem.held_rows, cfg.judge_rows, salt=4)
    best: tuple[EffectFit, Judgement] | None = None
    for g in _granularities(effect):
        if best is not None and g == "joint" and best[0].granularity == "shared":
            break  # neither joint types nor legs differ: no reason to try 12 values
        seed = start.values if start is not None and start.granularity == g else (best[0].values if best else None)
        fit = fit_effect(problem, model, effect, g, rows, start=seed)
        if best is None:
            best = (fit, judge(problem, model, fit.model, judge_rows, floor_mse))
            continue
        finer = judge(problem, best[0].model, fit.model, judge_rows, floor_mse)
        if finer.significant:
            best = (fit, judge(problem, model, fit.model, judge_rows, floor_mse))
    fit = best[0]
    more = problem.sample(problem.fit_rows, cfg.fit_rows, salt=5)
    if len(more) > len(rows):  # refine on more rows, starting from the chosen values
        fit = fit_effect(problem, model, effect, fit.granularity, more, start=fit.values, max_iter=6)
    return fit, judge(problem, model, fit.model, judge_rows, floor_mse)


def add_effect(problem: Problem, model: Model, name: str, cfg: DiagnoseConfig, floor_mse: float,
               before: Comparison, start: EffectFit | None = None) -> Added:
    fit, judgement = choose_fit(problem, model, name, cfg, floor_mse, start)
    return Added(fit, judgement, before, compare(problem, fit.model, cfg))


def auto(problem: Problem, model: Model, cfg: DiagnoseConfig, floor_mse: float, first: Comparison,
         ranking: list[Candidate], progress=None) -> list[Added]:
    """Greedy rank -> add while the best candidate removes more than the noise."""
    added: list[Added] = []
    current = first
    while len(added) < cfg.auto_max:
        best = next((c for c in ranking if c.name not in {a.name for a in added}), None)
        if best is None or not best.judgement.significant or best.judgement.explained < AUTO_MIN_EXPLAINED:
            break
        if progress:
            progress(f"adding {best.name}", None)
        step = add_effect(problem, current.model, best.name, cfg, floor_mse, current, start=best.fit)
        if not step.judgement.significant:
            break
        added.append(step)
        current = step.after
        if len(added) < cfg.auto_max:
            ranking = rank(problem, current.model, cfg, floor_mse, progress)
    return added


def explained_share(mse_before: float, mse_after: float, floor_mse: float) -> float:
    structured = mse_before - floor_mse
    return float(np.clip((mse_before - mse_after) / structured, 0.0, 1.0)) if structured > 0 else 0.0
