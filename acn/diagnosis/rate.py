"""Was the log simulated at a coarser physics rate than the model's?

A log written by another simulator carries that simulator's time step (legged_gym steps the A1
at 5 ms, four physics steps per 50 Hz action); the model here steps at 1 kHz by default
(``acn-import --physics-hz``). Where the PD is gentle for that step the difference stays within
the noise: logs from ``tests/robot_log.py`` simulated at 200 Hz with legged_gym's gains (kp 20,
kd 0.5) diagnose at 1 kHz as ``none`` (nominal), joint damping 0.47 (true 0.5) and latency
12.7-13.5 ms (true 15), and at 500 Hz (Euler or implicit-fast) as at 1 kHz. With stiff gains at
a coarse step (kp 60, kd 1.5 at 5 ms) the simulated joints chatter from one physics step to the
next, the logged joint velocities no longer follow the angles, and no physical effect of the
catalogue undoes that: a nominal noisy 2 x 4 s log came out ``unexplained`` and a 15 ms latency
was not found, while imported with ``--physics-hz 200`` they came out ``none`` and 14.4 ms.

``physics_rate`` re-simulates the model's one step from the same measured states at coarser
rates (the control rate times ``RATES``, 100 Hz or more) and names the rate whose one-step error is at most
``RATE_SHARE`` of the model's own, clearly lower row by row. Measured (noisy logs, 50 Hz): the
chattering 200 Hz logs' one-step error at 200 Hz is 0.14 (nominal) and 0.20 (latency) of the
1 kHz model's (0.14 and 0.24 at a 100 Hz control rate); for 1 kHz logs (noisy: nominal, damping,
latency, kp x 0.7, kd x 0.5, armature, strength, backlash; noise-free: five of them) no coarser
rate is more than 2 % better (500 Hz: 0.99-1.19 of it, 200 Hz: 2.3-846); 200 Hz logs with
legged_gym's gains read 1.14-1.25 at 200 Hz noisy and 0.29-1.5 noise-free (not clearly lower row
by row: not named). None is named on those, on PyBullet's and MuJoCo's sides of ``make demo``'s
paired trot and its hidden-effect log, or on ``benchmarks/diagnose_cases.py``'s 25 standard and
other logs (4 x 10 s, with and without ``--feedback 1``). A chattering log whose main gap
is another effect (joint damping 0.5: 1.26) is not named either; the diagnosis then names the
effect, its value biased by the step (0.34 instead of 0.5).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from acn.measurements import checks
from acn.diagnosis.problem import Problem
from acn.sim.backends.base import MAX_PHYSICS_DT
from acn.sim.effects import Model

RATES = (1, 2, 3, 4, 5, 6, 8, 10)  # candidate physics steps per control step, below the model's own
RATE_SHARE = 0.5    # a candidate rate must leave at most this share of the model's one-step error
RATE_Z = 5.0        # ... lower than the model's by at least this many standard errors, row by row
MIN_ROWS = 40


def candidate_rates(control_hz: float, physics_hz: float) -> list[int]:
    """Physics rates (Hz) to try: the control rate times ``RATES``, at most half the model's and
    no coarser than a backend's coarsest step (``MAX_PHYSICS_DT``)."""
    return [round(m * control_hz) for m in RATES
            if 1.0 / MAX_PHYSICS_DT - 1e-9 <= m * control_hz <= physics_hz / 2 + 1e-9]


def physics_rate(problem: Problem, model: Model, rows: np.ndarray, residual: np.ndarray) -> checks.Finding | None:
    """The ``physics_rate`` finding where ``model``'s one step from ``rows`` (whose residual at the
    model's own rate is ``residual``, (N, C)) is far better at a coarser physics rate; else None."""
    if len(rows) < MIN_ROWS:
        return None
    config = model.sim_config(problem.control)
    control_hz, physics_hz = 1.0 / config.control_dt, 1.0 / config.physics_dt
    own = np.mean(residual ** 2, axis=1)
    best = None
    for hz in candidate_rates(control_hz, physics_hz):
        coarse = replace(config, physics_dt=1.0 / hz, substeps=round(hz / control_hz))
        with np.errstate(over="ignore", invalid="ignore"):
            err = np.mean(problem.residual_of(coarse, rows) ** 2, axis=1)
        fine = np.isfinite(err)
        if fine.mean() < 0.99:  # a rate at which the model diverges from measured states is not the log's
            continue
        share = err[fine].mean() / own[fine].mean()
        gain = (own - err)[fine]
        if share <= RATE_SHARE and gain.mean() >= RATE_Z * gain.std(ddof=1) / np.sqrt(len(gain)) \
                and (best is None or share < best[1]):
            best = (hz, share)
    if best is None:
        return None
    hz, share = best
    return checks.Finding(
        "physics_rate", (), f"the model predicts each step far better with physics at {hz} Hz than at its "
        f"{physics_hz:.0f} Hz (one-step error {share:.0%} of it): the log looks simulated at {hz} Hz (a simulator's "
        f"time step of {1e3 / hz:.3g} ms); import it again with --physics-hz {hz}")
