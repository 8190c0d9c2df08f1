"""Collection speed, printed as name=value lines (ratios measured in this same run).

raw_<sim>_steps_per_s    control steps/s of one simulator alone: a plain loop that only steps
                         (PyBullet: the PD law and stepSimulation per physics step; MuJoCo:
                         mj_step(nstep=substeps), its actuators realise the PD law), replaying
                         the open-loop trot's targets so it simulates the same motion and contacts
collector_steps_per_s    paired control steps/s of acn-collect's path, dataset writing included
paired_ratio             collector rate / (1 / (t_pybullet + t_mujoco)); target >= 0.8
workers_speedup          wall time with 1 worker / with 2 workers, same collection; target >= 1.6

Usage: python benchmarks/collect.py [--episodes 12] [--seconds 10]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import mujoco  # noqa: E402

from acn.datasets.record import record  # noqa: E402
from acn.sim.backends import make_backend  # noqa: E402
from acn.sim.collector import CollectConfig, initial_state  # noqa: E402
from acn.sim.policies import Trot  # noqa: E402


def raw_rate(name: str, steps: int) -> float:
    """Control steps/s of one simulator replaying the trot's targets (open loop), nothing else."""
    sim = make_backend(name)
    s0 = initial_state(CollectConfig(), 0)
    sim.reset(s0)
    trot = Trot()
    actions = [trot(s0, k * sim.config.control_dt) for k in range(steps)]
    if name == "mujoco":
        m, d = sim.model, sim.data
        n = sim.config.substeps
        t = time.perf_counter()
        for a in actions:
            d.ctrl[:] = a
            mujoco.mj_step(m, d, nstep=n)
        return steps / (time.perf_counter() - t)
    t = time.perf_counter()
    for a in actions:  # the PD law per physics step + stepSimulation: the minimum PyBullet needs
        sim._advance(np.broadcast_to(a, (sim.config.substeps, len(a))))
    return steps / (time.perf_counter() - t)


def collect_rate(cfg: CollectConfig, workers: int, root: Path) -> tuple[float, float]:
    """(paired control steps/s, wall seconds) of record() into a fresh dataset."""
    from acn.datasets.record import record

    frames = 0

    def count(ep) -> None:
        nonlocal frames
        frames += len(ep)

    t = time.perf_counter()
    record(cfg, root / f"w{workers}", workers=workers, on_episode=count)
    wall = time.perf_counter() - t
    return frames / wall, wall


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=12)
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args()
    raw = {name: raw_rate(name, 1000) for name in ("pybullet", "mujoco")}
    serial = 1.0 / (1.0 / raw["pybullet"] + 1.0 / raw["mujoco"])
    cfg = CollectConfig(target="mujoco", policy="trot", episodes=args.episodes, seconds=args.seconds)
    with tempfile.TemporaryDirectory() as tmp:
        record(CollectConfig(target="mujoco", episodes=1, seconds=0.1), Path(tmp) / "warmup")
        rate1, wall1 = collect_rate(cfg, 1, Path(tmp))
        _, wall2 = collect_rate(cfg, 2, Path(tmp))
    print(f"raw_pybullet_steps_per_s={raw['pybullet']:.0f}")
    print(f"raw_mujoco_steps_per_s={raw['mujoco']:.0f}")
    print(f"raw_paired_steps_per_s={serial:.0f}")
    print(f"collector_steps_per_s={rate1:.0f}")
    print(f"paired_ratio={rate1 / serial:.3f}")
    print(f"workers_1_wall_s={wall1:.2f}")
    print(f"workers_2_wall_s={wall2:.2f}")
    print(f"workers_speedup={wall1 / wall2:.3f}")


if __name__ == "__main__":
    main()
