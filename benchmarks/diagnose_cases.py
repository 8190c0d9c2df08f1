"""How well the diagnosis finds hidden effects in robot logs written by code it does not own.

Every case is a log from ``tests/robot_log.py`` (MuJoCo stepped directly, its own PD loop and
delay line, controllers that are not acn's policies, sensor noise), imported with acn-import
and diagnosed against the nominal MuJoCo model with ``--add`` of the top candidate. Prints one
line per case and ``name=value`` totals:

- ``ranked_first``: cases whose hidden effect is ranked first (of those with an effect);
- ``within_15pct``: of those, the fitted parameter within 15 % (a per-joint vector: its norm);
- ``removed_80pct``: of those, the added effect explains >= 80 % of the error above the floor;
- ``verdict_right``: "none" on nominal logs, "unexplained" outside the catalogue (joint springs,
  calves 10 % long, thighs half as heavy again: structure a sum of flexible effects would paper
  over), "effect" else (one worn joint among them: its damping per joint, on that joint).

Each case's line ends with its time and, under it, the time of every stage of the diagnosis.
Under it, ``rules:`` the rules of the selection that decided something on that log (the
diagnosis' decision trace, ``acn.diagnosis.decisions``), and after the totals
``rule_decided_RULE=N``: on how many logs each did. A rule that decided nothing on a log changed
nothing there: neutralising it (``--threshold``) can only change the logs that list it.

With ``--threshold NAME=VALUE`` (repeatable), a ``policy.Thresholds`` field is set otherwise for
every case (``inf`` or 0 turns a rule's test off): the tally with a rule neutralised, against
the tally without, says whether the rule earns its place.

With ``--without RULE`` (repeatable), a rule of the selection is replaced by its neutral outcome
(``NEUTRAL``: the ranking as it is, no reason to set a candidate aside, nothing to revisit) in
every module that calls it: the ablation of a rule that no threshold turns off alone.

With ``--progress``, each step of every diagnosis is printed with the seconds since it began:
where a log's time goes.

With ``--other``, the ``OTHER`` cases instead: values and seeds the rules were not made on.
With ``--no-mocap``, the logs lack the trunk's position and linear velocity (no motion capture:
an IMU and encoders only), which the diagnosis estimates by leg odometry
(``acn.measurements.odometry``); ``--no-contacts`` leaves out the foot contact flags too.

With ``--feedback G``, every log's controller adds an attitude feedback on the measured, noisy
roll, pitch and gyro (``robot_log._level``, G its gain multiple; 1 keeps the pace gait upright):
a closed-loop controller, whose actions carry the sensor noise of the states they follow.

With ``--control-hz HZ``, the logs are recorded at that control rate (default 50); with
``--torque-control``, the controller runs the PD itself on its noisy readings and logs torques
(``robot_log.LogSpec.torque_control``, imported with ``--action-mode torque``; use a rate of
200 Hz or more: at 50-100 Hz the held torques make the robot oscillate and fall). The cases
whose effect lives in the robot's PD (``pd_gains``, ``backlash``) are skipped then.

With ``--stale S`` and ``--glitches G``, a share S of the rows repeats the previous row's
readings (a message that did not arrive, logged again; the controller acts on it too) and a
share G has one reading off by 30x its noise (a corrupted packet).

With ``--jitter J``, the control loop's period varies by up to +-J of it (whole physics steps,
uniform; the timestamps show it) and the logs are imported with ``--dt-tolerance`` 1.2 J, as the
import report suggests; the model still simulates every step for the control period.

With ``--velocity-filter TAU``, the robots low-pass the joint velocities they log (first order,
time constant TAU s, every physics step); the data checks name the lag and the diagnosis
derives those velocities from the joint angles.

With ``--feedforward``, the controllers send a hybrid command (q_des, dq_des, tau_ff; the motor
runs kp (q_des - q) + kd (dq_des - qd) + tau_ff), logged as ``action.*``, ``action_vel.*`` and
``action_torque.*``, which acn-import stores with the actions (the model's PD runs them as sent).

With ``--stance-gains KP,KD``, the controllers send their gains with every command and switch
each leg between the nominal gains (swing) and KP, KD times them (stance) on a gait clock
(``robot_log.LogSpec.stance_gains``), logged as ``action_kp.*`` and ``action_kd.*``, which
acn-import stores with the actions (the model's PD uses each row's gains).

With ``--stance-torque``, the controllers are MPC-style on the same clock: legs in stance get kp
0 and a torque computed from the noisy readings, legs in swing the nominal PD
(``robot_log.LogSpec.stance_torque``), logged with ``action_kp.*``, ``action_kd.*`` and
``action_torque.*``.

With ``--accelerometer sensor``, the logs' accelerometer is MuJoCo's sensor, read at each row's
instant (``robot_log.LogSpec.accelerometer``), not the schema's mean over the control step; the
logs are imported without ``--imu-acc``, so the diagnosis judges the reading (each line's
``imu=``, ``acn.diagnosis.accelerometer``); ``--imu-acc mean|instant`` states it on import
instead (as ``acn-import --imu-acc``).

With ``--pairs``, logs with TWO hidden effects instead (``--auto``), one line each and:

- ``pairs_both_named``: both hidden effects added, and nothing else;
- ``pairs_named_or_same_physics``: those, and the pairs whose added effects are the same physics
  as the hidden ones while the PD is unsaturated, which the report says under them (``pd_gains``
  for ``motor_strength`` + ``joint_damping``, or the reverse: ``same_physics``; ``both=same``);
- ``pairs_within_15pct``: of the parameters of those, within 15 % of the truth (in the hidden
  effects' words);
- ``pairs_missed_short_of_limit``: of the hidden effects missed, those whose true value lies short of
  the log's limit beside the final model (``acn-diagnose --limits``: the smallest size ``--auto`` would
  name); each missed effect's cell says ``short of`` or ``beyond`` its limit: one beyond it was
  missed although the log shows it (an effect added stood in for it). A hidden effect on one
  joint alone (the ``PAIRS`` with a fourth entry, ``--one-joint``) is named where it is added and
  its value on that joint is compared; a missed one is placed against that joint's own scan
  (``acn-diagnose --limits-per-joint``'s ``by_joint``): ``beyond`` or ``short of`` its grid size
  first shown, or ``between`` (that joint is not bisected; not counted as short of).

With ``--triples``, logs with THREE hidden effects instead (``TRIPLES``, ``--auto``), the same
line and totals (``triples_all_named``: all three added, and nothing else).

With ``--draws K0:K1``, fresh pairs drawn at random instead (``draw``; seeds ``--seed0`` + k, one
per draw k): two different effects of ``DRAWN``, each at a value uniform in the catalogue's
realistic range, on the sines or the pace controller (the pace wherever the floor's friction is
drawn); the latency + lag pair is not drawn (a delay beside a lag is a known limit). The same
line and totals as ``--pairs``. With ``--one-joint``, a drawn damping, friction, armature or
strength sits on one joint drawn at random (a worn joint, a weak motor), the other effect on
every joint alike; without it both effects act on every joint alike. ``--keep DIR`` keeps every
imported dataset there (``dK``), to re-diagnose with ``acn-diagnose``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
import time
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np

os.environ.setdefault("HF_HUB_OFFLINE", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from robot_log import LogSpec, welded_payload, write_log  # noqa: E402

from acn.measurements.importer import ImportConfig, import_log  # noqa: E402
from acn.measurements.data import load_measurements  # noqa: E402
from acn.diagnosis import THRESHOLDS, DiagnoseConfig, Thresholds, diagnose, policy  # noqa: E402
from acn.diagnosis.pipeline import rule_out  # noqa: E402
from acn.diagnosis.results import held  # noqa: E402
from acn.sim.backends import IMU_ACC_KINDS  # noqa: E402
from acn.sim.effects import CATALOGUE, Model  # noqa: E402
from acn.sim.effects.catalogue import pd_gains_as_strength_damping, strength_damping_as_pd_gains  # noqa: E402
from acn.sim.robot import URDF_JOINT  # noqa: E402
from acn.sim.state import GROUPS, JOINT_NAMES  # noqa: E402

OFFSETS = np.array([0.05, -0.08, 0.1, -0.04, 0.06, -0.12, 0.03, 0.09, -0.07, -0.1, 0.04, 0.08])
WEAK = np.array([1.0, 1.0, 0.5, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0])  # FR_calf at half strength


def _joints(attr: str, value: float, joint: str = ""):
    """Set ``attr`` to ``value`` on every joint, or on ``joint`` alone (a JOINT_NAMES name)."""
    def edit(spec):
        for j in spec.joints:
            if j.name != "root" and (not joint or j.name == URDF_JOINT[joint]):
                if attr == "damping":
                    j.damping[0] = value
                elif attr == "stiffness":
                    j.stiffness[0] = value
                else:
                    setattr(j, attr, value)
    return edit


_payload = welded_payload(2.0, [0.08, -0.04, 0.06], inertia=1e-4)


def _soft_ground(timeconst: float):
    """Every contact softer: MuJoCo's ``solref`` time constant of every geom, floor included."""
    def edit(spec):
        for g in spec.geoms:
            g.solref = [timeconst, 1.0]
    return edit


