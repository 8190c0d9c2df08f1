"""Whether an explanation holds where the log can check it: every added effect fitted again on
two disjoint halves of the episodes, its values compared.

A missing physical effect is one set of values the whole log shares; effects that paper over
structure the catalogue lacks (a wrong link mass, a spring, a wrong geometry) fit whatever the
states visited ask of them, which moves with the data they are fitted on. Each added effect is
fitted again, the others held at their values, on the rows of each half (all rows, fit and
held-out; episodes alternate between the halves, or with one episode its first and second half
of time), from its values, and the two fits are compared parameter by parameter:
chi^2 = sum (a - b)^2 / (se_a^2 + se_b^2 + resolution^2), with ``resolution`` the optimiser's
(``RESOLUTION`` of each parameter's typical magnitude: noise-free logs leave standard errors
smaller than where a fit stops). ``policy.does_not_hold`` judges it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acn.diagnosis.fitting import FINAL_ITER, FreeParameters, fit_effect, granularity_of
from acn.diagnosis.problem import DiagnoseConfig, Problem
from acn.sim.effects import Model

RESOLUTION = 0.01  # of a parameter's typical magnitude: where two fits of the same data stop apart


@dataclass(frozen=True)
class HalfFits:
    """One added effect fitted on each half of the episodes."""

    name: str
    names: tuple[str, ...]   # its free parameters
    first: np.ndarray        # values fitted on the first half
    second: np.ndarray       # on the second
    stderr_first: np.ndarray
    stderr_second: np.ndarray
    chi2: float              # of the differences, with ``len(names)`` degrees of freedom

    def worst(self) -> str:
        """The parameter whose halves differ most, in words."""
        spread = np.sqrt(self.stderr_first ** 2 + self.stderr_second ** 2)
        i = int(np.argmax(np.abs(self.first - self.second) / np.maximum(spread, 1e-12)))
        return (f"{self.name}.{self.names[i]} {self.first[i]:.4g} +- {self.stderr_first[i]:.2g} on one half, "
                f"{self.second[i]:.4g} +- {self.stderr_second[i]:.2g} on the other")

    def to_json(self) -> dict:
        return {"effect": self.name, "parameters": list(self.names), "first": self.first.tolist(),
                "second": self.second.tolist(), "stderr_first": self.stderr_first.tolist(),
                "stderr_second": self.stderr_second.tolist(), "chi2": self.chi2}


def halves(problem: Problem) -> tuple[np.ndarray, np.ndarray]:
    """Two disjoint sets of rows (fit and held-out alike): alternate episodes, or with one episode
    the first and second half of each episode's steps."""
    d = problem.data
    rows = np.sort(np.concatenate([problem.fit_rows, problem.held_rows]))
    episodes = np.unique(d.episode[rows])
    if len(episodes) >= 2:
        first = np.isin(d.episode[rows], episodes[::2])
    else:
        first = d.frame[rows] < np.median(d.frame[rows])
    return rows[first], rows[~first]


def fit_halves(problem: Problem, model: Model, added: list[str], cfg: DiagnoseConfig) -> list[HalfFits]:
    """Each of the ``added`` effects of ``model`` fitted again on each half (``halves``; at most
    ``cfg.rank_rows`` rows of each), the other effects at their values."""
    parts = [problem.sample(h, cfg.rank_rows, salt=7 + i) for i, h in enumerate(halves(problem))]
    out = []
    for name in added:
        applied = next(t for t in model.effects if t.name == name)
        granularity = granularity_of(applied.effect, applied.values)
        fits = [fit_effect(problem, model, applied.effect, granularity, rows, start=applied.values,
                           max_iter=FINAL_ITER, scan=False) for rows in parts]
        own = len(FreeParameters(applied.effect, granularity, applied.values).names)
        a, b = (f.x[:own] for f in fits)
        sa, sb = (f.stderr[:own] for f in fits)
        resolution = RESOLUTION * FreeParameters(applied.effect, granularity, applied.values).scale()
        chi2 = float(np.sum((a - b) ** 2 / (sa ** 2 + sb ** 2 + resolution ** 2)))
        out.append(HalfFits(name, tuple(fits[0].names[:own]), a, b, sa, sb, chi2))
    return out


def chi2_quantile(dof: int, z: float) -> float:
    """The chi^2 quantile with ``dof`` degrees of freedom at the normal quantile ``z`` (Wilson-Hilferty)."""
    k = 2.0 / (9.0 * dof)
    return float(dof * (1.0 - k + z * np.sqrt(k)) ** 3)
