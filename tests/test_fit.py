"""Fitting the ACN from dataset files, the frozen corrector, and acn-collect --corrector."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import torch

from acn.datasets.record import record
from acn.errors import UserError
from acn.models import Corrector
from acn.models.fit import FitConfig, fit, save
from acn.toolkit.collector import CollectConfig

FAST = dict(epochs=8, eval_episodes=1, eval_seconds=0.4)


@pytest.fixture(scope="module")
def paired(tmp_path_factory):
    cfg = CollectConfig(target="mujoco", policy="trot", episodes=6, seconds=2.0, seed=5)
    return record(cfg, tmp_path_factory.mktemp("fit") / "paired", workers=2)


@pytest.fixture(scope="module")
def fitted(paired, tmp_path_factory):
    model, metrics = fit([paired], FitConfig(variant="paper", **FAST), log=lambda s: None)
    return save(model, metrics, tmp_path_factory.mktemp("model") / "paper"), metrics


@pytest.mark.parametrize("variant", ["paper", "mujoco-jacobian"])
def test_training_lowers_the_validation_loss(paired, variant):
    _, m = fit([paired], FitConfig(variant=variant, **FAST), log=lambda s: None)
    assert m["val_objective"]["loss"] < m["val_objective_before"]["loss"]
    assert m["rows"]["train"] >= 64 and m["rows"]["val"] > 0
    cl = m["closed_loop"]
    assert np.isfinite(cl["divergence_uncorrected"]) and np.isfinite(cl["divergence_reduction"])
    for key in ("eps_transfer", "eps_transfer_uncorrected", "delta_corr"):
        assert np.isfinite(cl[key])
    assert set(cl["reward_difference_stats_corrected"]) == {"mean", "mode", "expectation"}


def test_save_load_round_trip_gives_identical_corrections(fitted, paired):
    path, metrics = fitted
    model = Corrector.load(path)
    again = Corrector.load(path)
    rng = np.random.default_rng(0)
    from acn.toolkit.backends import default_state

    s = default_state()[None] + rng.normal(0, 0.05, (16, 43))
    a = rng.normal(0, 0.3, (16, 12))
    np.testing.assert_array_equal(model.correct(s, a), again.correct(s, a))
    config = json.loads((path / "config.json").read_text())
    assert config["variant"] == "paper" and len(config["input_channels"]) == 40
    assert config["training_data"]["fingerprint"].startswith("sha256:")
    assert "closed_loop" in config["metrics"] and (path / "metrics.json").is_file()
    assert set(config["normalisation"]) >= {"state_mean", "state_std", "action_mean", "residual_std"}


def test_the_corrector_is_frozen_and_takes_numpy_or_torch(fitted):
    model = Corrector.load(fitted[0])
    assert not model.training and not any(p.requires_grad for p in model.parameters())
    from acn.toolkit.backends import default_state

    s, a = default_state(), np.full(12, 0.1)
    out = model.correct(s, a)
    assert isinstance(out, np.ndarray) and out.shape == (12,) and out.dtype == np.float64
    out_t = model.correct(torch.as_tensor(s), torch.as_tensor(a))
    assert torch.is_tensor(out_t) and out_t.dtype == torch.float64
    np.testing.assert_allclose(out_t.numpy(), out, rtol=1e-6)
    batch = model.correct(np.stack([s, s]), np.stack([a, a]))
    assert batch.shape == (2, 12)
    with pytest.raises(ValueError):
        model.correct(s[:40], a)


def test_collect_with_corrector_changes_only_the_targets_actions(fitted, tmp_path):
    import pyarrow.parquet as pq

    cfg = CollectConfig(target="mujoco", policy="trot", episodes=1, seconds=0.5, seed=9)
    plain = record(cfg, tmp_path / "plain")
    cfg.corrector = str(fitted[0])
    corrected = record(cfg, tmp_path / "corrected")
    p, c = (pq.read_table(next((d / "data").rglob("*.parquet"))).to_pydict() for d in (plain, corrected))
    for key in ("observation.state", "action", "next.observation.state", "observation.effort"):
        assert p[key] == c[key], key  # the source is untouched
    assert p["target.observation.state"][0] == c["target.observation.state"][0]  # same start
    assert c["action"] != c["target.action"]  # the target got a~ = a + F(s, a)
    assert p["action"] == p["target.action"]
    assert json.loads((corrected / "meta" / "info.json").read_text())["acn"]["corrector"] == str(fitted[0])


def test_not_paired_is_refused(tmp_path):
    meas = record(CollectConfig(target=None, episodes=2, seconds=0.2), tmp_path / "meas")
    with pytest.raises(UserError, match="not a paired"):
        fit([meas], FitConfig(**FAST))


def test_datasets_with_different_rates_are_refused(paired, tmp_path):
    from acn.toolkit.backends import SimConfig

    other = record(CollectConfig(target="mujoco", episodes=2, seconds=0.2, sim=SimConfig(substeps=10)),
                   tmp_path / "100hz")
    with pytest.raises(UserError, match="substeps"):
        fit([paired, other], FitConfig(**FAST))


def test_too_little_data_after_filtering(tmp_path):
    tiny = record(CollectConfig(target="mujoco", episodes=2, seconds=0.3), tmp_path / "tiny")
    with pytest.raises(UserError, match="too little data"):
        fit([tiny], FitConfig(**FAST))


def test_existing_model_directory_is_refused(fitted):
    model = Corrector.load(fitted[0])
    with pytest.raises(UserError, match="exists"):
        save(model, {}, fitted[0])


def test_corrupt_or_foreign_model_files_give_clear_errors(fitted, tmp_path):
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(fitted[0], bad)
    (bad / "model.safetensors").write_bytes(b"\x00not safetensors")
    with pytest.raises(UserError, match="corrupt"):
        Corrector.load(bad)
    foreign = tmp_path / "foreign"
    shutil.copytree(fitted[0], foreign)
    (foreign / "config.json").write_text(json.dumps({"format": "someone-else/3"}))
    with pytest.raises(UserError, match="not an acn corrector"):
        Corrector.load(foreign)
    with pytest.raises(UserError, match="not a corrector directory"):
        Corrector.load(tmp_path)


def _fit_cli(*args: str) -> subprocess.CompletedProcess:
    code = "import sys; from acn.cli import fit_main; sys.exit(fit_main())"
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=600)


def test_fit_cli_end_to_end_and_bad_input(paired, tmp_path):
    r = _fit_cli(str(paired), "--out", str(tmp_path / "m"), "--epochs", "3", "--eval-episodes", "1",
                 "--eval-seconds", "0.3")
    assert r.returncode == 0, r.stderr
    assert "divergence_reduction=" in r.stdout and (tmp_path / "m" / "model.safetensors").is_file()
    for args, msg in [
        ([str(paired), "--out", str(tmp_path / "m")], "exists"),
        ([str(tmp_path / "nope"), "--out", str(tmp_path / "x")], "does not exist"),
        ([str(paired), "--out", str(tmp_path / "x"), "--variant", "magic"], "invalid choice"),
        ([str(paired), "--out", str(tmp_path / "x"), "--lr", "-1"], "> 0"),
        ([str(paired), "--out", str(tmp_path / "x"), "--filter-percentile", "1", "--eval-episodes", "0"],
         "too little data"),
    ]:
        r = _fit_cli(*args)
        assert r.returncode == 2, (args, r.stderr)
        assert len(r.stderr.strip().splitlines()) == 1 and msg in r.stderr, r.stderr
        assert not (tmp_path / "x").exists()


def test_no_filter_writes_standard_json(paired, tmp_path):
    """--filter-percentile 100 keeps every row; the model files stay strict JSON."""
    model, metrics = fit([paired], FitConfig(filter_percentile=100.0, epochs=1, eval_episodes=0), log=lambda s: None)
    path = save(model, metrics, tmp_path / "nofilter")
    for name in ("config.json", "metrics.json"):
        json.loads((path / name).read_text(), parse_constant=lambda c: pytest.fail(f"{name} has {c}"))
    assert metrics["rows"]["filter_threshold"] is None
