"""What the selection (``policy``) produces, as the report, the JSON and ``acn-view`` read it: a
ranked ``Candidate``, an effect ``Added`` to the model, and a ``Chain`` of effects added one
after the other by ``--auto``."""

from __future__ import annotations

from dataclasses import dataclass, field

from acn.diagnosis.compare import Comparison
from acn.diagnosis.fitting import EffectFit, granularity_of
from acn.diagnosis.granularity import finer
from acn.diagnosis.heldout import Judgement, longest_removed
from acn.sim.effects import Model


@dataclass(frozen=True)
class Candidate:
    """One candidate effect, fitted and judged on held-out rows: evidence, which no rule changes
    (a rule that finds more gives a new one: ``policy.ranking.longer_gains``)."""

    fit: EffectFit
    judgement: Judgement
    score: float                      # the share of the error it removes, less a price per fitted parameter
    longer_gain: float | None = None  # share of the longest-horizon open-loop error it removes (None: not checked)

    @property
    def name(self) -> str:
        return self.fit.effect.name


@dataclass
class Added:
    """One effect added to the model: the fit and the error before and after."""

    fit: EffectFit
    judgement: Judgement
    before: Comparison
    after: Comparison
    ties: list[Candidate] = field(default_factory=list)  # the candidate it was added as, first, and those of the
    # same ranking the held-out one step could not tell from it (``policy.tied_either_way``; ``--auto``'s effects and
    # the first one ``--add`` names); [] if none
    refined: bool = False  # ``policy.refine_chain`` has refined this step (or kept it where refining predicted worse)

    @property
    def name(self) -> str:
        return self.fit.effect.name

    @property
    def refines(self) -> str:
        """The coarser granularity the effect had in the model before this step, where this step
        fits it finer ("" otherwise): ``policy.greedy`` fitting an effect again beside those added after it."""
        was = held(self.before.model, self.name)
        return was if finer(self.fit.granularity, was) else ""


def names(steps: list[Added]) -> list[str]:
    """The effects ``steps`` add, each once, in the order first added (a refinement adds none)."""
    return list(dict.fromkeys(a.name for a in steps))


def longer_gain(step: Added) -> float | None:
    """Share of the open-loop error at the check's horizon (> 1) the step removes (None with
    one-step horizons only)."""
    return longest_removed(step.before, step.after)


def held(model: Model, name: str) -> str:
    """The granularity ``model`` holds effect ``name`` at ("" where it does not hold it)."""
    return next((granularity_of(t.effect, t.values) for t in model.effects if t.name == name), "")


@dataclass
class Chain:
    """Effects added one after the other by --auto, and how well the result predicts."""

    steps: list[Added]
    start: str                      # the candidate the chain was started with
    kept: bool = False              # the chain the diagnosis reports
    why: str = ""                   # why it was kept or set aside, in words
    versus: dict = field(default_factory=dict)  # against the chain kept before it (``policy.other_starts``)

    @property
    def names(self) -> list[str]:
        return names(self.steps)

    @property
    def label(self) -> str:
        """The added effects in words: "payload + joint_damping", or "nothing added"."""
        return " + ".join(self.names) or "nothing added"

    def to_json(self) -> dict:
        return {"start": self.start, "added": self.names, "kept": self.kept, "why": self.why, **self.versus}
