"""The decision trace: each rule of the selection that decides something, what it read and what it decided.

A rule of ``policy`` is a named function from evidence (the held-out figures of ``heldout``, a
fit's values) and its ``Thresholds`` to a decision. Where one decides the course of the diagnosis
(a candidate added or set aside, one put in another's place, a granularity chosen, a chain kept,
the verdict), it calls ``record``. ``diagnose`` collects them (``tracing``) into
``Diagnosis.decisions``, which the JSON (``decisions``), the terminal, the HTML report and
``acn-view``'s diagnosis panel show: they read the trace and never run a rule again. Outside
``tracing`` (a rule called alone, as the unit tests do) ``record`` keeps nothing.

A ``Decision`` holds the ``rule`` (the function's name in ``policy``), its ``inputs`` by name (the
evidence and every threshold it compared them with), the ``outcome`` in a few words, the same
as a ``sentence`` built from those inputs (so a text cannot say another number than the rule
used), and ``within``: the search it was made in ("" for the chain the diagnosis reports as it
is built; "chain started with X" for ``policy.other_starts``' other chains, "revisit X" for an
effect judged again beside the others).
"""

from __future__ import annotations

from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass, field
from typing import Iterator

Input = float | int | str | bool | None


@dataclass(frozen=True)
class Decision:
    rule: str                    # the deciding function of ``policy``
    inputs: dict[str, Input]     # what it compared, thresholds included, by name
    outcome: str                 # what it decided, in a few words
    sentence: str                # the decision in words, built from ``inputs``
    within: str = ""             # the search it was made in ("" for the reported chain as it is built)

    def to_json(self) -> dict:
        return {"rule": self.rule, "inputs": dict(self.inputs), "outcome": self.outcome,
                "sentence": self.sentence, "within": self.within}


@dataclass
class Trace:
    """The decisions of one diagnosis, in the order made."""

    decisions: list[Decision] = field(default_factory=list)
    searches: list[str] = field(default_factory=list)  # the ``within`` labels open now, outermost first


_ACTIVE: ContextVar[Trace | None] = ContextVar("acn_diagnosis_trace", default=None)


@contextmanager
def tracing() -> Iterator[Trace]:
    """Collect every ``record`` made inside the block into the trace yielded."""
    trace = Trace()
    token = _ACTIVE.set(trace)
    try:
        yield trace
    finally:
        _ACTIVE.reset(token)


@contextmanager
def within(search: str) -> Iterator[None]:
    """Mark the decisions recorded inside the block as made in ``search`` (nested searches join by "; ")."""
    trace = _ACTIVE.get()
    if trace is None:
        yield
        return
    trace.searches.append(search)
    try:
        yield
    finally:
        trace.searches.pop()


def record(rule: str, outcome: str, sentence: str, **inputs: Input) -> None:
    """One decision of ``rule`` into the trace being collected (nothing outside ``tracing``)."""
    trace = _ACTIVE.get()
    if trace is not None:
        clean = {k: (v.item() if hasattr(v, "item") else v) for k, v in inputs.items()}  # numpy scalars as Python ones
        trace.decisions.append(Decision(rule, clean, outcome, sentence, "; ".join(trace.searches)))


def share(x: float | None) -> str:
    """A share as the decisions' sentences print it: "97%", "-3.1%" under 10 %."""
    if x is None:
        return "not checked"
    return f"{x:.0%}" if abs(x) >= 0.1 else f"{x:.1%}"
