"""Past one machine: collection episodes and batch re-simulation on Ray (an optional extra).

Two pieces of work leave the process, both through this module and both pure functions of
what is sent (so results equal the local run bit for bit):

- episodes: ``episodes_on_ray(config, indices)`` runs ``collect_episodes``' work as Ray tasks
  (one episode each) and yields the episodes in index order with at most ``in_flight`` tasks
  submitted ahead of the next one written, so the driver never holds the dataset;
- re-simulation rows: inside ``with ray_executor(...)``, ``Resimulator.run`` hands batches of
  at least ``RAY_MIN_CHUNK_STEPS`` control steps per chunk to ``RayResimExecutor`` (MuJoCo
  models; PyBullet batches stay local, see ``RayResimExecutor.takes``): the rows
  are cut into one contiguous chunk per Ray CPU, each chunk runs on a long-lived actor through
  the ordinary local ``Resimulator`` (one thread), and the predictions come back in row order.

Simulators and compiled models are built once per Ray worker process and kept, keyed by the
SHA-256 of their config's JSON (``config_key``): a worker that runs many episodes or chunks of
the same model builds it once. Nothing here holds state in the driver: the executor
``ray_executor`` opens is the one ``acn.sim.resim.executing_on`` hands the batches to.

``ray_session`` starts a local Ray instance (``address=None``: ``cpus`` CPUs, a small object
store, logs and sockets in a temporary directory that is removed afterwards) or joins a running
cluster (``address``: ``"auto"`` or ``"HOST:PORT"`` from ``ray start --head``), and shuts down
only what it started. Without Ray installed, every entry point raises a one-line ``UserError``.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import os
import shutil
import tempfile
from collections import OrderedDict, deque
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Iterable, Iterator

import numpy as np

from acn.errors import UserError
from acn.sim.cpus import usable_cpus
from acn.sim.resim import Prediction, Resimulator, executing_on

if TYPE_CHECKING:  # pragma: no cover
    from acn.sim.backends import SimConfig
    from acn.sim.collector import CollectConfig, Episode

INSTALL_HINT = "pip install -e '.[ray]'"
OBJECT_STORE_MB = 200        # local instance: shared-memory object store, MB
IN_FLIGHT_PER_CPU = 2        # episode tasks submitted ahead per Ray CPU
# A re-simulation chunk smaller than this many (row x control step) predictions stays local:
# below it a Ray round trip (a few ms, measured by benchmarks/scale.py) costs more than it saves.
RAY_MIN_CHUNK_STEPS = 2000
WORKER_CACHE_SIZE = 8        # built simulators / Resimulators kept per Ray worker process


def import_ray():
    """The ``ray`` module, or a one-line ``UserError`` saying how to install it."""
    try:
        import ray
    except ImportError:
        raise UserError(f"--ray needs Ray, which is not installed: {INSTALL_HINT}") from None
    return ray


@dataclass
class RayConfig:
    """Where Ray work runs."""

    address: str | None = None      # None: start a local instance; "auto" or "HOST:PORT": join a cluster
    cpus: int | None = None         # local instance only: CPUs it offers (default: those this process may use)
    object_store_mb: int = OBJECT_STORE_MB  # local instance only

    def validate(self) -> None:
        if self.cpus is not None and self.cpus < 1:
            raise ValueError(f"--ray-cpus must be >= 1, got {self.cpus}")
        if self.cpus is not None and self.address:
            raise UserError("--ray-cpus sets up a local Ray instance; a cluster (--ray ADDRESS) has its own CPUs")


@contextmanager
def ray_session(config: RayConfig | None = None) -> Iterator[Any]:
    """Yield the ``ray`` module connected to a cluster or a local instance (module docstring).
    A session opened inside a Ray worker, or while one is open, reuses the connection."""
    config = config or RayConfig()
    config.validate()
    ray = import_ray()
    if ray.is_initialized():
        yield ray
        return
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    temp = None
    kw: dict[str, Any] = dict(log_to_driver=False, logging_level=logging.WARNING, include_dashboard=False)
    if config.address:
        kw["address"] = config.address
    else:
        temp = tempfile.mkdtemp(prefix="acn-ray-")  # short: Ray's socket paths must fit in 107 bytes
        kw.update(num_cpus=config.cpus or usable_cpus(), object_store_memory=config.object_store_mb * 2**20,
                  _temp_dir=temp)
    try:
        ray.init(**kw)
    except ConnectionError as e:
        _remove(temp)
        hint = ("" if os.environ.get("RAY_AUTH_MODE") else "; a cluster started by `ray start --head` checks a token: "
                "set RAY_AUTH_MODE=token and RAY_AUTH_TOKEN to the output of `ray get-auth-token` on its head node")
        raise UserError(f"cannot reach the Ray cluster at {config.address!r}: {str(e).splitlines()[0]}{hint}") from None
    try:
        yield ray
    finally:
        ray.shutdown()
        _remove(temp)


def _remove(path: str | None) -> None:
    if path:
        shutil.rmtree(path, ignore_errors=True)


def cluster_cpus(ray) -> int:
    """CPUs the connected Ray cluster offers (at least 1)."""
    return max(1, int(ray.cluster_resources().get("CPU", 1)))


def task_error(ray, error: BaseException) -> BaseException:
    """A remote task's own exception (a ValueError stays a one-line ValueError), not Ray's wrapper."""
    if isinstance(error, ray.exceptions.RayTaskError) and isinstance(error.cause, Exception):
        return error.cause
    return error


# ----- per-worker caches -----------------------------------------------------------------------
def _plain(x: Any) -> Any:
    """JSON-able view of a config (dataclasses, arrays, tuples) for ``config_key``."""
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        return {"__type__": type(x).__name__, **{f.name: _plain(getattr(x, f.name)) for f in dataclasses.fields(x)}}
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, np.generic):
        return x.item()
    return x


def config_key(*parts: Any) -> str:
    """SHA-256 of the JSON of ``parts`` (configs): equal configs, equal keys."""
    return hashlib.sha256(json.dumps(_plain(list(parts)), sort_keys=True).encode()).hexdigest()


_CACHE: OrderedDict[str, Any] = OrderedDict()  # lives in a Ray worker process only


def _cached(key: str, build: Callable[[], Any], close: Callable[[Any], None], size: int = WORKER_CACHE_SIZE) -> Any:
    """The object built for ``key`` in this worker process (least recently used ones closed)."""
    if key in _CACHE:
        _CACHE.move_to_end(key)
        return _CACHE[key]
    obj = _CACHE[key] = build()
    while len(_CACHE) > size:
        close(_CACHE.popitem(last=False)[1])
    return obj


# ----- collection episodes ---------------------------------------------------------------------
def _collect(key: str, config: "CollectConfig", indices: list[int], load_corrector=None) -> list["Episode"]:
    """Ray task: ``collect_episodes(config, indices)`` with the simulators kept in the worker."""
    from acn.sim.collector import rollout_for

    rollout = _cached("rollout:" + key, lambda: rollout_for(config, load_corrector), lambda r: r.close(), size=1)
    return [rollout.episode(i) for i in indices]


_REMOTE: dict[str, Any] = {}


def remote(ray, name: str, fn: Any, **options) -> Any:
    """``ray.remote(**options)(fn)``, made once per process and kept under ``name``: each one
    ``ray.remote`` makes is exported to the cluster again on its first call."""
    if name not in _REMOTE:
        _REMOTE[name] = ray.remote(**options)(fn)
    return _REMOTE[name]


def episodes_on_ray(config: "CollectConfig", indices: Iterable[int], in_flight: int | None = None,
                    load_corrector=None) -> Iterator["Episode"]:
    """Yield the episodes ``indices`` in that order, simulated as Ray tasks (one episode each).

    At most ``in_flight`` tasks (default ``IN_FLIGHT_PER_CPU`` x the cluster's CPUs) are
    submitted beyond the last episode yielded; finished ones wait in Ray's object store. Closing
    the generator early (an interrupt, an error) drops the tasks still running without
    ``ray.cancel``: their results are freed when they end, and Ray kills a driver's tasks when the
    driver exits, as an interrupted command does. ``ray.cancel`` races the reply of a task that
    is just finishing, and Ray's driver then aborts ("Tried to complete task that was not
    pending", exit 1 instead of the interrupt's 130; seen with ``force=True`` and with
    ``force=False``; ray-project/ray#54798 mends the same race on retries only).
    """
    ray = import_ray()
    if not ray.is_initialized():
        raise RuntimeError("episodes_on_ray needs an open ray_session")
    task = remote(ray, "collect", _collect, num_cpus=1, max_retries=1)
    in_flight = max(1, in_flight or IN_FLIGHT_PER_CPU * cluster_cpus(ray))
    key, config_ref = config_key(config), ray.put(config)
    todo, running = iter(list(indices)), deque()

    def submit() -> None:
        for i in todo:
            running.append(task.remote(key, config_ref, [i], load_corrector))
            return

    for _ in range(in_flight):
        submit()
    while running:
        try:
            (episode,) = ray.get(running[0])
        except ray.exceptions.RayTaskError as e:
            raise task_error(ray, e) from None
        running.popleft()
        submit()
        yield episode


# ----- batch re-simulation ---------------------------------------------------------------------
class _ResimWorker:
    """Ray actor (one CPU): runs chunks of rows through the local Resimulator, models cached."""

    def run(self, key: str, backend: str, configs: list, states, actions, previous, model):
        sim = _cached("resim:" + key, lambda: Resimulator(backend, configs, threads=1), lambda r: r.close())
        p = sim.run(states, actions, previous, model=model)
        return p.state, p.effort, p.diverged

    def cached(self) -> int:
        return len(_CACHE)


class RayResimExecutor:
    """Sends large ``Resimulator.run`` batches to a pool of Ray actors (module docstring)."""

    def __init__(self, ray, workers: int | None = None, min_chunk_steps: int = RAY_MIN_CHUNK_STEPS) -> None:
        self.ray = ray
        self.workers = workers or cluster_cpus(ray)
        self.min_chunk_steps = min_chunk_steps
        self._actors: list = []
        self.batches = 0   # batches sent to Ray (the others ran locally)

    def takes(self, backend: str, rows: int, steps: int) -> bool:
        """True if a batch of ``rows`` x ``steps`` control steps fills two chunks or more.

        MuJoCo only: a PyBullet re-simulation depends (by ~1e-6) on the rows run before it in
        the same simulator (``set_state`` leaves the contact solver's warm start in place), so
        chunks would not reproduce the local result bit for bit; PyBullet batches stay local.
        """
        return backend == "mujoco" and rows * steps >= 2 * self.min_chunk_steps

    def _pool(self) -> list:
        if not self._actors:
            actor = remote(self.ray, "resim", _ResimWorker, num_cpus=1)
            self._actors = [actor.remote() for _ in range(self.workers)]
        return self._actors

    def resimulate(self, backend: str, configs: list["SimConfig"], states: np.ndarray, actions: np.ndarray,
                   previous: np.ndarray | None, model: np.ndarray) -> "Prediction":
        """``Resimulator(backend, configs).run(states, actions, previous, model)``, rows chunked on Ray."""
        ray = self.ray
        n, k = actions.shape[:2]
        chunks = max(1, min(self.workers, n * k // self.min_chunk_steps, n))
        bounds = np.linspace(0, n, chunks + 1).round().astype(int)
        key = config_key(backend, configs)
        configs_ref = ray.put(list(configs))
        prev = None if previous is None else np.asarray(previous)
        actors = self._pool()
        refs = [actors[c % len(actors)].run.remote(key, backend, configs_ref, states[lo:hi], actions[lo:hi],
                                                   None if prev is None else prev[lo:hi], model[lo:hi])
                for c, (lo, hi) in enumerate(zip(bounds[:-1], bounds[1:]))]
        try:
            parts = ray.get(refs)
        except ray.exceptions.RayTaskError as e:
            raise task_error(ray, e) from None
        except BaseException:
            for ref in refs:
                ray.cancel(ref)
            raise
        self.batches += 1
        return Prediction(np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]),
                          np.concatenate([p[2] for p in parts]))

    def close(self) -> None:
        for actor in self._actors:
            self.ray.kill(actor)
        self._actors = []


@contextmanager
def ray_executor(address: str | None = None, cpus: int | None = None,
                 min_chunk_steps: int = RAY_MIN_CHUNK_STEPS) -> Iterator[RayResimExecutor]:
    """Within this block every ``Resimulator.run`` batch of at least two chunks runs on Ray
    (``address``/``cpus``: as ``RayConfig``); results equal the local run bit for bit."""
    with ray_session(RayConfig(address=address or None, cpus=cpus)) as ray:
        executor = RayResimExecutor(ray, min_chunk_steps=min_chunk_steps)
        try:
            with executing_on(executor):
                yield executor
        finally:
            executor.close()
