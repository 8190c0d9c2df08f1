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
readings and keeps "instant" where it at least halves the accelerometer's mean squared error
(``INSTANT_SHARE``) and predicts it better in clearly more rows than not (a sign test,
``INSTANT_Z``); otherwise the schema's mean, also where sensor noise hides the difference (then
either reading predicts as well). Row by row, not by a paired z of the errors: the difference
sits in the rows where a foot lands, and a gait with few landings (a pace that tips over) had
the instant reading's error at 0.7 % of the mean one's with a paired z of 3.2.

The judgement is only as good as the model: one far from the robot leaves accelerometer errors
that either reading may fit. On a log of MuJoCo Menagerie's A1 (joint damping 1-2, friction
0.2, armature 0.01, no derivative gain; noise-free) with the MEAN reading, the nominal model
read the instant one better in 60 % of the rows (73 % of the error); with the effects ``--auto``
added, in 0.7 % (45 times the error). So the diagnosis judges again under its final model when
it added effects, and runs again with the other reading where the two judgements differ
(``pipeline.diagnose``).

Measured on ``tests/robot_log.py`` logs (sines and pace, 2 x 4 s, 300 rows, nominal model):
with MuJoCo's sensor the instant reading is better in 99-100 % of the rows noise-free (0.1-0.7 %
of the error), 94 % with a hidden joint damping (39 %), and 78-81 % with typical to twice typical
sensor noise (47-84 %: read as the mean where above half, which noise makes as good); with the
schema's mean it is better in 0 % noise-free and 25-33 % with noise (230-2,800 %). A dataset
that states its reading (``acn-import --imu-acc``, ``acn-collect``) is taken at its word.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from acn.models.diagnose.problem import Problem
from acn.toolkit.backends import IMU_ACC_KINDS
from acn.toolkit.effects import Model

INSTANT_SHARE = 0.5  # the instant reading must leave at most this share of the mean one's accelerometer MSE ...
INSTANT_Z = 5.0      # ... and be better in this many binomial standard errors more than half the rows


@dataclass
class Accelerometer:
    """How the diagnosis reads the logged accelerometer."""

    kind: str                     # "mean" (over the control step) or "instant" (``SimConfig.imu_acc``)
    stated: bool                  # the dataset says so; else judged here
    share: float | None = None    # judged: the instant reading's accelerometer MSE / the mean one's
    better: float | None = None   # judged: share of the rows whose accelerometer the instant reading predicts better
    again: bool = False           # judged again under the model with the effects added (``pipeline.diagnose``)

    def describe(self) -> str:
        """One line for the report ("" where it is the schema's mean)."""
        if self.stated:
            return "" if self.kind == "mean" else \
                "the accelerometer is read at each row's instant (as the dataset states)"
        model = "the model with the effects added" if self.again else "the model"
        if self.kind == "instant":
            return (f"the accelerometer reads like a sensor sampled at each row's instant, not the mean over the "
                    f"control step (read so, {model} predicts it better in {self.better:.0%} of the rows, with "
                    f"{self.share:.0%} of the mean squared error): compared so; acn-import --imu-acc instant states it")
        if self.again:
            return (f"the accelerometer reads as the mean over the control step (the schema's) under the model with "
                    f"the effects added (read at each instant, {self.better:.0%} of the rows predicted better, "
                    f"{self.share:.0%} of the mean squared error): compared so; acn-import --imu-acc mean states it")
        return ""

    def to_json(self) -> dict:
        return {"kind": self.kind, "stated": self.stated, "instant_share": self.share, "instant_better": self.better,
                "judged_again": self.again}


def read_accelerometer(problem: Problem, model: Model, rows: np.ndarray) -> Accelerometer:
    """How to read ``problem``'s accelerometer (module docstring), judged on ``rows`` under ``model``."""
    stated = problem.data.info.get("imu_acc")
    if stated in IMU_ACC_KINDS:
        return Accelerometer(stated, stated=True)
    columns = np.flatnonzero(np.array(problem.group_of_channel()) == "imu_acc")
    if not len(columns) or len(rows) < 8 or problem.control.substeps < 2:
        return Accelerometer("mean", stated=False)  # not compared, or one physics step per control step: the same
    config = model.sim_config(problem.control)
    err = {}
    for kind in IMU_ACC_KINDS:
        with np.errstate(over="ignore", invalid="ignore"):
            r = problem.residual_of(replace(config, imu_acc=kind), rows)[:, columns]
        err[kind] = np.mean(r ** 2, axis=1)
    fine = np.isfinite(err["mean"]) & np.isfinite(err["instant"])
    if fine.sum() < 8 or err["mean"][fine].mean() <= 0:
        return Accelerometer("mean", stated=False)
    share = float(err["instant"][fine].mean() / err["mean"][fine].mean())
    better = float(np.mean(err["instant"][fine] < err["mean"][fine]))
    clear = share <= INSTANT_SHARE and better >= 0.5 + INSTANT_Z * 0.5 / np.sqrt(fine.sum())
    return Accelerometer("instant" if clear else "mean", stated=False, share=share, better=better)
