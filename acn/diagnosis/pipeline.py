"""The diagnosis as one pipeline: compare -> where -> rank -> add -> verdict.

Each stage is a function of the previous stage's result (``compare``, ``where``, ``rank``,
``add``); ``diagnose`` runs them in order and returns a ``Diagnosis`` that the CLI, the JSON
file, the HTML report and ``acn-view`` all read.

Verdict:
- ``effect``: a candidate (the best one whose held-out improvement is significant and whose
  magnitude is plausible: ``rank.implausible``) explains at least 70 % of the error above the
  noise floor; with ``--auto``, or the effects added one after the other do, or the model with
  them matches within the noise by the rule that gives ``none`` (less than 15 % of its error
  structured; also where the error was mostly noise before: a small effect under sensor noise,
  which ``--auto`` adds only where it lowers the longest-horizon error too);
- ``unexplained``: otherwise, when at least 15 % of the error is structured (above the floor);
- ``none``: the model matches within the noise: the error is zero, or less structured than
  that and no plausible candidate explains it.

Before any model, the measurements' own consistency is checked (``acn.measurements.checks``: units,
signs, frames, conventions), and with the model, whether each state is paired with the action
that drove it (``pairing``); findings are listed with the diagnosis and named in the reason,
since a model compared with inconsistent data explains the inconsistency as physics. What the
logged accelerometer reads (the mean over the control step, or one instant) is taken from the
dataset, or judged from the log by integrating it against the trunk's velocity, or where that
does not decide with the model and again under the final model (``accelerometer``).

The noise floor is what ridge regressions on a library of state and action terms cannot
predict (``noise``) of the model's held-out residual, or of what the best candidates leave,
whichever is lower: after the right effect only noise is left. It is raised by what candidates
that fit the noise remove (``noise_fitted``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import numpy as np

from acn.measurements import checks
from acn.measurements.data import Measurements
from acn.diagnosis.accelerometer import Accelerometer, read_accelerometer
from acn.diagnosis.add import (Added, Chain, add_effect, auto, fit_over_steps, longest_removed, names,
                                     refine_chain)
from acn.diagnosis.compare import Comparison, compare, floor_of, informative_horizon
from acn.diagnosis.limits import Limit, limits
from acn.diagnosis.pairing import action_row
from acn.diagnosis.problem import DiagnoseConfig, Problem, corrected, prepare
from acn.diagnosis.rate import physics_rate
from acn.diagnosis.rank import (SIGNIFICANCE_Z, STRUCTURED_SHARE, Candidate, doubt, explained_share, finer_look,
                                      fits_noise_by_size, floor_says_noise, implausible, one_step_only, rank,
                                      structured_share, ties_of)
from acn.diagnosis.where import breakdown
from acn.sim.effects import Model, get_effect

EXACT = 1e-3                  # headline error below which a model reproduces the data (float32 storage: ~1e-6)
EFFECT_SHARE = 0.7            # of the structured error an effect must explain to be named
FLOOR_CANDIDATES = 2          # best candidates whose leftover residual also bounds the noise floor


@dataclass
class Diagnosis:
    measurements: str
    problem: Problem
    before: Comparison
    judge_rows: np.ndarray       # held-out rows every candidate is judged on
    floor: np.ndarray            # (C,) noise-floor MSE per compared channel on those rows
    mse_judged: float            # the model's MSE on those rows
    where: dict
    ranking: list[Candidate]
    added: list[Added]
    verdict: str
    reason: str
    seconds: dict = field(default_factory=dict)
    closed_loop: dict | None = None  # robot vs model in closed loop (``transfer.closed_loop_models``)
    data_checks: list[checks.Finding] = field(default_factory=list)  # the measurements' own consistency
    chains: list[Chain] = field(default_factory=list)  # --auto: every chain of added effects tried (``add.auto``)
    set_aside: dict[str, str] = field(default_factory=dict)  # --auto: not added on their final fit: name -> why
    accelerometer: Accelerometer | None = None  # how the logged accelerometer is read (``accelerometer``)
    limits: list[Limit] | None = None  # --limits: the smallest size of each effect not named it shows (``rule_out``)

    @property
    def floor_mse(self) -> float:
        return float(np.mean(self.floor))

    @property
    def final(self) -> Comparison:
        return self.added[-1].after if self.added else self.before

    @property
    def structured_share(self) -> float:
        return structured_share(self.mse_judged, self.floor_mse)


def verdict(before: Comparison, mse: float, floor_mse: float, ranking: list[Candidate], added: list[Added],
            automatic: bool, set_aside: dict[str, str] | None = None) -> tuple[str, str, tuple[str, ...]]:
    """(verdict, reason in words, the effects it names); see module docstring. ``set_aside``:
    candidates ``--auto`` did not add on their final fit (name -> why); never named."""
    set_aside = set_aside or {}
    if before.headline < EXACT:
        return "none", f"the model reproduces the measurements (headline error {before.headline:.2g})", ()
    structured = 1.0 - floor_mse / mse if mse > 0 else 0.0
    if automatic and added:
        share = explained_share(mse, added[-1].judgement.mse_after, floor_mse)
        effects = tuple(names(added))
        explain = f"{' + '.join(effects)} explains" if len(effects) == 1 else f"{' + '.join(effects)} explain"
        if share >= EFFECT_SHARE:
            return "effect", f"{explain} {share:.0%} of the error above the noise floor", \
                effects
        after = added[-1].judgement.mse_after
        left = 1.0 - floor_mse / after if after > 0 else 0.0
        if min(structured, left) < STRUCTURED_SHARE:  # what is left is noise, by the rule that gives "none"
            longer = longest_removed(before, added[-1].after)
            gain = f" (the {before.check}-step open-loop error falls by {longer:.0%})" if longer and longer > 0 else ""
            why = (f"the one-step error is mostly sensor noise (only {max(structured, 0):.0%} of it is predictable "
                   f"from the state and actions)" if structured < STRUCTURED_SHARE else
                   f"only {max(left, 0):.0%} of the one-step error left is predictable from the state and actions, "
                   f"against {structured:.0%} before")
            return "effect", (f"{explain} {share:.0%} of the error above the noise floor{gain}, and what is "
                              f"left matches within the noise: {why}"), effects
    plausible = [c for c in ranking if c.judgement.significant and not doubt(c) and c.name not in set_aside]
    top = plausible[0] if plausible else None
    aside = "".join(f"; {name} set aside: {why}" for name, why in set_aside.items())
    if top is not None and top.judgement.explained(floor_mse) >= EFFECT_SHARE:
        skipped = [c.name for c in ranking[: ranking.index(top)] if c.name not in set_aside]
        also = f"; ranked above it but set aside: {', '.join(skipped)}" if skipped else ""
        also += aside
        return "effect", (f"{top.name} explains {top.judgement.explained(floor_mse):.0%} of the error above the noise "
                          f"floor ({evidence(top)}){also}"), (top.name,)
    best = ranking[0] if ranking else None
    if structured >= STRUCTURED_SHARE:
        why = ("no candidate improves held-out predictions significantly" if best is None
               or not best.judgement.significant else
               f"the best plausible candidate, {top.name}, explains only {top.judgement.explained(floor_mse):.0%} of it"
               if top is not None else
               f"the best candidate, {best.name}, {doubt(best) or set_aside.get(best.name, '')}")
        return "unexplained", f"{structured:.0%} of the error is structured (above the noise floor); {why}{aside}", ()
    extra = f"; the best candidate, {best.name}, removes {best.judgement.removed:.1%} of it" if best else ""
    if best is not None and (implausible(best.fit) or best.name in set_aside):
        extra += f" but {implausible(best.fit) or set_aside[best.name]}"
    noise = sorted((c for c in ranking if one_step_only(c)), key=lambda c: -c.judgement.removed)  # the most convincing
    if noise:
        extra += f"; {noise[0].name} {one_step_only(noise[0])}"
    return "none", (f"the model matches within the noise: only {max(structured, 0):.0%} of the error is predictable "
                    f"from the state and actions and no plausible effect explains it{extra}"), ()


def evidence(c: Candidate) -> str:
    """Why ``c``'s held-out improvement is significant, in words."""
    if c.judgement.by_longest and c.judgement.z >= SIGNIFICANCE_Z:
        return (f"it removes {c.longer_gain:.0%} of the longest-horizon open-loop error; at one step only "
                f"{c.judgement.removed:.1%} ({c.judgement.z:.1f} standard errors): a small effect that adds up")
    if c.judgement.by_longest:
        return (f"it removes {c.longer_gain:.0%} of the longest-horizon open-loop error; at one step its held-out "
                f"improvement is uneven, {c.judgement.z:.1f} standard errors: it acts on few steps")
    return f"held-out improvement {c.judgement.z:.1f} standard errors"


