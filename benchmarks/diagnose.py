"""How long ``acn-diagnose --auto`` takes per log, stage by stage, and on 50k frames.

Per log: fresh draws of ``benchmarks/diagnose_cases.py`` (``draw``: two hidden effects at
realistic values on the sines or pace controller, typical sensor noise), each a robot log of 4
episodes x 8 s at 50 Hz (about 1,600 rows) written by ``tests/robot_log.py``, imported with
acn-import and diagnosed with the default configuration (``--auto``) on the CPUs given (2 by
default). Then 50k frames of acn-collect (MuJoCo, the excitation policy, a hidden 12 ms actuator
latency), diagnosed the same way. Prints one line per log (what it found, its time and stages)
and ``name=value`` lines:

- ``per_log_seconds_median`` / ``per_log_seconds_max``: wall time of the diagnosis per log
  (target <= 60 on 2 cores);
- ``reference_seconds``: one re-simulation of 10,000 rows by one control step in the same run, the
  machine's speed; ``per_log_over_reference_median``: the median per-log time in those units
  (comparable between machines and loads);
- ``frames_50k_seconds``: the 50k-frame diagnosis (target <= 180 on 2 cores), with its stages,
  ``found`` and ``latency_ms`` (the answer is 12 ms).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("HF_HUB_OFFLINE", "1")
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

import diagnose_cases  # noqa: E402
from robot_log import write_log  # noqa: E402

from acn.datasets.record import record  # noqa: E402
from acn.diagnosis import DiagnoseConfig, diagnose  # noqa: E402
from acn.diagnosis.problem import prepare  # noqa: E402
from acn.measurements.data import load_measurements  # noqa: E402
from acn.measurements.importer import import_log  # noqa: E402
from acn.sim.backends import SimConfig  # noqa: E402
from acn.sim.collector import CollectConfig  # noqa: E402
from acn.sim.effects import Model, get_effect  # noqa: E402
from acn.sim.effects.effect import AppliedEffect  # noqa: E402


def reference_seconds(data) -> float:
    """One re-simulation of 10,000 rows (drawn with repeats) by one control step under the nominal model."""
    model = Model.parse("mujoco")
    problem = prepare(data, model, DiagnoseConfig())
    rows = np.resize(problem.fit_rows, 10_000)
    t = time.perf_counter()
    problem.residual_of(model.sim_config(problem.control), rows)
    return time.perf_counter() - t


def timed(data) -> tuple[float, object]:
    t = time.perf_counter()
    d = diagnose(data, Model.parse("mujoco"), DiagnoseConfig(), automatic=True)
    return time.perf_counter() - t, d


def described(d) -> str:
    found = " + ".join(f"{a.name}({', '.join(f'{k}={float(np.mean(v)):.4g}' for k, v in a.fit.values.items())})"
                       for a in d.added) or "-"
    stages = ", ".join(f"{k} {v:.0f}" for k, v in d.stages.items())
    return f"verdict={d.verdict} found={found} stages: {stages}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=diagnose_cases._draws, default=(0, 4), metavar="K0:K1",
                    help="the draws of diagnose_cases.draw timed (seeds --seed0 + k)")
    ap.add_argument("--seed0", type=int, default=5500)
    ap.add_argument("--one-joint", action="store_true", help="a joint effect of each draw on one joint alone")
    ap.add_argument("--frames", type=int, default=50_000, help="frames of the long run (0: skip it)")
    ap.add_argument("--data", type=Path, default=None, help="reuse (or create) the 50k-frame dataset here")
    args = ap.parse_args()
    root = Path(tempfile.mkdtemp())
    logs = diagnose_cases.parser().parse_args(["--seconds", "8", "--episodes", "4"])
    seconds, reference = [], None
    for k in range(*args.draws):
        name, over, truth = diagnose_cases.draw(args.seed0 + k, args.one_joint)
        write_log(root / f"d{k}.csv", diagnose_cases.log_spec(logs, args.seed0 + k, over))
        path, _ = import_log(root / f"d{k}.csv", root / f"d{k}", diagnose_cases.import_config(logs))
        data = load_measurements(path)
        reference = reference if reference is not None else reference_seconds(data)
        took, d = timed(data)
        seconds.append(took)
        truth_text = ", ".join(f"{e}.{p}={v:.4g}{'@' + j if j else ''}" for e, p, v, j in truth)
        print(f"d{k} ({len(data)} rows; {truth_text}): {took:.0f} s {described(d)}", flush=True)
    if seconds:
        print(f"per_log_seconds_median={np.median(seconds):.1f}")
        print(f"per_log_seconds_max={np.max(seconds):.1f}")
        print(f"reference_seconds={reference:.2f}")
        print(f"per_log_over_reference_median={np.median(seconds) / reference:.0f}")
    if not args.frames:
        return
    episodes = max(1, -(-args.frames * 105 // 100) // 500)  # 10 s episodes; a few end early on a fall
    long_root = args.data or root / "bench_latency"
    if not long_root.exists():
        latency = AppliedEffect(get_effect("actuator_latency"), {"seconds": 0.012})
        cfg = CollectConfig(source="mujoco", target=None, policy="excite", episodes=episodes, seconds=10.0, seed=11,
                            sim=SimConfig(), hidden_effects=[latency])
        t = time.perf_counter()
        record(cfg, long_root, workers=2)
        print(f"collect_seconds={time.perf_counter() - t:.1f}")
    data = load_measurements(long_root)
    took, d = timed(data)
    print(f"frames={len(data)}")
    print(f"frames_50k_seconds={took:.1f}")
    print(f"frames_50k_stages={described(d)}")
    print(f"found={'+'.join(a.name for a in d.added) or '-'}")
    latency = next((a for a in d.added if a.name == "actuator_latency"), None)
    if latency is not None:
        print(f"latency_ms={1000 * float(latency.fit.values['seconds']):.2f}")


if __name__ == "__main__":
    main()