def _calves(length: float):
    """Every calf ``length`` m long instead of 0.2 (the foot moved along it): a wrong geometry."""
    def edit(spec):
        for b in spec.bodies:
            if b.name.endswith("_toe"):
                b.pos[2] = -length
    return edit


def _link_mass(suffix: str, factor: float):
    """Every body named ``*suffix`` ``factor`` times as heavy (its inertia alike): a wrong link mass."""
    def edit(spec):
        for b in spec.bodies:
            if b.name.endswith(suffix):
                b.mass *= factor
                b.inertia = [factor * x for x in b.inertia]
    return edit


def _floor(value):
    def edit(spec):
        for g in spec.geoms:
            g.friction[0] = value
    return edit


# name -> (LogSpec overrides, expected verdict, effect, parameter, true value)
CASES = {
    "nominal": ({}, "none", None, None, None),
    "damping": ({"spec_edit": _joints("damping", 0.5)}, "effect", "joint_damping", "value", 0.5),
    "friction": ({"spec_edit": _joints("frictionloss", 0.3)}, "effect", "joint_friction", "value", 0.3),
    "armature": ({"spec_edit": _joints("armature", 0.02)}, "effect", "armature", "value", 0.02),
    "latency": ({"latency_steps": 15}, "effect", "actuator_latency", "seconds", 0.015),
    "strength": ({"strength": 0.8}, "effect", "motor_strength", "scale", 0.8),
    "torque_limit": ({"torque_limit": 15.0}, "effect", "torque_limit", "value", 15.0),
    "pd_gains": ({"gains": (0.7, 1.0)}, "effect", "pd_gains", "kp_scale", 0.7),
    "payload": ({"spec_edit": _payload}, "effect", "payload", "mass", 2.0),
    "ground_friction": ({"spec_edit": _floor(0.3), "controller": "pace"}, "effect", "ground_friction", "value", 0.3),
    "encoder_offset": ({"encoder_offset": OFFSETS}, "effect", "encoder_offset", "value", OFFSETS),
    "backlash": ({"deadband": 0.04}, "effect", "backlash", "value", 0.04),
    "springs (outside)": ({"spec_edit": _joints("stiffness", 3.0)}, "unexplained", None, None, None),
    # the trunk logged as a motion-capture body 6 cm above its origin, tilted (a reading, not physics)
    "mocap body": ({"marker": (0.02, -0.015, 0.06, 0.02, -0.03)}, "effect", "base_frame_offset", "z", 0.06),
    # softer ground (the feet sink 11 mm standing instead of 1.3), which ground_friction (1.69) would
    # stand in for without ground_softness in the catalogue
    "soft ground": ({"spec_edit": _soft_ground(0.05)}, "effect", "ground_softness", "timeconst", 0.05),
    # a DC motor's torque-speed line (Isaac Lab's DCMotor: 33.5 N m stall, 14 rad/s no load, slope 2.39) on a
    # robot that hops, the one controller of these logs that drives the motors fast and hard at once
    "torque-speed (hop)": ({"dc_motor": (33.5, 14.0), "controller": "hop", "gait_speed": 1.2}, "effect",
                           "torque_speed", "slope", 33.5 / 14.0),
    "nominal (hop)": ({"controller": "hop", "gait_speed": 1.2}, "none", None, None, None),
    # the motor follows its commands through a first-order low-pass (a driver's bandwidth), which a
    # latency would stand in for without actuator_lag in the catalogue
    "actuator lag": ({"command_lag": 0.015}, "effect", "actuator_lag", "timeconst", 0.015),
    # structure outside the catalogue, which a sum of flexible effects would paper over: the calves 10 % long,
    # the thighs half as heavy again (1.52 kg instead of 1.01)
    "long calves (outside)": ({"spec_edit": _calves(0.22)}, "unexplained", None, None, None),
    "heavy thighs (outside)": ({"spec_edit": _link_mass("_upper", 1.5)}, "unexplained", None, None, None),
    # one worn joint (RL_thigh damping 2.0, the eleven others nominal): named per joint, on that joint
    "worn RL_thigh": ({"spec_edit": _joints("damping", 2.0, "RL_thigh")}, "effect", "joint_damping", "value",
                      np.where(np.array(JOINT_NAMES) == "RL_thigh", 2.0, 0.0)),
}


