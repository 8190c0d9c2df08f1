"""Malformed datasets and model files: a one-line error and exit status 2, never a traceback.

Property-based (hypothesis): the ``acn`` metadata block, the Parquet data files, a corrector's
config and weights and an effects model file are mutated at random; every reader either reads
the file or raises a one-line ``UserError`` (which every command prints as one line, exit 2).
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from acn.measurements.data import load_measurements
from acn.datasets.reader import load_frames, load_paired
from acn.errors import UserError
from acn.corrector.card import CorrectorCard
from acn.corrector.corrector import Corrector
from acn.weights import CONFIG, WEIGHTS
from acn.sim.effects import Model

SETTINGS = settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
JSON = st.recursive(st.none() | st.booleans() | st.integers(-5, 10**6) | st.floats(allow_nan=True) | st.text(max_size=6),
                    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=5), inner, max_size=3),
                    max_leaves=5)


def readers(path: Path):
    """Every way a command reads a dataset."""
    return [lambda: load_paired([path]), lambda: load_frames(path), lambda: load_measurements(path),
            lambda: load_measurements(path, side="target")]


def reads_or_one_line(read) -> None:
    try:
        read()
    except UserError as e:
        assert str(e) and "\n" not in str(e), repr(str(e))


def mutate_json(value: dict, key: str, delete: bool, new) -> dict:
    out = dict(value)
    if delete:
        out.pop(key, None)
    else:
        out[key] = new
    return out


@SETTINGS
@given(data=st.data(), delete=st.booleans(), new=JSON)
def test_mutated_acn_metadata(small_dataset, data, delete, new):
    info = json.loads((small_dataset / "meta" / "info.json").read_text())
    key = data.draw(st.sampled_from(sorted(info["acn"])))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(shutil.copytree(small_dataset, Path(tmp) / "d"))
        info["acn"] = mutate_json(info["acn"], key, delete, new)
        (path / "meta" / "info.json").write_text(json.dumps(info))
        for read in readers(path):
            reads_or_one_line(read)


@pytest.mark.parametrize("key, value, named", [
    ("kp", "sixty", "'acn.kp' = 'sixty'"),
    ("state_names", ["x"], "different state channels"),
    ("episodes", [{"episode_index": 0, "end": "time_limit", "collection_index": 0}], "'length'"),
    ("target", None, "'acn.paired' = true"),
    ("init_noise", {"joint_pos": "wide"}, "'acn.init_noise'"),
    ("import", {"rows_cut_implausible": -1}, "'acn.import.rows_cut_implausible' = -1"),
])
def test_a_malformed_acn_block_is_refused_in_one_line_naming_the_file_and_key(small_dataset, tmp_path, key, value,
                                                                                named):
    path = Path(shutil.copytree(small_dataset, tmp_path / "d"))
    info = json.loads((path / "meta" / "info.json").read_text())
    info["acn"][key] = value
    (path / "meta" / "info.json").write_text(json.dumps(info))
    for read in readers(path):
        with pytest.raises(UserError) as e:
            read()
        assert str(e.value).startswith(str(path)) and named in str(e.value) and "\n" not in str(e.value), str(e.value)


@SETTINGS
@given(data=st.data(), cut=st.floats(0.0, 0.999), flips=st.lists(st.tuples(st.floats(0, 0.999), st.integers(0, 255)),
                                                                  max_size=4))
def test_truncated_or_damaged_parquet_files(small_dataset, data, cut, flips):
    files = sorted(p.relative_to(small_dataset) for p in small_dataset.rglob("*.parquet"))
    name = data.draw(st.sampled_from(files))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(shutil.copytree(small_dataset, Path(tmp) / "d"))
        raw = bytearray((path / name).read_bytes())
        for where, byte in flips:
            raw[int(where * len(raw))] = byte
        (path / name).write_bytes(bytes(raw[: max(1, int(len(raw) * (1 - cut)))] if cut > 0.5 else raw))
        for read in readers(path):
            reads_or_one_line(read)


@pytest.fixture(scope="module")
def corrector_dir(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("corrector")
    Corrector(CorrectorCard.untrained("inverse", 16, 2)).save(d)
    return d


@SETTINGS
@given(data=st.data(), delete=st.booleans(), new=JSON, cut=st.integers(0, 400))
def test_mutated_corrector_files(corrector_dir, data, delete, new, cut):
    config = json.loads((corrector_dir / CONFIG).read_text())
    key = data.draw(st.sampled_from(sorted(config) + ["network.hidden", "network.layers"]))
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(shutil.copytree(corrector_dir, Path(tmp) / "c"))
        if "." in key:
            outer, inner = key.split(".")
            config[outer] = mutate_json(config[outer], inner, delete, new)
        else:
            config = mutate_json(config, key, delete, new)
        (d / CONFIG).write_text(json.dumps(config))
        if cut:
            raw = (d / WEIGHTS).read_bytes()
            (d / WEIGHTS).write_bytes(raw[:-cut])
        reads_or_one_line(lambda: Corrector.load(d))


@SETTINGS
@given(doc=st.dictionaries(st.sampled_from(["backend", "effects", "corrector", "extra"]), JSON, max_size=3),
       effect=st.dictionaries(st.sampled_from(["name", "params", "where"]), JSON | st.sampled_from(
           ["joint_damping", "actuator_latency", "payload"]), max_size=3))
@example(doc={"effects": None}, effect={"name": []})  # found by hypothesis: an unhashable name was a TypeError
def test_mutated_model_files(doc, effect):
    if "effects" in doc and not isinstance(doc["effects"], list):
        doc["effects"] = [effect]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "model.json"
        path.write_text(json.dumps(doc))
        reads_or_one_line(lambda: Model.load(path))


def run_cli(command: str, *args: str) -> subprocess.CompletedProcess:
    """A console script as a user runs it (its own process, so library logging reaches stderr)."""
    main = {"acn-fit": "fit_main", "acn-diagnose": "diagnose_main"}[command]
    code = f"import sys; from acn.cli import {main}; sys.exit({main}(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("damage", ["no kp", "truncated parquet"])
def test_commands_print_one_line_for_a_broken_dataset(small_dataset, tmp_path, damage):
    path = Path(shutil.copytree(small_dataset, tmp_path / "d"))
    if damage == "no kp":
        info = json.loads((path / "meta" / "info.json").read_text())
        del info["acn"]["kp"]
        (path / "meta" / "info.json").write_text(json.dumps(info))
        expected = "'kp'"
    else:
        data = sorted(path.glob("data/*/*.parquet"))[0]
        data.write_bytes(data.read_bytes()[: data.stat().st_size // 2])
        expected = "not a readable Parquet file"
    for args in (["acn-fit", str(path), "--out", str(tmp_path / "m")],
                 ["acn-diagnose", str(path), "--model", "mujoco"]):
        r = run_cli(*args)
        assert r.returncode == 2, r.stderr
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and expected in lines[0] and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "m").exists()
