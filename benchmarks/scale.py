"""Past one machine: Ray against local processes, printed as name=value lines (same run).

workers_frames_per_s     acn-collect --workers 2: paired frames/s, dataset writing included
ray_frames_per_s         acn-collect --ray with a local 2-CPU Ray instance (already started)
ray_overhead_ratio       ray / workers frames/s; target >= 0.9 for >= 20 episodes
ray_start_s              starting the local Ray instance (once per command; a cluster is running already)
driver_peak_mb           the driver's peak resident memory during the Ray collection
driver_growth_mb         its resident memory at the end minus after the first quarter of episodes
dataset_mb               the dataset's size on disk (what the driver would hold if it kept the data)
writer_frames_per_s      the single writer alone (episodes already in memory): the serial ceiling
                         of one dataset, whatever the number of CPUs (--shards K writes K at once)
resim_local_rows_per_s   Resimulator.run (MuJoCo, 1 control step per row), 2 threads in-process
resim_ray_rows_per_s     the same batch through ray_executor (2 actors of 1 CPU, rows in chunks)
resim_ray_ratio          ray / local; the results are equal bit for bit (checked here)
ray_call_overhead_ms     extra wall time of a tiny batch sent to Ray instead of run locally
chunk_overhead_share     that overhead / the local time of a RAY_MIN_CHUNK_STEPS chunk (threshold check)

Each collection rate is the best of --rounds runs, workers and Ray interleaved (the machine is
shared and noisy). Usage: python benchmarks/scale.py [--episodes 20] [--seconds 10] [--rounds 2]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

os.environ.setdefault("HF_HUB_OFFLINE", "1")

from acn.datasets.record import record  # noqa: E402
from acn.datasets.writer import DatasetWriter  # noqa: E402
from acn.sim import parallel  # noqa: E402
from acn.sim.backends import SimConfig  # noqa: E402
from acn.sim.collector import CollectConfig, collect_episodes  # noqa: E402
from acn.sim.resim import Resimulator  # noqa: E402

PAGE = os.sysconf("SC_PAGE_SIZE")


def rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * PAGE / 2**20


class PeakMemory:
    """Samples this process's resident memory every 10 ms while in the block."""

    def __enter__(self) -> "PeakMemory":
        self.peak, self._stop = rss_mb(), threading.Event()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def _sample(self) -> None:
        while not self._stop.wait(0.01):
            self.peak = max(self.peak, rss_mb())

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()


def collect(cfg: CollectConfig, out: Path, **kw) -> tuple[float, list[float]]:
    """(frames/s, resident MB after each episode) of one record() call."""
    frames, memory = 0, []

    def count(ep) -> None:
        nonlocal frames
        frames += len(ep)
        memory.append(rss_mb())

    t = time.perf_counter()
    record(cfg, out, on_episode=count, overwrite=True, **kw)
    return frames / (time.perf_counter() - t), memory


def writer_rate(cfg: CollectConfig, root: Path, repeats: int) -> float:
    """Frames/s of DatasetWriter alone: a few episodes written ``repeats`` times, then committed."""
    from acn.datasets.metadata import collection_metadata

    episodes = collect_episodes(cfg, list(range(2)))
    writer = DatasetWriter(root, fps=int(round(1 / cfg.sim.control_dt)), paired=True, task="bench",
                           acn_meta=collection_metadata(cfg))
    frames = 0
    t = time.perf_counter()
    for _ in range(repeats):
        for ep in episodes:
            writer.write(ep)
            frames += len(ep)
    writer.commit()
    return frames / (time.perf_counter() - t)


