"""Physical effects a model can lack: a catalogue you can list, apply, fit and print.

``CATALOGUE`` maps each effect name to an ``Effect`` (parameters with units, nominal values and
bounds, and a modifier writing them into ``ModelParams``); ``Model`` is a backend plus applied
effects, saved as JSON. ``print(describe_catalogue())`` lists them all.
"""

from acn.sim.effects.catalogue import CATALOGUE, EFFECT_NAMES, get_effect
from acn.sim.effects.effect import AppliedEffect, Effect, Parameter, Values
from acn.sim.effects.model import Model


def describe_catalogue() -> str:
    return "\n".join(e.describe() for e in CATALOGUE.values())


__all__ = ["CATALOGUE", "EFFECT_NAMES", "AppliedEffect", "Effect", "Model", "Parameter", "Values",
           "describe_catalogue", "get_effect"]
