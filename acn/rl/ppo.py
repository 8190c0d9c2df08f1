"""PPO for the A1 with the frozen corrector in the loop: the paper's Algorithm 2 (``acn-ppo``).

Two models (``acn.sim.hidden.load_model``: pybullet, mujoco, a model JSON file, a sealed robot):
``PPOConfig.train``, where the policy is trained (PyBullet in the paper), and ``PPOConfig.robot``,
where it is deployed and corrected (MuJoCo in the paper).

Top to bottom (one file, every hyper-parameter in ``PPOConfig``; stable-baselines3 PPO):

1. environments: ``n_envs`` ``A1Env`` of the training model (``acn.sim.envs``), one subprocess
   each (``SubprocVecEnv``), ``VecMonitor`` (raw episode returns), ``VecNormalize`` (observation
   statistics and reward scale for PPO);
2. policy: SB3's actor-critic MLP on the state channels the corrector reads (absolute x, y and
   yaw dropped, ``StateChannels``); its action is a residual on the open-loop trot, so the
   untrained policy already walks and PPO refines it;
3. Algorithm 2 (``Algorithm2`` callback, at rollout boundaries, when the policy is fixed):
   - every ``refit_every`` episodes: run the current policy in the training model with the
     same actions replayed on the robot from the same initial state (``PairedRollout``), write
     the pairs as a LeRobot dataset and refit the corrector F with acn-fit's code
     (``acn.corrector.fit.fit``, variant ``corrector_variant``, the robot re-simulated with its
     effects) on the latest ``refit_window`` datasets;
   - every ``eval_every`` episodes: ``evaluate_transfer``: the deterministic policy, closed
     loop, from the same held-out initial states, in the training model, on the robot, and on
     the robot with ``pi_corr(s) = pi(s) + F(s, pi(s))``;
   with ``refit_every`` 0 and no corrector given, plain PPO: no F, the evaluations without it;
4. at the end: a final evaluation over ``final_eval_episodes`` (>= 20), the paper's Table 1
   statistics, ``metrics.json``, ``curves.png``, the shareable policy (``policy_io``).

WHERE THE CORRECTION IS APPLIED. On the robot (the TARGET) only, at evaluation, as the paper's
formula says: F maps the target's state and the policy's action to the action that makes the
target behave like the source. PPO trains the plain policy in the training model (the source)
with no correction; the paper's Algorithm 2 listing applies F in PyBullet during training,
which would correct the simulator that needs no correction. F is never trained by PPO: it is a
frozen ``Corrector`` (no gradients, not in PPO's optimiser) replaced only by refits, and the
sha256 of its tensors is recorded when it is loaded and checked when it is retired.

Rewards. The paper's reward ``w = (1.0, 0.01, 0.5, 0.1)`` is what the paper's statistics
report (eps_transfer, delta_corr). PPO trains on the same four terms with ``train_reward_weights``
plus an ``alive_bonus``: with the paper's weights standing still (-1.0 per step) beats the
trot (-10 per step, mostly torque and joint-speed penalties) and an early fall beats both (the
return is a sum of negative rewards), so a PPO that maximises them learns not to walk. Every
evaluation records both returns per episode: the paper's (``returns``) and the training
reward's (``training_returns``, the objective the policy was trained for).
"""

from __future__ import annotations

import hashlib
import json
import math
import shutil
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecMonitor, VecNormalize
from torch import nn

from acn.corrector.acn import INPUT_CHANNELS
from acn.corrector.card import TargetDescription
from acn.corrector.config import FitConfig
from acn.corrector.corrector import Corrector, load_for_target, torch_threads
from acn.corrector.evaluate import HELD_OUT_SEED_OFFSET, distribution_stats, episode_stats
from acn.errors import UserError
from acn.jsonfile import strict_json
from acn.outputs.kinds import Output, json_with_format
from acn.outputs.writing import Layout, Writing, replacing, write_file
from acn.rl.policy_io import WalkingPolicy, policy_config
from acn.sim.backends import ACTION_MODES, SimConfig
from acn.sim.collector import CollectConfig, initial_state
from acn.sim.effects import Model
from acn.sim.envs import A1Env, EnvConfig
from acn.sim.hidden import load_model
from acn.sim.policies import POLICIES
from acn.sim.reward import REWARD_WEIGHTS, TERM_NAMES, weighted
from acn.sim.state import STATE_NAMES

RUN_MANIFEST, RUN_FORMAT, EVAL_FORMAT = "run.json", "acn-ppo-run/1", "acn-ppo-eval/1"


def _is_run(path: Path) -> bool:
    """A PPO run directory this toolkit wrote: its manifest, or a run's checkpoint state."""
    return json_with_format(RUN_FORMAT)(path / RUN_MANIFEST) or (path / "checkpoint" / "state.json").is_file()


PPO_RUN = Output("PPO run directory", directory=True, recognise=_is_run)
PPO_EVAL = Output("PPO evaluation JSON", directory=False, recognise=json_with_format(EVAL_FORMAT))
REFIT_SEED_BASE = 2_000_000  # initial states of refit data: never training's or evaluation's