def best_time(fn, repeats: int = 3) -> float:
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def resim(rows: int) -> dict[str, float]:
    """Local vs Ray re-simulation of ``rows`` recorded states, one control step each."""
    ep = collect_episodes(CollectConfig(target="mujoco", policy="random", episodes=1, seconds=4.0, seed=1), [0])[0]
    reps = -(-rows // len(ep))
    states = np.tile(ep.target.state, (reps, 1))[:rows]
    actions = np.tile(ep.target.action, (reps, 1))[:rows]
    tiny = 20
    with Resimulator("mujoco", SimConfig(), threads=2) as sim:
        local = sim.run(states, actions)
        t_local = best_time(lambda: sim.run(states, actions))
        t_tiny_local = best_time(lambda: sim.run(states[:tiny], actions[:tiny]), 5)
        chunk = parallel.RAY_MIN_CHUNK_STEPS
        t_chunk_local = best_time(lambda: sim.run(states[:chunk], actions[:chunk]))
    with parallel.ray_executor() as executor, Resimulator("mujoco", SimConfig(), threads=2) as sim:
        remote = sim.run(states, actions)  # actors start, models compile once per actor
        assert executor.batches == 1
        t_ray = best_time(lambda: sim.run(states, actions))
        executor.min_chunk_steps = 1  # force a tiny batch onto Ray
        t_tiny_ray = best_time(lambda: sim.run(states[:tiny], actions[:tiny]), 5)
    for field in ("state", "effort", "diverged"):
        assert np.array_equal(getattr(local, field), getattr(remote, field), equal_nan=True), field
    overhead = t_tiny_ray - t_tiny_local
    return {"resim_rows": rows, "resim_local_rows_per_s": rows / t_local, "resim_ray_rows_per_s": rows / t_ray,
            "resim_ray_ratio": t_local / t_ray, "ray_call_overhead_ms": 1000 * overhead,
            "chunk_overhead_share": overhead / t_chunk_local}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--resim-rows", type=int, default=20000)
    args = ap.parse_args()
    cfg = CollectConfig(target="mujoco", policy="trot", episodes=args.episodes, seconds=args.seconds)
    ray_cfg = parallel.RayConfig(cpus=2)
    out: dict[str, float] = {}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        record(CollectConfig(target="mujoco", episodes=1, seconds=0.1), root / "warmup")
        t = time.perf_counter()
        with parallel.ray_session(ray_cfg):
            out["ray_start_s"] = time.perf_counter() - t
            record(CollectConfig(target="mujoco", episodes=2, seconds=0.1), root / "warmup_ray", ray=ray_cfg)
            workers, ray, peak, growth = [], [], 0.0, 0.0
            for _ in range(args.rounds):
                workers.append(collect(cfg, root / "w2", workers=2)[0])
                with PeakMemory() as mem:
                    rate, memory = collect(cfg, root / "ray", ray=ray_cfg)
                ray.append(rate)
                peak = max(peak, mem.peak)
                growth = max(growth, memory[-1] - memory[max(0, len(memory) // 4 - 1)])
            out.update(resim(args.resim_rows))
        out["dataset_mb"] = sum(p.stat().st_size for p in (root / "ray").rglob("*") if p.is_file()) / 2**20
        out["writer_frames_per_s"] = writer_rate(cfg, root / "writer", repeats=10)
    out.update(episodes=args.episodes, seconds=args.seconds,
               workers_frames_per_s=max(workers), ray_frames_per_s=max(ray),
               ray_overhead_ratio=max(ray) / max(workers), driver_peak_mb=peak, driver_growth_mb=growth)
    order = ["episodes", "seconds", "workers_frames_per_s", "ray_frames_per_s", "ray_overhead_ratio", "ray_start_s",
             "driver_peak_mb", "driver_growth_mb", "dataset_mb", "writer_frames_per_s", "resim_rows",
             "resim_local_rows_per_s", "resim_ray_rows_per_s", "resim_ray_ratio", "ray_call_overhead_ms",
             "chunk_overhead_share"]
    for name in order:
        v = out[name]
        print(f"{name}={v:.3f}" if isinstance(v, float) else f"{name}={v}")
    print(f"all_ray_rates={','.join(f'{r:.0f}' for r in ray)} all_workers_rates={','.join(f'{r:.0f}' for r in workers)}")


if __name__ == "__main__":
    main()
