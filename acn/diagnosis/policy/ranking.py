"""Ranking the candidates: fit every catalogue effect beside the current model, judge it on
held-out rows, check the best at the longest horizon, and order them (the simpler, the longer
prediction, the finer look at joints apart).
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import replace

import numpy as np

from acn.diagnosis.decisions import record, share
from acn.diagnosis.fitting import (EffectFit, FreeParameters, finer_gains, fit_effect, multistep_refit, rank_rows,
                                   refittable, screen_rows)
from acn.diagnosis.granularity import GRANULARITIES
from acn.diagnosis.heldout import LongestHorizon, paired_z
from acn.diagnosis.policy.judging import (Plausibility, doubt, floor_says_noise, implausible, judge, one_step_only,
                                          plausibility, short_lived)
from acn.diagnosis.policy.thresholds import THRESHOLDS, Thresholds
from acn.diagnosis.problem import DiagnoseConfig, Problem
from acn.diagnosis.results import Candidate
from acn.diagnosis.traits import traits
from acn.sim.effects import Model, get_effect


def rank(problem: Problem, model: Model, cfg: DiagnoseConfig, judge_rows: np.ndarray, base_residual: np.ndarray,
         progress=None, t: Thresholds = THRESHOLDS) -> list[Candidate]:
    """Every candidate effect fitted on fit rows and judged on ``judge_rows``; best first.

    Each is fitted first on ``screen_rows`` (``cfg.screen_rows`` of the ranking's rows), the
    effects in the model held at their values, and judged on every judge row; the best of them
    (``promising``) are fitted again on all ``rank_rows`` from those values, without the scan for
    a start, with the few-parameter effects of the model refitted beside them (``refittable``).
    The others keep their screening fit, judged on the same held-out rows as the rest."""
    rows, few = rank_rows(problem, cfg), screen_rows(problem, cfg)
    screened = []
    for i, name in enumerate(cfg.candidates):
        if progress:
            progress(f"fitting {name}", i / len(cfg.candidates))
        fit = fit_effect(problem, model, get_effect(name), traits(name).granularity, few,
                         max_iter=cfg.rank_iterations)
        screened.append(candidate(problem, fit, judge_rows, base_residual, t=t))
    out, again = [], {id(c) for c in promising(screened, t=t)} if len(few) < len(rows) else set()
    for c in screened:
        if id(c) in again:
            fit = fit_effect(problem, model, c.fit.effect, c.fit.granularity, rows, start=c.fit.values,
                             max_iter=cfg.rank_iterations, refit=refittable(model), scan=False)
            c = candidate(problem, fit, judge_rows, base_residual, t=t)
        name, fit = c.name, c.fit
        if (traits(name).fit_over_steps and c.judgement.significant
                and plausibility(fit, t=t)[0] not in (Plausibility.PLAUSIBLE, Plausibility.TOO_SMALL)):
            ahead = over_steps_from_realistic(problem, model, fit, rows, t=t)
            c = c if ahead is fit else candidate(problem, ahead, judge_rows, base_residual, t=t)
        out.append(c)
    return order(problem, model, cfg, out, progress, t=t)


def promising(screened: list[Candidate], t: Thresholds = THRESHOLDS) -> list[Candidate]:
    """The candidates of a screening (``rank``) fitted again on all the ranking's rows: of the
    ``screen_keep`` best by score, those that remove ``screen_removed`` of the error."""
    return [c for c in sorted(screened, key=lambda c: -c.score)[:t.screen_keep]
            if c.judgement.removed >= t.screen_removed]


def over_steps_from_realistic(problem: Problem, model: Model, fit: EffectFit, rows: np.ndarray,
                              t: Thresholds = THRESHOLDS) -> EffectFit:
    """For an effect whose one-step fit the noise in the start states biases (``EffectTraits.fit_over_steps``:
    the payload) and came out implausible though significant: its fit over several steps
    (``fitting.multistep_refit``) started from the middle of its realistic range (signed
    parameters at nominal), where that is plausible; else ``fit``.

    The one-step fit of a payload can run into a corner where a light mass far from the trunk
    stands in for a heavy one near it. Measured on a pace log with a 3.58 kg payload and kp x
    0.727, on top of the PD gains: 0.68 kg 16 cm above the trunk (implausible, so the payload
    was never added); over five steps from 2.25 kg at the trunk's centre, 5.22 kg at 4 cm, first
    in the ranking, and 3.31 kg with kp x 0.722 once added and fitted with the gains (forward
    differences in the refit; with central ones, ``multistep_refit``, 3.15 kg with kp x 0.713).
    Started from the corner, the refit stays in it. Only for a significant fit: the refit costs a
    multi-step fit, and a fit that removes nothing has no corner worth leaving."""
    effect, refit = fit.effect, refittable(model)
    middle = {p.name: p.nominal if p.realistic_middle is None else p.realistic_middle for p in effect.parameters}
    start = fit_effect(problem, model, effect, fit.granularity, rows, start=middle, max_iter=0, refit=refit)
    ahead = multistep_refit(problem, start, rows, refit=refit)
    return ahead if ahead is not start and not implausible(ahead, t=t) else fit


def candidate(problem: Problem, fit: EffectFit, judge_rows: np.ndarray, base_residual: np.ndarray,
              t: Thresholds = THRESHOLDS) -> Candidate:
    j = judge(problem, fit.model, judge_rows, base_residual, t=t)
    return Candidate(fit, j, j.removed - t.price_per_parameter * len(fit.x))


def order(problem: Problem, model: Model, cfg: DiagnoseConfig, out: list[Candidate], progress=None,
          t: Thresholds = THRESHOLDS) -> list[Candidate]:
    """Candidates best first: by score, then checked at the longest horizon (module docstring)."""
    out = sorted(out, key=lambda c: (-c.score, len(c.fit.x)))
    if progress:
        progress("checking the best candidates at the longest horizon", None)
    horizon = LongestHorizon(problem, model, cfg)
    for _ in range(2):  # twice: the simpler candidate put in the best one's place is checked too
        out = screen(horizon, out, t=t)
        out = prefer_simpler(noise_fits_last(out, t=t), horizon, t=t)
    out = longer_gains(horizon, out, tied_with_best(out, t=t), t=t)
    out = prefer_longer(out, t=t)
    out = uneven(horizon, out, t=t)
    return noise_fits_last(out, t=t)  # those ``uneven`` found, too


def longer_gains(horizon: LongestHorizon, ranking: list[Candidate], which: list[Candidate],
                 until_one_passes: bool = False, t: Thresholds = THRESHOLDS) -> list[Candidate]:
    """``ranking`` with the ``longer_gain`` of the candidates ``which`` (of it) checked where it is
    not yet, in order: a new ``Candidate`` in each one's place, the others as they are (``ranking``
    itself with one-step horizons only); ``until_one_passes``: stop at the first that lowers the
    longest-horizon error. Each candidate is checked once: a rule that asks again reads it."""
    if horizon.steps <= 1:
        return ranking
    checked: dict[int, Candidate] = {}
    for c in which:
        if c.longer_gain is None:
            c = checked.setdefault(id(c), replace(c, longer_gain=horizon.gain(c.fit.model)))
            if why := one_step_only(c, t=t):
                beside = " + ".join(e.name for e in horizon.model.effects)
                ranked = f"{c.name} ranked last" + (f" beside {beside}" if beside else "")
                record("one_step_only", "ranked last", f"{ranked}: it {why}", effect=c.name, beside=beside,
                       longest_horizon_removed=c.longer_gain, horizon=horizon.steps,
                       reading_only=traits(c.name).reading_only, reading_tolerance=t.reading_tolerance)
        if until_one_passes and not one_step_only(c, t=t):
            break
    return [checked.get(id(c), c) for c in ranking]


def screen(horizon: LongestHorizon, ranking: list[Candidate], t: Thresholds = THRESHOLDS) -> list[Candidate]:
    """``ranking`` with the ``longer_gains`` of its significant candidates of plausible magnitude,
    in rank order, until one lowers the open-loop error at the longest horizon (at most ``screened``)."""
    plausible = [c for c in ranking if c.judgement.significant and not implausible(c.fit, t=t)]
    return longer_gains(horizon, ranking, plausible[:t.screened], until_one_passes=True, t=t)


def noise_fits_last(ranking: list[Candidate], t: Thresholds = THRESHOLDS) -> list[Candidate]:
    """``ranking`` with the candidates found fitting the noise (``one_step_only``) moved to the end, in order."""
    return sorted(ranking, key=lambda c: bool(one_step_only(c, t=t)))


def uneven(horizon: LongestHorizon, ranking: list[Candidate], t: Thresholds = THRESHOLDS) -> list[Candidate]:
    """``ranking``, where no plausible candidate is significant at one step, with the one that is
    significant by its longest-horizon gain in its place (a new ``Candidate``, ``Judgement.by_longest``):
    the plausible ones that remove at least ``min_improvement`` of the one-step error or improve
    it by ``significance_z`` standard errors, in rank order (at most ``screened``), are checked at
    the longest horizon; the one that removes the most of that error, if at least
    ``large_improvement``, is significant.

    An effect that acts on few steps is uneven at one step and shows over a long prediction:
    on a noisy log with a 20 N m torque limit, which the controller reached in 3.6 % of the
    physics steps, the fitted limit (19.8) removed 4.1 % of the held-out one-step error (z 1.3,
    not significant) and 48 % of the 25-step open-loop error. Fitting the noise in the start
    states does the opposite (it raises the long error: ``one_step_only``); on five noisy logs
    without an effect, no plausible candidate removed 2 % of the one-step error. On another log
    of the same limit (another seed) it did not fire, nor could it: its held-out episodes barely
    show the limit (the fit removes 0.3 % of the 25-step error there); on the first log, 90 % of
    the 48 % came from 5 of the 200 rollout starts, large events a rarely reached limit makes.

    A small effect can be clear at one step (by z) and still remove less than 2 % there (a draw
    under attitude feedback: a 0.97 kg payload beside an 11 ms delay; after the delay the payload
    removed 1.8 % of the one-step error at z 8.1 and 54 % of the 25-step error, motor strength
    1.4 % at z 5.6 and 49 %). Both are checked, and the one that removes the most is taken, not
    the first in rank order: a simpler effect standing in for a richer one ranks first by its
    price.

    A candidate significant at one step that was checked and removes less than
    ``min_improvement`` of the longest-horizon error does not stand in the way (a draw: floor
    friction 0.63 + a 2.2 kg payload on the pace; after the floor's friction, joint friction
    removed 3.4 % of the one-step error at z 6.4 and 0.2 % of the 25-step error, too little to
    add, while the payload, 3.0 % at z 2.99, removes 86 % of the 25-step error).
    """
    if horizon.steps <= 1 or any(c.judgement.significant and not doubt(c, t=t) and not short_lived(c, t=t)
                                 for c in ranking):
        return ranking
    checked = [i for i, c in enumerate(ranking) if not implausible(c.fit, t=t) and (
        c.judgement.removed >= t.min_improvement or c.judgement.z >= t.significance_z)][:t.screened]
    ranking = longer_gains(horizon, ranking, [ranking[i] for i in checked], t=t)  # each in its place
    pool = [ranking[i] for i in checked]
    best = max(pool, key=lambda c: c.longer_gain, default=None)
    if best is None or best.longer_gain < t.large_improvement:
        return ranking
    record("uneven", "significant", (
        f"{best.name} is significant by its {horizon.steps}-step prediction: it removes "
        f"{share(best.longer_gain)} of that open-loop error (at least {share(t.large_improvement)}), "
        f"at one step {share(best.judgement.removed)} (z {best.judgement.z:.1f}; at least "
        f"{share(t.min_improvement)} and z {t.significance_z:g} there)"),
        effect=best.name, longest_horizon_removed=best.longer_gain, large_improvement=t.large_improvement,
        removed=best.judgement.removed, z=best.judgement.z, min_improvement=t.min_improvement,
        significance_z=t.significance_z, horizon=horizon.steps)
    significant = replace(best, judgement=replace(best.judgement, significant=True, by_longest=True))
    return [significant if c is best else c for c in ranking]


def prefer_simpler(ranking: list[Candidate], horizon: LongestHorizon | None = None,
                   t: Thresholds = THRESHOLDS) -> list[Candidate]:
    """Put in the place of the best candidate not set aside (``doubt``) the simplest one it does
    not clearly beat.

    Some effects look alike in data (extra derivative gain and joint damping, strength and both
    gains scaled): the one with fewer parameters is the explanation unless the richer one
    predicts held-out rows significantly better (paired z >= 2, blocks of rows) AND by a margin
    (the simpler one removes less than 90 % of what it removes): with many rows, a richer
    effect also wins significantly by fitting the bias that sensor noise leaves in contacts.
    And (``horizon``) unless the richer one also lowers the open-loop error at the longest
    horizon more than the simpler one does: extra parameters that buy only one-step accuracy
    fit the noise in the measured start states (``one_step_only``). Measured on a log with joint
    damping 0.5 and twice the typical sensor noise: both PD gains (kp x1.06, kd x1.54) removed
    12.6 % of the one-step error, damping 11.1 % (88 % of it, z 19 vs 18 against the model
    without), but damping alone predicted 25 steps 18 % better.

    Close at one step (the 90 %) does not hand the place over where the richer one is
    significantly better there and also removes ``longer_margin`` more of the longest-horizon
    error (``longer_margin``). A draw of a 2.9 kg payload beside a 19 ms
    delay: after the delay, motor strength removed 92 % of what the payload removed at one step
    (z 4.0 between them), but the payload 75 % of the 25-step error against 70 %. Strength was
    added instead, and the payload never came back.
    """
    free = [c for c in ranking if not doubt(c, t=t)]
    if len(free) < 2 or not free[0].judgement.significant:
        return ranking
    best = free[0]
    for c in sorted(free[1:], key=lambda c: len(c.fit.x)):
        if len(c.fit.x) >= len(best.fit.x) or not c.judgement.significant:
            continue
        close = c.judgement.removed >= t.parsimony_share * best.judgement.removed
        z = paired_z(c.judgement.row_errors - best.judgement.row_errors)
        gives_way, margin = not better_at_one_step(best, c, t=t), None
        if not gives_way and horizon is not None and horizon.steps > 1:  # it predicts one step better: further?
            ranking = longer_gains(horizon, ranking, [x for x in ranking if x.fit is best.fit or x.fit is c.fit], t=t)
            best, c = (next(x for x in ranking if x.fit is y.fit) for y in (best, c))
            margin = best.longer_gain - c.longer_gain
        if not gives_way:
            gives_way = (margin is not None and margin <= 0.0) or (
                close and (margin is None or margin < t.longer_margin))
        if gives_way:
            out = [x for x in ranking if x is not c]
            out.insert(out.index(best), c)
            ahead = f"{c.name} ({len(c.fit.x)} parameters) goes before {best.name} ({len(best.fit.x)})"
            if margin is None:
                why = f"{best.name} predicts the held-out one step better by z {z:.1f} only (at least {t.parsimony_z:g})"
            elif margin <= 0.0:
                why = (f"{best.name} predicts one step better (z {z:.1f}) but removes no more of the longest-horizon "
                       f"error ({share(margin)} more)")
            else:
                why = (f"it removes {share(c.judgement.removed)} of the one-step error against {share(best.judgement.removed)} "
                       f"(close: at least {share(t.parsimony_share)} of it), and {best.name} removes only {share(margin)} "
                       f"more of the longest-horizon error (at least {share(t.longer_margin)} to keep its place)")
            record("prefer_simpler", f"{c.name} before {best.name}", f"{ahead}: {why}", simpler=c.name,
                   richer=best.name, simpler_removed=c.judgement.removed, richer_removed=best.judgement.removed,
                   z=z, parsimony_z=t.parsimony_z, parsimony_share=t.parsimony_share, longer_margin=margin,
                   least_longer_margin=t.longer_margin)
            return out
    return ranking


def tied_with_best(ranking: list[Candidate], t: Thresholds = THRESHOLDS) -> list[Candidate]:
    """The best candidate not set aside (``doubt``) and those ``tied_with`` it. [] if none.

    A fresh draw of a 1.8 kg payload beside a 14.9 N m torque limit: after the limit, the payload
    removed 2.9 % of the one-step error and motor strength 2.6 % (z 0.8 between them), the
    payload's three centre-of-mass coordinates put strength first, and strength was added (0.90)
    though the payload predicted 25 steps clearly better.
    """
    free = [c for c in ranking if not doubt(c, t=t)]
    if len(free) < 2 or not free[0].judgement.significant:
        return []
    ties = tied_with(free[0], ranking, t=t)
    return [free[0], *ties] if ties else []


def tied_with(best: Candidate, ranking: list[Candidate], t: Thresholds = THRESHOLDS) -> list[Candidate]:
    """The significant, plausible candidates of ``ranking`` (``best`` aside) the held-out one step
    does not put behind ``best`` (``one_step_tie``), in rank order."""
    return [c for c in ranking
            if c is not best and c.judgement.significant and not doubt(c, t=t) and one_step_tie(best, c, t=t)]


def one_step_tie(best: Candidate, c: Candidate, t: Thresholds = THRESHOLDS) -> bool:
    """Whether the held-out one step does not put ``c`` behind ``best`` (blocks of rows).

    Of no more parameters than ``best``: ``best`` does not predict significantly better (paired
    z < ``parsimony_z``). Of more: ``c`` removes at least as much of the one-step error and ranks
    behind only by the price of its parameters, unless it reproduces ``best`` (``Effect.reproduces``:
    both PD gains fit motor strength, and whatever else the PD's extra freedom absorbs)."""
    if len(c.fit.x) > len(best.fit.x):
        return c.judgement.removed >= best.judgement.removed and best.name not in c.fit.effect.reproduces
    return not better_at_one_step(best, c, t=t)


def better_at_one_step(a: Candidate, b: Candidate, t: Thresholds = THRESHOLDS) -> bool:
    """Whether ``a`` predicts the held-out one step significantly better than ``b`` (paired z of
    the rows' errors, blocks of rows, >= ``parsimony_z``)."""
    return paired_z(b.judgement.row_errors - a.judgement.row_errors) >= t.parsimony_z


def tied_either_way(best: Candidate, ranking: list[Candidate], t: Thresholds = THRESHOLDS) -> list[Candidate]:
    """The candidates of ``ranking`` ``tied_with`` ``best``, and those that score at least as high
    with which ``best`` would be tied were they first: what the held-out one step leaves open
    beside ``best``, for the report. A richer ``best`` that ``prefer_longer`` put before a simpler
    one it predicts one step significantly better than is tied from the simpler one's side only (a
    fresh draw of a 1.2 kg payload beside a 3 ms delay: motor strength first by price, the payload
    z 3.4 better at one step). Not a candidate of no more parameters that predicts one step
    significantly better than ``best``: it is ahead, not tied (``other_starts`` starts chains
    past it)."""
    def ahead(c: Candidate) -> bool:
        return len(c.fit.x) <= len(best.fit.x) and better_at_one_step(c, best, t=t)

    return [c for c in ranking if c is not best and c.judgement.significant and not doubt(c, t=t) and not ahead(c)
            and (one_step_tie(best, c, t=t) or (c.score >= best.score and one_step_tie(c, best, t=t)))]


def ties_of(added: Candidate, ranking: list[Candidate], t: Thresholds = THRESHOLDS) -> list[Candidate]:
    """``Added.ties`` of an effect added as the ranked candidate ``added``: it first, then those
    ``tied_either_way`` with it; [] if none."""
    rivals = tied_either_way(added, ranking, t=t)
    return [added, *rivals] if rivals else []


def prefer_longer(ranking: list[Candidate], t: Thresholds = THRESHOLDS) -> list[Candidate]:
    """Put in the place of the best candidate the one ``tied_with_best`` that removes at least
    ``longer_margin`` more of the open-loop error at the longest horizon (``longer_gain``, set
    by ``longer_gains``; the most, if several do).

    Where one step cannot tell two effects apart, the longer prediction can: the sensor noise in
    a measured start state enters the one step whole, a long prediction only at its start, while
    a physical effect acts at every step. On a noisy log with a 2 kg payload and joint damping
    0.4, after the payload, Coulomb friction predicted the held-out one step a little better
    than the hidden viscous damping (z 1.96 between them) and damping the 25 steps clearly
    better (it removed 71 % of that error, friction 61 %); on two more logs of the same
    effects, damping was first at both horizons.
    """
    ties = tied_with_best(ranking, t=t)
    if not ties or ties[0].longer_gain is None:
        return ranking
    best = ties[0]
    pick = max(ties[1:], key=lambda c: -np.inf if c.longer_gain is None else c.longer_gain)
    if pick.longer_gain is None or pick.longer_gain < best.longer_gain + t.longer_margin:
        return ranking
    out = [x for x in ranking if x is not pick]
    out.insert(out.index(best), pick)
    record("prefer_longer", f"{pick.name} before {best.name}", (
        f"{pick.name} goes before {best.name}: the held-out one step cannot tell them apart, and it removes "
        f"{share(pick.longer_gain)} of the longest-horizon open-loop error against {share(best.longer_gain)} "
        f"(at least {share(t.longer_margin)} more)"), first=pick.name, second=best.name,
        first_longer=pick.longer_gain, second_longer=best.longer_gain, longer_margin=t.longer_margin)
    return out


def needs_finer_look(ranking: list[Candidate], mse: float, floor_mse: float, t: Thresholds = THRESHOLDS) -> bool:
    """Whether the first ranking is looked at finer (``finer_look``): the model has an error, and no
    significant, plausible candidate explains ``effect_share`` of it above the floor. The finer look
    runs even where the floor calls the error noise (``finer_look``'s ``floor_says_noise``)."""
    return mse > 0 and not any(
        c.judgement.significant and not doubt(c, t=t) and c.judgement.explained(floor_mse) >= t.effect_share
        for c in ranking)


def finer_look(problem: Problem, model: Model, cfg: DiagnoseConfig, judge_rows: np.ndarray,
               base_residual: np.ndarray, ranking: list[Candidate], floor_says_noise: bool = False,
               progress=None, only: Collection[str] | None = None, t: Thresholds = THRESHOLDS) -> list[Candidate]:
    """``ranking`` with its per-joint candidates fitted again per joint type, per leg or per
    joint (``finer``; at most ``finer_keep`` fits, each at the granularity that promises most:
    ``promised``), for where no significant, plausible candidate explains most of the error
    above the floor (``pipeline.diagnose``). An effect that differs joint by joint can cancel in
    one shared value: one motor at half strength (FR_calf) was a strength of 0.915 on every
    joint, z 2.4, and the verdict was unexplained. Per leg it is diluted over three joints (0.66
    -0.73 for the FR leg, z 2.2-3.0 on four short logs), per joint it is 0.51-0.53 (z 3.2-4.9).
    A finer fit replaces the shared one where it is significant, plausible, and scores higher
    (its price per parameter included); the ranking is then ordered again.

    ``floor_says_noise`` (under ``structured_share`` of the error above the noise floor): the
    floor's library is linear with a term per joint type, and one weak motor acts in its leg's
    stance only (the true strengths removed 30-40 % of a short noisy log's error where the floor
    called 4-7 % of it structured), so the finer look runs there too, but a finer fit must show
    the structure itself and remove ``structured_share`` of the error (on a pace log whose robot
    lies on its back, no effect hidden, hip damping per joint type removed 2.9 %, z 8: the
    sensor noise in the start states). It is fitted per joint only there: what a per-type
    library misses differs leg by leg or joint by joint, 12 values fit a leg too, and
    ``choose_fit`` then takes the coarsest granularity that holds (a nominal log's
    diagnosis: 56 s, against 86 s with all three granularities and 25 s without the look).

    ``only``: the candidates looked at (``greedy``: the effects it added, beside those added
    after them). No granularity finer than ``cfg.finest`` is fitted (``--finest``)."""
    shared = [c for c in ranking if c.fit.granularity == "shared" and (only is None or c.name in only)
              and any(p.per_joint for p in c.fit.effect.parameters)]
    rows, few = rank_rows(problem, cfg), screen_rows(problem, cfg)
    granularities, least_removed = (("joint",), t.structured_share) if floor_says_noise else (t.finer, 0.0)
    granularities = tuple(g for g in granularities if GRANULARITIES.index(g) <= GRANULARITIES.index(cfg.finest))
    if not granularities:
        return ranking
    out, changed = list(ranking), False
    for c, g in promised(problem, shared, few, granularities, max(t.finer_screen, least_removed / 2), t=t):
        if progress:
            progress(f"fitting {c.name} per {g}", None)
        fit = fit_effect(problem, model, c.fit.effect, g, rows, start=c.fit.values, max_iter=cfg.rank_iterations,
                         refit=refittable(model))
        new = candidate(problem, fit, judge_rows, base_residual, t=t)
        if (new.judgement.significant and not implausible(fit, t=t) and new.score > c.score
                and new.judgement.removed >= least_removed):
            out[out.index(c)], changed = new, True
            record("finer_look", f"{c.name} per {g}", (
                f"{c.name} fitted per {g} in place of one value for every joint: it removes "
                f"{share(new.judgement.removed)} of the one-step error (z {new.judgement.z:.1f}) against "
                f"{share(c.judgement.removed)}, and scores {new.score:.3f} against {c.score:.3f} "
                f"({t.price_per_parameter:g} per parameter)"), effect=c.name, granularity=g,
                removed=new.judgement.removed, shared_removed=c.judgement.removed, z=new.judgement.z,
                score=new.score, shared_score=c.score, price_per_parameter=t.price_per_parameter,
                least_removed=least_removed)
    return order(problem, model, cfg, out, progress, t=t) if changed else ranking


def promised(problem: Problem, shared: list[Candidate], rows: np.ndarray, granularities: tuple[str, ...], least: float,
             t: Thresholds = THRESHOLDS) -> list[tuple[Candidate, str]]:
    """The finer fits ``finer_look`` makes: for each of the ``shared`` candidates, the granularity
    whose one-step promise (``fitting.finer_gains`` on ``rows``: the share of its error one
    Gauss-Newton step removes) is at least ``least`` and whose promised score, its price per
    parameter included, beats the candidate's by most; of those, the ``finer_keep`` that promise
    the highest score. The rest are not fitted: under structure no effect describes, every
    per-joint effect promises something at every granularity (joint springs: 21 fits, a third of
    that log's diagnosis)."""
    offers = []
    for c in shared:
        promise = finer_gains(problem, c.fit, rows, granularities)
        scores = {g: c.judgement.removed + promise[g] * (1.0 - c.judgement.removed)
                  - t.price_per_parameter * len(FreeParameters(c.fit.effect, g, c.fit.values).names)
                  for g in granularities if promise[g] >= least}
        if scores and max(scores.values()) > c.score:
            g = max(scores, key=scores.get)
            offers.append((scores[g], c, g))
    offers.sort(key=lambda o: -o[0])
    return [(c, g) for _, c, g in offers[:t.finer_keep]]
