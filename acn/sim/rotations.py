"""Quaternion and Euler conversions shared by both backends.

Quaternions here are scalar-LAST ``(x, y, z, w)`` (PyBullet's order); the MuJoCo backend
converts to MuJoCo's scalar-first order at its boundary. Euler angles are extrinsic XYZ
(roll about world x, then pitch about world y, then yaw about world z), the convention of
``pybullet.getEulerFromQuaternion``.
"""

from __future__ import annotations

import numpy as np


def quat_to_rpy(q: np.ndarray) -> np.ndarray:
    """(x, y, z, w) -> (roll, pitch, yaw) in rad."""
    x, y, z, w = q
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.array([roll, pitch, yaw])


def rpy_to_quat(rpy: np.ndarray) -> np.ndarray:
    """(roll, pitch, yaw) in rad -> unit quaternion (x, y, z, w)."""
    cr, sr = np.cos(rpy[0] / 2), np.sin(rpy[0] / 2)
    cp, sp = np.cos(rpy[1] / 2), np.sin(rpy[1] / 2)
    cy, sy = np.cos(rpy[2] / 2), np.sin(rpy[2] / 2)
    return np.array([
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    ])


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(x, y, z, w) -> 3x3 rotation matrix R (body-to-world: v_world = R @ v_body)."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b for 3-vectors (np.cross is ~20x slower on this size)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def rpy_rate_to_body(rpy: np.ndarray, rate: np.ndarray) -> np.ndarray:
    """Body-frame angular velocity from extrinsic-XYZ Euler angles and their rates (N, 3)."""
    r, p, _ = rpy.T
    dr, dp, dy = rate.T
    # omega_body for R = Rz(y) Ry(p) Rx(r)
    wx = dr - np.sin(p) * dy
    wy = np.cos(r) * dp + np.sin(r) * np.cos(p) * dy
    wz = -np.sin(r) * dp + np.cos(r) * np.cos(p) * dy
    return np.stack([wx, wy, wz], axis=1)


def rpy_to_matrices(rpy: np.ndarray) -> np.ndarray:
    """(N, 3) extrinsic-XYZ Euler angles -> (N, 3, 3) body-to-world rotation matrices."""
    return np.moveaxis(np.array(quat_to_matrix(np.array(rpy_to_quat(np.asarray(rpy).T)))), -1, 0)