# The same kind of logs at values the rules were never looked at on: the other side of nominal
# (stronger motors, stiffer gains), larger and smaller magnitudes, a payload behind the trunk's
# centre, another gait without an effect, a torque limit the controller rarely reaches; other
# seeds (700 + i). Selected with --other.
OTHER = {
    "damping 1.0": ({"spec_edit": _joints("damping", 1.0)}, "effect", "joint_damping", "value", 1.0),
    "strength 1.2": ({"strength": 1.2}, "effect", "motor_strength", "scale", 1.2),
    "kp x1.3": ({"gains": (1.3, 1.0)}, "effect", "pd_gains", "kp_scale", 1.3),
    "latency 25 ms": ({"latency_steps": 25}, "effect", "actuator_latency", "seconds", 0.025),
    "payload 3.5 kg": ({"spec_edit": welded_payload(3.5, [-0.1, 0.0, 0.1])}, "effect", "payload", "mass", 3.5),
    "friction 0.15": ({"spec_edit": _joints("frictionloss", 0.15)}, "effect", "joint_friction", "value", 0.15),
    "armature 0.01": ({"spec_edit": _joints("armature", 0.01)}, "effect", "armature", "value", 0.01),
    "floor 0.5 (pace)": ({"spec_edit": _floor(0.5), "controller": "pace"}, "effect", "ground_friction", "value", 0.5),
    "nominal (pace)": ({"controller": "pace"}, "none", None, None, None),
    "torque limit 20": ({"torque_limit": 20.0}, "effect", "torque_limit", "value", 20.0),  # reached in ~4 % of steps
    # one motor at half strength (a failing driver), the other eleven nominal: a shared strength cancels it
    "weak FR_calf 0.5": ({"strength": WEAK}, "effect", "motor_strength", "scale", WEAK),
    # a faster motor (no load 16 rad/s: slope 2.09) on a gentler hop
    "torque-speed 16 rad/s (hop)": ({"dc_motor": (33.5, 16.0), "controller": "hop", "gait_speed": 1.1}, "effect",
                                    "torque_speed", "slope", 33.5 / 16.0),
    # a faster driver on the pace gait, which a latency and joint damping would stand in for without actuator_lag
    "lag 8 ms (pace)": ({"command_lag": 0.008, "controller": "pace"}, "effect", "actuator_lag", "timeconst", 0.008),
    # a controller that smooths its actions after logging them (an exponential moving average, 0.5 of the
    # previous sent target per control step): another form of a lag; true value the continuous time
    # constant whose samples it equals, -0.02 s / ln 0.5
    "action smoothing 0.5": ({"action_smoothing": 0.5}, "effect", "actuator_lag", "timeconst", -0.02 / np.log(0.5)),
}


def _both(*edits):
    def edit(spec):
        for e in edits:
            e(spec)
    return edit