def findings_note(findings: list[checks.Finding], named: tuple[str, ...]) -> str:
    """What the verdict's reason adds about the data checks: a finding that an effect the verdict
    names produces too (``Finding.may_be``, e.g. encoder offsets put stance feet off the ground)
    is accounted for, so is one whose rows were left out (``checks.LEFT_OUT``) or whose channels
    were derived from positions (``checks.DERIVED``); any other says to fix the data first."""
    covered = [f for f in findings if set(f.may_be) & set(named)]
    left_out = [f for f in findings if f.check in checks.LEFT_OUT]
    derived = [f for f in findings if f.check in checks.DERIVED]
    rest = [f for f in findings if f not in covered and f not in left_out and f not in derived]
    note = "".join(f"; the {f.check} data check's finding is what {' / '.join(set(f.may_be) & set(named))} "
                   "does too" for f in covered)
    note += "".join(f"; the steps the {f.check} data check names were left out" for f in left_out)
    note += "".join(f"; the readings the {f.check} data check names were derived from the positions instead"
                    for f in derived)
    if rest:
        note += (f"; the measurements have {len(rest)} consistency finding(s) (data checks): fix the data first, "
                 "a model explains them as physics")
    return note


def noise_fitted(floor: np.ndarray, residual: np.ndarray, ranking: list[Candidate]) -> np.ndarray:
    """The floor (C,) raised by what a candidate that fits the noise removes per channel: one
    that improves the one step only (``rank.one_step_only``), or a significant one set aside only
    for a value below 3/4 of the smallest realistic magnitude (``rank.fits_noise_by_size``: a 2 mm
    trunk frame where the trunk lies on the floor and the noise in its measured height decides
    how deep it starts).
    That part of the error is caused by the sensor noise in the start states too, though the
    library regressions predict it (it depends on the true state).

    Only what it removes beyond the best candidate that can be the explanation (significant,
    ``rank.doubt`` empty) counts: a dozen encoder offsets also soak up a real error of the start
    states (a trunk measured in another frame), which is not noise. Of the candidates that fit
    noise, the one with the largest such excess sets the floor, so one more of them never
    lowers it."""
    fits = [c for c in ranking if one_step_only(c) or fits_noise_by_size(c)]
    if not fits:
        return floor
    before = np.mean(residual ** 2, axis=0)

    def removed(c: Candidate) -> np.ndarray:
        return np.clip(before - np.mean(c.judgement.residual_after ** 2, axis=0), 0.0, None)

    real = [removed(c) for c in ranking if c.judgement.significant and not doubt(c)]
    best = max(real, key=np.sum) if real else 0.0
    noise = max((np.clip(removed(c) - best, 0.0, None) for c in fits), key=np.sum)
    return np.minimum(before, floor + noise)


