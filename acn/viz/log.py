"""Columnar logging of an episode into a Rerun recording (``send_columns``, never per frame).

Entity layout under an episode root ``episode_NNN`` (one subtree per episode):

- ``robots/<trajectory>/links/<link>``  per-frame ``Transform3D`` (link pose in the world, from
  MuJoCo forward kinematics) and a static ``Mesh3D`` in the link frame, tinted per trajectory;
  frames without a finite pose are left out; a log without any trunk pose gets a fixed,
  level trunk at standing height so its legs still show;
- ``robots/<trajectory>/contacts``      ``Points3D`` at the feet in contact, per frame;
- ``robots/<trajectory>/trunk_path``    static ``LineStrips3D`` of the trunk origin;
- ``joints/<joint>/<trajectory>``       joint angle, rad (``Scalars``, named and coloured series);
- ``divergence/<trajectory>/<group>``   ||s_trajectory - s_reference|| over a channel group
  (``acn.sim.state.GROUPS``, angles wrapped), in the group's units;
- ``gait/<trajectory>/<foot>``          stance band: a constant lane value while the foot is in
  contact, a gap (NaN) in swing.

A trajectory without contact readings (a model's prediction) has no gait band and no contact
markers; a channel group that is NaN throughout (not measured, not predicted) has no
divergence series.

Timelines: ``frame`` (index within the episode) and ``sim_time`` (s from the episode start),
the same for every trajectory, so trajectories line up frame by frame.

Further named series (``EpisodeView.series``, e.g. a diagnosis's residual per joint) go
through ``log_series`` onto the same timelines, next to the measured ones; documents
(``EpisodeView.documents``) are static markdown ``TextDocument``s.
"""

from __future__ import annotations

import numpy as np
import rerun as rr

from acn.datasets.reader import state_difference
from acn.sim.robot import STANDING_HEIGHT
from acn.sim.state import FOOT_NAMES, GROUPS, JOINT_NAMES, SLICES, STATE_DIM
from acn.sim.kinematics import RobotKinematics
from acn.viz.meshes import LinkMesh
from acn.viz.trajectories import EpisodeView, Trajectory

# Distinct colours for the channel groups of the divergence panel (tab10 order).
GROUP_COLORS = dict(zip(GROUPS, [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40),
                                 (148, 103, 189), (140, 86, 75), (227, 119, 194), (127, 127, 127)]))
CONTACT_MARKER_RADIUS = 0.025  # m
TRUNK_PATH_RADIUS = 0.004      # m
GAIT_LANE_OFFSET = 0.25        # lane of trajectory k for foot f: f + k * offset
GAIT_BAND_WIDTH = 6.0          # ui points
# What forward kinematics reads from a state: the trunk pose and the joint angles.
TRUNK_POSE = np.r_[np.arange(STATE_DIM)[SLICES["base_pos"]], np.arange(STATE_DIM)[SLICES["base_rpy"]]]
POSE = np.r_[TRUNK_POSE, np.arange(STATE_DIM)[SLICES["joint_pos"]]]
FIXED_TRUNK_POSE = np.array([0.0, 0.0, STANDING_HEIGHT, 0.0, 0.0, 0.0])  # m, rad


def timelines(episode: EpisodeView, frame: np.ndarray) -> list[rr.TimeColumn]:
    """The ``frame`` and ``sim_time`` columns for the given frame indices of ``episode``."""
    frame = np.asarray(frame, dtype=np.int64)
    return [rr.TimeColumn("frame", sequence=frame),
            rr.TimeColumn("sim_time", duration=episode.timestamp[frame])]


def log_series(rec: rr.RecordingStream, entity: str, episode: EpisodeView, frame: np.ndarray,
               values: np.ndarray, label: str, color: tuple[int, int, int], width: float | None = None) -> None:
    """One named scalar series on the episode's timelines (values (T,) at frames ``frame``)."""
    rec.send_columns(entity, indexes=timelines(episode, frame),
                     columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=np.float64)))
    rec.log(entity, rr.SeriesLines(colors=[color], names=[label], widths=None if width is None else [width]),
            static=True)


def log_meshes(rec: rr.RecordingStream, base: str, meshes: tuple[LinkMesh, ...], color: tuple[int, int, int]) -> None:
    """Static link meshes under ``base/links/<link>`` (drawn at the link's logged pose)."""
    for mesh in meshes:
        rec.log(f"{base}/links/{mesh.link}",
                rr.Mesh3D(vertex_positions=mesh.vertices, triangle_indices=mesh.triangles,
                          vertex_normals=mesh.normals, albedo_factor=[*color, 255]), static=True)