# name -> (LogSpec overrides, [(effect, parameter, true value[, the one joint it is on]), ...])
PAIRS = {
    "latency+damping": ({"latency_steps": 15, "spec_edit": _joints("damping", 0.5)},
                        [("actuator_latency", "seconds", 0.015), ("joint_damping", "value", 0.5)]),
    "strength+friction": ({"strength": 0.85, "spec_edit": _joints("frictionloss", 0.2)},
                          [("motor_strength", "scale", 0.85), ("joint_friction", "value", 0.2)]),
    "latency+strength": ({"latency_steps": 10, "strength": 0.85},
                         [("actuator_latency", "seconds", 0.01), ("motor_strength", "scale", 0.85)]),
    "payload+damping": ({"spec_edit": _both(_payload, _joints("damping", 0.4))},
                        [("payload", "mass", 2.0), ("joint_damping", "value", 0.4)]),
    "pd_gains+armature": ({"gains": (0.75, 1.0), "spec_edit": _joints("armature", 0.02)},
                          [("pd_gains", "kp_scale", 0.75), ("armature", "value", 0.02)]),
    # a delay and a low-pass on one signal path (transport, then the driver's bandwidth)
    "latency+lag": ({"latency_steps": 8, "command_lag": 0.01},
                    [("actuator_latency", "seconds", 0.008), ("actuator_lag", "timeconst", 0.01)]),
    # one weak motor, one worn joint beside an effect on every joint (4th entry: the one joint)
    "latency+weak FR_calf": ({"latency_steps": 10, "strength": WEAK},
                             [("actuator_latency", "seconds", 0.01), ("motor_strength", "scale", 0.5, "FR_calf")]),
    "payload+damping RL_thigh": ({"spec_edit": _both(_payload, _joints("damping", 2.0, "RL_thigh"))},
                                 [("payload", "mass", 2.0), ("joint_damping", "value", 2.0, "RL_thigh")]),
}


# name -> (LogSpec overrides, [(effect, parameter, true value[, the one joint it is on]), ...] x 3); --triples
TRIPLES = {
    "latency+damping+payload": ({"latency_steps": 10, "spec_edit": _both(_payload, _joints("damping", 0.4))},
                                [("actuator_latency", "seconds", 0.01), ("joint_damping", "value", 0.4),
                                 ("payload", "mass", 2.0)]),
    "strength+friction+latency": ({"strength": 0.85, "latency_steps": 12, "spec_edit": _joints("frictionloss", 0.2)},
                                  [("motor_strength", "scale", 0.85), ("joint_friction", "value", 0.2),
                                   ("actuator_latency", "seconds", 0.012)]),
    # three effects of every joint at once, each of which PD gains or encoder offsets could partly stand in for
    "damping+friction+armature": ({"spec_edit": _both(_joints("damping", 0.6), _joints("frictionloss", 0.2),
                                                      _joints("armature", 0.015))},
                                  [("joint_damping", "value", 0.6), ("joint_friction", "value", 0.2),
                                   ("armature", "value", 0.015)]),
}


# A rule of the selection replaced by its neutral outcome (--without RULE): what the search does without it.
NEUTRAL = {
    "one_step_only": lambda c, t=THRESHOLDS: "",                                   # no candidate fits the noise
    "uneven": lambda horizon, ranking, t=THRESHOLDS: ranking,                      # the ranking as it is
    "prefer_simpler": lambda ranking, horizon=None, t=THRESHOLDS: ranking,
    "prefer_longer": lambda ranking, t=THRESHOLDS: ranking,
    "finer_look": lambda problem, model, cfg, judge_rows, base_residual, ranking, *a, **k: ranking,
    "final_doubt": lambda step, t=THRESHOLDS: "",                                  # every final fit holds
    "too_little": lambda j, longer, floor_mse, t=THRESHOLDS: "",
    "nothing_left": lambda *a, **k: False,                                         # always something to look for
    "revisit": lambda problem, first, cfg, judge_rows, base_residual, added, *a, **k: added,
    "does_not_hold": lambda fits, t=THRESHOLDS: "",                                # the halves always agree
}


def without(rules: list[str]) -> None:
    """Replace each rule by its ``NEUTRAL`` outcome in every module of ``acn.diagnosis`` that holds it."""
    for rule in rules:
        real = getattr(policy, rule)
        for name, module in list(sys.modules.items()):
            if name.startswith("acn.diagnosis") and getattr(module, rule, None) is real:
                setattr(module, rule, NEUTRAL[rule])


def _realistic(rng: np.random.Generator, effect: str) -> float:
    low, high = CATALOGUE[effect].parameters[0].realistic
    return float(rng.uniform(low, high))


def _drawn_payload(rng: np.random.Generator) -> tuple[dict, float]:
    """A payload of realistic mass, its centre up to 8 cm ahead or behind, 4 cm to a side and 0-8 cm
    above the trunk's origin (a box on the back)."""
    mass = _realistic(rng, "payload")
    pos = [float(rng.uniform(-0.08, 0.08)), float(rng.uniform(-0.04, 0.04)), float(rng.uniform(0.0, 0.08))]
    return {"spec_edit": welded_payload(mass, pos, inertia=1e-4)}, mass


def _drawn_latency(rng: np.random.Generator) -> tuple[dict, float]:
    steps = int(round(1000 * _realistic(rng, "actuator_latency")))  # whole physics steps of 1 ms
    return {"latency_steps": steps}, steps / 1000


def _drawn_joints(attr: str, effect: str):
    def drawn(rng: np.random.Generator, joint: str = "") -> tuple[dict, float]:
        v = _realistic(rng, effect)
        return {"spec_edit": _joints(attr, v, joint)}, v
    return drawn


def _drawn_field(field: str, effect: str, wrap=lambda v: v):
    def drawn(rng: np.random.Generator) -> tuple[dict, float]:
        v = _realistic(rng, effect)
        return {field: wrap(v)}, v
    return drawn


