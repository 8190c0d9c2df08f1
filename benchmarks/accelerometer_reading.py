"""How well the diagnosis tells an accelerometer read at each instant from the schema's mean.

Every log of ``benchmarks/diagnose_cases.py`` (the first set at typical sensor noise, the
``--other`` set at twice typical; 4 x 10 s, the same seeds) is written twice, with the schema's
mean reading and with MuJoCo's sensor (an instant), imported without ``--imu-acc`` and judged
under the nominal model (``acn.diagnosis.accelerometer.read_accelerometer``): first by
integrating the accelerometer against the trunk's velocity (the logged one; with ``--no-mocap``
the legs'), else by the model. One line per log, and ``name=value`` totals:

- ``integration_decided``: logs the integration decided, of all;
- ``integration_wrong``: of those, decided wrongly;
- ``read_right``: logs read as they were written, by either judgement;
- ``sensor_read_right``: of the logs written with the sensor, read as instant.

Each log takes 5-15 s on 2 cores (the whole run, 52 logs, about 10 minutes).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("HF_HUB_OFFLINE", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parent))

import diagnose_cases as cases  # noqa: E402
from robot_log import write_log  # noqa: E402

from acn.measurements.importer import import_log  # noqa: E402
from acn.measurements.data import load_measurements  # noqa: E402
from acn.diagnosis import DiagnoseConfig  # noqa: E402
from acn.diagnosis.accelerometer import read_accelerometer  # noqa: E402
from acn.diagnosis.problem import prepare  # noqa: E402
from acn.sim.effects import Model  # noqa: E402

SETS = {"first": (cases.CASES, 100, 1.0), "other": (cases.OTHER, 700, 2.0)}  # cases, first seed, noise


def recording(no_mocap: bool, accelerometer: str, noise: float) -> argparse.Namespace:
    """The recording options ``diagnose_cases.log_spec`` and ``import_config`` read: that
    benchmark's own command line, defaults and all."""
    return cases.parser().parse_args(["--noise", str(noise), "--accelerometer", accelerometer]
                                     + (["--no-mocap"] if no_mocap else []))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="first,other", help="comma-separated: first, other")
    ap.add_argument("--no-mocap", action="store_true", help="logs without the trunk's position and linear velocity")
    ap.add_argument("--cases", default=None, help="comma-separated case names (default: every case of the sets)")
    args = ap.parse_args()
    unknown = [s for s in args.sets.split(",") if s not in SETS]
    if unknown:
        ap.error(f"no set {unknown[0]!r}; the sets: {', '.join(SETS)}")
    root, model, cfg = Path(tempfile.mkdtemp()), Model.parse("mujoco"), DiagnoseConfig()
    decided = wrong = right = sensor_right = sensor = total = 0
    for set_name in args.sets.split(","):
        logs, seed, noise = SETS[set_name]
        for i, (name, (over, *_)) in enumerate(logs.items()):
            if args.cases and name not in args.cases.split(","):
                continue
            for written, truth in (("mean", "mean"), ("sensor", "instant")):
                rec = recording(args.no_mocap, written, noise)
                stem = root / f"{set_name}{i}{written}"
                write_log(stem.with_suffix(".csv"), cases.log_spec(rec, seed + i, over))
                path, _ = import_log(stem.with_suffix(".csv"), stem, cases.import_config(rec))
                problem = prepare(load_measurements(path), model, cfg)
                read = read_accelerometer(problem, model, problem.sample(problem.held_rows, cfg.judge_rows, salt=4))
                test = read.integration
                total += 1
                right += read.kind == truth
                sensor += truth == "instant"
                sensor_right += truth == "instant" and read.kind == truth
                line = f"{name:18s} written={written:6s} read={read.kind:7s}"
                if test is not None:
                    line += f" gamma={test.gamma:.3f} stderr={test.stderr:.3f} velocity={test.velocity}"
                if not read.by_model:
                    decided += 1
                    wrong += read.kind != truth
                    line += " by=integration"
                elif read.share is not None:
                    line += f" by=model instant_share={read.share:.3f} instant_better={read.better:.3f}"
                else:
                    line += " by=model (too few rows to compare)"
                print(line, flush=True)
    print(f"integration_decided={decided}/{total}")
    print(f"integration_wrong={wrong}/{decided}")
    print(f"read_right={right}/{total}")
    print(f"sensor_read_right={sensor_right}/{sensor}")


if __name__ == "__main__":
    main()
