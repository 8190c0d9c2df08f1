"""ACN training speed, printed as name=value lines, on the same data and network in one run.

baseline_samples_per_s   the paper authors' loop: a per-sample torch Dataset of tensors and a
                         DataLoader (batch 256, shuffle), ActionNet + JacobianNet, their loss
                         (J delta_a by torch.bmm, autograd), Adam, float32
fit_samples_per_s        acn-fit's loop (acn.corrector.train): plain PyTorch (autograd,
                         torch.optim.Adam(fused=True)) on tensors held whole, a batch one index
                         gather, the matmuls in bf16 under torch.autocast where the CPU has native
                         bf16 (fit_bf16=1), the loss summed on the device
fit_threads              the torch thread count acn-fit's loop ran on (--train-threads, default 1)
fit_speedup              fit / baseline, each on its default threads (acn-fit: one; the baseline:
                         torch's, all cores; on a busy machine the baseline's threads wait on each other)
fit_1_thread_samples_per_s  acn-fit's loop on one thread (--train-threads 1)
fit_speedup_1_thread     fit_1_thread / the baseline on one thread too (equal resources, one core)
fit_fp32_1_thread_samples_per_s  acn-fit's loop on one thread in float32 (--precision fp32)
fit_speedup_fp32_1_thread  fit_fp32_1_thread / the baseline on one thread: the loop alone, same precision
fit_all_threads_samples_per_s  acn-fit's loop on torch's default threads (--train-threads 0)
fit_speedup_all_threads  fit_all_threads / the baseline (equal resources, all cores)
fit_all_threads_vs_1_thread  what all cores gain (or cost) here over one thread
inverse_samples_per_s    acn-fit's loop with inverse's network and batch (512 wide, batch 64; the
                         default variant, what `make demo` trains): its default, one thread, all threads
fit_gflops               training FLOP/s of acn-fit's loop (forward + backward ~ 3x forward)
matmul_gflops            this machine's float32 matmul rate on the network's widest layer shape
matmul_bf16_gflops       the same in bf16
fit_fraction_of_matmul   fit_gflops / matmul_gflops
million_frames_10_epochs_s  projected time for 1M frames x 10 epochs at fit_samples_per_s
label_rows_per_s         Gauss-Newton same-state labels (acn.corrector.labels.solve, acn-fit's default
                         solve) on real paired trot rows, with 1 and 2 re-simulation threads
label_simulator_share    the share of the labelling time spent inside the re-simulation (MuJoCo)
label_thread_scaling     label_rows_per_s with 2 threads / with 1

With --device cuda, the same loops on the GPU instead of the CPU and no labelling (without the
flag, these lines follow the CPU's wherever torch sees a GPU):
cuda_baseline_samples_per_s  the authors' loop with its tensors on the GPU
cuda_fit_samples_per_s       acn-fit's loop, each full-batch step replayed as one CUDA graph
cuda_fit_eager_samples_per_s acn-fit's loop launched from Python (--no-cuda-graph)
cuda_fit_speedup             cuda_fit / cuda_baseline;  cuda_graph_speedup  cuda_fit / cuda_fit_eager
cuda_inverse_samples_per_s   acn-fit's loop with inverse's network and batch (512 wide, batch 64)

Data: synthetic rows with the real shapes (40 state + 12 action inputs, 33 residual channels):
speed does not depend on the values. Usage: python benchmarks/fit.py [--samples 100000] [--busy 1]
(--busy N: every training loop runs beside N processes that keep a core busy each, as on a shared
machine; busy_processes= says how many).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from contextlib import contextmanager
from dataclasses import replace
from typing import Iterator

import torch
from torch.utils.data import DataLoader, Dataset

from acn.corrector.acn import INPUT_CHANNELS, OUTPUT_CHANNELS
from acn.corrector.card import CorrectorCard
from acn.corrector.config import FitConfig
from acn.corrector.corrector import Corrector, torch_threads
from acn.corrector.rows import Split
from acn.corrector.train import train

N_IN, N_OUT, N_ACT = len(INPUT_CHANNELS) + 12, len(OUTPUT_CHANNELS), 12


class PerSampleDataset(Dataset):
    """One dict of tensors per sample, as the authors' training script builds it."""

    def __init__(self, state, action, delta_s):
        self.state, self.action, self.delta_s = state, action, delta_s

    def __len__(self):
        return len(self.state)

    def __getitem__(self, i):
        return {"state": self.state[i], "action": self.action[i], "delta_s": self.delta_s[i]}