def _drawn_strength(rng: np.random.Generator, joint: str = "") -> tuple[dict, float]:
    v = _realistic(rng, "motor_strength")
    if not joint:
        return {"strength": v}, v
    strength = np.ones(len(JOINT_NAMES))
    strength[JOINT_NAMES.index(joint)] = v
    return {"strength": strength}, v


def _drawn_floor(rng: np.random.Generator) -> tuple[dict, float]:
    v = _realistic(rng, "ground_friction")
    return {"spec_edit": _floor(v), "controller": "pace"}, v


# effect -> (its parameter, a function of a random generator giving (LogSpec overrides, true value))
DRAWN = {
    "joint_damping": ("value", _drawn_joints("damping", "joint_damping")),
    "joint_friction": ("value", _drawn_joints("frictionloss", "joint_friction")),
    "armature": ("value", _drawn_joints("armature", "armature")),
    "actuator_latency": ("seconds", _drawn_latency),
    "actuator_lag": ("timeconst", _drawn_field("command_lag", "actuator_lag")),
    "motor_strength": ("scale", _drawn_strength),
    "torque_limit": ("value", _drawn_field("torque_limit", "torque_limit")),
    "pd_gains": ("kp_scale", _drawn_field("gains", "pd_gains", lambda v: (v, 1.0))),
    "payload": ("mass", _drawn_payload),
    "ground_friction": ("value", _drawn_floor),
}


# the effects ``--one-joint`` sets on one drawn joint alone (a worn joint, a weak motor)
ONE_JOINT = ("joint_damping", "joint_friction", "armature", "motor_strength")


def draw(seed: int, one_joint: bool = False) -> tuple[str, dict, list[tuple[str, str, float, str]]]:
    """One fresh pair: (a name, its LogSpec overrides, [(effect, parameter, true value, joint)] x 2);
    ``one_joint``: an effect of ``ONE_JOINT`` is set on one joint drawn at random (joint: its name),
    the others on every joint alike (joint: ""); without it every effect is on every joint alike."""
    rng = np.random.default_rng(seed)
    while True:
        pair = sorted(str(e) for e in rng.choice(list(DRAWN), size=2, replace=False))
        if pair != ["actuator_lag", "actuator_latency"]:
            break
    over: dict = {"controller": str(rng.choice(["sines", "pace"]))}
    edits, truth = [], []
    for effect in pair:
        key, drawn = DRAWN[effect]
        joint = str(rng.choice(JOINT_NAMES)) if one_joint and effect in ONE_JOINT else ""
        o, true = drawn(rng, joint) if joint else drawn(rng)
        if "spec_edit" in o:
            edits.append(o.pop("spec_edit"))
        over.update(o)
        truth.append((effect, key, true, joint))
    if edits:
        over["spec_edit"] = _both(*edits)
    return "+".join(f"{e}@{j}" if j else e for e, _, _, j in truth), over, truth


def dropped(args) -> tuple[str, ...]:
    """Channels the logs leave out (``--no-mocap``, ``--no-contacts``)."""
    out = tuple(GROUPS["base_pos"] + GROUPS["base_linvel"]) if args.no_mocap else ()
    return out + (tuple(GROUPS["contact"]) if args.no_contacts else ())


def log_spec(args, seed: int, over: dict) -> LogSpec:
    """The log of one case under the command line's recording options."""
    return LogSpec(seconds=args.seconds, episodes=args.episodes, seed=seed, noise=args.noise, feedback=args.feedback,
                   drop=dropped(args), control_hz=args.control_hz, torque_control=args.torque_control,
                   stale=args.stale, glitches=args.glitches, jitter=args.jitter,
                   velocity_filter=args.velocity_filter, feedforward=args.feedforward,
                   stance_gains=args.stance_gains, stance_torque=args.stance_torque,
                   accelerometer=args.accelerometer, **{"controller": "sines", **over})


def import_config(args) -> ImportConfig:
    return ImportConfig(args.control_hz, 60.0, 1.5, 33.5, action_mode="torque" if args.torque_control else "position",
                        dt_tolerance=max(0.1, 1.2 * args.jitter), imu_acc=args.imu_acc)


def skipped(args, name: str, over: dict) -> bool:
    """Whether a case is skipped (and says so): under ``--torque-control`` the effects that live in
    the robot's PD loop, which the controller's logged torques then contain."""
    if args.torque_control and ("gains" in over or "deadband" in over):
        print(f"{name:18s} skipped: its effect is in the robot's PD, which --torque-control moves into the log")
        return True
    return False


def same_physics(fitted: dict, hidden: set[str], kd: float) -> dict | None:
    """``fitted`` (name -> values) read in the hidden effects' words where it names other effects that
    are the same physics while the PD is unsaturated: ``pd_gains`` as ``motor_strength`` +
    ``joint_damping``, or the reverse (``catalogue.pd_gains_as_strength_damping``; kd: the
    commanded derivative gain, N m s/rad); None where no such reading names exactly ``hidden``."""
    pair, out = set(CATALOGUE["pd_gains"].reproduces), dict(fitted)  # motor_strength, joint_damping
    if "pd_gains" in out and pair <= hidden and not pair & set(out):
        g = out.pop("pd_gains")
        s, d = pd_gains_as_strength_damping(float(np.mean(g["kp_scale"])), float(np.mean(g["kd_scale"])), kd)
        out.update(motor_strength={"scale": s}, joint_damping={"value": d})
    elif pair <= set(out) and "pd_gains" in hidden and "pd_gains" not in out:
        kp_s, kd_s = strength_damping_as_pd_gains(float(np.mean(out.pop("motor_strength")["scale"])),
                                                  float(np.mean(out.pop("joint_damping")["value"])), kd)
        out["pd_gains"] = {"kp_scale": kp_s, "kd_scale": kd_s}
    else:
        return None
    return out if set(out) == hidden else None


