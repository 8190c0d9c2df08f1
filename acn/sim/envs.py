"""Gymnasium environments of the A1: ``acn/A1-PyBullet-v0`` and ``acn/A1-MuJoCo-v0``.

One class (``A1Env``) over the public ``Backend`` interface, so both simulators behave the
same way except for their physics. The robot is a model (``acn.sim.effects.Model``): a backend
with physical effects written in, given as a ``Model`` or as what ``acn.sim.hidden.load_model``
reads (``"pybullet"``, ``"mujoco"``, a model JSON file, a sealed robot with hidden effects):

- observation: the documented 43-channel state ``s_t`` (``acn.sim.state``), float32;
- action: ``u`` in [-1, 1]^12, a residual on a built-in gait (``EnvConfig.base_policy``, the
  open-loop trot by default): joint targets ``q* = gait(s, t) + residual_scale * u`` (rad);
  in ``position`` mode the simulator gets ``q*`` (PD at the physics rate), in ``torque`` mode
  the torques of the PD law evaluated once per control step (``policies.policy_action``);
  ``base_policy="stand"`` makes ``u`` an absolute target around the stance;
- optional corrector: an object with ``correct(state, action)``; the simulator then gets
  ``a~ = a + F(s, a)``. It belongs in the TARGET simulator (the paper's pi_corr); the
  environment does not check which simulator it corrects;
- reward: the paper's ``w1 v_x - w2 |tau|^2 - w3 |(roll, pitch)| - w4 |qdot|^2`` from s_{t+1}
  and the mean applied torque (``acn.sim.reward``), weights ``EnvConfig.reward_weights``
  (default the paper's), plus ``alive_bonus`` per step that does not end in a fall;
  ``info["reward_terms"]`` (v_x, |tau|^2, |(roll, pitch)|, |qdot|^2) and
  ``info["paper_reward"]`` (paper weights, no bonus) allow any other weighting afterwards;
- termination: the documented fall rule (``collector.fallen``) or a simulator blow-up
  (reward 0, ``info["diverged"]``); truncation: the time limit ``EnvConfig.seconds``;
- reset: a random initial state as in the collector (``collector.initial_state``, drawn
  from the environment's seeded generator), or ``options={"state": s0}``.

``import acn.sim.envs`` registers both ids: ``gymnasium.make("acn/A1-MuJoCo-v0", seconds=5)``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace
from typing import Any, Callable

import gymnasium as gym
import numpy as np

from acn.sim.backends import SimConfig, SimulationDiverged, make_backend
from acn.sim.collector import CollectConfig, InitNoise, fallen, initial_state
from acn.sim.effects import Model
from acn.sim.hidden import load_model
from acn.sim.policies import POLICIES, Policy, make_policy, policy_action
from acn.sim.reward import REWARD_WEIGHTS, reward_terms, weighted
from acn.sim.state import ACTION_DIM, STATE_DIM

ENV_IDS: dict[str, str] = {"pybullet": "acn/A1-PyBullet-v0", "mujoco": "acn/A1-MuJoCo-v0"}


@dataclass
class EnvConfig:
    """Everything that defines the task (both simulators read the same config)."""

    sim: SimConfig = field(default_factory=SimConfig)
    seconds: float = 10.0                 # s, time limit (truncation)
    reward_weights: tuple[float, float, float, float] = REWARD_WEIGHTS  # w1..w4
    alive_bonus: float = 0.0              # per step not ending in a fall (0: the paper's reward)
    base_policy: str = "trot"             # built-in gait the action is a residual on
    residual_scale: float = 0.3           # rad of joint target per unit of action
    init_noise: InitNoise = field(default_factory=InitNoise)

    @property
    def max_steps(self) -> int:
        return int(round(self.seconds / self.sim.control_dt))

    def validate(self) -> None:
        self.sim.validate()
        if not (np.isfinite(self.seconds) and self.seconds > 0) or self.max_steps < 1:
            raise ValueError(f"seconds must be at least one control step, got {self.seconds}")
        if len(self.reward_weights) != 4 or not np.all(np.isfinite(self.reward_weights)):
            raise ValueError(f"reward_weights must be 4 finite numbers, got {self.reward_weights}")
        if self.base_policy not in POLICIES:
            raise ValueError(f"unknown base policy {self.base_policy!r}; choose from {', '.join(POLICIES)}")
        if not self.residual_scale >= 0:
            raise ValueError(f"residual_scale must be >= 0, got {self.residual_scale}")


@dataclass
class Residual:
    """A policy (``acn.sim.policies.Policy``): joint targets ``gait(s, t) + scale * clip(u(s), -1, 1)``.

    The one place where the residual is composed with the gait: the environment (``u`` = the
    agent's action) and a trained policy (``u`` = its network) both use it.
    """

    base: Policy
    scale: float                                  # rad per unit of u
    residual: Callable[[np.ndarray], np.ndarray]  # state (43,) -> u (12,)
    name: str = "residual"

    def reset(self, rng: np.random.Generator) -> None:
        self.base.reset(rng)

    def __call__(self, state: np.ndarray, t: float) -> np.ndarray:
        u = np.clip(np.asarray(self.residual(state), dtype=np.float64), -1.0, 1.0)
        return self.base(state, t) + self.scale * u


class A1Env(gym.Env):
    """The A1 in one simulator as a Gymnasium environment; see the module docstring."""

    metadata = {"render_modes": []}

    def __init__(self, model: Model | str = "pybullet", config: EnvConfig | None = None, corrector: Any = None,
                 **overrides: Any) -> None:
        """``model``: the robot (module docstring); ``config.sim`` holds the control settings and
        the model's effects are written into its physical parameters. ``overrides``: ``EnvConfig``
        fields by name (e.g. ``seconds=5``) for ``gymnasium.make``."""
        self.model = model if isinstance(model, Model) else load_model(model)
        if self.model.corrector:
            raise ValueError(f"the model carries a corrector ({self.model.corrector}); pass the loaded corrector "
                             "as A1Env(..., corrector=...)")
        names = {f.name for f in fields(EnvConfig)}
        unknown = set(overrides) - names
        if unknown:
            raise TypeError(f"unknown EnvConfig field(s): {', '.join(sorted(unknown))}")
        self.config = replace(config or EnvConfig(), **overrides)
        self.config.validate()
        self.corrector = corrector
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (STATE_DIM,), np.float32)
        self.action_space = gym.spaces.Box(-1.0, 1.0, (ACTION_DIM,), np.float32)
        self._sim = make_backend(self.model.backend, self.model.sim_config(self.config.sim))
        self._init = CollectConfig(source=self.model.backend, target=None, seed=0, sim=self.config.sim,
                                   init_noise=self.config.init_noise)
        self._u = np.zeros(ACTION_DIM)
        self._gait = Residual(make_policy(self.config.base_policy), self.config.residual_scale, lambda s: self._u)
        self._state: np.ndarray | None = None
        self._step = 0

    # ----- Gymnasium API --------------------------------------------------------------------
    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        if options and options.get("state") is not None:
            s0 = np.asarray(options["state"], dtype=np.float64)
        else:
            s0 = initial_state(self._init, int(self.np_random.integers(2**62)))
        self._gait.reset(self.np_random)
        self._state = self._sim.reset(s0)
        self._step = 0
        return self._state.astype(np.float32), {"time": 0.0}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        if self._state is None:
            raise RuntimeError("call reset() before step()")
        cfg = self.config
        t = self._step * cfg.sim.control_dt
        self._u = np.asarray(action, dtype=np.float64)
        a = policy_action(self._gait, self._state, t, cfg.sim)
        if self.corrector is not None:  # a~ = a + F(s, a): the corrector acts in THIS simulator
            a = self.corrector.correct(self._state, a)
        self._step += 1
        truncated = self._step >= cfg.max_steps
        try:
            tau = self._sim.step(a)
        except SimulationDiverged as e:
            info = {"time": t + cfg.sim.control_dt, "diverged": True, "fallen": False, "error": str(e),
                    "reward_terms": np.zeros(4), "paper_reward": 0.0, "action": a}
            return self._state.astype(np.float32), 0.0, True, False, info
        s = self._sim.get_state()
        terms = reward_terms(s, tau)
        fell = fallen(s)
        r = float(weighted(terms, cfg.reward_weights)) + (0.0 if fell else cfg.alive_bonus)
        self._state = s
        info = {"time": self._step * cfg.sim.control_dt, "diverged": False, "fallen": fell,
                "reward_terms": terms, "paper_reward": float(weighted(terms, REWARD_WEIGHTS)), "action": a}
        return s.astype(np.float32), r, fell, truncated and not fell, info

    def close(self) -> None:
        if getattr(self, "_sim", None) is not None:
            self._sim.close()
            self._sim = None

    @property
    def state(self) -> np.ndarray | None:
        """The current state, float64 (the observation is its float32 copy)."""
        return None if self._state is None else self._state.copy()


def register_envs() -> None:
    """Register ``ENV_IDS`` with Gymnasium (idempotent)."""
    for backend, env_id in ENV_IDS.items():  # the nominal simulators; any other model: A1Env(model)
        if env_id not in gym.registry:
            gym.register(id=env_id, entry_point="acn.sim.envs:A1Env", kwargs={"model": backend})


register_envs()
