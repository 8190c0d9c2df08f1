"""Judging one candidate: its held-out gain and significance, the plausibility of its fitted
values, and whether it fits what sensor noise does.

Every function here reads evidence (a ``Judgement``, an ``EffectFit``, a ``Candidate``) and its
thresholds, and returns a verdict on that one candidate; none changes it.
"""

from __future__ import annotations

from enum import Enum

import numpy as np

from acn.diagnosis import heldout
from acn.diagnosis.compare import floor_of
from acn.diagnosis.fitting import EffectFit
from acn.diagnosis.heldout import Judgement, structured_share
from acn.diagnosis.policy.thresholds import THRESHOLDS, Thresholds
from acn.diagnosis.problem import Problem
from acn.diagnosis.results import Added, Candidate, longer_gain
from acn.diagnosis.traits import traits
from acn.sim.effects import Effect, Model, Parameter


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


def evidence(c: Candidate, t: Thresholds = THRESHOLDS) -> str:
    """Why ``c``'s held-out improvement is significant, in words."""
    if c.judgement.by_longest and c.judgement.z >= t.significance_z:
        return (f"it removes {c.longer_gain:.0%} of the longest-horizon open-loop error; at one step only "
                f"{c.judgement.removed:.1%} ({c.judgement.z:.1f} standard errors): a small effect that adds up")
    if c.judgement.by_longest:
        return (f"it removes {c.longer_gain:.0%} of the longest-horizon open-loop error; at one step its held-out "
                f"improvement is uneven, {c.judgement.z:.1f} standard errors: it acts on few steps")
    return f"held-out improvement {c.judgement.z:.1f} standard errors"


def significant(step: Added, t: Thresholds = THRESHOLDS) -> bool:
    """Whether the added effect's final fit is significant as ``rank`` judges a candidate: at one
    step (``judge``) or by removing ``large_improvement`` of the longest-horizon open-loop
    error (``uneven``)."""
    return step.judgement.significant or (longer_gain(step) or 0.0) >= t.large_improvement
