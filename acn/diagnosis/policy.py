"""The selection: which candidate effects to rank first, which to add, when to stop, which verdict.

Every rule the diagnosis chooses by lives here, and every threshold of those rules is a field of
``Thresholds`` (the defaults: ``THRESHOLDS``), handed to each rule as ``t``. The engine below it
fits an effect (``fitting``), re-simulates and judges a model on held-out rows (``heldout``,
``compare``) and knows nothing of how candidates are chosen; what the diagnosis knows of each
effect beyond its physics is ``traits``. ``pipeline`` runs the stages in order.

Ranking: for every catalogue effect, fit its parameters (``fitting``) on a sample of fit rows,
at its first granularity (``EffectTraits.granularity``), added to the current model; then
re-simulate held-out "judge" rows with and without it. A candidate's evidence:

- ``explained``: the share of the STRUCTURED error (error minus the noise floor) it removes,
  0..1, on held-out rows (``Judgement.explained``, once the floor is known);
- ``significant``: the held-out improvement is at least 2 % of the error and either larger
  than 3 standard errors of its row-to-row variation (blocks of consecutive rows, so correlated
  rows do not count twice) or a quarter of the whole error (an effect such as a torque limit
  acts on few rows: its improvement is large but uneven; fitting noise never removes that much
  on held-out rows); where no plausible candidate is, the best plausible ones that remove at
  least 2 % or improve by 3 standard errors are checked at the longest horizon too, and the one
  that removes most of that error, if a quarter, is significant (``uneven``: a torque limit
  reached in 4 % of the steps);
- ``score``: the share of the whole held-out error it removes, minus a small price per fitted
  parameter (ties go to the simpler effect); it orders candidates as ``explained`` does, and
  still orders them when the error is all noise;
- an effect whose one-step fit the start states' noise biases (the payload) and whose fit is
  significant but implausible (a light mass in a far corner) is fitted again over several
  steps from its realistic middle (``over_steps_from_realistic``);
- ``finer_look``: where no significant, plausible candidate explains most of the error above
  the floor, the per-joint candidates fitted again per joint type, per leg and per joint (one
  weak motor cancels in a strength shared by every joint);
- ``longer_gain`` (``screen``): how much it lowers the open-loop error at the longest horizon;
  candidates that do not lower it are ranked after the others, and where the one step cannot
  tell the best candidate from another (``tied_with_best``), the one that lowers it clearly
  more goes first (``prefer_longer``).
  A missing physical effect makes long predictions wrong too; an effect that improves the one
  step from the MEASURED start state but not the long prediction is fitting what the sensor
  noise in that start state does: contacts are one-sided, so noisy joint readings press the
  feet into the ground on average, and a dozen encoder offsets, armature or damping soak that
  bias up (measured on a 100 Hz log with sensor noise and no effect at all: encoder offsets of up
  to 0.017 rad removed 30 % of the one-step error and raised the 25-step error 13 %).

Adding: ``add_effect`` fits the effect at the granularity the data support (shared by all
joints, per joint type, per leg, per joint: a finer one must beat the coarser one significantly
on held-out rows), refits on more rows (``fitting.final_fit``), and compares the model before
and after at every horizon. ``auto`` repeats rank -> add while the best plausible candidate's
held-out improvement is larger than the noise (significant, ``judge``, or at the longest
horizon: ``uneven``) and removes at least 5 % of the error: after the right effects, a noisy
log still lets armature or damping fit a few per cent of the contact bias that noise in joint
readings leaves. An effect whose final fit lowers the one-step error but not the open-loop
error at the longest horizon is not added (``one_step_only``), nor one whose final fit (on more
rows, at the granularity chosen) is no longer significant or turns implausible
(``implausible``): it is set aside with the reason, and the next candidate is tried. Then
``revisit`` judges each added effect again beside the others (a simpler effect takes a richer
one's place where the chain then predicts no horizon worse; one no longer significant is left
out where the chain then predicts as well), and ``other_starts`` runs the same greedy chain
from the next-best first candidates, keeping one that predicts clearly better.
``refine_chain`` refines the fit of the effects that move the start state (encoder offsets)
with central differences (``fitting`` module docstring), where that predicts the held-out rows
no worse: on each chain before ``other_starts`` compares them, and on the effects chosen.

The noise floor is what ridge regressions on a library of state and action terms cannot
predict (``noise``) of the model's held-out residual, or of what the best candidates leave,
whichever is lower: after the right effect only noise is left (``floor_after``). It is raised by
what candidates that fit the noise remove (``noise_fitted``).

Verdict (``verdict``):
- ``effect``: a candidate (the best one whose held-out improvement is significant and whose
  magnitude is plausible: ``implausible``; with ``--auto``, one it added: a candidate its chain
  declined as too little is not named) explains at least 70 % of the error above the
  noise floor; with ``--auto``, or the effects added one after the other do, or the model with
  them matches within the noise by the rule that gives ``none`` (less than 15 % of its error
  structured; also where the error was mostly noise before: a small effect under sensor noise,
  which ``--auto`` adds only where it lowers the longest-horizon error too);
- ``unexplained``: otherwise, when at least 15 % of the error is structured (above the floor);
- ``none``: the model matches within the noise: the error is zero, or less structured than
  that and no plausible candidate explains it.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, replace
from enum import Enum

import numpy as np

from acn.diagnosis import heldout
from acn.diagnosis.clock import StageClock
from acn.diagnosis.compare import Comparison, compare, floor_of
from acn.diagnosis.decisions import record, share, within
from acn.diagnosis.fitting import (EffectFit, FreeParameters, final_fit, final_rows, finer_gains, fit_effect,
                                   multistep_refit, rank_rows, refittable, screen_rows)
from acn.diagnosis.granularity import GRANULARITIES, finer
from acn.diagnosis.halves import HalfFits, chi2_quantile
from acn.diagnosis.heldout import (Judgement, LongestHorizon, explained_share, longest_removed, paired_z,
                                   removed_at, structured_share)
from acn.diagnosis.problem import DiagnoseConfig, Problem
from acn.diagnosis.results import Added, Candidate, Chain, held, longer_gain, names
from acn.diagnosis.traits import traits
from acn.sim.effects import Effect, Model, Parameter, get_effect


@dataclass(frozen=True)
class Thresholds:
    """Every threshold of the selection, each with what it guards against (the figures that set
    them are in the docstrings of the rules that read them)."""

    # judging a candidate on held-out rows
    min_improvement: float = 0.02     # of the one-step error (MSE): a gain as small as what fitting noise removes
    significance_z: float = 3.0       # paired z of a gain (blocks of rows): row-to-row chance passing for an effect
    large_improvement: float = 0.25   # of the error: significant however uneven (an effect acting on few rows,
    # a torque limit), since fitting noise never removes that much held out
    price_per_parameter: float = 0.003  # explained share each free parameter must earn: a richer effect winning
    # by its extra freedom alone
    # plausibility of a fitted value
    at_bound_share: float = 0.01      # of a parameter's range: a value this near a bound stands in for another effect
    largest_factor: float = 2.0       # x the largest realistic magnitude: a value beyond stands in for another
    # effect (joint springs fitted as damping 2.5 N m s/rad)
    smallest_share: float = 0.75      # of the smallest realistic magnitude: a value below fits noise or another
    # effect's leftovers
    unidentified_share: float = 0.5   # x the largest realistic magnitude: a standard error above reports a
    # parameter as pinned down that the data do not pin down
    # the noise floor
    structured_share: float = 0.15    # of the error above the noise floor before an effect is missing: naming
    # an effect for sensor noise
    floor_candidates: int = 2         # best candidates whose leftover also bounds the floor: a floor the model's
    # own residual overstates (after the right effect only noise is left)
    # the open-loop check at the longest horizon
    screened: int = 3                 # plausible candidates checked there at most: a long re-simulation for each
    reading_tolerance: float = 0.05   # of that error a reading-only effect may add: setting aside a frame that a
    # long prediction forgets
    longer_margin: float = 0.05       # of that error a candidate must remove more to overrule the one step:
    # reordering on a difference within the noise
    # the ranking's screen on fewer rows (``rank``)
    screen_keep: int = 4              # best candidates by score fitted again on all rows: more than every later
    # stage looks at (``screened`` at the longest horizon, ``floor_candidates``, the first other start) ...
    screen_removed: float = 0.01      # ... of those, the ones removing this share of the error on the screen:
    # half of ``min_improvement``, as a fit on fewer rows removes less held out than one on more
    # look-alike candidates
    parsimony_z: float = 2.0          # paired z a richer candidate must beat a simpler one by: a richer effect
    # winning by fitting the contact bias sensor noise leaves
    parsimony_share: float = 0.9      # of the richer one's removal the simpler one must reach to be close: a
    # richer effect ranked first for a gain the simpler one nearly matches
    finer: tuple[str, ...] = ("type", "leg", "joint")  # granularities the finer look fits: one weak motor
    # cancelling in a value shared by every joint
    finer_keep: int = 3               # finer fits the finer look makes at most, those promising the highest score
    finer_screen: float = 0.01        # of the fit rows' error one Gauss-Newton step at a finer granularity must
    # promise before that granularity is fitted (``fitting.finer_gains``): half of ``min_improvement``, as the
    # in-sample linear promise of a finer fit that holds out overstates what it removes held out
    # adding (--auto)
    auto_min_explained: float = 0.05  # of the structured error left: adding what noise-fitting effects manage
    auto_min_removed: float = 0.05    # of the one-step error: the same, measured on the whole error ...
    auto_min_longer: float = 0.05     # ... unless it lowers the longest-horizon error this much: missing a second,
    # smaller effect that sensor noise hides at one step
    shortlist: int = 5                # candidates an alternative chain re-ranks: re-ranking the catalogue per chain
    auto_min_share: float = 0.05      # of the structured error of the model --auto starts from, an added effect
    # explains held out (or of its longest-horizon open-loop error, removes): 2.5 x ``min_improvement``, what
    # fitting noise removes, so that an effect fitted to the last per cent a first effect leaves is not added
    halves_z: float = 3.09            # normal quantile of the chi^2 test that an added effect's fits on two halves of
    # the episodes agree (0.999): effects that paper over structure the catalogue lacks named as the answer
    nominal_z: float = 2.0            # standard errors within which every fitted value lies at nominal: the data
    # cannot tell the effect from its absence
    # the verdict
    exact: float = 1e-3               # headline error under which a model reproduces the data: naming float32
    # storage's rounding (~1e-6)
    effect_share: float = 0.7         # of the structured error an effect must explain to be named: naming a
    # part of the gap as all of it


THRESHOLDS = Thresholds()


# ----- judging a candidate ----------------------------------------------------------------------
def significant_gain(gain: float, z: float, t: Thresholds = THRESHOLDS) -> bool:
    """Whether a held-out improvement of ``gain`` (share of the error) at paired ``z`` is significant:
    at least ``min_improvement``, and ``significance_z`` standard errors or ``large_improvement``."""
    return bool(gain >= t.min_improvement and (z >= t.significance_z or gain >= t.large_improvement))


def judgement(before_residual: np.ndarray, after_residual: np.ndarray, reference_mse: float | None = None,
              t: Thresholds = THRESHOLDS) -> Judgement:
    """The residuals ``after_residual`` (N, C) against ``before_residual`` on the same rows
    (``heldout.judgement``), significant by ``significant_gain``."""
    return heldout.judgement(before_residual, after_residual, lambda gain, z: significant_gain(gain, z, t),
                             reference_mse)


def judge(problem: Problem, after: Model, rows: np.ndarray, before_residual: np.ndarray,
          reference_mse: float | None = None, t: Thresholds = THRESHOLDS) -> Judgement:
    """``after`` against the residuals ``before_residual`` of the current model on ``rows``.

    ``reference_mse``: the error the ``min_improvement`` and ``large_improvement`` thresholds
    refer to (default: the current one; a finer granularity of the same effect must improve on
    the error before the effect).
    """
    return heldout.judge(problem, after, rows, before_residual, lambda gain, z: significant_gain(gain, z, t),
                         reference_mse)


# ----- plausibility of a fitted value -------------------------------------------------------
def at_bound(fit: EffectFit, t: Thresholds = THRESHOLDS) -> list[str]:
    """Parameters pushed against a bound that is not their nominal value (within ``at_bound_share`` of
    their range)."""
    out = []
    for p in fit.effect.parameters:
        v = np.atleast_1d(np.asarray(fit.values[p.name], float))
        span = p.upper - p.lower
        if any(bound != p.nominal and np.any(np.abs(v - bound) <= t.at_bound_share * span)
               for bound in (p.lower, p.upper)):
            out.append(p.name)
    return out


def _realistic_magnitudes(p: Parameter) -> tuple[float, float]:
    """(smallest, largest) realistic distance from nominal of a parameter with a realistic range."""
    return p.realistic if p.signed else tuple(sorted(abs(x - p.nominal) for x in p.realistic))


def _magnitudes(fit: EffectFit) -> list[tuple[str, float, float, float]]:
    """(name, largest |fitted - nominal|, smallest and largest realistic magnitude) per parameter
    with a realistic range."""
    out = []
    for p in fit.effect.parameters:
        if p.realistic is None:
            continue
        v = np.atleast_1d(np.asarray(fit.values[p.name], float))
        nominal = np.atleast_1d(np.asarray(fit.nominal[p.name], float))
        out.append((p.name, float(np.abs(v - nominal).max()), *_realistic_magnitudes(p)))
    return out


def unidentified(fit: EffectFit, t: Thresholds = THRESHOLDS) -> list[str]:
    """Free parameters these data do not pin down: a standard error above half the largest
    realistic magnitude, so the 95 % interval reaches from nominal to beyond a realistic value
    (e.g. the encoder offsets of a leg that is in the air most of the time: in the air an offset
    moves the reading and the leg together, only the trunk sees it)."""
    largest = {p.name: _realistic_magnitudes(p)[1] for p in fit.effect.parameters if p.realistic is not None}
    return [n for n, e in zip(fit.names, fit.stderr)
            if n.split("[")[0] in largest and not e <= t.unidentified_share * largest[n.split("[")[0]]]


def too_small(fit: EffectFit, t: Thresholds = THRESHOLDS) -> bool:
    """Every parameter closer to its nominal value than 3/4 of the smallest realistic magnitude."""
    sizes = _magnitudes(fit)
    return bool(sizes) and all(dev < t.smallest_share * smallest for _, dev, smallest, _ in sizes)


def too_large(fit: EffectFit, t: Thresholds = THRESHOLDS) -> list[str]:
    """Parameters further from nominal than ``largest_factor`` x the largest realistic magnitude."""
    return [name for name, dev, _, largest in _magnitudes(fit) if dev > t.largest_factor * largest]


class Plausibility(Enum):
    """What a fitted value's size says (``plausibility``)."""

    PLAUSIBLE = "plausible"
    CONTRADICTED = "contradicted by the measurements"  # ``EffectTraits.check``
    AT_BOUND = "at a bound"                            # ``at_bound``
    TOO_LARGE = "too large"                            # ``too_large``
    TOO_SMALL = "too small"                            # ``too_small``


