"""Which effect is missing: fit every candidate, judge each on held-out rows.

For every catalogue effect: fit its parameters (``fitting``) on a sample of fit rows, at its
default granularity, added to the current model; then re-simulate held-out "judge" rows with
and without it. A candidate's evidence:

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
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field, replace

import numpy as np

from acn.diagnosis.fitting import GRANULARITIES, EffectFit, default_granularity, fit_effect, multistep_refit, refittable
from acn.diagnosis.problem import DiagnoseConfig, Problem
from acn.sim.effects import Effect, Model, Parameter, get_effect

PRICE_PER_PARAMETER = 0.003  # explained share a parameter has to earn
SIGNIFICANCE_Z = 3.0
MIN_IMPROVEMENT = 0.02       # of the error (MSE)
LARGE_IMPROVEMENT = 0.25     # of the error (MSE): significant however unevenly spread
BLOCK = 10                   # rows per block in the significance test
LARGEST_FACTOR = 2.0         # a fit further from nominal than this x the largest realistic magnitude is implausible
SCREENED = 3                 # significant, plausible candidates checked at the longest horizon (until one passes)
SMALLEST_SHARE = 0.75        # of the smallest realistic magnitude a named effect must reach
UNIDENTIFIED_SHARE = 0.5     # a standard error above this x the largest realistic magnitude: not identified
STRUCTURED_SHARE = 0.15      # of the error that must be above the noise floor before an effect is missing
PARSIMONY_Z = 2.0            # a richer candidate must beat a simpler one by this much to rank first,
PARSIMONY_SHARE = 0.9        # and the simpler one remove less than this share of what it removes
LONGER_MARGIN = 0.05         # of the longest-horizon error: a candidate tied at one step must remove this much more
READING_TOLERANCE = 0.05     # of the longest-horizon error: what a reading-only effect may add to it (fits_noise)
FINER = ("type", "leg", "joint")  # granularities ``finer_look`` fits the per-joint candidates at
TOO_SMALL = "fits a value below 3/4 of the smallest realistic magnitude"  # implausible's reason for too_small


@dataclass
class Judgement:
    """Held-out comparison of a model with and without an effect."""

    mse_before: float
    mse_after: float
    removed: float       # share of the whole error (MSE) removed, may be < 0
    z: float             # improvement / its standard error
    significant: bool
    residual_after: np.ndarray  # (N, C) held-out residuals with the effect
    by_longest: bool = False     # significant by its longest-horizon gain, not at one step (``uneven``)

    @property
    def row_errors(self) -> np.ndarray:
        """(N,) each held-out row's mean squared residual with the effect: what ``paired_z`` compares."""
        return (self.residual_after ** 2).mean(1)

    def explained(self, floor_mse: float) -> float:
        """Share 0..1 of the structured error (MSE above ``floor_mse``) removed."""
        return explained_share(self.mse_before, self.mse_after, floor_mse)


def explained_share(mse_before: float, mse_after: float, floor_mse: float) -> float:
    structured = mse_before - floor_mse
    return float(np.clip((mse_before - mse_after) / structured, 0.0, 1.0)) if structured > 0 else 0.0


def at_bound(fit: EffectFit) -> list[str]:
    """Parameters pushed against a bound that is not their nominal value."""
    out = []
    for p in fit.effect.parameters:
        v = np.atleast_1d(np.asarray(fit.values[p.name], float))
        span = p.upper - p.lower
        if any(bound != p.nominal and np.any(np.abs(v - bound) <= 0.01 * span) for bound in (p.lower, p.upper)):
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


def unidentified(fit: EffectFit) -> list[str]:
    """Free parameters these data do not pin down: a standard error above half the largest
    realistic magnitude, so the 95 % interval reaches from nominal to beyond a realistic value
    (e.g. the encoder offsets of a leg that is in the air most of the time: in the air an offset
    moves the reading and the leg together, only the trunk sees it)."""
    largest = {p.name: _realistic_magnitudes(p)[1] for p in fit.effect.parameters if p.realistic is not None}
    return [n for n, e in zip(fit.names, fit.stderr)
            if n.split("[")[0] in largest and not e <= UNIDENTIFIED_SHARE * largest[n.split("[")[0]]]


