"""Hidden effects: measurements with a physical effect the diagnosis has to find.

``acn-collect --hidden-effect SPEC`` applies effects to the source simulator (the "robot")
and writes the answer beside the dataset (``DIR.answer.json``), never inside it. SPEC is

- ``random``: a random catalogue effect at a realistic magnitude;
- ``NAME``: that effect, every parameter at a random realistic magnitude;
- ``NAME:param=value,...``: the given values (a joint parameter: one number for every joint, or
  12 numbers separated by ``/``); parameters not given stay nominal.

Realistic magnitudes are each parameter's ``realistic`` range (``acn.sim.effects``); a
``signed`` parameter (encoder offsets, payload COM) gets a random sign, drawn per joint.

A robot with hidden effects can be driven again without being shown: ``load_model`` takes the
answer file (or the dataset it sits beside) and returns a sealed ``Model``, which every command
that runs a robot (``acn-collect``, ``acn-fit --model``, ``acn-ppo``, ``acn-transfer``) simulates
like any other model while its description names no effect.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from acn.errors import UserError
from acn.jsonfile import read_json
from acn.outputs.kinds import Output, json_object
from acn.outputs.writing import write_file
from acn.sim.backends import BACKENDS
from acn.sim.effects import CATALOGUE, EFFECT_NAMES, AppliedEffect, Effect, Model, get_effect
from acn.sim.state import NUM_JOINTS


def realistic_values(effect: Effect, rng: np.random.Generator, control) -> dict:
    """Every parameter of ``effect`` at a random realistic magnitude (see module docstring)."""
    values = effect.nominal(control)
    for p in effect.parameters:
        if p.realistic is None:
            continue
        lo, hi = p.realistic
        if p.signed:
            n = NUM_JOINTS if p.per_joint else 1
            v = p.nominal + rng.uniform(lo, hi, n) * rng.choice([-1.0, 1.0], n)
            values[p.name] = v if p.per_joint else float(v[0])
        else:
            v = float(rng.uniform(lo, hi))
            values[p.name] = np.full(NUM_JOINTS, v) if p.per_joint else v
    return values


def parse_hidden(spec: str, rng: np.random.Generator, control) -> AppliedEffect:
    """One ``--hidden-effect`` argument (module docstring) -> an effect with values."""
    if spec == "random":
        effect = CATALOGUE[EFFECT_NAMES[rng.integers(len(EFFECT_NAMES))]]
        return AppliedEffect(effect, realistic_values(effect, rng, control))
    name, _, rest = spec.partition(":")
    effect = get_effect(name)
    if not rest:
        return AppliedEffect(effect, realistic_values(effect, rng, control))
    raw: dict = {}
    for item in rest.split(","):
        key, eq, text = item.partition("=")
        if not eq:
            raise UserError(f"--hidden-effect {spec!r}: expected param=value, got {item!r}")
        try:
            numbers = [float(x) for x in text.split("/")]
        except ValueError:
            raise UserError(f"--hidden-effect {spec!r}: {text!r} is not a number") from None
        raw[key.strip()] = numbers[0] if len(numbers) == 1 else numbers
    return AppliedEffect(effect, effect.parse(raw, control))


def draw_hidden(specs: list[str] | tuple[str, ...], seed: int, control,
                given: list[AppliedEffect] = ()) -> list[AppliedEffect]:
    """``given`` effects (a source model's) and ``--hidden-effect`` arguments -> effects with values,
    drawn from ``seed``; no effect twice."""
    rng = np.random.default_rng([seed, 0x41])
    out: list[AppliedEffect] = list(given)
    for spec in specs:
        for _ in range(100):
            effect = parse_hidden(spec, rng, control)
            if effect.name not in {e.name for e in out}:
                break
            if spec != "random":
                raise UserError(f"--hidden-effect {effect.name} is given twice, or the source model has it already")
        out.append(effect)
    return out


ANSWER_FORMAT = "acn-answer/1"


def _is_answer(path: Path) -> bool:
    d = json_object(path) if path.is_file() else None
    return d is not None and (d.get("format") == ANSWER_FORMAT or set(d) == {"dataset", "seed", "hidden_effects"})


# The sealed answer beside a dataset: replaced (or removed, with a dataset collected without
# hidden effects) only where it is one the toolkit wrote.
ANSWER = Output("hidden-effect answer", directory=False, recognise=_is_answer)


def answer_path(dataset: str | Path) -> Path:
    """Where the answer to a hidden-effect dataset lives: ``DIR.answer.json`` beside ``DIR``."""
    d = Path(dataset)
    return d.parent / f"{d.name}.answer.json"


def write_answer(dataset: str | Path, backend: str, effects: list[AppliedEffect], seed: int) -> Path:
    """Write the answer file whole or not at all: the robot's simulator and its hidden effects."""
    return write_file(answer_path(dataset), json.dumps({"format": ANSWER_FORMAT, "dataset": str(Path(dataset).name),
                                                        "seed": seed, "backend": backend,
                                                        "hidden_effects": [e.to_json() for e in effects]},
                                                       indent=2) + "\n", ANSWER)


def sealed_robot(answer: str | Path, backend: str | None = None) -> Model:
    """The robot an answer file describes, sealed (its effects are simulated, never shown).
    ``backend``: the robot's simulator where the answer does not name it."""
    path = Path(answer)
    d = read_json(path, f"answer file {path} does not exist")
    if not _is_answer(path):
        raise UserError(f"{path} is not a hidden-effect answer (format {ANSWER_FORMAT!r} expected)")
    backend = d.get("backend", backend)
    if backend is None:
        raise UserError(f"{path} does not name its robot's simulator; collect the dataset again")
    model = Model.from_json({"backend": backend, "effects": d.get("hidden_effects", [])}, where=str(path))
    return Model(model.backend, model.effects, sealed=True)


def load_model(spec: str | Path) -> Model:
    """A model from the command line: a backend (nominal), a model JSON file, or a robot with
    hidden effects, sealed (its answer file, or the dataset directory the answer sits beside)."""
    text = str(spec)
    if text in BACKENDS:
        return Model(backend=text)
    path = Path(spec)
    if path.is_dir():
        if not answer_path(path).is_file():
            raise UserError(f"{path} is a directory without a hidden-effect answer beside it ({answer_path(path)}); "
                            f"a model is {', '.join(BACKENDS)}, a model JSON file or a hidden-effect dataset")
        return sealed_robot(answer_path(path))
    if path.is_file() and _is_answer(path):
        return sealed_robot(path)
    return Model.parse(spec)