def paper_loss(delta_a: torch.Tensor, jacobian: torch.Tensor, residual: torch.Tensor, lambda_l1: float):
    """The paper's loss as the authors compute it: J delta_a by torch.bmm, autograd for the rest."""
    predicted = torch.bmm(jacobian, delta_a.unsqueeze(-1)).squeeze(-1)
    fit = (predicted - residual).pow(2).mean()
    return fit + lambda_l1 * delta_a.abs().sum(dim=1).mean(), fit


def baseline(model: Corrector, x: torch.Tensor, r: torch.Tensor, epochs: int, device: str = "cpu") -> float:
    ds = PerSampleDataset(x[:, :-N_ACT].clone(), x[:, -N_ACT:].clone(), r.clone())
    loader = DataLoader(ds, batch_size=256, shuffle=True)
    model.net.to(device)
    opt = torch.optim.Adam(model.net.parameters(), lr=1e-3)
    model.net.train()
    t, n = time.perf_counter(), 0
    for _ in range(epochs):
        for batch in loader:
            inp = torch.cat([batch["state"], batch["action"]], dim=-1).to(device, non_blocking=True)
            batch["delta_s"] = batch["delta_s"].to(device, non_blocking=True)
            delta_a, jac = model.net(inp)
            loss, _ = paper_loss(delta_a, jac, batch["delta_s"], 0.01)
            opt.zero_grad()
            loss.backward()
            opt.step()
            n += len(inp)
    if device != "cpu":
        torch.cuda.synchronize()
    return n / (time.perf_counter() - t)


def flops_per_sample(model: Corrector) -> float:
    fwd = sum(2 * m.in_features * m.out_features for m in model.net.modules() if isinstance(m, torch.nn.Linear))
    return 3.0 * fwd  # forward + backward (two matmuls per layer)


def matmul_gflops(seconds: float = 1.0, dtype=torch.float32) -> float:
    a, b = torch.randn(256, 256, dtype=dtype), torch.randn(256, 396, dtype=dtype)
    for _ in range(10):
        a @ b
    t, n = time.perf_counter(), 0
    while time.perf_counter() - t < seconds:
        for _ in range(50):
            a @ b
        n += 50
    return n * 2 * 256 * 256 * 396 / (time.perf_counter() - t) / 1e9


def ours(cfg: FitConfig, model: Corrector, split: Split) -> tuple[float, int]:
    """acn-fit's loop, as acn-fit runs it: samples/s and the thread count it ended on."""
    t = time.perf_counter()
    history = train(model, split, cfg)
    return len(split) * cfg.epochs / (time.perf_counter() - t), history[-1].get("threads", 0)


def inverse_split(x: torch.Tensor, r: torch.Tensor) -> tuple[Corrector, Split]:
    model = Corrector(CorrectorCard.untrained("inverse", 512, 2))
    n_in = model.net.action_net[0].in_features
    return model, Split(x[:, :n_in].contiguous(), r, torch.randn(len(x), N_OUT, N_ACT), torch.randn(len(x), N_ACT),
                        torch.ones(N_ACT))


