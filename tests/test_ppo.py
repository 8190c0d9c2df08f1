"""acn-ppo: the Gymnasium environments, the shareable policy, Algorithm 2 end to end, bad input.

Real PyBullet, MuJoCo, lerobot and stable-baselines3 on tiny sizes (1 s episodes, ~1k steps).
"""

from __future__ import annotations

import hashlib
import json
import shutil
import warnings

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

from acn.cli import ppo_main
from acn.datasets.record import record
from acn.corrector.config import FitConfig
from acn.corrector.fit import fit, save
from acn.sim.collector import CollectConfig, fallen
from acn.sim.envs import ENV_IDS, A1Env, EnvConfig
from acn.sim.reward import REWARD_WEIGHTS, weighted
from acn.sim.state import SLICES

# This module runs on one test process (`make test`'s -n 2): the tiny PPO run and its corrector are made once.
pytestmark = pytest.mark.xdist_group("ppo")

TINY = ["--seconds", "1", "--eval-seconds", "1", "--refit-seconds", "1", "--n-steps", "128", "--batch-size", "64",
        "--n-epochs", "4", "--refit-episodes", "3", "--fit-epochs", "2", "--checkpoint-every", "512",
        "--eval-episodes", "2", "--final-eval-episodes", "3"]


def sha256(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def corrector_dir(tmp_path_factory):
    """A tiny corrector from acn-fit's code (3 paired episodes of 1.2 s: fit needs >= 64 training rows,
    which the 2 x 1 s ``small_dataset`` cannot give after the validation split)."""
    root = tmp_path_factory.mktemp("ppo_data")
    data = record(CollectConfig(target="mujoco", policy="trot", episodes=3, seconds=1.2, seed=11), root / "paired")
    # No closed-loop rounds and one-step labels: what the test needs is a real corrector file, fast.
    model, metrics = fit([data], FitConfig(epochs=2, eval_episodes=0, rounds=0, label_iterations=1, label_broyden=0),
                         log=lambda s: None)
    return save(model, metrics, root / "corrector")


@pytest.fixture(scope="module")
def tiny_run(corrector_dir, tmp_path_factory):
    """1024 steps, then --resume to 1536; returns (run dir, policy tensors and metrics after part 1, the given
    corrector's file hash before training)."""
    out = tmp_path_factory.mktemp("ppo_run") / "run"
    before = sha256(corrector_dir / "model.safetensors")
    rc = ppo_main(["--timesteps", "1024", "--out", str(out), "--corrector", str(corrector_dir), "--refit-every", "10",
                   "--eval-every", "10", *TINY])
    assert rc == 0
    from safetensors.torch import load_file

    first = load_file(str(out / "policy" / "model.safetensors"))
    first_metrics = json.loads((out / "metrics.json").read_text())
    rc = ppo_main(["--timesteps", "1536", "--out", str(out), "--resume"])
    assert rc == 0
    return out, first, first_metrics, before


# ----- environments ---------------------------------------------------------------------------
@pytest.mark.parametrize("env_id", sorted(ENV_IDS.values()))
def test_environments_pass_the_gymnasium_checker(env_id):
    env = gym.make(env_id, seconds=0.3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the unbounded-Box notice for the state is expected
        check_env(env.unwrapped)
    obs, _ = env.reset(seed=1)
    assert obs.shape == (43,) and obs.dtype == np.float32 and env.action_space.shape == (12,)
    env.close()


def test_reward_time_limit_and_fall_rule():
    weights = (2.0, 0.001, 0.3, 0.01)
    env = A1Env("mujoco", EnvConfig(seconds=0.2, reward_weights=weights, alive_bonus=0.5))
    env.reset(seed=0)
    steps = 0
    while True:
        _, r, terminated, truncated, info = env.step(np.zeros(12))
        steps += 1
        terms = info["reward_terms"]
        assert r == pytest.approx(float(weighted(terms, weights)) + 0.5)
        assert info["paper_reward"] == pytest.approx(float(weighted(terms, REWARD_WEIGHTS)))
        if terminated or truncated:
            break
    assert truncated and not terminated and steps == 10  # 0.2 s at 50 Hz
    low = env.state.astype(np.float64)
    low[SLICES["base_pos"]][2] = 0.12  # below the fall height, lying on the ground
    env.reset(options={"state": low})
    _, r, terminated, truncated, info = env.step(np.zeros(12))
    assert terminated and not truncated and info["fallen"] and fallen(env.state)
    assert r == pytest.approx(float(weighted(info["reward_terms"], weights)))  # no bonus for a fall
    env.close()


def test_corrector_acts_in_the_environment_it_is_given_to(corrector_dir):
    from acn.corrector import Corrector

    corrector = Corrector.load(corrector_dir)
    plain, corrected = A1Env("mujoco", seconds=0.5), A1Env("mujoco", seconds=0.5, corrector=corrector)
    plain.reset(seed=3)
    corrected.reset(options={"state": plain.state})
    s = corrected.state
    u = np.full(12, 0.2, dtype=np.float32)
    a, b = plain.step(u)[4]["action"], corrected.step(u)[4]["action"]
    np.testing.assert_allclose(b, corrector.correct(s, a), rtol=1e-6)  # a~ = a + F(s, a)
    assert not np.allclose(a, b)
    plain.close()
    corrected.close()


# ----- the run ----------------------------------------------------------------------------
def test_tiny_run_trains_applies_a_frozen_corrector_and_writes_the_papers_metrics(tiny_run, corrector_dir):
    out, first, first_metrics, before = tiny_run
    m = json.loads((out / "metrics.json").read_text())
    for key in ("eps_transfer", "delta_corr"):
        assert set(m[key]) == {"mean", "mode", "expectation"} and all(np.isfinite(list(m[key].values())))
    assert m["training"]["timesteps"] >= 1536 and m["training"]["episodes"] > first_metrics["training"]["episodes"]
    # the corrector is applied (MuJoCo + F differs from MuJoCo) and stays frozen
    fin = m["final_evaluation"]
    assert fin["returns"]["robot_corrected"] != fin["returns"]["robot"] and len(fin["returns"]["sim"]) == 3
    assert fin["models"] == {"sim": "pybullet", "robot": "mujoco"} and len(fin["training_returns"]["robot"]) == 3
    assert m["corrector_frozen"] and all(c["digest"] == c["digest_at_retirement"] for c in m["correctors"])
    assert sha256(corrector_dir / "model.safetensors") == before
    from acn.rl.ppo import file_digest

    given = m["correctors"][0]
    assert given["source"].startswith("given") and file_digest(corrector_dir) == given["digest"]
    for c in m["correctors"]:
        assert file_digest(out / c["dir"]) == c["digest"]  # each file = the tensors used while it was in use
    refits = [c for c in m["correctors"] if c["source"] == "refit"]
    assert len(refits) >= 2 and (out / "corrector" / "model.safetensors").is_file()
    assert file_digest(out / "corrector") == m["correctors"][-1]["digest"]
    # the same-state oracle bound: an optional field, filled where acn.corrector.evaluate offers the oracle
    from acn.corrector import evaluate

    if hasattr(evaluate, "same_state_oracle"):
        o = m["same_state_oracle"]
        assert o["episodes"] == 3 and np.isfinite(o["eps_transfer"]["mean"])
    else:
        assert m["same_state_oracle"] is None
    # Algorithm 2's evaluations and the plot
    assert len(m["evaluations"]) >= 3 and all("robot_corrected" in e["returns"] for e in m["evaluations"])
    png = (out / "curves.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000
    # it trains: the policy after the resumed half differs from the one after the first half
    from safetensors.torch import load_file

    second = load_file(str(out / "policy" / "model.safetensors"))
    assert any(not torch.equal(first[k], second[k]) for k in first if k.startswith("net."))


def test_shared_policy_equals_the_sb3_actor_and_holds_no_pickle(tiny_run):
    from stable_baselines3 import PPO

    from acn.rl.policy_io import WalkingPolicy

    out = tiny_run[0]
    assert sorted(p.name for p in (out / "policy").iterdir()) == ["config.json", "model.safetensors"]
    policy = WalkingPolicy.load(out / "policy")
    model = PPO.load(out / "checkpoint" / "ppo.zip", device="cpu")
    norm = json.loads((out / "checkpoint" / "normalisation.json").read_text())["obs_rms"]
    rng = np.random.default_rng(0)
    env = A1Env("pybullet", seconds=0.5)
    states = np.stack([env.reset(seed=i)[0] for i in range(8)]) + rng.normal(0, 0.05, (8, 43)).astype(np.float32)
    env.close()
    z = np.clip((states - np.array(norm["mean"])) / np.sqrt(np.array(norm["var"]) + 1e-8), -10, 10).astype(np.float32)
    theirs, _ = model.predict(z, deterministic=True)
    np.testing.assert_allclose(policy.residual(states), theirs, atol=1e-5)
    # as a toolkit Policy: joint targets = trot + scale * u
    from acn.sim.policies import Trot

    t = 0.26
    np.testing.assert_allclose(policy(states[0].astype(np.float64), t),
                               Trot()(states[0], t) + policy.env.residual_scale * policy.residual(states[0]), atol=1e-9)


def test_eval_reloads_policy_and_corrector(tiny_run, capsys, tmp_path):
    out = tiny_run[0]
    rc = ppo_main(["--eval", str(out / "policy"), "--corrector", str(out / "corrector"), "--episodes", "20",
                   "--seconds", "0.3", "--out", str(tmp_path / "eval.json")])
    text = capsys.readouterr().out
    assert rc == 0 and "eps_transfer (per step)" in text and "delta_corr (per episode)" in text
    assert "+- " in text and "20 episodes" in text
    ev = json.loads((tmp_path / "eval.json").read_text())
    assert all(len(ev["returns"][run]) == 20 for run in ("sim", "robot", "robot_corrected"))
    assert ev["eps_transfer"]["n"] == 20 and np.isfinite(ev["gap"]["closer_by"]["stderr"])


# ----- any model to train in, any robot to deploy on --------------------------------------------
def test_a_models_effects_are_the_environments_physics():
    from acn.sim.effects import Model, get_effect

    damping = get_effect("joint_damping")
    damped = Model("mujoco").with_effect(damping, damping.parse({"value": 2.0}))
    nominal, heavy = A1Env("mujoco", seconds=0.3), A1Env(damped, seconds=0.3)
    nominal.reset(seed=4)
    heavy.reset(options={"state": nominal.state})
    u = np.full(12, 0.5, dtype=np.float32)
    a, b = nominal.step(u)[0], heavy.step(u)[0]
    assert np.abs(a[SLICES["joint_vel"]] - b[SLICES["joint_vel"]]).max() > 0.05  # the same action, slower joints
    assert heavy.model.describe().startswith("mujoco + joint_damping")
    nominal.close()
    heavy.close()


def test_plain_ppo_in_one_model_evaluated_on_a_sealed_robot(tmp_path, capsys):
    """--train mujoco --robot ROBOT without a corrector: plain PPO; the robot with hidden effects is
    simulated (its returns differ) and never shown, in training or in --eval."""
    from acn.sim.effects import AppliedEffect, get_effect
    from acn.sim.hidden import write_answer

    latency = get_effect("actuator_latency")
    answer = write_answer(tmp_path / "robot", "mujoco", [AppliedEffect(latency, latency.parse({"seconds": 0.0234567}))], 0)
    run = tmp_path / "run"
    assert ppo_main(["--train", "mujoco", "--robot", str(answer), "--timesteps", "256", "--refit-every", "0",
                     "--eval-every", "0", "--out", str(run), *TINY]) == 0
    m = json.loads((run / "metrics.json").read_text())
    fin = m["final_evaluation"]
    assert fin["models"] == {"sim": "mujoco", "robot": "mujoco + sealed effects"}
    assert "robot_corrected" not in fin["returns"] and m["corrector_frozen"] is None and not m["correctors"]
    assert fin["returns"]["robot"] != fin["returns"]["sim"]
    assert json.loads((run / "policy" / "config.json").read_text())["training"]["model"] == "mujoco"
    assert ppo_main(["--eval", str(run / "policy"), "--robot", str(answer), "--episodes", "2",
                     "--seconds", "0.3", "--out", str(tmp_path / "eval.json")]) == 0
    ev = json.loads((tmp_path / "eval.json").read_text())
    assert ev["models"]["robot"] == "mujoco + sealed effects" and len(ev["training_returns"]["robot"]) == 2
    printed = capsys.readouterr()
    assert "0.0234" not in printed.out + printed.err
    assert "0.0234" not in (run / "metrics.json").read_text() + (run / "policy" / "config.json").read_text()


# ----- bad input --------------------------------------------------------------------------
def _schema_mismatch(out, tmp_path):
    bad = tmp_path / "policy_40"
    shutil.copytree(out / "policy", bad)
    cfg = json.loads((bad / "config.json").read_text())
    cfg["state_names"] = cfg["state_names"][:40]
    (bad / "config.json").write_text(json.dumps(cfg))
    return bad


def _torque_corrector(out, tmp_path):
    bad = tmp_path / "corrector_torque"
    shutil.copytree(out / "corrector", bad)
    cfg = json.loads((bad / "config.json").read_text())
    cfg["training_data"]["action_mode"] = "torque"
    (bad / "config.json").write_text(json.dumps(cfg))
    return bad


@pytest.mark.parametrize("case, message", [
    ("missing_corrector_train", "does not exist"),
    ("missing_corrector_eval", "does not exist"),
    ("schema", "different state schema"),
    ("torque_corrector", "fitted for torque-mode actions"),
    ("existing_out", "exists"),
    ("resume_nothing", "no checkpoint"),
    ("eval_with_training_setting", "not --n-steps"),
    ("no_out", "needs --out"),
    ("corrector_for_another_robot", "fitted for a mujoco target"),
    ("robot_not_a_model", "neither a backend"),
])
def test_bad_input_is_one_line_and_exit_2(tiny_run, tmp_path, capsys, case, message):
    out = tiny_run[0]
    new = tmp_path / "new_run"
    args = {
        "missing_corrector_train": ["--timesteps", "64", "--out", str(new), "--corrector", str(tmp_path / "none")],
        "missing_corrector_eval": ["--eval", str(out / "policy"), "--corrector", str(tmp_path / "none")],
        "schema": ["--eval", str(_schema_mismatch(out, tmp_path)), "--corrector", str(out / "corrector")],
        "torque_corrector": ["--eval", str(out / "policy"), "--corrector", str(_torque_corrector(out, tmp_path))],
        # a corrector from elsewhere: one inside --out is refused first, as an input the run would replace
        "existing_out": ["--timesteps", "64", "--out", str(out), "--corrector",
                         str(shutil.copytree(out / "corrector", tmp_path / "elsewhere"))],
        "resume_nothing": ["--timesteps", "64", "--out", str(new), "--resume"],
        "eval_with_training_setting": ["--eval", str(out / "policy"), "--n-steps", "64"],
        "no_out": ["--timesteps", "64", "--corrector", str(out / "corrector")],
        "corrector_for_another_robot": ["--eval", str(out / "policy"), "--robot", "pybullet", "--corrector",
                                        str(out / "corrector")],
        "robot_not_a_model": ["--timesteps", "64", "--out", str(new), "--robot", "mujocco"],
    }[case]
    rc = ppo_main(args)
    err = capsys.readouterr().err
    assert rc == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and lines[0].startswith("acn-ppo: error:"), err
    assert not new.exists()