def plausibility(fit: EffectFit, t: Thresholds = THRESHOLDS) -> tuple[Plausibility, str]:
    """Whether a fitted effect can be the explanation, and why not in words ("" where it can): a
    value pushed against a bound, or more than twice the largest magnitude real robots show,
    stands in for something else (joint springs fit as damping 2.5 N m s/rad or a derivative gain
    x 2.8); one below 3/4 of the smallest realistic magnitude is fitting noise or another effect's
    leftovers (sensor noise in joint readings biases the contact forces a re-simulation starts
    with, and encoder offsets of a few mrad fit that). Values the measurements contradict without
    simulation (``EffectTraits.check``: a measured frame that lifts the stance feet off the ground)
    stand in for something else too."""
    if fit.contradicted:
        return Plausibility.CONTRADICTED, fit.contradicted
    stuck = at_bound(fit, t=t)
    if stuck:
        return Plausibility.AT_BOUND, f"needs {', '.join(stuck)} at the bound of its range"
    large = too_large(fit, t=t)
    if large:
        return Plausibility.TOO_LARGE, \
            f"needs {', '.join(large)} beyond {t.largest_factor:g}x the largest realistic magnitude"
    if too_small(fit, t=t):
        return Plausibility.TOO_SMALL, \
            f"fits a value below {t.smallest_share:.0%} of the smallest realistic magnitude"
    return Plausibility.PLAUSIBLE, ""


