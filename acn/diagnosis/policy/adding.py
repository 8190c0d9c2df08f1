"""Adding an effect: its granularity (``choose_fit``), its final fit, whether it holds there
(``final_doubt``, ``too_little``), and ``greedy``, which ranks and adds while the
best candidate removes more than the noise.
"""

from __future__ import annotations

import numpy as np

from acn.diagnosis.clock import StageClock
from acn.diagnosis.compare import Comparison, compare
from acn.diagnosis.decisions import record, share
from acn.diagnosis.fitting import (EffectFit, final_fit, final_rows, finer_gains, fit_effect,
                                   multistep_refit, rank_rows, refittable)
from acn.diagnosis.granularity import GRANULARITIES, finer
from acn.diagnosis.heldout import Judgement, removed_at
from acn.diagnosis.policy.judging import doubt, fits_noise, floor_says_noise, implausible, judge, judgement, significant
from acn.diagnosis.policy.ranking import finer_look, rank, ties_of
from acn.diagnosis.policy.thresholds import THRESHOLDS, Thresholds
from acn.diagnosis.problem import DiagnoseConfig, Problem
from acn.diagnosis.results import Added, Candidate, held, longer_gain, names
from acn.diagnosis.traits import traits
from acn.sim.effects import Model, get_effect


def _granularities(effect, finest: str) -> list[str]:
    """Those ``choose_fit`` tries, coarsest first, down to ``finest`` (an effect that is per joint
    by nature, such as encoder offsets, is fitted per joint whatever ``finest`` says)."""
    if not effect.per_joint:
        return ["shared"]
    if traits(effect.name).granularity == "joint":
        return ["joint"]
    return list(GRANULARITIES[: GRANULARITIES.index(finest) + 1])


def choose_fit(problem: Problem, model: Model, name: str, cfg: DiagnoseConfig, judge_rows: np.ndarray,
               base_residual: np.ndarray, start: EffectFit | None = None,
               t: Thresholds = THRESHOLDS) -> tuple[EffectFit, Judgement]:
    """The effect fitted at the coarsest granularity (down to ``cfg.finest``) no finer one
    significantly beats. Where the final fit at that granularity is implausible (``implausible``:
    a value at a bound or beyond twice the realistic range), the coarser one it beat is fitted
    finally instead, down to the first: a joint type the log hardly moves lets its value run off
    and soak up another effect (fresh draw k 61, a pace log with joint damping 1.951 and floor
    friction 0.391: damping per joint type, hip 5.0 (the bound), thigh 1.83, calf 1.99, was set aside
    whole, and a 31.6 ms lag named in its place)."""
    effect = get_effect(name)
    rows = rank_rows(problem, cfg)
    chosen: list[tuple[EffectFit, Judgement]] = []  # each granularity that beat the one before it
    granularities = _granularities(effect, cfg.finest)
    promise: dict[str, float] = {}  # the finer granularities' screen from the coarsest fit (``finer_gains``)
    for g in granularities:
        best = chosen[-1] if chosen else None
        # neither joint types nor legs differ, and the ranking did not fit joints apart: no reason to try 12 values
        if best is not None and g == "joint" and best[0].granularity == "shared" and not (
                start is not None and start.granularity == "joint"):
            break
        if best is not None and not (start is not None and start.granularity == g):
            promise = promise or finer_gains(problem, chosen[0][0], rows, granularities[1:])
            if promise[g] < t.finer_screen:
                continue
        seed = start.values if start is not None and start.granularity == g else (best[0].values if best else None)
        fit = fit_effect(problem, model, effect, g, rows, start=seed, refit=refittable(model))
        if best is None or judge(problem, fit.model, judge_rows, best[1].residual_after,
                                 reference_mse=best[1].mse_before, t=t).significant:
            chosen.append((fit, judge(problem, fit.model, judge_rows, base_residual, t=t)))
    fell_back = []  # finer final fits found implausible, finest first
    for i in range(len(chosen) - 1, -1, -1):
        fit = final_fit(problem, model, chosen[i][0], cfg)
        if i == 0 or not (why := implausible(fit, t=t)):
            break
        fell_back.append(f"per {fit.granularity} {why}")
    if len(granularities) > 1:
        beat = [f.granularity for f, _ in chosen]
        said = f"{name} fitted {'as ' if fit.granularity == 'shared' else 'per '}{fit.granularity}"
        said += (f": per {', then per '.join(beat[1:])} predicted the held-out rows significantly better than coarser"
                 if len(beat) > 1 else ": no finer granularity predicts the held-out rows significantly better")
        said += "".join(f"; its final fit {x}" for x in fell_back)
        record("choose_fit", f"{name} {fit.granularity}", said, effect=name, granularity=fit.granularity,
               granularities=", ".join(granularities), significant_finer=", ".join(beat[1:]), fell_back=len(fell_back))
    return fit, judge(problem, fit.model, judge_rows, base_residual, t=t)


