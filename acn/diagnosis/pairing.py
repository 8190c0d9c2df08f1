"""Are the measured states paired with the actions that drove them?

A logger that writes the last action sent together with the new observation pairs each state
with the action sent BEFORE it: the action that drives the step from row t to row t+1 stands in
row t+1. No physical effect of the catalogue undoes that (the actuator latency delays an action;
this one would have to act before it is sent), so the diagnosis reads it as an unexplained
error, and no check without a model can see it: at 50 Hz a joint follows its smooth targets so
closely that the next row's target predicts the step's accelerations better than the row's own
one in a consistent log too (R^2 0.55 against 0.49 on a noisy log from ``tests/robot_log.py``).
The simulator cannot be fooled by that: ``action_row`` re-simulates the model's one step from
the same measured states with the actions delayed by a grid of latencies that runs from minus
one control period (the next row's actions) to plus one (the previous row's): an action logged
one row late on a robot with latency L acts L - T after its row, before it. Where the best
negative delay leaves at most ``SHIFT_SHARE`` of the best non-negative one's error, clearly row
by row, the pairing is named. With a latency of its own below the period such a log is named
too (the best non-negative delay is then 0 while the truth is L - T < 0): the first version,
which compared the next row's action with the row's own at the model's latency, missed a late
log with a 15 ms latency (93 % of the error). At or above one period the two are the same
physics, and a late log reads as a latency one period shorter.
"""

from __future__ import annotations

import numpy as np

from acn.measurements import checks
from acn.diagnosis.problem import Problem
from acn.sim.effects import Model, get_effect
from acn.sim.state import ACTION_NAMES

SHIFT_SHARE = 0.8   # the best negative delay leaves at most this share of the best non-negative one's
                    # one-step error (consistent logs from tests/robot_log.py: 1.0 exactly, where they agree)
SHIFT_Z = 5.0       # ... lower than the best non-negative delay's by at least this many standard errors, row by row
MIN_ROWS = 40


def action_row(problem: Problem, model: Model, rows: np.ndarray, residual: np.ndarray) -> checks.Finding | None:
    """The ``action_row`` finding where ``model``'s one step from ``rows`` is far better with the
    actions acting before their rows (module docstring) than at any latency from 0 to one control
    period; else None. ``residual``: the rows' residual under the logged pairing, (N, C) (used
    only for its finite rows). The previous row's action (a latency of one period) is among the
    non-negative delays: where it is as good, the actions alternate from row to row (a controller
    oscillating at half the control rate); a logged action one row EARLY is what a command delay
    of one step does, which the catalogue's actuator_latency explains."""
    ok = np.isin(rows - 1, problem.data.windows(problem.unit + 2))  # the previous and next rows in the same run
    rows = rows[ok & np.isfinite(residual).all(1)]
    if len(rows) < MIN_ROWS:
        return None
    period = problem.control.control_dt
    latency = get_effect("actuator_latency")

    def error(shift: int, quarters: int) -> np.ndarray:
        """Per row: the one step's mean squared error with the actions of ``shift`` rows later,
        delayed by ``quarters`` quarters of the control period."""
        m = model.with_effect(latency, {"seconds": quarters * period / 4})
        return np.mean(problem.residual_of(m.sim_config(problem.control), rows, shift=shift) ** 2, axis=1)

    # delays -T, -3T/4, ..., -T/4 are the next row's actions at 0 .. 3T/4; 0 .. T are the row's own
    before = [error(1, k) for k in range(4)]
    after = [error(0, k) for k in range(5)]
    best = lambda errs: min(errs, key=lambda e: np.nanmean(e) if np.isfinite(e).mean() > 0.5 else np.inf)  # noqa: E731
    early, own = best(before), best(after)
    fine = np.isfinite(early) & np.isfinite(own)
    gain = (own - early)[fine]
    if fine.sum() < MIN_ROWS or early[fine].mean() > SHIFT_SHARE * own[fine].mean() \
            or gain.mean() < SHIFT_Z * gain.std(ddof=1) / np.sqrt(len(gain)):
        return None
    return checks.Finding(
        "action_row", tuple(f"action.{j}" for j in ACTION_NAMES),
        f"the actions look one row late: the model predicts each step far better with each action acting before "
        f"its row, from the next row on (one-step error {early[fine].mean() / own[fine].mean():.0%} of the best "
        "with the row's own action at any latency up to one control period): the log pairs each state with the "
        "action sent before it (the last action logged with the new observation); import it again with "
        "--shift-actions 1")
