"""The walking policy a user shares: ``model.safetensors`` + ``config.json``, never pickle.

``WalkingPolicy`` is the deterministic actor of a PPO run, rebuilt from plain tensors:

    u(s) = clip(MLP(select(clip((s - mean) / sqrt(var + eps), -c, c))), -1, 1)   (12 residual units)
    pi(s, t) = gait(s, t) + residual_scale * u(s)                                 (joint targets, rad)

with ``select`` the state channels the network reads (the corrector's: absolute x, y and yaw
carry no dynamics), ``mean``/``var`` the observation statistics of training, and the gait and
scale of the environment it was trained in (``acn.sim.envs``). It implements the toolkit's
``Policy`` protocol (``reset(rng)``, ``__call__(state, t)``), so the collector can run it.

The config holds the state and action channel names (checked on load: a policy trained on
another state schema is refused), the network shape, and the environment it was trained in.
An SB3 ``.zip`` holds cloudpickled objects: ``acn-ppo`` keeps one only to resume training.
"""

from __future__ import annotations

from dataclasses import asdict, fields
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file
from torch import nn

from acn.errors import UserError
from acn.sim.backends import SimConfig
from acn.sim.collector import InitNoise
from acn.sim.envs import EnvConfig, Residual
from acn.sim.policies import make_policy
from acn.sim.robot import ModelParams
from acn.sim.state import ACTION_DIM, ACTION_NAMES, STATE_DIM, STATE_NAMES
from acn.weights import CONFIG, WEIGHTS, corrupt_weights, read_config, save_weights

FORMAT = "acn-ppo-policy/1"
ACTIVATIONS = {"Tanh": nn.Tanh, "ReLU": nn.ReLU, "SiLU": nn.SiLU, "ELU": nn.ELU}


# ----- EnvConfig <-> JSON --------------------------------------------------------------------
def env_config_to_json(cfg: EnvConfig) -> dict:
    sim = cfg.sim
    params = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in vars(sim.params).items()}
    return {
        "sim": {"physics_dt": sim.physics_dt, "substeps": sim.substeps, "action_mode": sim.action_mode,
                "kp": sim.kp, "kd": sim.kd, "torque_limit": sim.torque_limit, "params": params},
        "seconds": cfg.seconds, "reward_weights": list(cfg.reward_weights), "alive_bonus": cfg.alive_bonus,
        "base_policy": cfg.base_policy, "residual_scale": cfg.residual_scale, "init_noise": asdict(cfg.init_noise),
    }


def env_config_from_json(d: dict) -> EnvConfig:
    s = d["sim"]
    known = {f.name for f in fields(ModelParams)}
    params = ModelParams(**{k: v for k, v in s.get("params", {}).items() if k in known})
    sim = SimConfig(physics_dt=s["physics_dt"], substeps=s["substeps"], action_mode=s["action_mode"], kp=s["kp"],
                    kd=s["kd"], torque_limit=s["torque_limit"], params=params)
    return EnvConfig(sim=sim, seconds=d["seconds"], reward_weights=tuple(d["reward_weights"]),
                     alive_bonus=d["alive_bonus"], base_policy=d["base_policy"], residual_scale=d["residual_scale"],
                     init_noise=InitNoise(**d["init_noise"]))