def add_effect(problem: Problem, model: Model, name: str, cfg: DiagnoseConfig, judge_rows: np.ndarray,
               base_residual: np.ndarray, before: Comparison, start: EffectFit | None = None,
               t: Thresholds = THRESHOLDS) -> Added:
    fit, judgement = choose_fit(problem, model, name, cfg, judge_rows, base_residual, start, t=t)
    return Added(fit, judgement, before, compare(problem, fit.model, cfg))


def added_fits_noise(step: Added, t: Thresholds = THRESHOLDS) -> str:
    """Why an effect the user added (``--add``) may fit what sensor noise in the measured start
    states does ("" where it does not): ``fits_noise`` on its final fit, by the effect's own rule
    (a reading-only effect may raise the longest-horizon error by ``reading_tolerance``), the rule
    ``--auto`` sets such an effect aside by."""
    g = longer_gain(step)
    if not fits_noise(g, step.fit.effect, t=t):
        return ""
    why = (f"it raises the open-loop error at the longest horizon ({-g:+.0%}): it may fit what sensor noise in the "
           "measured start states does rather than a physical effect")
    record("one_step_only", "warned", f"{step.name} (--add): {why}", effect=step.name, longest_horizon_removed=g,
           reading_only=traits(step.name).reading_only, reading_tolerance=t.reading_tolerance)
    return why


def final_doubt(step: Added, t: Thresholds = THRESHOLDS) -> str:
    """Why an effect's final fit is not added ("" if it is): no longer significant, or implausible."""
    f = step.fit
    values = ", ".join(f"{n}={x:.4g}" for n, x in zip(f.names, f.x)) if len(f.x) <= 4 else f"{len(f.x)} values"
    if not significant(step, t=t):
        return (f"its final fit ({values}) improves held-out predictions by only {step.judgement.z:.1f} standard errors "
                f"(at least {t.significance_z:g}, or {t.large_improvement:.0%} of the longest-horizon error removed)")
    why = implausible(f, t=t)
    return f"its final fit ({values}) {why}" if why else ""


def too_little(j: Judgement, longer: float | None, floor_mse: float, t: Thresholds = THRESHOLDS) -> str:
    """Why an effect that removes ``j`` of the one-step error and ``longer`` of the longest-horizon
    one is too small for ``--auto`` to add ("" where it is not): it explains less than
    ``auto_min_explained`` of the structured error left (and less than ``structured_share`` of the
    whole), or removes less than ``auto_min_removed`` of the one-step error and less than
    ``auto_min_longer`` of the longest-horizon one. ``greedy`` asks it of the best candidate, and
    again of its final fit (a final fit on more rows can remove less than the ranking's)."""
    if j.explained(floor_mse) < t.auto_min_explained and j.removed < t.structured_share:
        return (f"explains only {j.explained(floor_mse):.1%} of the structured error left (at least "
                f"{t.auto_min_explained:.1%}, or {t.structured_share:.0%} of the whole error removed)")
    if j.removed < t.auto_min_removed and (longer or 0.0) < t.auto_min_longer:
        tail = f" and {longer:.1%} at the longest horizon" if longer is not None else ""
        return (f"removes only {j.removed:.1%} of the one-step error{tail} (at least {t.auto_min_removed:.1%} "
                f"at one step or {t.auto_min_longer:.1%} at the longest horizon)")
    return ""