def too_small(fit: EffectFit) -> bool:
    """Every parameter closer to its nominal value than 3/4 of the smallest realistic magnitude."""
    sizes = _magnitudes(fit)
    return bool(sizes) and all(dev < SMALLEST_SHARE * smallest for _, dev, smallest, _ in sizes)


def too_large(fit: EffectFit) -> list[str]:
    """Parameters further from nominal than LARGEST_FACTOR x the largest realistic magnitude."""
    return [name for name, dev, _, largest in _magnitudes(fit) if dev > LARGEST_FACTOR * largest]


def implausible(fit: EffectFit) -> str:
    """Why a fitted effect cannot be the explanation ("" if it can): a value pushed against a
    bound, or more than twice the largest magnitude real robots show, stands in for something
    else (joint springs fit as damping 2.5 N m s/rad or a derivative gain x 2.8); one below 3/4
    of the smallest realistic magnitude is fitting noise or another effect's leftovers (sensor
    noise in joint readings biases the contact forces a re-simulation starts with, and encoder
    offsets of a few mrad fit that). Values the measurements contradict without simulation
    (``Effect.check``: a measured frame that lifts the stance feet off the ground) stand in for
    something else too."""
    if fit.contradicted:
        return fit.contradicted
    stuck = at_bound(fit)
    if stuck:
        return f"needs {', '.join(stuck)} at the bound of its range"
    large = too_large(fit)
    if large:
        return f"needs {', '.join(large)} beyond {LARGEST_FACTOR:g}x the largest realistic magnitude"
    if too_small(fit):
        return TOO_SMALL
    return ""


@dataclass
class Candidate:
    fit: EffectFit
    judgement: Judgement
    score: float
    longer_gain: float | None = None  # share of the longest-horizon open-loop error it removes (None: not checked)

    @property
    def name(self) -> str:
        return self.fit.effect.name


def fits_noise(longer_gain: float | None, effect: Effect | None = None) -> bool:
    """Whether an effect with this share of the longest-horizon open-loop error removed (None:
    not checked) fits the noise in the measured start states: it does not lower that error.

    An effect on the reading only (``Effect.reading_only``: the frame the trunk is measured in)
    acts on a prediction through its start state and its reading; the physics in between is the
    same, and a long prediction forgets its start. So it need not lower the longest-horizon
    error, only not raise it by more than ``READING_TOLERANCE``; what guards it against fitting
    noise is ``too_small`` (a frame within 3/4 of the smallest realistic offset is set aside)."""
    if longer_gain is None:
        return False
    return longer_gain < -READING_TOLERANCE if effect is not None and effect.reading_only else longer_gain <= 0


def one_step_only(c: Candidate) -> str:
    """Why ``c`` is fitting the noise in the measured start states ("" if it is not, or unchecked)."""
    if not fits_noise(c.longer_gain, c.fit.effect):
        return ""
    return (f"improves the one-step prediction only (open-loop error at the longest horizon {-c.longer_gain:+.0%}): "
            "it fits what sensor noise in the measured start states does")


def doubt(c: Candidate) -> str:
    """Why a candidate cannot be the explanation ("" if it can): ``implausible`` or ``one_step_only``."""
    return implausible(c.fit) or one_step_only(c)


def fits_noise_by_size(c: Candidate) -> bool:
    """Whether ``c`` is significant and set aside only for its size (``implausible`` is
    ``TOO_SMALL``: not contradicted, not at a bound, not too large): it fits noise or another
    effect's leftovers, and ``pipeline.noise_fitted`` counts what it removes as noise."""
    return c.judgement.significant and implausible(c.fit) == TOO_SMALL


def open_loop_gain(before: np.ndarray, after: np.ndarray) -> float:
    """Share of the open-loop MSE of residuals ``before`` (N, C) that ``after`` removes, on the
    rows ``before`` predicted (a prediction that blew up after counts as error 10, as in ``judge``)."""
    ok = np.isfinite(before).all(1)
    mse = float(np.mean(before[ok] ** 2)) if ok.any() else 0.0
    return 1.0 - float(np.mean(np.where(np.isfinite(after[ok]), after[ok], 10.0) ** 2)) / mse if mse > 0 else 0.0