def implausible(fit: EffectFit, t: Thresholds = THRESHOLDS) -> str:
    """Why a fitted effect cannot be the explanation ("" if it can): ``plausibility``'s words."""
    return plausibility(fit, t=t)[1]


# ----- fitting the noise --------------------------------------------------------------------
def fits_noise(longer_gain: float | None, effect: Effect | None = None, t: Thresholds = THRESHOLDS) -> bool:
    """Whether an effect with this share of the longest-horizon open-loop error removed (None:
    not checked) fits the noise in the measured start states: it does not lower that error.

    An effect on the reading only (``EffectTraits.reading_only``: the frame the trunk is measured in)
    acts on a prediction through its start state and its reading; the physics in between is the
    same, and a long prediction forgets its start. So it need not lower the longest-horizon
    error, only not raise it by more than ``reading_tolerance``; what guards it against fitting
    noise is ``too_small`` (a frame within 3/4 of the smallest realistic offset is set aside)."""
    if longer_gain is None:
        return False
    if effect is not None and traits(effect.name).reading_only:
        return longer_gain < -t.reading_tolerance
    return longer_gain <= 0


def one_step_only(c: Candidate, t: Thresholds = THRESHOLDS) -> str:
    """Why ``c`` is fitting the noise in the measured start states ("" if it is not, or unchecked)."""
    if not fits_noise(c.longer_gain, c.fit.effect, t=t):
        return ""
    return (f"improves the one-step prediction only (open-loop error at the longest horizon {-c.longer_gain:+.0%}): "
            "it fits what sensor noise in the measured start states does")


def doubt(c: Candidate, t: Thresholds = THRESHOLDS) -> str:
    """Why a candidate cannot be the explanation ("" if it can): ``implausible`` or ``one_step_only``."""
    return implausible(c.fit, t=t) or one_step_only(c, t=t)


def fits_noise_by_size(c: Candidate, t: Thresholds = THRESHOLDS) -> bool:
    """Whether ``c`` is significant and set aside only for its size (``Plausibility.TOO_SMALL``:
    not contradicted, not at a bound, not too large): it fits noise or another effect's
    leftovers, and ``noise_fitted`` counts what it removes as noise."""
    return c.judgement.significant and plausibility(c.fit, t=t)[0] is Plausibility.TOO_SMALL


def short_lived(c: Candidate, t: Thresholds = THRESHOLDS) -> bool:
    """Whether ``c`` was checked at the longest horizon and removes less than ``min_improvement``
    of that error (it may still lower it: not ``one_step_only``)."""
    return c.longer_gain is not None and c.longer_gain < t.min_improvement


def floor_says_noise(mse: float, floor_mse: float, t: Thresholds = THRESHOLDS) -> bool:
    """Whether less than ``structured_share`` of the error ``mse`` lies above the noise floor."""
    return structured_share(mse, floor_mse) < t.structured_share


