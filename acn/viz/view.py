"""``acn-view``: a dataset (and a corrector's closed loop) in the Rerun viewer, or in a ``.rrd``.

Steps: read the dataset (``acn.datasets.reader.load_frames``) -> one ``EpisodeView`` per
selected episode with its recorded trajectories (+ the corrected target with ``--corrector``)
-> log every episode columnar (``acn.viz.log``) -> one blueprint (``acn.viz.blueprint``) ->
a spawned viewer, or a ``.rrd`` written all or nothing (temporary file, then rename).
"""

from __future__ import annotations

import json
import os
import sys
from dataclasses import dataclass
from pathlib import Path

from acn.datasets.reader import RecordedFrames, load_frames
from acn.errors import UserError
from acn.viz.blueprint import build_blueprint
from acn.viz.meshes import DEFAULT_CELL, link_meshes
from acn.viz.trajectories import EpisodeView, check_corrector_fits, corrected_target, parse_episodes, recorded_episode

APPLICATION_ID = "acn-view"


@dataclass
class ViewConfig:
    """What ``acn-view`` shows and where it goes."""

    dataset: Path
    episodes: str | None = None     # "0,3,5"; None: every episode
    corrector: Path | None = None   # frozen corrector directory (acn-fit output)
    model: Path | None = None       # MODEL.json of acn-diagnose (diagnosis view)
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


def _diagnosis_available() -> bool:
    try:
        import acn.toolkit.effects  # noqa: F401
    except Exception:  # noqa: BLE001 - missing or broken: either way not available
        return False
    return True


def load_corrector(directory: Path, frames: RecordedFrames):
    """A frozen corrector that fits this dataset, or a one-line ``UserError``."""
    from acn.models.corrector import CONFIG, Corrector

    if not frames.paired:
        raise UserError(f"--corrector needs a paired dataset (source and target); {frames.path} has measurements only")
    path = Path(directory) / CONFIG
    if path.is_file():
        try:
            check_corrector_fits(json.loads(path.read_text()), frames, str(directory))
        except (json.JSONDecodeError, UnicodeDecodeError, AttributeError, TypeError):
            pass  # Corrector.load reports a broken config
    return Corrector.load(directory)


def add_model_trajectories(model_path: Path, frames: RecordedFrames, episodes: list[EpisodeView]) -> None:
    """The diagnosis view: measured against the identified model's prediction, residuals, errors.

    TODO(diagnosis): plug acn-diagnose in here. For each ``EpisodeView`` in ``episodes``:
    - the model's prediction of the episode -> ``episode.trajectories.append(Trajectory("model",
      "model (MODEL.json)", states, frames))``: the 3D robot, joint series against the measured
      ones, gait band and divergence from the reference come for free (``acn.viz.log``);
    - the residual per joint and the error before/after each added effect are extra series:
      ``episode.series.append(Series("residual/<joint>", "<joint>", values, frames))`` and
      ``Series("effects/<effect>", "+ <effect>", error, frames)`` (``acn.viz.log.log_series``
      puts them on the same timelines), plus ``episode.panels.append(Panel("residual per
      joint, rad", "residual"))`` / ``Panel("error after each added effect", "effects")`` so
      the blueprint (``acn.viz.blueprint.episode_tab``) shows them in the bottom row.
    """
    raise UserError("--model: the diagnosis view is not wired to acn-diagnose yet")


def prepare(cfg: ViewConfig) -> tuple[RecordedFrames, list[EpisodeView]]:
    """Read the dataset and build the trajectories of every selected episode."""
    if cfg.model is not None and not _diagnosis_available():
        raise UserError("--model needs acn-diagnose (not available yet)")
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
        if not Path(cfg.model).is_file():
            raise UserError(f"model file {cfg.model} does not exist")
        add_model_trajectories(cfg.model, frames, episodes)
    return frames, episodes


def record(rec, episodes: list[EpisodeView], mesh_cell: float = DEFAULT_CELL) -> None:
    """Log ``episodes`` into the recording stream ``rec``."""
    from acn.viz.kinematics import RobotKinematics
    from acn.viz.log import log_episode

    kinematics, meshes = RobotKinematics(), link_meshes(mesh_cell)
    for ep in episodes:
        log_episode(rec, ep, kinematics, meshes)


def write_rrd(episodes: list[EpisodeView], out: Path, mesh_cell: float = DEFAULT_CELL) -> Path:
    """Write a ``.rrd`` (recording + blueprint) all or nothing; returns its path as given."""
    import rerun as rr

    out = Path(out)
    if out.is_dir():
        raise UserError(f"--save {out} is a directory; give a file name ending in .rrd")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.parent / f".{out.name}.partial-{os.getpid()}"
    rec = rr.RecordingStream(APPLICATION_ID)
    try:
        rec.save(tmp)
        # Active, not only default: a viewer keeps the last layout per application otherwise.
        rec.send_blueprint(build_blueprint(episodes), make_active=True, make_default=True)
        record(rec, episodes, mesh_cell)
        rec.flush()
        rec.disconnect()
        os.replace(tmp, out)
    finally:
        tmp.unlink(missing_ok=True)
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
