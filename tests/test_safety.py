"""Nothing a user owns is ever lost, and every mistake gets one line (exit 2) before any work.

``--overwrite`` replaces only the toolkit's own output of the same kind; every output path is
checked before a run starts; an interrupted ``--overwrite`` run leaves the old output as it was;
values no A1 can produce are cut on import and refused in datasets; datasets that do not belong
together are refused; MuJoCo writes nothing into the working directory.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from acn.outputs.writing import write_file
from acn.datasets.reader import load_frames
from acn.sim.state import ACTION_NAMES, STATE_NAMES

IMPORT_ARGS = ("--control-hz", "50", "--kp", "60", "--kd", "1.5", "--torque-limit", "33.5")


def _tree(path: Path) -> dict[str, bytes]:
    """Every file under ``path`` with its bytes (a directory's full content, to compare)."""
    return {str(p.relative_to(path)): p.read_bytes() for p in sorted(path.rglob("*")) if p.is_file()}


def _one_line_refusal(result, *words: str) -> None:
    assert result.returncode == 2, (result.returncode, result.stderr)
    err = result.stderr.strip()
    assert "\n" not in err and "Traceback" not in err, err
    for w in words:
        assert w in err, err


@pytest.fixture
def notes(tmp_path):
    d = tmp_path / "notes"
    d.mkdir()
    (d / "todo.txt").write_text("x")
    return d


# ----------------------------------------------------------------------------- --overwrite
@pytest.mark.parametrize("where, words", [
    ("notes", ("not a dataset directory this toolkit wrote",)),
    ("notes/todo.txt", ("is a file",)),
    (".", ("working directory",)),
    ("..", ("working directory",)),
    ("/", ("root",)),
    ("~", ("home directory",)),
])
def test_collect_overwrite_refuses_what_it_did_not_write(acn, tmp_path, notes, monkeypatch, where, words):
    monkeypatch.chdir(tmp_path)
    before = _tree(tmp_path)
    r = acn("collect", "--episodes", "1", "--seconds", "0.1", "--out", where, "--overwrite")
    _one_line_refusal(r, *words)
    assert _tree(tmp_path) == before


def test_an_empty_out_is_refused_as_an_empty_path(acn):
    _one_line_refusal(acn("collect", "--episodes", "1", "--seconds", "0.1", "--out", "", "--overwrite"), "empty")


def test_fit_and_import_refuse_to_write_over_their_inputs(acn, tmp_path, small_dataset):
    log = tmp_path / "logs" / "robot.csv"
    log.parent.mkdir()
    log.write_text("t,q\n0,0\n")
    _one_line_refusal(acn("fit", str(small_dataset), "--out", str(small_dataset), "--overwrite"), "is the input")
    _one_line_refusal(acn("fit", str(small_dataset), "--out", str(small_dataset.parent), "--overwrite"),
                      "holds the input")
    _one_line_refusal(acn("import", str(log), "--out", str(log.parent), "--overwrite", *IMPORT_ARGS), "holds the input")
    _one_line_refusal(acn("import", str(log), "--out", str(log), "--overwrite", *IMPORT_ARGS), "is the input")
    assert log.read_text() == "t,q\n0,0\n" and (small_dataset / "meta" / "info.json").is_file()


def test_fit_overwrite_refuses_a_dataset_and_ppo_refuses_an_existing_directory(acn, tmp_path, small_dataset, notes):
    other = tmp_path / "copy"
    shutil.copytree(small_dataset, other)
    _one_line_refusal(acn("fit", str(small_dataset), "--out", str(other), "--overwrite"),
                      "not a corrector directory this toolkit wrote")
    _one_line_refusal(acn("ppo", "--timesteps", "10", "--out", str(notes)), "exists (use --overwrite")
    _one_line_refusal(acn("ppo", "--timesteps", "10", "--out", str(notes), "--overwrite"),
                      "not a PPO run directory this toolkit wrote")
    assert (notes / "todo.txt").read_text() == "x" and (other / "meta" / "info.json").is_file()


def test_overwrite_replaces_the_toolkits_own_dataset(acn, tmp_path):
    out = tmp_path / "ds"
    assert acn("collect", "--episodes", "1", "--seconds", "0.1", "--out", str(out)).returncode == 0
    assert acn("collect", "--episodes", "2", "--seconds", "0.1", "--out", str(out), "--overwrite").returncode == 0
    assert len(np.unique(load_frames(out).episode)) == 2
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_an_interrupted_overwrite_leaves_the_old_dataset(tmp_path, small_config):
    from acn.datasets.record import record
    from acn.datasets.stream import Interrupted

    out = record(small_config, tmp_path / "ds")
    before = _tree(out)

    def stop(_episode) -> None:
        raise KeyboardInterrupt

    with pytest.raises(Interrupted) as e:
        record(small_config, out, overwrite=True, on_episode=stop)
    assert e.value.path is None and _tree(out) == before
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


# ----------------------------------------------------------------------------- output paths
@pytest.mark.parametrize("flag", ["--json", "--report", "--save-model"])
def test_diagnose_checks_each_output_path_before_the_run(acn, tmp_path, small_dataset, notes, flag):
    for path, words in ((notes, "is a directory"), (tmp_path / "missing" / "x", "does not exist"),
                        (notes / "todo.txt", "not a"), (small_dataset / "meta" / "info.json", "input")):
        _one_line_refusal(acn("diagnose", str(small_dataset), flag, str(path)), flag, words)
    assert (notes / "todo.txt").read_text() == "x"


def test_view_checks_save_before_the_run(acn, small_dataset, notes):
    _one_line_refusal(acn("view", str(small_dataset), "--save", str(notes)), "is a directory")
    _one_line_refusal(acn("view", str(small_dataset), "--save", str(notes / "todo.txt")), "not a Rerun recording")


def test_a_failed_file_write_leaves_no_partial(tmp_path):
    target = tmp_path / "taken"
    target.mkdir()
    (target / "keep").write_text("y")
    with pytest.raises(OSError):
        write_file(target, "data")
    assert [p.name for p in tmp_path.iterdir()] == ["taken"] and (target / "keep").read_text() == "y"


# ----------------------------------------------------------------------------- absurd values
def _set_column(dataset: Path, column: str, edit) -> None:
    """Rewrite one array column of a dataset's first data file with ``edit(values)``."""
    f = sorted(dataset.rglob("data/**/*.parquet"))[0]
    t = pq.read_table(f)
    values = np.stack(t.column(column).to_numpy(zero_copy_only=False)).astype(np.float32)
    edit(values)
    flat = pa.array(values.reshape(-1))
    t = t.set_column(t.schema.get_field_index(column), column, pa.FixedSizeListArray.from_arrays(flat, values.shape[1]))
    pq.write_table(t, f)


def test_an_absurd_action_in_a_dataset_is_refused_by_fit_and_diagnose(acn, tmp_path, small_dataset, monkeypatch):
    bad = tmp_path / "bad"
    shutil.copytree(small_dataset, bad)
    _set_column(bad, "action", lambda a: a.__setitem__((3, 4), 3e38))
    monkeypatch.chdir(tmp_path)
    for tool, args in (("fit", ("--out", str(tmp_path / "m"))), ("diagnose", ())):
        _one_line_refusal(acn(tool, str(bad), *args), "episode 0", "FL_thigh", "no A1 can produce")
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_a_dataset_of_nan_states_says_so(acn, tmp_path, small_dataset):
    bad = tmp_path / "nan"
    shutil.copytree(small_dataset, bad)
    _set_column(bad, "observation.state", lambda s: s.fill(np.nan))
    _one_line_refusal(acn("fit", str(bad), "--out", str(tmp_path / "m")), "non-finite")


def _log_from(dataset: Path, path: Path, edit=None) -> Path:
    f = load_frames(dataset)
    df = pd.DataFrame(f.state, columns=list(STATE_NAMES))
    for i, n in enumerate(ACTION_NAMES):
        df[f"action.{n}"] = f.action[:, i]
    df["timestamp"], df["episode_index"] = f.timestamp, f.episode
    if edit:
        edit(df)
    df.to_csv(path, index=False)
    return path


@pytest.mark.parametrize("column, value", [("FR_hip_pos", 1e308), ("action.FR_hip", 1e308), ("FR_calf_vel", -5e4)])
def test_import_cuts_and_counts_rows_no_a1_can_produce(acn, tmp_path, small_dataset, column, value):
    log = _log_from(small_dataset, tmp_path / "log.csv", lambda df: df.__setitem__((column), df[column].where(
        df.index != 7, value)))
    r = acn("import", str(log), "--out", str(tmp_path / "ds"), *IMPORT_ARGS)
    assert r.returncode == 0, r.stderr
    assert "cut 1 row(s) with values no A1 can produce" in r.stdout and column.removeprefix("action.") in r.stdout
    info = json.loads((tmp_path / "ds" / "meta" / "info.json").read_text())
    assert info["acn"]["import"]["rows_cut_implausible"] == 1
    assert np.isfinite(load_frames(tmp_path / "ds").state).all()


# ----------------------------------------------------------------------------- inputs together
def test_datasets_of_two_directions_are_refused_together(acn, tmp_path, small_dataset):
    from acn.datasets.record import record
    from acn.sim.collector import CollectConfig

    reverse = record(CollectConfig(source="mujoco", target="pybullet", episodes=1, seconds=0.2), tmp_path / "rev")
    _one_line_refusal(acn("fit", str(small_dataset), str(reverse), "--out", str(tmp_path / "m")),
                      str(reverse), str(small_dataset), "direction")


def test_datasets_of_two_control_rates_name_the_flag(acn, tmp_path, small_dataset):
    from acn.datasets.record import record
    from acn.sim.backends import SimConfig
    from acn.sim.collector import CollectConfig

    fast = record(CollectConfig(target="mujoco", episodes=1, seconds=0.2,
                                sim=SimConfig(physics_dt=0.001, substeps=10)), tmp_path / "fast")
    _one_line_refusal(acn("fit", str(small_dataset), str(fast), "--out", str(tmp_path / "m")), "--control-hz")


# ----------------------------------------------------------------------------- messages
def test_a_file_given_for_a_dataset_is_named_a_file(acn, small_dataset):
    _one_line_refusal(acn("diagnose", str(small_dataset / "meta" / "info.json")), "is a file, not a")


def test_a_binary_csv_is_one_line(acn, tmp_path):
    log = tmp_path / "noise.csv"
    log.write_bytes(np.random.default_rng(0).bytes(4000))
    r = acn("import", str(log), "--out", str(tmp_path / "ds"), *IMPORT_ARGS)
    _one_line_refusal(r, "not a text CSV")
    assert "Exception ignored" not in r.stderr


def test_a_model_whose_corrector_is_not_a_path_is_refused(acn, tmp_path, small_dataset):
    model = tmp_path / "m.json"
    model.write_text(json.dumps({"backend": "mujoco", "effects": [], "corrector": 42}))
    for tool, args in (("diagnose", (str(small_dataset), "--model", str(model))),
                       ("view", (str(small_dataset), "--model", str(model), "--save", str(tmp_path / "v.rrd")))):
        _one_line_refusal(acn(tool, *args), "corrector")


def test_every_help_shows_its_defaults():
    import re

    import acn.cli

    for name in ("collect", "fit", "ppo", "view", "import", "diagnose"):
        parser = getattr(acn.cli, f"{name}_parser")()
        blocks = re.split(r"\n(?=  -)", parser.format_help())  # one block per option
        for action in parser._actions:  # noqa: SLF001 - argparse lists its options only here
            if not action.option_strings or action.default in (None, False, [], "==SUPPRESS=="):
                continue
            block = next(b for b in blocks if b.lstrip().startswith(action.option_strings[0]))
            assert "default" in block.lower(), (name, block)


def test_a_tiny_ppo_request_stays_tiny():
    from acn.rl.ppo import PPOConfig

    small = PPOConfig(timesteps=100).sized_for_run()
    assert small.n_steps * small.n_envs <= 100 + small.n_envs and small.final_eval_episodes == 2
    assert PPOConfig(timesteps=100).sized_for_run(keep={"final_eval_episodes"}).final_eval_episodes == 20
    assert PPOConfig(timesteps=10_000).sized_for_run() == PPOConfig(timesteps=10_000)


def test_mujoco_writes_no_log_file_into_the_working_directory(tmp_path, monkeypatch):
    import importlib

    import mujoco

    importlib.import_module("acn.sim")  # which turns MuJoCo's own log off

    monkeypatch.chdir(tmp_path)
    m = mujoco.MjModel.from_xml_string('<mujoco><worldbody><body><joint name="j"/><geom size=".1"/></body>'
                                       '</worldbody><actuator><motor joint="j"/></actuator></mujoco>')
    d = mujoco.MjData(m)
    d.ctrl[:] = 3e38
    mujoco.mj_step(m, d)
    assert d.warning[mujoco.mjtWarning.mjWARN_BADCTRL].number > 0
    assert not os.listdir(tmp_path)


def test_an_interrupted_ppo_overwrite_leaves_the_old_run(tmp_path, monkeypatch):
    from acn.rl import ppo

    out = tmp_path / "run"
    out.mkdir()
    (out / ppo.RUN_MANIFEST).write_text(json.dumps({"format": ppo.RUN_FORMAT}))
    (out / "metrics.json").write_text("{}")
    before = _tree(out)
    trainer = ppo.Trainer(ppo.PPOConfig(timesteps=64), out, overwrite=True, log=lambda line: None)
    assert trainer.out != out and (trainer.out / ppo.RUN_MANIFEST).is_file()  # the new run trains beside the old

    def interrupted() -> dict:
        raise KeyboardInterrupt

    monkeypatch.setattr(trainer, "_run", interrupted)
    with pytest.raises(KeyboardInterrupt):
        trainer.run()
    assert _tree(out) == before and [p.name for p in tmp_path.iterdir()] == ["run"]