def nothing_left(current: Comparison, mse: float, start: Comparison, start_mse: float, floor_mse: float,
                 t: Thresholds = THRESHOLDS, then: str = "stopped") -> bool:
    """Whether no effect added beside ``current`` (held-out one-step error ``mse``) could be
    needed: all of what is left, noise included, is under ``auto_min_share`` of the structured
    error ``start`` had (one-step error ``start_mse``), and of its open-loop error at the longest
    horizon. --auto stops there: no ranking, finer look or other start (``then``: what the
    decision recorded says it does). Once one effect has explained a noise-free log to its last
    per cent, any flexible effect explains a share of that rest (a payload of 0 kg, its centre of
    mass 5 mm off): against the error the diagnosis started from, such a step is nothing."""
    one, longer = left_over(current, mse, start, start_mse, floor_mse)
    if not (one < t.auto_min_share and longer < t.auto_min_share):
        return False
    record("nothing_left", then, (
        f"{then}: what is left, {share(one)} of the error above the noise floor the diagnosis started from and "
        f"{share(longer)} of its {start.check}-step open-loop error, is under {share(t.auto_min_share)} of each: "
        "no effect added beside it could be needed"), one_step_left=one, longest_horizon_left=longer,
        auto_min_share=t.auto_min_share)
    return True


def left_over(current: Comparison, mse: float, start: Comparison, start_mse: float, floor_mse: float) -> tuple[float, float]:
    """What ``nothing_left`` compares: the one-step error ``mse`` left beside ``current`` as a share of
    the structured error ``start`` had (one-step error ``start_mse``), and the share of ``start``'s
    open-loop error at the longest horizon left."""
    one = mse / (start_mse - floor_mse) if start_mse > floor_mse else 0.0
    longer = 1.0 - removed_at(start, current, start.check) if start.check > 1 else 0.0
    return one, longer


def refine_chain(problem: Problem, before: Comparison, steps: list[Added], cfg: DiagnoseConfig,
                 judge_rows: np.ndarray, base_residual: np.ndarray, t: Thresholds = THRESHOLDS) -> list[Added]:
    """``steps`` (the effects the diagnosis added, in order) with the fit of each effect that
    moves the start state (``EffectTraits.moves_start``) refined by central differences, and every
    later step refitted on top of it; each at the granularity chosen, from its values (the
    refine stage of ``choose_fit``). The effects are chosen with forward differences, whose
    thresholds were measured on them; this only makes the chosen values more exact (fitting
    module docstring; the benchmark's offsets log: 12 offsets 38 % -> 13.5 % off). ``steps``
    itself where no effect moves the start state, or where the refined chain predicts the held-out
    rows worse than ``steps`` (refined values that fit the fitting rows' noise: twelve offsets on a
    log with joint springs removed 2.5 % of the error refined, 10.9 % unrefined)."""
    first = next((i for i, s in enumerate(steps) if traits(s.name).moves_start), None)
    if first is None or all(s.refined for s in steps[first:]):  # nothing to refine, or refined already
        return steps
    out = steps[:first]
    current = out[-1].after if out else before
    residual = out[-1].judgement.residual_after if out else base_residual
    for step in steps[first:]:
        fit = final_fit(problem, current.model, step.fit, cfg, again=True, central=traits(step.name).moves_start)
        judgement = judge(problem, fit.model, judge_rows, residual, t=t)
        out.append(Added(fit, judgement, current, compare(problem, fit.model, cfg), step.ties, refined=True))
        current, residual = out[-1].after, judgement.residual_after
    refined, unrefined = (float(np.mean(c[-1].judgement.residual_after ** 2)) for c in (out, steps))
    if refined <= unrefined:
        return out
    for step in steps[first:]:
        step.refined = True  # tried: refining it again gives the same
    return steps


