"""Batch re-simulation from recorded states: the engine behind diagnosis, labels and oracles.

Given models (``SimConfig`` each: control settings + physical parameters), recorded states
s_t, the actions a_t .. a_{t+K-1} and the actions before t (a model with latency still applies
them early in the step), ``Resimulator.run`` returns the predicted s_{t+1} .. s_{t+K} and the
mean applied torque of every control step, row by row. Each row may use another model, so a
batch can hold many parameter values (finite differences, fits) at once.

- MuJoCo: ``mujoco.rollout`` on a thread pool, each model compiled once. The physics state
  comes from the state vector without MjData (``PhysicsLayout``); the control sequence per
  physics step carries the latency (``Actuation.commands``). A law MuJoCo cannot express
  (a dead band) is evaluated in numpy between single-step rollouts.
- PyBullet: ``set_state`` / ``step`` row by row, in chunks of about ``PYBULLET_CHUNK_STEPS``
  control steps, each chunk in a simulator of its own (PyBullet's contact solver starts each
  step from the last one's impulses, so a row's prediction would depend, by about 1e-6, on the
  rows run before it; with a fresh simulator per chunk it depends on its chunk only). The chunks
  run on up to ``threads`` worker processes (``acn.sim.workers``), the same result bit for bit
  as one after the other here.

Predicted contacts are not simulated state: they come back NaN.

Inside ``with executing_on(executor)``, ``Resimulator.run`` hands the batches the executor
``takes`` to it instead (``acn.sim.parallel.ray_executor``: chunks on Ray actors, the same
result bit for bit); everywhere else every batch runs here.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator, Protocol, Sequence

import numpy as np

from acn.sim.actuation import Actuation, history_window
from acn.sim.backends import SimConfig, SimulationDiverged, make_backend
from acn.sim.cpus import usable_cpus
from acn.sim.state import ACTION_DIM, SLICES, STATE_DIM
from acn.sim.workers import pool_map

MAX_BATCH_FLOATS = 4_000_000  # rollout output held at once (~32 MB)
# PyBullet control steps per chunk: a few seconds of work, beside which building its simulator
# (10-30 ms) and sending its rows to a worker cost under 1 %.
PYBULLET_CHUNK_STEPS = 2000


@dataclass
class Prediction:
    """What a re-simulation predicts for N rows and K control steps."""

    state: np.ndarray     # (N, K, 43) s_{t+1} .. s_{t+K}; contacts NaN; NaN rows where diverged
    effort: np.ndarray    # (N, K, 12) mean applied joint torque over each control step, N m
    diverged: np.ndarray  # (N,) bool: the simulation blew up (non-finite or absurd state)


class BatchExecutor(Protocol):
    """Runs some ``Resimulator.run`` batches elsewhere (``acn.sim.parallel.RayResimExecutor``)."""

    def takes(self, backend: str, rows: int, steps: int) -> bool:
        """True if a batch of ``rows`` x ``steps`` control steps of ``backend`` should run here."""
        ...

    def resimulate(self, backend: str, configs: list[SimConfig], states: np.ndarray, actions: np.ndarray,
                   previous: np.ndarray | None, model: np.ndarray) -> Prediction:
        """``Resimulator(backend, configs).run(states, actions, previous, model)``, the same result."""
        ...


_EXECUTOR: BatchExecutor | None = None


def active_executor() -> BatchExecutor | None:
    """The executor ``Resimulator.run`` sends the batches it takes to (None: everything runs locally)."""
    return _EXECUTOR


@contextmanager
def executing_on(executor: BatchExecutor) -> Iterator[BatchExecutor]:
    """Within this block ``Resimulator.run`` hands ``executor`` the batches it ``takes``."""
    global _EXECUTOR
    previous, _EXECUTOR = _EXECUTOR, executor
    try:
        yield executor
    finally:
        _EXECUTOR = previous


class Resimulator:
    """Re-simulates recorded states under one or several models of one backend."""

    def __init__(self, backend: str, configs: SimConfig | Sequence[SimConfig], threads: int | None = None) -> None:
        self.backend = backend
        self.configs = [configs] if isinstance(configs, SimConfig) else list(configs)
        if not self.configs:
            raise ValueError("a Resimulator needs at least one model")
        base = self.configs[0]
        for c in self.configs:
            if (c.physics_dt, c.substeps, c.action_mode, c.hybrid, c.imu_acc) != \
                    (base.physics_dt, base.substeps, base.action_mode, base.hybrid, base.imu_acc):
                raise ValueError("all models of one Resimulator share physics_dt, substeps, action mode, "
                                 "whether the actions are hybrid commands and what the accelerometer reads")
        self.actuation = [Actuation.from_config(c) for c in self.configs]
        self.threads = threads or max(1, min(usable_cpus(), 8))
        self._models: list | None = None   # MuJoCo models, compiled on first use

    @property
    def control_dt(self) -> float:
        return self.configs[0].control_dt

    def run(self, states: np.ndarray, actions: np.ndarray, previous: np.ndarray | None = None,
            model: np.ndarray | int | None = None) -> Prediction:
        """Predict K control steps from each of N states.

        ``states`` (N, 43) recorded s_t; ``actions`` (N, K, A) or (N, A) the actions from t on
        (A = ``SimConfig.action_dim``: 12, or 60 with the gains); ``previous`` (N, P, A) the actions
        before t, oldest first (optional); ``model`` (N,) index into the models per row (default:
        model 0 for every row).
        """
        states = np.asarray(states, dtype=np.float64)
        actions = np.asarray(actions, dtype=np.float64)
        if actions.ndim == 2:
            actions = actions[:, None, :]
        n, width = len(states), self.configs[0].action_dim
        if states.shape != (n, STATE_DIM) or actions.shape[0] != n or actions.shape[2] != width:
            raise ValueError(f"states (N, {STATE_DIM}) and actions (N, K, {width}) must match; "
                             f"got {states.shape} and {actions.shape}")
        index = np.zeros(n, dtype=int) if model is None else np.broadcast_to(np.asarray(model, dtype=int), (n,))
        out = Prediction(np.full((n, actions.shape[1], STATE_DIM), np.nan),
                         np.full((n, actions.shape[1], ACTION_DIM), np.nan), np.zeros(n, dtype=bool))
        if n == 0:
            return out
        executor = active_executor()  # Ray (acn.sim.parallel): large batches in chunks, same result
        if executor is not None and executor.takes(self.backend, n, actions.shape[1]):
            return executor.resimulate(self.backend, self.configs, states, actions, previous, index)
        if self.backend == "mujoco":
            self._run_mujoco(index, states, actions, previous, out)
            return out
        per = max(1, PYBULLET_CHUNK_STEPS // actions.shape[1])
        chunks, tasks = [], []
        for m in np.unique(index):
            rows = np.flatnonzero(index == m)
            window = history_window(actions[rows], None if previous is None else np.asarray(previous)[rows],
                                    self.actuation[m].history)
            for lo in range(0, len(rows), per):
                chunks.append(rows[lo:lo + per])
                tasks.append((self.backend, self.configs[m], self.actuation[m].history, states[rows[lo:lo + per]],
                              window[lo:lo + per]))
        for rows, (state, effort, diverged) in zip(chunks, pool_map(resimulate_rows, tasks, self.threads)):
            out.state[rows], out.effort[rows], out.diverged[rows] = state, effort, diverged
        return out

    # ----- MuJoCo: mujoco.rollout ------------------------------------------------------------
    def _compile(self) -> None:
        import mujoco

        from acn.sim.backends.mujoco_backend import PhysicsLayout, build_spec

        self._models = [build_spec(c).compile() for c in self.configs]
        self._layout = PhysicsLayout(self._models[0])
        self._datas = [mujoco.MjData(self._models[0]) for _ in range(self.threads)]

    def _run_mujoco(self, index: np.ndarray, states: np.ndarray, actions: np.ndarray, previous, out: Prediction) -> None:
        """All rows in as few rollout calls as memory allows, each row with its own model."""
        import mujoco.rollout

        if self._models is None:
            self._compile()
        layout, sub, k = self._layout, self.configs[0].substeps, actions.shape[1]
        offset = np.stack([a.offset for a in self.actuation])[index]
        frame = np.stack([c.params.base_frame_offset for c in self.configs])[index]
        width = self.actuation[0].command_width
        commands = np.empty((len(states), k * sub, width))
        for m in np.unique(index):  # per-physics-step commands carry each model's latency
            rows = np.flatnonzero(index == m)
            act = self.actuation[m]
            window = history_window(actions[rows], None if previous is None else np.asarray(previous)[rows],
                                    act.history)
            commands[rows] = act.commands(window)
        native = np.array([a.native for a in self.actuation])[index]
        chunk = max(1, MAX_BATCH_FLOATS // (k * sub * (layout.size + width)))
        with mujoco.rollout.Rollout(nthread=self.threads) as pool:
            for lo in range(0, len(states), chunk):
                sel = slice(lo, min(lo + chunk, len(states)))
                phys0 = layout.to_physics(states[sel], offset[sel], frame[sel])
                models = [self._models[i] for i in index[sel]]
                if native[sel].all():
                    phys, torque = pool.rollout(models, self._datas, phys0, commands[sel])
                else:
                    phys, torque = self._step_by_step(pool, models, index[sel], phys0, commands[sel])
                self._store(np.arange(len(states))[sel], phys0, phys, torque, offset[sel], frame[sel], k, out)

    def _step_by_step(self, pool, models: list, index: np.ndarray, phys0: np.ndarray, commands: np.ndarray):
        """One physics step per rollout call; rows whose law MuJoCo cannot express get their
        torque from ``Actuation.torque`` in numpy in between (the others their command)."""
        n, steps = commands.shape[:2]
        layout = self._layout
        phys = np.empty((n, steps, layout.size))
        torque = np.empty((n, steps, ACTION_DIM))
        x = phys0
        python_law = [np.flatnonzero(index == m) for m in np.unique(index) if not self.actuation[m].native]
        for j in range(steps):
            ctrl = commands[:, j].copy()
            for rows in python_law:
                act = self.actuation[index[rows[0]]]
                ctrl[rows, :ACTION_DIM] = act.torque(commands[rows, j], x[rows][:, 1 + layout.qadr],
                                                     x[rows][:, 1 + layout.nq + layout.dadr])
            st, sens = pool.rollout(models, self._datas, x, ctrl[:, None, :])
            phys[:, j], torque[:, j] = st[:, -1], sens[:, -1]
            x = st[:, -1]
        return phys, torque

    def _store(self, rows, phys0, phys, torque, offset: np.ndarray, frame: np.ndarray, k: int, out: Prediction) -> None:
        config = self.configs[0]
        sub = config.substeps
        ends = phys[:, sub - 1::sub]                               # (n, K, size)
        starts = np.concatenate([phys0[:, None], ends[:, :-1]], axis=1)
        dt = self.control_dt
        if config.imu_acc == "instant" and sub > 1:  # the accelerometer reads each control step's last physics step
            starts, dt = phys[:, sub - 2::sub], config.physics_dt
        n = len(rows)
        pred = self._layout.to_states(ends.reshape(n * k, -1), starts.reshape(n * k, -1), np.repeat(offset, k, axis=0),
                                      dt, np.repeat(frame, k, axis=0)).reshape(n, k, STATE_DIM)
        eff = torque.reshape(n, k, sub, ACTION_DIM).mean(axis=2)
        bad = ~np.isfinite(pred[..., : SLICES["contact"].start]).all(axis=(1, 2))
        bad |= np.abs(pred[:, :, SLICES["joint_vel"]]).max(axis=(1, 2), initial=0.0) > 500.0
        pred[bad], eff[bad] = np.nan, np.nan
        out.state[rows], out.effort[rows], out.diverged[rows] = pred, eff, bad

    def close(self) -> None:
        """Nothing to release: MuJoCo's models are freed with the object, PyBullet's simulators
        with their chunk (kept so that callers may use ``with Resimulator(...)``)."""

    def __enter__(self) -> "Resimulator":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def resimulate_rows(backend: str, config: SimConfig, history: int, states: np.ndarray,
                    window: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Any backend, ``set_state`` / ``step``: the rows of one chunk in a simulator of their own;
    ``window`` (n, history + K, A) the actions before and from each row's step. Returns the
    predicted states (contacts NaN), the efforts and which rows diverged (their values NaN)."""
    n, k = len(states), window.shape[1] - history
    state, effort = np.full((n, k, STATE_DIM), np.nan), np.full((n, k, ACTION_DIM), np.nan)
    diverged = np.zeros(n, dtype=bool)
    sim = make_backend(backend, config)
    try:
        for i in range(n):
            sim.set_state(states[i], previous_actions=window[i, :history])
            try:
                for j, a in enumerate(window[i, history:]):
                    effort[i, j] = sim.step(a)
                    state[i, j] = sim.get_state()
            except SimulationDiverged:
                state[i], effort[i], diverged[i] = np.nan, np.nan, True
                continue
            state[i, :, SLICES["contact"]] = np.nan
    finally:
        sim.close()
    return state, effort, diverged
