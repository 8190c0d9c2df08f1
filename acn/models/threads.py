"""How many torch intra-op threads a CPU loop runs on: fixed, or chosen by timing the loop itself.

Small networks on a small shared CPU are the case where the right answer changes with the
machine's load. Measured on 2 shared cores (AMD EPYC, bf16), acn-fit's training step at the
paper's network and batch 256: 47-63k samples/s on one thread and 103k on two while the machine
is otherwise idle, but 46-58k on one and 16-18k on two while another process keeps one core busy
(OpenMP's threads wait on each other whenever one is descheduled). ``AdaptiveThreads`` times the
candidate counts on the loop's own steps, interleaved, and runs on the fastest until the next
probe, so it follows the load as it changes.

Changing the count between steps does not change the results here: oneDNN splits a matmul's
rows and columns among threads, not its sums, so a fit on one or two threads gives the same
weights to the bit (``tests/test_fit.py`` checks it on this machine's kernels).
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable, Iterator

import torch


@contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Run a block on ``n`` torch intra-op threads (None or 0: leave torch's setting). Single-row
    calls of a small network lose much on a busy machine with more threads (0.1 ms on one, 8 ms on
    two while the other core was busy)."""
    if not n:
        yield
        return
    before = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def thread_candidates(most: int | None = None) -> tuple[int, ...]:
    """1, 2, 4, ... up to ``most`` (default: torch's own count, the machine's cores), and ``most``."""
    most = most or torch.get_num_threads()
    counts, n = [], 1
    while n < most:
        counts.append(n)
        n *= 2
    return (*counts, most)


@dataclass
class AdaptiveThreads:
    """Runs each step of a loop on the thread count that has been fastest lately.

    Every ``every_s`` seconds (and at the first step) a probe runs ``settle + window`` steps on
    each candidate count in turn and times the last ``window`` of them (the first steps after a
    change of count are slow: the thread team and the kernels' caches settle); the count with the
    least median step time is used until the next probe. Switching at every step instead made
    each two-thread step 2-3x slower than in a run of them. ``steps`` counts the steps run on
    each count (probes included). Use as a context manager: torch's setting is restored after.
    """

    candidates: tuple[int, ...] = field(default_factory=thread_candidates)
    window: int = 6          # timed steps per candidate in a probe
    settle: int = 2          # untimed steps after each change of count
    every_s: float = 2.0     # seconds of training between probes
    chosen: int = 0          # the current count (0 before the first probe)
    steps: dict[int, int] = field(default_factory=dict)
    _queue: list[tuple[int, bool]] = field(default_factory=list)
    _times: dict[int, list[float]] = field(default_factory=dict)
    _next_probe: float = 0.0
    _before: int = 0

    def __enter__(self) -> "AdaptiveThreads":
        self._before = torch.get_num_threads()
        return self

    def __exit__(self, *exc) -> None:
        torch.set_num_threads(self._before)

    def __call__(self, step: Callable[[], object]) -> None:
        """Run ``step()`` once, on the chosen count or as part of a probe."""
        if len(self.candidates) == 1:
            return self._run(self.candidates[0], step)
        if not self._queue and time.perf_counter() >= self._next_probe:
            # (count, timed?) per step, each candidate in one run; the chosen one last, so
            # training goes on without another change when it stays the fastest
            order = sorted(self.candidates, key=lambda c: c == self.chosen)
            self._queue = [(c, k >= self.settle) for c in order for k in range(self.settle + self.window)]
            self._times = {c: [] for c in self.candidates}
        if not self._queue:
            return self._run(self.chosen, step)
        n, timed = self._queue.pop(0)
        t = time.perf_counter()
        self._run(n, step)
        if timed:
            self._times[n].append(time.perf_counter() - t)
        if not self._queue:
            self.chosen = min(self.candidates, key=lambda c: sorted(self._times[c])[len(self._times[c]) // 2])
            self._next_probe = time.perf_counter() + self.every_s

    def _run(self, n: int, step: Callable[[], object]) -> None:
        if torch.get_num_threads() != n:
            torch.set_num_threads(n)
        step()
        self.steps[n] = self.steps.get(n, 0) + 1
