"""How many CPUs this process may run on: the thread pools and a local Ray instance size by it."""

from __future__ import annotations

import os


def usable_cpus() -> int:
    """CPUs this process may run on (a taskset or a container's CPU set; all of them where the
    platform cannot say, as on macOS)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