def _swapped(chains: list[Chain], steps: list[Added], new: list[Added]) -> list[Added]:
    """``new`` (the steps that stand for ``steps``, in order), with every chain's steps swapped alike."""
    swap = {id(a): b for a, b in zip(steps, new)}
    for chain in chains:
        chain.steps = [swap.get(id(s), s) for s in chain.steps]
    return new


def diagnose(data: Measurements, model: Model, cfg: DiagnoseConfig | None = None, add: list[str] = (),
             automatic: bool = False, progress=None, check_data: bool = True,
             accelerometer: Accelerometer | None = None) -> Diagnosis:
    """Run the whole diagnosis (module docstring); ``add``: effects to add in this order;
    ``check_data``: check the measurements' consistency first (off for synthetic ones);
    ``accelerometer``: how to read it (None: as the dataset states, else judged under ``model``
    and, where effects are added, again under the final model: where that judgement differs, the
    diagnosis runs again with it, ``acn.diagnosis.accelerometer``)."""
    cfg = cfg or DiagnoseConfig()
    for name in add:
        get_effect(name)  # unknown names fail before any work
    say = progress or (lambda msg, fraction=None: None)
    t0 = time.perf_counter()
    findings = checks.from_measurements(data) if check_data else []
    given = accelerometer
    if given is not None:
        data = data.reading_accelerometer(given.kind)
    problem = prepare(data, model, cfg)
    judge_rows = problem.sample(problem.held_rows, cfg.judge_rows, salt=4)
    accelerometer = given or read_accelerometer(problem, model, judge_rows)
    if accelerometer.kind != problem.control.imu_acc:  # leg odometry fuses the accelerometer as it reads
        data = data.reading_accelerometer(accelerometer.kind)
        problem = prepare(data, model, cfg)
        judge_rows = problem.sample(problem.held_rows, cfg.judge_rows, salt=4)
    say("comparing the model with the measurements")
    before = compare(problem, model, cfg)
    problem.check_horizon = before.check_horizon = informative_horizon(before)
    residual = problem.residual_of(model.sim_config(problem.control), judge_rows)
    ok = np.isfinite(residual).all(1)
    judge_rows, residual = judge_rows[ok], residual[ok]
    mse = float(np.mean(residual ** 2))
    if check_data and (pairing := action_row(problem, model, judge_rows, residual)):
        findings = findings + [pairing]
    if check_data and (rate := physics_rate(problem, model, judge_rows, residual)):
        findings = findings + [rate]
    where = breakdown(problem, before)
    t1 = time.perf_counter()
    say("ranking the catalogue")
    ranking = rank(problem, model, cfg, judge_rows, residual, progress=say)
    # The floor: what no regression on the state and actions predicts, of the model's residual
    # or of what the best candidates leave (after the right effect, only noise is left).
    model_floor = floor_of(problem, model, judge_rows, residual)

    def floor_after(ranking: list[Candidate]) -> np.ndarray:
        floors = [model_floor] + [
            floor_of(problem, c.fit.model, judge_rows, c.judgement.residual_after)
            for c in ranking[:FLOOR_CANDIDATES] if c.judgement.significant and not one_step_only(c)]
        return noise_fitted(min(floors, key=lambda f: float(np.mean(f))), residual, ranking)

    floor = floor_after(ranking)
    floor_mse = float(np.mean(floor))
    # The finer look runs even where the floor calls the error noise (``rank.finer_look``).
    if mse > 0 and not any(
            c.judgement.significant and not doubt(c) and c.judgement.explained(floor_mse) >= EFFECT_SHARE
            for c in ranking):
        finer = finer_look(problem, model, cfg, judge_rows, residual, ranking,
                           floor_says_noise=floor_says_noise(mse, floor_mse), progress=say)
        if finer is not ranking:
            ranking, floor = finer, floor_after(finer)
            floor_mse = float(np.mean(floor))
    t2 = time.perf_counter()
    added: list[Added] = []
    current, current_residual = before, residual
    for name in add:
        say(f"adding {name}", None)
        ranked = next((c for c in ranking if c.name == name), None) if not added else None
        step = add_effect(problem, current.model, name, cfg, judge_rows, current_residual, current,
                          start=ranked.fit if ranked else None)
        if ranked is not None:  # the first effect named: what the first ranking cannot tell it from
            step.ties = ties_of(ranked, ranking)
        added.append(step)
        current, current_residual = step.after, step.judgement.residual_after
    chains: list[Chain] = []
    set_aside: dict[str, str] = {}
    if automatic:
        again = ranking if not added else rank(problem, current.model, cfg, judge_rows, current_residual, say)
        steps, chains, set_aside = auto(problem, current, cfg, judge_rows, current_residual, floor_mse, again, say)
        added += steps
    if any(a.fit.effect.moves_start for a in added):
        say("refining the fits of effects that move the start state", None)
        added = _swapped(chains, added, refine_chain(problem, before, added, cfg, judge_rows, residual))
    added = _swapped(chains, added, fit_over_steps(problem, added, cfg, judge_rows, residual, say))
    if given is None and accelerometer.by_model and added:  # the integration's judgement needs no model
        again = replace(read_accelerometer(problem, added[-1].after.model, judge_rows), again=True)
        if again.kind != accelerometer.kind:
            how = "at each instant" if again.kind == "instant" else "as the mean over the control step"
            say(f"with the effects added the accelerometer reads {how}: diagnosing again", None)
            return diagnose(data, model, cfg, add, automatic, progress, check_data, accelerometer=again)
    t3 = time.perf_counter()
    v, reason, named = verdict(before, mse, floor_mse, ranking, added, automatic, set_aside)
    reason += findings_note(findings, named)
    return Diagnosis(data.description, problem, before, judge_rows, floor, mse, where, ranking, added, v, reason,
                     seconds={"compare": t1 - t0, "rank": t2 - t1, "add": t3 - t2, "total": t3 - t0},
                     data_checks=findings, chains=chains, set_aside=set_aside, accelerometer=accelerometer)


