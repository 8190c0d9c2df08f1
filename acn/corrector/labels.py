"""Gauss-Newton action labels: the correction delta_a that makes the target reach a goal state.

For N rows (state s, action a, goal s*), each independently:

    delta_a* = argmin_d  || W (s* - T_tgt(s, a + d)) ||^2        over the 33 output channels

with T_tgt one control step of the target re-simulated from s (``Resimulator``) and
W = diag(1 / channel scale) (``weights``: the training spread of each channel). Solver
(``SolveConfig``): ``iterations`` Levenberg-Marquardt steps, each from one Resimulator call
of N x 13 rows (a + d and the 12 forward-difference bumps of ``fd_eps``),

    (J^T J + damping * tr(J^T J) / 12 * I) step = J^T r,    step clipped to +- max_step,

then ``broyden`` quasi-Newton steps that update J from the last step (one re-simulation per
row each), and one last evaluation. Every iterate's error is evaluated; each row keeps the best
d seen (d = 0 included), so a label never makes the one-step error worse than no correction.

Uses: same-state labels (goal = the recorded source s'_src, state = the source's s_t: the
target re-simulated from the SOURCE state, not two drifted trajectories), labels at states a
corrected robot visits (goal = the source re-simulated from there) and both oracles
(``acn.corrector.oracle``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from acn.corrector.sensitivity import channel_difference, finite_differences
from acn.sim.resim import Resimulator
from acn.sim.state import ACTION_DIM


@dataclass
class SolveConfig:
    """The Gauss-Newton / Levenberg-Marquardt solve of ``solve``."""

    iterations: int = 2        # LM steps with a finite-difference Jacobian (13 re-simulations per row each)
    broyden: int = 1           # further steps with a Broyden-updated Jacobian (1 re-simulation per row each)
    fd_eps: float = 0.01       # action units (rad for joint targets)
    damping: float = 0.01      # LM ridge, relative to the mean diagonal of J^T J
    max_step: float = 0.5      # action units, per channel and step

    def validate(self) -> None:
        if self.iterations < 1 or self.broyden < 0:
            raise ValueError("the solve needs iterations >= 1 and broyden >= 0")
        if not (self.fd_eps > 0 and self.damping >= 0 and self.max_step > 0):
            raise ValueError("fd_eps and max_step must be > 0, damping >= 0")

    @property
    def resims_per_row(self) -> int:
        return self.iterations * (1 + ACTION_DIM) + self.broyden + 1


@dataclass
class Solution:
    """The labels of N rows and what they achieve (errors are squared weighted norms)."""

    delta: np.ndarray         # (N, 12) delta_a*, action units; 0 where diverged
    error_before: np.ndarray  # (N,) || W (s* - T(s, a)) ||^2 (+ the effort term when matched)
    error_after: np.ndarray   # (N,) the same at a + delta
    residual: np.ndarray      # (N, C) s* - T(s, a), channel units (same-state gap when s* = s'_src)
    jacobian: np.ndarray      # (N, C, 12) d T(s, a) / d a at delta = 0, channel units
    diverged: np.ndarray      # (N,) bool: the re-simulation at a blew up (row unusable)
    resim_seconds: float = 0.0  # wall time inside Resimulator.run (the simulator's share of the solve)

    @property
    def removed(self) -> float:
        """Share of the summed one-step error the labels remove."""
        ok = ~self.diverged
        return float(1.0 - self.error_after[ok].sum() / max(self.error_before[ok].sum(), 1e-300))


def solve(resim: Resimulator, states: np.ndarray, actions: np.ndarray, goals: np.ndarray, channels: np.ndarray,
          weights: np.ndarray, cfg: SolveConfig | None = None, previous: np.ndarray | None = None,
          goal_effort: np.ndarray | None = None, effort_weights: np.ndarray | None = None) -> Solution:
    """delta_a* per row (module docstring). ``goals`` (N, 43) or (N, C) over ``channels``.

    With ``goal_effort`` (N, 12) and ``effort_weights`` (12,), 1 / N m: the mean applied torque
    over the step is matched too, || W_e (tau* - tau(s, a + d)) ||^2 added to the error.
    """
    cfg = cfg or SolveConfig()
    cfg.validate()
    states, actions = np.asarray(states, float), np.asarray(actions, float)
    goals = np.asarray(goals, float)
    if goals.shape[1] != len(channels):
        goals = goals[:, channels]
    n, w = len(states), np.asarray(weights, float)
    effort = goal_effort is not None and effort_weights is not None
    we = np.asarray(effort_weights, float) if effort else None
    delta = np.zeros((n, ACTION_DIM))
    best_delta, best_err = delta.copy(), np.full(n, np.inf)
    first = None
    jac = step = r_prev = None
    t_resim = 0.0
    for it in range(cfg.iterations + cfg.broyden + 1):
        full = it < cfg.iterations
        t0 = time.perf_counter()
        if full:
            sens = finite_differences(resim, states, actions + delta, channels, cfg.fd_eps, previous=previous)
            nxt, j_raw, tau, bad = sens.next, sens.jacobian, sens.effort, sens.diverged
        else:
            p = resim.run(states, actions + delta, previous=previous)
            nxt, tau, bad = p.state[:, 0, channels], p.effort[:, 0], p.diverged
        t_resim += time.perf_counter() - t0
        r = channel_difference(goals, nxt, channels)
        rw = w * r
        if effort:
            rw = np.concatenate([rw, we * (goal_effort - tau)], axis=1)
        err = np.where(bad, np.inf, (rw ** 2).sum(axis=1))
        if it == 0:
            first = (r.copy(), err.copy(), j_raw.copy(), bad.copy())
        better = err < best_err
        best_err[better], best_delta[better] = err[better], delta[better]
        if it == cfg.iterations + cfg.broyden:
            break
        if full:
            jac = w[None, :, None] * np.nan_to_num(j_raw)
            if effort:
                jac = np.concatenate([jac, we[None, :, None] * np.nan_to_num(sens.effort_jacobian)], axis=1)
        else:  # Broyden: the weighted prediction changed by -(r - r_prev) under the last step
            dy = np.nan_to_num(r_prev - rw)
            jac = jac + np.einsum("nc,ni->nci", dy - np.einsum("nci,ni->nc", jac, step), step) \
                / ((step * step).sum(axis=1) + 1e-12)[:, None, None]
        jtj = np.einsum("nci,ncj->nij", jac, jac)
        ridge = cfg.damping * np.trace(jtj, axis1=1, axis2=2) / ACTION_DIM + 1e-12
        rhs = np.einsum("nci,nc->ni", jac, np.nan_to_num(rw))
        step = np.linalg.solve(jtj + ridge[:, None, None] * np.eye(ACTION_DIM), rhs[..., None])[..., 0]
        step = np.clip(step, -cfg.max_step, cfg.max_step)
        step[bad] = 0.0
        r_prev, delta = rw, delta + step
    r0, err0, j0, bad0 = first
    best_delta[bad0] = 0.0
    return Solution(delta=best_delta, error_before=np.where(bad0, np.nan, err0),
                    error_after=np.where(bad0, np.nan, np.minimum(best_err, err0)),
                    residual=r0, jacobian=j0, diverged=bad0, resim_seconds=t_resim)