@dataclass
class LongestHorizon:
    """The open-loop check at the longest horizon of ``cfg`` against ``model``: the same held-out
    start rows for every candidate, and ``model``'s residuals from them simulated once, on first
    use (``rank`` asks for it up to three times)."""

    problem: Problem
    model: Model
    cfg: DiagnoseConfig
    _base: np.ndarray | None = field(default=None, repr=False)

    @property
    def steps(self) -> int:
        """The check's horizon (``compare.informative_horizon``; the longest before it is known)."""
        return (self.problem.check_horizon if self.problem is not None else None) or max(self.cfg.horizons)

    def gain(self, candidate: Model) -> float:
        """Share of ``model``'s open-loop error at the longest horizon that ``candidate`` removes."""
        starts = self.problem.rollout_starts(self.steps, self.cfg.rollout_starts)
        if self._base is None:
            self._base = self.problem.residual_of(self.model.sim_config(self.problem.control), starts, self.steps)
        after = self.problem.residual_of(candidate.sim_config(self.problem.control), starts, self.steps)
        return open_loop_gain(self._base, after)


def longer_gains(horizon: LongestHorizon, candidates: list[Candidate], until_one_passes: bool = False) -> None:
    """Set ``longer_gain`` of ``candidates`` where it is not set, in order (nothing with one-step
    horizons only); ``until_one_passes``: stop at the first that lowers the longest-horizon error."""
    if horizon.steps <= 1:
        return
    for c in candidates:
        if c.longer_gain is None:
            c.longer_gain = horizon.gain(c.fit.model)
        if until_one_passes and not one_step_only(c):
            break


def screen(horizon: LongestHorizon, ranking: list[Candidate]) -> None:
    """``longer_gains`` of the significant candidates of plausible magnitude, in rank order,
    until one lowers the open-loop error at the longest horizon (at most SCREENED)."""
    plausible = [c for c in ranking if c.judgement.significant and not implausible(c.fit)]
    longer_gains(horizon, plausible[:SCREENED], until_one_passes=True)


def significant_gain(gain: float, z: float) -> bool:
    """Whether a held-out improvement of ``gain`` (share of the error) at paired ``z`` is significant:
    at least ``MIN_IMPROVEMENT``, and ``SIGNIFICANCE_Z`` standard errors or ``LARGE_IMPROVEMENT``."""
    return bool(gain >= MIN_IMPROVEMENT and (z >= SIGNIFICANCE_Z or gain >= LARGE_IMPROVEMENT))


def judge(problem: Problem, after: Model, rows: np.ndarray, before_residual: np.ndarray,
          reference_mse: float | None = None) -> Judgement:
    """``after`` against the residuals ``before_residual`` of the current model on ``rows``.

    ``reference_mse``: the error the 2 % and 25 % thresholds refer to (default: the current one;
    a finer granularity of the same effect must improve on the error before the effect).
    """
    return judgement(before_residual, problem.residual_of(after.sim_config(problem.control), rows), reference_mse)


def judgement(before_residual: np.ndarray, after_residual: np.ndarray, reference_mse: float | None = None) -> Judgement:
    """The residuals ``after_residual`` (N, C) against ``before_residual`` on the same rows (``judge``):
    rows whose before residual is not finite are left out, an after one that blew up counts 10."""
    ok = np.isfinite(before_residual).all(1)
    ra = np.where(np.isfinite(after_residual), after_residual, 10.0)
    eb, ea = (before_residual[ok] ** 2).mean(1), (ra[ok] ** 2).mean(1)
    mse_b, mse_a = float(eb.mean()), float(ea.mean())
    z = paired_z(eb - ea)
    removed = 1.0 - mse_a / mse_b if mse_b > 0 else 0.0
    gain = (mse_b - mse_a) / (reference_mse or mse_b) if mse_b > 0 else 0.0
    return Judgement(mse_b, mse_a, removed, z, significant_gain(gain, z), ra)


