"""The diagnosis as one pipeline: compare -> where -> rank -> add -> verdict, then on request what
the log rules out and the closed loop.

Each stage is a function of the previous stage's result (``compare``, ``where``, the ranking,
the added effects); ``diagnose`` runs them in order and returns a ``Diagnosis`` that the CLI,
the JSON file, the HTML report and ``acn-view`` all read, and ``run`` adds the stages a user
asks for after it (``Stages``: what the log rules out, the closed loop) or diagnoses a
corrector's corrections instead (``explain_corrector``). Which candidates are ranked first,
which are added, when to stop and which verdict: ``policy``, with its ``Thresholds``.

Before any model, the measurements' own consistency is checked (``acn.measurements.checks``: units,
signs, frames, conventions), and with the model, whether each state is paired with the action
that drove it (``pairing``) and whether the log was simulated at a coarser physics rate
(``rate``); findings are listed with the diagnosis and named in the reason, since a model
compared with inconsistent data explains the inconsistency as physics. What the logged
accelerometer reads (the mean over the control step, or one instant) is taken from the
dataset, or judged from the log by integrating it against the trunk's velocity, or where that
does not decide with the model and again under the final model (``accelerometer``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from acn.measurements import checks
from acn.measurements.data import Measurements
from acn.diagnosis.accelerometer import Accelerometer, read_accelerometer
from acn.diagnosis.clock import StageClock
from acn.diagnosis.compare import Comparison, compare, floor_of, informative_horizon
from acn.diagnosis.decisions import Decision, tracing
from acn.diagnosis.halves import HalfFits, fit_halves
from acn.diagnosis.heldout import structured_share
from acn.diagnosis.limits import Limit, limits
from acn.diagnosis.pairing import action_row
from acn.diagnosis.policy import (THRESHOLDS, Thresholds, add_effect, added_fits_noise, auto, finer_look, fit_over_steps,
                                  floor_after, floor_says_noise, holds_on_halves, needs_finer_look, rank, refine_chain,
                                  ties_of, verdict)
from acn.diagnosis.problem import DiagnoseConfig, Problem, corrected, prepare
from acn.diagnosis.rate import physics_rate
from acn.diagnosis.results import Added, Candidate, Chain, names
from acn.diagnosis.traits import traits
from acn.diagnosis.transfer import closed_loop_models, robot_config
from acn.diagnosis.where import breakdown
from acn.sim.effects import Model, get_effect


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
    seconds: dict = field(default_factory=dict)  # compare, rank, add (everything after the ranking), total
    stages: dict[str, float] = field(default_factory=dict)  # every stage's wall time, s, in order (``StageClock``)
    halves: list[HalfFits] = field(default_factory=list)  # --auto: the added effects on two halves (``halves``)
    closed_loop: dict | None = None  # robot vs model in closed loop (``transfer.closed_loop_models``)
    data_checks: list[checks.Finding] = field(default_factory=list)  # the measurements' own consistency
    chains: list[Chain] = field(default_factory=list)  # --auto: every chain of added effects tried (``policy.auto``)
    set_aside: dict[str, str] = field(default_factory=dict)  # --auto: not added on their final fit: name -> why
    accelerometer: Accelerometer | None = None  # how the logged accelerometer is read (``accelerometer``)
    limits: list[Limit] | None = None  # --limits: the smallest size of each effect not named it shows (``rule_out``)
    thresholds: Thresholds = THRESHOLDS  # the selection's, which the report judges by too
    decisions: list[Decision] = field(default_factory=list)  # every decision of the selection, in order (``decisions``)

    @property
    def floor_mse(self) -> float:
        return float(np.mean(self.floor))

    @property
    def final(self) -> Comparison:
        return self.added[-1].after if self.added else self.before

    @property
    def model(self) -> Model:
        """The model the verdict stands for: the final one, or the model as given where the added
        effects do not hold (unexplained after --auto: the effects only papered over the error)."""
        return self.before.model if self.verdict == "unexplained" and self.halves else self.final.model

    @property
    def structured_share(self) -> float:
        return structured_share(self.mse_judged, self.floor_mse)


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


def _swapped(chains: list[Chain], steps: list[Added], new: list[Added]) -> list[Added]:
    """``new`` (the steps that stand for ``steps``, in order), with every chain's steps swapped alike."""
    swap = {id(a): b for a, b in zip(steps, new)}
    for chain in chains:
        chain.steps = [swap.get(id(s), s) for s in chain.steps]
    return new


