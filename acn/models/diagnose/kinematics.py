"""A first guess for encoder offsets from leg kinematics: feet in contact rest on the floor.

With offsets o the true joint angles are ``reading - o``. Forward kinematics (MuJoCo
``mj_kinematics``) from the measured trunk pose must put every foot the measurements report in
contact at one common height (the foot sphere's radius minus the contact's small penetration),
and a foot that stays in contact from one step to the next does not slide. Gauss-Newton on
these residuals over many rows gives the 12 offsets without simulating any dynamics; a
dynamic fit started there converges where one started at zero gets lost among contacts.
"""

from __future__ import annotations

import mujoco
import numpy as np

from acn.models.diagnose.problem import Problem
from acn.toolkit.backends import SimConfig
from acn.toolkit.backends.mujoco_backend import PhysicsLayout, build_spec
from acn.toolkit.state import FOOT_NAMES, SLICES

FD = 1e-4  # rad, finite-difference step


class _Feet:
    """Foot positions (N, 4, 3) in the world for states read with given encoder offsets."""

    def __init__(self) -> None:
        self.model = build_spec(SimConfig()).compile()
        self.data = mujoco.MjData(self.model)
        self.layout = PhysicsLayout(self.model)
        self.geoms = [self.model.geom(f"{f}_foot").id for f in FOOT_NAMES]
        self.radius = float(self.model.geom_size[self.geoms[0], 0])

    def __call__(self, states: np.ndarray, offset: np.ndarray) -> np.ndarray:
        m, d, nq = self.model, self.data, self.model.nq
        physics = self.layout.to_physics(states, offset)
        out = np.empty((len(states), len(self.geoms), 3))
        for i, p in enumerate(physics):
            d.qpos[:] = p[1:1 + nq]
            mujoco.mj_kinematics(m, d)
            out[i] = d.geom_xpos[self.geoms]
        return out


def stance_offsets(problem: Problem, rows: int = 400, iterations: int = 8) -> np.ndarray | None:
    """(12,) encoder offsets, rad, from the stance kinematics of fit rows; None if the
    measurements lack the contacts or the trunk pose, or too few feet are on the ground."""
    d = problem.data
    needed = [*range(SLICES["base_pos"].start, SLICES["base_rpy"].stop), *range(SLICES["contact"].start,
                                                                                   SLICES["contact"].stop)]
    if any(name in d.missing for name in (*(f"{f}_contact" for f in FOOT_NAMES), "base_pos_z", "base_roll")):
        return None
    pick = problem.sample(problem.fit_rows, rows, salt=6)
    pick = pick[np.isfinite(d.state[pick][:, needed]).all(1)]
    nxt = pick + 1
    linked = (nxt < len(d)) & (d.episode[np.minimum(nxt, len(d) - 1)] == d.episode[pick])
    now, later = d.state[pick], d.state[np.minimum(nxt, len(d) - 1)]
    stance = now[:, SLICES["contact"]] > 0.5
    stays = stance & (later[:, SLICES["contact"]] > 0.5) & linked[:, None]
    if stance.sum() < 24:
        return None
    feet = _Feet()

    def residual(x: np.ndarray) -> np.ndarray:
        offset, height = x[:12], x[12]
        p_now, p_later = feet(now, offset), feet(later, offset)
        z = (p_now[..., 2] - height)[stance]
        slide = (p_later[..., :2] - p_now[..., :2])[stays].ravel()
        return np.concatenate([z, slide])

    x = np.zeros(13)
    x[12] = feet.radius
    for _ in range(iterations):
        r = residual(x)
        jac = np.stack([(residual(x + FD * e) - r) / FD for e in np.eye(13)], axis=1)
        step = np.linalg.lstsq(jac, -r, rcond=None)[0]
        x = x + np.clip(step, -0.2, 0.2)
        if np.abs(step[:12]).max() < 1e-5:
            break
    return np.clip(x[:12], -0.5, 0.5)
