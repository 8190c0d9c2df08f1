"""Paired collection: the same A1 in a source and a target simulator, same start, same actions.

One episode, step by step (``PairedRollout.episode``):

1. draw the initial state from ``(seed, episode index)`` and set it in both simulators;
2. each control step: the policy acts on the SOURCE state (as in the paper); the source gets
   ``a``, the target gets ``a`` or, with a corrector, ``a + F(s_target, a)``;
3. record s_t, a_t, applied torque and s_{t+1} for each simulator;
4. stop at the time limit, when either robot falls (``fallen``), or when a simulator blows
   up (the step that diverged is dropped, the episode is kept and marked).

``collect_episodes(config, indices, load_corrector)`` is a pure function of its arguments (it
builds its own simulators, and its corrector with the loader it is given), so it can run in a
process pool here or on a distributed engine.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from acn.sim.backends import BACKENDS, SimConfig, SimulationDiverged, default_state, make_backend
from acn.sim.policies import POLICIES, Policy, make_policy, policy_action
from acn.sim.state import ACTION_DIM, SLICES, STATE_DIM

# Fall rule (the authors' thresholds, without their yaw term, which would end a walk that turns).
FALL_HEIGHT = 0.18      # m, trunk origin below this height
FALL_TILT_SQ = 0.73     # rad^2, roll^2 + pitch^2 at or above this
FALL_RULE = f"base_pos_z < {FALL_HEIGHT} m or base_roll^2 + base_pitch^2 >= {FALL_TILT_SQ} rad^2"

END_REASONS = ("time_limit", "source_fell", "target_fell", "source_diverged", "target_diverged")


def fallen(state: np.ndarray) -> bool:
    """True if ``state`` meets the fall rule (``FALL_RULE``)."""
    roll, pitch = state[SLICES["base_rpy"]][:2]
    return bool(state[SLICES["base_pos"]][2] < FALL_HEIGHT or roll * roll + pitch * pitch >= FALL_TILT_SQ)


@dataclass
class InitNoise:
    """Randomisation of the initial state around standing still (all uniform, +- value)."""

    joint_pos: float = 0.05    # rad
    joint_vel: float = 0.2     # rad/s
    roll_pitch: float = 0.03   # rad
    base_linvel: float = 0.05  # m/s
    base_angvel: float = 0.05  # rad/s
    yaw: float = float(np.pi)  # rad (full circle by default: headings are covered evenly)


@dataclass
class CollectConfig:
    """Everything that determines a collection; same config and seed -> identical data."""

    source: str = "pybullet"
    target: str | None = "mujoco"
    policy: str = "trot"
    episodes: int = 4
    seconds: float = 10.0
    seed: int = 0
    sim: SimConfig = field(default_factory=SimConfig)
    init_noise: InitNoise = field(default_factory=InitNoise)
    # The frozen corrector applied in the target, as a label (its directory, written into the
    # metadata); the object itself comes from the caller (``load_corrector`` below): the toolkit
    # applies a corrector, it does not load one.
    corrector: str | None = None
    # Physical effects applied to the SOURCE (the measured robot) and never written into the
    # dataset: measurements with a hidden effect, for testing a diagnosis (``acn.sim.hidden``).
    hidden_effects: list = field(default_factory=list)  # [AppliedEffect]
    # Physical effects written into the TARGET: a model under test (``acn-diagnose --closed-loop``:
    # the model with the effects a diagnosis added, run beside the measured robot).
    target_effects: list = field(default_factory=list)  # [AppliedEffect]

    @property
    def paired(self) -> bool:
        return self.target is not None

    @property
    def source_sim(self) -> SimConfig:
        """The source simulator's config: ``sim`` with the hidden effects written in."""
        return self._with_effects(self.source, self.hidden_effects)

    @property
    def target_sim(self) -> SimConfig:
        """The target simulator's config: ``sim`` with the target effects written in."""
        return self._with_effects(self.target, self.target_effects)

    def _with_effects(self, backend: str | None, effects: list) -> SimConfig:
        if not effects:
            return self.sim
        from acn.sim.effects import Model

        return Model(backend, list(effects)).sim_config(self.sim)

    @property
    def steps_per_episode(self) -> int:
        return int(round(self.seconds / self.sim.control_dt))

    def validate(self, builtin_policy: bool = True) -> None:
        """Check every field; ``builtin_policy=False``: ``policy`` is only a label (a policy object runs)."""
        if self.source not in BACKENDS:
            raise ValueError(f"unknown source simulator {self.source!r}; choose from {', '.join(BACKENDS)}")
        if self.target is not None and self.target not in BACKENDS:
            raise ValueError(f"unknown target simulator {self.target!r}; choose from {', '.join(BACKENDS)}")
        if builtin_policy and self.policy not in POLICIES:
            raise ValueError(f"unknown policy {self.policy!r}; choose from {', '.join(POLICIES)}")
        if self.episodes < 1:
            raise ValueError(f"--episodes must be >= 1, got {self.episodes}")
        if not (np.isfinite(self.seconds) and self.seconds > 0):
            raise ValueError(f"--seconds must be > 0, got {self.seconds}")
        if self.steps_per_episode < 1:
            raise ValueError(f"--seconds {self.seconds} is shorter than one control step ({self.sim.control_dt} s)")
        if self.seed < 0:
            raise ValueError(f"--seed must be >= 0, got {self.seed}")
        if self.corrector is not None and self.target is None:
            raise ValueError("--corrector needs a --target simulator to correct")
        self.sim.validate()


