"""The corrector's card (``config.json``): what a corrector is, what it was fitted on, and the one
check that it fits the target it is about to run on.

``CorrectorCard.from_json`` parses and validates the card once (``Corrector.load``), with a
one-line ``UserError`` for a malformed one; ``to_json`` writes the same JSON back. The network's
shape (variant, width, channels, ``delta_scale``) is what ``Corrector`` is built from; the rest
(``fit``, ``normalisation``, ``training_data``, ``metrics``) is the record ``acn-fit`` adds, absent
in the card of a corrector that was never fitted.

``refuse_unless_fits(target, directory)`` compares the card's training data with a
``TargetDescription`` (simulator, action mode, control rate, physical effects, action channels):
every command that applies a corrector calls it, through ``load_for_target``
(``acn.corrector.corrector``). A training-data field the card does not record is not compared.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

from acn.corrector.acn import OUTPUT_CHANNELS, VARIANTS, input_channels
from acn.datasets.metadata import Simulator
from acn.errors import UserError
from acn.sim.state import ACTION_DIM, ACTION_NAMES, STATE_NAMES

FORMAT = "acn-corrector/1"
ACTIVATIONS = ("SiLU",)
_REQUIRED = object()


@dataclass(frozen=True)
class Network:
    """The width and depth of ActionNet (and JacobianNet); SiLU between layers."""

    hidden: int
    layers: int
    activation: str = "SiLU"


@dataclass(frozen=True)
class Normalisation:
    """Training-set statistics (the network's own copies are buffers in ``model.safetensors``);
    ``state_spread``: each output channel's spread, the channel scale of divergence and oracles."""

    state_mean: tuple[float, ...]
    state_std: tuple[float, ...]
    action_mean: tuple[float, ...]
    action_std: tuple[float, ...]
    residual_std: tuple[float, ...]
    state_spread: tuple[float, ...]
    delta_scale: tuple[float, ...] | None = None  # labelled variants, before calibration


@dataclass(frozen=True)
class TrainingData:
    """What the corrector was fitted on. None (or empty): not recorded, so not compared."""

    datasets: tuple[str, ...] = ()
    fingerprint: str | None = None
    source: Simulator | None = None
    target: Simulator | None = None
    target_effects: tuple[dict, ...] = ()   # ``AppliedEffect.to_json`` of ``acn-fit --model``'s effects
    action_mode: str | None = None
    control_hz: float | None = None
    policy: str | None = None

    def to_json(self) -> dict:
        return {"datasets": list(self.datasets), "fingerprint": self.fingerprint,
                "source": None if self.source is None else self.source.to_json(),
                "target": None if self.target is None else self.target.to_json(),
                "target_effects": [dict(e) for e in self.target_effects], "action_mode": self.action_mode,
                "control_hz": self.control_hz, "policy": self.policy}


@dataclass(frozen=True)
class TargetDescription:
    """The target a corrector is about to run on, in the terms of its card's training data.
    ``effects``: the physical effects the target has (``AppliedEffect.to_json``; () the simulator
    as is); None where the target takes the corrector's own effects (``acn-view`` re-simulates
    the target with them)."""

    simulator: str
    action_mode: str
    control_hz: float
    effects: tuple[dict, ...] | None = ()
    action_channels: tuple[str, ...] = ACTION_NAMES


@dataclass(frozen=True)
class CorrectorCard:
    """A corrector's ``config.json``; see the module docstring."""

    variant: str
    network: Network
    input_channels: tuple[str, ...]
    output_channels: tuple[str, ...] = OUTPUT_CHANNELS
    action_channels: tuple[str, ...] | None = None
    delta_scale: tuple[float, ...] | None = None  # network output -> action units (labelled variants)
    fit: Mapping[str, Any] | None = None          # every hyper-parameter of acn-fit (``FitConfig``)
    normalisation: Normalisation | None = None
    training_data: TrainingData = field(default_factory=TrainingData)
    metrics: Mapping[str, Any] | None = None      # a summary of ``metrics.json``

    @classmethod
    def untrained(cls, variant: str, hidden: int, layers: int, sensors: bool | None = None) -> "CorrectorCard":
        """The card of a network not fitted yet: its shape only."""
        return cls(variant, Network(hidden, layers), input_channels(variant, sensors))

    def refuse_unless_fits(self, target: TargetDescription, directory: object) -> None:
        """A one-line ``UserError`` where the corrector was fitted for another target than ``target``."""
        t = self.training_data

        def refuse(fitted_for: str, here: str, hint: str = "") -> None:
            raise UserError(f"corrector {directory} was fitted for {fitted_for}; here {here}{hint}")

        if t.target is not None and t.target.simulator != target.simulator:
            refuse(f"a {t.target.simulator} target", f"the target is {target.simulator}")
        if t.action_mode is not None and t.action_mode != target.action_mode:
            refuse(f"{t.action_mode}-mode actions", f"the actions are {target.action_mode}-mode")
        if t.control_hz is not None and abs(t.control_hz - target.control_hz) > 1e-6:
            refuse(f"{t.control_hz:g} Hz control", f"the control rate is {target.control_hz:g} Hz")
        if self.action_channels is not None and tuple(self.action_channels) != tuple(target.action_channels):
            refuse(f"the action channels {', '.join(self.action_channels)}",
                   f"they are {', '.join(target.action_channels)}")
        if target.effects is not None and list(t.target_effects) != list(target.effects):
            def text(effects) -> str:
                return " + ".join(str(e.get("name", "?")) for e in effects) or "nothing"

            refuse(f"a target with {text(t.target_effects)} added", f"the target has {text(target.effects)} added",
                   " (fit one for it: acn-fit --model MODEL.json)")

    # ----- JSON ---------------------------------------------------------------------------------
    def to_json(self) -> dict:
        """The card as written to ``config.json`` (``"format"`` first, the record only if fitted)."""
        out: dict = {"format": FORMAT, "variant": self.variant,
                     "network": {"hidden": self.network.hidden, "layers": self.network.layers,
                                 "activation": self.network.activation},
                     "input_channels": list(self.input_channels), "output_channels": list(self.output_channels),
                     "action_channels": None if self.action_channels is None else list(self.action_channels),
                     "delta_scale": None if self.delta_scale is None else list(self.delta_scale)}
        if self.fit is not None:
            out["fit"] = dict(self.fit)
        if self.normalisation is not None:
            n = self.normalisation
            out["normalisation"] = {k: None if v is None else list(v) for k, v in vars(n).items()}
        if self.fit is not None or self.training_data != TrainingData():
            out["training_data"] = self.training_data.to_json()
        if self.metrics is not None:
            out["metrics"] = dict(self.metrics)
        return out

    @classmethod
    def from_json(cls, obj: object, where: str, directory: object) -> "CorrectorCard":
        """Parse and validate a card; a one-line ``UserError`` naming ``where`` (the file) if it is
        malformed, or naming the corrector ``directory`` if it was fitted for other state channels."""
        if not isinstance(obj, dict) or obj.get("format") != FORMAT:
            raise UserError(f"{where} is not an acn corrector config (format {FORMAT!r} expected)")
        read = _Reader(where)
        variant = read(obj, "variant", lambda v: v in VARIANTS, f"one of {', '.join(VARIANTS)}")
        net = read(obj, "network", _is_dict, "an object")
        network = Network(read(net, "hidden", _positive_int, "a whole number > 0", "network."),
                          read(net, "layers", _positive_int, "a whole number > 0", "network."),
                          read(net, "activation", lambda v: v in ACTIVATIONS, " or ".join(ACTIVATIONS), "network.",
                               default="SiLU"))
        channels = {}
        for key in ("input_channels", "output_channels"):
            channels[key] = tuple(read(obj, key, _names, "a list of state channel names"))
            unknown = [c for c in channels[key] if c not in STATE_NAMES]
            if unknown:
                raise UserError(f"corrector {directory} was fitted for other state channels ({unknown[0]!r} is not "
                                f"one of this toolkit's)")
        actions = read(obj, "action_channels", _names, "a list of action channel names", default=None)
        delta = read(obj, "delta_scale", _numbers(ACTION_DIM), f"a list of {ACTION_DIM} numbers", default=None)
        fit = read(obj, "fit", _is_dict, "an object", default=None)
        metrics = read(obj, "metrics", _is_dict, "an object", default=None)
        norm = read(obj, "normalisation", _is_dict, "an object", default=None)
        data = read(obj, "training_data", _is_dict, "an object", default=None) or {}
        return cls(variant, network, channels["input_channels"], channels["output_channels"],
                   None if actions is None else tuple(actions), None if delta is None else tuple(delta),
                   fit, None if norm is None else _normalisation(read, norm), _training_data(read, data), metrics)


class _Reader:
    """``read(obj, key, ok, what)``: ``obj[key]`` if ``ok`` accepts it, else a one-line ``UserError``."""

    def __init__(self, where: str) -> None:
        self.where = where

    def __call__(self, obj: dict, key: str, ok: Callable[[Any], bool], what: str, prefix: str = "",
                 default: Any = _REQUIRED) -> Any:
        if obj.get(key) is None and default is not _REQUIRED:
            return default
        if key not in obj:
            raise UserError(f"{self.where} has no '{prefix}{key}'")
        if not ok(obj[key]):
            raise UserError(f"{self.where}: '{prefix}{key}' must be {what}, got {json.dumps(obj[key])[:60]}")
        return obj[key]


def _is_dict(v) -> bool:
    return isinstance(v, dict)


def _positive_int(v) -> bool:
    return isinstance(v, int) and not isinstance(v, bool) and v > 0


def _number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _names(v) -> bool:
    return isinstance(v, list) and all(isinstance(x, str) for x in v)


def _numbers(n: int | None = None) -> Callable[[Any], bool]:
    return lambda v: isinstance(v, list) and (n is None or len(v) == n) and all(_number(x) for x in v)


def _simulator(v) -> bool:
    return isinstance(v, dict) and isinstance(v.get("simulator"), str) \
        and isinstance(v.get("version"), (str, type(None)))


def _normalisation(read: _Reader, norm: dict) -> Normalisation:
    values = {key: tuple(read(norm, key, _numbers(), "a list of numbers", "normalisation."))
              for key in ("state_mean", "state_std", "action_mean", "action_std", "residual_std", "state_spread")}
    delta = read(norm, "delta_scale", _numbers(ACTION_DIM), f"a list of {ACTION_DIM} numbers", "normalisation.",
                 default=None)
    return Normalisation(**values, delta_scale=None if delta is None else tuple(delta))


def _training_data(read: _Reader, data: dict) -> TrainingData:
    p = "training_data."

    def simulator(key: str) -> Simulator | None:
        v = read(data, key, _simulator, 'an object with a "simulator" name and a "version"', p, default=None)
        return None if v is None else Simulator(simulator=v["simulator"], version=v["version"])

    effects = read(data, "target_effects", lambda v: isinstance(v, list) and all(
        isinstance(e, dict) and isinstance(e.get("name"), str) for e in v), 'a list of effects ({"name": ...})', p,
        default=[])
    hz = read(data, "control_hz", lambda v: _number(v) and v > 0, "a number > 0 (Hz)", p, default=None)
    return TrainingData(
        datasets=tuple(read(data, "datasets", _names, "a list of dataset paths", p, default=[])),
        fingerprint=read(data, "fingerprint", lambda v: isinstance(v, str), "a string", p, default=None),
        source=simulator("source"), target=simulator("target"), target_effects=tuple(effects),
        action_mode=read(data, "action_mode", lambda v: isinstance(v, str), "an action mode", p, default=None),
        control_hz=hz,
        policy=read(data, "policy", lambda v: isinstance(v, str), "a policy name", p, default=None))