def rank(problem: Problem, model: Model, cfg: DiagnoseConfig, judge_rows: np.ndarray, base_residual: np.ndarray,
         progress=None) -> list[Candidate]:
    """Every candidate effect fitted on fit rows and judged on ``judge_rows``; best first."""
    fit_rows = rank_rows(problem, cfg)
    out = []
    for i, name in enumerate(cfg.candidates):
        if progress:
            progress(f"fitting {name}", i / len(cfg.candidates))
        effect = get_effect(name)
        fit = fit_effect(problem, model, effect, default_granularity(effect), fit_rows, max_iter=cfg.rank_iterations,
                         refit=refittable(model))
        c = candidate(problem, fit, judge_rows, base_residual)
        if effect.fit_over_steps and c.judgement.significant and implausible(fit) not in ("", TOO_SMALL):
            ahead = over_steps_from_realistic(problem, model, fit, fit_rows)
            c = c if ahead is fit else candidate(problem, ahead, judge_rows, base_residual)
        out.append(c)
    return order(problem, model, cfg, out, progress)


def over_steps_from_realistic(problem: Problem, model: Model, fit: EffectFit, rows: np.ndarray) -> EffectFit:
    """For an effect whose one-step fit the noise in the start states biases (``Effect.fit_over_steps``:
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
    return ahead if ahead is not start and not implausible(ahead) else fit


def rank_rows(problem: Problem, cfg: DiagnoseConfig) -> np.ndarray:
    """The fit rows every candidate is fitted on while ranking (the same sample for each)."""
    return problem.sample(problem.fit_rows, cfg.rank_rows, salt=3)


def candidate(problem: Problem, fit: EffectFit, judge_rows: np.ndarray, base_residual: np.ndarray) -> Candidate:
    j = judge(problem, fit.model, judge_rows, base_residual)
    return Candidate(fit, j, j.removed - PRICE_PER_PARAMETER * len(fit.x))


def order(problem: Problem, model: Model, cfg: DiagnoseConfig, out: list[Candidate], progress=None) -> list[Candidate]:
    """Candidates best first: by score, then checked at the longest horizon (module docstring)."""
    out = sorted(out, key=lambda c: (-c.score, len(c.fit.x)))
    if progress:
        progress("checking the best candidates at the longest horizon", None)
    horizon = LongestHorizon(problem, model, cfg)
    for _ in range(2):  # twice: the simpler candidate put in the best one's place is checked too
        screen(horizon, out)
        out = prefer_simpler(noise_fits_last(out), horizon)
    longer_gains(horizon, tied_with_best(out))
    out = prefer_longer(out)
    uneven(horizon, out)
    return noise_fits_last(out)  # those ``uneven`` found, too


def structured_share(mse: float, floor_mse: float) -> float:
    """The share of an error ``mse`` above the noise floor ``floor_mse``, 0..1 (0 where there is no error)."""
    return float(np.clip(1.0 - floor_mse / mse, 0.0, 1.0)) if mse > 0 else 0.0


def floor_says_noise(mse: float, floor_mse: float) -> bool:
    """Whether less than ``STRUCTURED_SHARE`` of the error ``mse`` lies above the noise floor."""
    return structured_share(mse, floor_mse) < STRUCTURED_SHARE


def finer_look(problem: Problem, model: Model, cfg: DiagnoseConfig, judge_rows: np.ndarray,
               base_residual: np.ndarray, ranking: list[Candidate], floor_says_noise: bool = False,
               progress=None, only: Collection[str] | None = None) -> list[Candidate]:
    """``ranking`` with its per-joint candidates fitted again per joint type, per leg and per
    joint (``FINER``), for where no significant, plausible candidate explains most of the error
    above the floor (``pipeline.diagnose``). An effect that differs joint by joint can cancel in
    one shared value: one motor at half strength (FR_calf) was a strength of 0.915 on every
    joint, z 2.4, and the verdict was unexplained. Per leg it is diluted over three joints (0.66
    -0.73 for the FR leg, z 2.2-3.0 on four short logs), per joint it is 0.51-0.53 (z 3.2-4.9).
    A finer fit replaces the shared one where it is significant, plausible, and scores higher
    (its price per parameter included); the ranking is then ordered again.

    ``floor_says_noise`` (under ``STRUCTURED_SHARE`` of the error above the noise floor): the
    floor's library is linear with a term per joint type, and one weak motor acts in its leg's
    stance only (the true strengths removed 30-40 % of a short noisy log's error where the floor
    called 4-7 % of it structured), so the finer look runs there too, but a finer fit must show
    the structure itself and remove ``STRUCTURED_SHARE`` of the error (on a pace log whose robot
    lies on its back, no effect hidden, hip damping per joint type removed 2.9 %, z 8: the
    sensor noise in the start states). It is fitted per joint only there: what a per-type
    library misses differs leg by leg or joint by joint, 12 values fit a leg too, and
    ``add.choose_fit`` then takes the coarsest granularity that holds (a nominal log's
    diagnosis: 56 s, against 86 s with all three granularities and 25 s without the look).

    ``only``: the candidates looked at (``add.greedy``: the effects it added, beside those added
    after them). No granularity finer than ``cfg.finest`` is fitted (``--finest``)."""
    shared = [c for c in ranking if c.fit.granularity == "shared" and (only is None or c.name in only)
              and any(p.per_joint for p in c.fit.effect.parameters)]
    rows = rank_rows(problem, cfg)
    granularities, least_removed = (("joint",), STRUCTURED_SHARE) if floor_says_noise else (FINER, 0.0)
    granularities = tuple(g for g in granularities if GRANULARITIES.index(g) <= GRANULARITIES.index(cfg.finest))
    out, changed = list(ranking), False
    for c in shared:
        best = c
        for g in granularities:
            if progress:
                progress(f"fitting {c.name} per {g}", None)
            fit = fit_effect(problem, model, c.fit.effect, g, rows, start=c.fit.values, max_iter=cfg.rank_iterations,
                             refit=refittable(model))
            new = candidate(problem, fit, judge_rows, base_residual)
            if (new.judgement.significant and not implausible(fit) and new.score > best.score
                    and new.judgement.removed >= least_removed):
                best = new
        if best is not c:
            out[out.index(c)], changed = best, True
    return order(problem, model, cfg, out, progress) if changed else ranking


def noise_fits_last(ranking: list[Candidate]) -> list[Candidate]:
    """``ranking`` with the candidates found fitting the noise (``one_step_only``) moved to the end, in order."""
    return sorted(ranking, key=lambda c: bool(one_step_only(c)))


def uneven(horizon: LongestHorizon, ranking: list[Candidate]) -> None:
    """Where no plausible candidate is significant at one step: the plausible ones that remove at
    least ``MIN_IMPROVEMENT`` of the one-step error or improve it by ``SIGNIFICANCE_Z`` standard
    errors, in rank order (at most ``SCREENED``), are checked at the longest horizon; the one
    that removes the most of that error, if at least ``LARGE_IMPROVEMENT``, is significant
    (``Judgement.by_longest``).

    An effect that acts on few steps is uneven at one step and shows over a long prediction:
    on a noisy log with a 20 N m torque limit, which the controller reached in 3.6 % of the
    physics steps, the fitted limit (19.8) removed 4.1 % of the held-out one-step error (z 1.3,
    not significant) and 48 % of the 25-step open-loop error. Fitting the noise in the start
    states does the opposite (it raises the long error: ``one_step_only``); on five noisy logs
    without an effect, no plausible candidate removed 2 % of the one-step error. On another log
    of the same limit (another seed) it did not fire, nor could it: its held-out episodes barely
    show the limit (the fit removes 0.3 % of the 25-step error there); on the first log, 90 % of
    the 48 % came from 5 of the 200 rollout starts, large events a rarely reached limit makes.

    A small effect can be clear at one step (by z) and still remove less than 2 % there (a draw under attitude feedback: a 0.97 kg payload beside an 11 ms delay; after the
    delay the payload removed 1.8 % of the one-step error at z 8.1 and 54 % of the 25-step
    error, motor strength 1.4 % at z 5.6 and 49 %). Both are checked, and the one that removes
    the most is taken, not the first in rank order: a simpler effect standing in for a richer
    one ranks first by its price.

    A candidate significant at one step that was checked and removes less than
    ``MIN_IMPROVEMENT`` of the longest-horizon error does not stand in the way (a draw: floor friction 0.63 + a 2.2 kg payload on the pace; after the floor's friction, joint
    friction removed 3.4 % of the one-step error at z 6.4 and 0.2 % of the 25-step error, too
    little to add, while the payload, 3.0 % at z 2.99, removes 86 % of the 25-step error).
    """
    if horizon.steps <= 1 or any(c.judgement.significant and not doubt(c) and not short_lived(c) for c in ranking):
        return
    pool = [c for c in ranking if not implausible(c.fit) and (
        c.judgement.removed >= MIN_IMPROVEMENT or c.judgement.z >= SIGNIFICANCE_Z)][:SCREENED]
    longer_gains(horizon, pool)
    best = max(pool, key=lambda c: c.longer_gain, default=None)
    if best is not None and best.longer_gain >= LARGE_IMPROVEMENT:
        best.judgement = replace(best.judgement, significant=True, by_longest=True)


def short_lived(c: Candidate) -> bool:
    """Whether ``c`` was checked at the longest horizon and removes less than ``MIN_IMPROVEMENT``
    of that error (it may still lower it: not ``one_step_only``)."""
    return c.longer_gain is not None and c.longer_gain < MIN_IMPROVEMENT


def prefer_simpler(ranking: list[Candidate], horizon: LongestHorizon | None = None) -> list[Candidate]:
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
    significantly better there and also removes ``LONGER_MARGIN`` more of the longest-horizon
    error (``longer_margin``). A draw of a 2.9 kg payload beside a 19 ms
    delay: after the delay, motor strength removed 92 % of what the payload removed at one step
    (z 4.0 between them), but the payload 75 % of the 25-step error against 70 %. Strength was
    added instead, and the payload never came back.
    """
    free = [c for c in ranking if not doubt(c)]
    if len(free) < 2 or not free[0].judgement.significant:
        return ranking
    best = free[0]
    for c in sorted(free[1:], key=lambda c: len(c.fit.x)):
        if len(c.fit.x) >= len(best.fit.x) or not c.judgement.significant:
            continue
        close = c.judgement.removed >= PARSIMONY_SHARE * best.judgement.removed
        gives_way = not better_at_one_step(best, c)
        if not gives_way:  # the richer one predicts one step significantly better: and further?
            margin = longer_margin(horizon, best, c)
            gives_way = (margin is not None and margin <= 0.0) or (close and (margin is None or margin < LONGER_MARGIN))
        if gives_way:
            out = [x for x in ranking if x is not c]
            out.insert(out.index(best), c)
            return out
    return ranking