@dataclass
class Trace:
    """What one simulator did in one episode; T transitions."""

    state: np.ndarray       # (T, STATE_DIM) s_t
    action: np.ndarray      # (T, ACTION_DIM) a_t sent to this simulator
    effort: np.ndarray      # (T, ACTION_DIM) mean applied joint torque over the step, N m
    next_state: np.ndarray  # (T, STATE_DIM) s_{t+1}
    fallen: np.ndarray      # (T,) bool, s_{t+1} meets the fall rule


@dataclass
class Episode:
    index: int
    timestamp: np.ndarray   # (T,) s, time of s_t from the episode start
    source: Trace
    target: Trace | None
    end: str                # one of END_REASONS

    def __len__(self) -> int:
        return len(self.timestamp)


def initial_state(config: CollectConfig, episode_index: int) -> np.ndarray:
    """The initial state of an episode, a function of (seed, episode index) only."""
    rng = np.random.default_rng([config.seed, episode_index])
    n = config.init_noise
    s = default_state(yaw=float(rng.uniform(-n.yaw, n.yaw)))
    s[SLICES["joint_pos"]] += rng.uniform(-n.joint_pos, n.joint_pos, 12)
    s[SLICES["joint_vel"]] += rng.uniform(-n.joint_vel, n.joint_vel, 12)
    s[SLICES["base_rpy"]][:2] += rng.uniform(-n.roll_pitch, n.roll_pitch, 2)
    s[SLICES["base_linvel"]] += rng.uniform(-n.base_linvel, n.base_linvel, 3)
    s[SLICES["base_angvel"]] += rng.uniform(-n.base_angvel, n.base_angvel, 3)
    return s


class _TraceBuffer:
    def __init__(self, steps: int) -> None:
        self.state = np.empty((steps, STATE_DIM))
        self.action = np.empty((steps, ACTION_DIM))
        self.effort = np.empty((steps, ACTION_DIM))
        self.next_state = np.empty((steps, STATE_DIM))
        self.fallen = np.zeros(steps, dtype=bool)

    def trace(self, n: int) -> Trace:
        return Trace(self.state[:n], self.action[:n], self.effort[:n], self.next_state[:n], self.fallen[:n])