# ----- the policy ----------------------------------------------------------------------------
class WalkingPolicy(nn.Module):
    """Observation normalisation + actor MLP + gait; see the module docstring."""

    def __init__(self, config: dict) -> None:
        super().__init__()
        self.config = config
        self.register_buffer("input_index", torch.tensor([STATE_NAMES.index(n) for n in config["input_channels"]]))
        self.register_buffer("obs_mean", torch.zeros(STATE_DIM, dtype=torch.float64))
        self.register_buffer("obs_var", torch.ones(STATE_DIM, dtype=torch.float64))
        act = ACTIVATIONS[config["network"]["activation"]]
        sizes = [len(config["input_channels"]), *config["network"]["hidden"]]
        mods: list[nn.Module] = []
        for a, b in zip(sizes[:-1], sizes[1:]):
            mods += [nn.Linear(a, b), act()]
        mods.append(nn.Linear(sizes[-1], ACTION_DIM))
        self.net = nn.Sequential(*mods)
        self.env = env_config_from_json(config["env"])
        self._gait = Residual(make_policy(self.env.base_policy), self.env.residual_scale, self.residual)
        self.name = "ppo"
        self.eval()
        for p in self.parameters():
            p.requires_grad_(False)

    def normalise(self, state: torch.Tensor) -> torch.Tensor:
        """The network input: normalised, clipped, selected channels (float32)."""
        n = self.config["obs_normalisation"]
        z = (state.double() - self.obs_mean) / torch.sqrt(self.obs_var + n["epsilon"])
        return z.clamp(-n["clip"], n["clip"]).float().index_select(-1, self.input_index)

    def forward(self, state: torch.Tensor) -> torch.Tensor:
        """The actor's mean action, unclipped, for states (..., 43)."""
        return self.net(self.normalise(state))

    @torch.no_grad()
    def residual(self, state: np.ndarray) -> np.ndarray:
        """u(s) in [-1, 1]^12 (deterministic: the mean action) for a state (43,) or batch."""
        u = self(torch.as_tensor(np.asarray(state, dtype=np.float64)))
        return u.clamp(-1.0, 1.0).numpy().astype(np.float64)

    def reset(self, rng: np.random.Generator) -> None:
        self._gait.reset(rng)

    def __call__(self, state, t: float | None = None):  # Policy protocol: joint targets, rad
        if t is None:  # nn.Module-style call on a tensor: the mean action
            return super().__call__(state)
        return self._gait(state, t)

    # ----- files --------------------------------------------------------------------------
    def save(self, directory: str | Path) -> None:
        """Write ``model.safetensors`` and ``config.json`` into ``directory`` (must exist)."""
        save_weights(directory, self, {**self.config, "format": FORMAT}, FORMAT)

    @classmethod
    def load(cls, directory: str | Path) -> "WalkingPolicy":
        """Load a policy; a one-line ``UserError`` for a missing, corrupt or foreign directory."""
        d = Path(directory)
        config = read_config(d, "policy")
        if not isinstance(config, dict) or config.get("format") != FORMAT:
            raise UserError(f"{d / CONFIG} is not an acn policy config (format {FORMAT!r} expected)")
        check_schema(config, str(d))
        try:
            model = cls(config)
            model.load_state_dict(load_file(str(d / WEIGHTS)), strict=True)
        except Exception as e:  # noqa: BLE001 - a broken config or weights file can fail in many ways
            raise corrupt_weights(d, e) from None
        return model


def check_schema(config: dict, where: str) -> None:
    """Refuse a policy whose state or action channels differ from this toolkit's."""
    names = config.get("state_names")
    if names != list(STATE_NAMES):
        n = len(names) if isinstance(names, list) else "?"
        raise UserError(f"{where} was trained on a different state schema ({n} channels) than this toolkit's "
                        f"{STATE_DIM}-channel state")
    if config.get("action_names") != list(ACTION_NAMES):
        raise UserError(f"{where} acts on different action channels than this toolkit's {ACTION_DIM} joints")
    missing = [c for c in config.get("input_channels", []) if c not in STATE_NAMES]
    if missing or not config.get("input_channels"):
        raise UserError(f"{where} reads state channels this toolkit does not have: {missing[:3]}")


def policy_config(env: EnvConfig, input_channels: list[str], hidden: list[int], activation: str,
                  obs_clip: float, obs_epsilon: float, training: dict) -> dict:
    """The JSON half of a policy directory."""
    if activation not in ACTIVATIONS:
        raise ValueError(f"activation must be one of {', '.join(ACTIVATIONS)}, got {activation!r}")
    return {
        "format": FORMAT,
        "state_names": list(STATE_NAMES), "action_names": list(ACTION_NAMES),
        "input_channels": list(input_channels),
        "network": {"hidden": list(hidden), "activation": activation},
        "obs_normalisation": {"clip": float(obs_clip), "epsilon": float(obs_epsilon)},
        "output": "residual u in [-1, 1]^12; joint targets = gait(s, t) + env.residual_scale * u (rad)",
        "env": env_config_to_json(env),
        "training": training,
    }