def _on_joint(limit, joint: str, true: float) -> tuple[str, str]:
    """Where ``true`` on ``joint`` alone lies against ``limit``'s scan of that joint: "beyond" (at or past
    the first grid size shown there), "short of" (at or within the size before it, or none shown),
    "between" (between the two, or nearer nominal than the smallest size: the grid halves, that joint was
    not bisected); and the limit's text."""
    first = float(limit.by_joint[JOINT_NAMES.index(joint)])
    distance = abs(true - limit.nominal)
    text = f", {limit.one_joint.describe()} on any joint"
    if not np.isfinite(first):
        return "short of", f"not shown on {joint} alone{text}"
    i = int(np.flatnonzero(limit.sizes == first)[0])
    below = abs(limit.sizes[i - 1] - limit.nominal) if i > 0 else 0.0
    where = ("beyond" if distance >= abs(first - limit.nominal) else "short of" if i > 0 and distance <= below
             else "between")
    return where, f"{first:.4g} on {joint} alone (grid){text}"


def diagnose_pair(args, name: str, stem: str, over: dict, truth: list, seed: int, root: Path, tally: dict) -> None:
    """Write (``root/stem.csv``), import (``root/stem``) and diagnose (``--auto``) one log with two
    hidden effects; print its line and count into ``tally`` ({"named": [right, of], "same": [right or the
    same physics, of], "within": [right, of], "short": [missed short of the log's limit, missed]})."""
    write_log(root / f"{stem}.csv", log_spec(args, seed, over))
    path, _ = import_log(root / f"{stem}.csv", root / stem, import_config(args))
    t = time.perf_counter()
    d = diagnose(load_measurements(path), Model.parse("mujoco"), diagnose_config(args), automatic=True,
                 thresholds=args.thresholds, progress=timeline(args, t))
    count_rules(d, tally.setdefault("rules", Counter()))
    fitted = {t.name: t.values for t in d.final.model.effects}
    hidden = {t[0] for t in truth}
    both = set(fitted) == hidden
    reading = None if both else same_physics(fitted, hidden, float(np.mean(d.problem.control.kd)))
    tally["named"][0] += both
    tally["named"][1] += 1
    tally["same"][0] += both or reading is not None
    tally["same"][1] += 1
    extra = [f"{n}({', '.join(f'{k}={float(np.mean(v)):.4g}' for k, v in values.items())})"
             for n, values in fitted.items() if reading is not None or n not in hidden]  # all, where read anew
    fitted = fitted if reading is None else reading
    cells = []
    for effect, key, true, *on in truth:
        joint = on[0] if on else ""  # the one joint the effect was set on ("": every joint)
        at = f"@{joint}" if joint else ""
        if effect in fitted:
            values = np.broadcast_to(np.asarray(fitted[effect][key], dtype=float), (len(JOINT_NAMES),)) \
                if joint else np.asarray(fitted[effect][key], dtype=float)
            value = float(values[JOINT_NAMES.index(joint)] if joint else np.mean(values))
            tally["within"][0] += abs(value - true) <= 0.15 * abs(true)
            tally["within"][1] += 1
            cells.append(f"{effect}.{key}{at}={value:.4g} (true {true:.4g})")
        else:
            (limit,) = [x for x in rule_out(d, (effect,), one_joint=bool(joint)) if x.parameter == key]
            if joint:
                where, said_limit = _on_joint(limit, joint, true)
            else:
                where, said_limit = ("short of" if not limit.shows(true) else "beyond"), limit.describe()
            tally["short"][0] += where == "short of"
            tally["short"][1] += 1
            cells.append(f"{effect}{at} missed (true {key}={true:.4g}, {where} its limit {said_limit})")
    said = "yes" if both else "same" if reading is not None else "no"
    also = (" as " if reading is not None else " also ") + " ".join(extra) if extra else ""
    aside = f" set_aside={sorted(d.set_aside)}" if d.set_aside else ""
    print(f"{name:18s} verdict={d.verdict:11s} imu={d.accelerometer.kind:7s} both={said:4s} "
          f"{' '.join(cells)}{also}{aside} {time.perf_counter() - t:.0f}s", flush=True)
    print_stages_and_rules(d)


def pairs(args, root: Path, cases: dict = PAIRS, seed: int = 300) -> None:
    """The ``PAIRS`` (or ``TRIPLES``) cases, or the ``--draws``, one line each, then the totals
    (``pairs_both_named``: every hidden effect added and nothing else, ``triples_...`` for triples)."""
    tally = {"named": [0, 0], "same": [0, 0], "within": [0, 0], "short": [0, 0]}
    if args.draws:
        for k in range(*args.draws):
            name, over, truth = draw(args.seed0 + k, args.one_joint)
            print(f"d{k} ({over['controller']}): {name}", flush=True)
            diagnose_pair(args, f"d{k}", f"d{k}", over, truth, args.seed0 + k, root, tally)
    else:
        for i, (name, (over, truth)) in enumerate(cases.items()):
            if args.cases and name not in args.cases.split(","):
                continue
            if skipped(args, name, over):
                continue
            diagnose_pair(args, name, f"p{seed + i}", over, truth, seed + i, root, tally)
    what = "triples_all" if cases is TRIPLES and not args.draws else "pairs_both"
    print(f"{what}_named={tally['named'][0]}/{tally['named'][1]}")
    print(f"{what.split('_')[0]}_named_or_same_physics={tally['same'][0]}/{tally['same'][1]}")
    print(f"{what.split('_')[0]}_within_15pct={tally['within'][0]}/{tally['within'][1]}")
    print(f"{what.split('_')[0]}_missed_short_of_limit={tally['short'][0]}/{tally['short'][1]}")
    print_rules(tally.get("rules", Counter()))


