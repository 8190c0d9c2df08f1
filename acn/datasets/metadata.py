"""The ``acn`` block of a dataset's ``meta/info.json``, typed: ``AcnMetadata``.

The block says how a dataset was made: the simulator of each side and its version (or the
measured robot's log), the control settings a reader re-simulates with (rates, action mode, PD
gains, torque limit, what the accelerometer reads), the physical description, the policy and
seed of a collection, the channel names, the fall rule, how each episode ended and, for an
imported log, what the import read and cut (``ImportInfo``).

``AcnMetadata.from_json`` reads a block once, where a dataset is read (``acn.datasets.reader``):
every field is checked against what it must be (the ``what`` of its ``_Json``), and a malformed
block is a one-line ``UserError`` naming the file and the key. ``to_json`` writes the same JSON
keys in the same order, so every dataset this toolkit wrote reads back. ``DatasetCard`` is
what a reader knows of a dataset before its rows: the block and LeRobot's robot type.

``collection_metadata`` / ``config_from_metadata`` turn a collection's ``CollectConfig`` into
its block and back.
"""

from __future__ import annotations

import dataclasses
import math
import types
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Callable, Mapping

from acn.datasets.schema import ACN_KEY, FORMAT_VERSION
from acn.errors import UserError
from acn.sim.backends import ACTION_MODES, IMU_ACC_KINDS, SimConfig, simulator_version
from acn.sim.backends.base import JointGains, joint_gains
from acn.sim.collector import FALL_RULE, CollectConfig, InitNoise
from acn.sim.state import ACTION_DIM, ACTION_NAMES, STATE_DIM, STATE_NAMES


class _Malformed(Exception):
    """A block that does not fit: the message is a phrase after the dataset's path."""


@dataclass(frozen=True)
class _Json:
    """How one field is read from and written to the JSON block."""

    what: str                                   # what the JSON value must be, for the message
    read: Callable[[Any, str], Any]             # (JSON value, its key path) -> field value; ValueError if it does not fit
    write: Callable[[Any], Any] = lambda v: v   # field value -> JSON value
    key: str | None = None                      # the JSON key, where it is not the field name
    required: bool = False                      # absent: the block is malformed
    null_written: bool = False                  # None is written as null (else the key is left out)


def _json(what: str, read: Callable[[Any, str], Any], write: Callable[[Any], Any] = lambda v: v, *,
          key: str | None = None, null_written: bool = False, default: Any = dataclasses.MISSING) -> Any:
    """A dataclass field read and written as ``_Json`` says; without ``default`` it is required."""
    spec = _Json(what, read, write, key, default is dataclasses.MISSING, null_written)
    return field(default=default, metadata={"json": spec})


