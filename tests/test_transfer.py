"""acn-transfer: the whole study on tiny sizes (its files, the table's rows, the sealed answer never
printed), the table's arithmetic, bad input.

Real MuJoCo, lerobot, acn-diagnose, acn-fit and stable-baselines3, every stage the toolkit's own
command; the sizes check the plumbing, not the result (the study's numbers: README, make transfer).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from acn.cli import transfer_main
from acn.transfer import ROUTES, TransferTable
from acn.transfer.table import share_closed

TINY = ["--timesteps", "256", "--episodes", "2", "--seconds", "0.6", "--measure-episodes", "2", "--measure-seconds", "2",
        "--fit-epochs", "2", "--fit-rounds", "0", "--effects", "joint_damping", "--envs", "1"]


# Thirteen commands, each a new process whose imports (torch, lerobot, the simulators) take seconds:
# about 3 minutes on 2 idle cores, more beside other tests.
@pytest.mark.timeout(900)
def test_the_whole_study_runs_on_tiny_sizes_and_never_prints_the_sealed_robot(tmp_path, capsys):
    out = tmp_path / "study"
    # The robot's latency is outside the diagnosis' candidates (TINY: --effects joint_damping), so no
    # stage can print its value by finding it.
    rc = transfer_main(["--robot", "mujoco", "--sim", "mujoco", "--hidden-effect", "actuator_latency:seconds=0.0123457",
                        "--out", str(out), *TINY])
    printed = capsys.readouterr()
    assert rc == 0, printed.err
    study = json.loads((out / "transfer.json").read_text())
    rows = study["table"]["rows"]
    assert [r["route"] for r in rows] == [r.key for r in ROUTES]
    assert all(r["episodes"] == 2 and np.isfinite(r["on_robot"]["mean"]) for r in rows)
    assert [r["share_closed"] is None for r in rows] == [True, False, False, False, True]
    for r in rows:  # the terms of the training reward add up to the return: the table can say which term moved
        assert sum(r["terms_on_robot"].values()) == pytest.approx(r["on_robot"]["mean"], rel=1e-6, abs=1e-6)
    assert len(study["table"]["by_term"]) == 4
    assert study["table"]["verdict"] in printed.out and "pi_M + F_M" in printed.out
    assert [s.split(".")[0] for s in study["stages_seconds"]] == ["1", "2", "3", "4", "5"]
    for path in ("physics/model.json", "physics/diagnosis.json", "correctors/F/model.safetensors",
                 "correctors/F_M/model.safetensors", "policies/sim/policy/model.safetensors",
                 "policies/model/policy/config.json", "policies/robot/policy/config.json", "evaluations/sim.json",
                 "evaluations/model.json", "evaluations/robot.json", "measurements/excite/meta/info.json",
                 "measurements/trot/meta/info.json", "measurements/trot_model/meta/info.json"):
        assert (out / path).is_file(), path
    assert (out / "transfer.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # every policy was evaluated on the same starts; each in its own model (pi_robot's own model is the robot)
    evals = {k: json.loads((out / "evaluations" / f"{k}.json").read_text()) for k in ("sim", "model", "robot")}
    assert len({e["seed"] for e in evals.values()}) == 1
    assert evals["robot"]["models"] == {"sim": "mujoco + sealed effects", "robot": "mujoco + sealed effects"}
    assert evals["sim"]["models"]["sim"] == "mujoco"
    # the sealed robot: simulated by every stage, its value printed by none and written into no log
    logs = "".join(p.read_text() for p in (out / "logs").iterdir())
    for shown in ("0.0123457", "0.01235", "12.35"):  # as given, as a model describes it, in ms
        assert shown not in printed.out + printed.err + logs, shown
    # a second study over it needs --overwrite, and replaces only what the toolkit wrote
    assert transfer_main(["--robot", "mujoco", "--sim", "mujoco", "--out", str(out), *TINY]) == 2
    assert "--overwrite" in capsys.readouterr().err


def _evaluation(returns: dict[str, list[float]], ends: dict[str, list[str]] | None = None) -> dict:
    n = len(next(iter(returns.values())))
    ends = ends or {k: ["time_limit"] * n for k in returns}
    return {"training_returns": returns, "returns": returns, "episode_ends": ends,
            "episode_forward_speed": {k: [0.5] * n for k in returns}}


def test_the_table_measures_each_route_against_the_gap_from_pi_sim_to_pi_robot():
    rng = np.random.default_rng(0)
    n = 40
    base = 100 + rng.normal(0, 5, n)            # pi_sim on the robot
    bound = base + 20 + rng.normal(0, 1, n)     # pi_robot: 20 better, same starts
    half = base + 10 + rng.normal(0, 1, n)      # pi_M: half the gap
    table = TransferTable.from_evaluations({
        "sim": _evaluation({"sim": list(base + 30), "robot": list(base), "robot_corrected": list(base + 0.1)}),
        "model": _evaluation({"sim": list(half + 5), "robot": list(half), "robot_corrected": list(half - 5)}),
        "robot": _evaluation({"sim": list(bound), "robot": list(bound)},
                             {"sim": ["time_limit"] * n, "robot": ["fell"] + ["time_limit"] * (n - 1)}),
    })
    assert table.row("pi_M").share_closed.mean == pytest.approx(0.5, abs=0.02)
    assert table.row("pi_sim").transfer_gap.mean == pytest.approx(-30)
    assert table.row("pi_robot").falls == 1 and table.gap.mean == pytest.approx(20, abs=0.5)
    assert table.verdict.startswith("pi_M closes the most") and "train in the model the diagnosis identified" in table.verdict
    # a corrector that adds nothing measurable on top: both named, the simpler one advised
    tied = TransferTable.from_evaluations({
        "sim": _evaluation({"sim": list(base + 30), "robot": list(base), "robot_corrected": list(base + 0.1)}),
        "model": _evaluation({"sim": list(half + 5), "robot": list(half), "robot_corrected": list(half + 0.1)}),
        "robot": _evaluation({"sim": list(bound), "robot": list(bound)}),
    })
    assert tied.verdict.startswith("pi_M and pi_M + F_M close about as much")
    assert tied.verdict.endswith("train in the model the diagnosis identified.")
    # the ratio's standard error: from the per-episode scatter of the differences
    s = share_closed(half, base, bound)
    assert 0 < s.se < 0.05
    # no gap to close: the verdict says so instead of ranking routes
    same = TransferTable.from_evaluations({
        "sim": _evaluation({"sim": list(base), "robot": list(base), "robot_corrected": list(base)}),
        "model": _evaluation({"sim": list(base), "robot": list(base), "robot_corrected": list(base)}),
        "robot": _evaluation({"sim": list(base), "robot": list(base + rng.normal(0, 0.1, n))}),
    })
    assert "no policy-level gap" in same.verdict


@pytest.mark.parametrize("args, message", [
    (["--robot", "pybullet", "--sim", "mujoco"], "must be a MuJoCo model"),
    (["--robot", "ROBOT_MODEL", "--sim", "mujoco", "--hidden-effect", "joint_damping"], "from a plain simulator"),
    (["--robot", "mujoco", "--sim", "mujoco", "--hidden-effect", "warp"], "unknown effect"),
    (["--robot", "mujoco", "--sim", "mujoco", "--finest", "atom"], "--finest must be one of"),
])
def test_bad_input_is_one_line_and_exit_2_before_any_work(tmp_path, capsys, args, message):
    model = tmp_path / "model.json"
    model.write_text(json.dumps({"backend": "mujoco", "effects": [{"name": "joint_damping", "params": {"value": 0.3}}]}))
    out = tmp_path / "study"
    rc = transfer_main([a.replace("ROBOT_MODEL", str(model)) for a in args] + ["--out", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and message in err[0] and err[0].startswith("acn-transfer: error:"), err
    assert not out.exists()
