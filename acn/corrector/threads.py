"""How many torch intra-op threads a CPU loop runs on: fixed, or chosen by timing the loop itself.

Small networks on a small shared CPU are the case where the right answer changes with the
machine's load. Measured on 2 shared cores (AMD EPYC, bf16), acn-fit's training step at the
paper's network and batch 256: 55-66k samples/s on one thread and 80-96k on two while the machine
is otherwise idle, but 46-69k on one and 16-18k on two while another process keeps one core busy
(OpenMP's threads wait on each other whenever one is descheduled). ``AdaptiveThreads`` times the
candidate counts on the loop's own steps, one stretch each, and runs on the fastest until the
next probe, so it follows the load as it changes.

Changing the count between steps does not change the results here: oneDNN splits a matmul's
rows and columns among threads, not its sums, so a fit on one or two threads gives the same
weights to the bit (``tests/test_threads.py`` checks it on this machine's kernels).
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

    A probe runs each candidate count in turn: ``settle`` untimed steps (the first steps after a
    change of count are slow while the thread team and the kernels' caches settle; switching at
    every step made each two-thread step 2-3x slower than in a run of them), then timed steps for
    at least ``window_s`` seconds: longer than the scheduler's time slice, so that threads
    descheduled by another process show in the mean (a median over a few steps once chose two
    threads on a busy machine and trained at a third of one thread's rate). The count with the
    least mean step time runs until the next probe. Probes come at the first step and then after
    ``every_s`` seconds, an interval that doubles while the choice stays (up to ``most_every_s``);
    a change of choice, or the chosen count's steps slowing to ``slow_down`` times their probed
    time over a ``4 window_s`` stretch, brings the next probe at once. A candidate whose step
    takes ``give_up`` times the chosen count's is left at once (two threads on a busy machine can
    be a hundred times slower). ``steps`` counts the steps run on each count, probes included.
    Use as a context manager: torch's setting is restored after.
    """

    candidates: tuple[int, ...] = field(default_factory=thread_candidates)
    settle: int = 2             # untimed steps after each change of count
    window_s: float = 0.05      # timed seconds per candidate in a probe (at least 3 steps)
    every_s: float = 2.0        # seconds of training between probes, at first and after a change
    most_every_s: float = 32.0  # the longest interval while the choice stays
    give_up: float = 3.0        # leave a candidate whose step takes this times the chosen one's
    slow_down: float = 1.5      # probe again when the chosen count's steps get this much slower
    chosen: int = 0             # the current count (0 before the first probe)
    steps: dict[int, int] = field(default_factory=dict)
    _pending: list[int] = field(default_factory=list)  # the counts this probe has still to time
    _mean: dict[int, float] = field(default_factory=dict)  # this probe's mean step time per count (s)
    _ran: list = field(default_factory=lambda: [0, 0, 0.0])  # current stretch: steps, timed steps, seconds
    _typical: float = 0.0       # the chosen count's mean step time at the last probe (s)
    _interval: float = 0.0
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
        if not self._pending and time.perf_counter() >= self._next_probe:
            # each candidate in one stretch, the chosen one last: training goes on without
            # another change of count when it stays the fastest
            self._pending = sorted(self.candidates, key=lambda c: c == self.chosen)
            self._mean, self._ran = {}, [0, 0, 0.0]
        n = self._pending[0] if self._pending else self.chosen
        t = time.perf_counter()
        self._run(n, step)
        took = time.perf_counter() - t
        ran = self._ran
        ran[0] += 1
        if ran[0] > (self.settle if self._pending else 0):
            ran[1], ran[2] = ran[1] + 1, ran[2] + took
        if not self._pending:  # watch the chosen count
            if ran[2] >= 4 * self.window_s:
                if ran[2] / ran[1] > self.slow_down * self._typical:
                    self._next_probe, self._interval = 0.0, self.every_s / 2  # the next probe now, then every_s
                self._ran = [0, 0, 0.0]
        elif self._typical and n != self.chosen and took > self.give_up * self._typical:
            self._next_count(took)
        elif ran[1] >= 3 and ran[2] >= self.window_s:
            self._next_count(ran[2] / ran[1])

    def _next_count(self, mean: float) -> None:
        self._mean[self._pending.pop(0)] = mean
        self._ran = [0, 0, 0.0]
        if self._pending:
            return
        best = min(self._mean, key=self._mean.__getitem__)
        self._interval = min(2 * self._interval, self.most_every_s) if best == self.chosen else self.every_s
        self.chosen, self._typical = best, self._mean[best]
        self._next_probe = time.perf_counter() + self._interval

    def _run(self, n: int, step: Callable[[], object]) -> None:
        if torch.get_num_threads() != n:
            torch.set_num_threads(n)
        step()
        self.steps[n] = self.steps.get(n, 0) + 1
