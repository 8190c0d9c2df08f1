"""The diagnosis as one pipeline: compare -> where -> rank -> add -> verdict.

Each stage is a function of the previous stage's result (``compare``, ``where``, ``rank``,
``add``); ``diagnose`` runs them in order and returns a ``Diagnosis`` that the CLI, the JSON
file, the HTML report and ``acn-view`` all read.

Verdict:
- ``none``: the model matches within the noise (the error is all noise floor, or zero), and no
  candidate improves held-out predictions significantly;
- ``effect``: the best candidate (or, with ``--auto``, the effects added one after the other)
  significantly removes at least half of the structured error (error above the noise floor);
- ``unexplained``: there is structured error, and no candidate explains half of it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from acn.datasets.measurements import Measurements
from acn.models.diagnose.add import Added, add_effect, auto, explained_share
from acn.models.diagnose.compare import Comparison, compare, floor_of
from acn.models.diagnose.problem import DiagnoseConfig, Problem, prepare
from acn.models.diagnose.rank import Candidate, rank
from acn.models.diagnose.where import breakdown
from acn.toolkit.effects import Model, get_effect

EXACT = 1e-3                   # headline error below which a model reproduces the data (float32 storage: ~1e-6)
EFFECT_SHARE = 0.5            # of the structured error an effect must explain to be named
STRUCTURED_SHARE = 0.15       # of the error that must be structured before anything is missing


@dataclass
class Diagnosis:
    measurements: str
    problem: Problem
    before: Comparison
    floor: np.ndarray            # (C,) noise-floor MSE per compared channel
    where: dict
    ranking: list[Candidate]
    added: list[Added]
    verdict: str
    reason: str
    seconds: dict = field(default_factory=dict)

    @property
    def floor_mse(self) -> float:
        return float(np.mean(self.floor))

    @property
    def final(self) -> Comparison:
        return self.added[-1].after if self.added else self.before

    @property
    def structured_share(self) -> float:
        mse = self.before.headline ** 2
        return float(np.clip(1.0 - self.floor_mse / mse, 0.0, 1.0)) if mse > 0 else 0.0


def verdict(before: Comparison, floor_mse: float, ranking: list[Candidate], added: list[Added],
            automatic: bool) -> tuple[str, str]:
    """(verdict, reason in words); see module docstring."""
    mse = before.headline ** 2
    if before.headline < EXACT:
        return "none", f"the model reproduces the measurements (headline error {before.headline:.2g})"
    structured = 1.0 - floor_mse / mse
    top = ranking[0] if ranking else None
    if automatic and added:
        share = explained_share(mse, added[-1].after.headline ** 2, floor_mse)
        names = " + ".join(a.name for a in added)
        if share >= EFFECT_SHARE:
            return "effect", f"{names} explain {share:.0%} of the error above the noise floor"
    if top is not None and top.judgement.significant and top.judgement.explained >= EFFECT_SHARE:
        return "effect", (f"{top.name} explains {top.judgement.explained:.0%} of the error above the noise floor "
                          f"(held-out improvement {top.judgement.z:.1f} standard errors)")
    if structured >= STRUCTURED_SHARE:
        best = (f"; the best candidate, {top.name}, explains {top.judgement.explained:.0%}" if top else "")
        return "unexplained", f"{structured:.0%} of the error is structured (above the noise floor){best}"
    return "none", (f"the error is within the noise (only {max(structured, 0):.0%} of it is predictable from the "
                    "state and actions) and no candidate improves held-out predictions significantly")


def _lower_floor(floor: np.ndarray, before: Comparison, ranking: list[Candidate]) -> np.ndarray:
    """The learned floor, lowered to the held-out error the best candidate reached: what a
    fitted effect removes is structured error, whatever the networks missed. The candidates'
    explained shares are restated against the final floor."""
    if not ranking:
        return floor
    best = min(c.judgement.mse_after / c.judgement.mse_before for c in ranking if c.judgement.mse_before > 0)
    mse = before.headline ** 2
    target = min(float(np.mean(floor)), best * mse)
    lowered = floor * (target / float(np.mean(floor))) if np.mean(floor) > 0 else floor
    for c in ranking:
        j = c.judgement
        j.explained = explained_share(j.mse_before, j.mse_after, target * j.mse_before / mse)
    return lowered


def diagnose(data: Measurements, model: Model, cfg: DiagnoseConfig | None = None, add: list[str] = (),
             automatic: bool = False, progress=None) -> Diagnosis:
    """Run the whole diagnosis (module docstring); ``add``: effects to add in this order."""
    cfg = cfg or DiagnoseConfig()
    for name in add:
        get_effect(name)  # unknown names fail before any work
    say = progress or (lambda msg, fraction=None: None)
    t0 = time.perf_counter()
    problem = prepare(data, model, cfg)
    say("comparing the model with the measurements")
    before = compare(problem, model, cfg)
    floor = floor_of(problem, before)
    t1 = time.perf_counter()
    where = breakdown(problem, before)
    say("ranking the catalogue")
    ranking = rank(problem, model, cfg, float(np.mean(floor)), progress=say)
    t2 = time.perf_counter()
    added: list[Added] = []
    current = before
    for name in add:
        say(f"adding {name}")
        start = next((c.fit for c in ranking if c.name == name), None) if not added else None
        step = add_effect(problem, current.model, name, cfg, float(np.mean(floor)), current, start=start)
        added.append(step)
        current = step.after
    if automatic:
        added += auto(problem, current.model, cfg, float(np.mean(floor)), current,
                      ranking if not added else rank(problem, current.model, cfg, float(np.mean(floor)), say), say)
    t3 = time.perf_counter()
    floor = _lower_floor(floor, before, ranking)
    v, reason = verdict(before, float(np.mean(floor)), ranking, added, automatic)
    return Diagnosis(data.description, problem, before, floor, where, ranking, added, v, reason,
                     seconds={"compare": t1 - t0, "rank": t2 - t1, "add": t3 - t2, "total": t3 - t0})


def explain_corrector(data: Measurements, model: Model, corrector_dir, cfg: DiagnoseConfig | None = None,
                      progress=None) -> Diagnosis:
    """Which physical effects a corrector's corrections look like.

    On the measured states and actions, the model is driven once with the corrected actions
    a + F(s, a): those one-step outcomes become the "measurements", and the model without the
    corrector is diagnosed against them (one-step horizon: the synthetic rows do not chain).
    An effect that explains them changes the model the way the corrector does.
    """
    from dataclasses import replace

    from acn.models.corrector import Corrector
    from acn.toolkit.resim import Resimulator

    corrector = Corrector.load(corrector_dir)
    cfg = replace(cfg or DiagnoseConfig(), horizons=(1,))
    problem = prepare(data, model, cfg)
    rows = np.concatenate([problem.fit_rows, problem.held_rows])
    d = problem.data
    corrected = corrector.correct(d.state[rows], d.action[rows])
    with Resimulator(model.backend, model.sim_config(problem.control), threads=cfg.threads) as sim:
        pred = sim.run(d.state[rows], corrected, d.previous_actions(rows, problem.history))
    outcome = pred.state[:, 0]
    unpredicted = np.isnan(outcome).all(0)  # contacts: keep the measured readings
    outcome[:, unpredicted] = d.next_state[rows][:, unpredicted]
    next_state = d.next_state.copy()
    next_state[rows] = outcome
    synthetic = Measurements(d.state, d.action, next_state, d.effort, d.episode, d.frame, d.control, d.info,
                             f"corrections of {corrector_dir} on {data.description}", d.missing)
    return diagnose(synthetic, model, cfg, progress=progress)
