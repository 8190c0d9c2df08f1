"""The state vector shared by every backend, dataset and model.

One flat float vector per time step. Channel names are part of the public contract:
they are written into each dataset's ``meta/info.json`` (feature ``names``) and
external tools index channels by these exact strings.

Frames and units
----------------
- ``base_pos_*``       trunk (base link) origin in the world frame, m.
- ``base_roll/pitch/yaw``  trunk orientation as extrinsic XYZ Euler angles
  (= intrinsic ZYX: yaw, then pitch, then roll), rad, world frame.
- ``<joint>_pos``      joint angle, rad.
- ``base_linvel_*``    trunk linear velocity, m/s, expressed in the trunk (body) frame.
- ``base_angvel_*``    trunk angular velocity, rad/s, expressed in the trunk (body) frame
  (what a gyroscope on the trunk reads).
- ``<joint>_vel``      joint velocity, rad/s.
- ``<foot>_contact``   1.0 if that foot touched the ground during the last physics step, else 0.0.
- ``imu_acc_*``        accelerometer on the trunk origin, body frame, m/s^2, gravity INCLUDED
  (specific force: reads about +9.81 on z when standing level). It is the mean over the
  last control step: (v_world(t) - v_world(t - dt_control)) / dt_control - g, rotated into
  the body frame at t. (A log may state that its sensor reads at the instant instead, over the
  last physics step: ``acn.imu_acc`` "instant" in the metadata, ``SimConfig.imu_acc``.)

Sensor channels (contacts, IMU) are readings of the last step, not dynamic state: a
backend's ``set_state`` writes the dynamic channels into the simulator and keeps the sensor
channels as the current reading until the next step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

JOINT_NAMES: tuple[str, ...] = (
    "FR_hip", "FR_thigh", "FR_calf",
    "FL_hip", "FL_thigh", "FL_calf",
    "RR_hip", "RR_thigh", "RR_calf",
    "RL_hip", "RL_thigh", "RL_calf",
)
FOOT_NAMES: tuple[str, ...] = ("FR", "FL", "RR", "RL")
NUM_JOINTS = len(JOINT_NAMES)

GROUPS: dict[str, tuple[str, ...]] = {
    "base_pos": ("base_pos_x", "base_pos_y", "base_pos_z"),
    "base_rpy": ("base_roll", "base_pitch", "base_yaw"),
    "joint_pos": tuple(f"{j}_pos" for j in JOINT_NAMES),
    "base_linvel": ("base_linvel_x", "base_linvel_y", "base_linvel_z"),
    "base_angvel": ("base_angvel_x", "base_angvel_y", "base_angvel_z"),
    "joint_vel": tuple(f"{j}_vel" for j in JOINT_NAMES),
    "contact": tuple(f"{f}_contact" for f in FOOT_NAMES),
    "imu_acc": ("imu_acc_x", "imu_acc_y", "imu_acc_z"),
}
STATE_NAMES: tuple[str, ...] = tuple(n for names in GROUPS.values() for n in names)
STATE_DIM = len(STATE_NAMES)
ACTION_NAMES: tuple[str, ...] = JOINT_NAMES
ACTION_DIM = NUM_JOINTS
# A hybrid (MIT-style) command's columns beside the joint targets: kp, kd, velocity target, feedforward torque.
HYBRID_NAMES: tuple[str, ...] = tuple(f"{g}.{j}" for g in ("kp", "kd", "vel", "torque") for j in ACTION_NAMES)

# Channels the simulator integrates (everything a re-simulation needs); the rest are sensors.
DYNAMIC_GROUPS = ("base_pos", "base_rpy", "joint_pos", "base_linvel", "base_angvel", "joint_vel")
SENSOR_GROUPS = ("contact", "imu_acc")
# Angles that wrap at +-pi and must be differenced on the circle.
WRAPPED_CHANNELS = ("base_roll", "base_pitch", "base_yaw")


def _slices() -> dict[str, slice]:
    out, i = {}, 0
    for g, names in GROUPS.items():
        out[g] = slice(i, i + len(names))
        i += len(names)
    return out


SLICES: dict[str, slice] = _slices()
WRAPPED_INDEX = np.array([STATE_NAMES.index(n) for n in WRAPPED_CHANNELS])


def wrap_angle(x: np.ndarray) -> np.ndarray:
    """Map angles (rad) into [-pi, pi)."""
    return (x + np.pi) % (2 * np.pi) - np.pi


@dataclass
class RobotState:
    """A state split into its parts; ``to_vector`` / ``from_vector`` give the flat layout."""

    base_pos: np.ndarray      # (3,) m, world
    base_rpy: np.ndarray      # (3,) rad, extrinsic XYZ
    joint_pos: np.ndarray     # (12,) rad
    base_linvel: np.ndarray   # (3,) m/s, body frame
    base_angvel: np.ndarray   # (3,) rad/s, body frame
    joint_vel: np.ndarray     # (12,) rad/s
    contact: np.ndarray       # (4,) 0/1
    imu_acc: np.ndarray       # (3,) m/s^2, body frame, gravity included

    def to_vector(self) -> np.ndarray:
        return np.concatenate([np.asarray(getattr(self, g), dtype=np.float64) for g in GROUPS])

    @classmethod
    def from_vector(cls, v: np.ndarray) -> "RobotState":
        v = np.asarray(v, dtype=np.float64)
        if v.shape != (STATE_DIM,):
            raise ValueError(f"state vector must have shape ({STATE_DIM},), got {v.shape}")
        return cls(**{g: v[s].copy() for g, s in SLICES.items()})
