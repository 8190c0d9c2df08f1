"""What the diagnosis tests and ``benchmarks/diagnose_scenarios.py`` share: a small diagnosis
configuration, measurements recorded by acn-collect with hidden effects, noisy logs written by
code outside acn-collect (``robot_log``) and imported with acn-import, and the tolerance a
fitted parameter is held to."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from robot_log import LogSpec, write_log

from acn.measurements.data import load_measurements
from acn.diagnosis import DiagnoseConfig
from acn.sim.collector import CollectConfig
from acn.sim.effects import AppliedEffect, get_effect

# Small and quick: a few hundred rows, a few hundred re-simulated per stage.
# Small sizes; no time bound on the search, so a busy machine gives the same answer as an idle one
FAST = DiagnoseConfig(horizons=(1, 5), compare_rows=300, rollout_starts=30, rank_rows=100, judge_rows=300,
                      fit_rows=200, rank_iterations=2, auto_seconds=None)


def measured(tmp_path, hidden: dict, policy: str = "excite", source: str = "mujoco", seconds: float = 3.0,
             episodes: int = 2, seed: int = 0):
    """Measurements recorded by acn-collect with hidden effects, read back through LeRobotDataset."""
    from acn.datasets.record import record

    effects = [AppliedEffect(get_effect(n), get_effect(n).parse(v)) for n, v in hidden.items()]
    cfg = CollectConfig(source=source, target=None, policy=policy, episodes=episodes, seconds=seconds, seed=seed,
                        hidden_effects=effects)
    path = record(cfg, tmp_path / "measured")
    return load_measurements(path)


def close(fitted, true, rel: float = 0.2) -> bool:
    """Within ``rel`` of the truth; a per-joint parameter as a vector (its norm)."""
    fitted, true = np.atleast_1d(np.asarray(fitted, float)), np.atleast_1d(np.asarray(true, float))
    true = np.broadcast_to(true, fitted.shape)
    return bool(np.linalg.norm(fitted - true) <= rel * np.linalg.norm(true))


def _springs(spec) -> None:
    for j in spec.joints:
        if j.name != "root":
            j.stiffness[0] = 3.0


def _friction(spec) -> None:
    for j in spec.joints:
        if j.name != "root":
            j.frictionloss = 0.3


# Logs of another controller (random smooth joint targets) with the typical sensor noise: no effect,
# a 15 ms latency, joint springs (in no candidate of the catalogue), joint friction 0.3 N m.
NOISY_LOGS = {"nominal": LogSpec(noise=1.0, seed=1),
              "latency": LogSpec(noise=1.0, seed=3, latency_steps=15),
              "springs": LogSpec(noise=1.0, seed=2, spec_edit=_springs),
              "friction": LogSpec(noise=1.0, seed=4, seconds=10.0, episodes=4, spec_edit=_friction)}


def noisy_log(root: Path, name: str) -> Path:
    """The ``NOISY_LOGS`` log ``name`` written under ``root`` and imported with acn-import (50 Hz, kp 60,
    kd 1.5, torque limit 33.5); a dataset already imported there is reused."""
    from acn.measurements.importer import ImportConfig, import_log

    out = Path(root) / name
    if not (out / "meta" / "info.json").is_file():
        write_log(Path(root) / f"{name}.csv", NOISY_LOGS[name])
        out, _ = import_log(Path(root) / f"{name}.csv", out, ImportConfig(50, 60.0, 1.5, 33.5))
    return out
