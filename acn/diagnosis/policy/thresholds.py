"""Every threshold the diagnosis decides by, each with what it guards against.

``Thresholds`` is handed to every rule as ``t`` (the defaults: ``THRESHOLDS``); the figures that
set each value are in the docstrings of the rules that read it, and ``benchmarks/diagnose_cases.py
--threshold NAME=VALUE`` runs the benchmark with one set otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass

from acn.diagnosis.granularity import finer
from acn.diagnosis.heldout import structured_share


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
    # the verdict
    exact: float = 1e-3               # headline error under which a model reproduces the data: naming float32
    # storage's rounding (~1e-6)
    effect_share: float = 0.7         # of the structured error an effect must explain to be named: naming a


THRESHOLDS = Thresholds()
