"""What the view shows: per episode, a few named trajectories of the A1 on shared frames.

A ``Trajectory`` is one robot's states on (a subset of) an episode's frames: the recorded
source and target of a paired dataset, the measured robot of an unpaired one, the target
re-simulated under a corrector, and the model's one-step prediction of a diagnosis. Each gets
the same treatment (3D robot, joint series, gait band, divergence from the reference), so
a new source of trajectories is one more ``Trajectory`` in ``EpisodeView.trajectories``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from acn.corrector.card import TargetDescription
from acn.datasets.reader import RecordedFrames
from acn.errors import UserError
from acn.sim.state import STATE_NAMES

# One colour per trajectory name (RGB, 0-255), used for meshes, markers and series alike.
COLORS: dict[str, tuple[int, int, int]] = {
    "source": (31, 119, 180),     # blue
    "measured": (31, 119, 180),
    "target": (255, 127, 14),     # orange
    "corrected": (44, 160, 44),   # green
    "model": (148, 103, 189),     # purple (diagnosis: the identified model's prediction)
}
OTHER_COLOR = (127, 127, 127)


@dataclass
class Trajectory:
    """States of one robot on frames ``frame`` of an episode."""

    name: str            # entity name: source, target, corrected, measured, model, ...
    label: str           # legend text, e.g. "mujoco (target)"
    state: np.ndarray    # (T, 43) state vectors (``acn.sim.state``)
    frame: np.ndarray    # (T,) int, frame indices within the episode (ascending)

    @property
    def color(self) -> tuple[int, int, int]:
        return COLORS.get(self.name, OTHER_COLOR)


@dataclass
class Panel:
    """An extra panel of an episode's tab (entities under ``root/origin``): ``kind`` "series"
    (a time-series panel, bottom row) or "text" (a markdown ``Document``, under the robot)."""

    title: str
    origin: str          # entity path relative to the episode root, e.g. "residual"
    kind: str = "series"
    legend: bool = True  # a time-series panel's legend


@dataclass
class Series:
    """An extra named scalar series of an episode (e.g. a diagnosis's residual of one joint)."""

    path: str            # entity path relative to the episode root, e.g. "residual/FR_hip"
    label: str           # legend text
    values: np.ndarray   # (T,)
    frame: np.ndarray    # (T,) int, frame indices within the episode
    color: tuple[int, int, int] = OTHER_COLOR
    width: float | None = None  # line width, ui points (None: Rerun's default)


@dataclass
class Document:
    """A static markdown text of an episode (e.g. a diagnosis's verdict and ranking)."""

    path: str            # entity path relative to the episode root, e.g. "diagnosis"
    text: str            # markdown


@dataclass
class EpisodeView:
    """One episode: its timelines, trajectories, extra series and the panels that show them."""

    index: int                   # the dataset's episode_index
    timestamp: np.ndarray        # (T,) s, time of each frame (frame k at timestamp[k])
    trajectories: list[Trajectory]
    reference: str | None = None  # divergence of every other trajectory is measured from this one
    series: list[Series] = field(default_factory=list)
    panels: list[Panel] = field(default_factory=list)
    documents: list[Document] = field(default_factory=list)

    @property
    def root(self) -> str:
        return f"episode_{self.index:03d}"

    def trajectory(self, name: str) -> Trajectory:
        for t in self.trajectories:
            if t.name == name:
                return t
        raise KeyError(name)


def parse_episodes(text: str | None, available: list[int], dataset: str) -> list[int]:
    """``"0,3,5"`` -> [0, 3, 5], each checked against the dataset (None: all episodes)."""
    if text is None:
        return list(available)
    try:
        wanted = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise UserError(f"--episodes expects comma-separated episode numbers, got {text!r}") from None
    if not wanted:
        raise UserError("--episodes is empty")
    missing = [e for e in wanted if e not in available]
    if missing:
        span = f"{available[0]}-{available[-1]}" if available else "none"
        raise UserError(f"episode {missing[0]} does not exist in {dataset} (it has episodes {span})")
    return list(dict.fromkeys(wanted))


def recorded_episode(frames: RecordedFrames, episode: int) -> EpisodeView:
    """The recorded trajectories of one episode: source and target, or the measured robot."""
    rows = frames.rows(episode)
    frame = frames.frame[rows]
    source_sim = frames.info.source.simulator
    if frames.paired:
        target_sim = frames.info.target.simulator
        trajectories = [Trajectory("source", f"{source_sim} (source)", frames.state[rows], frame),
                        Trajectory("target", f"{target_sim} (target)", frames.target_state[rows], frame)]
        reference = "source"
    else:
        trajectories = [Trajectory("measured", f"{source_sim} (measured)", frames.state[rows], frame)]
        reference = "measured"
    timestamp = np.zeros(int(frame.max()) + 1 if len(frame) else 0)
    timestamp[frame] = frames.timestamp[rows]
    missing = np.setdiff1d(np.arange(len(timestamp)), frame)
    timestamp[missing] = missing / frames.fps
    return EpisodeView(episode, timestamp, trajectories, reference)


def corrector_target(frames: RecordedFrames) -> TargetDescription:
    """What a corrector runs on in ``corrected_target``: the dataset's target simulator, action mode,
    control rate and action channels, with the physical effects the corrector was fitted on top of."""
    info = frames.info
    return TargetDescription(info.target.simulator, info.action_mode, info.control_hz, effects=None,
                             action_channels=info.action_names)


def corrected_target(frames: RecordedFrames, episode: EpisodeView, corrector) -> Trajectory:
    """The target re-simulated in closed loop with ``a~ = a + F(s_target, a)``.

    The target is the dataset's target simulator with the physical effects the corrector was
    fitted on top of (``acn-fit --model``; none for a corrector of the simulator as is). It
    starts from the recorded target state of frame 0 and receives the recorded source actions
    (the policy acts on the source state, so these are the actions a paired collection would
    send), corrected on its own state at every step. Stops early only if the simulator blows
    up. Frame k of the result is the state before the k-th action.
    """
    from acn.datasets.metadata import config_from_metadata
    from acn.sim.backends import SimulationDiverged, make_backend
    from acn.sim.effects import Model

    import torch

    cfg = config_from_metadata(frames.info)
    model = Model.from_json({"backend": cfg.target, "effects": list(corrector.card.training_data.target_effects)},
                            where="the corrector's config")
    cfg = replace(cfg, target_effects=list(model.effects))
    rows = frames.rows(episode.index)
    actions = frames.action[rows]
    states = np.empty((len(rows), len(STATE_NAMES)))
    threads = torch.get_num_threads()
    # One row per call: torch's intra-op threads only add overhead (measured 8 ms per call on a
    # busy 2-core machine instead of about 0.1 ms with one thread).
    torch.set_num_threads(1)
    try:
        with make_backend(cfg.target, cfg.target_sim) as sim:
            s = sim.reset(frames.target_state[rows[0]])
            n = 0
            for k, a in enumerate(actions):
                states[k] = s
                n = k + 1
                try:
                    sim.step(corrector.correct(s, a))
                except SimulationDiverged:
                    break
                s = sim.get_state()
    finally:
        torch.set_num_threads(threads)
    return Trajectory("corrected", f"{model.describe()} corrected", states[:n], frames.frame[rows][:n])
