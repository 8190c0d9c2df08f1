"""The catalogue of physical effects. Names and parameter names are a public contract.

==================  =========================================  ==================================
name                parameters                                 realistic (12 kg quadruped)
==================  =========================================  ==================================
joint_damping       value N m s/rad (per joint)                0.1 - 2 (see below)
joint_friction      value N m, Coulomb (per joint)             0.1 - 0.6
armature            value kg m^2, reflected rotor (per joint)  0.005 - 0.03
actuator_latency    seconds                                    0.002 - 0.025
actuator_lag        timeconst s: the motors follow commands    0.003 - 0.03
                    through a first-order low-pass
motor_strength      scale, produced / commanded (per joint)    0.7 - 0.95
torque_limit        value N m (per joint)                      12 - 25 (below the commanded peaks)
pd_gains            kp_scale, kd_scale (per joint)             0.6 - 0.9, 0.5 - 0.9
payload             mass kg, com_x, com_y, com_z m (trunk)     0.5 - 4 kg, COM within +-5 cm
ground_friction     value (foot-ground sliding coefficient)    0.2 - 0.8
ground_softness     timeconst s, the foot-ground contact's     0.03 - 0.1 (nominal 0.02, MuJoCo's
                    time constant (larger: softer; below two   default; the feet sink 3 - 20 mm);
                    physics steps MuJoCo clamps it)            stiffer: PyBullet's rigid contact
encoder_offset      value rad (per joint)                      +-(0.02 - 0.15)
backlash            value rad, dead band width (per joint)     0.01 - 0.05
torque_speed        slope N m s/rad: the torque in the          0.5 - 2.5 (A1: 33.5 N m stall,
                    direction of motion falls by slope x speed  21 rad/s no load: 1.6)
                    (a DC motor's torque-speed line; per joint)
base_frame_offset   x, y, z m, roll, pitch rad: the frame the   +-(0.005 - 0.05) m, +-(0.005 - 0.05)
                    trunk is measured in (trunk frame; no yaw:  rad: a marker, a tilted IMU, the
                    flat ground does not see it)               inertial frame PyBullet reports
==================  =========================================  ==================================

Joint damping reaches 2 N m s/rad where it stands for the motor's own damping: MuJoCo
Menagerie's Unitree A1 drives position actuators without a derivative gain, with damping 1 on
the hips and 2 on the thighs and calves. The range ended at 1 before: a log of that model
imported with kd 0 had its damping (2.6 for every joint) refused as implausible, and actuator
latency and a softer ground were named instead.
"""

from __future__ import annotations

import copyreg

import numpy as np

from acn.errors import UserError
from acn.sim.effects.effect import Effect, Parameter
from acn.sim.robot import GROUND_TIMECONST, ModelParams
from acn.sim.state import NUM_JOINTS


def _setter(field: str, parameter: str = "value"):
    """A modifier writing one joint parameter into the per-joint ``ModelParams`` field."""
    def modify(params: ModelParams, values) -> None:
        setattr(params, field, np.asarray(values[parameter], float) * np.ones(NUM_JOINTS))
    return modify


def _latency(params: ModelParams, values) -> None:
    params.latency = float(values["seconds"])


def _lag(params: ModelParams, values) -> None:
    params.lag = float(values["timeconst"])


def _pd_gains(params: ModelParams, values) -> None:
    params.kp_scale = np.asarray(values["kp_scale"], float) * np.ones(NUM_JOINTS)
    params.kd_scale = np.asarray(values["kd_scale"], float) * np.ones(NUM_JOINTS)


def pd_gains_as_strength_damping(kp_scale: float, kd_scale: float, kd: float) -> tuple[float, float]:
    """PD gains scaled by kp_scale and kd_scale as (motor strength, joint damping N m s/rad), the
    same torque while the PD is unsaturated (its velocity target 0): kp_scale (kp e - kd qdot) -
    (kd_scale - kp_scale) kd qdot. kd: the commanded derivative gain, N m s/rad."""
    return kp_scale, (kd_scale - kp_scale) * kd


