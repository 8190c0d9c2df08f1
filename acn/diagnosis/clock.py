"""The wall time of each stage of a diagnosis, in the order the stages ran.

``StageClock.stage(name)`` times a block; a stage that runs again (a second add of the same
name) adds up. ``verbose`` hears each stage as it ends (``acn-diagnose --verbose``), and the
JSON result carries them all (``Diagnosis.stages``).
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable, Iterator


@dataclass
class StageClock:
    seconds: dict[str, float] = field(default_factory=dict)  # stage -> wall time, s, in the order run
    verbose: Callable[[str], None] | None = None              # hears "<stage>: <seconds> s" as each ends
    started: float = field(default_factory=time.perf_counter)  # the diagnosis's start (``time.perf_counter``)

    def elapsed(self) -> float:
        """Seconds since the clock was made (the diagnosis's wall time so far)."""
        return time.perf_counter() - self.started

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time the block as stage ``name``."""
        start = time.perf_counter()
        try:
            yield
        finally:
            self.record(name, start)

    def record(self, name: str, start: float) -> float:
        """Stage ``name`` ran from ``start`` (``time.perf_counter``) until now; returns now."""
        now = time.perf_counter()
        self.seconds[name] = self.seconds.get(name, 0.0) + now - start
        if self.verbose:
            self.verbose(f"{name}: {now - start:.1f} s")
        return now