def noise_fitted(floor: np.ndarray, residual: np.ndarray, ranking: list[Candidate],
                 t: Thresholds = THRESHOLDS) -> np.ndarray:
    """The floor (C,) raised by what a candidate that fits the noise removes per channel: one
    that improves the one step only (``one_step_only``), or a significant one set aside only
    for a value below 3/4 of the smallest realistic magnitude (``fits_noise_by_size``: a 2 mm
    trunk frame where the trunk lies on the floor and the noise in its measured height decides
    how deep it starts).
    That part of the error is caused by the sensor noise in the start states too, though the
    library regressions predict it (it depends on the true state).

    Only what it removes beyond the best candidate that can be the explanation (significant,
    ``doubt`` empty) counts: a dozen encoder offsets also soak up a real error of the start
    states (a trunk measured in another frame), which is not noise. Of the candidates that fit
    noise, the one with the largest such excess sets the floor, so one more of them never
    lowers it."""
    fits = [c for c in ranking if one_step_only(c, t=t) or fits_noise_by_size(c, t=t)]
    if not fits:
        return floor
    before = np.mean(residual ** 2, axis=0)

    def removed(c: Candidate) -> np.ndarray:
        return np.clip(before - np.mean(c.judgement.residual_after ** 2, axis=0), 0.0, None)

    real = [removed(c) for c in ranking if c.judgement.significant and not doubt(c, t=t)]
    best = max(real, key=np.sum) if real else 0.0
    noise = max((np.clip(removed(c) - best, 0.0, None) for c in fits), key=np.sum)
    return np.minimum(before, floor + noise)


def floor_after(problem: Problem, model_floor: np.ndarray, judge_rows: np.ndarray, residual: np.ndarray,
                ranking: list[Candidate], t: Thresholds = THRESHOLDS) -> np.ndarray:
    """The noise floor (C,) beside ``ranking``: what no regression on the state and actions
    predicts (``compare.floor_of``) of the model's residual (its floor ``model_floor``) or of what
    the ``floor_candidates`` best significant candidates leave, whichever is lower (after the right
    effect only noise is left); raised by what candidates that fit the noise remove (``noise_fitted``)."""
    floors = [model_floor] + [
        floor_of(problem, c.fit.model, judge_rows, c.judgement.residual_after)
        for c in ranking[:t.floor_candidates] if c.judgement.significant and not one_step_only(c, t=t)]
    return noise_fitted(min(floors, key=lambda f: float(np.mean(f))), residual, ranking, t=t)


# ----- ranking ------------------------------------------------------------------------------
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
        screen(horizon, out, t=t)
        out = prefer_simpler(noise_fits_last(out, t=t), horizon, t=t)
    longer_gains(horizon, tied_with_best(out, t=t), t=t)
    out = prefer_longer(out, t=t)
    out = uneven(horizon, out, t=t)
    return noise_fits_last(out, t=t)  # those ``uneven`` found, too


def longer_gains(horizon: LongestHorizon, candidates: list[Candidate], until_one_passes: bool = False,
                 t: Thresholds = THRESHOLDS) -> None:
    """Set ``longer_gain`` of ``candidates`` where it is not set, in order (nothing with one-step
    horizons only); ``until_one_passes``: stop at the first that lowers the longest-horizon error."""
    if horizon.steps <= 1:
        return
    for c in candidates:
        if c.longer_gain is None:
            c.longer_gain = horizon.gain(c.fit.model)
            if why := one_step_only(c, t=t):
                beside = " + ".join(e.name for e in horizon.model.effects)
                ranked = f"{c.name} ranked last" + (f" beside {beside}" if beside else "")
                record("one_step_only", "ranked last", f"{ranked}: it {why}", effect=c.name, beside=beside,
                       longest_horizon_removed=c.longer_gain, horizon=horizon.steps,
                       reading_only=traits(c.name).reading_only, reading_tolerance=t.reading_tolerance)
        if until_one_passes and not one_step_only(c, t=t):
            break


def screen(horizon: LongestHorizon, ranking: list[Candidate], t: Thresholds = THRESHOLDS) -> None:
    """``longer_gains`` of the significant candidates of plausible magnitude, in rank order,
    until one lowers the open-loop error at the longest horizon (at most ``screened``)."""
    plausible = [c for c in ranking if c.judgement.significant and not implausible(c.fit, t=t)]
    longer_gains(horizon, plausible[:t.screened], until_one_passes=True, t=t)


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
    pool = [c for c in ranking if not implausible(c.fit, t=t) and (
        c.judgement.removed >= t.min_improvement or c.judgement.z >= t.significance_z)][:t.screened]
    longer_gains(horizon, pool, t=t)
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
        if not gives_way:  # the richer one predicts one step significantly better: and further?
            margin = longer_margin(horizon, best, c, t=t)
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


def longer_margin(horizon: LongestHorizon | None, richer: Candidate, simpler: Candidate,
                  t: Thresholds = THRESHOLDS) -> float | None:
    """How much more of the open-loop error at the longest horizon ``richer`` removes than
    ``simpler`` (share of that error; None with one-step horizons only)."""
    if horizon is None or horizon.steps <= 1:
        return None
    longer_gains(horizon, [richer, simpler], t=t)
    return richer.longer_gain - simpler.longer_gain


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


# ----- adding an effect ---------------------------------------------------------------------
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


def significant(step: Added, t: Thresholds = THRESHOLDS) -> bool:
    """Whether the added effect's final fit is significant as ``rank`` judges a candidate: at one
    step (``judge``) or by removing ``large_improvement`` of the longest-horizon open-loop
    error (``uneven``)."""
    return step.judgement.significant or (longer_gain(step) or 0.0) >= t.large_improvement


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


def unneeded(step: Added, start: Comparison, start_mse: float, floor_mse: float, t: Thresholds = THRESHOLDS) -> str:
    """Why the data do not need ``step``'s effect ("" where they do): every value it fits lies at
    nominal within ``nominal_z`` standard errors, or it explains under ``auto_min_share`` of the
    structured error of the model --auto started from (``start``, whose held-out one-step error is
    ``start_mse``) and removes under ``auto_min_share`` of that model's open-loop error at the
    longest horizon.

    ``too_little`` judges a step against what the effects before it left; once one effect has
    explained a noise-free log to its last per cent, any flexible effect explains a share of
    that rest (a payload of 0 kg, its centre of mass 5 mm off, beside a joint damping that
    explained the rest). Against the error the diagnosis started from, such a step is nothing."""
    f = step.fit
    own = len(FreeParameters(f.effect, f.granularity, f.values).names)
    nominal = FreeParameters(f.effect, f.granularity, f.nominal).vector(f.nominal)
    off = np.abs(f.x[:own] - nominal) / np.maximum(f.stderr[:own], 1e-12)
    if np.all(off <= t.nominal_z):
        return f"its fitted values lie at nominal within {t.nominal_z:g} standard errors"
    share = (step.judgement.mse_before - step.judgement.mse_after) / (start_mse - floor_mse) \
        if start_mse > floor_mse else 0.0
    longer = removed_at(start, step.after, start.check) - removed_at(start, step.before, start.check) \
        if start.check > 1 else 0.0
    if share < t.auto_min_share and longer < t.auto_min_share:
        return (f"it explains only {max(share, 0):.1%} of the error above the noise floor the diagnosis started from "
                f"and removes {max(longer, 0):.1%} of its {start.check}-step open-loop error")
    return ""


