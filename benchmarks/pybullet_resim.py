"""PyBullet re-simulation on worker processes against one process, printed as name=value lines.

The diagnosis with PyBullet as the model (``acn-diagnose --model pybullet``, the transfer study
in the paper's direction) spends its time in ``Resimulator.run``: rows re-simulated one at a time
in PyBullet, in chunks of ``PYBULLET_CHUNK_STEPS`` control steps each in a fresh simulator. The
batch here is a diagnosis' typical one: the same recorded rows under several models (a finite
difference per parameter), ``--steps`` control steps each.

pybullet_rows_per_s_one    rows/s, every chunk in this process (threads=1)
pybullet_rows_per_s_pool   rows/s, the chunks on worker processes (threads = usable CPUs)
pybullet_pool_speedup      pool / one (same run, best of --repeats; the results are equal bit for bit)
workers                    worker processes used

Usage: python benchmarks/pybullet_resim.py [--rows 150] [--models 6] [--steps 1] [--repeats 3]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from acn.sim.backends import SimConfig
from acn.sim.collector import CollectConfig, collect_episodes
from acn.sim.cpus import usable_cpus
from acn.sim.resim import Resimulator


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=150, help="recorded rows per model (the diagnosis' screen)")
    ap.add_argument("--models", type=int, default=6)
    ap.add_argument("--steps", type=int, default=1, help="control steps per row")
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    cfg = CollectConfig(source="pybullet", policy="trot", episodes=2, seconds=args.rows / 50 + 1, seed=0)
    trace = [e.source for e in collect_episodes(cfg, [0, 1])]
    n = args.rows
    states = np.concatenate([t.state for t in trace])[:n]
    actions = np.concatenate([t.action for t in trace])
    steps = np.stack([actions[i:i + args.steps] for i in range(n)])
    states, steps = np.tile(states, (args.models, 1)), np.tile(steps, (args.models, 1, 1))
    model = np.repeat(np.arange(args.models), n)
    configs = [SimConfig()] * args.models
    workers = max(1, min(usable_cpus(), 8))
    best = {"one": np.inf, "pool": np.inf}
    results = {}
    for _ in range(args.repeats):  # interleaved: the machine is shared and noisy
        for name, threads in (("one", 1), ("pool", workers)):
            t0 = time.perf_counter()
            results[name] = Resimulator("pybullet", configs, threads=threads).run(states, steps, model=model)
            best[name] = min(best[name], time.perf_counter() - t0)
    assert np.array_equal(results["one"].state, results["pool"].state, equal_nan=True)
    rows = len(states)
    print(f"pybullet_rows_per_s_one={rows / best['one']:.0f}")
    print(f"pybullet_rows_per_s_pool={rows / best['pool']:.0f}")
    print(f"pybullet_pool_speedup={best['one'] / best['pool']:.2f}")
    print(f"workers={workers}")


if __name__ == "__main__":
    main()
