"""Built-in policies: no training needed.

A policy maps (state vector, time in s) to 12 joint position targets (rad). In ``torque``
action mode the collector turns targets into torques with the same PD law evaluated once per
control step (``policy_action``); that needs a fast control rate (e.g. ``--control-hz 500``)
to be stable, since a 50 Hz PD on the A1's light legs is not.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np

from acn.sim.backends.base import SimConfig, pd_torque
from acn.sim.robot import STANCE
from acn.sim.state import NUM_JOINTS, SLICES

# Leg order FR, FL, RR, RL; joint order per leg hip, thigh, calf.
HIP, THIGH, CALF = 0, 1, 2


class Policy(Protocol):
    name: str

    def reset(self, rng: np.random.Generator) -> None: ...

    def __call__(self, state: np.ndarray, t: float) -> np.ndarray: ...


def _leg_joint(leg: int, joint: int) -> int:
    return 3 * leg + joint


@dataclass
class Stand:
    """Hold the stance."""

    name: str = "stand"

    def reset(self, rng: np.random.Generator) -> None:
        pass

    def __call__(self, state: np.ndarray, t: float) -> np.ndarray:
        return STANCE.copy()


@dataclass
class Trot:
    """Open-loop trot: diagonal pairs (FR+RL, FL+RR) in antiphase.

    Per leg with phase phi = 2 pi f t (+ pi for the FL+RR pair):
    thigh = stance + swing * cos(phi) (back-to-front in the swing half, front-to-back in
    stance), calf = stance - lift * max(sin(phi), 0) (knee lifts the foot in the swing half).
    """

    frequency: float = 2.0   # Hz, gait cycles per second
    swing: float = 0.35      # rad, thigh amplitude
    lift: float = 0.6        # rad, extra knee flexion at mid-swing
    name: str = "trot"

    def reset(self, rng: np.random.Generator) -> None:
        pass

    def __call__(self, state: np.ndarray, t: float) -> np.ndarray:
        target = STANCE.copy()
        for leg, offset in ((0, 0.0), (3, 0.0), (1, np.pi), (2, np.pi)):
            phi = 2 * np.pi * self.frequency * t + offset
            target[_leg_joint(leg, THIGH)] += self.swing * np.cos(phi)
            target[_leg_joint(leg, CALF)] -= self.lift * max(np.sin(phi), 0.0)
        return target


@dataclass
class Excite:
    """Identification signal: a Schroeder-phased multisine on every joint around the stance.

    Each joint gets ``n_sines`` sinusoids on its own interleaved frequency grid in
    [f_min, f_max] Hz, so every joint is excited at distinct frequencies (no two joints share
    one) and the crest factor stays low. Phases are Schroeder's, shifted per episode by the rng.
    """

    amplitude: float = 0.25  # rad, peak per joint (hip gets half)
    f_min: float = 0.3
    f_max: float = 6.0
    n_sines: int = 8
    name: str = "excite"

    def reset(self, rng: np.random.Generator) -> None:
        grid = np.linspace(self.f_min, self.f_max, self.n_sines * NUM_JOINTS)
        self._freqs = grid.reshape(self.n_sines, NUM_JOINTS)  # (k, joint), interleaved
        k = np.arange(1, self.n_sines + 1)[:, None]
        self._phases = -np.pi * k * (k - 1) / self.n_sines + rng.uniform(0, 2 * np.pi, NUM_JOINTS)
        scale = np.full(NUM_JOINTS, self.amplitude)
        scale[HIP::3] *= 0.5
        self._scale = scale / self.n_sines * 1.6  # Schroeder crest factor ~1.6

    def __call__(self, state: np.ndarray, t: float) -> np.ndarray:
        sig = np.sin(2 * np.pi * self._freqs * t + self._phases).sum(axis=0)
        return STANCE + np.clip(self._scale * sig, -self.amplitude, self.amplitude)


@dataclass
class RandomTargets:
    """Uniform random joint targets around the stance, redrawn every ``hold`` seconds."""

    amplitude: float = 0.2  # rad
    hold: float = 0.1       # s
    name: str = "random"

    def reset(self, rng: np.random.Generator) -> None:
        self._rng = rng
        self._next_draw = 0.0
        self._target = STANCE.copy()

    def __call__(self, state: np.ndarray, t: float) -> np.ndarray:
        if t >= self._next_draw - 1e-9:
            self._target = STANCE + self._rng.uniform(-self.amplitude, self.amplitude, NUM_JOINTS)
            self._next_draw = t + self.hold
        return self._target.copy()


POLICIES: dict[str, Callable[[], Policy]] = {
    "stand": Stand, "trot": Trot, "excite": Excite, "random": RandomTargets,
}


def make_policy(name: str) -> Policy:
    if name not in POLICIES:
        raise ValueError(f"unknown policy {name!r}; choose from {', '.join(POLICIES)}")
    return POLICIES[name]()


def policy_action(policy: Policy, state: np.ndarray, t: float, config: SimConfig) -> np.ndarray:
    """The action sent to a simulator: targets in position mode, PD torques in torque mode."""
    target = policy(state, t)
    if config.action_mode == "position":
        return target
    return pd_torque(target, state[SLICES["joint_pos"]], state[SLICES["joint_vel"]], config)