def longer_margin(horizon: LongestHorizon | None, richer: Candidate, simpler: Candidate) -> float | None:
    """How much more of the open-loop error at the longest horizon ``richer`` removes than
    ``simpler`` (share of that error; None with one-step horizons only)."""
    if horizon is None or horizon.steps <= 1:
        return None
    longer_gains(horizon, [richer, simpler])
    return richer.longer_gain - simpler.longer_gain


def tied_with_best(ranking: list[Candidate]) -> list[Candidate]:
    """The best candidate not set aside (``doubt``) and those ``tied_with`` it. [] if none.

    A fresh draw of a 1.8 kg payload beside a 14.9 N m torque limit: after the limit, the payload
    removed 2.9 % of the one-step error and motor strength 2.6 % (z 0.8 between them), the
    payload's three centre-of-mass coordinates put strength first, and strength was added (0.90)
    though the payload predicted 25 steps clearly better.
    """
    free = [c for c in ranking if not doubt(c)]
    if len(free) < 2 or not free[0].judgement.significant:
        return []
    ties = tied_with(free[0], ranking)
    return [free[0], *ties] if ties else []


def tied_with(best: Candidate, ranking: list[Candidate]) -> list[Candidate]:
    """The significant, plausible candidates of ``ranking`` (``best`` aside) the held-out one step
    does not put behind ``best`` (``one_step_tie``), in rank order."""
    return [c for c in ranking if c is not best and c.judgement.significant and not doubt(c) and one_step_tie(best, c)]


