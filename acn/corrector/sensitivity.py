"""The target simulator's control sensitivity d s_{t+1} / d a_t over one control step.

Finite differences through ``acn.sim.resim.Resimulator``: each row is re-simulated once
with its action and once per bumped action channel, all rows and bumps in one batch
(``mujoco.rollout`` on a thread pool for MuJoCo). Channel differences wrap angles.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acn.sim.resim import Resimulator
from acn.sim.state import ACTION_DIM, STATE_NAMES, WRAPPED_INDEX, wrap_angle


def channel_index(channels: list[str] | tuple[str, ...]) -> np.ndarray:
    """Indices of named channels in the state vector."""
    return np.array([STATE_NAMES.index(c) for c in channels])


def channel_difference(a: np.ndarray, b: np.ndarray, index: np.ndarray) -> np.ndarray:
    """a - b for arrays over the channels ``index`` (last axis), angles differenced on the circle."""
    d = a - b
    wrapped = np.isin(index, WRAPPED_INDEX)
    if wrapped.any():
        d[..., wrapped] = wrap_angle(d[..., wrapped])
    return d


@dataclass
class Sensitivity:
    """Predictions at N (state, action) rows and their derivatives with respect to the action."""

    next: np.ndarray             # (N, C) the chosen channels of s_{t+1}
    jacobian: np.ndarray         # (N, C, 12) d next / d a
    effort: np.ndarray           # (N, 12) mean applied joint torque over the step, N m
    effort_jacobian: np.ndarray  # (N, 12, 12) d effort / d a
    diverged: np.ndarray         # (N,) any re-simulation of the row blew up (its values are NaN)


def finite_differences(resim: Resimulator, states: np.ndarray, actions: np.ndarray, channels: np.ndarray,
                       eps: float = 0.01, central: bool = False,
                       previous: np.ndarray | None = None) -> Sensitivity:
    """Prediction and sensitivity at each (state, action) row, from one ``Resimulator.run``.

    ``channels``: state-vector indices to return. ``eps`` in action units (rad for joint
    targets, N m for torques). Forward differences: 1 + 12 re-simulations per row; central:
    1 + 24.
    """
    n = len(states)
    eye = np.eye(ACTION_DIM) * eps
    bumps = np.concatenate([np.zeros((1, ACTION_DIM)), eye] + ([-eye] if central else []))  # (B, 12)
    b = len(bumps)
    acts = (np.asarray(actions, float)[:, None, :] + bumps[None]).reshape(n * b, ACTION_DIM)
    prev = None if previous is None else np.repeat(np.asarray(previous, float), b, axis=0)
    pred = resim.run(np.repeat(np.asarray(states, float), b, axis=0), acts, previous=prev)
    nxt = pred.state[:, 0, channels].reshape(n, b, len(channels))
    eff = pred.effort[:, 0].reshape(n, b, ACTION_DIM)
    diverged = pred.diverged.reshape(n, b).any(axis=1)
    step = 2 * eps if central else eps
    lo = slice(1 + ACTION_DIM, None) if central else slice(0, 1)
    jac = np.swapaxes(channel_difference(nxt[:, 1:1 + ACTION_DIM], nxt[:, lo], channels), 1, 2) / step
    eff_jac = np.swapaxes(eff[:, 1:1 + ACTION_DIM] - eff[:, lo], 1, 2) / step
    return Sensitivity(nxt[:, 0], jac, eff[:, 0], eff_jac, diverged)


def control_jacobian(resim: Resimulator, states: np.ndarray, actions: np.ndarray, channels: list[str],
                     eps: float = 0.01, previous: np.ndarray | None = None) -> np.ndarray:
    """J (N, len(channels), 12): d(channels of s_{t+1}) / d a_t by central differences."""
    return finite_differences(resim, states, actions, channel_index(channels), eps, central=True,
                              previous=previous).jacobian
