"""PPO training speed, printed as name=value lines (ratios measured in this same run).

raw_steps_per_s      control steps/s of N PyBullet simulators stepping the trot's targets through the
                     public Backend API (``step`` + ``get_state``), nothing else, in N processes at
                     once: the simulator's own rate with the training's parallelism
env_steps_per_s      control steps/s of the N vectorised training environments (SubprocVecEnv of
                     A1Env -> VecMonitor -> VecNormalize, episode resets included) driven from this
                     process with zero residual actions (the trot)
env_overhead_ratio   env_steps_per_s / raw_steps_per_s; target >= 0.8
ppo_steps_per_s      control steps/s of PPO learning (rollouts with the policy + updates), no
                     evaluations or refits
ppo_update_share     share of PPO's wall time spent in the PPO update (the rest: rollouts)

Usage: python benchmarks/ppo.py [--envs 2] [--steps 3000] [--ppo-steps 8192]
"""

from __future__ import annotations

import argparse
import multiprocessing as mp
import os
import time
from dataclasses import replace

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np  # noqa: E402
from stable_baselines3.common.callbacks import BaseCallback  # noqa: E402

from acn.rl.ppo import PPOConfig, make_model, make_vec_env  # noqa: E402


def raw_rate(args: tuple[int, float]) -> float:
    """Control steps/s of one PyBullet backend replaying the trot (one process)."""
    steps, start_at = args
    from acn.sim.backends import make_backend
    from acn.sim.collector import CollectConfig, initial_state
    from acn.sim.policies import Trot

    sim = make_backend("pybullet", PPOConfig().sim())
    s = sim.reset(initial_state(CollectConfig(), 0))
    trot, dt = Trot(), sim.config.control_dt
    while time.time() < start_at:  # start together: the rates add up to the aggregate
        time.sleep(0.001)
    t = time.perf_counter()
    for k in range(steps):
        sim.step(trot(s, k * dt))
        s = sim.get_state()
    rate = steps / (time.perf_counter() - t)
    sim.close()
    return rate


def env_rate(cfg: PPOConfig, steps: int) -> float:
    venv = make_vec_env(cfg)
    venv.reset()
    zeros = np.zeros((cfg.n_envs, 12), dtype=np.float32)
    for _ in range(20):  # warm up
        venv.step(zeros)
    t = time.perf_counter()
    for _ in range(steps):
        venv.step(zeros)
    rate = steps * cfg.n_envs / (time.perf_counter() - t)
    venv.close()
    return rate


class _Timer(BaseCallback):
    def __init__(self) -> None:
        super().__init__()
        self.rollout = self.update = 0.0
        self._mark = time.perf_counter()

    def _on_training_start(self) -> None:
        self._mark = time.perf_counter()

    def _on_rollout_start(self) -> None:
        now = time.perf_counter()
        self.update += now - self._mark
        self._mark = now

    def _on_rollout_end(self) -> None:
        now = time.perf_counter()
        self.rollout += now - self._mark
        self._mark = now

    def _on_training_end(self) -> None:
        self.update += time.perf_counter() - self._mark

    def _on_step(self) -> bool:
        return True


def ppo_rate(cfg: PPOConfig, steps: int) -> tuple[float, float]:
    import torch

    torch.set_num_threads(cfg.torch_threads)
    venv = make_vec_env(cfg)
    model = make_model(cfg, venv)
    timer = _Timer()
    t = time.perf_counter()
    model.learn(total_timesteps=steps, callback=timer)
    wall = time.perf_counter() - t
    venv.close()
    return model.num_timesteps / wall, timer.update / (timer.update + timer.rollout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--envs", type=int, default=2)
    ap.add_argument("--steps", type=int, default=3000, help="per environment, for the raw and env rates")
    ap.add_argument("--ppo-steps", type=int, default=8192)
    args = ap.parse_args()
    cfg = replace(PPOConfig(), n_envs=args.envs)
    with mp.get_context("forkserver").Pool(args.envs) as pool:
        pool.map(raw_rate, [(50, 0.0)] * args.envs)  # import and build once before timing
        raw = sum(pool.map(raw_rate, [(args.steps, time.time() + 1.0)] * args.envs))
    env = env_rate(cfg, args.steps)
    ppo, share = ppo_rate(cfg, args.ppo_steps)
    print(f"envs={args.envs}")
    print(f"raw_steps_per_s={raw:.0f}")
    print(f"env_steps_per_s={env:.0f}")
    print(f"env_overhead_ratio={env / raw:.3f}")
    print(f"ppo_steps_per_s={ppo:.0f}")
    print(f"ppo_update_share={share:.3f}")


if __name__ == "__main__":
    main()
