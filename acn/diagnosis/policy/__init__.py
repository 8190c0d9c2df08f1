"""The selection: which candidate effects to rank first, which to add, when to stop, which verdict.

Every rule the diagnosis chooses by lives in this package, one module per job: ``judging`` (a
candidate's significance, the plausibility of its values, fitting the noise), ``ranking``,
``adding`` (``greedy``), ``chains`` (``--auto``: ``revisit``, ``other_starts``) and ``verdicts``.
Every threshold of those rules is a field of ``Thresholds`` (``thresholds``; the defaults:
``THRESHOLDS``), handed to each rule as ``t``. The engine below it
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

from acn.diagnosis.policy.thresholds import THRESHOLDS, Thresholds
from acn.diagnosis.policy.judging import (Plausibility, at_bound, doubt, evidence, fits_noise, fits_noise_by_size,
                                          floor_after, floor_says_noise, implausible, judge, judgement, noise_fitted,
                                          one_step_only, plausibility, short_lived, significant, significant_gain,
                                          too_large, too_small, unidentified)
from acn.diagnosis.policy.ranking import (better_at_one_step, candidate, finer_look, longer_gains,
                                          needs_finer_look, noise_fits_last, one_step_tie, order,
                                          over_steps_from_realistic, prefer_longer, prefer_simpler, promised,
                                          promising, rank, screen, tied_either_way, tied_with, tied_with_best, ties_of,
                                          uneven)
from acn.diagnosis.policy.adding import (add_effect, added_fits_noise, choose_fit, final_doubt, fit_over_steps, greedy,
                                         left_over, nothing_left, out_of_time, refine_chain, too_little)
from acn.diagnosis.policy.chains import (auto, horizon_votes, improvement, other_starts, predicts_as_well,
                                         predicts_better, revisit)
from acn.diagnosis.policy.verdicts import NOT_ADDED, does_not_hold, holds_on_halves, verdict

__all__ = ["NOT_ADDED", "Plausibility", "THRESHOLDS", "Thresholds", "add_effect", "added_fits_noise", "at_bound",
           "auto", "better_at_one_step", "candidate", "choose_fit", "does_not_hold", "doubt", "evidence",
           "final_doubt", "finer_look", "fit_over_steps", "fits_noise", "fits_noise_by_size", "floor_after",
           "floor_says_noise", "greedy", "holds_on_halves", "horizon_votes", "implausible", "improvement", "judge",
           "judgement", "left_over", "longer_gains", "needs_finer_look", "noise_fits_last",
           "noise_fitted", "nothing_left", "one_step_only", "one_step_tie", "order", "out_of_time", "other_starts",
           "over_steps_from_realistic", "plausibility", "predicts_as_well", "predicts_better",
           "prefer_longer", "prefer_simpler", "promised", "promising", "rank", "refine_chain", "revisit", "screen",
           "short_lived", "significant", "significant_gain", "tied_either_way", "tied_with", "tied_with_best",
           "ties_of", "too_large", "too_little", "too_small", "uneven", "unidentified", "verdict"]
