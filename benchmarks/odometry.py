"""How well leg odometry recovers the trunk's height and velocity of logs without motion capture.

Each dataset is read twice: as recorded, and with its trunk position and linear velocity left
out, which ``fill_derived`` then estimates (``acn.measurements.odometry``). Prints, over the rows
where the robot stands (trunk above 0.15 m, after its first 10 control steps), the median and
90th percentile of the height error (mm) and of the velocity error's norm (m/s), against the
velocity's spread, as ``name=value`` lines:

- acn-collect trot, both simulators (2 episodes x 6 s, contact flags);
- ``tests/robot_log.py`` logs (random smooth joint targets and a pace-like gait, whose feet
  scrape along the ground; 4 episodes x 10 s), without and with typical sensor noise.

``--raw`` turns the smoother off (the per-sample leg estimates alone). ``--accelerometer sensor``
writes the logs' accelerometer as MuJoCo's sensor, read at each row's instant
(``robot_log.LogSpec.accelerometer``), and imports them with ``--imu-acc instant``.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

os.environ.setdefault("HF_HUB_OFFLINE", "1")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from robot_log import LogSpec, write_log  # noqa: E402

import acn.measurements.odometry as odometry  # noqa: E402
from acn.measurements.importer import ImportConfig, import_log  # noqa: E402
from acn.measurements.data import Measurements, fill_derived, load_measurements  # noqa: E402
from acn.sim.state import GROUPS, SLICES  # noqa: E402

NO_MOCAP = list(GROUPS["base_pos"] + GROUPS["base_linvel"])


def blind(m: Measurements) -> Measurements:
    """``m`` without the trunk's position and linear velocity."""
    out = Measurements(m.state.copy(), m.action, m.next_state.copy(), m.effort, m.episode, m.frame, m.control,
                       m.info, m.description, sorted(set(m.missing) | set(NO_MOCAP)))
    for s in (out.state, out.next_state):
        s[:, SLICES["base_pos"]] = np.nan
        s[:, SLICES["base_linvel"]] = np.nan
    return out


def report(name: str, m: Measurements) -> None:
    est, _ = fill_derived(blind(m))
    standing = (m.state[:, 2] > 0.15) & (m.frame >= 10)
    z = np.abs(est.state[standing, 2] - m.state[standing, 2]) * 1e3
    lin = SLICES["base_linvel"]
    v = np.linalg.norm(est.state[standing, lin] - m.state[standing, lin], axis=1)
    spread = np.linalg.norm(m.state[standing, lin].std(0))
    print(f"{name}_standing_share={standing.mean():.2f}")
    print(f"{name}_height_error_mm={np.median(z):.1f}/{np.percentile(z, 90):.1f}")
    print(f"{name}_velocity_error={np.median(v):.3f}/{np.percentile(v, 90):.3f}")
    print(f"{name}_velocity_spread={spread:.3f}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--raw", action="store_true", help="no smoother: the per-sample leg estimates alone")
    ap.add_argument("--accelerometer", choices=("mean", "sensor"), default="mean",
                    help="the logs' accelerometer: the mean over the control step, or MuJoCo's sensor (an instant)")
    args = ap.parse_args()
    if args.raw:
        odometry.smooth_velocity = lambda legs, change, dt, spread=None: legs.copy()
    from acn.datasets.record import record
    from acn.sim.collector import CollectConfig

    root = Path(tempfile.mkdtemp())
    for source in ("mujoco", "pybullet"):
        path = record(CollectConfig(source=source, target=None, policy="trot", episodes=2, seconds=6.0, seed=3),
                      root / f"trot_{source}")
        report(f"trot_{source}", load_measurements(path))
    for noise in (0.0, 1.0):
        for controller, seed in (("sines", 101), ("pace", 109)):
            name = f"log_{controller}_noise{noise:g}"
            write_log(root / f"{name}.csv", LogSpec(seconds=10, episodes=4, seed=seed, noise=noise,
                                                    controller=controller, accelerometer=args.accelerometer))
            imu_acc = "instant" if args.accelerometer == "sensor" else "mean"
            path, _ = import_log(root / f"{name}.csv", root / name, ImportConfig(50, 60.0, 1.5, 33.5, imu_acc=imu_acc))
            report(name, load_measurements(path))


if __name__ == "__main__":
    main()