def nothing_left(current: Comparison, mse: float, start: Comparison, start_mse: float, floor_mse: float,
                 t: Thresholds = THRESHOLDS, then: str = "stopped") -> bool:
    """Whether no effect added beside ``current`` (held-out one-step error ``mse``) can pass
    ``unneeded`` any more: all of what is left, noise included, is under ``auto_min_share`` of
    the structured error ``start`` had (one-step error ``start_mse``), and of its open-loop error
    at the longest horizon. --auto stops there: no ranking, finer look or other start (``then``:
    what the decision recorded says it does)."""
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


# ----- --auto: chains of added effects ------------------------------------------------------
def auto(problem: Problem, first: Comparison, cfg: DiagnoseConfig, judge_rows: np.ndarray, base_residual: np.ndarray,
         floor_mse: float, ranking: list[Candidate], progress=None, t: Thresholds = THRESHOLDS,
         clock: StageClock | None = None) -> tuple[list[Added], list[Chain], dict[str, str]]:
    """``greedy`` then ``revisit``, from the best candidate and (``other_starts``) from the next
    ``cfg.auto_alternatives`` ones; the added effects of the chain kept, every chain tried, and the
    candidates the first chain set aside on their final fit (name -> why).

    The other starts are tried whatever the chain leaves: once one effect has stood in for two,
    the one-step error can sit at the noise floor (nothing left to rank) while the open-loop
    error is still three times what the right pair leaves (payload + damping below)."""
    clock = clock or StageClock()
    steps, set_aside = greedy(problem, first, cfg, judge_rows, base_residual, floor_mse, ranking, progress, t=t,
                              clock=clock)
    with clock.stage("revisit"):
        chain = revisit(problem, first, cfg, judge_rows, base_residual, steps, progress, t=t)
    with clock.stage("other starts"):
        return (*other_starts(problem, first, cfg, judge_rows, base_residual, floor_mse, ranking, chain, progress, t=t),
                set_aside)


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
        if progress:
            progress(f"adding {best.name}", None)
        with clock.stage(f"add {best.name}"):
            step = add_effect(problem, current.model, best.name, cfg, judge_rows, residual, current, start=best.fit,
                              t=t)
        step.ties = ties_of(best, open_, t=t)
        rule, why = "final_doubt", final_doubt(step, t=t)
        if not why and (little := too_little(step.judgement, longer_gain(step), floor_mse, t=t)):
            rule, why = "too_little", f"its final fit {little}"
        if not why:
            rule, why = "unneeded", unneeded(step, first, start_mse, floor_mse, t=t)
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


def improvement(new: list[Added], old: list[Added]) -> dict:
    """How much better the final model of chain ``new`` predicts than that of ``old``
    (``heldout.improvement_between``, on the same judge rows): the share of ``old``'s held-out
    one-step error it removes, its paired z (blocks of rows), the share of ``old``'s open-loop
    error at the longest horizon it removes, and at each open-loop horizon compared
    (``horizons_removed``: steps -> share)."""
    return heldout.improvement_between(new[-1].judgement.row_errors, old[-1].judgement.row_errors,
                                       old[-1].after, new[-1].after)


def horizon_votes(v: dict, t: Thresholds = THRESHOLDS) -> tuple[int, int]:
    """Of the horizons an ``improvement`` ``v`` compares, at how many the new chain predicts
    better and at how many worse: by ``auto_min_removed`` of the one-step error with paired
    |z| >= ``parsimony_z``, by ``auto_min_longer`` at each open-loop horizon."""
    one, z = v["one_step_removed"], v["z"]
    better = int(one >= t.auto_min_removed and z >= t.parsimony_z)
    worse = int(one <= -t.auto_min_removed and z <= -t.parsimony_z)
    for share in v["horizons_removed"].values():
        better, worse = better + (share >= t.auto_min_longer), worse + (share <= -t.auto_min_longer)
    return better, worse


def predicts_better(v: dict, t: Thresholds = THRESHOLDS) -> bool:
    """Whether a chain whose ``improvement`` over the kept one is ``v`` replaces it.

    Either it predicts the held-out one step significantly better (z >= ``parsimony_z``) and
    lowers the longest-horizon error too, by ``auto_min_removed`` at one step or
    ``auto_min_longer`` at the longest horizon: an extra effect that fits the noise in the start
    states does neither. Or, where the horizons disagree, it predicts better at two of them or
    more (so at an open-loop one), at more than worse (``horizon_votes``), and by more than it
    loses: the product of its error ratios over the horizons is below 1 (each horizon's relative
    change weighs alike; a chain 30 % worse at 25 steps is not kept for 8 % and 10 % better at 1
    and 5). One horizon alone is not enough: a fresh draw (a payload beside an 11 ms delay) had
    a chain with an extra actuator lag 10 % better at 25 steps and even elsewhere.

    Under a closed-loop controller the actions carry the sensor noise of the states they follow,
    and neither horizon alone decides. Fresh draws under attitude feedback: kp x0.63 with a
    19.6 N m limit, the true pair (torque limit + PD gains) predicted one step 6.3 % better
    (z 7.7) and 5 steps 9 % better than motor strength + joint damping, 25 steps 6 % worse; kp
    x0.67 with an 11 ms lag, the true lag (the gains as strength + damping beside it) predicted 5
    and 25 steps 14 % and 38 % better than PD gains + armature, one step 8 % worse (z -5.9). An
    effect that only fits the noise wins the one step alone.
    """
    longer = v["longest_horizon_removed"]
    if (v["z"] >= t.parsimony_z and (longer is None or longer > 0)
            and (v["one_step_removed"] >= t.auto_min_removed or (longer or 0.0) >= t.auto_min_longer)):
        return True
    better, worse = horizon_votes(v, t=t)
    return better >= 2 and better > worse and _error_ratio(v) < 1.0