def log_robot(rec: rr.RecordingStream, episode: EpisodeView, traj: Trajectory, kinematics: RobotKinematics,
              meshes: tuple[LinkMesh, ...]) -> None:
    """The 3D robot of one trajectory: link poses per frame, meshes, foot contacts, trunk path."""
    base = f"{episode.root}/robots/{traj.name}"
    state = traj.state.copy()
    if np.isnan(state[:, TRUNK_POSE]).all():  # a log without the trunk pose: legs under a fixed trunk
        state[:, TRUNK_POSE] = FIXED_TRUNK_POSE
    finite = np.isfinite(state[:, POSE]).all(axis=1)
    state, frame = state[finite], traj.frame[finite]
    if not len(frame):
        return
    poses = kinematics.poses(state)
    times = timelines(episode, frame)
    for k, link in enumerate(poses.links):
        rec.send_columns(f"{base}/links/{link}", indexes=times,
                         columns=rr.Transform3D.columns(translation=poses.translation[:, k],
                                                        quaternion=poses.quaternion[:, k]))
    log_meshes(rec, base, meshes, traj.color)

    if not np.isnan(state[:, SLICES["contact"]]).all():  # a prediction has no contact readings
        contact = state[:, SLICES["contact"]] > 0.5
        rec.send_columns(f"{base}/contacts", indexes=times,
                         columns=rr.Points3D.columns(positions=poses.foot[contact]).partition(contact.sum(axis=1)))
        rec.log(f"{base}/contacts", rr.Points3D.from_fields(colors=[traj.color], radii=[CONTACT_MARKER_RADIUS]),
                static=True)
    rec.log(f"{base}/trunk_path", rr.LineStrips3D([state[:, SLICES["base_pos"]]], colors=[traj.color],
                                                   radii=[TRUNK_PATH_RADIUS]), static=True)


def log_joints(rec: rr.RecordingStream, episode: EpisodeView, traj: Trajectory) -> None:
    """Joint angles (rad) of one trajectory, one series per joint."""
    q = traj.state[:, SLICES["joint_pos"]]
    for j, joint in enumerate(JOINT_NAMES):
        log_series(rec, f"{episode.root}/joints/{joint}/{traj.name}", episode, traj.frame, q[:, j],
                   traj.label, traj.color)


def log_gait(rec: rr.RecordingStream, episode: EpisodeView, traj: Trajectory, lane: int) -> None:
    """Stance/swing band per foot: value ``foot + lane * GAIT_LANE_OFFSET`` in stance, gap in swing."""
    if np.isnan(traj.state[:, SLICES["contact"]]).all():  # no contact readings (a prediction)
        return
    contact = traj.state[:, SLICES["contact"]] > 0.5
    for f, foot in enumerate(FOOT_NAMES):
        band = np.where(contact[:, f], f + lane * GAIT_LANE_OFFSET, np.nan)
        log_series(rec, f"{episode.root}/gait/{traj.name}/{foot}", episode, traj.frame, band,
                   f"{foot} {traj.label}", traj.color, width=GAIT_BAND_WIDTH)


def log_divergence(rec: rr.RecordingStream, episode: EpisodeView, traj: Trajectory, reference: Trajectory) -> None:
    """||s - s_ref|| per channel group on the frames both trajectories have."""
    common, i, j = np.intersect1d(traj.frame, reference.frame, return_indices=True)
    d = state_difference(traj.state[i], reference.state[j])
    for group in GROUPS:
        norm = np.linalg.norm(d[:, SLICES[group]], axis=1)
        if np.isnan(norm).all():  # not measured or not predicted
            continue
        log_series(rec, f"{episode.root}/divergence/{traj.name}/{group}", episode, common, norm, group,
                   GROUP_COLORS[group])


def log_episode(rec: rr.RecordingStream, episode: EpisodeView, kinematics: RobotKinematics,
                meshes: tuple[LinkMesh, ...]) -> None:
    """Everything of one episode (see module docstring)."""
    rec.log(episode.root, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    reference = episode.trajectory(episode.reference) if episode.reference else None
    for lane, traj in enumerate(episode.trajectories):
        log_robot(rec, episode, traj, kinematics, meshes)
        log_joints(rec, episode, traj)
        log_gait(rec, episode, traj, lane)
        if reference is not None and traj is not reference:
            log_divergence(rec, episode, traj, reference)
    for series in episode.series:
        log_series(rec, f"{episode.root}/{series.path}", episode, series.frame, series.values, series.label,
                   series.color, series.width)
    for doc in episode.documents:
        rec.log(f"{episode.root}/{doc.path}", rr.TextDocument(doc.text, media_type=rr.MediaType.MARKDOWN),
                static=True)