def one_step_tie(best: Candidate, c: Candidate) -> bool:
    """Whether the held-out one step does not put ``c`` behind ``best`` (blocks of rows).

    Of no more parameters than ``best``: ``best`` does not predict significantly better (paired
    z < ``PARSIMONY_Z``). Of more: ``c`` removes at least as much of the one-step error and ranks
    behind only by the price of its parameters, unless it reproduces ``best`` (``Effect.reproduces``:
    both PD gains fit motor strength, and whatever else the PD's extra freedom absorbs)."""
    if len(c.fit.x) > len(best.fit.x):
        return c.judgement.removed >= best.judgement.removed and best.name not in c.fit.effect.reproduces
    return not better_at_one_step(best, c)


def better_at_one_step(a: Candidate, b: Candidate) -> bool:
    """Whether ``a`` predicts the held-out one step significantly better than ``b`` (paired z of
    the rows' errors, blocks of rows, >= ``PARSIMONY_Z``)."""
    return paired_z(b.judgement.row_errors - a.judgement.row_errors) >= PARSIMONY_Z


def tied_either_way(best: Candidate, ranking: list[Candidate]) -> list[Candidate]:
    """The candidates of ``ranking`` ``tied_with`` ``best``, and those that score at least as high
    with which ``best`` would be tied were they first: what the held-out one step leaves open
    beside ``best``, for the report. A richer ``best`` that ``prefer_longer`` put before a simpler
    one it predicts one step significantly better than is tied from the simpler one's side only (a
    fresh draw of a 1.2 kg payload beside a 3 ms delay: motor strength first by price, the payload
    z 3.4 better at one step). Not a candidate of no more parameters that predicts one step
    significantly better than ``best``: it is ahead, not tied (``add.other_starts`` starts chains
    past it)."""
    def ahead(c: Candidate) -> bool:
        return len(c.fit.x) <= len(best.fit.x) and better_at_one_step(c, best)

    return [c for c in ranking if c is not best and c.judgement.significant and not doubt(c) and not ahead(c)
            and (one_step_tie(best, c) or (c.score >= best.score and one_step_tie(c, best)))]