def predicts_as_well(v: dict, t: Thresholds = THRESHOLDS) -> bool:
    """Whether a chain whose ``improvement`` over the kept one is ``v`` predicts at least as well:
    at no horizon worse by the margins of ``horizon_votes``, and the product of its error ratios
    over the horizons at most 1. With fewer effects it replaces the kept chain: the kept one's
    extra effect does not improve the held-out prediction (a fresh draw of kp x0.85 with an 11 ms
    delay: with an actuator lag added beside them the chain predicted 1, 5 and 25 steps 0.4 %,
    3.5 % and 3.9 % worse than without it, and the delay was fitted 14 % short)."""
    return predicts_no_worse(v, t=t) and _error_ratio(v) <= 1.0


def predicts_no_worse(v: dict, t: Thresholds = THRESHOLDS) -> bool:
    """Whether a chain whose ``improvement`` over another is ``v`` predicts no horizon worse by the
    margins of ``horizon_votes`` (``revisit`` keeps a refitted chain only then)."""
    return horizon_votes(v, t=t)[1] == 0


def _error_ratio(v: dict) -> float:
    """The product over the horizons of the new chain's error over the kept one's."""
    return float(np.prod([1.0 - v["one_step_removed"], *(1.0 - s for s in v["horizons_removed"].values())]))


def other_starts(problem: Problem, first: Comparison, cfg: DiagnoseConfig, judge_rows: np.ndarray,
                 base_residual: np.ndarray, floor_mse: float, ranking: list[Candidate], chain: list[Added],
                 progress=None, t: Thresholds = THRESHOLDS) -> tuple[list[Added], list[Chain]]:
    """The greedy chain started from each of the next ``cfg.auto_alternatives`` plausible,
    significant candidates of the first ranking, re-ranking only the ``shortlist`` best of them.
    Another chain adds at most one effect more than the kept one holds: it stands for two effects that one of the kept
    chain stood in for, or for the same effects in another order (below); longer, it is a chain
    of flexible effects (on a log with calves 10 % long, up to four effects, the other chain took
    four fifths of the diagnosis's time). None is started where the kept chain leaves nothing
    another could explain (``nothing_left``).

    Adding greedily, one effect can stand in for two: payload 2 kg + joint damping 0.4 came out as
    both PD gains scaled (0.89 / 1.17: a higher derivative gain is damping, a lower proportional
    gain sags like a heavier trunk), after which neither true effect removed 5 % of what was
    left, although the pair predicts the held-out rows better (one-step error 4.7 % lower) and
    the 25-step open-loop error 61 % lower. Another chain replaces the one kept when its final
    model predicts better (``predicts_better``): at one step significantly and at the longest
    horizon too, by the margins ``greedy`` asks of an added effect, or, where the horizons
    disagree, at more of them than worse; or, with fewer effects, as well (``predicts_as_well``).
    A chain of the same effects in another order is judged
    alike: fitted from other starting points, its values can be better (a fresh draw under
    feedback: armature 0.0327 added first, 0.0254 added after the torque limit, for 0.0253; one
    step 2.4 % better, z 7.0, 5 and 25 steps 12 % and 11 %).

    Where another chain may replace the kept one (it predicts some horizon better, or none
    worse), the two are compared refined (``refine_chain``; a no-op on a chain without an effect
    that moves the start state), as the diagnosis would report them: twelve encoder offsets
    chosen by forward differences are 20-40 % off, and another effect can make up for that. On
    the benchmark's offsets log behind a 10 ms velocity filter, the chain ground_softness +
    encoder_offset predicted one step 5.7 % better (z 7.8), 5 and 25 steps 2 % and 4 % better
    than the offsets alone, both unrefined, and was kept (softness 0.025 s once refined, offsets
    11.4 % off). Both refined, it predicts one step 6.7 % better (z 7.7) but 5 and 25 steps 4 %
    and 25 % worse, and the offsets alone are kept, 8.3 % off.
    """
    if not chain:
        return chain, []
    kept = Chain(chain, chain[0].name, kept=True, why="the best candidate first")
    tried = [kept]
    if nothing_left(chain[-1].after, chain[-1].judgement.mse_after, first, float(np.mean(base_residual ** 2)),
                    floor_mse, t=t, then="no other start tried"):
        return kept.steps, tried  # no other chain can explain a share of the error this one leaves
    pool = [c for c in ranking if c.judgement.significant and not doubt(c, t=t)]
    shortlist = replace(cfg, candidates=tuple(c.name for c in pool[:t.shortlist]),
                        auto_max=min(cfg.auto_max, len(names(chain)) + 1))
    for c in [c for c in pool if c.name != chain[0].name][:cfg.auto_alternatives]:
        if progress:
            progress(f"trying {c.name} first", None)
        with within(f"chain started with {c.name}"):
            steps, _ = greedy(problem, first, shortlist, judge_rows, base_residual, floor_mse, [c], progress, t=t)
            if steps and steps[0].name == c.name:  # its ties in the first ranking, which this chain started past
                steps[0].ties = ties_of(c, ranking, t=t)
            steps = revisit(problem, first, cfg, judge_rows, base_residual, steps, progress, t=t)
        other = Chain(steps, c.name)
        tried.append(other)
        if not steps:
            other.why = f"{c.name} is not added on its own final fit"
            record("other_starts", "nothing added", f"the chain started with {other.why}", start=c.name)
            continue
        better, worse = horizon_votes(improvement(steps, kept.steps), t=t)
        if better or not worse:  # it may replace the kept chain: compare the two as they would be reported
            kept.steps = refine_chain(problem, first, kept.steps, cfg, judge_rows, base_residual, t=t)
            other.steps = steps = refine_chain(problem, first, steps, cfg, judge_rows, base_residual, t=t)
        # The same effects added in another order are fitted from other starting points: the
        # chain that predicts better by the same rule keeps its values.
        same = " (the same effects, fitted otherwise)" if sorted(other.names) == sorted(kept.names) else ""
        other.versus = v = improvement(steps, kept.steps)
        gains = f"{_versus_text(v)} against {kept.label}{same}"
        better = predicts_better(v, t=t)
        figures = dict(start=c.name, chain=other.label, against=kept.label, one_step_removed=v["one_step_removed"],
                       z=v["z"], longest_horizon_removed=v["longest_horizon_removed"], parsimony_z=t.parsimony_z,
                       auto_min_removed=t.auto_min_removed, auto_min_longer=t.auto_min_longer)
        if better or (len(other.names) < len(kept.names) and predicts_as_well(v, t=t)):
            kept.kept, kept.why = False, f"replaced by the chain started with {c.name}"
            said = "predicts better" if better else "predicts as well with fewer effects"
            kept, other.kept, other.why = other, True, f"{said}: {gains}"
            record("predicts_better" if better else "predicts_as_well", f"{other.label} kept",
                   f"the chain started with {c.name}, {other.label}, is kept: it {said}: {gains}", **figures)
        else:
            other.why = f"not clearly better: {gains}"
            record("predicts_better", f"{kept.label} kept",
                   f"the chain started with {c.name}, {other.label}, is not clearly better: {gains}", **figures)
    return kept.steps, tried