@contextmanager
def busy_cores(n: int) -> Iterator[None]:
    """``n`` other processes spinning on the CPU for the block: a shared machine's load."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--samples", type=int, default=100_000)
    ap.add_argument("--epochs", type=int, default=2)
    ap.add_argument("--label-rows", type=int, default=500, help="0: no labelling (a machine without MuJoCo)")
    ap.add_argument("--device", default="cpu", help="cpu, or cuda: the GPU loops instead (no labelling)")
    ap.add_argument("--busy", type=int, default=0, help="run the training loops beside this many spinning processes")
    args = ap.parse_args()
    torch.manual_seed(0)
    x, r = torch.randn(args.samples, N_IN), torch.randn(args.samples, N_OUT)
    if args.device != "cpu":
        return gpu(x, r, args.epochs, args.device)
    make = lambda: Corrector(CorrectorCard.untrained("paper", 256, 2))  # noqa: E731
    cfg = FitConfig(variant="paper", epochs=args.epochs)  # the paper's network and batch 256, one thread
    everything = torch.get_num_threads()  # torch's default: all cores
    with busy_cores(args.busy):
        # Each loop once on a small slice first, on every count: the kernels' one-time set-up
        # (oneDNN's primitives, per thread count) would otherwise fall on whichever runs first.
        for threads in (1, everything):
            with torch_threads(threads):
                baseline(make(), x[:2048], r[:2048], 1)
            for precision in ("auto", "fp32"):
                ours(replace(cfg, epochs=1, train_threads=threads, precision=precision), make(),
                     Split(x[:2048], r[:2048], None))
        # One thread, then all: each pair of loops back to back, as the machine's load drifts.
        with torch_threads(1):
            base_1 = baseline(make(), x, r, args.epochs)
        fit_1, _ = ours(replace(cfg, train_threads=1), make(), Split(x, r, None))
        fit_fp32_1, _ = ours(replace(cfg, train_threads=1, precision="fp32"), make(), Split(x, r, None))
        base = baseline(make(), x, r, args.epochs)
        fit, threads = ours(cfg, make(), Split(x, r, None))
        fit_all, _ = ours(replace(cfg, train_threads=0), make(), Split(x, r, None))
        inverse = FitConfig(variant="inverse", epochs=1)  # its defaults: 512 wide, batch 64, cosine
        inv, _ = ours(inverse, *inverse_split(x, r))
        inv_1, _ = ours(replace(inverse, train_threads=1), *inverse_split(x, r))
        inv_all, _ = ours(replace(inverse, train_threads=0), *inverse_split(x, r))
    gflops = fit * flops_per_sample(make()) / 1e9
    peak = matmul_gflops()
    print(f"busy_processes={args.busy}")
    print(f"baseline_samples_per_s={base:.0f}")
    print(f"fit_samples_per_s={fit:.0f}")
    print(f"fit_threads={threads}")
    print(f"fit_speedup={fit / base:.3f}")
    print(f"baseline_1_thread_samples_per_s={base_1:.0f}")
    print(f"fit_1_thread_samples_per_s={fit_1:.0f}")
    print(f"fit_speedup_1_thread={fit_1 / base_1:.3f}")
    print(f"fit_fp32_1_thread_samples_per_s={fit_fp32_1:.0f}")
    print(f"fit_speedup_fp32_1_thread={fit_fp32_1 / base_1:.3f}")
    print(f"fit_all_threads_samples_per_s={fit_all:.0f}")
    print(f"fit_speedup_all_threads={fit_all / base:.3f}")
    print(f"fit_all_threads_vs_1_thread={fit_all / fit_1:.3f}")
    print(f"inverse_samples_per_s={inv:.0f}")
    print(f"inverse_1_thread_samples_per_s={inv_1:.0f}")
    print(f"inverse_all_threads_samples_per_s={inv_all:.0f}")
    print(f"fit_gflops={gflops:.1f}")
    print(f"matmul_gflops={peak:.1f}")
    print(f"fit_fraction_of_matmul={gflops / peak:.3f}")
    print(f"matmul_bf16_gflops={matmul_gflops(dtype=torch.bfloat16):.1f}")
    print(f"million_frames_10_epochs_s={1e7 / fit:.0f}")
    print(f"torch_threads={torch.get_num_threads()}")
    print(f"fit_bf16={int(cfg.use_bf16())}")
    if args.label_rows > 0:
        labelling(args.label_rows)
    if torch.cuda.is_available():  # `make bench` on a machine with a GPU measures it too
        gpu(x, r, args.epochs, "cuda")


def gpu(x: torch.Tensor, r: torch.Tensor, epochs: int, device: str) -> None:
    """The authors' loop and acn-fit's (graphed and eager) on the GPU, same data and network."""
    if not torch.cuda.is_available():
        raise SystemExit("--device cuda: no CUDA device is available")
    make = lambda: Corrector(CorrectorCard.untrained("paper", 256, 2))  # noqa: E731
    n = len(x)

    def ours_gpu(cfg: FitConfig, model: Corrector, split: Split) -> float:
        split, b = split.to(device), cfg.resolved().batch_size
        model.net.to(device)
        warm = Split(*(None if t is None else t[:4 * b] for t in (split.x, split.residual, split.jacobian, split.label)),
                     split.scale)
        train(model, warm, cfg, epochs=1)  # CUDA context, kernels, cuBLAS handles
        torch.cuda.synchronize()
        t = time.perf_counter()
        train(model, split, cfg)
        torch.cuda.synchronize()
        return n * cfg.epochs / (time.perf_counter() - t)

    base = baseline(make(), x, r, epochs, device)
    paper = FitConfig(variant="paper", epochs=epochs, device=device)
    graphed = ours_gpu(paper, make(), Split(x, r, None))
    eager = ours_gpu(replace(paper, cuda_graph=False), make(), Split(x, r, None))
    inverse = FitConfig(variant="inverse", epochs=epochs, device=device)  # its defaults: 512 wide, batch 64, cosine
    inv = ours_gpu(inverse, *inverse_split(x, r))
    print(f"device={torch.cuda.get_device_name()}")
    print(f"cuda_baseline_samples_per_s={base:.0f}")
    print(f"cuda_fit_samples_per_s={graphed:.0f}")
    print(f"cuda_fit_eager_samples_per_s={eager:.0f}")
    print(f"cuda_fit_speedup={graphed / base:.2f}")
    print(f"cuda_graph_speedup={graphed / eager:.2f}")
    print(f"cuda_inverse_samples_per_s={inv:.0f}")
    print(f"fit_bf16={int(paper.use_bf16())}")


def labelling(rows: int) -> None:
    """Label speed on real rows: a short paired trot, labels from the source states."""
    from acn.corrector.evaluate import typical_spread
    from acn.corrector.labels import solve
    from acn.corrector.oracle import OUTPUT_INDEX
    from acn.sim.collector import CollectConfig, collect_episodes
    from acn.sim.resim import Resimulator

    ccfg = CollectConfig(target="mujoco", policy="trot", episodes=1, seconds=rows * 0.02, seed=0)
    (ep,) = collect_episodes(ccfg, [0])
    s, a, g = ep.source.state, ep.source.action, ep.source.next_state
    rate = {}
    for threads in (1, 2):
        with Resimulator("mujoco", ccfg.sim, threads=threads) as resim:
            solve(resim, s[:4], a[:4], g[:4], OUTPUT_INDEX, 1 / typical_spread(), FitConfig().solver())  # compile
            t = time.perf_counter()
            sol = solve(resim, s, a, g, OUTPUT_INDEX, 1 / typical_spread(), FitConfig().solver())
            rate[threads] = len(s) / (time.perf_counter() - t)
            share = sol.resim_seconds / (len(s) / rate[threads])
        print(f"label_rows_per_s_{threads}_threads={rate[threads]:.0f}")
    print(f"label_rows_per_s={rate[2]:.0f}")
    print(f"label_simulator_share={share:.3f}")
    print(f"label_thread_scaling={rate[2] / rate[1]:.2f}")
    print(f"label_resims_per_row={FitConfig().solver().resims_per_row}")
    print(f"label_removed={sol.removed:.3f}")
    print(f"make_demo_labels_s={6000 / rate[2]:.0f}")


if __name__ == "__main__":
    main()