def ties_of(added: Candidate, ranking: list[Candidate]) -> list[Candidate]:
    """``Added.ties`` of an effect added as the ranked candidate ``added``: it first, then those
    ``tied_either_way`` with it; [] if none."""
    rivals = tied_either_way(added, ranking)
    return [added, *rivals] if rivals else []


def prefer_longer(ranking: list[Candidate]) -> list[Candidate]:
    """Put in the place of the best candidate the one ``tied_with_best`` that removes at least
    ``LONGER_MARGIN`` more of the open-loop error at the longest horizon (``longer_gain``, set
    by ``longer_gains``; the most, if several do).

    Where one step cannot tell two effects apart, the longer prediction can: the sensor noise in
    a measured start state enters the one step whole, a long prediction only at its start, while
    a physical effect acts at every step. On a noisy log with a 2 kg payload and joint damping
    0.4, after the payload, Coulomb friction predicted the held-out one step a little better
    than the hidden viscous damping (z 1.96 between them) and damping the 25 steps clearly
    better (it removed 71 % of that error, friction 61 %); on two more logs of the same
    effects, damping was first at both horizons.
    """
    ties = tied_with_best(ranking)
    if not ties or ties[0].longer_gain is None:
        return ranking
    best = ties[0]
    pick = max(ties[1:], key=lambda c: -np.inf if c.longer_gain is None else c.longer_gain)
    if pick.longer_gain is None or pick.longer_gain < best.longer_gain + LONGER_MARGIN:
        return ranking
    out = [x for x in ranking if x is not pick]
    out.insert(out.index(best), pick)
    return out


def paired_z(diff: np.ndarray) -> float:
    """mean / standard error of ``diff`` over blocks of consecutive rows."""
    blocks = diff[: len(diff) // BLOCK * BLOCK].reshape(-1, BLOCK).mean(1) if len(diff) >= 2 * BLOCK else diff
    se = float(blocks.std(ddof=1) / np.sqrt(len(blocks))) if len(blocks) > 1 else np.inf
    return float(diff.mean() / se) if se > 0 else (np.inf if diff.mean() > 0 else 0.0)