def _size(name: str) -> int:
    """Free parameters of an effect fitted at its default granularity."""
    effect = get_effect(name)
    return len(effect.parameters) * (12 if traits(effect.name).granularity == "joint" else 1)


def revisit(problem: Problem, first: Comparison, cfg: DiagnoseConfig, judge_rows: np.ndarray,
            base_residual: np.ndarray, added: list[Added], progress=None, t: Thresholds = THRESHOLDS) -> list[Added]:
    """Each of two or more added effects judged again beside the others.

    Adding greedily, a richer effect can absorb part of one added after it (both PD gains scaled
    soaking up joint friction where the motors are weak: strength 0.85 and friction 0.2 came out
    as gains 0.87 / 0.97 and friction 0.31). Beside the others, the effect is ranked against the
    simpler candidates not in the model (fewer parameters at their default granularity), with
    ``rank``'s simpler-explanation rule; where one takes its place, the chain is refitted in the
    same order from ``first`` (each effect once: ``choose_fit`` chooses its granularity again).

    The refitted chain is kept only where it predicts no horizon worse (``predicts_no_worse``):
    judged beside the others, a richer effect is fitted again from its nominal
    values and can land elsewhere. A fresh draw under attitude feedback (floor friction 0.67 and
    a 1.55 kg payload 7.8 cm ahead of the trunk): the payload, added second at 1.47 kg and
    com_x 9 cm, was fitted again at 1.07 kg and com_x 13.6 cm (implausible), and motor strength
    took its place; that chain predicted 1, 5 and 25 steps 3.6 % (z -7.3), 26 % and 93 % worse
    (mean squares) than the payload's.

    An effect is left out where neither it nor a simpler one is significant beside the others:
    added first, an effect can stand in for one added after it and end, once that one
    is refitted beside it, near its nominal values. A fresh draw of floor friction 0.27 with
    motor strength 0.89: the ground's softness, added first at 34.4 ms, ended at 18.8 ms (nominal
    20 ms) beside both; judged again it removed 1.8 % of the one-step error (not significant),
    and left out it changed the 1-, 5- and 25-step errors by +1.2 %, +0.1 % and -9 %. A chain
    with an effect left out is kept where it predicts as well (``predicts_as_well``); where every
    effect would be left out (each standing in for another), the chain stays as it is.
    """
    effects = names(added)
    if len(effects) < 2:
        return added
    chosen: list[str | None] = list(effects)
    final = added[-1].after.model
    for i, a in enumerate(next(s for s in added if s.name == n) for n in effects):
        simpler = tuple(n for n in cfg.candidates if n not in chosen and n not in effects and _size(n) < _size(a.name))
        others = Model(final.backend, [t for t in final.effects if t.name != a.name], final.corrector)
        residual = problem.residual_of(others.sim_config(problem.control), judge_rows)
        if progress:
            progress(f"judging {a.name} again beside the other added effects", None)
        with within(f"revisit {a.name}"):
            again = rank(problem, others, replace(cfg, candidates=(a.name, *simpler)), judge_rows, residual, t=t)
        top = next((c for c in again if c.judgement.significant and not doubt(c, t=t)), None)
        chosen[i] = top.name if top is not None else None
        if top is None:
            record("revisit", f"{a.name} left out", (
                f"{a.name} judged again beside the other added effects: neither it nor a simpler candidate is "
                "significant and plausible there"), effect=a.name, simpler=", ".join(simpler))
        elif top.name != a.name:
            record("revisit", f"{top.name} in {a.name}'s place", (
                f"{a.name} judged again beside the other added effects: the simpler {top.name} goes first there"),
                effect=a.name, simpler=", ".join(simpler), instead=top.name)
    kept = [n for n in chosen if n is not None]
    if kept == effects or not kept:
        if not kept:
            record("revisit", "kept as added", "every added effect would be left out (each stands in for another): "
                   "the chain stays as added", effects=" + ".join(effects))
        return added
    chain, current, residual = [], first, base_residual
    for name in kept:
        if progress:
            progress(f"adding {name}", None)
        step = add_effect(problem, current.model, name, cfg, judge_rows, residual, current, t=t)
        step.ties = next((s.ties for s in added if s.name == name), [])  # an effect kept: as it was added
        chain.append(step)
        current, residual = step.after, step.judgement.residual_after
    holds = predicts_as_well if len(kept) < len(effects) else predicts_no_worse
    v = improvement(chain, added)
    figures = dict(one_step_removed=v["one_step_removed"], z=v["z"], longest_horizon_removed=v["longest_horizon_removed"],
                   auto_min_removed=t.auto_min_removed, auto_min_longer=t.auto_min_longer, parsimony_z=t.parsimony_z)
    if not holds(v, t=t):
        if progress:
            progress(f"{' + '.join(names(chain))} predicts worse: kept {' + '.join(effects)}", None)
        record(holds.__name__, "kept as added", (
            f"{' + '.join(names(chain))} predicts the held-out rows worse than {' + '.join(effects)} "
            f"({_versus_text(v)}): kept as added"), **figures)
        return added
    record(holds.__name__, f"{' + '.join(names(chain))} instead", (
        f"{' + '.join(names(chain))} in place of {' + '.join(effects)}: it predicts "
        f"{'as well with fewer effects' if len(kept) < len(effects) else 'no horizon worse'} ({_versus_text(v)})"),
        **figures)
    return chain


def _versus_text(v: dict) -> str:
    """An ``improvement`` in words: the one-step error's change with its z, then each open-loop horizon's."""
    said = f"one-step error {-v['one_step_removed']:+.1%} (z {v['z']:.1f})"
    return said + "".join(f", {h}-step error {-removed:+.0%}" for h, removed in v["horizons_removed"].items())


def does_not_hold(fits: list[HalfFits], t: Thresholds = THRESHOLDS) -> str:
    """Why the added effects do not hold on two halves of the episodes ("" where they do): an
    effect whose two fits differ beyond their standard errors (chi^2 above its quantile at
    ``halves_z``, ``acn.diagnosis.halves``)."""
    off = [f for f in fits if f.chi2 > chi2_quantile(len(f.names), t.halves_z)]
    return "; ".join(f"{f.worst()} (chi^2 {f.chi2:.0f} on {len(f.names)} values)" for f in off)