def rule_out(d: Diagnosis, candidates: tuple[str, ...], one_joint: bool = False, progress=None) -> list[Limit]:
    """What the log rules out beside the final model: the smallest size of each of the ``candidates``
    not in it that the diagnosis would have named (``acn.diagnosis.limits``); ``one_joint``:
    also on one joint alone, the joint the log shows least."""
    if progress:
        progress("the smallest effects this log shows" + (", also on one joint alone" if one_joint else ""), None)
    model = d.final.model
    residual = d.problem.residual_of(model.sim_config(d.problem.control), d.judge_rows)
    return limits(d.problem, model, d.judge_rows, np.where(np.isfinite(residual), residual, 10.0), d.floor_mse,
                  candidates, one_joint=one_joint, floor_says_noise=floor_says_noise(d.mse_judged, d.floor_mse))


def explain_corrector(data: Measurements, model: Model, corrector_dir, cfg: DiagnoseConfig | None = None,
                      progress=None) -> Diagnosis:
    """Which physical effects a corrector's corrections look like.

    On the measured states and actions, the model is driven once with the corrected actions
    a + F(s, a): those one-step outcomes become the "measurements", and the model without the
    corrector is diagnosed against them (one-step horizon: the synthetic rows do not chain).
    An effect that explains them changes the model the way the corrector does.
    """
    from acn.corrector.corrector import Corrector
    from acn.sim.resim import Resimulator

    corrector = Corrector.load(corrector_dir)
    cfg = replace(cfg or DiagnoseConfig(), horizons=(1,), step_seconds=None)
    problem = prepare(data, model, cfg)
    rows = np.concatenate([problem.fit_rows, problem.held_rows])
    d = problem.data
    actions = corrected(corrector, d.state[rows], d.action[rows])
    config = model.sim_config(problem.control)
    with Resimulator(model.backend, config, threads=cfg.threads) as sim:
        pred = sim.run(problem.starts(sim, rows, config), actions, d.previous_actions(rows, problem.history))
    outcome = pred.state[:, 0]
    unpredicted = np.isnan(outcome).all(0)  # contacts: keep the measured readings
    outcome[:, unpredicted] = d.next_state[rows][:, unpredicted]
    next_state = d.next_state.copy()
    next_state[rows] = outcome
    synthetic = replace(d, next_state=next_state, description=f"corrections of {corrector_dir} on {data.description}")
    return diagnose(synthetic, model, cfg, progress=progress, check_data=False)
