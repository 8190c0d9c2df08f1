"""Are the measured states paired with the actions that drove them?

A logger that writes the last action sent together with the new observation pairs each state
with the action sent BEFORE it: the action that drives the step from row t to row t+1 stands in
row t+1. No physical effect of the catalogue undoes that (the actuator latency delays an action;
this one would have to act before it is sent), so the diagnosis reads it as an unexplained
error, and no check without a model can see it: at 50 Hz a joint follows its smooth targets so
closely that the next row's target predicts the step's accelerations better than the row's own
one in a consistent log too (R^2 0.55 against 0.49 on a noisy log from ``tests/robot_log.py``).
The simulator cannot be fooled by that: ``action_row`` re-simulates the model's one step from
the same measured states with each row's actions, the next row's and the previous row's, and
where the next row's leave at most ``SHIFT_SHARE`` of the others' error, clearly row by row, the
pairing is named.
"""

from __future__ import annotations

import numpy as np

from acn.datasets import checks
from acn.models.diagnose.problem import Problem
from acn.toolkit.effects import Model
from acn.toolkit.state import ACTION_NAMES

SHIFT_SHARE = 0.8   # the next row's actions leave at most this share of the one-step error of the row's own
                    # and of the previous row's (consistent logs from tests/robot_log.py: 1.05-4.2 at 50-500 Hz)
SHIFT_Z = 5.0       # ... lower than the row's own by at least this many standard errors, row by row
MIN_ROWS = 40


def action_row(problem: Problem, model: Model, rows: np.ndarray, residual: np.ndarray) -> checks.Finding | None:
    """The ``action_row`` finding where ``model``'s one step from ``rows`` (whose residual under the
    logged pairing is ``residual``, (N, C)) is far better with each row's next action than with its
    own and with its previous one; else None. The previous row's action is the other suspect: where
    it is as good, the actions alternate from row to row (a controller oscillating at half the
    control rate), and a logged action one row EARLY is what a command delay of one step does, which
    the catalogue's actuator_latency explains."""
    ok = np.isin(rows - 1, problem.data.windows(problem.unit + 2))  # the previous and next rows in the same run
    rows, residual = rows[ok], residual[ok]
    if len(rows) < MIN_ROWS:
        return None
    config = model.sim_config(problem.control)

    def error(shift: int) -> np.ndarray:
        """Per row: the one step's mean squared error with the actions of ``shift`` rows later."""
        return np.mean(problem.residual(problem.predict(config, rows, shift=shift), rows) ** 2, axis=1)

    own, nxt = np.mean(residual ** 2, axis=1), error(1)
    fine = np.isfinite(nxt)
    gain = (own - nxt)[fine]
    if fine.sum() < MIN_ROWS or nxt[fine].mean() > SHIFT_SHARE * own[fine].mean() \
            or gain.mean() < SHIFT_Z * gain.std(ddof=1) / np.sqrt(len(gain)):
        return None
    prev = error(-1)
    both = fine & np.isfinite(prev)
    if both.sum() < MIN_ROWS or nxt[both].mean() > SHIFT_SHARE * prev[both].mean():
        return None
    return checks.Finding(
        "action_row", tuple(f"action.{j}" for j in ACTION_NAMES),
        f"the actions look one row late: the model predicts each step with the NEXT row's action far better than "
        f"with the row's own (one-step error {nxt[fine].mean() / own[fine].mean():.0%} of it) or the previous "
        "row's: the log pairs each state with the action sent before it (the last action logged with the new "
        "observation); import it again with --shift-actions 1")
