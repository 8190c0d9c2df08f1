"""How long the whole diagnosis takes on 50k measured frames, and how much of it is simulation.

Collects 50k frames (MuJoCo, the excitation policy, a hidden 12 ms actuator latency) once,
then times ``diagnose`` (compare, rank every catalogue effect, fit and add the top one) with
the default configuration on 2 CPU cores. Prints ``name=value`` lines:

- ``diagnose_seconds``: wall time of compare + rank + add (target <= 60 on 2 cores);
- ``simulate_share``: share of it spent in batch re-simulation (``Resimulator.run``);
- ``stage_seconds``: compare (with the breakdown), rank, add;
- ``load_seconds``: reading the dataset through LeRobotDataset (not in diagnose_seconds);
- ``found`` / ``latency_ms``: what it found (the answer is 12 ms).
"""

from __future__ import annotations

import argparse
import cProfile
import os
import pstats
import tempfile
import time
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")

from acn.measurements.data import load_measurements  # noqa: E402
from acn.datasets.record import record  # noqa: E402
from acn.diagnosis import DiagnoseConfig, diagnose  # noqa: E402
from acn.sim.backends import SimConfig  # noqa: E402
from acn.sim.collector import CollectConfig  # noqa: E402
from acn.sim.effects import Model, get_effect  # noqa: E402
from acn.sim.effects.effect import AppliedEffect  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=50_000)
    ap.add_argument("--data", type=Path, default=None, help="reuse (or create) the dataset here")
    args = ap.parse_args()
    episodes = max(1, -(-args.frames * 105 // 100) // 500)  # 10 s episodes; a few end early on a fall
    root = args.data or Path(tempfile.mkdtemp()) / "bench_latency"
    if not root.exists():
        latency = AppliedEffect(get_effect("actuator_latency"), {"seconds": 0.012})
        cfg = CollectConfig(source="mujoco", target=None, policy="excite", episodes=episodes, seconds=10.0, seed=11,
                            sim=SimConfig(), hidden_effects=[latency])
        t = time.perf_counter()
        record(cfg, root, workers=2)
        print(f"collect_seconds={time.perf_counter() - t:.1f}")
    t = time.perf_counter()
    data = load_measurements(root)
    print(f"load_seconds={time.perf_counter() - t:.2f}")
    print(f"frames={len(data)}")
    profile = cProfile.Profile()
    t = time.perf_counter()
    profile.enable()
    # rank all, add the top (no second start: --auto's runner-up chain is timed by diagnose_cases.py)
    d = diagnose(data, Model.parse("mujoco"), DiagnoseConfig(auto_max=1, auto_alternatives=0), automatic=True)
    profile.disable()
    total = time.perf_counter() - t
    stats = pstats.Stats(profile)
    simulate = sum(v[3] for k, v in stats.stats.items() if k[2] == "run" and k[0].endswith("resim.py"))
    print(f"diagnose_seconds={total:.1f}")
    print(f"simulate_share={simulate / total:.2f}")
    print(f"stage_seconds=compare {d.seconds['compare']:.1f}, rank {d.seconds['rank']:.1f}, add {d.seconds['add']:.1f}")
    print(f"verdict={d.verdict}")
    print(f"found={d.ranking[0].name}")
    if d.added and d.added[0].name == "actuator_latency":
        print(f"latency_ms={1000 * float(d.added[0].fit.values['seconds']):.2f}")
    print(f"headline_before={d.before.headline:.4f}")
    print(f"headline_after={d.final.headline:.4f}")


if __name__ == "__main__":
    main()