def strength_damping_as_pd_gains(strength: float, damping: float, kd: float) -> tuple[float, float]:
    """Motor strength s and joint damping d (N m s/rad) as PD gain scales (kp_scale, kd_scale), the
    same torque while the PD is unsaturated: s (kp e - kd qdot) - d qdot = s kp e - (s kd + d) qdot.
    The inverse of ``pd_gains_as_strength_damping``; kd > 0."""
    return strength, strength + damping / kd


def _payload(params: ModelParams, values) -> None:
    params.payload_mass = float(values["mass"])
    params.payload_com = np.array([values["com_x"], values["com_y"], values["com_z"]], dtype=float)


def _ground_friction(params: ModelParams, values) -> None:
    params.ground_friction = float(values["value"])


def _ground_softness(params: ModelParams, values) -> None:
    params.ground_timeconst = float(values["timeconst"])


def _base_frame_offset(params: ModelParams, values) -> None:
    params.base_frame_offset = np.array([*(values[k] for k in ("x", "y", "z", "roll", "pitch")), 0.0], dtype=float)


CATALOGUE: dict[str, Effect] = {e.name: e for e in (
    Effect("joint_damping", "viscous friction in the joints, tau = -value * qdot",
           (Parameter("value", "N m s/rad", 0.0, 0.0, 5.0, per_joint=True, realistic=(0.1, 2.0)),),
           _setter("joint_damping"), mujoco="joint.damping", pybullet="changeDynamics(jointDamping)"),
    Effect("joint_friction", "Coulomb friction in the joints, |tau| <= value opposing motion",
           (Parameter("value", "N m", 0.0, 0.0, 3.0, per_joint=True, realistic=(0.1, 0.6)),),
           _setter("joint_friction"), mujoco="joint.frictionloss",
           pybullet="velocity motor with target 0 and max force = value"),
    Effect("armature", "reflected rotor inertia added to each joint",
           (Parameter("value", "kg m^2", 0.0, 0.0, 0.1, per_joint=True, realistic=(0.005, 0.03)),),
           _setter("armature"), mujoco="joint.armature",
           pybullet="a rotor disc added to the child link's inertia in the loaded URDF"),
    Effect("actuator_latency", "commands reach the motors late (transport and driver delay)",
           (Parameter("seconds", "s", 0.0, 0.0, 0.06, realistic=(0.002, 0.025)),),
           _latency, mujoco="per-physics-step control sequence (rollout control), the law of acn.sim.actuation",
           pybullet="the same control sequence"),
    Effect("actuator_lag", "the motors follow commands through a first-order low-pass (a driver's bandwidth, "
           "an action filter after the log)",
           (Parameter("timeconst", "s", 0.0, 0.0, 0.06, realistic=(0.003, 0.03)),),
           _lag, mujoco="per-physics-step control sequence (rollout control), the law of acn.sim.actuation",
           pybullet="the same control sequence"),
    Effect("motor_strength", "the motors produce a fraction of the commanded torque",
           (Parameter("scale", "1", 1.0, 0.2, 1.5, per_joint=True, realistic=(0.7, 0.95)),),
           _setter("motor_strength", "scale"), mujoco="actuator gain, bias and force range scaled",
           pybullet="torque scaled in the control law"),
    Effect("torque_limit", "the motor drivers saturate at a lower torque",
           (Parameter("value", "N m", 33.5, 1.0, 200.0, per_joint=True, realistic=(12.0, 25.0),
                      from_control="torque_limit"),),
           _setter("torque_limit"), mujoco="actuator forcerange", pybullet="clip in the control law"),
    Effect("pd_gains", "the joint PD runs with other gains than commanded",
           (Parameter("kp_scale", "1", 1.0, 0.2, 3.0, per_joint=True, realistic=(0.6, 0.9)),
            Parameter("kd_scale", "1", 1.0, 0.0, 5.0, per_joint=True, realistic=(0.5, 0.9))),
           _pd_gains, mujoco="actuator gainprm / biasprm", pybullet="gains of the control law",
           reproduces=("motor_strength", "joint_damping")),
    Effect("payload", "a mass rigidly attached to the trunk",
           (Parameter("mass", "kg", 0.0, 0.0, 20.0, realistic=(0.5, 4.0)),
            Parameter("com_x", "m", 0.0, -0.3, 0.3, realistic=(0.0, 0.05), signed=True),
            Parameter("com_y", "m", 0.0, -0.3, 0.3, realistic=(0.0, 0.05), signed=True),
            Parameter("com_z", "m", 0.0, -0.3, 0.3, realistic=(0.0, 0.05), signed=True)),
           _payload, mujoco="trunk mass, ipos and inertia combined with a point mass",
           pybullet="trunk inertial of the loaded URDF combined with a point mass"),
    Effect("ground_friction", "foot-ground sliding friction differs",
           (Parameter("value", "1", 1.0, 0.05, 2.0, realistic=(0.2, 0.8)),),
           _ground_friction, mujoco="foot and floor geom friction", pybullet="lateralFriction of the feet"),
    Effect("ground_softness", "the ground (or the feet) is softer or stiffer: the contact's time constant",
           (Parameter("timeconst", "s", GROUND_TIMECONST, 0.001, 0.12, realistic=(0.03, 0.1)),),
           _ground_softness, mujoco="floor and robot geom solref (damping ratio 1)",
           pybullet="contactStiffness / contactDamping of the feet, the sink MuJoCo gives (an approximation)"),
    Effect("encoder_offset", "joint encoders read q + value; the PD acts on the reading",
           (Parameter("value", "rad", 0.0, -0.5, 0.5, per_joint=True, realistic=(0.02, 0.15), signed=True),),
           _setter("encoder_offset"), mujoco="actuator bias (-kp offset) and the state's reading",
           pybullet="the control law's reading and the state's reading"),
    Effect("backlash", "a dead band in the joint position loop (gear play)",
           (Parameter("value", "rad", 0.0, 0.0, 0.3, per_joint=True, realistic=(0.01, 0.05)),),
           _setter("backlash"), mujoco="motor actuators, the dead-band law computed each physics step",
           pybullet="dead band in the control law"),
    Effect("torque_speed", "the motors' torque in the direction of motion falls with joint speed (a DC motor's "
           "torque-speed line: back-EMF against the supply voltage; stall torque the limit, no-load speed "
           "limit / slope)",
           (Parameter("slope", "N m s/rad", 0.0, 0.0, 20.0, per_joint=True, realistic=(0.5, 2.5)),),
           _setter("torque_speed", "slope"), mujoco="motor actuators, the torque-speed law computed each physics step",
           pybullet="the control law's torque bounds"),
    Effect("base_frame_offset", "the trunk's pose and velocities are measured in a frame off the trunk's "
           "(a motion-capture body, a tilted IMU, PyBullet's centre of mass and principal axes)",
           (Parameter("x", "m", 0.0, -0.2, 0.2, realistic=(0.005, 0.05), signed=True),
            Parameter("y", "m", 0.0, -0.2, 0.2, realistic=(0.005, 0.05), signed=True),
            Parameter("z", "m", 0.0, -0.2, 0.2, realistic=(0.005, 0.05), signed=True),
            Parameter("roll", "rad", 0.0, -0.3, 0.3, realistic=(0.005, 0.05), signed=True),
            Parameter("pitch", "rad", 0.0, -0.3, 0.3, realistic=(0.005, 0.05), signed=True)),
           _base_frame_offset, mujoco="the state's reading of the trunk channels (acn.sim.frames)",
           pybullet="the same reading"),
)}
EFFECT_NAMES: tuple[str, ...] = tuple(CATALOGUE)


def get_effect(name: str) -> Effect:
    """The catalogue effect called ``name``; a one-line error listing the names otherwise."""
    if not isinstance(name, str) or name not in CATALOGUE:  # a model file may hold any JSON value here
        raise UserError(f"unknown effect {name!r}; the catalogue: {', '.join(EFFECT_NAMES)}")
    return CATALOGUE[name]


def _by_name(effect: Effect) -> tuple:
    """How a catalogue effect travels to worker processes: by its name (its modifier may be a closure)."""
    return get_effect, (effect.name,)


copyreg.pickle(Effect, _by_name)
