"""Hidden effects: measurements with a physical effect the diagnosis has to find.

``acn-collect --hidden-effect SPEC`` applies effects to the source simulator (the "robot")
and writes the answer beside the dataset (``DIR.answer.json``), never inside it. SPEC is

- ``random``: a random catalogue effect at a realistic magnitude;
- ``NAME``: that effect, every parameter at a random realistic magnitude;
- ``NAME:param=value,...``: the given values (a joint parameter: one number for every joint, or
  12 numbers separated by ``/``); parameters not given stay nominal.

Realistic magnitudes are each parameter's ``realistic`` range (``acn.sim.effects``); a
``signed`` parameter (encoder offsets, payload COM) gets a random sign, drawn per joint.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from acn.atomic import write_file
from acn.errors import UserError
from acn.outputs import Output, json_object
from acn.sim.effects import CATALOGUE, EFFECT_NAMES, AppliedEffect, Effect, get_effect
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


def write_answer(dataset: str | Path, effects: list[AppliedEffect], seed: int) -> Path:
    """Write the answer file whole or not at all."""
    return write_file(answer_path(dataset), json.dumps({"format": ANSWER_FORMAT, "dataset": str(Path(dataset).name),
                                                        "seed": seed, "hidden_effects": [e.to_json() for e in effects]},
                                                       indent=2) + "\n")