def _draws(text: str) -> tuple[int, int]:
    try:
        k0, k1 = (int(k) for k in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"K0:K1, two whole numbers, got {text!r}") from None
    return k0, k1


def parser() -> argparse.ArgumentParser:
    """The command line: the cases to run and how their logs are recorded (``log_spec``,
    ``import_config``)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--noise", type=float, default=1.0, help="sensor noise, multiple of robot_log.NOISE")
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--episodes", type=int, default=4)
    ap.add_argument("--threshold", type=_threshold, action="append", default=[], metavar="NAME=VALUE",
                    help="a policy.Thresholds field set otherwise for every case (repeatable): a rule neutralised")
    ap.add_argument("--without", action="append", default=[], choices=sorted(NEUTRAL), metavar="RULE",
                    help="a rule of the selection replaced by its neutral outcome (repeatable): the rule ablated")
    ap.add_argument("--auto-seconds", type=float, default=DiagnoseConfig().auto_seconds, metavar="S",
                    help="the search's time bound (acn-diagnose --auto-seconds; 0: none)")
    ap.add_argument("--progress", action="store_true", help="print each step of every diagnosis with its time")
    ap.add_argument("--cases", default=None, help="comma-separated names (default: every case of the set)")
    ap.add_argument("--other", action="store_true", help="the OTHER set: values and seeds the rules never saw")
    ap.add_argument("--pairs", action="store_true", help="logs with two hidden effects instead (PAIRS)")
    ap.add_argument("--triples", action="store_true", help="logs with three hidden effects instead (TRIPLES)")
    ap.add_argument("--draws", default=None, metavar="K0:K1", type=_draws,
                    help="fresh random pairs k = K0..K1-1 instead (seeds --seed0 + k; see draw)")
    ap.add_argument("--one-joint", action="store_true",
                    help="--draws: a joint effect (damping, friction, armature, strength) on one drawn joint alone")
    ap.add_argument("--seed0", type=int, default=5500, help="--draws: the seed of draw 0")
    ap.add_argument("--keep", type=Path, default=None, help="keep the logs and datasets in this folder")
    ap.add_argument("--no-mocap", action="store_true", help="logs without the trunk's position and linear velocity")
    ap.add_argument("--no-contacts", action="store_true", help="logs without foot contact flags")
    ap.add_argument("--feedback", type=float, default=0.0,
                    help="the controllers level the trunk on the measured roll and pitch, with this gain multiple")
    ap.add_argument("--control-hz", type=int, default=50, help="the logs' control rate")
    ap.add_argument("--torque-control", action="store_true",
                    help="the controller runs the PD on its noisy readings and logs torques (use >= 200 Hz)")
    ap.add_argument("--stale", type=float, default=0.0,
                    help="share of rows whose readings repeat the previous row's (a message that did not arrive)")
    ap.add_argument("--jitter", type=float, default=0.0,
                    help="the control period varies by up to +- this share of it (imported with 1.2x that tolerance)")
    ap.add_argument("--velocity-filter", type=float, default=0.0,
                    help="s, time constant of a low-pass filter on the logged joint velocities")
    ap.add_argument("--feedforward", action="store_true",
                    help="hybrid commands: a velocity target and a feedforward torque beside the position target")
    ap.add_argument("--stance-gains", type=lambda v: tuple(float(x) for x in v.split(",")), default=None,
                    metavar="KP,KD", help="gains per row: legs in stance run KP, KD times the nominal gains")
    ap.add_argument("--stance-torque", action="store_true",
                    help="MPC-style: legs in stance get kp 0 and a torque from the readings, legs in swing the PD")
    ap.add_argument("--accelerometer", choices=("mean", "sensor"), default="mean",
                    help="the logs' accelerometer: the mean over the control step, or MuJoCo's sensor (an instant)")
    ap.add_argument("--imu-acc", choices=IMU_ACC_KINDS, default=None,
                    help="state the accelerometer's reading on import (default: not stated, the diagnosis judges it)")
    ap.add_argument("--glitches", type=float, default=0.0,
                    help="share of rows with one reading off by robot_log.GLITCH x its noise (a corrupted packet)")
    return ap


def main() -> None:
    ap = parser()
    args = ap.parse_args()
    if (args.feedforward or args.stance_gains or args.stance_torque) and args.torque_control:
        ap.error("--feedforward, --stance-gains and --stance-torque complete a position target; --torque-control "
                 "logs torques: choose one")
    if args.stance_torque and (args.feedforward or args.stance_gains):
        ap.error("--stance-torque sends its own gains and torques: not with --feedforward or --stance-gains")
    if args.stance_gains is not None and len(args.stance_gains) != 2:
        ap.error("--stance-gains takes two multiples, KP,KD")
    args.thresholds = replace(THRESHOLDS, **dict(args.threshold))
    if args.threshold:
        print("thresholds: " + ", ".join(f"{k}={v:g}" for k, v in args.threshold), flush=True)
    if args.without:
        without(args.without)
        print("without: " + ", ".join(args.without), flush=True)
    root = args.keep or Path(tempfile.mkdtemp())
    root.mkdir(parents=True, exist_ok=True)
    cases, seed = (PAIRS, 300) if args.pairs else (TRIPLES, 900) if args.triples else (OTHER, 700) if args.other \
        else (CASES, 100)
    unknown = [n for n in (args.cases.split(",") if args.cases else []) if n not in cases]
    if unknown:
        ap.error(f"no case {unknown[0]!r}; the cases: {', '.join(cases)}")
    if args.pairs or args.triples or args.draws:
        return pairs(args, root, cases, seed)
    tally = {"ranked_first": [0, 0], "within_15pct": [0, 0], "removed_80pct": [0, 0], "verdict_right": [0, 0]}
    rules: Counter = Counter()
    for name in args.cases.split(",") if args.cases else cases:
        over, want, effect, key, true = cases[name]
        i = list(cases).index(name)  # a case's log is the same whichever cases run with it
        if skipped(args, name, over):
            continue
        write_log(root / f"{i}.csv", log_spec(args, seed + i, over))
        path, _ = import_log(root / f"{i}.csv", root / f"d{i}", import_config(args))
        t = time.perf_counter()
        d = diagnose(load_measurements(path), Model.parse("mujoco"), diagnose_config(args), automatic=True,
                     thresholds=args.thresholds, progress=timeline(args, t))
        seconds = time.perf_counter() - t
        count_rules(d, rules)
        tally["verdict_right"][0] += d.verdict == want
        tally["verdict_right"][1] += 1
        line = f"{name:18s} verdict={d.verdict:11s} imu={d.accelerometer.kind:7s} first={d.ranking[0].name:16s}"
        if effect:
            first = d.ranking[0].name == effect
            tally["ranked_first"][0] += first
            tally["ranked_first"][1] += 1
            fitted = {t.name: t.values for t in d.final.model.effects}.get(effect)
            if fitted is not None:
                f = np.atleast_1d(np.asarray(fitted[key], float))
                err = float(np.linalg.norm(f - np.broadcast_to(true, f.shape)) / np.linalg.norm(np.broadcast_to(true, f.shape)))
                added = next(a for a in d.added if a.name == effect)
                explained = added.judgement.explained(d.floor_mse)
                tally["within_15pct"][0] += err <= 0.15
                tally["removed_80pct"][0] += explained >= 0.8
                line += (f" {key}={np.round(f.mean(), 4)} (true {np.round(np.mean(true), 4)}, error {err:.1%}) "
                         f"explained={explained:.0%} per={held(d.final.model, effect)}")
                odd = np.flatnonzero(np.asarray(true) != np.median(true)) if np.ndim(true) else []
                if len(odd) == 1 and len(f) == len(JOINT_NAMES):  # one joint apart: its own value
                    line += f" {JOINT_NAMES[odd[0]]}={f[odd[0]]:.4g} (true {np.asarray(true)[odd[0]]:.4g})"
            tally["within_15pct"][1] += 1
            tally["removed_80pct"][1] += 1
        aside = f" set_aside={sorted(d.set_aside)}" if d.set_aside else ""
        added = [f"{a.name}({', '.join(f'{k}={float(np.mean(v)):.4g}' for k, v in a.fit.values.items())})"
                 for a in d.added]
        print(line + f" added={added}{aside} {seconds:.0f}s", flush=True)
        print_stages_and_rules(d)
        if d.verdict != want:
            print(f"  {d.verdict}: {d.reason}", flush=True)
    for k, (good, n) in tally.items():
        print(f"{k}={good}/{n}")
    print_rules(rules)


def diagnose_config(args) -> DiagnoseConfig:
    """The diagnosis' defaults, with the search's time bound of ``--auto-seconds`` (0: none)."""
    return DiagnoseConfig(auto_seconds=args.auto_seconds or None)


def timeline(args, start: float):
    """With ``--progress``: a diagnosis' progress callback printing each step with the seconds since ``start``."""
    if not args.progress:
        return None
    return lambda message, fraction=None: print(f"    {time.perf_counter() - start:6.1f} s  {message}", flush=True)


