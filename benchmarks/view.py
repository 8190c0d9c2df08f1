"""acn-view speed, printed as name=value lines (the ratio is measured in this same run).

view_frames            frames in the benchmark dataset (paired: two robots per frame)
view_read_seconds      reading the dataset through LeRobotDataset
view_fk_seconds        MuJoCo forward kinematics of every frame of both robots
view_seconds           the whole of acn-view --save: read, kinematics, columnar logging of every
                       entity (robots, meshes, contacts, paths, joints, gait, divergence), the
                       blueprint, and the .rrd written; target <= 10 s for 50k frames on 2 cores
view_rrd_mb            size of the written .rrd
view_speedup           logging the same entities of one episode frame by frame (rr.set_time +
                       rr.log per frame and entity, the naive way) / columnar (send_columns),
                       kinematics precomputed for both, same recording sink

The dataset is one simulated paired episode set (PyBullet -> MuJoCo trot) written repeatedly
as ``--episodes`` episodes of ``--seconds`` s, so it is real data of the requested size
without simulating all of it.

Usage: python benchmarks/view.py [--episodes 100] [--seconds 10]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import rerun as rr  # noqa: E402

from acn.datasets.reader import load_frames  # noqa: E402
from acn.datasets.metadata import collection_metadata  # noqa: E402
from acn.datasets.writer import DatasetWriter  # noqa: E402
from acn.sim.collector import CollectConfig, collect_episodes  # noqa: E402
from acn.sim.state import FOOT_NAMES, GROUPS, JOINT_NAMES, SLICES  # noqa: E402
from acn.sim.kinematics import RobotKinematics  # noqa: E402
from acn.viz.log import log_episode, log_meshes  # noqa: E402
from acn.viz.meshes import link_meshes  # noqa: E402
from acn.viz.trajectories import recorded_episode  # noqa: E402
from acn.viz.view import ViewConfig, view  # noqa: E402


def make_dataset(root: Path, episodes: int, seconds: float) -> Path:
    """A paired dataset of ``episodes`` x ``seconds`` built from two simulated episodes."""
    cfg = CollectConfig(source="pybullet", target="mujoco", policy="trot", episodes=episodes, seconds=seconds)
    simulated = collect_episodes(replace(cfg, episodes=2), [0, 1])
    writer = DatasetWriter(root, fps=int(round(1 / cfg.sim.control_dt)), paired=True, task="trot (benchmark)",
                           acn_meta=collection_metadata(cfg))
    for i in range(episodes):
        writer.write(replace(simulated[i % 2], index=i))
    return writer.commit()


def log_per_frame(rec: rr.RecordingStream, episode, poses: dict) -> None:
    """The naive baseline: the same entities as ``log_episode``, one rr.log per frame and entity."""
    root, ref = episode.root, episode.trajectory(episode.reference)
    for traj in episode.trajectories:
        log_meshes(rec, f"{root}/robots/{traj.name}", link_meshes(), traj.color)
    for k, f in enumerate(episode.trajectories[0].frame):
        rec.set_time("frame", sequence=int(f))
        rec.set_time("sim_time", duration=float(episode.timestamp[f]))
        for lane, traj in enumerate(episode.trajectories):
            base, s, p = f"{root}/robots/{traj.name}", traj.state[k], poses[traj.name]
            for j, link in enumerate(p.links):
                rec.log(f"{base}/links/{link}", rr.Transform3D(translation=p.translation[k, j],
                                                               quaternion=p.quaternion[k, j]))
            contact = s[SLICES["contact"]] > 0.5
            rec.log(f"{base}/contacts", rr.Points3D(p.foot[k][contact]))
            for j, joint in enumerate(JOINT_NAMES):
                rec.log(f"{root}/joints/{joint}/{traj.name}", rr.Scalars(s[SLICES["joint_pos"]][j]))
            for i, foot in enumerate(FOOT_NAMES):
                rec.log(f"{root}/gait/{traj.name}/{foot}", rr.Scalars(i + 0.25 * lane if contact[i] else np.nan))
            if traj is not ref:
                d = s - ref.state[k]
                for g in GROUPS:
                    rec.log(f"{root}/divergence/{traj.name}/{g}", rr.Scalars(np.linalg.norm(d[SLICES[g]])))


class _Precomputed(RobotKinematics):
    """Kinematics answered from a table (the baseline gets the same precomputed poses)."""

    def __init__(self, poses: dict) -> None:
        self._queue = list(poses.values())  # in trajectory order, as log_episode asks

    def poses(self, states):
        return self._queue.pop(0)


def speedup(dataset: Path, tmp: Path) -> float:
    """Per-frame logging time / columnar logging time for episode 0 (kinematics precomputed)."""
    episode = recorded_episode(load_frames(dataset), 0)
    meshes = link_meshes()
    poses = {t.name: RobotKinematics().poses(t.state) for t in episode.trajectories}
    times = {}
    for name, body in (("columnar", lambda rec: log_episode(rec, episode, _Precomputed(poses), meshes)),
                       ("per_frame", lambda rec: log_per_frame(rec, episode, poses))):
        rec = rr.RecordingStream("acn-view-bench")
        rec.save(tmp / f"{name}.rrd")
        t = time.perf_counter()
        body(rec)
        rec.flush()
        times[name] = time.perf_counter() - t
        rec.disconnect()
    return times["per_frame"] / times["columnar"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=100)
    ap.add_argument("--seconds", type=float, default=10.0)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        dataset = make_dataset(tmp / "bench", args.episodes, args.seconds)
        t = time.perf_counter()
        frames = load_frames(dataset)
        read_s = time.perf_counter() - t
        t = time.perf_counter()
        kinematics = RobotKinematics()
        kinematics.poses(frames.state)
        kinematics.poses(frames.target_state)
        fk_s = time.perf_counter() - t
        t = time.perf_counter()
        out = view(ViewConfig(dataset=dataset, save=tmp / "bench.rrd"))
        view_s = time.perf_counter() - t
        print(f"view_frames={len(frames.episode)}")
        print(f"view_read_seconds={read_s:.2f}")
        print(f"view_fk_seconds={fk_s:.2f}")
        print(f"view_seconds={view_s:.2f}")
        print(f"view_rrd_mb={out.stat().st_size / 2**20:.1f}")
        print(f"view_speedup={speedup(dataset, tmp):.1f}")


if __name__ == "__main__":
    main()