def diagnose(data: Measurements, model: Model, cfg: DiagnoseConfig | None = None, add: list[str] = (),
             automatic: bool = False, progress=None, check_data: bool = True,
             accelerometer: Accelerometer | None = None, thresholds: Thresholds = THRESHOLDS,
             clock: StageClock | None = None) -> Diagnosis:
    """Run the whole diagnosis (module docstring); ``add``: effects to add in this order;
    ``check_data``: check the measurements' consistency first (off for synthetic ones);
    ``accelerometer``: how to read it (None: as the dataset states, else judged under ``model``
    and, where effects are added, again under the final model: where that judgement differs, the
    diagnosis runs once more with it, ``acn.diagnosis.accelerometer``); ``thresholds``: the selection's
    (``policy``); ``clock``: times every stage (``Diagnosis.stages``). The decisions of the run
    reported are in ``Diagnosis.decisions``."""
    clock = clock or StageClock()  # both runs' stages add up
    while True:
        with tracing() as trace:
            result = _diagnose(data, model, cfg, add, automatic, progress, check_data, accelerometer, thresholds,
                               clock)
        if isinstance(result, Diagnosis):
            result.decisions = trace.decisions
            return result
        accelerometer = result  # judged otherwise under the final model: once more, read as judged


def _diagnose(data: Measurements, model: Model, cfg: DiagnoseConfig | None, add: list[str], automatic: bool,
              progress, check_data: bool, accelerometer: Accelerometer | None, thresholds: Thresholds,
              clock: StageClock) -> Diagnosis | Accelerometer:
    """One run of ``diagnose``: the Diagnosis, or where the accelerometer was judged with the model
    and reads otherwise under the final model, that judgement (``diagnose`` runs again with it)."""
    cfg, t = cfg or DiagnoseConfig(), thresholds
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
    t1 = clock.record("compare", t0)
    say("ranking the catalogue")
    ranking = rank(problem, model, cfg, judge_rows, residual, progress=say, t=t)
    model_floor = floor_of(problem, model, judge_rows, residual)
    floor = floor_after(problem, model_floor, judge_rows, residual, ranking, t=t)
    floor_mse = float(np.mean(floor))
    if needs_finer_look(ranking, mse, floor_mse, t=t):
        finer = finer_look(problem, model, cfg, judge_rows, residual, ranking,
                           floor_says_noise=floor_says_noise(mse, floor_mse, t=t), progress=say, t=t)
        if finer is not ranking:
            ranking, floor = finer, floor_after(problem, model_floor, judge_rows, residual, finer, t=t)
            floor_mse = float(np.mean(floor))
    t2 = clock.record("rank", t1)
    added: list[Added] = []
    current, current_residual = before, residual
    for name in add:
        say(f"adding {name}", None)
        ranked = next((c for c in ranking if c.name == name), None) if not added else None
        with clock.stage(f"add {name}"):
            step = add_effect(problem, current.model, name, cfg, judge_rows, current_residual, current,
                              start=ranked.fit if ranked else None, t=t)
        if ranked is not None:  # the first effect named: what the first ranking cannot tell it from
            step.ties = ties_of(ranked, ranking, t=t)
        added_fits_noise(step, t=t)  # a warning in the trace, which the report reads
        added.append(step)
        current, current_residual = step.after, step.judgement.residual_after
    chains: list[Chain] = []
    set_aside: dict[str, str] = {}
    if automatic:
        with clock.stage(f"rank beside {' + '.join(add)}" if added else "rank"):
            again = ranking if not added else rank(problem, current.model, cfg, judge_rows, current_residual, say, t=t)
        steps, chains, set_aside = auto(problem, current, cfg, judge_rows, current_residual, floor_mse, again, say,
                                        t=t, clock=clock)
        added += steps
    with clock.stage("final refit"):
        if any(traits(a.name).moves_start for a in added):
            say("refining the fits of effects that move the start state", None)
            added = _swapped(chains, added, refine_chain(problem, before, added, cfg, judge_rows, residual, t=t))
        added = _swapped(chains, added, fit_over_steps(problem, added, cfg, judge_rows, residual, say, t=t))
    if given is None and accelerometer.by_model and added:  # the integration's judgement needs no model
        again = replace(read_accelerometer(problem, added[-1].after.model, judge_rows), again=True)
        if again.kind != accelerometer.kind:
            how = "at each instant" if again.kind == "instant" else "as the mean over the control step"
            say(f"with the effects added the accelerometer reads {how}: diagnosing again", None)
            return again
    t3 = time.perf_counter()
    v, reason, named = verdict(before, mse, floor_mse, ranking, added, automatic, set_aside, t=t)
    half_fits: list[HalfFits] = []
    if automatic and v == "effect" and added:
        say("fitting the added effects on two halves of the episodes", None)
        with clock.stage("halves"):
            half_fits = fit_halves(problem, added[-1].after.model, names(added), cfg)
        t3 = time.perf_counter()
        v, reason, named = holds_on_halves((v, reason, named), half_fits, added, mse, floor_mse, t=t)
    reason += findings_note(findings, named)
    return Diagnosis(data.description, problem, before, judge_rows, floor, mse, where, ranking, added, v, reason,
                     seconds={"compare": t1 - t0, "rank": t2 - t1, "add": t3 - t2, "total": t3 - t0},
                     stages=dict(clock.seconds), halves=half_fits,
                     data_checks=findings, chains=chains, set_aside=set_aside, accelerometer=accelerometer,
                     thresholds=t)


