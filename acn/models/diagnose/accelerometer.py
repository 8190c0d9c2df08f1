"""Does the logged accelerometer read the mean over the control step, or one instant?

The schema's ``imu_acc`` is the trunk's MEAN specific force over the control step before the row
(what ``acn-collect`` writes: ``SimConfig.imu_acc`` "mean"). A sensor read at the row's INSTANT
reads the last moment instead: MuJoCo's ``accelerometer`` sensor (the last physics step), an IMU
the control loop samples without averaging over the period. While a foot lands the two differ by
several m/s^2 (12 m/s^2 for a 3 cm drop, ``tests/test_backends.py``), so a model compared with
the wrong reading leaves a structured accelerometer error that no physical effect explains
(stop 42: a noise-free log written with MuJoCo's sensor came out ``unexplained`` under the true
model, ``imu_acc`` 25 times the median group's error).

``read_accelerometer`` re-simulates the model's one step from the judging rows with both
readings and keeps "instant" where it predicts the accelerometer better overall (lower mean
squared error) and in clearly more rows than not (a sign test, ``INSTANT_Z``); otherwise the
schema's mean, also where sensor noise hides the difference (then either reading predicts as
well). Row by row, not by a paired z of the errors: the difference sits in the rows where a foot
lands, and a gait with few landings (a pace that tips over) had the instant reading's error at
0.7 % of the mean one's with a paired z of 3.2. Measured on ``tests/robot_log.py`` logs (sines
and pace, 2 x 4 s, 300 rows, nominal model): with MuJoCo's sensor the instant reading is better
in 99-100 % of the rows noise-free and 78-81 % with typical to twice typical sensor noise
(mean squared error 0.1-84 % of the mean reading's); with the schema's mean it is better in 0 %
noise-free and 25-33 % with noise (230-2,800 %). A dataset that states its reading
(``acn-import --imu-acc``, ``acn-collect``) is taken at its word.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from acn.models.diagnose.problem import Problem
from acn.toolkit.effects import Model

INSTANT_Z = 5.0  # the instant reading must be better in this many binomial standard errors more than half the rows


@dataclass
class Accelerometer:
    """How the diagnosis reads the logged accelerometer."""

    kind: str                     # "mean" (over the control step) or "instant" (``SimConfig.imu_acc``)
    stated: bool                  # the dataset says so; else judged here
    share: float | None = None    # judged: the instant reading's accelerometer MSE / the mean one's
    better: float | None = None   # judged: share of the rows whose accelerometer the instant reading predicts better

    def describe(self) -> str:
        """One line for the report ("" where it is the schema's mean)."""
        if self.stated:
            return "" if self.kind == "mean" else \
                "the accelerometer is read at each row's instant (as the dataset states)"
        if self.kind == "instant":
            return (f"the accelerometer reads like a sensor sampled at each row's instant, not the mean over the "
                    f"control step (read so, the model predicts it better in {self.better:.0%} of the rows, with "
                    f"{self.share:.0%} of the mean squared error): compared so; acn-import --imu-acc instant states it")
        return ""

    def to_json(self) -> dict:
        return {"kind": self.kind, "stated": self.stated, "instant_share": self.share, "instant_better": self.better}


def read_accelerometer(problem: Problem, model: Model, rows: np.ndarray) -> Accelerometer:
    """How to read ``problem``'s accelerometer (module docstring), judged on ``rows`` under ``model``."""
    stated = problem.data.info.get("imu_acc")
    if stated in ("mean", "instant"):
        return Accelerometer(stated, stated=True)
    columns = np.flatnonzero(np.array(problem.group_of_channel()) == "imu_acc")
    if not len(columns) or len(rows) < 8 or problem.control.substeps < 2:
        return Accelerometer("mean", stated=False)  # not compared, or one physics step per control step: the same
    config = model.sim_config(problem.control)
    err = {}
    for kind in ("mean", "instant"):
        with np.errstate(over="ignore", invalid="ignore"):
            r = problem.residual_of(replace(config, imu_acc=kind), rows)[:, columns]
        err[kind] = np.mean(r ** 2, axis=1)
    fine = np.isfinite(err["mean"]) & np.isfinite(err["instant"])
    if fine.sum() < 8 or err["mean"][fine].mean() <= 0:
        return Accelerometer("mean", stated=False)
    share = float(err["instant"][fine].mean() / err["mean"][fine].mean())
    better = float(np.mean(err["instant"][fine] < err["mean"][fine]))
    clear = share < 1.0 and better >= 0.5 + INSTANT_Z * 0.5 / np.sqrt(fine.sum())
    return Accelerometer("instant" if clear else "mean", stated=False, share=share, better=better)
