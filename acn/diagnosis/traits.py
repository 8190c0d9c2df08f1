"""What the diagnosis knows of each catalogue effect beyond its physics: how it is fitted and judged.

``acn.sim.effects`` says what an effect is (its parameters, what they change in the robot, the
magnitudes real robots show, which other effects it reproduces at some values: that is physics,
checked against both simulators and printed in the catalogue). How an effect behaves under
this diagnosis' fits and rules is not physics of the robot; it lives here, one ``EffectTraits``
per effect name (``TRAITS``; an effect not named has none of them):

- ``granularity``: how finely it is first fitted (encoder offsets differ joint by joint; the
  rest starts with one value shared by every joint);
- ``guess``: a first estimate from the measured states (N, 43) that its fit starts from (the
  trunk's frame by the kinematics of the stance feet). The kinematics is ``acn.sim.stance``'s;
  that a fit starts from it is the fitting's business;
- ``check``: why the measured states contradict fitted values without any simulation ("" where
  they agree), which makes the fit implausible;
- ``reading_only``: it changes how the state is read, not the physics, so a long prediction
  forgets it (``policy.fits_noise``);
- ``moves_start``: it moves the measured start state against the ground (encoder offsets move
  the feet): its chosen fit is refined with central differences (``policy.refine_chain``);
- ``fit_over_steps``: start-state noise biases its one-step fit and no instrument corrects it
  (the trunk's payload): its final fit is refined on predictions several steps ahead
  (``fitting.multistep_refit``);
- ``least_squares_under_step``: where rows start from the model's own step (derived joint
  velocities), the instrumental refit leaves it at its least-squares value
  (``fitting.instrumental_refit``);
- ``alike`` / ``together``: the report's reading of an effect that reproduces others (``Effect.reproduces``)
  in their words, and of those others together in its words.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from acn.sim import stance as stance_feet
from acn.sim.effects import CATALOGUE, Values
from acn.sim.effects.catalogue import pd_gains_as_strength_damping, strength_damping_as_pd_gains


@dataclass(frozen=True)
class EffectTraits:
    """How the diagnosis fits and judges one effect (module docstring)."""

    granularity: str = "shared"   # how finely a candidate is first fitted (``granularity.GRANULARITIES``)
    guess: Callable[[np.ndarray], "Values | None"] | None = None  # measured states (N, 43) -> a first estimate
    check: Callable[[np.ndarray, Values], str] | None = None  # measured states (N, 43), fitted values -> why they
    # contradict each other without simulation ("" where they agree)
    reading_only: bool = False    # changes how the state is read, not the physics
    moves_start: bool = False     # moves the measured start state against the ground
    fit_over_steps: bool = False  # its final fit is refined on predictions several steps ahead
    least_squares_under_step: bool = False  # kept at least squares where rows start from the model's step
    alike: Callable[[Values, float, float], str] | None = None  # fitted values, the commanded kd (N m s/rad) and
    # the share of the smallest realistic magnitude below which an effect is none -> the same physics in the words
    # of the effects it reproduces ("" where none)
    together: Callable[[dict[str, Values], float], str] | None = None  # the fitted values of every effect it
    # reproduces (name -> values) and the commanded kd -> the same physics in its own words: ``alike`` reversed


def _base_frame_check(states: np.ndarray, values: Values) -> str:
    """A measured frame must put the feet that carry the robot closer to the ground than the
    trunk frame does (``acn.sim.stance.Stance``): a frame fitted to what dynamics the model
    lacks (joint springs: z 3.8 mm, 6.2 mm rms against 3.4) moves them away."""
    stance = stance_feet.Stance(states)
    if len(stance.s) < stance_feet.MIN_STANCE_ROWS:
        return ""
    frame = np.array([*(float(values[k]) for k in ("x", "y", "z", "roll", "pitch")), 0.0])
    before, after = stance.carrying(np.zeros(6)), stance.carrying(frame)
    rms_before, rms_after = (float(np.sqrt(np.mean(h ** 2))) for h in (before, after))
    if rms_after <= rms_before:
        return ""
    return (f"puts the feet that carry the robot further from the ground (rms {rms_after * 1000:.1f} mm, "
            f"{rms_before * 1000:.1f} mm in the trunk frame)")


def _base_frame_guess(states: np.ndarray) -> Values | None:
    """Where the stance feet put the measured frame (``acn.sim.stance.frame_from_stance``)."""
    frame = stance_feet.frame_from_stance(states)
    return None if frame is None else dict(zip(("x", "y", "z", "roll", "pitch"), (float(v) for v in frame[:5])))


def _pd_gains_alike(values: Values, kd: float, smallest_share: float) -> str:
    """PD gains as motor strength and joint damping (``pd_gains_as_strength_damping``), in words;
    or, keeping the gains, kp_scale alone and joint damping (kd_scale - 1) kd. Means over joints;
    "" where kd is 0 or the derivative gain is below what strength alone gives (no damping is
    negative). Damping below ``smallest_share`` of its smallest realistic magnitude is none."""
    kp_s, kd_s = float(np.mean(values["kp_scale"])), float(np.mean(values["kd_scale"]))
    smallest = smallest_share * CATALOGUE["joint_damping"].parameters[0].realistic[0]
    _, damping = pd_gains_as_strength_damping(kp_s, kd_s, kd)
    if kd <= 0 or damping < -smallest:
        return ""
    if damping < smallest:
        return f"motor_strength {kp_s:.3g}"
    out = f"motor_strength {kp_s:.3g} + joint_damping {damping:.3g} N m s/rad"
    if (kd_s - 1.0) * kd >= smallest:
        out += f"; kp x{kp_s:.3g} alone + joint_damping {(kd_s - 1.0) * kd:.3g} N m s/rad"
    return out


def _pd_gains_together(values: dict[str, Values], kd: float) -> str:
    """Motor strength and joint damping together as PD gains (``strength_damping_as_pd_gains``),
    in words. Means over joints; "" where kd is 0."""
    if kd <= 0:
        return ""
    kp_s, kd_s = strength_damping_as_pd_gains(float(np.mean(values["motor_strength"]["scale"])),
                                              float(np.mean(values["joint_damping"]["value"])), kd)
    return f"pd_gains kp_scale {kp_s:.3g}, kd_scale {kd_s:.3g}"


TRAITS: dict[str, EffectTraits] = {
    "armature": EffectTraits(least_squares_under_step=True),
    "pd_gains": EffectTraits(alike=_pd_gains_alike, together=_pd_gains_together),
    "payload": EffectTraits(fit_over_steps=True),
    "encoder_offset": EffectTraits(granularity="joint", moves_start=True),
    "base_frame_offset": EffectTraits(guess=_base_frame_guess, check=_base_frame_check, reading_only=True),
}
NONE = EffectTraits()


def traits(name: str) -> EffectTraits:
    """The traits of the catalogue effect ``name`` (``NONE`` for one without any)."""
    return TRAITS.get(name, NONE)
