"""A model: a backend with the shared A1 description plus physical effects, saved as JSON.

    {"format": "acn-model/1",
     "backend": "mujoco",
     "effects": [{"name": "actuator_latency", "params": {"seconds": 0.012}},
                 {"name": "joint_damping", "params": {"value": [0.3, 0.3, ...]}}],
     "corrector": null}

Control settings (rates, gains, torque limit, action mode) are not part of a model: they belong
to the measurements (each dataset's ``acn`` metadata) and are combined with the model by
``Model.sim_config``. Effects apply in order; adding an effect already present replaces it.
``format`` marks a file the toolkit saved (only such a file is replaced by ``--save-model``); a
hand-written model may leave it out.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path

from acn.errors import UserError
from acn.jsonfile import read_json
from acn.outputs.kinds import Output, json_with_format
from acn.outputs.writing import write_file
from acn.sim.backends import BACKENDS, SimConfig
from acn.sim.effects.catalogue import get_effect
from acn.sim.effects.effect import AppliedEffect, Effect, Values
from acn.sim.robot import ModelParams

MODEL_KEYS = ("format", "backend", "effects", "corrector")
FORMAT = "acn-model/1"  # written into every model file the toolkit saves; a hand-written one may omit it
EFFECT_KEYS = ("name", "params")


@dataclass
class Model:
    backend: str = "mujoco"
    effects: list[AppliedEffect] = field(default_factory=list)
    corrector: str | None = None  # directory of a frozen corrector applied to the model's actions
    # A sealed model (a robot with hidden effects, ``acn.sim.hidden.load_model``) is simulated like any
    # other, but never shows or writes its effects: ``describe`` names none and ``to_json`` refuses.
    sealed: bool = False

    def params(self, base: ModelParams | None = None) -> ModelParams:
        """``base`` (default nominal) with every effect written in, in order."""
        out = (base or ModelParams()).copy()
        for term in self.effects:
            term.effect.apply(out, term.values)
        return out

    def sim_config(self, control: SimConfig) -> SimConfig:
        """The simulator config: ``control``'s settings, this model's physical parameters."""
        return replace(control, params=self.params(control.params))

    def with_effect(self, effect: Effect, values: Values) -> "Model":
        """A new model with ``effect`` added (replacing an earlier one of the same name)."""
        kept = [t for t in self.effects if t.name != effect.name]
        return Model(self.backend, [*kept, AppliedEffect(effect, dict(values))], self.corrector, self.sealed)

    def describe(self) -> str:
        if self.sealed:
            return f"{self.backend} + sealed effects"
        parts = [self.backend]
        for t in self.effects:
            vals = ", ".join(f"{k}={_short(v)}" for k, v in t.effect.to_json(t.values).items())
            parts.append(f"{t.name}({vals})")
        return " + ".join(parts)

    # ----- JSON -----------------------------------------------------------------------------
    def to_json(self) -> dict:
        if self.sealed:
            raise UserError("a sealed robot's effects are not written out; give the robot itself (its answer file)")
        return {"format": FORMAT, "backend": self.backend, "effects": [t.to_json() for t in self.effects],
                "corrector": self.corrector}

    @classmethod
    def from_json(cls, d: dict, where: str = "model") -> "Model":
        if not isinstance(d, dict):
            raise UserError(f"{where}: a model is a JSON object with keys {', '.join(MODEL_KEYS)}")
        unknown = [k for k in d if k not in MODEL_KEYS]
        if unknown:
            raise UserError(f"{where}: unknown key(s) {', '.join(map(repr, unknown))}; a model has {', '.join(MODEL_KEYS)}")
        backend = d.get("backend", "mujoco")
        if backend not in BACKENDS:
            raise UserError(f"{where}: unknown backend {backend!r}; choose from {', '.join(BACKENDS)}")
        effects_raw = d.get("effects", [])
        if not isinstance(effects_raw, list):
            raise UserError(f"{where}: 'effects' must be a list")
        if "format" in d and d["format"] != FORMAT:
            raise UserError(f"{where}: format {d['format']!r:.40} is not {FORMAT!r}")
        corrector = d.get("corrector")
        if corrector is not None and not (isinstance(corrector, str) and corrector.strip()):
            raise UserError(f"{where}: 'corrector' must be null or a corrector directory path, got {corrector!r:.40}")
        model = cls(backend=backend, corrector=corrector)
        for e in effects_raw:
            if not isinstance(e, dict) or "name" not in e:
                raise UserError(f"{where}: each effect is an object with 'name' and 'params'")
            bad = [k for k in e if k not in EFFECT_KEYS]
            if bad:
                raise UserError(f"{where}: unknown key(s) {', '.join(map(repr, bad))} in effect {e.get('name')!r}")
            effect = get_effect(e["name"])
            model = model.with_effect(effect, effect.parse(e.get("params", {})))
        return model

    @classmethod
    def load(cls, path: str | Path) -> "Model":
        p = Path(path)
        return cls.from_json(read_json(p, f"model file {p} does not exist"), where=str(p))

    @classmethod
    def parse(cls, spec: str | Path) -> "Model":
        """A backend name (the nominal model) or a model JSON file."""
        if str(spec) in BACKENDS:
            return cls(backend=str(spec))
        if not str(spec).endswith(".json") and not Path(spec).is_file():
            raise UserError(f"model {str(spec)!r} is neither a backend ({', '.join(BACKENDS)}) nor a model JSON file")
        return cls.load(spec)

    def to_text(self) -> str:
        """The model file's text."""
        return json.dumps(self.to_json(), indent=2) + "\n"

    def save(self, path: str | Path) -> Path:
        """Write the JSON file whole or not at all."""
        return write_file(path, self.to_text(), MODEL_FILE)


def _short(v) -> str:
    return f"{v:.4g}" if isinstance(v, float) else "[" + ", ".join(f"{x:.3g}" for x in v) + "]"


# A model file the toolkit saved (``--save-model``): recognised by its format, so a hand-written
# model is never replaced.
MODEL_FILE = Output("model file", directory=False, recognise=json_with_format(FORMAT))
