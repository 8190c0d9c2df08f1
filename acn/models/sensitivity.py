"""The target simulator's control Jacobian J = d s_{t+1} / d a_t over one control step.

Central finite differences: from each recorded state, MuJoCo re-simulates the control step
(``substeps`` physics steps with the action held) for a +- eps on each action channel, in
batches through ``mujoco.rollout`` (threaded, no Python per physics step).
"""

from __future__ import annotations

import os

import mujoco
import mujoco.rollout
import numpy as np

from acn.toolkit.backends import SimConfig
from acn.toolkit.backends.mujoco_backend import MuJoCoBackend
from acn.toolkit.state import ACTION_DIM, STATE_NAMES


def control_jacobian(sim: SimConfig, states: np.ndarray, actions: np.ndarray, channels: list[str],
                     eps: float = 0.01, chunk: int = 128, threads: int | None = None) -> np.ndarray:
    """J (N, len(channels), 12): d(channels of s_{t+1}) / d a_t at each (state, action) row.

    ``eps`` is in action units (rad for joint targets, N m for torques).
    """
    backend = MuJoCoBackend(sim)
    m = backend.model
    threads = threads or min(os.cpu_count() or 1, 8)
    datas = [mujoco.MjData(m) for _ in range(threads)]
    index = np.array([STATE_NAMES.index(c) for c in channels])
    n = len(states)
    out = np.empty((n, len(channels), ACTION_DIM))
    bump = np.concatenate([np.eye(ACTION_DIM), -np.eye(ACTION_DIM)]) * eps  # (24, 12)
    with mujoco.rollout.Rollout(nthread=threads) as rollout:
        for lo in range(0, n, chunk):
            hi = min(lo + chunk, n)
            phys = np.stack([backend.physics_state(s) for s in states[lo:hi]])
            init = np.repeat(phys, len(bump), axis=0)
            ctrl = (actions[lo:hi, None, :] + bump[None]).reshape(-1, 1, ACTION_DIM)
            ctrl = np.repeat(ctrl, sim.substeps, axis=1)
            final = rollout.rollout([m] * len(init), datas, init, ctrl)[0][:, -1]
            nxt = np.stack([backend.state_from_physics(p)[index] for p in final])
            nxt = nxt.reshape(hi - lo, 2, ACTION_DIM, len(channels))
            diff = nxt[:, 0] - nxt[:, 1]
            # Angles: a bump cannot move them by pi, but their wrap point can sit between the two.
            diff = np.where(np.abs(diff) > np.pi, diff - np.sign(diff) * 2 * np.pi, diff)
            out[lo:hi] = np.swapaxes(diff, 1, 2) / (2 * eps)
    backend.close()
    return out
