"""Where the state's trunk channels are measured: the trunk link frame, or a frame fixed to the
trunk off it (``ModelParams.base_frame_offset``, the catalogue's ``base_frame_offset``).

A motion-capture rigid body, an IMU mounted askew, or the inertial frame PyBullet reports
(``getBasePositionAndOrientation`` gives the centre of mass and the principal axes) measure the
trunk in a frame M rigidly attached to it: origin at ``d`` (m, trunk frame), axes rotated by
``R_o`` (extrinsic-XYZ roll, pitch, yaw, rad) from the trunk's. With the trunk link at ``p``,
rotation ``R`` (body to world), linear velocity ``v`` and angular velocity ``w`` (both in the
body frame), the state reads

    base_pos = p + R d,   base_rpy = rpy(R R_o),   base_angvel = R_o^T w,
    base_linvel = R_o^T (v + w x d),   imu_acc = R_o^T a   (a: the trunk origin's specific force)

``read`` applies this to many rows at once, ``unread`` inverts it; ``state_in_frame`` and
``state_in_trunk`` do the same on state vectors, for the backends and the rollout layout alike,
and leave rows whose frame is the trunk's (all six values 0) as they were, bit for bit.
"""

from __future__ import annotations

import numpy as np

from acn.sim.rotations import rpy_to_matrices
from acn.sim.state import SLICES


def matrices_to_rpy(rot: np.ndarray) -> np.ndarray:
    """(N, 3, 3) body-to-world rotation matrices -> (N, 3) extrinsic-XYZ Euler angles, rad."""
    roll = np.arctan2(rot[:, 2, 1], rot[:, 2, 2])
    pitch = np.arcsin(np.clip(-rot[:, 2, 0], -1.0, 1.0))
    yaw = np.arctan2(rot[:, 1, 0], rot[:, 0, 0])
    return np.stack([roll, pitch, yaw], axis=1)


def _parts(frame: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    f = np.broadcast_to(np.asarray(frame, dtype=np.float64), (n, 6))
    return f[:, :3], rpy_to_matrices(f[:, 3:])


def _mat_vec(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("nij,nj->ni", m, v)


def _mat_t_vec(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("nji,nj->ni", m, v)


def read(frame: np.ndarray, pos: np.ndarray, rot: np.ndarray, v_body: np.ndarray, w_body: np.ndarray,
         acc_body: np.ndarray | None = None):
    """The trunk link's (N, 3) position, (N, 3, 3) rotation, (N, 3) body-frame velocities and
    specific force -> what frame (N, 6) or (6,) [x, y, z, roll, pitch, yaw] reads: position,
    (N, 3) rpy, linear and angular velocity, specific force (None stays None)."""
    n = len(pos)
    d, r_o = _parts(frame, n)
    pos_m = pos + _mat_vec(rot, d)
    rpy_m = matrices_to_rpy(rot @ r_o)
    v_m = _mat_t_vec(r_o, v_body + np.cross(w_body, d))
    w_m = _mat_t_vec(r_o, w_body)
    acc_m = None if acc_body is None else _mat_t_vec(r_o, acc_body)
    return pos_m, rpy_m, v_m, w_m, acc_m


def unread(frame: np.ndarray, pos_m: np.ndarray, rpy_m: np.ndarray, v_m: np.ndarray, w_m: np.ndarray,
           acc_m: np.ndarray | None = None):
    """Inverse of ``read``: the frame's readings (N, 3 each) -> the trunk link's position,
    (N, 3, 3) rotation, body-frame linear and angular velocities, specific force (None stays None)."""
    n = len(pos_m)
    d, r_o = _parts(frame, n)
    rot = rpy_to_matrices(rpy_m) @ np.transpose(r_o, (0, 2, 1))
    w_body = _mat_vec(r_o, w_m)
    v_body = _mat_vec(r_o, v_m) - np.cross(w_body, d)
    acc_body = None if acc_m is None else _mat_vec(r_o, acc_m)
    return pos_m - _mat_vec(rot, d), rot, v_body, w_body, acc_body


_READ = ("base_pos", "base_rpy", "base_linvel", "base_angvel", "imu_acc")  # the channels a frame changes


def _moved(states: np.ndarray, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    s = np.array(states, dtype=np.float64)  # a copy
    f = np.broadcast_to(np.asarray(frame, dtype=np.float64), (len(s), 6))
    rows = np.flatnonzero(f.any(axis=1))
    return s, f[rows], rows


def state_in_frame(states: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """(N, 43) states read in the trunk link frame -> the same states read in ``frame`` (N, 6) or (6,)."""
    s, f, rows = _moved(states, frame)
    if len(rows):
        t = s[rows]
        values = read(f, t[:, SLICES["base_pos"]], rpy_to_matrices(t[:, SLICES["base_rpy"]]),
                      t[:, SLICES["base_linvel"]], t[:, SLICES["base_angvel"]], t[:, SLICES["imu_acc"]])
        for g, v in zip(_READ, values):
            s[rows, SLICES[g]] = v
    return s


def state_in_trunk(states: np.ndarray, frame: np.ndarray) -> np.ndarray:
    """Inverse of ``state_in_frame``: (N, 43) states read in ``frame`` -> read in the trunk link frame."""
    s, f, rows = _moved(states, frame)
    if len(rows):
        t = s[rows]
        pos, rot, v, w, acc = unread(f, *(t[:, SLICES[g]] for g in _READ))
        for g, value in zip(_READ, (pos, matrices_to_rpy(rot), v, w, acc)):
            s[rows, SLICES[g]] = value
    return s
