"""The stance feet of measured states: which feet carry the robot, and where they put the frame
the trunk is measured in (``frame_from_stance``). The data check of the stance feet
(``acn.measurements.checks``), the frame's first guess and its kinematic check read them here.
"""

from __future__ import annotations

import numpy as np

from acn.sim.frames import unread
from acn.sim.kinematics import FOOT_RADIUS, RobotKinematics
from acn.sim.state import SLICES

MIN_STANCE_ROWS = 50  # rows needed for a kinematic estimate of the frame


class Stance:
    """Rows of measured states with a trunk pose, and the feet that carry the robot in them:
    those the log marks as touching, or without contact flags the lowest foot of each row (at
    most ``most`` rows, spread evenly). The data check of the stance feet, the frame's first
    guess and its kinematic check all read them here."""

    def __init__(self, states: np.ndarray, most: int = 2000) -> None:
        s = np.asarray(states, dtype=np.float64)
        pose = np.r_[SLICES["base_pos"], SLICES["base_rpy"], SLICES["joint_pos"]]
        rows = np.flatnonzero(np.isfinite(s[:, pose]).all(axis=1))
        self.s = s[rows[np.linspace(0, len(rows) - 1, min(most, len(rows))).astype(int)]] if len(rows) else s[:0]
        level = self.s.copy()
        level[:, SLICES["base_pos"]] = 0.0
        level[:, SLICES["base_rpy"]] = 0.0
        # (n, 4, 3) the feet in the trunk frame
        self.feet = RobotKinematics().poses(level).foot if len(level) else np.zeros((0, 4, 3))
        self.flags = self.s[:, SLICES["contact"]]
        self.marked = bool(np.isfinite(self.flags).all() and (self.flags > 0.5).any())

    def heights(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(n, 4) foot heights above the ground (m) with the trunk read in ``frame``, the (n, 4)
        stance mask, and (n, 3) the world's up axis in the trunk frame."""
        zeros = np.zeros((len(self.s), 3))
        pos, rot, *_ = unread(frame, self.s[:, SLICES["base_pos"]], self.s[:, SLICES["base_rpy"]], zeros, zeros)
        g = rot[:, 2, :]
        h = pos[:, None, 2] + np.einsum("nfi,ni->nf", self.feet, g) - FOOT_RADIUS
        stance = (self.flags > 0.5) if self.marked else h == h.min(axis=1, keepdims=True)
        return h, stance, g

    def carrying(self, frame: np.ndarray) -> np.ndarray:
        """Heights above the ground (m) of the feet carrying the robot, the trunk read in ``frame``."""
        h, stance, _ = self.heights(np.asarray(frame, dtype=np.float64))
        return h[stance]


def frame_from_stance(states: np.ndarray, most: int = 2000, iterations: int = 3) -> np.ndarray | None:
    """A first estimate of the measured frame (6,) from the feet on the ground, or None.

    The feet the log marks as touching (or, without contact flags, the lowest foot of each row)
    must be at ground height (z = 0, foot radius above) once the trunk is moved from the measured
    frame to the trunk's. For small angles a foot at ``f`` (trunk frame) seen from a frame at
    ``d`` rotated by ``theta`` sits at ``h0 - g . d - theta . (f x g)``, with ``h0`` its height as
    measured and ``g`` the world's up axis in the trunk frame: linear least squares in (d, roll,
    pitch), repeated (Gauss-Newton) from the trunk poses the last estimate gives. Yaw stays 0:
    on flat ground the feet cannot see it.
    """
    st = Stance(states, most)
    if len(st.s) < MIN_STANCE_ROWS:
        return None
    frame = np.zeros(6)
    for _ in range(iterations):
        h, stance, g = st.heights(frame)
        f, up = st.feet[stance], np.broadcast_to(g[:, None], st.feet.shape)[stance]
        if len(f) < MIN_STANCE_ROWS:
            return None
        a = np.column_stack([up, np.cross(f, up)[:, :2]])
        step, *_ = np.linalg.lstsq(a, h[stance], rcond=None)
        frame[:5] += step
    return frame
