"""Local worker processes for pure functions of the simulators: ``pool_map(fn, tasks, workers)``.

A simulator that runs on one thread (PyBullet) uses more than one core only through processes.
The pool is started on first use and kept for the life of the process (its workers import the
simulators once); its workers end with the process that started them, however it ends
(``acn.lifetime``). Inside a daemonic process (a collection's worker), which may not start
children, the tasks run here, one after the other: the results are the same.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Callable, Sequence

from acn.lifetime import end_with

_CTX = mp.get_context("forkserver")
_pool: ProcessPoolExecutor | None = None
_pool_workers = 0
_pool_owner = 0


def pool_map(fn: Callable[..., Any], tasks: Sequence[tuple], workers: int) -> list:
    """``[fn(*task) for task in tasks]``, on up to ``workers`` worker processes."""
    global _pool, _pool_workers, _pool_owner
    workers = min(workers, len(tasks))
    if workers < 2 or mp.current_process().daemon:
        return [fn(*task) for task in tasks]
    if _pool is None or _pool_workers < workers or _pool_owner != os.getpid():
        if _pool is not None and _pool_owner == os.getpid():
            _pool.shutdown(wait=False, cancel_futures=True)
        _pool = ProcessPoolExecutor(workers, mp_context=_CTX, initializer=end_with, initargs=(os.getpid(),))
        _pool_workers, _pool_owner = workers, os.getpid()
    return list(_pool.map(fn, *zip(*tasks)))