def rule_out(d: Diagnosis, candidates: tuple[str, ...], one_joint: bool = False, progress=None) -> list[Limit]:
    """What the log rules out beside the final model: the smallest size of each of the ``candidates``
    not in it that the diagnosis would have named (``acn.diagnosis.limits``); ``one_joint``:
    also on one joint alone, the joint the log shows least."""
    if progress:
        progress("the smallest effects this log shows" + (", also on one joint alone" if one_joint else ""), None)
    model = d.final.model
    residual = d.problem.residual_of(model.sim_config(d.problem.control), d.judge_rows)
    return limits(d.problem, model, d.judge_rows, np.where(np.isfinite(residual), residual, 10.0), d.floor_mse,
                  candidates, one_joint=one_joint,
                  floor_says_noise=floor_says_noise(d.mse_judged, d.floor_mse, t=d.thresholds), t=d.thresholds)


def explain_corrector(data: Measurements, model: Model, corrector_dir, cfg: DiagnoseConfig | None = None,
                      progress=None, thresholds: Thresholds = THRESHOLDS) -> Diagnosis:
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
    return diagnose(synthetic, model, cfg, progress=progress, check_data=False, thresholds=thresholds)


@dataclass(frozen=True)
class ClosedLoop:
    """``--closed-loop``: the measured robot re-run beside the models (``transfer.closed_loop_models``)."""

    dataset: Path             # the acn-collect dataset whose robot is re-run
    side: str                 # the side of it the measurements are (source: the policy acts on it)
    episodes: int             # held-out initial states
    seconds: float            # each episode's length, s
    corrector: Path | None = None  # also run the model with this corrector (acn-fit output)
    oracles: bool = True      # and the oracle bounds


@dataclass(frozen=True)
class Stages:
    """What ``run`` does beside comparing the model with the measurements and ranking the catalogue."""

    add: tuple[str, ...] = ()               # effects to add, in this order (--add)
    automatic: bool = False                 # repeat rank -> add while it helps (--auto)
    explain_corrector: Path | None = None   # diagnose this corrector's corrections instead (--explain-corrector)
    limits: bool = False                    # then what the log rules out (--limits)
    limits_per_joint: bool = False          # ... and each per-joint effect on one joint alone (implies ``limits``)
    closed_loop: ClosedLoop | None = None   # then the closed loop beside the robot (--closed-loop)

    def check(self, data: Measurements, model: Model) -> None:
        """Refuse what cannot run, before any long work: a closed loop of a log that cannot be re-run,
        a corrector that was not fitted for ``model`` (each is applied to the model as given)."""
        if self.closed_loop is not None:
            c = self.closed_loop
            robot_config(c.dataset, data, c.side, model, c.episodes, c.seconds, c.corrector)
        from acn.corrector.card import TargetDescription
        from acn.corrector.corrector import load_for_target

        target = TargetDescription(model.backend, data.control.action_mode, round(1.0 / data.control.control_dt, 9),
                                   tuple(e.to_json() for e in model.effects))
        for corrector in (model.corrector, self.closed_loop and self.closed_loop.corrector, self.explain_corrector):
            if corrector:  # each is applied to the model as given, driven as the robot was
                load_for_target(corrector, target)


def run(data: Measurements, model: Model, cfg: DiagnoseConfig, stages: Stages = Stages(), progress=None,
        thresholds: Thresholds = THRESHOLDS, clock: StageClock | None = None) -> Diagnosis:
    """Every stage of ``acn-diagnose``: the diagnosis (``diagnose``; or, with
    ``stages.explain_corrector``, ``explain_corrector``), then what the log rules out
    (``rule_out``) and the closed loop where ``stages`` asks for them; the result carries them.
    ``progress(message, fraction or None)`` hears of each stage (``Stages.check`` first: it
    refuses what cannot run)."""
    say = progress or (lambda msg, fraction=None: None)
    if stages.explain_corrector is not None:
        result = explain_corrector(data, model, stages.explain_corrector, cfg, progress=say, thresholds=thresholds)
    else:
        result = diagnose(data, model, cfg, add=list(stages.add), automatic=stages.automatic, progress=say,
                          thresholds=thresholds, clock=clock)
    if stages.limits or stages.limits_per_joint:
        result.limits = rule_out(result, cfg.candidates, one_joint=stages.limits_per_joint, progress=say)
    if stages.closed_loop is not None:
        c = stages.closed_loop
        say("closed loop")
        result.closed_loop = closed_loop_models(c.dataset, data, c.side, model, result.final.model, c.corrector,
                                                c.episodes, c.seconds, oracles=c.oracles)
    say("done", 1.0)
    return result
