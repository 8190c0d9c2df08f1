"""The Unitree A1 description both simulators are built from.

Source: ``pybullet_data/a1/a1.urdf`` (shipped with pybullet). PyBullet loads it directly;
MuJoCo compiles the same file through ``mujoco.MjSpec``. Everything a backend needs to
build the model (file, joint map, stance, gains, nominal physical parameters) is here, so
the two backends cannot drift apart.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from acn.sim.state import FOOT_NAMES, JOINT_NAMES, NUM_JOINTS

# Our joint names -> the URDF's joint names (the URDF says upper/lower for thigh/calf).
URDF_JOINT: dict[str, str] = {
    j: j.replace("_thigh", "_upper_joint").replace("_calf", "_lower_joint").replace("_hip", "_hip_joint")
    for j in JOINT_NAMES
}
URDF_FOOT_LINK: dict[str, str] = {f: f"{f}_toe" for f in FOOT_NAMES}
TRUNK_LINK = "trunk"

# Stance (rad): hip 0, thigh 0.8, calf -1.6 for every leg; feet straight under the hips.
STANCE = np.tile(np.array([0.0, 0.8, -1.6]), 4)
# Trunk height (m) at which the stance feet (sphere radius 0.02 m) just touch flat ground:
# 0.2*cos(0.8) + 0.2*cos(-0.8) + 0.02 = 0.2987 m, rounded up by 1.3 mm.
STANDING_HEIGHT = 0.30
GRAVITY = 9.81  # m/s^2, along -z of the world frame
# s, MuJoCo's default contact time constant (``solref[0]``, damping ratio 1): the nominal ground.
# Nominal PyBullet keeps its own rigid contact (``ModelParams`` table).
GROUND_TIMECONST = 0.02


def urdf_path() -> str:
    """Absolute path of the A1 URDF inside the installed ``pybullet_data``."""
    import pybullet_data

    path = os.path.join(pybullet_data.getDataPath(), "a1", "a1.urdf")
    if not os.path.exists(path):
        raise FileNotFoundError(f"A1 URDF not found at {path}; is pybullet installed?")
    return path


def joint_limits() -> np.ndarray:
    """(12, 2) lower and upper joint angle of each joint (rad, ``JOINT_NAMES`` order), from the URDF."""
    import xml.etree.ElementTree as ET

    limits = {j.get("name"): j.find("limit") for j in ET.parse(urdf_path()).getroot().iter("joint")
              if j.find("limit") is not None}
    return np.array([[float(limits[URDF_JOINT[j]].get(k)) for k in ("lower", "upper")] for j in JOINT_NAMES])


def combine_point_mass(mass: float, com: np.ndarray, inertia: np.ndarray, m_p: float, p: np.ndarray):
    """A rigid body (mass kg, COM m, 3x3 inertia about the COM) plus a point mass at ``p``.

    Returns (mass, COM, 3x3 inertia about the new COM), all in the body frame.
    """
    total = mass + m_p
    c = (mass * com + m_p * p) / total

    def shift(m: float, r: np.ndarray) -> np.ndarray:  # parallel-axis term of mass m at offset r
        return m * (r @ r * np.eye(3) - np.outer(r, r))

    return total, c, inertia + shift(mass, com - c) + shift(m_p, p - c)


JOINT_FIELDS = ("joint_damping", "joint_friction", "armature", "motor_strength", "torque_limit", "kp_scale",
                "kd_scale", "encoder_offset", "backlash", "torque_speed")


def per_joint(value, default: float = 0.0) -> np.ndarray:
    """(12,) values in ``JOINT_NAMES`` order of a setting given once (a number) or per joint
    (12 numbers); None gives ``default`` on every joint."""
    v = default if value is None else value
    return np.broadcast_to(np.asarray(v, dtype=float), (NUM_JOINTS,)).copy()


@dataclass
class ModelParams:
    """The physical description beyond the URDF; both backends realise every field.

    Nominal values reproduce the URDF (no joint damping, friction or rotor inertia) on each
    simulator's own ground contact with friction 1, driven exactly by the control law of
    ``SimConfig``. Physical effects (``acn.sim.effects``) write into these fields;
    per-joint fields are (12,) arrays in ``JOINT_NAMES`` order (a scalar is broadcast). Where
    each field lands in each simulator:

    ==================  =======================================  ===================================
    field               MuJoCo                                   PyBullet
    ==================  =======================================  ===================================
    joint_damping       ``joint.damping``                        ``changeDynamics(jointDamping)``
    joint_friction      ``joint.frictionloss``                   velocity motor, max force = value
    armature            ``joint.armature``                       child link inertia about the axis
    payload_*           trunk mass, COM and inertia combined     trunk inertial of the loaded URDF
    ground_friction     floor and foot ``geom.friction``         ``lateralFriction`` of the feet
    ground_timeconst    floor and robot ``geom.solref`` (time    feet ``contactStiffness`` and
                        constant, critically damped)             ``contactDamping`` (``soft_contact``)
    base_frame_offset   the state's reading of the trunk         the same
                        (``acn.sim.frames``)
    latency, lag, ...   the control law (``acn.sim.actuation``): native actuator parameters
    backlash,           in MuJoCo where the law allows, otherwise a torque computed per physics
    torque_speed        step, as in PyBullet
    ==================  =======================================  ===================================
    """

    joint_damping: np.ndarray = field(default_factory=lambda: np.zeros(NUM_JOINTS))   # N m s/rad
    joint_friction: np.ndarray = field(default_factory=lambda: np.zeros(NUM_JOINTS))  # N m (Coulomb)
    armature: np.ndarray = field(default_factory=lambda: np.zeros(NUM_JOINTS))        # kg m^2, reflected rotor
    payload_mass: float = 0.0     # kg, a point mass rigidly attached to the trunk
    payload_com: np.ndarray = field(default_factory=lambda: np.zeros(3))  # m, trunk frame (link origin)
    ground_friction: float = 1.0  # sliding friction coefficient, foot-ground
    ground_timeconst: float = GROUND_TIMECONST  # s, the foot-ground contact's time constant (softness)
    latency: float = 0.0          # s, a command reaches the motors this late
    lag: float = 0.0              # s, time constant of a first-order low-pass the motors follow commands through
    motor_strength: np.ndarray = field(default_factory=lambda: np.ones(NUM_JOINTS))   # produced / commanded
    torque_limit: np.ndarray | None = None  # N m per joint; None: the control settings' limit
    kp_scale: np.ndarray = field(default_factory=lambda: np.ones(NUM_JOINTS))
    kd_scale: np.ndarray = field(default_factory=lambda: np.ones(NUM_JOINTS))
    encoder_offset: np.ndarray = field(default_factory=lambda: np.zeros(NUM_JOINTS))  # rad, reading - true angle
    backlash: np.ndarray = field(default_factory=lambda: np.zeros(NUM_JOINTS))        # rad, dead band width
    torque_speed: np.ndarray = field(default_factory=lambda: np.zeros(NUM_JOINTS))    # N m s/rad: the torque
    # available in the direction of motion falls by this per rad/s of joint speed (a DC motor's torque-speed line)
    base_frame_offset: np.ndarray = field(default_factory=lambda: np.zeros(6))  # x, y, z m (trunk frame), roll,
    # pitch, yaw rad: the frame the state's trunk channels are read in, relative to the trunk link frame

    def __post_init__(self) -> None:
        for name in JOINT_FIELDS:
            if name == "torque_limit" and self.torque_limit is None:
                continue
            setattr(self, name, per_joint(getattr(self, name)))
        self.payload_com = np.broadcast_to(np.asarray(self.payload_com, dtype=float), (3,)).copy()
        self.base_frame_offset = np.broadcast_to(np.asarray(self.base_frame_offset, dtype=float), (6,)).copy()
        self.payload_mass, self.ground_friction = float(self.payload_mass), float(self.ground_friction)
        self.ground_timeconst = float(self.ground_timeconst)
        self.latency, self.lag = float(self.latency), float(self.lag)

    def copy(self) -> "ModelParams":
        return ModelParams(**{k: (np.copy(v) if isinstance(v, np.ndarray) else v) for k, v in vars(self).items()})

    def as_json(self) -> dict:
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in vars(self).items()}

    @classmethod
    def from_json(cls, d: dict) -> "ModelParams":
        """Inverse of ``as_json``; keys missing (older datasets) take their nominal value."""
        names = {f for f in cls.__dataclass_fields__}
        return cls(**{k: v for k, v in d.items() if k in names})
