"""``acn-view``: a dataset (a corrector's closed loop, a model's predictions) in the Rerun
viewer, or in a ``.rrd``.

Steps: read the dataset (``acn.datasets.reader.load_frames``) -> one ``EpisodeView`` per
selected episode with its recorded trajectories (+ the corrected target with ``--corrector``;
+ the model's one-step prediction, residuals and error per added effect with ``--model``,
``acn.viz.diagnosis``)
-> log every episode columnar (``acn.viz.log``) -> one blueprint (``acn.viz.blueprint``) ->
a spawned viewer, or a ``.rrd`` written all or nothing (temporary file, then rename).
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path

from acn.datasets.reader import RecordedFrames, load_frames
from acn.errors import UserError
from acn.outputs.kinds import Output
from acn.outputs.writing import replacing
from acn.viz.blueprint import build_blueprint
from acn.viz.meshes import DEFAULT_CELL, link_meshes
from acn.viz.trajectories import EpisodeView, corrected_target, corrector_target, parse_episodes, recorded_episode

APPLICATION_ID = "acn-view"


@dataclass
class ViewConfig:
    """What ``acn-view`` shows and where it goes."""

    dataset: Path
    episodes: str | None = None     # "0,3,5"; None: every episode
    corrector: Path | None = None   # frozen corrector directory (acn-fit output)
    model: str | Path | None = None  # mujoco, pybullet or a MODEL.json of acn-diagnose (diagnosis view)
    diagnosis: Path | None = None   # acn-diagnose --json result, shown as text with --model
    save: Path | None = None        # write this .rrd instead of opening the viewer
    mesh_cell: float = DEFAULT_CELL  # m, mesh simplification grid (0: original meshes)


def has_display() -> bool:
    """Whether a viewer window can open here."""
    if sys.platform in ("darwin", "win32"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def default_rrd_path(dataset: Path) -> Path:
    """Where the recording goes without ``--save`` and without a display: beside the dataset."""
    dataset = Path(dataset)
    return dataset.parent / f"{dataset.resolve().name}.rrd"


def load_corrector(directory: Path, frames: RecordedFrames):
    """A frozen corrector fitted for this dataset's target, or a one-line ``UserError``."""
    from acn.corrector.corrector import load_for_target

    if not frames.paired:
        raise UserError(f"--corrector needs a paired dataset (source and target); {frames.path} has measurements only")
    return load_for_target(directory, corrector_target(frames))


def add_model_trajectories(model_path: str | Path, frames: RecordedFrames, episodes: list[EpisodeView],
                           diagnosis: Path | None = None) -> None:
    """The diagnosis view (``acn.viz.diagnosis``): measured against the model's one-step
    prediction, residuals per joint, the error as the model's effects are added, and the
    ``acn-diagnose --json`` result ``diagnosis`` as text."""
    from acn.viz.diagnosis import add_diagnosis_view

    add_diagnosis_view(model_path, frames, episodes, diagnosis)


def prepare(cfg: ViewConfig) -> tuple[RecordedFrames, list[EpisodeView]]:
    """Read the dataset and build the trajectories of every selected episode."""
    if cfg.diagnosis is not None and cfg.model is None:
        raise UserError("--diagnosis needs --model (the model whose predictions are shown)")
    if cfg.model is not None:  # bad model or diagnosis files fail before anything is read
        from acn.sim.effects import Model
        from acn.viz.diagnosis import load_diagnosis

        Model.parse(cfg.model)
        if cfg.diagnosis is not None:
            load_diagnosis(cfg.diagnosis)
    if not Path(cfg.dataset).is_dir():
        raise UserError(f"{cfg.dataset} is not a dataset directory")
    frames = load_frames(cfg.dataset)
    selected = parse_episodes(cfg.episodes, frames.episodes, str(cfg.dataset))
    corrector = load_corrector(cfg.corrector, frames) if cfg.corrector is not None else None
    episodes = []
    for k in selected:
        ep = recorded_episode(frames, k)
        if corrector is not None:
            ep.trajectories.append(corrected_target(frames, ep, corrector))
        episodes.append(ep)
    if cfg.model is not None:
        add_model_trajectories(cfg.model, frames, episodes, cfg.diagnosis)
    return frames, episodes


def record(rec, episodes: list[EpisodeView], mesh_cell: float = DEFAULT_CELL) -> None:
    """Log ``episodes`` into the recording stream ``rec``."""
    from acn.sim.kinematics import RobotKinematics
    from acn.viz.log import log_episode

    kinematics, meshes = RobotKinematics(), link_meshes(mesh_cell)
    for ep in episodes:
        log_episode(rec, ep, kinematics, meshes)


def _is_recording(path: Path) -> bool:
    """A Rerun recording: the file starts with Rerun's magic bytes."""
    try:
        with open(path, "rb") as f:
            return f.read(3) == b"RRF"
    except OSError:
        return False


RECORDING = Output("Rerun recording (.rrd)", directory=False, recognise=_is_recording)


def write_rrd(episodes: list[EpisodeView], out: Path, mesh_cell: float = DEFAULT_CELL) -> Path:
    """Write a ``.rrd`` (recording + blueprint) all or nothing; returns its path as given."""
    import rerun as rr

    out = Path(out)
    if out.is_dir():
        raise UserError(f"--save {out} is a directory; give a file name ending in .rrd")
    out.parent.mkdir(parents=True, exist_ok=True)
    rec = rr.RecordingStream(APPLICATION_ID)
    with replacing(out, RECORDING) as tmp:
        rec.save(tmp)
        # Active, not only default: a viewer keeps the last layout per application otherwise.
        rec.send_blueprint(build_blueprint(episodes), make_active=True, make_default=True)
        record(rec, episodes, mesh_cell)
        rec.flush()
        rec.disconnect()
    return out


def spawn_viewer(episodes: list[EpisodeView], mesh_cell: float = DEFAULT_CELL) -> None:
    """Open the Rerun viewer and stream the episodes into it."""
    import rerun as rr

    rec = rr.RecordingStream(APPLICATION_ID)
    rec.spawn()
    rec.send_blueprint(build_blueprint(episodes), make_active=True, make_default=True)
    record(rec, episodes, mesh_cell)
    rec.flush()
    rec.disconnect()


def view(cfg: ViewConfig) -> Path | None:
    """Run ``acn-view``: the written ``.rrd`` path, or None when a viewer was opened."""
    _, episodes = prepare(cfg)
    if cfg.save is None and has_display():
        spawn_viewer(episodes, cfg.mesh_cell)
        return None
    return write_rrd(episodes, cfg.save or default_rrd_path(cfg.dataset), cfg.mesh_cell)