def fit_over_steps(problem: Problem, steps: list[Added], cfg: DiagnoseConfig, judge_rows: np.ndarray,
                   base_residual: np.ndarray, progress=None, t: Thresholds = THRESHOLDS) -> list[Added]:
    """``steps`` (the effects the diagnosis added, in order) with the last one's final fit, and
    every few-parameter effect refitted with it, refined on predictions several steps ahead
    (``fitting.multistep_refit``), where the model holds an effect whose one-step fit the noise in
    the start states biases and no instrument corrects (``EffectTraits.fit_over_steps``: the payload).

    Only once the effects are chosen, with all of them in the model: fitted over several steps
    while an effect is still missing, the payload takes the missing effect's share too (a payload
    2 kg + damping 0.4 log: the payload alone 2.42 kg, after which Coulomb friction, not the
    damping, was added). The effects are chosen, and their thresholds were measured, on one-step
    fits; this makes the chosen values more exact."""
    if not steps:
        return steps
    last = steps[-1]
    refit = refittable(last.before.model)
    if not (traits(last.name).fit_over_steps or any(traits(n).fit_over_steps for n in refit)):
        return steps
    if progress:
        progress(f"fitting {last.name} again over several steps", None)
    fit = multistep_refit(problem, last.fit, final_rows(problem, cfg)[0], refit=refit)
    if fit is last.fit:
        return steps
    residual = steps[-2].judgement.residual_after if len(steps) > 1 else base_residual
    return steps[:-1] + [Added(fit, judge(problem, fit.model, judge_rows, residual, t=t), last.before,
                               compare(problem, fit.model, cfg), last.ties)]