def _checked(ok: Callable[[Any], bool], convert: Callable[[Any], Any] = lambda v: v) -> Callable[[Any, str], Any]:
    def read(v: Any, path: str) -> Any:
        if not ok(v):
            raise ValueError(path)
        return convert(v)
    return read


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _is_whole(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _number(minimum: float, strict: bool) -> Callable[[Any, str], float]:
    return _checked(lambda v: _is_number(v) and (v > minimum if strict else v >= minimum), float)


def _whole(minimum: int) -> Callable[[Any, str], int]:
    return _checked(lambda v: _is_whole(v) and v >= minimum)


_BOOL = _checked(lambda v: isinstance(v, bool))
_TEXT = _checked(lambda v: isinstance(v, str))


def _one_of(values: tuple[str, ...]) -> Callable[[Any, str], str]:
    return _checked(lambda v: v in values)


def _texts(allowed: tuple[str, ...] | None = None) -> Callable[[Any, str], tuple[str, ...]]:
    return _checked(lambda v: isinstance(v, list) and all(isinstance(x, str) and (allowed is None or x in allowed)
                                                          for x in v), tuple)


def _exactly(names: tuple[str, ...]) -> Callable[[Any, str], tuple[str, ...]]:
    return _checked(lambda v: v == list(names), tuple)


def _nullable(read: Callable[[Any, str], Any]) -> Callable[[Any, str], Any]:
    return lambda v, path: None if v is None else read(v, path)


def _gains(v: Any, path: str) -> JointGains:
    """A PD gain: a number >= 0 for every joint, or a list of 12 (one per joint), as ``SimConfig`` keeps it."""
    values = v if isinstance(v, list) and len(v) == ACTION_DIM else [v]
    if not all(_is_number(x) and x >= 0 for x in values):
        raise ValueError(path)
    return joint_gains(v)


def _object(v: Any, path: str) -> Mapping[str, Any]:
    if not isinstance(v, dict):
        raise ValueError(path)
    return types.MappingProxyType(dict(v))


def _objects(v: Any, path: str) -> tuple[Mapping[str, Any], ...]:
    if not isinstance(v, list):
        raise ValueError(path)
    return tuple(_object(x, path) for x in v)


def _init_noise(v: Any, path: str) -> InitNoise:
    names = {f.name for f in fields(InitNoise)}
    if not (isinstance(v, dict) and set(v) <= names and all(_is_number(x) and x >= 0 for x in v.values())):
        raise ValueError(path)
    return InitNoise(**{k: float(x) for k, x in v.items()})


def _as_list(v: tuple) -> list:
    return list(v)


def _as_dict(v: Mapping) -> dict:
    return dict(v)


def _read_fields(cls: type, block: Any, path: str) -> Any:
    """``cls`` from the JSON object ``block`` at key path ``path`` (``_Json`` of each field)."""
    if not isinstance(block, dict):
        raise _Malformed(f"has {path!r} = {block!r:.60} in meta/info.json; it must be an object")
    values: dict[str, Any] = {}
    for f in fields(cls):
        spec: _Json = f.metadata["json"]
        key = spec.key or f.name
        if key not in block:
            if spec.required:
                raise _Malformed(f"has no {key!r} in its {path!r} block (meta/info.json)")
            continue
        try:
            values[f.name] = spec.read(block[key], f"{path}.{key}")
        except (ValueError, TypeError):
            raise _Malformed(f"has '{path}.{key}' = {block[key]!r:.60} in meta/info.json; it must be "
                             f"{spec.what}") from None
    return cls(**values)


def _write_fields(obj: Any) -> dict[str, Any]:
    """The JSON object of a dataclass read by ``_read_fields``, keys in field order."""
    out: dict[str, Any] = {}
    for f in fields(obj):
        spec: _Json = f.metadata["json"]
        value = getattr(obj, f.name)
        if value is not None:
            out[spec.key or f.name] = spec.write(value)
        elif spec.null_written:
            out[spec.key or f.name] = None
    return out


def _nested(cls: type) -> Callable[[Any, str], Any]:
    return lambda v, path: _read_fields(cls, v, path)


def _nested_list(cls: type) -> Callable[[Any, str], tuple]:
    def read(v: Any, path: str) -> tuple:
        if not isinstance(v, list):
            raise ValueError(path)
        return tuple(_read_fields(cls, x, f"{path}[{i}]") for i, x in enumerate(v))
    return read


def _write_nested_list(v: tuple) -> list[dict[str, Any]]:
    return [_write_fields(x) for x in v]


@dataclass(frozen=True, kw_only=True)
class Simulator:
    """One side of a dataset: the simulator that produced it, or ``"log"`` for a measured robot."""

    simulator: str = _json("a name", _TEXT)
    version: str | None = _json("null or a version", _nullable(_TEXT), null_written=True, default=None)
    file: str | None = _json("a file name", _TEXT, default=None)  # an imported log: its (first) file
    files: tuple[str, ...] | None = _json("a list of file names", _texts(), _as_list, default=None)  # several files

    def to_json(self) -> dict[str, Any]:
        return _write_fields(self)


@dataclass(frozen=True, kw_only=True)
class EpisodeEntry:
    """An episode of the dataset and the collection episode it was."""

    episode_index: int = _json("a whole number >= 0", _whole(0))
    length: int = _json("a whole number >= 1 (frames)", _whole(1))
    end: str = _json("how the episode ended (a name)", _TEXT)
    collection_index: int = _json("a whole number >= 0", _whole(0))


@dataclass(frozen=True, kw_only=True)
class EmptyEpisode:
    """A collection episode that ended before its first step (not in the data)."""

    collection_index: int = _json("a whole number >= 0", _whole(0))
    end: str = _json("how the episode ended (a name)", _TEXT)


_COUNT = ("a whole number >= 0", _whole(0))


@dataclass(frozen=True, kw_only=True)
class ImportInfo:
    """What ``acn-import`` read and cut (``acn.measurements.importer``); a key an import did not
    write is None."""

    file: str | None = _json("a file name", _TEXT, default=None)
    files: tuple[str, ...] | None = _json("a list of file names", _texts(), _as_list, default=None)
    rows: int | None = _json(*_COUNT, default=None)
    transitions: int | None = _json(*_COUNT, default=None)
    rows_cut_nonfinite: int | None = _json(*_COUNT, default=None)
    rows_cut_implausible: int | None = _json(*_COUNT, default=None)
    rows_malformed: int | None = _json(*_COUNT, default=None)
    rows_with_text: int | None = _json(*_COUNT, default=None)
    time_step_breaks: int | None = _json(*_COUNT, default=None)
    time_step_spread: float | None = _json("a number >= 0", _number(0.0, strict=False), default=None)
    hybrid_command: tuple[str, ...] | None = _json("a list of column kinds", _texts(), _as_list, default=None)
    segments_too_short: int | None = _json(*_COUNT, default=None)
    dt_tolerance: float | None = _json("a number >= 0", _number(0.0, strict=False), default=None)
    linvel_frame: str | None = _json("a frame name", _TEXT, default=None)
    angvel_frame: str | None = _json("a frame name", _TEXT, default=None)
    leg_order: tuple[str, ...] | None = _json("a list of leg names", _texts(), _as_list, default=None)
    shift_actions: int | None = _json("a whole number", _checked(_is_whole), default=None)
    checks: tuple[Mapping[str, Any], ...] | None = _json("a list of findings (objects)", _objects,
                                                         lambda v: [dict(x) for x in v], default=None)


_GAINS = f"a number >= 0 or a list of {ACTION_DIM} (one per joint)"


@dataclass(frozen=True, kw_only=True)
class AcnMetadata:
    """The ``acn`` block (module docstring). Fields in the block's key order; a field a dataset
    may lack is None there (a collection has no ``import_info``, an imported log no ``seconds``)."""

    format_version: int | None = _json("a whole number >= 1", _whole(1), default=None)
    paired: bool = _json("true or false", _BOOL)
    source: Simulator = _json('an object with a "simulator" name', _nested(Simulator), Simulator.to_json)
    target: Simulator | None = _json('null or an object with a "simulator" name', _nullable(_nested(Simulator)),
                                     Simulator.to_json, null_written=True)
    physics_dt: float = _json("a number > 0 (s)", _number(0.0, strict=True))
    substeps: int = _json("a whole number >= 1", _whole(1))
    control_hz: float = _json("a number > 0 (Hz)", _number(0.0, strict=True))
    action_mode: str = _json('"position" or "torque"', _one_of(ACTION_MODES))
    kp: JointGains = _json(_GAINS, _gains, lambda v: v if isinstance(v, float) else list(v))
    kd: JointGains = _json(_GAINS, _gains, lambda v: v if isinstance(v, float) else list(v))
    torque_limit: float = _json("a number > 0 (N m)", _number(0.0, strict=True))
    # what the accelerometer averages over (``SimConfig.imu_acc``); None: not stated (acn-diagnose judges it)
    imu_acc: str | None = _json('null, "mean" or "instant"', _nullable(_one_of(IMU_ACC_KINDS)), null_written=True,
                                default=None)
    model_params: Mapping[str, Any] = _json("an object", _object, _as_dict)  # ModelParams.as_json
    policy: str = _json("a name", _TEXT)
    seed: int | None = _json("null or a whole number >= 0", _nullable(_whole(0)), null_written=True, default=None)
    seconds: float | None = _json("a number > 0 (s)", _number(0.0, strict=True), default=None)
    episodes_requested: int | None = _json("a whole number >= 1", _whole(1), default=None)
    init_noise: InitNoise | None = _json("an object of InitNoise's numbers (>= 0)", _init_noise, asdict, default=None)
    corrector: str | None = _json("null or a corrector directory", _nullable(_TEXT), null_written=True, default=None)
    state_names: tuple[str, ...] = _json(f"this toolkit's {STATE_DIM} state channel names", _exactly(STATE_NAMES),
                                         _as_list)
    action_names: tuple[str, ...] = _json(f"this toolkit's {ACTION_DIM} joint names", _exactly(ACTION_NAMES),
                                          _as_list)
    fall_rule: str | None = _json("a rule (text)", _TEXT, default=None)
    missing_channels: tuple[str, ...] | None = _json("a list of state channel names", _texts(STATE_NAMES), _as_list,
                                                     default=None)
    effort_logged: bool | None = _json("true or false", _BOOL, default=None)
    hybrid_actions: bool | None = _json("true or false", _BOOL, default=None)
    episodes: tuple[EpisodeEntry, ...] = _json("a list of episode objects", _nested_list(EpisodeEntry),
                                               _write_nested_list, default=())
    empty_episodes: tuple[EmptyEpisode, ...] | None = _json("a list of episode objects", _nested_list(EmptyEpisode),
                                                            _write_nested_list, default=None)
    import_info: ImportInfo | None = _json("an object", _nested(ImportInfo), _write_fields, key="import", default=None)

    @classmethod
    def from_json(cls, block: Any, where: str | Path) -> "AcnMetadata":
        """The block read and checked; a one-line ``UserError`` naming ``where`` (the dataset) if
        any field is not what it must be or the rates do not agree."""
        try:
            if isinstance(block, dict) and "state_names" in block and block["state_names"] != list(STATE_NAMES):
                raise _Malformed("has different state channels than this toolkit")
            meta = _read_fields(cls, block, ACN_KEY)
            if problem := meta._inconsistency():
                raise _Malformed(problem)
        except _Malformed as e:
            raise UserError(f"{where} {e}") from None
        return meta

    def _inconsistency(self) -> str | None:
        if self.paired != (self.target is not None):
            return (f"has '{ACN_KEY}.paired' = {str(self.paired).lower()} with target "
                    f"{self.target.simulator if self.target else None!r} in meta/info.json: a paired dataset has a "
                    "target simulator and only a paired one")
        if self.hybrid_actions and self.action_mode != "position":
            return (f"has '{ACN_KEY}.hybrid_actions' with action mode {self.action_mode!r}: hybrid commands need "
                    "position mode")
        if abs(self.physics_dt * self.substeps * self.control_hz - 1.0) > 1e-6:
            return (f"has inconsistent rates in meta/info.json: physics_dt {self.physics_dt} s x substeps "
                    f"{self.substeps} is not one control period (control_hz {self.control_hz})")
        return None

    def to_json(self) -> dict[str, Any]:
        """The block as ``meta/info.json`` holds it (``from_json`` reads it back equal)."""
        return _write_fields(self)

    @property
    def direction(self) -> str:
        """``"source -> target"`` by simulator name (``None`` as the target of an unpaired dataset)."""
        return f"{self.source.simulator} -> {self.target.simulator if self.target else None}"

    @property
    def physics_hz(self) -> float:
        return 1.0 / self.physics_dt

    def sim_config(self, **extra: Any) -> SimConfig:
        """The simulator settings the block records (rates, action mode, gains, torque limit, what
        the accelerometer reads; an unstated reading is the schema's mean), plus ``extra``
        ``SimConfig`` fields."""
        return SimConfig(physics_dt=self.physics_dt, substeps=self.substeps, action_mode=self.action_mode,
                         kp=self.kp, kd=self.kd, torque_limit=self.torque_limit, imu_acc=self.imu_acc or "mean",
                         **extra)


@dataclass(frozen=True)
class DatasetCard:
    """What a reader knows of a dataset before its rows (``acn.datasets.reader.read_card``)."""

    path: Path
    robot_type: str | None  # LeRobot's own ``robot_type`` field of meta/info.json
    acn: AcnMetadata


def collection_metadata(cfg: CollectConfig) -> AcnMetadata:
    """The ``acn`` block of a collection with ``cfg`` (no episodes yet: the writer adds them)."""
    sim = cfg.sim
    return AcnMetadata(
        format_version=FORMAT_VERSION, paired=cfg.paired,
        source=Simulator(simulator=cfg.source, version=simulator_version(cfg.source)),
        target=Simulator(simulator=cfg.target, version=simulator_version(cfg.target)) if cfg.target else None,
        physics_dt=sim.physics_dt, substeps=sim.substeps, control_hz=round(1.0 / sim.control_dt, 9),
        action_mode=sim.action_mode, kp=sim.kp, kd=sim.kd, torque_limit=sim.torque_limit, imu_acc=sim.imu_acc,
        model_params=types.MappingProxyType(sim.params.as_json()), policy=cfg.policy, seed=cfg.seed,
        seconds=cfg.seconds, episodes_requested=cfg.episodes, init_noise=dataclasses.replace(cfg.init_noise),
        corrector=cfg.corrector, state_names=STATE_NAMES, action_names=ACTION_NAMES, fall_rule=FALL_RULE)


def config_from_metadata(meta: AcnMetadata, **overrides: Any) -> CollectConfig:
    """The collection config a dataset was recorded with (inverse of ``collection_metadata``);
    a one-line ``UserError`` for a dataset that records none (an imported log)."""
    from acn.sim.robot import ModelParams

    kept = {"seconds": meta.seconds, "episodes_requested": meta.episodes_requested, "seed": meta.seed,
            "init_noise": meta.init_noise}
    if lacking := [name for name, value in kept.items() if value is None]:
        raise UserError(f"the dataset (policy {meta.policy!r}) records no collection to run again: its "
                        f"'{ACN_KEY}' block has no {lacking[0]!r}")
    kw: dict[str, Any] = dict(
        source=meta.source.simulator, target=meta.target.simulator if meta.target else None, policy=meta.policy,
        episodes=meta.episodes_requested, seconds=meta.seconds, seed=meta.seed,
        sim=meta.sim_config(params=ModelParams.from_json(dict(meta.model_params))),
        init_noise=dataclasses.replace(meta.init_noise), corrector=None)
    kw.update(overrides)
    return CollectConfig(**kw)