class PairedRollout:
    """Owns the simulators (and corrector) of one process and runs episodes with them."""

    def __init__(self, config: CollectConfig, corrector=None, policy: Policy | None = None) -> None:
        """``corrector``: an object with ``correct(state, action)`` (``config.corrector`` is its label).
        ``policy``: any object with ``reset(rng)`` and ``__call__(state, t)`` (e.g. a trained PPO
        policy) run instead of the built-in ``config.policy``, which then only labels the data."""
        config.validate(builtin_policy=policy is None)
        self.config = config
        self.source = make_backend(config.source, config.source_sim)
        self.target = make_backend(config.target, config.target_sim) if config.target else None
        self.policy = make_policy(config.policy) if policy is None else policy
        if corrector is None and config.corrector:
            raise ValueError(f"config.corrector names {config.corrector!r}: pass the loaded corrector object "
                             "(PairedRollout(config, corrector=...)) or load_corrector to the collection function")
        self.corrector = corrector

    def close(self) -> None:
        self.source.close()
        if self.target:
            self.target.close()

    def episode(self, index: int) -> Episode:
        cfg = self.config
        steps, dt = cfg.steps_per_episode, cfg.sim.control_dt
        s0 = initial_state(cfg, index)
        self.policy.reset(np.random.default_rng([cfg.seed, index, 1]))
        src, tgt = _TraceBuffer(steps), _TraceBuffer(steps) if self.target else None
        s_src = self.source.reset(s0)
        s_tgt = self.target.reset(s0) if self.target else None
        end, n = "time_limit", 0
        for k in range(steps):
            a = policy_action(self.policy, s_src, k * dt, cfg.sim)
            try:
                tau_src = self.source.step(a)
            except SimulationDiverged:
                end = "source_diverged"
                break
            next_src = self.source.get_state()
            if self.target:
                a_tgt = a if self.corrector is None else self.corrector.correct(s_tgt, a)
                try:
                    tau_tgt = self.target.step(a_tgt)
                except SimulationDiverged:
                    end = "target_diverged"
                    break
                next_tgt = self.target.get_state()
                tgt.state[k], tgt.action[k], tgt.effort[k], tgt.next_state[k] = s_tgt, a_tgt, tau_tgt, next_tgt
                tgt.fallen[k] = fallen(next_tgt)
                s_tgt = next_tgt
            src.state[k], src.action[k], src.effort[k], src.next_state[k] = s_src, a, tau_src, next_src
            src.fallen[k] = fallen(next_src)
            s_src = next_src
            n = k + 1
            if src.fallen[k] or (tgt is not None and tgt.fallen[k]):
                end = "source_fell" if src.fallen[k] else "target_fell"
                break
        return Episode(
            index=index,
            timestamp=np.arange(n) * dt,
            source=src.trace(n),
            target=tgt.trace(n) if tgt is not None else None,
            end=end,
        )


LoadCorrector = Callable[[str], Any]  # config.corrector -> an object with correct(state, action)


def rollout_for(config: CollectConfig, load_corrector: LoadCorrector | None = None) -> "PairedRollout":
    """A ``PairedRollout`` with ``config.corrector`` loaded by ``load_corrector`` (e.g.
    ``acn.corrector.Corrector.load``, passed down by the caller: worker processes and Ray tasks
    build their own rollout and load the corrector there; without a loader PairedRollout refuses
    a corrector label)."""
    loaded = load_corrector(config.corrector) if config.corrector and load_corrector else None
    return PairedRollout(config, corrector=loaded)


def collect_episodes(config: CollectConfig, indices: list[int], load_corrector: LoadCorrector | None = None
                     ) -> list[Episode]:
    """Run the given episodes with freshly built simulators (a pure, picklable unit of work)."""
    rollout = rollout_for(config, load_corrector)
    try:
        return [rollout.episode(i) for i in indices]
    finally:
        rollout.close()