def greedy(problem: Problem, first: Comparison, cfg: DiagnoseConfig, judge_rows: np.ndarray,
           base_residual: np.ndarray, floor_mse: float, ranking: list[Candidate],
           progress=None, t: Thresholds = THRESHOLDS, clock: StageClock | None = None) -> tuple[list[Added], dict[str, str]]:
    """Greedy rank -> add while the best candidate removes more than the noise: it explains at
    least ``auto_min_explained`` of what is left above the floor, and removes ``auto_min_removed``
    of the one-step error or ``auto_min_longer`` of the longest-horizon open-loop error.

    A candidate whose final fit is not added (``final_doubt``, or ``too_little`` on it) is set
    aside and the next one is tried by the same rules. A significant candidate too little to add
    is passed over for the next significant one, which a long prediction may have shown
    (``uneven``). Returns the added effects and those set
    aside (name -> why).

    An effect already added comes back as a candidate where the ranking beside the effects added
    after it fits it finer (joint damping shared by all joints, then per joint type once armature
    has taken its share: a step that ``refines`` it). The noise floor is an upper bound on the noise
    (its linear library misses nonlinear structure: on a noise-free log it called 40 % of what two
    added effects left noise), so a candidate that removes ``structured_share`` of what is left by
    itself is added whatever the floor says.

    Before it stops with an effect added, it fits the per-joint candidates not added per joint type,
    per leg and per joint (``finer_look``; per joint alone, removing ``structured_share``, where
    the floor calls what is left noise), once per ranking: beside an added effect a new one is
    ranked with one value for every joint, where one weak motor cancels. A 20 ms delay beside
    FR_calf at half strength (a short noisy log): one strength for every joint was not added
    beside the delay, and --auto stopped there; per joint it is FR_calf 0.511. The first ranking
    looks at joints apart only where no effect explains most of the error (``pipeline.diagnose``)."""
    added: list[Added] = []
    noise_fits: set[str] = set()  # added, then found to improve the one step only
    set_aside: dict[str, str] = {}
    kept_coarse: set[str] = set()  # added; a finer fit of it was not added on its final fit
    looked = False  # the new candidates of this ranking fitted finer (finer_look)
    current, residual = first, base_residual
    start_mse = float(np.mean(base_residual ** 2))
    clock = clock or StageClock()
    while len(names(added)) < cfg.auto_max and len(added) < 2 * cfg.auto_max:  # --auto-max (refinements: bounded)
        open_ = [c for c in ranking if c.name not in names(added) or c.name not in kept_coarse  # refinements too
                 and finer(c.fit.granularity, held(current.model, c.name))]
        open_ = [c for c in open_ if c.name not in noise_fits | set(set_aside)]
        candidates = [c for c in open_ if c.judgement.significant and not doubt(c, t=t)]
        # a candidate too little to add does not hide one behind it that a long prediction shows
        # (uneven, short_lived)
        best = next((c for c in candidates if not too_little(c.judgement, c.longer_gain, floor_mse, t=t)), None)
        if best is None and added and not looked:  # one joint apart (docstring)
            if out_of_time(cfg, clock, "the finer look at joints apart (per joint type, leg and joint)"):
                break
            looked = True
            with clock.stage("finer look"):
                looked_finer = finer_look(
                    problem, current.model, cfg, judge_rows, residual, ranking, progress=progress,
                    floor_says_noise=floor_says_noise(float(np.mean(residual ** 2)), floor_mse, t=t),
                    only=[c.name for c in ranking if c.name not in names(added)], t=t)
            if looked_finer is not ranking:
                ranking = looked_finer
                continue
        if best is None:
            _record_no_candidate(candidates, open_, floor_mse, t=t)
            break
        if out_of_time(cfg, clock, f"adding {best.name}" + (
                f" (then {', '.join(c.name for c in candidates if c is not best)})" if len(candidates) > 1 else "")):
            break
        if progress:
            progress(f"adding {best.name}", None)
        with clock.stage(f"add {best.name}"):
            step = add_effect(problem, current.model, best.name, cfg, judge_rows, residual, current, start=best.fit,
                              t=t)
        step.ties = ties_of(best, open_, t=t)
        rule, why = "final_doubt", final_doubt(step, t=t)
        if not why and (little := too_little(step.judgement, longer_gain(step), floor_mse, t=t)):
            rule, why = "too_little", f"its final fit {little}"
        noise = fits_noise(longer_gain(step), step.fit.effect, t=t)
        figures = dict(effect=best.name, granularity=step.fit.granularity, explained=step.judgement.explained(floor_mse),
                       removed=step.judgement.removed, z=step.judgement.z, longest_horizon_removed=longer_gain(step))
        if best.name in names(added) and (why or not step.refines or noise):
            kept_coarse.add(best.name)  # its finer fit did not hold: the effect stays as added
            record("greedy", f"{best.name} kept {held(current.model, best.name)}", (
                f"{best.name} stays {held(current.model, best.name)}: fitted per {step.fit.granularity} beside the "
                f"effects added after it, {why or 'it lowers the one-step error only'}"), **figures)
            continue
        if why:
            set_aside[best.name] = why
            record(rule, "set aside", f"{best.name} set aside: {why}", **figures)
            if progress:
                progress(f"{best.name} set aside: {why}", None)
            continue
        if noise:
            noise_fits.add(best.name)  # one_step_only, found on the refitted effect: try the next one
            record("one_step_only", "set aside", (
                f"{best.name} set aside: its final fit lowers the one-step error only (open-loop error at the longest "
                f"horizon {share(-(longer_gain(step) or 0.0))}): it fits what sensor noise in the measured start "
                "states does"), **figures)
            continue
        added.append(step)
        record("greedy", f"{best.name} {'refined' if step.refines else 'added'}", _added_sentence(step, floor_mse, t),
               **figures, auto_min_explained=t.auto_min_explained, auto_min_removed=t.auto_min_removed,
               auto_min_longer=t.auto_min_longer, significance_z=t.significance_z,
               large_improvement=t.large_improvement)
        current, residual = step.after, step.judgement.residual_after
        if nothing_left(current, step.judgement.mse_after, first, start_mse, floor_mse, t=t):
            break
        if len(names(added)) < cfg.auto_max:
            if out_of_time(cfg, clock, f"ranking the candidates beside {' + '.join(names(added))} (and adding one)"):
                break
            with clock.stage(f"rank beside {' + '.join(names(added))}"):
                ranking, looked = rank(problem, current.model, cfg, judge_rows, residual, progress, t=t), False
                coarse = [n for n in names(added) if n not in kept_coarse
                          and held(current.model, n) == "shared" and cfg.finest != "shared"]
                if len(added) > 1 and coarse:  # fit them finer beside the effects added after them
                    ranking = finer_look(problem, current.model, cfg, judge_rows, residual, ranking,
                                         progress=progress, only=coarse, t=t)
    else:
        record("greedy", "stopped", f"stopped at the --auto-max bound ({cfg.auto_max} effects): no more were tried",
               auto_max=cfg.auto_max)
    return added, set_aside


