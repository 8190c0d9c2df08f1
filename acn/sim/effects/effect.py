"""What a physical effect is: named parameters with units, nominal values and bounds, and a
modifier that writes them into the robot description (``ModelParams``) both backends build from.

The pattern is ``mujoco.sysid``'s ``Parameter`` with a spec modifier, one level up: the
modifier writes ``ModelParams`` instead of an ``MjSpec``, and each backend realises
``ModelParams`` in its own simulator (``Effect.mujoco`` / ``Effect.pybullet`` say where), so
one effect object serves both simulators. An effect holds its physics only (what its parameters
are, what they change, which other effects it reproduces); how the diagnosis fits and judges it
is ``acn.diagnosis.traits``.

Values. A parameter's value is a float, or for a joint parameter (``per_joint``) a (12,) array
in ``JOINT_NAMES`` order. In JSON a joint parameter is one shared number, a list of 12, or a
mapping joint name -> value (unnamed joints keep their nominal value).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from acn.errors import UserError
from acn.sim.robot import ModelParams
from acn.sim.state import JOINT_NAMES, NUM_JOINTS

Values = dict[str, "float | np.ndarray"]


@dataclass(frozen=True)
class Parameter:
    """One named parameter of an effect."""

    name: str
    unit: str
    nominal: float            # the value at which the effect is absent
    lower: float              # bounds for fitting and for values read from files
    upper: float
    per_joint: bool = False
    realistic: tuple[float, float] | None = None  # magnitudes seen on real 12 kg quadrupeds
    signed: bool = False      # a realistic value is nominal +- a magnitude (offsets), not nominal -> range
    from_control: str | None = None  # nominal taken from this ``SimConfig`` field (e.g. torque_limit)

    def nominal_for(self, control) -> float:
        return float(getattr(control, self.from_control)) if self.from_control else self.nominal

    @property
    def realistic_middle(self) -> float | None:
        """The middle of the realistic range; None for a signed parameter or one without a range."""
        return float(np.mean(self.realistic)) if self.realistic and not self.signed else None


@dataclass(frozen=True)
class Effect:
    """A physical effect: name, parameters, and the modifier that applies their values."""

    name: str
    summary: str
    parameters: tuple[Parameter, ...]
    modifier: Callable[[ModelParams, Values], None]
    mujoco: str     # where MuJoCo realises it
    pybullet: str   # where PyBullet realises it
    reproduces: tuple[str, ...] = ()  # effects it equals at some values of its parameters while the joint PD is
    # unsaturated (pd_gains: motor_strength at equal kp and kd scales)

    @property
    def per_joint(self) -> bool:
        return any(p.per_joint for p in self.parameters)

    def parameter(self, name: str) -> Parameter:
        for p in self.parameters:
            if p.name == name:
                return p
        raise UserError(f"effect {self.name!r} has no parameter {name!r}; "
                        f"its parameters: {', '.join(p.name for p in self.parameters)}")

    def nominal(self, control) -> Values:
        """Values at which the effect is absent, for the control settings ``control`` (SimConfig)."""
        return {p.name: (np.full(NUM_JOINTS, p.nominal_for(control)) if p.per_joint else p.nominal_for(control))
                for p in self.parameters}

    def apply(self, params: ModelParams, values: Values) -> None:
        """Write ``values`` into ``params`` (in place)."""
        self.modifier(params, values)

    # ----- JSON ---------------------------------------------------------------------------
    def parse(self, raw: dict, control=None) -> Values:
        """Values from their JSON form, checked; parameters not given take their nominal value."""
        if not isinstance(raw, dict):
            raise UserError(f"params of effect {self.name!r} must be an object, got {type(raw).__name__}")
        for key in raw:
            self.parameter(key)
        out: Values = {}
        for p in self.parameters:
            nominal = p.nominal_for(control) if control is not None else p.nominal
            v = raw.get(p.name, nominal)
            out[p.name] = _joint_values(self.name, p, v, nominal) if p.per_joint else _number(self.name, p, v)
            arr = np.atleast_1d(out[p.name])
            if np.any(arr < p.lower) or np.any(arr > p.upper):
                raise UserError(f"{self.name}.{p.name} = {v} is outside its bounds [{p.lower:g}, {p.upper:g}] {p.unit}")
        return out

    def to_json(self, values: Values) -> dict:
        """The JSON form of ``values``: a joint parameter shared by all joints is one number."""
        out = {}
        for p in self.parameters:
            v = np.atleast_1d(np.asarray(values[p.name], dtype=float))
            out[p.name] = float(v[0]) if np.all(v == v[0]) else [float(x) for x in v]
        return out

    def describe(self) -> str:
        """One line per parameter: the catalogue as a user reads it (``acn-diagnose --list-effects``)."""
        lines = [f"{self.name}: {self.summary}", f"    MuJoCo: {self.mujoco}; PyBullet: {self.pybullet}"]
        for p in self.parameters:
            real = f", realistic {p.realistic[0]:g}..{p.realistic[1]:g}" if p.realistic else ""
            nominal = f"control setting {p.from_control}" if p.from_control else f"{p.nominal:g}"
            lines.append(f"    {p.name} [{p.unit}]{' per joint' if p.per_joint else ''}: nominal {nominal}, "
                         f"bounds {p.lower:g}..{p.upper:g}{real}")
        if self.reproduces:
            lines.append(f"    reproduces {', '.join(self.reproduces)} at some of its values (unsaturated PD)")
        return "\n".join(lines)


def _number(effect: str, p: Parameter, v) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v):
        raise UserError(f"{effect}.{p.name} must be a finite number, got {v!r}")
    return float(v)


def _joint_values(effect: str, p: Parameter, v, nominal: float) -> np.ndarray:
    if isinstance(v, dict):
        unknown = [k for k in v if k not in JOINT_NAMES]
        if unknown:
            raise UserError(f"{effect}.{p.name}: unknown joint(s) {', '.join(map(str, unknown))}; "
                            f"joints are {', '.join(JOINT_NAMES)}")
        out = np.full(NUM_JOINTS, float(nominal))
        for k, x in v.items():
            out[JOINT_NAMES.index(k)] = _number(effect, p, x)
        return out
    if isinstance(v, list):
        if len(v) != NUM_JOINTS:
            raise UserError(f"{effect}.{p.name}: a per-joint list needs {NUM_JOINTS} values, got {len(v)}")
        return np.array([_number(effect, p, x) for x in v])
    return np.full(NUM_JOINTS, _number(effect, p, v))


@dataclass
class AppliedEffect:
    """An effect with values, as it appears in a model."""

    effect: Effect
    values: Values

    @property
    def name(self) -> str:
        return self.effect.name

    def to_json(self) -> dict:
        return {"name": self.effect.name, "params": self.effect.to_json(self.values)}
