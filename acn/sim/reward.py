"""The paper's per-step reward, one function for the environments and the evaluations.

    r_t = w1 v_x - w2 |tau_t|^2 - w3 |(roll, pitch)| - w4 |qdot|^2,   w = (1.0, 0.01, 0.5, 0.1)

from the state AFTER the step (s_{t+1}) and the mean applied joint torque over the step:
v_x trunk forward speed in the trunk (body) frame, m/s; tau joint torques, N m; roll and
pitch, rad; qdot joint velocities, rad/s.
"""

from __future__ import annotations

import numpy as np

from acn.sim.state import SLICES

REWARD_WEIGHTS: tuple[float, float, float, float] = (1.0, 0.01, 0.5, 0.1)  # the paper's w1..w4
TERM_NAMES: tuple[str, ...] = ("v_x", "torque_sq", "tilt", "joint_vel_sq")


def reward_terms(next_state: np.ndarray, effort: np.ndarray) -> np.ndarray:
    """(..., 4): v_x (m/s), |tau|^2 (N^2 m^2), |(roll, pitch)| (rad), |qdot|^2 (rad^2/s^2)."""
    s = np.asarray(next_state, dtype=np.float64)
    tau = np.asarray(effort, dtype=np.float64)
    return np.stack([s[..., SLICES["base_linvel"]][..., 0],
                     (tau ** 2).sum(-1),
                     np.linalg.norm(s[..., SLICES["base_rpy"]][..., :2], axis=-1),
                     (s[..., SLICES["joint_vel"]] ** 2).sum(-1)], axis=-1)


def weighted(terms: np.ndarray, weights: tuple[float, float, float, float] = REWARD_WEIGHTS) -> np.ndarray:
    """w1 v_x - w2 |tau|^2 - w3 |(roll, pitch)| - w4 |qdot|^2 from ``reward_terms`` (..., 4)."""
    w1, w2, w3, w4 = weights
    return np.asarray(terms) @ np.array([w1, -w2, -w3, -w4])


def reward(next_state: np.ndarray, effort: np.ndarray,
           weights: tuple[float, float, float, float] = REWARD_WEIGHTS) -> np.ndarray:
    """The per-step reward, (...,) for states (..., 43) and torques (..., 12)."""
    return weighted(reward_terms(next_state, effort), weights)