# ----- the verdict --------------------------------------------------------------------------
def verdict(before: Comparison, mse: float, floor_mse: float, ranking: list[Candidate], added: list[Added],
            automatic: bool, set_aside: dict[str, str] | None = None,
            t: Thresholds = THRESHOLDS) -> tuple[str, str, tuple[str, ...]]:
    """(verdict, reason in words, the effects it names); see module docstring. ``set_aside``:
    candidates ``--auto`` did not add on their final fit (name -> why); never named."""
    v, reason, named = _verdict(before, mse, floor_mse, ranking, added, automatic, set_aside or {}, t)
    record("verdict", v, f"verdict {v}: {reason}", named=" + ".join(named), headline=before.headline, exact=t.exact,
           structured=structured_share(mse, floor_mse), structured_share=t.structured_share,
           effect_share=t.effect_share)
    return v, reason, named


def holds_on_halves(judged: tuple[str, str, tuple[str, ...]], fits: list[HalfFits], added: list[Added], mse: float,
                    floor_mse: float, t: Thresholds = THRESHOLDS) -> tuple[str, str, tuple[str, ...]]:
    """The verdict ``judged`` (``verdict``'s) once the added effects are fitted on two halves of the
    episodes (``fits``): where they do not agree (``does_not_hold``), the effects only paper over
    structure the catalogue lacks and the verdict is ``unexplained``."""
    why = does_not_hold(fits, t=t)
    worst = max((f.chi2 for f in fits), default=0.0)
    if not why:
        record("does_not_hold", "holds", (
            f"the fits of {' + '.join(names(added))} on two halves of the episodes agree within their standard errors "
            f"(chi^2 at most its {t.halves_z:g}-sigma quantile)"), largest_chi2=worst, halves_z=t.halves_z)
        return judged
    reason = (f"{structured_share(mse, floor_mse):.0%} of the error is structured (above the noise floor); "
              f"{' + '.join(names(added))} would explain it, but not alike on two halves of the episodes: {why}")
    record("does_not_hold", "unexplained", f"verdict unexplained: {reason}", largest_chi2=worst, halves_z=t.halves_z)
    return "unexplained", reason, ()


NOT_ADDED = "is not added by --auto (too little to add)"  # a candidate --auto declined, in a reason


def _verdict(before: Comparison, mse: float, floor_mse: float, ranking: list[Candidate], added: list[Added],
             automatic: bool, set_aside: dict[str, str], t: Thresholds) -> tuple[str, str, tuple[str, ...]]:
    if before.headline < t.exact:
        return "none", f"the model reproduces the measurements (headline error {before.headline:.2g})", ()
    structured = 1.0 - floor_mse / mse if mse > 0 else 0.0
    if automatic and added:
        part = explained_share(mse, added[-1].judgement.mse_after, floor_mse)
        effects = tuple(names(added))
        explain = f"{' + '.join(effects)} explains" if len(effects) == 1 else f"{' + '.join(effects)} explain"
        if part >= t.effect_share:
            return "effect", f"{explain} {part:.0%} of the error above the noise floor", \
                effects
        after = added[-1].judgement.mse_after
        left = 1.0 - floor_mse / after if after > 0 else 0.0
        if min(structured, left) < t.structured_share:  # what is left is noise, by the rule that gives "none"
            longer = longest_removed(before, added[-1].after)
            gain = f" (the {before.check}-step open-loop error falls by {longer:.0%})" if longer and longer > 0 else ""
            why = (f"the one-step error is mostly sensor noise (only {max(structured, 0):.0%} of it is predictable "
                   f"from the state and actions)" if structured < t.structured_share else
                   f"only {max(left, 0):.0%} of the one-step error left is predictable from the state and actions, "
                   f"against {structured:.0%} before")
            return "effect", (f"{explain} {part:.0%} of the error above the noise floor{gain}, and what is "
                              f"left matches within the noise: {why}"), effects
    # With --auto its chain is the answer: a candidate it did not add (too little to, or set aside) is not named
    declined = {c.name for c in ranking if c.name not in names(added)} if automatic else set()
    plausible = [c for c in ranking if c.judgement.significant and not doubt(c, t=t) and c.name not in set_aside
                 and c.name not in declined]
    top = plausible[0] if plausible else None
    aside = "".join(f"; {name} set aside: {why}" for name, why in set_aside.items())
    if top is not None and top.judgement.explained(floor_mse) >= t.effect_share:
        skipped = [c.name for c in ranking[: ranking.index(top)] if c.name not in set_aside]
        also = f"; ranked above it but set aside: {', '.join(skipped)}" if skipped else ""
        also += aside
        return "effect", (f"{top.name} explains {top.judgement.explained(floor_mse):.0%} of the error above the noise "
                          f"floor ({evidence(top, t=t)}){also}"), (top.name,)
    best = ranking[0] if ranking else None
    if structured >= t.structured_share:
        why = ("no candidate improves held-out predictions significantly" if best is None
               or not best.judgement.significant else
               f"the best plausible candidate, {top.name}, explains only {top.judgement.explained(floor_mse):.0%} of it"
               if top is not None else
               f"the best candidate, {best.name}, {doubt(best, t=t) or set_aside.get(best.name, '') or NOT_ADDED}")
        return "unexplained", f"{structured:.0%} of the error is structured (above the noise floor); {why}{aside}", ()
    extra = f"; the best candidate, {best.name}, removes {best.judgement.removed:.1%} of it" if best else ""
    if best is not None and (implausible(best.fit, t=t) or best.name in set_aside or best.name in declined):
        extra += f" but {implausible(best.fit, t=t) or set_aside.get(best.name) or NOT_ADDED}"
    noise = sorted((c for c in ranking if one_step_only(c, t=t)),
                   key=lambda c: -c.judgement.removed)  # the most convincing first
    if noise:
        extra += f"; {noise[0].name} {one_step_only(noise[0], t=t)}"
    return "none", (f"the model matches within the noise: only {max(structured, 0):.0%} of the error is predictable "
                    f"from the state and actions and no plausible effect explains it{extra}"), ()


def evidence(c: Candidate, t: Thresholds = THRESHOLDS) -> str:
    """Why ``c``'s held-out improvement is significant, in words."""
    if c.judgement.by_longest and c.judgement.z >= t.significance_z:
        return (f"it removes {c.longer_gain:.0%} of the longest-horizon open-loop error; at one step only "
                f"{c.judgement.removed:.1%} ({c.judgement.z:.1f} standard errors): a small effect that adds up")
    if c.judgement.by_longest:
        return (f"it removes {c.longer_gain:.0%} of the longest-horizon open-loop error; at one step its held-out "
                f"improvement is uneven, {c.judgement.z:.1f} standard errors: it acts on few steps")
    return f"held-out improvement {c.judgement.z:.1f} standard errors"