def print_stages_and_rules(d) -> None:
    """Under a case's line: the time of each stage, s, and the rules that decided something."""
    print(f"  stages: {', '.join(f'{k} {v:.0f}' for k, v in d.stages.items())}", flush=True)
    print(f"  rules: {', '.join(sorted({x.rule for x in d.decisions}))}", flush=True)


def count_rules(d, rules: Counter) -> None:
    """Count each rule of the selection that decided something in diagnosis ``d`` (its trace), in
    any search; a rule counted on no case of any set decides nothing these logs need."""
    rules.update({x.rule for x in d.decisions})  # once per log


def print_rules(rules: Counter) -> None:
    for rule, n in sorted(rules.items()):
        print(f"rule_decided_{rule}={n}")


def _threshold(text: str) -> tuple[str, float]:
    """``NAME=VALUE`` of a ``policy.Thresholds`` field (a number; ``inf`` turns a rule's test off)."""
    name, _, value = text.partition("=")
    fields = {f.name: f for f in dataclasses.fields(Thresholds)}
    if name not in fields or not value:
        raise argparse.ArgumentTypeError(f"NAME=VALUE with NAME one of {', '.join(fields)}; got {text!r}")
    if fields[name].type in ("int", int):
        try:
            return name, int(value)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} takes a whole number, got {value!r}") from None
    try:
        return name, float(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{name} takes a number, got {value!r}") from None


if __name__ == "__main__":
    main()