@dataclass
class PPOConfig:
    """Every hyper-parameter of acn-ppo; each is an option of the command (``n_steps``: ``--n-steps``)."""

    # ----- run
    timesteps: int = 500_000            # control steps in the training model, all environments together
    seed: int = 0
    n_envs: int = 2                     # training environments, one subprocess each
    torch_threads: int = 1              # PPO's own process (the simulators run in the others)
    checkpoint_every: int = 50_000      # timesteps between resumable checkpoints
    # ----- task (the training environments; evaluations use the same controller and time limit)
    train: str = "pybullet"             # the training model: pybullet, mujoco, a model file or a sealed robot
    robot: str = "mujoco"               # where the policy is deployed and F applied: the same choices
    seconds: float = 10.0               # episode time limit, s
    base_policy: str = "trot"           # built-in gait the policy is a residual on
    residual_scale: float = 0.3         # rad of joint target per unit of action
    train_reward_weights: tuple[float, float, float, float] = (1.0, 0.0002, 0.5, 0.001)  # see module doc
    alive_bonus: float = 0.1            # per step that does not end in a fall
    action_mode: str = "position"
    control_hz: int = 50
    physics_hz: int = 1000
    kp: float = 60.0                    # N m/rad
    kd: float = 1.5                     # N m s/rad
    torque_limit: float = 33.5          # N m
    # ----- PPO (stable-baselines3)
    learning_rate: float = 3e-4
    n_steps: int = 1024                 # per environment per rollout
    batch_size: int = 256
    n_epochs: int = 10
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_range: float = 0.2
    ent_coef: float = 0.0
    vf_coef: float = 0.5
    max_grad_norm: float = 0.5
    target_kl: float = 0.0              # 0: no early stop on KL
    hidden: tuple[int, ...] = (128, 128)  # actor and critic, each
    log_std_init: float = -1.0          # initial exploration: std e^-1 = 0.37 units = 0.11 rad
    norm_reward: bool = True
    clip_obs: float = 10.0
    # ----- Algorithm 2
    refit_every: int = 50               # episodes between corrector refits; 0: never refit
    eval_every: int = 100               # episodes between evaluations on the robot; 0: only the final one
    eval_episodes: int = 10             # per evaluation during training
    final_eval_episodes: int = 20
    eval_seconds: float = 10.0
    refit_episodes: int = 4             # paired training model -> robot episodes collected per refit
    refit_seconds: float = 10.0
    refit_window: int = 4               # a refit fits on the latest this-many paired datasets
    corrector_variant: str = field(default_factory=lambda: FitConfig().variant)  # acn-fit's default
    fit_epochs: int = 30
    oracle_episodes: int = 20           # OPTIONAL same-state oracle bound, final evaluation only (slow;
    #                                     only where acn.corrector.evaluate offers same_state_oracle)

    def sized_for_run(self, keep: set[str] = frozenset()) -> "PPOConfig":
        """This config with a short run kept short. A run of fewer ``timesteps`` than one rollout
        (``n_steps`` x ``n_envs``, 2,048 by default) is a trial of the plumbing: it collects its steps
        in one rollout, refits on two 2 s paired episodes for 2 epochs, and evaluates 2 episodes of
        2 s; a longer run is unchanged. Fields named in ``keep`` (set by the user) are left as they are."""
        if self.timesteps >= self.n_steps * self.n_envs:
            return self
        n_steps = max(2, math.ceil(self.timesteps / self.n_envs))
        small = dict(n_steps=n_steps, batch_size=min(self.batch_size, n_steps * self.n_envs), final_eval_episodes=2,
                     eval_seconds=2.0, eval_every=0, refit_episodes=2, refit_seconds=2.0, fit_epochs=2,
                     oracle_episodes=0)
        return replace(self, **{k: v for k, v in small.items() if k not in keep})

    def sim(self) -> SimConfig:
        return SimConfig(physics_dt=1.0 / self.physics_hz, substeps=self.physics_hz // self.control_hz,
                         action_mode=self.action_mode, kp=self.kp, kd=self.kd, torque_limit=self.torque_limit)

    def env(self) -> EnvConfig:
        """The training task (the controller and reward; the physics is the training model's)."""
        return EnvConfig(sim=self.sim(), seconds=self.seconds, reward_weights=tuple(self.train_reward_weights),
                         alive_bonus=self.alive_bonus, base_policy=self.base_policy,
                         residual_scale=self.residual_scale)

    def validate(self) -> None:
        from acn.corrector.acn import VARIANTS

        positive = ("timesteps", "n_envs", "torch_threads", "checkpoint_every", "control_hz", "physics_hz", "n_steps",
                    "batch_size", "n_epochs", "final_eval_episodes", "refit_episodes", "refit_window", "fit_epochs")
        for name in positive:
            if getattr(self, name) < 1:
                raise UserError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("seconds", "eval_seconds", "refit_seconds", "learning_rate", "clip_range", "clip_obs"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise UserError(f"{name} must be a finite number > 0, got {v}")
        for name in ("refit_every", "eval_every", "eval_episodes", "seed", "oracle_episodes"):
            if getattr(self, name) < 0:
                raise UserError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.physics_hz % self.control_hz:
            raise UserError(f"physics_hz ({self.physics_hz}) must be a multiple of control_hz ({self.control_hz})")
        if not 0 < self.gamma <= 1 or not 0 < self.gae_lambda <= 1:
            raise UserError("gamma and gae_lambda must be in (0, 1]")
        if self.action_mode not in ACTION_MODES:
            raise UserError(f"action_mode must be one of {', '.join(ACTION_MODES)}, got {self.action_mode!r}")
        if self.base_policy not in POLICIES:
            raise UserError(f"base_policy must be one of {', '.join(POLICIES)}, got {self.base_policy!r}")
        if self.corrector_variant not in VARIANTS:
            raise UserError(f"corrector_variant must be one of {', '.join(VARIANTS)}, got {self.corrector_variant!r}")
        if len(self.train_reward_weights) != 4 or not self.hidden:
            raise UserError("train_reward_weights needs 4 numbers and hidden at least one layer")
        try:
            self.env().validate()
        except ValueError as e:
            raise UserError(str(e)) from None
        for name in ("train", "robot"):
            model = load_model(getattr(self, name))
            if model.corrector:
                raise UserError(f"--{name} carries a corrector ({model.corrector}); give --corrector instead")

    def models(self) -> tuple[Model, Model]:
        """(training model, robot)."""
        return load_model(self.train), load_model(self.robot)


# ----- environments and the SB3 model ---------------------------------------------------------
def _make_env(model: str, env_cfg: EnvConfig) -> A1Env:
    torch.set_num_threads(1)
    return A1Env(model, env_cfg)


def make_vec_env(cfg: PPOConfig, training: bool = True):
    """Training environments (the training model): subprocesses -> VecMonitor -> VecNormalize."""
    fns = [partial(_make_env, cfg.train, cfg.env()) for _ in range(cfg.n_envs)]
    venv = SubprocVecEnv(fns) if cfg.n_envs > 1 else DummyVecEnv(fns)
    venv.seed(cfg.seed)
    return VecNormalize(VecMonitor(venv), training=training, norm_obs=True, norm_reward=cfg.norm_reward,
                        clip_obs=cfg.clip_obs, gamma=cfg.gamma)


class StateChannels(BaseFeaturesExtractor):
    """The (normalised) state channels the networks read: the corrector's input channels."""

    def __init__(self, observation_space, channels: tuple[str, ...] = INPUT_CHANNELS) -> None:
        super().__init__(observation_space, features_dim=len(channels))
        self.register_buffer("index", torch.tensor([STATE_NAMES.index(c) for c in channels]))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return obs.index_select(-1, self.index)


def make_model(cfg: PPOConfig, venv) -> PPO:
    return PPO(
        "MlpPolicy", venv, learning_rate=cfg.learning_rate, n_steps=cfg.n_steps, batch_size=cfg.batch_size,
        n_epochs=cfg.n_epochs, gamma=cfg.gamma, gae_lambda=cfg.gae_lambda, clip_range=cfg.clip_range,
        ent_coef=cfg.ent_coef, vf_coef=cfg.vf_coef, max_grad_norm=cfg.max_grad_norm,
        target_kl=cfg.target_kl or None, seed=cfg.seed, device="cpu", verbose=0,
        policy_kwargs=dict(features_extractor_class=StateChannels,
                           features_extractor_kwargs=dict(channels=tuple(INPUT_CHANNELS)),
                           net_arch=dict(pi=list(cfg.hidden), vf=list(cfg.hidden)), activation_fn=nn.Tanh,
                           log_std_init=cfg.log_std_init, ortho_init=True))


def export_policy(model, norm, cfg: PPOConfig, training: dict) -> WalkingPolicy:
    """The deterministic actor of ``model`` with ``norm``'s observation statistics, as plain tensors."""
    p = model.policy
    config = policy_config(cfg.env(), list(INPUT_CHANNELS), list(cfg.hidden), "Tanh", norm.clip_obs, norm.epsilon,
                           training)
    wp = WalkingPolicy(config)
    theirs = [m for m in p.mlp_extractor.policy_net if isinstance(m, nn.Linear)] + [p.action_net]
    mine = [m for m in wp.net if isinstance(m, nn.Linear)]
    with torch.no_grad():
        for a, b in zip(mine, theirs, strict=True):
            a.weight.copy_(b.weight)
            a.bias.copy_(b.bias)
        wp.obs_mean.copy_(torch.as_tensor(norm.obs_rms.mean))
        wp.obs_var.copy_(torch.as_tensor(norm.obs_rms.var))
    return wp


def save_policy(policy: WalkingPolicy, out: Path) -> Path:
    """Write a policy directory atomically."""
    with Writing(out, None) as output:
        output.path.mkdir()
        policy.save(output.path)
    return output.out


def _norm_stats(norm) -> dict:
    rms = lambda r: {"mean": np.asarray(r.mean).tolist(), "var": np.asarray(r.var).tolist(), "count": float(r.count)}  # noqa: E731
    return {"obs_rms": rms(norm.obs_rms), "ret_rms": rms(norm.ret_rms)}


def _load_norm_stats(norm, d: dict) -> None:
    for key in ("obs_rms", "ret_rms"):
        r = getattr(norm, key)
        r.mean = np.asarray(d[key]["mean"], dtype=np.float64).reshape(np.shape(r.mean))
        r.var = np.asarray(d[key]["var"], dtype=np.float64).reshape(np.shape(r.var))
        r.count = d[key]["count"]


# ----- the frozen corrector ------------------------------------------------------------------
def tensor_digest(tensors: dict[str, torch.Tensor]) -> str:
    """sha256 over names, dtypes, shapes and bytes of a tensor dict (a state dict or a safetensors file)."""
    h = hashlib.sha256()
    for k in sorted(tensors):
        t = tensors[k].detach().cpu().contiguous()
        h.update(f"{k}|{t.dtype}|{tuple(t.shape)}|".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes())
    return "sha256:" + h.hexdigest()


def file_digest(corrector_dir: str | Path) -> str:
    """``tensor_digest`` of a corrector directory's ``model.safetensors``."""
    from safetensors.torch import load_file

    return tensor_digest(load_file(str(Path(corrector_dir) / "model.safetensors")))


def load_corrector(directory: str | Path, env: EnvConfig, robot: Model) -> Corrector:
    """A frozen corrector that fits ``robot`` (its simulator and effects) driven by ``env``'s
    controller (action mode, control rate); one-line errors."""
    d = Path(directory)
    if not d.is_dir():
        raise UserError(f"corrector directory {d} does not exist")
    return load_for_target(d, TargetDescription(robot.backend, env.sim.action_mode, round(1.0 / env.sim.control_dt, 9),
                                                effects=tuple(e.to_json() for e in robot.effects)))


# ----- evaluation: the training model, the robot, the robot + F -----------------------------------
RUNS = ("sim", "robot", "robot_corrected")  # "sim": the policy's own training model
RUN_LABELS = {"sim": "training model", "robot": "robot", "robot_corrected": "robot + F"}
END_KINDS = ("time_limit", "fell", "diverged")


@dataclass
class EpisodeResult:
    """One closed-loop episode: per-step paper rewards and training rewards, how it ended, speed."""

    paper: np.ndarray
    training: np.ndarray
    end: str
    forward_speed: float  # mean v_x over the episode, m/s
    terms: np.ndarray     # (4,) the episode's sums of the reward terms (``TERM_NAMES``), unweighted


def _episode(env: A1Env, policy: WalkingPolicy, s0: np.ndarray, training: EnvConfig) -> EpisodeResult:
    """One closed-loop episode of the deterministic policy; the training reward with ``training``'s
    weights and alive bonus."""
    obs, _ = env.reset(options={"state": s0})
    policy.reset(np.random.default_rng(0))
    paper, trained, speed, terms = [], [], [], np.zeros(len(TERM_NAMES))
    while True:
        obs, _, terminated, truncated, info = env.step(policy.residual(obs))
        terms += info["reward_terms"]
        paper.append(info["paper_reward"])
        bonus = 0.0 if info["fallen"] else training.alive_bonus  # the training environment's reward, A1Env.step
        trained.append(0.0 if info["diverged"] else float(weighted(info["reward_terms"], training.reward_weights)) + bonus)
        speed.append(info["reward_terms"][0])
        if terminated or truncated:
            end = "diverged" if info["diverged"] else ("fell" if info["fallen"] else "time_limit")
            return EpisodeResult(np.array(paper), np.array(trained), end, float(np.mean(speed)), terms)


def same_state_oracle_rewards(policy: WalkingPolicy, env: EnvConfig, corrector: Corrector | None,
                               states: list[np.ndarray], sim: Model, robot: Model) -> list[np.ndarray] | None:
    """OPTIONAL bound: the robot's per-step paper rewards with the same-state oracle, or None.

    Filled only where ``acn.corrector.evaluate`` offers ``same_state_oracle``: the policy acts on
    the robot's own state and every action is replaced by the oracle's (from that state, the
    training model re-simulated one control step with a; delta_a solved so the robot's next
    state matches it): the best any per-step F(s, a) can do for the paper's objective. Channel
    weights: 1 / the corrector's training spread where it has one. Slow (a Gauss-Newton solve
    per step).
    """
    from acn.corrector import evaluate

    oracle = getattr(evaluate, "same_state_oracle", None)
    if oracle is None:
        return None
    norm = None if corrector is None else corrector.card.normalisation
    spread = None if norm is None else norm.state_spread
    return [np.asarray(r, dtype=float) for r in oracle(
        robot.sim_config(env.sim), policy, states, env.seconds, source=sim.backend, target=robot.backend,
        source_sim=sim.sim_config(env.sim), channel_scale=None if spread is None else np.asarray(spread, dtype=float))]


def evaluate_transfer(policy: WalkingPolicy, corrector: Corrector | None, episodes: int, seconds: float,
                      seed: int = 0, oracle_episodes: int = 0, robot: Model | None = None,
                      sim: Model | None = None) -> dict:
    """The policy, deterministic and closed loop, from the same held-out starts, in ``sim`` (default
    the model it was trained in, ``training_model``), on ``robot`` (default MuJoCo) and on the robot
    with pi_corr = pi + F(s, pi(s)) (F applied on the robot, the TARGET).

    Per episode: the paper's return (``returns``, weights ``REWARD_WEIGHTS``), the training
    reward's (``training_returns``: the policy's own weights and alive bonus), how it ended, the
    mean forward speed. eps_transfer = mean_i (R_i^robot,corr - R_i^sim), delta_corr = mean_i
    (R_i^sim - R_i^robot), paper's reward. Table 1 statistics (mean, mode, expectation;
    ``distribution_stats``) are over per-step reward differences on each episode's common
    horizon, as ``acn.corrector.evaluate.closed_loop`` does. ``oracle_episodes`` > 0: also the
    same-state oracle on the first that-many starts (OPTIONAL, ``same_state_oracle_rewards``;
    ``None`` in the result where it is not available).
    """
    with torch_threads(1):
        return _evaluate_transfer(policy, corrector, episodes, seconds, seed, oracle_episodes,
                                  robot or Model("mujoco"), sim or training_model(policy))


def training_model(policy: WalkingPolicy) -> Model:
    """The model a policy was trained in (its ``training.model``; PyBullet where it names none)."""
    spec = policy.config.get("training", {}).get("model", "pybullet")
    try:
        return load_model(spec)
    except UserError as e:
        raise UserError(f"the policy's training model cannot be loaded ({e}); give it with --train MODEL") from None


def _evaluate_transfer(policy: WalkingPolicy, corrector: Corrector | None, episodes: int, seconds: float, seed: int,
                       oracle_episodes: int, robot: Model, sim: Model) -> dict:
    env_cfg = replace(policy.env, seconds=seconds, reward_weights=REWARD_WEIGHTS, alive_bonus=0.0)
    init = CollectConfig(seed=seed + HELD_OUT_SEED_OFFSET, init_noise=env_cfg.init_noise, sim=env_cfg.sim)
    states = [initial_state(init, i) for i in range(episodes)]
    per_step: dict[str, list[np.ndarray]] = {}
    out: dict = {"episodes": episodes, "seconds": seconds, "seed": init.seed, "corrected": corrector is not None,
                 "models": {"sim": sim.describe(), "robot": robot.describe()},
                 "returns": {}, "training_returns": {}, "ends": {}, "forward_speed": {}, "episode_ends": {},
                 "episode_forward_speed": {}, "episode_steps": {}, "reward_term_names": list(TERM_NAMES),
                 "episode_reward_terms": {},
                 "training_reward": {"weights": list(policy.env.reward_weights), "alive_bonus": policy.env.alive_bonus}}
    for run in RUNS:
        if run == "robot_corrected" and corrector is None:
            continue
        env = A1Env(sim if run == "sim" else robot, env_cfg, corrector=corrector if run == "robot_corrected" else None)
        try:
            results = [_episode(env, policy, s0, policy.env) for s0 in states]
        finally:
            env.close()
        per_step[run] = [r.paper for r in results]
        out["returns"][run] = [float(r.paper.sum()) for r in results]
        out["training_returns"][run] = [float(r.training.sum()) for r in results]
        out["ends"][run] = {e: sum(1 for r in results if r.end == e) for e in END_KINDS}
        out["episode_ends"][run] = [r.end for r in results]
        out["episode_forward_speed"][run] = [r.forward_speed for r in results]
        out["episode_steps"][run] = [len(r.paper) for r in results]
        out["episode_reward_terms"][run] = [r.terms.tolist() for r in results]  # sums over the episode, unweighted
        out["forward_speed"][run] = float(np.mean(out["episode_forward_speed"][run]))
    R = {k: np.array(v) for k, v in out["returns"].items()}

    def step_diff(a: list[np.ndarray], b: list[np.ndarray]) -> np.ndarray:
        return np.concatenate([x[: min(len(x), len(y))] - y[: min(len(x), len(y))] for x, y in zip(a, b)])

    out["delta_corr"] = episode_stats(R["sim"] - R["robot"])
    out["eps_transfer_uncorrected"] = episode_stats(R["robot"] - R["sim"])
    out["step_stats"] = {"delta_corr": distribution_stats(step_diff(per_step["sim"], per_step["robot"]))}
    gap_unc = np.abs(R["robot"] - R["sim"])
    if corrector is not None:
        out["eps_transfer"] = episode_stats(R["robot_corrected"] - R["sim"])
        out["step_stats"]["eps_transfer"] = distribution_stats(step_diff(per_step["robot_corrected"],
                                                                         per_step["sim"]))
        gap_cor = np.abs(R["robot_corrected"] - R["sim"])
        out["gap"] = {
            "uncorrected": episode_stats(gap_unc), "corrected": episode_stats(gap_cor),
            "closer_by": episode_stats(gap_unc - gap_cor),  # > 0: the corrected robot's return is closer to the sim's
            "fraction_closed": float(1.0 - abs(out["eps_transfer"]["mean"]) / abs(out["delta_corr"]["mean"]))
            if out["delta_corr"]["mean"] else None,
        }
    out["same_state_oracle"] = None  # OPTIONAL field: filled only where the oracle exists and was asked for
    n = min(oracle_episodes, episodes)
    oracle = same_state_oracle_rewards(policy, env_cfg, corrector, states[:n], sim, robot) if n > 0 else None
    if oracle is not None:
        r_or = np.array([r.sum() for r in oracle])
        steps = [len(r) for r in oracle]
        out["same_state_oracle"] = {
            "episodes": n, "returns": r_or.tolist(),
            "full_length_episodes": int(sum(k == env_cfg.max_steps for k in steps)),
            "eps_transfer": episode_stats(r_or - R["sim"][:n]),
            "eps_transfer_uncorrected_same_episodes": episode_stats(R["robot"][:n] - R["sim"][:n]),
            "eps_transfer_corrector_same_episodes": (episode_stats(R["robot_corrected"][:n] - R["sim"][:n])
                                                     if corrector is not None else None),
        }
    return out


def format_table(ev: dict) -> str:
    """The paper's Table 1 layout for one evaluation, plus returns and the gap, as text."""
    lines = [f"{'':<34}{'mean':>12}{'mode':>12}{'expectation':>14}"]
    for key, label in (("eps_transfer", "eps_transfer (per step)"), ("delta_corr", "delta_corr (per step)")):
        if key in ev["step_stats"]:
            s = ev["step_stats"][key]
            lines.append(f"{label:<34}{s['mean']:>12.4f}{s['mode']:>12.4f}{s['expectation']:>14.4f}")
    n = ev["episodes"]
    for key, label in (("eps_transfer", "eps_transfer (per episode)"), ("delta_corr", "delta_corr (per episode)")):
        if key in ev:
            s = ev[key]
            lines.append(f"{label:<34}{s['mean']:>12.2f}   +- {s['std']:.2f} (std over {n} episodes)")
    models = ev.get("models", {})
    lines.append(f"training model: {models.get('sim', '?')}; robot: {models.get('robot', '?')}")
    lines.append("returns, mean +- std over episodes (paper's reward | training reward); ends; forward speed:")
    for run in RUNS:
        if run in ev["returns"]:
            r, t = np.array(ev["returns"][run]), np.array(ev["training_returns"][run])
            ends = ", ".join(f"{v} {k}" for k, v in ev["ends"][run].items() if v)
            lines.append(f"  {RUN_LABELS[run]:<16}{r.mean():>12.2f} +- {r.std(ddof=1) if n > 1 else 0:.2f} | "
                         f"{t.mean():.2f} +- {t.std(ddof=1) if n > 1 else 0:.2f}   ({ends}; "
                         f"{ev['forward_speed'][run]:.3f} m/s)")
    if "gap" in ev:
        g = ev["gap"]
        lines.append(f"|R_robot - R_sim|: uncorrected {g['uncorrected']['mean']:.2f}, corrected {g['corrected']['mean']:.2f}; "
                     f"closer by {g['closer_by']['mean']:.2f} +- {g['closer_by']['stderr']:.2f} (stderr)")
    o = ev.get("same_state_oracle")
    if o:
        c = o["eps_transfer_corrector_same_episodes"]
        lines.append(f"same-state oracle bound, first {o['episodes']} episodes ({o['full_length_episodes']} reached the "
                     f"time limit): eps_transfer {o['eps_transfer']['mean']:.2f} +- {o['eps_transfer']['std']:.2f}"
                     f" (uncorrected {o['eps_transfer_uncorrected_same_episodes']['mean']:.2f}"
                     + (f", corrector {c['mean']:.2f})" if c else ")"))
    else:
        lines.append("same-state oracle bound: not computed (optional; needs acn.corrector.evaluate.same_state_oracle "
                     "and oracle_episodes > 0)")
    return "\n".join(lines)


# ----- Algorithm 2 ---------------------------------------------------------------------------
@dataclass
class RunState:
    """What a checkpoint must remember besides the SB3 model and the normalisation."""

    timesteps: int = 0
    episodes: int = 0
    train_curve: list = field(default_factory=list)    # [timesteps, episode, return (training reward), length]
    evaluations: list = field(default_factory=list)    # evaluate_transfer summaries with timesteps, episodes
    correctors: list = field(default_factory=list)     # {dir (relative to the run), from_episode, digest, ...}
    datasets: list = field(default_factory=list)       # paired datasets written for refits (relative)
    next_refit: int = 0
    next_eval: int = 0
    last_checkpoint: int = 0
    wall: dict = field(default_factory=lambda: {"rollout": 0.0, "update": 0.0, "evaluate": 0.0, "refit": 0.0,
                                                "checkpoint": 0.0})


class Trainer:
    """One acn-ppo run in ``out``; ``run()`` does everything (see the module docstring)."""

    def __init__(self, cfg: PPOConfig, out: Path, corrector_dir: Path | None = None, resume: bool = False,
                 overwrite: bool = False, log: Callable[[str], None] = print) -> None:
        cfg.validate()
        self.log = log
        # A new run is written where it is (a killed one resumes from its checkpoint); a new run over
        # an earlier one trains beside it and replaces it only when complete (``run``): a run that
        # fails or is interrupted leaves the earlier one as it was.
        self.output = Writing(out, PPO_RUN, overwrite, layout=Layout.RESUMABLE, resume=resume)
        try:
            self._start(cfg, corrector_dir, resume)
        except BaseException as e:
            raise self.output.fail(e) from None

    def _start(self, cfg: PPOConfig, corrector_dir: Path | None, resume: bool) -> None:
        self.out = self.output.out
        self.ckpt = self.out / "checkpoint"
        if resume:
            if not (self.ckpt / "state.json").is_file():
                raise UserError(f"no checkpoint to resume in {self.out} (expected {self.ckpt / 'state.json'})")
            saved = json.loads((self.ckpt / "state.json").read_text())
            old = PPOConfig(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in saved["config"].items()})
            self.cfg = replace(old, timesteps=cfg.timesteps)
            self.state = RunState(**saved["state"])
            if self.state.timesteps >= self.cfg.timesteps:
                raise UserError(f"{self.out} already has {self.state.timesteps} timesteps; ask for more with --timesteps")
        else:
            self.cfg, self.state = cfg, RunState()
        if resume and corrector_dir is not None:
            raise UserError("--resume continues with the checkpoint's corrector; drop --corrector")
        if corrector_dir is not None and not Path(corrector_dir).is_dir():
            raise UserError(f"corrector directory {corrector_dir} does not exist")
        self.env_cfg = self.cfg.env()
        self.sim, self.robot = self.cfg.models()
        if self.cfg.refit_every and self.sim.effects:
            raise UserError("refits re-simulate the training model as a dataset records it, without effects: train "
                            "in pybullet or mujoco, or give --refit-every 0 (and --corrector DIR, or none)")
        if self.cfg.refit_every and self.robot.effects:
            from acn.corrector.acn import LABELLED

            if self.cfg.corrector_variant not in LABELLED:
                raise UserError(f"a robot with effects is re-simulated only by the variants {', '.join(LABELLED)}; "
                                f"--variant {self.cfg.corrector_variant} cannot be refitted on it")
        self.corrector: Corrector | None = None
        self.corrector_digest: str | None = None
        given = load_corrector(corrector_dir, self.env_cfg, self.robot) if corrector_dir is not None else None
        self.out = self.output.path
        self.ckpt = self.out / "checkpoint"
        self.out.mkdir(parents=True, exist_ok=True)
        write_file(self.out / RUN_MANIFEST, json.dumps({"format": RUN_FORMAT}) + "\n")
        if resume and self.state.correctors:
            last = self.state.correctors[-1]
            self._use_corrector(load_corrector(self.out / last["dir"], self.env_cfg, self.robot), last["dir"], None)
        elif given is not None:  # a copy inside the run keeps it self-contained; same tensors, same digest
            copy = self.out / "correctors" / "given"
            shutil.copytree(corrector_dir, copy)
            if file_digest(copy) != tensor_digest(given.state_dict()):
                raise RuntimeError(f"the copy of {corrector_dir} differs from it")
            self._use_corrector(given, "correctors/given", self.state.episodes,
                                source=f"given: {Path(corrector_dir).absolute()}")

    # ----- corrector bookkeeping ---------------------------------------------------------
    def _use_corrector(self, corrector: Corrector, directory: str, episode: int | None, source: str = "") -> None:
        """Make ``corrector`` (loaded from ``directory``, relative to the run) the one in use."""
        digest = tensor_digest(corrector.state_dict())
        if digest != file_digest(self.out / directory):
            raise RuntimeError(f"corrector in memory differs from {directory}")
        if episode is None:  # resumed: the same corrector as before
            if digest != self.state.correctors[-1]["digest"]:
                raise UserError(f"corrector {directory} changed on disk since the checkpoint")
        else:
            self._retire_corrector()
            self.state.correctors.append({"dir": directory, "source": source, "from_episode": episode,
                                          "from_timesteps": self.state.timesteps, "digest": digest})
        assert not corrector.training and not any(p.requires_grad for p in corrector.parameters())
        self.corrector, self.corrector_digest = corrector, digest

    def _retire_corrector(self) -> None:
        """Check the frozen corrector's tensors are unchanged since it was loaded."""
        if self.corrector is None:
            return
        now = tensor_digest(self.corrector.state_dict())
        entry = self.state.correctors[-1]
        entry["digest_at_retirement"] = now
        entry["unchanged"] = now == entry["digest"]
        if not entry["unchanged"]:
            raise RuntimeError(f"the frozen corrector {entry['dir']} changed while in use")

    # ----- Algorithm 2 steps -------------------------------------------------------------
    def current_policy(self) -> WalkingPolicy:
        return export_policy(self.model, self.norm, self.cfg, self._training_info())

    def _training_info(self) -> dict:
        from importlib.metadata import version

        return {"algorithm": f"PPO (stable-baselines3 {version('stable_baselines3')})", "model": self.cfg.train,
                "simulator": self.sim.backend,
                "timesteps": self.state.timesteps, "episodes": self.state.episodes, "ppo_config": asdict(self.cfg)}

    def refit(self) -> None:
        """Collect paired data with the current policy and refit F with acn-fit's code."""
        from acn.datasets.metadata import collection_metadata
        from acn.datasets.writer import DatasetWriter
        from acn.corrector.fit import fit, save
        from acn.sim.collector import PairedRollout

        t0 = time.perf_counter()
        cfg, k = self.cfg, len(self.state.datasets)
        ccfg = CollectConfig(source=self.sim.backend, target=self.robot.backend, policy="ppo",
                             episodes=cfg.refit_episodes, seconds=cfg.refit_seconds,
                             seed=REFIT_SEED_BASE + 10_000 * cfg.seed + k, sim=self.env_cfg.sim,
                             init_noise=self.env_cfg.init_noise, hidden_effects=list(self.sim.effects),
                             target_effects=list(self.robot.effects))
        rollout = PairedRollout(ccfg, policy=self.current_policy())
        try:
            episodes = [rollout.episode(i) for i in range(ccfg.episodes)]
        finally:
            rollout.close()
        rel = f"paired/refit_{k:03d}"
        path = self.out / rel
        writer = DatasetWriter(path, fps=int(round(1.0 / ccfg.sim.control_dt)), paired=True,
                               task=f"ppo policy ({self.sim.backend} -> {self.robot.backend})",
                               acn_meta=collection_metadata(ccfg),
                               overwrite=True)
        try:
            for ep in episodes:
                writer.write(ep)
            writer.commit()
        except BaseException as e:
            raise writer.fail(e) from None
        self.state.datasets.append(rel)
        paths = [self.out / d for d in self.state.datasets[-cfg.refit_window:]]
        fcfg = FitConfig(variant=cfg.corrector_variant, epochs=cfg.fit_epochs, eval_episodes=0, seed=cfg.seed)
        try:
            model, metrics = fit(paths, fcfg, log=lambda s: None, target=self.robot if self.robot.effects else None)
        except UserError as e:  # e.g. the policy fell at once: too few rows; keep the current F
            self.log(f"refit {k} skipped at episode {self.state.episodes}: {e}")
            self.state.wall["refit"] += time.perf_counter() - t0
            return
        rel = f"correctors/refit_{k:03d}"
        directory = save(model, metrics, self.out / rel, overwrite=True)
        self._use_corrector(Corrector.load(directory), rel, self.state.episodes, source="refit")
        self.state.correctors[-1]["val_objective"] = metrics["val_objective"]
        rows = sum(len(e) for e in episodes)
        self.log(f"refit {k} at episode {self.state.episodes}: {rows} paired rows "
                 f"({', '.join(e.end for e in episodes)}), fitted on {len(paths)} dataset(s), "
                 f"val fit {metrics['val_objective']['fit']:.4f} (no correction "
                 f"{metrics['val_objective']['fit_no_correction']:.4f})")
        self.state.wall["refit"] += time.perf_counter() - t0

    def evaluate(self, episodes: int, final: bool = False, oracle_episodes: int = 0) -> dict:
        """Algorithm 2's evaluation (kept in the history unless ``final``)."""
        t0 = time.perf_counter()
        ev = evaluate_transfer(self.current_policy(), self.corrector, episodes, self.cfg.eval_seconds, self.cfg.seed,
                               oracle_episodes, robot=self.robot, sim=self.sim)
        ev.update(timesteps=self.state.timesteps, episode=self.state.episodes,
                  corrector=self.state.correctors[-1]["dir"] if self.state.correctors else None)
        if not final:
            self.state.evaluations.append(ev)
        r = {k: np.mean(v) for k, v in ev["returns"].items()}
        self.log(f"{'final eval' if final else 'eval'} at episode {self.state.episodes} ({self.state.timesteps} steps): "
                 f"return (paper's reward) training model {r['sim']:.1f}, robot {r['robot']:.1f}, robot + F "
                 f"{r.get('robot_corrected', float('nan')):.1f}; "
                 f"eps_transfer {ev.get('eps_transfer', {}).get('mean', float('nan')):.1f}, "
                 f"delta_corr {ev['delta_corr']['mean']:.1f}")
        self.state.wall["evaluate"] += time.perf_counter() - t0
        return ev

    def checkpoint(self) -> None:
        """SB3 zip (LOCAL RESUME ONLY: cloudpickled), normalisation and run state; then the policy."""
        t0 = time.perf_counter()
        with Writing(self.ckpt, None) as output:
            output.path.mkdir()
            self.model.save(output.path / "ppo.zip")
            write_json(output.path / "normalisation.json", _norm_stats(self.norm))
            write_json(output.path / "state.json", {"config": asdict(self.cfg), "state": asdict(self.state)})
        save_policy(self.current_policy(), self.out / "policy")
        self.state.last_checkpoint = self.state.timesteps
        self.state.wall["checkpoint"] += time.perf_counter() - t0
        recent = [r for _, _, r, _ in self.state.train_curve[-20:]]
        self.log(f"checkpoint at {self.state.timesteps} steps, episode {self.state.episodes}"
                 + (f": mean training return of the last {len(recent)} episodes {np.mean(recent):.1f}" if recent else ""))

    def at_rollout_end(self) -> None:
        """Algorithm 2's schedule, checked whenever the policy is fixed (between PPO updates)."""
        cfg, st = self.cfg, self.state
        if cfg.refit_every and st.episodes >= st.next_refit:
            self.refit()
            st.next_refit = (st.episodes // cfg.refit_every + 1) * cfg.refit_every
        if cfg.eval_every and st.episodes >= st.next_eval:
            self.evaluate(cfg.eval_episodes)
            st.next_eval = (st.episodes // cfg.eval_every + 1) * cfg.eval_every
        if st.timesteps - st.last_checkpoint >= cfg.checkpoint_every:
            self.checkpoint()

    # ----- the run -----------------------------------------------------------------------
    def run(self) -> dict:
        try:
            with torch_threads(self.cfg.torch_threads):
                metrics = self._run()
        except BaseException as e:  # beside an earlier run: nothing of this one is kept
            raise self.output.fail(e) from None
        self.out = self.output.commit()
        self.ckpt = self.out / "checkpoint"
        return metrics

    def _run(self) -> dict:
        cfg, st = self.cfg, self.state
        t_start = time.perf_counter()
        self.norm = make_vec_env(cfg)
        resumed = (self.ckpt / "ppo.zip").is_file() and st.timesteps > 0
        if resumed:
            _load_norm_stats(self.norm, json.loads((self.ckpt / "normalisation.json").read_text()))
            self.model = PPO.load(self.ckpt / "ppo.zip", env=self.norm, device="cpu")
            self.log(f"resumed {self.out} at {st.timesteps} steps, episode {st.episodes}")
        else:
            self.model = make_model(cfg, self.norm)
            if self.corrector is None and cfg.refit_every:  # Algorithm 2 at k = 0: F for the initial policy
                self.refit()
            if cfg.eval_every:
                self.evaluate(cfg.eval_episodes)
            st.next_refit, st.next_eval = cfg.refit_every, cfg.eval_every
        # SB3's default logger makes an empty tempdir/SB3-<date> folder on every learn(); ours logs itself
        self.model.set_logger(Logger(folder=None, output_formats=[]))
        callback = Algorithm2(self)
        try:
            self.model.learn(total_timesteps=cfg.timesteps - st.timesteps, callback=callback,
                             reset_num_timesteps=not resumed, progress_bar=False)
        finally:
            callback.close_bar()
        st.timesteps = int(self.model.num_timesteps)
        self.checkpoint()
        self.norm.close()
        self.log(f"final evaluation: {cfg.final_eval_episodes} episodes of {cfg.eval_seconds:g} s in the training "
                 f"model ({self.sim.describe()}) and on the robot ({self.robot.describe()})"
                 + (", with and without F" if self.corrector is not None else ""))
        final = self.evaluate(cfg.final_eval_episodes, final=True, oracle_episodes=cfg.oracle_episodes)
        self._retire_corrector()
        if self.corrector is not None:
            final_dir = self.out / "corrector"
            shutil.rmtree(final_dir, ignore_errors=True)
            shutil.copytree(self.out / self.state.correctors[-1]["dir"], final_dir)
        metrics = self.metrics(final, time.perf_counter() - t_start)
        write_json(self.out / "metrics.json", metrics)
        plot_curves(self.state, final, self.out / "curves.png")
        write_json(self.ckpt / "state.json", {"config": asdict(cfg), "state": asdict(st)})
        return metrics

    def metrics(self, final: dict, wall: float) -> dict:
        st = self.state
        recent = [r for _, _, r, _ in st.train_curve[-100:]]
        m = {
            "eps_transfer": final["step_stats"].get("eps_transfer"),
            "delta_corr": final["step_stats"]["delta_corr"],
            "eps_transfer_per_episode": final.get("eps_transfer"),
            "delta_corr_per_episode": final["delta_corr"],
            "eps_transfer_uncorrected_per_episode": final["eps_transfer_uncorrected"],
            "gap": final.get("gap"),
            "same_state_oracle": final.get("same_state_oracle"),  # OPTIONAL: None until evaluate offers it
            "definitions": {
                "eps_transfer": "R^robot,corrected - R^sim (paper's reward); Table 1 stats over per-step differences",
                "delta_corr": "R^sim - R^robot,uncorrected (paper's reward); Table 1 stats over per-step differences",
                "per_episode": "the same over per-episode returns: mean, std, stderr, n",
                "correction": "pi_corr(s) = pi(s) + F(s, pi(s)) applied on the robot (the TARGET) only; "
                              "PPO trains pi in the training model (sim) uncorrected",
            },
            "final_evaluation": final,
            "evaluations": [{k: e[k] for k in ("timesteps", "episode", "returns", "delta_corr", "corrector")}
                            | {"eps_transfer": e.get("eps_transfer")} for e in st.evaluations],
            "training": {"timesteps": st.timesteps, "episodes": st.episodes, "wall_seconds_this_session": wall,
                         "wall_split_seconds": st.wall,
                         "train_return_last_100_episodes": float(np.mean(recent)) if recent else None,
                         "train_reward_weights": list(self.cfg.train_reward_weights),
                         "alive_bonus": self.cfg.alive_bonus},
            "correctors": st.correctors,
            "corrector_frozen": all(c.get("unchanged", False) for c in st.correctors) if st.correctors else None,
            "config": asdict(self.cfg),
        }
        return m


class Algorithm2(BaseCallback):
    """SB3 callback: episode bookkeeping, the progress bar, Algorithm 2 at rollout ends, timing."""

    def __init__(self, trainer: Trainer) -> None:
        super().__init__()
        self.t = trainer
        self.bar = None
        self._mark = time.perf_counter()

    def _on_training_start(self) -> None:
        from tqdm import tqdm

        self.bar = tqdm(total=self.t.cfg.timesteps, initial=self.t.state.timesteps, unit="step", desc="acn-ppo",
                        file=sys.stderr, disable=None, mininterval=1.0, dynamic_ncols=True)
        self._mark = time.perf_counter()

    def _on_rollout_start(self) -> None:  # the time since the last rollout ended was PPO's update
        now = time.perf_counter()
        self.t.state.wall["update"] += now - self._mark
        self._mark = now

    def _on_step(self) -> bool:
        st = self.t.state
        st.timesteps = int(self.num_timesteps)
        for info in self.locals["infos"]:
            ep = info.get("episode")
            if ep is not None:  # VecMonitor: the raw (unnormalised) training return
                st.episodes += 1
                st.train_curve.append([st.timesteps, st.episodes, float(ep["r"]), int(ep["l"])])
        if self.bar is not None:
            self.bar.update(st.timesteps - self.bar.n)
            if st.train_curve:
                recent = [r for _, _, r, _ in st.train_curve[-20:]]
                self.bar.set_postfix(episodes=st.episodes, mean_return=f"{np.mean(recent):.1f}", refresh=False)
        return True

    def _on_rollout_end(self) -> None:
        now = time.perf_counter()
        self.t.state.wall["rollout"] += now - self._mark
        self.t.at_rollout_end()
        self._mark = time.perf_counter()

    def _on_training_end(self) -> None:
        self.t.state.wall["update"] += time.perf_counter() - self._mark

    def close_bar(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


# ----- files ---------------------------------------------------------------------------------
def write_json(path: str | Path, data: dict) -> None:
    """Strict JSON (``strict_json``: numpy numbers and arrays as plain ones, a non-finite number as
    null), written whole or not at all."""
    write_file(path, json.dumps(strict_json(data), indent=2, allow_nan=False))


def plot_curves(state: RunState, final: dict | None, path: Path) -> None:
    """Training returns (training model, training reward) and evaluation returns (paper's reward) as PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(12, 4.2))
    if state.train_curve:
        c = np.array(state.train_curve, dtype=float)
        a.plot(c[:, 0], c[:, 2], ".", ms=2, alpha=0.3, color="tab:blue", label="episode")
        k = max(1, min(50, len(c) // 10))
        a.plot(c[k - 1:, 0], np.convolve(c[:, 2], np.ones(k) / k, mode="valid"), color="tab:blue",
               label=f"mean of {k}")
    a.set(title="PPO training in the training model (training reward)", xlabel="timesteps", ylabel="episode return")
    if state.train_curve:
        a.legend(loc="lower right")
    else:  # a run shorter than one episode
        a.text(0.5, 0.5, "no training episode finished", transform=a.transAxes, ha="center")
    colours = {"sim": "tab:blue", "robot": "tab:red", "robot_corrected": "tab:green"}
    labels = RUN_LABELS
    for run in RUNS:
        evs = [e for e in state.evaluations if run in e["returns"]]
        pts = [(e["timesteps"], np.mean(e["returns"][run]), np.std(e["returns"][run])) for e in evs]
        if pts:
            x, y, s = map(np.array, zip(*pts))
            b.plot(x, y, "o-", color=colours[run], label=labels[run])
            b.fill_between(x, y - s, y + s, color=colours[run], alpha=0.15)
        for e in evs + ([final] if final is not None and run in final["returns"] else []):
            fell = e["ends"][run]["fell"] + e["ends"][run]["diverged"]
            if fell:  # a fall ends the sum of negative rewards early: say so beside the point
                b.annotate(f"{fell}/{len(e['returns'][run])} fell", (e["timesteps"], np.mean(e["returns"][run])),
                           textcoords="offset points", xytext=(4, 6), fontsize=7, color=colours[run])
        if final is not None and run in final["returns"]:
            r = np.array(final["returns"][run])
            b.errorbar([final["timesteps"]], [r.mean()], yerr=[r.std()], fmt="D", color=colours[run], capsize=4,
                       label=f"{labels[run]}, final ({len(r)} episodes)")
    b.set(title="evaluation, same initial states (paper's reward, mean +- std)", xlabel="timesteps",
          ylabel="episode return")
    b.margins(x=0.08)
    b.legend(loc="lower right", fontsize=8)
    fig.tight_layout()
    with replacing(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def evaluate_saved(policy_dir: str | Path, corrector_dir: str | Path | None, episodes: int, seconds: float | None,
                   seed: int, oracle_episodes: int = 0, robot: str = "mujoco", sim: str | None = None) -> dict:
    """``acn-ppo --eval POLICY --robot ROBOT [--corrector DIR] [--sim MODEL]``: reload and evaluate
    (``sim``: default the model the policy was trained in)."""
    policy = WalkingPolicy.load(policy_dir)
    robot_model = load_model(robot)
    sim_model = load_model(sim) if sim is not None else training_model(policy)
    corrector = load_corrector(corrector_dir, policy.env, robot_model) if corrector_dir is not None else None
    return evaluate_transfer(policy, corrector, episodes, seconds or policy.env.seconds, seed, oracle_episodes,
                             robot=robot_model, sim=sim_model)
