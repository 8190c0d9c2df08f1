"""Helper processes end with the run they help, however it ends (a SIGKILL included).

A helper's parent is not always the run: a ``multiprocessing`` forkserver child's parent is the
forkserver, which lives as long as its children do. So a helper watches the run's pid itself:
``end_with(pid)`` starts a thread that waits on a pidfd of ``pid`` (no polling, no pid reuse) and
ends this process once ``pid`` has ended: at once (``os._exit``), or, with ``graceful``, by a
SIGTERM to itself, so that a toolkit command stops as on Ctrl-C and removes what it was building.

A toolkit command run as a child of another (the transfer study's stages) learns its run's pid
from ``ACN_END_WITH`` in its environment (``child_environment``), read by the CLI.
"""

from __future__ import annotations

import os
import select
import signal
import threading
import time

ENV = "ACN_END_WITH"
GRACE_S = 60.0  # a graceful end that has not ended the process by then ends it at once


def end_with(pid: int, graceful: bool = False) -> None:
    """End this process when process ``pid`` ends (module docstring)."""
    def finish() -> None:
        if graceful:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(GRACE_S)
        os._exit(1)

    try:
        fd = os.pidfd_open(pid)
    except ProcessLookupError:
        finish()
        return
    except (AttributeError, OSError):  # no pidfd (an old kernel): look once a second
        fd = None

    def watch() -> None:
        if fd is not None:
            select.select([fd], [], [])
        else:
            while _alive(pid):
                time.sleep(1.0)
        finish()

    threading.Thread(target=watch, name=f"end-with-{pid}", daemon=True).start()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def child_environment() -> dict[str, str]:
    """This process's environment for a toolkit command that must end with it."""
    return {**os.environ, ENV: str(os.getpid())}


def end_with_runner_from_environment() -> None:
    """In a toolkit command: end gracefully with the run named by ``ACN_END_WITH``, if any (the
    variable is taken out, so the command's own children do not watch that run)."""
    pid = os.environ.pop(ENV, "")
    if pid.isdigit():
        end_with(int(pid), graceful=True)