def out_of_time(cfg: DiagnoseConfig, clock: StageClock | None, untried: str) -> bool:
    """Whether the search has run its ``cfg.auto_seconds`` (``--auto-seconds``) by ``clock`` (None:
    no clock, no bound); if so, records ``untried``, the step it does not start. A model wrong in many small ways (another model of
    the robot) or by structure outside the catalogue keeps every candidate promising, and the
    search would otherwise run for tens of minutes; the step already running ends, and the
    verdict is given on what was found."""
    if cfg.auto_seconds is None or clock is None or clock.elapsed() < cfg.auto_seconds:
        return False
    record("out_of_time", "left untried", (
        f"{untried} left untried: the search has run {clock.elapsed():.0f} s (--auto-seconds {cfg.auto_seconds:g})"),
        elapsed=clock.elapsed(), auto_seconds=cfg.auto_seconds)
    return True


def _added_sentence(step: Added, floor_mse: float, t: Thresholds = THRESHOLDS) -> str:
    """Why ``greedy`` added ``step``, with every threshold it passed."""
    j, longer = step.judgement, longer_gain(step)
    verb = f"refined ({step.refines} -> {step.fit.granularity})" if step.refines else f"added ({step.fit.granularity})"
    said = (f"{step.name} {verb}: explains {share(j.explained(floor_mse))} of the error above the noise floor "
            f"(at least {share(t.auto_min_explained)}), removes {share(j.removed)} of the one-step error (at least "
            f"{share(t.auto_min_removed)}, or {share(t.auto_min_longer)} of the longest-horizon error)")
    said += (f", z {j.z:.1f} (at least {t.significance_z:g})" if j.significant else
             f", significant by the longest horizon (at least {share(t.large_improvement)} of it removed)")
    if longer is not None:
        said += f", {step.before.check}-step open-loop error {-longer:+.0%}"
    return said


def _record_no_candidate(candidates: list[Candidate], open_: list[Candidate], floor_mse: float,
                         t: Thresholds = THRESHOLDS) -> None:
    """``greedy`` stops: no significant, plausible candidate is left that removes more than the noise."""
    if candidates:
        c = candidates[0]
        why = f"the best, {c.name}, {too_little(c.judgement, c.longer_gain, floor_mse, t=t)}"
    elif open_:
        c = open_[0]
        why = (f"the best, {c.name}, {doubt(c, t=t)}" if c.judgement.significant else
               f"the best, {c.name}, improves held-out predictions by {c.judgement.z:.1f} standard errors "
               f"(removes {share(c.judgement.removed)})")
    else:
        why = "every candidate is added or set aside"
    record("greedy", "stopped", f"stopped: no candidate left is significant, plausible and more than the noise: {why}",
           candidates_left=len(open_), significant_plausible=len(candidates))
