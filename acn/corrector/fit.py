"""Fit an Action Correction Network from paired dataset files (``acn-fit``).

From files to a frozen corrector, top to bottom:

1. ``load_paired``: read the datasets through lerobot, skip non-finite rows;
2. split train / validation by episode;
3. the paper's filter (an option; by default only for ``paper`` and ``mujoco-jacobian``): keep
   rows with ||s_src - s_tgt|| (input channels) below the training rows' ``filter_percentile``-th
   percentile (the same threshold for validation);
4. targets per variant (``acn.corrector.acn``):
   - ``paper``: the residual delta_s = (s'_src - s_src) - (s'_tgt - s_tgt) of the two recorded
     trajectories, the network sees the target state;
   - ``mujoco-jacobian``: the same, plus J from the target simulator (``control_jacobian``);
   - ``inverse``: same-state labels: per row, delta_a* from a Gauss-Newton solve on target
     re-simulations started from the SOURCE state (``acn.corrector.labels``), goal the recorded
     s'_src; the network sees that state;
5. normalise: inputs by their training mean / std, residuals by their training std, labels by
   their training spread (``delta_scale``, kept in the corrector's config);
6. train from tensors held whole (no per-sample Python);
7. ``inverse`` with ``rounds`` > 0: closed-loop rounds (``acn.corrector.rounds``): collect with the
   current corrector in the target, label the visited target states, add them, train further;
8. ``inverse``: calibrate: F is scaled by the value of ``SHRINK_GRID`` that leaves the least
   one-step error (re-simulated) on the first half of the held-out episodes, so a corrector that
   does not generalise is shrunk towards "no correction" instead of making the target worse;
9. evaluate on held-out data: the objective, the one-step same-state error against the
   oracle's (``evaluate.one_step``, on the held-out rows the calibration did not see) and
   held-out closed-loop episodes beside both oracles (``evaluate.closed_loop``).

Fields of ``FitConfig`` left None take the variant's default (``VARIANT_DEFAULTS``).

On top of a physical model (``fit(..., target=Model)``, ``acn-fit --model MODEL.json``): the
target is the dataset's target simulator with that model's effects written in (e.g. what
``acn-diagnose --auto --save-model`` added), for labels, rounds, the one-step reference and the
closed loop, so the network learns what the physics leaves. Only ``inverse`` re-simulates every
target it learns from (``paper`` and ``mujoco-jacobian`` learn the recorded, nominal target's
residual). The corrector records the effects (``training_data.target_effects``) and is refused
where it would be applied to another model.

At deployment the corrector runs in the target and sees only the target's own state.
"""

from __future__ import annotations

import hashlib
import math
import shutil
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from acn.atomic import move_into_place, temporary_beside
from acn.datasets.reader import PairedTransitions, load_paired, percentile_filter
from acn.errors import UserError
from acn.jsonfile import strict_json
from acn.corrector.acn import (INPUT_CHANNELS, LABELLED, OUTPUT_CHANNELS, VARIANTS, acn_loss, acn_loss_and_grad,
                            input_channels, regression_loss, regression_loss_and_grad)
from acn.corrector.backprop import AdamStep, FlatMLPs
from acn.corrector.corrector import CORRECTOR, Corrector, default_config
from acn.corrector.evaluate import output_spread
from acn.corrector.labels import Solution, SolveConfig
from acn.corrector.threads import AdaptiveThreads, torch_threads
from acn.outputs import refuse_foreign
from acn.sim.policies import POLICIES
from acn.sim.state import STATE_NAMES

MIN_TRAIN_ROWS = 64
_PAPER = {"hidden": 256, "batch_size": 256, "epochs": 30, "lr_schedule": "constant", "filter_percentile": 70.0,
          "rounds": 0, "calibrate": False}
# What a None field of FitConfig means for each variant (the paper's settings for its own two).
VARIANT_DEFAULTS: dict[str, dict] = {
    "paper": _PAPER, "mujoco-jacobian": _PAPER,
    # Regression of non-smooth labels: wider, smaller batches, longer, decaying step (one-step
    # share of the oracle on the demo's held-out rows 0.57 with the paper's settings, 0.70 with these).
    # Closed-loop rounds: on `make demo`'s trot, eps_transfer 347 (none) -> 289 (2 rounds) -> 268 (4).
    # Calibration: where F does not generalise (`excite`: held-out one-step error +47 %), it is shrunk.
    "inverse": {"hidden": 512, "batch_size": 64, "epochs": 60, "lr_schedule": "cosine", "filter_percentile": 100.0,
                "rounds": 4, "calibrate": True},
}
SHRINK_GRID = (0.0, 0.25, 0.5, 0.75, 1.0)  # candidate scales of F for the calibration


@dataclass
class FitConfig:
    """Every hyper-parameter of acn-fit; defaults are the paper's where it gives one."""

    variant: str = "inverse"
    # None: the variant's default (VARIANT_DEFAULTS; the paper's 256 / 256 / 70th percentile for its own two)
    hidden: int | None = None       # width of each hidden layer
    layers: int = 2                 # hidden layers per network
    sensor_inputs: bool | None = None  # F also reads contact and IMU readings (None: all but labelled variants)
    lambda_l1: float = 0.01         # paper (paper and mujoco-jacobian losses)
    lr: float = 1e-3                # paper, Adam
    lr_schedule: str | None = None  # "constant" or "cosine" (decay to 0 over the epochs)
    batch_size: int | None = None
    epochs: int | None = None
    filter_percentile: float | None = None  # keep rows whose source-target gap is below this percentile
    val_fraction: float = 0.2       # of episodes
    seed: int = 0
    device: str = "cpu"
    precision: str = "auto"         # bf16 weights and matmuls in training where the CPU/GPU has bf16 natively
    train_threads: int = 0          # torch threads in training on a CPU (0: the fastest, timed while training; threads.py)
    cuda_graph: bool = True         # on a GPU, replay each full-batch training step as one CUDA graph
    jacobian_eps: float = 0.01      # action units (rad for joint targets), mujoco-jacobian's central differences
    # inverse: the Gauss-Newton labels (acn.corrector.labels.SolveConfig) and the loss
    label_iterations: int = 2       # LM steps with a finite-difference Jacobian
    label_broyden: int = 1          # further quasi-Newton steps
    label_fd_eps: float = 0.01      # action units
    label_damping: float = 0.01     # LM ridge, relative
    jacobian_weight: float = 0.0    # + this times the paper's fit term under the true J
    label_state_weight: float = 0.0  # + this times the label error seen through the true J (state units)
    # inverse: closed-loop (DAgger-style) rounds (None: 4 for inverse; skipped if the policy is not built in)
    rounds: int | None = None
    round_episodes: int = 4
    round_seconds: float = 5.0
    round_epochs: int = 10
    # evaluation
    oracle_iterations: int = 3      # Gauss-Newton steps of the oracles (closed loop, one-step reference)
    eval_episodes: int = 4          # closed-loop episodes from held-out initial states
    eval_seconds: float = 5.0
    oracles: bool = True            # run the same-state and tracking oracles beside the corrector
    one_step: bool = True           # one-step same-state error against the oracle's on held-out rows
    # Scale F by the SHRINK_GRID value with the least one-step error on half of the held-out
    # episodes (the other half reports); None: the variant's default (inverse only)
    calibrate: bool | None = None
    threads: int | None = None      # re-simulation threads (default: the CPU count, at most 8)

    def validate(self) -> None:
        if self.variant not in VARIANTS:
            raise UserError(f"unknown variant {self.variant!r}; choose from {', '.join(VARIANTS)}")
        if not 0 < self.val_fraction < 1:
            raise UserError(f"--val-fraction must be in (0, 1), got {self.val_fraction}")
        if self.device.startswith("cuda") and not torch.cuda.is_available():
            raise UserError("--device cuda: no CUDA device is available")
        if self.lr_schedule not in (None, "constant", "cosine"):
            raise UserError(f"--lr-schedule must be constant or cosine, got {self.lr_schedule!r}")
        if self.train_threads is None or self.train_threads < 0:
            raise UserError(f"--train-threads must be 0 (chosen by timing) or a count, got {self.train_threads}")
        if self.precision not in ("auto", "bf16", "fp32"):
            raise UserError(f"--precision must be auto, bf16 or fp32, got {self.precision!r}")
        if self.filter_percentile is not None and not 0 < self.filter_percentile <= 100:
            raise UserError(f"--filter-percentile must be in (0, 100], got {self.filter_percentile}")
        if self.rounds and self.variant not in LABELLED:
            raise UserError(f"--rounds needs a labelled variant ({', '.join(LABELLED)}), not {self.variant}")
        try:
            self.solver().validate()
            self.oracle_solver().validate()
        except ValueError as e:
            raise UserError(f"label solve: {e}") from None

    def resolved(self) -> "FitConfig":
        """A copy with every None field set to the variant's default (``VARIANT_DEFAULTS``)."""
        self.validate()
        return replace(self, **{k: v for k, v in VARIANT_DEFAULTS[self.variant].items() if getattr(self, k) is None})

    def solver(self) -> SolveConfig:
        """The solve of the training labels."""
        return SolveConfig(iterations=self.label_iterations, broyden=self.label_broyden, fd_eps=self.label_fd_eps,
                           damping=self.label_damping)

    def oracle_solver(self) -> SolveConfig:
        """The oracles' solve: held-out one-step reference and closed-loop oracles."""
        return SolveConfig(iterations=self.oracle_iterations, broyden=0, fd_eps=self.label_fd_eps,
                           damping=self.label_damping)

    def use_bf16(self) -> bool:
        if self.precision != "auto":
            return self.precision == "bf16"
        if self.device.startswith("cuda"):
            return torch.cuda.is_bf16_supported()
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())


@dataclass
class Split:
    """Tensors of one split. ``jacobian``: the target's J (mujoco-jacobian; inverse, at delta 0);
    ``label`` / ``scale``: the labelled variants' delta_a* / delta_scale and the scale itself."""

    x: torch.Tensor          # (N, 52) normalised [s_in; a]
    residual: torch.Tensor   # (N, 33) normalised delta_s (inverse: the same-state gap)
    jacobian: torch.Tensor | None  # (N, 33, 12) J / residual_std, per action unit
    label: torch.Tensor | None = None  # (N, 12) delta_a* / delta_scale
    scale: torch.Tensor | None = None  # (12,) delta_scale: network output -> action units

    def __len__(self) -> int:
        return len(self.x)

    def to(self, device) -> "Split":
        move = lambda t: None if t is None else t.to(device)  # noqa: E731
        return Split(move(self.x), move(self.residual), move(self.jacobian), move(self.label), move(self.scale))


@dataclass
class Labelled:
    """Rows of the labelled variants: the state F sees, the action, the goal and the solve."""

    state: np.ndarray      # (N, 43)
    action: np.ndarray     # (N, 12)
    goal: np.ndarray       # (N, 43) next state to reach
    solution: Solution

    def __len__(self) -> int:
        return len(self.state)

    def usable(self) -> "Labelled":
        return self.subset(~self.solution.diverged)

    def subset(self, ok: np.ndarray) -> "Labelled":
        s = self.solution
        return Labelled(self.state[ok], self.action[ok], self.goal[ok],
                        Solution(s.delta[ok], s.error_before[ok], s.error_after[ok], s.residual[ok],
                                 s.jacobian[ok], s.diverged[ok], s.resim_seconds))

    def __add__(self, other: "Labelled") -> "Labelled":
        a, b = self.solution, other.solution
        cat = lambda x, y: np.concatenate([x, y])  # noqa: E731
        return Labelled(cat(self.state, other.state), cat(self.action, other.action), cat(self.goal, other.goal),
                        Solution(*(cat(getattr(a, f), getattr(b, f)) for f in
                                   ("delta", "error_before", "error_after", "residual", "jacobian", "diverged")),
                                 resim_seconds=a.resim_seconds + b.resim_seconds))


_IN = np.array([STATE_NAMES.index(c) for c in INPUT_CHANNELS])
_OUT = np.array([STATE_NAMES.index(c) for c in OUTPUT_CHANNELS])


def split_episodes(episodes: np.ndarray, val_fraction: float, seed: int) -> np.ndarray:
    """Boolean mask of validation rows: whole episodes, at least one, never all."""
    unique = np.unique(episodes)
    if len(unique) < 2:
        raise UserError("need at least 2 episodes to hold one out for validation")
    rng = np.random.default_rng(seed)
    n_val = min(len(unique) - 1, max(1, round(val_fraction * len(unique))))
    return np.isin(episodes, rng.permutation(unique)[:n_val])


def fingerprint(paths: list[str]) -> str:
    """sha256 over each dataset's meta/info.json and data files: which data trained a model."""
    h = hashlib.sha256()
    for root in paths:
        files = [Path(root) / "meta" / "info.json", *sorted((Path(root) / "data").rglob("*.parquet"))]
        for f in files:
            h.update(f.relative_to(root).as_posix().encode())
            with open(f, "rb") as fh:
                for block in iter(lambda: fh.read(1 << 20), b""):
                    h.update(block)
    return "sha256:" + h.hexdigest()


class Normaliser:
    """Training-set statistics, stored in the corrector."""

    def __init__(self, states: np.ndarray, actions: np.ndarray, residual: np.ndarray, spread_states: np.ndarray,
                 delta: np.ndarray | None = None, channels: tuple[str, ...] = INPUT_CHANNELS) -> None:
        self._in = np.array([STATE_NAMES.index(c) for c in channels])
        s = states[:, self._in]
        self.state_mean, self.state_std = s.mean(0), _safe_std(s)
        self.action_mean, self.action_std = actions.mean(0), _safe_std(actions)
        self.residual_std = _safe_std(residual)
        self.state_spread = output_spread(spread_states)  # channel scale: divergence, label weights
        self.delta_scale = None if delta is None else _safe_std(delta, floor=1e-6)

    def inputs(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
        s = (states[:, self._in] - self.state_mean) / self.state_std
        return np.concatenate([s, (actions - self.action_mean) / self.action_std], axis=1)

    def load_into(self, model: Corrector) -> None:
        for name in ("state_mean", "state_std", "action_mean", "action_std", "residual_std"):
            getattr(model, name).copy_(torch.as_tensor(getattr(self, name), dtype=torch.float32))
        if self.delta_scale is not None:
            model.delta_scale.copy_(torch.as_tensor(self.delta_scale, dtype=torch.float32))

    def as_dict(self) -> dict:
        return {k: None if v is None else np.asarray(v).tolist() for k, v in vars(self).items() if k != "_in"}


def _safe_std(x: np.ndarray, floor: float = 1e-8) -> np.ndarray:
    std = x.std(0)
    return np.where(std > floor, std, 1.0)


def _tensor(a: np.ndarray, device: torch.device) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float32, device=device)


def trajectory_split(d: PairedTransitions, norm: Normaliser, jacobian: np.ndarray | None,
                     device: torch.device) -> Split:
    """paper / mujoco-jacobian: the target's state and action in, the two-trajectory residual out."""
    jac = None if jacobian is None else _tensor(jacobian / norm.residual_std[None, :, None], device)
    return Split(_tensor(norm.inputs(d.target_state, d.target_action), device),
                 _tensor(d.residual()[:, _OUT] / norm.residual_std, device), jac)


def labelled_split(rows: Labelled, norm: Normaliser, device: torch.device) -> Split:
    """inverse: the labelled state and action in, delta_a* / delta_scale out (plus gap and J)."""
    s = rows.solution
    return Split(_tensor(norm.inputs(rows.state, rows.action), device), _tensor(s.residual / norm.residual_std, device),
                 _tensor(s.jacobian / norm.residual_std[None, :, None], device),
                 _tensor(s.delta / norm.delta_scale, device), _tensor(norm.delta_scale, device))


def _batch_loss(delta_out: torch.Tensor, j_pred: torch.Tensor | None, batch: Split, cfg: FitConfig,
                jacobian: torch.Tensor | None = None, report_fit: bool = True) -> tuple[torch.Tensor, torch.Tensor | None]:
    """(loss, paper fit term) on the rows of ``batch`` for the variant it belongs to. A labelled
    variant's loss needs the fit term only with ``jacobian_weight``: training asks for it only
    then (``report_fit=False``; the term is None otherwise), which saves 6 % of an inverse step."""
    if batch.label is None:
        jac = jacobian if jacobian is not None else (j_pred if j_pred is not None else batch.jacobian)
        return acn_loss(delta_out, jac, batch.residual, cfg.lambda_l1)
    loss = regression_loss(delta_out, batch.label)
    jac = jacobian if jacobian is not None else batch.jacobian
    fit = None
    if report_fit or cfg.jacobian_weight:
        _, fit = acn_loss(delta_out * batch.scale, jac, batch.residual, 0.0)
    if cfg.jacobian_weight:
        loss = loss + cfg.jacobian_weight * fit
    if cfg.label_state_weight:  # (delta_a - delta_a*) as the next state sees it, to first order
        seen = torch.bmm(jac, ((delta_out - batch.label) * batch.scale).unsqueeze(-1)).squeeze(-1)
        loss = loss + cfg.label_state_weight * seen.pow(2).mean()
    return loss, fit


def _batch_loss_and_grads(out: list[torch.Tensor], batch: Split, cfg: FitConfig, net) -> tuple[torch.Tensor, list]:
    """``_batch_loss``'s training loss and its gradient for each network output (ActionNet's, then
    JacobianNet's flattened), written out, for the losses that have one (``written_out``)."""
    m = len(out[0])
    if batch.label is not None:
        loss, g = regression_loss_and_grad(out[0], batch.label)
        return loss, [g]
    jac = out[1].view(m, net.n_out, net.n_action) if len(out) > 1 else batch.jacobian
    loss, g_delta, g_jac = acn_loss_and_grad(out[0], jac, batch.residual, cfg.lambda_l1)
    return loss, [g_delta] + ([g_jac.view(m, -1)] if len(out) > 1 else [])


def written_out(cfg: FitConfig, labelled: bool) -> bool:
    """Whether the training loss's gradient is written out (``_batch_loss_and_grads``): the paper's
    loss, and the labels' regression alone; the extra terms (``jacobian_weight``,
    ``label_state_weight``) go through autograd."""
    return not labelled or not (cfg.jacobian_weight or cfg.label_state_weight)


def train(model: Corrector, tr: Split, cfg: FitConfig, on_epoch=None, epochs: int | None = None) -> list[dict]:
    """Adam on the variant's loss; batches are index slices of tensors held whole.

    Speed (benchmarks/fit.py): batches are gathered into preallocated buffers; the networks'
    forward and backward are written out on one flat parameter buffer (``acn.corrector.backprop``:
    the two networks' first layers as one matmul, fused Adam on one tensor); where the hardware
    has native bf16, weights and inputs are held in bf16 for the matmuls while Adam updates a
    float32 master copy and the loss is float32; the loss's gradient is written out
    (``acn.corrector.acn``). On a CPU the torch thread count is chosen by timing the steps
    (``acn.corrector.threads.AdaptiveThreads``) unless ``cfg.train_threads`` fixes it. On a GPU each
    full-batch step is replayed as one CUDA graph (``GraphedStep``; ``cfg.cuda_graph``).
    """
    cfg = cfg.resolved()
    epochs = cfg.epochs if epochs is None else epochs
    if tr.x.device.type != "cpu":
        return _train(model, tr, cfg, on_epoch, epochs, lambda step: step())
    if cfg.train_threads:
        with torch_threads(cfg.train_threads):
            return _train(model, tr, cfg, on_epoch, epochs, lambda step: step())
    with AdaptiveThreads() as threads:
        return _train(model, tr, cfg, on_epoch, epochs, threads)


def _train(model: Corrector, tr: Split, cfg: FitConfig, on_epoch, epochs: int,
           run: Callable[[Callable[[], None]], None]) -> list[dict]:
    """``run(step)`` runs one training step (on the CPU, on the thread count ``train`` chose)."""
    net = model.net
    net.train()
    dev = tr.x.device
    dtype = torch.bfloat16 if cfg.use_bf16() else torch.float32
    graphed = dev.type == "cuda" and cfg.cuda_graph
    flat = FlatMLPs([n for n in (net.action_net, net.jacobian_net) if n is not None], dtype)
    try:
        # A graph replays the learning rate from a tensor it reads; eagerly it is a float.
        lr = torch.tensor(cfg.lr, device=dev) if graphed else cfg.lr
        opt = torch.optim.Adam([flat.master], lr=lr, fused=True, capturable=graphed)
        adam_step = AdamStep(opt)
        gen = torch.Generator(device="cpu").manual_seed(cfg.seed)
        history, n, b = [], len(tr), cfg.batch_size
        steps = epochs * ((n + b - 1) // b)
        whole = replace(tr, x=tr.x.to(dtype))  # cast once, not per batch
        rows = {k: t for k in ("x", "residual", "jacobian", "label") if (t := getattr(whole, k)) is not None}
        buffers = {k: t.new_empty((b, *t.shape[1:])) for k, t in rows.items()}
        total, index = torch.zeros((), device=dev), torch.empty(b, dtype=torch.long, device=dev)
        closed_form = written_out(cfg, tr.label is not None)

        def step(idx: torch.Tensor) -> None:
            """One Adam step on rows ``idx`` (at most a batch); adds the batch's summed loss to ``total``."""
            m = len(idx)
            batch = replace(whole, **{k: torch.index_select(t, 0, idx, out=buffers[k][:m]) for k, t in rows.items()})
            if closed_form:
                loss = flat.step(batch.x, grads_of=lambda out: _batch_loss_and_grads(out, batch, cfg, net))
            else:
                loss = flat.step(batch.x, lambda out: _batch_loss(
                    out[0], out[1].view(m, net.n_out, net.n_action) if len(out) > 1 else None, batch, cfg,
                    report_fit=False)[0])
            adam_step()
            flat.sync()
            total.add_(loss, alpha=m)

        full_batch = GraphedStep(lambda: step(index)) if graphed else None
        k = 0
        for epoch in range(epochs):
            perm = torch.randperm(n, generator=gen).to(dev)
            total.zero_()
            for i in range(0, n, b):
                if cfg.lr_schedule == "cosine":  # CosineAnnealingLR's closed form (eta_min 0, T_max = all steps)
                    _set_lr(opt, cfg.lr * 0.5 * (1.0 + math.cos(math.pi * k / steps)))
                idx = perm[i:i + b]
                if full_batch is not None and len(idx) == b:
                    index.copy_(idx)
                    full_batch()
                else:
                    run(lambda: step(idx))
                k += 1
            history.append({"epoch": epoch + 1, "train_loss": float(total) / n})
            if dev.type == "cpu":  # the count in use as the epoch ended (chosen by timing unless fixed)
                history[-1]["threads"] = torch.get_num_threads()
            if on_epoch:
                on_epoch(history[-1])
    finally:
        flat.restore()
        net.eval()
    return history


def _set_lr(opt: torch.optim.Optimizer, lr: float) -> None:
    for group in opt.param_groups:
        if isinstance(group["lr"], torch.Tensor):
            group["lr"].fill_(lr)  # in place: a captured graph reads this tensor
        else:
            group["lr"] = lr


class GraphedStep:
    """``fn()`` (one training step on static buffers) run through a CUDA graph.

    On a GPU a step of these small networks is about 60 kernels of ~3 us each (H100: 182 us of
    kernel time per batch of 256), so launching them from Python costs more than running them. The
    first ``warmup`` calls run eagerly on a side stream (real steps: they allocate the optimiser
    state and autograd's buffers, as capture requires); the next call captures the step once and
    every call replays it. ``fn`` must read its inputs from and write its results to tensors that
    live across calls.
    """

    def __init__(self, fn, warmup: int = 3) -> None:
        self.fn, self.warmup, self.calls, self.graph = fn, warmup, 0, None

    def __call__(self) -> None:
        if self.graph is not None:
            self.graph.replay()
            return
        if self.calls < self.warmup:
            side = torch.cuda.Stream()
            side.wait_stream(torch.cuda.current_stream())
            with torch.cuda.stream(side):
                self.fn()
            torch.cuda.current_stream().wait_stream(side)
            self.calls += 1
            return
        self.graph = torch.cuda.CUDAGraph()
        with torch.cuda.graph(self.graph):
            self.fn()
        self.graph.replay()  # capture records the step; the replay runs it


@torch.no_grad()
def objective(model: Corrector, split: Split, cfg: FitConfig, jacobian: torch.Tensor | None = None) -> dict:
    """The variant's loss on ``split`` and the paper's fit term (own J, or the given J)."""
    delta_out, j_pred = model.net(split.x)
    total, fit = _batch_loss(delta_out, j_pred, split, cfg, jacobian)
    delta = delta_out if split.scale is None else delta_out * split.scale
    out = {"loss": float(total), "fit": float(fit), "fit_no_correction": float(split.residual.pow(2).mean()),
           "mean_abs_delta_a": float(delta.abs().mean())}
    if split.label is not None:
        out["label_mse"] = float(regression_loss(delta_out, split.label))
        out["label_mse_no_correction"] = float(split.label.pow(2).mean())
    return out


def calibration_rows(episodes: np.ndarray) -> np.ndarray:
    """Mask of the held-out rows that calibrate: the first half of the held-out episodes (or, with
    one episode, the first half of its rows); the rest report."""
    unique = np.unique(episodes)
    if len(unique) > 1:
        return np.isin(episodes, unique[: (len(unique) + 1) // 2])
    mask = np.zeros(len(episodes), dtype=bool)
    mask[: len(episodes) // 2] = True
    return mask


def calibrate(model: Corrector, resim, rows: Labelled, weights: np.ndarray) -> dict:
    """Scale F by the ``SHRINK_GRID`` value with the least one-step error on ``rows`` (re-simulated)."""
    from acn.corrector.evaluate import one_step

    base = model.delta_scale.clone()
    errors = {}
    for k in SHRINK_GRID:
        model.delta_scale.copy_(base * k)
        errors[k] = one_step(model, resim, rows.state, rows.action, rows.goal, rows.solution, _OUT,
                             weights)["error_corrected"]
    best = min(errors, key=errors.get)
    model.delta_scale.copy_(base * best)
    model.config["delta_scale"] = model.delta_scale.tolist()
    return {"scale": best, "rows": len(rows), "error_by_scale": {str(k): v for k, v in errors.items()}}


def same_state_rows(d: PairedTransitions, resim, weights: np.ndarray, solver: SolveConfig) -> Labelled:
    """Labels at the SOURCE states of recorded rows: goal the recorded s'_src (``labels.solve``)."""
    from acn.corrector.labels import solve

    return Labelled(d.state, d.action, d.next_state, solve(resim, d.state, d.action, d.next_state, _OUT, weights, solver))


def _resimulators(ccfg, threads: int | None):
    """(collection config, source, target) Resimulators of the dataset's models (the target with
    the effects of ``fit``'s target model)."""
    from acn.sim.resim import Resimulator

    return (ccfg, Resimulator(ccfg.source, ccfg.source_sim, threads=threads),
            Resimulator(ccfg.target, ccfg.target_sim, threads=threads))


def _target_effects(target, variant: str, target_sim: str | None) -> list:
    """The effects of the target model ``fit`` is given (``[]``: the dataset's own target)."""
    if target is None:
        return []
    if target.corrector:
        raise UserError(f"--model carries a corrector ({target.corrector}); give a model with effects only")
    if target.backend != target_sim:
        raise UserError(f"--model is a {target.backend} model; the datasets' target simulator is {target_sim}")
    if target.effects and variant not in LABELLED:
        raise UserError(f"--model with effects needs a variant that re-simulates the target ({', '.join(LABELLED)}); "
                        f"{variant} learns the recorded target's residual")
    return list(target.effects)


def fit(paths: list[str | Path], cfg: FitConfig, log=print, target=None) -> tuple[Corrector, dict]:
    """Steps 1-9 of the module docstring; returns the frozen corrector and its metrics.
    ``target``: an ``acn.sim.effects.Model`` of the target simulator whose effects the
    target gets (module docstring); None: the dataset's target as recorded."""
    from acn.datasets.record import config_from_metadata

    cfg = cfg.resolved()
    t0 = time.perf_counter()
    device = torch.device(cfg.device)
    torch.manual_seed(cfg.seed)
    data = load_paired([str(p) for p in paths])
    target_sim = data.info.target.simulator if data.info.target else None
    if cfg.variant != "paper" and target_sim != "mujoco":
        raise UserError(f"variant {cfg.variant} needs datasets whose target simulator is mujoco")
    effects = _target_effects(target, cfg.variant, target_sim)
    ccfg = config_from_metadata(data.info, target_effects=effects)
    if effects:
        log(f"target: {target.describe()} (the network learns what these effects leave)")
    is_val = split_episodes(data.episode, cfg.val_fraction, cfg.seed)
    train_d, val_d = data.subset(~is_val), data.subset(is_val)
    val_all = val_d  # every held-out row: the one-step evaluation is on the same rows for every variant
    # Channel scale (divergence metric, label and oracle weights 1 / spread): all training rows.
    spread = output_spread(train_d.target_state)
    gap_train = train_d.gap(_IN)
    pct = cfg.filter_percentile
    threshold = float(np.percentile(gap_train, pct)) if pct < 100 else np.inf
    keep_train = percentile_filter(gap_train, pct)
    train_d, val_d = train_d.subset(keep_train), val_d.subset(val_d.gap(_IN) < threshold)
    if len(train_d) < MIN_TRAIN_ROWS or len(val_d) == 0:
        raise UserError(f"too little data after filtering: {len(train_d)} training / {len(val_d)} validation rows "
                        f"(need >= {MIN_TRAIN_ROWS} / 1); collect more episodes or raise --filter-percentile")
    log(f"data: {len(data)} rows from {len(paths)} dataset(s), {data.skipped_nonfinite} non-finite skipped; "
        f"after the {pct:g}th-percentile filter {len(train_d)} train / {len(val_d)} val")

    weights = 1.0 / spread
    sims = _resimulators(ccfg, cfg.threads) if target_sim == "mujoco" else None
    timing: dict[str, float] = {}
    labels: dict[str, Labelled] = {}
    solver = cfg.solver()
    if sims is not None and (cfg.variant in LABELLED or cfg.one_step):
        # Same-state labels: training rows for the labelled variants, held-out rows for their
        # validation and every variant's one-step evaluation against the oracle.
        t = time.perf_counter()
        if cfg.variant in LABELLED:
            labels["train"] = same_state_rows(train_d, sims[2], weights, solver).usable()
        labels["val"] = same_state_rows(val_all, sims[2], weights, cfg.oracle_solver())
        timing["label_seconds"] = time.perf_counter() - t
        n_rows = sum(len(v) for v in labels.values())
        timing["label_rows_per_s"] = n_rows / max(timing["label_seconds"], 1e-9)
        timing["label_simulator_share"] = sum(v.solution.resim_seconds for v in labels.values()) \
            / max(timing["label_seconds"], 1e-9)
        log(f"same-state labels: {n_rows} rows in {timing['label_seconds']:.1f} s ({solver.resims_per_row} "
            f"re-simulations per training row, {cfg.oracle_solver().resims_per_row} per held-out row): label_rows_per_s={timing['label_rows_per_s']:.0f} "
            f"label_simulator_share={timing['label_simulator_share']:.2f}")

    channels = input_channels(cfg.variant, cfg.sensor_inputs)
    if cfg.variant in LABELLED:
        tr_rows = labels["train"]
        if len(tr_rows) < MIN_TRAIN_ROWS:
            raise UserError(f"too little data: {len(tr_rows)} labelled training rows (need >= {MIN_TRAIN_ROWS})")
        norm = Normaliser(tr_rows.state, tr_rows.action, tr_rows.solution.residual, train_d.target_state,
                          delta=tr_rows.solution.delta, channels=channels)
    else:
        norm = Normaliser(train_d.target_state, train_d.target_action, train_d.residual()[:, _OUT],
                          train_d.target_state, channels=channels)
    config = default_config(cfg.variant, cfg.hidden, cfg.layers, cfg.sensor_inputs)
    config["delta_scale"] = None if norm.delta_scale is None else norm.delta_scale.tolist()
    model = Corrector(config)
    norm.load_into(model)
    model.to(device)
    t = time.perf_counter()
    if cfg.variant in LABELLED:
        tr, va = labelled_split(labels["train"], norm, device), labelled_split(labels["val"].usable(), norm, device)
    else:
        jac_tr = jac_va = None
        if cfg.variant == "mujoco-jacobian":
            from acn.corrector.sensitivity import control_jacobian

            jac_tr = control_jacobian(sims[2], train_d.target_state, train_d.target_action, list(OUTPUT_CHANNELS),
                                      eps=cfg.jacobian_eps)
            jac_va = control_jacobian(sims[2], val_d.target_state, val_d.target_action, list(OUTPUT_CHANNELS),
                                      eps=cfg.jacobian_eps)
            log(f"control Jacobians from MuJoCo: {len(train_d) + len(val_d)} rows in {time.perf_counter() - t:.1f} s")
        tr, va = trajectory_split(train_d, norm, jac_tr, device), trajectory_split(val_d, norm, jac_va, device)
    timing["jacobian_seconds"] = time.perf_counter() - t
    val_before = objective(model, va, cfg)
    t = time.perf_counter()

    def log_epoch(h: dict) -> None:
        if h["epoch"] % max(1, cfg.epochs // 5) == 0 or h["epoch"] == cfg.epochs:
            log(f"epoch {h['epoch']}: train loss {h['train_loss']:.5f}"
                + (f" ({h['threads']} torch thread{'s' if h['threads'] > 1 else ''})" if "threads" in h else ""))

    history = train(model, tr, cfg, on_epoch=log_epoch)
    timing["train_seconds"] = time.perf_counter() - t
    model.to("cpu").freeze()
    round_reports = None
    if cfg.rounds:
        t = time.perf_counter()
        round_reports = _rounds(model, labels["train"], norm, sims, weights, solver, cfg, device, log)
        timing["rounds_seconds"] = time.perf_counter() - t
    va_cpu = va.to("cpu")
    metrics: dict = {
        "variant": cfg.variant,
        "rows": {"read": len(data), "skipped_nonfinite": data.skipped_nonfinite, "train": len(tr), "val": len(va),
                 "filter_percentile": pct, "filter_threshold": threshold if np.isfinite(threshold) else None},
        "val_objective_before": val_before,
        "val_objective": objective(model, va_cpu, cfg),
        "train_history": history,
        "train_seconds": timing["train_seconds"],
        "train_samples_per_s": len(tr) * cfg.epochs / timing["train_seconds"],
    }
    if cfg.variant in LABELLED:
        metrics["labels"] = {"train_removed": labels["train"].solution.removed,
                             "val_removed_by_oracle": labels["val"].solution.removed, "solver": asdict(solver),
                             "oracle_solver": asdict(cfg.oracle_solver()),
                             "seconds": timing["label_seconds"], "label_rows_per_s": timing["label_rows_per_s"],
                             "simulator_share": timing["label_simulator_share"]}
    if round_reports is not None:
        metrics["rounds"] = round_reports
    if sims is not None:
        if cfg.variant != "mujoco-jacobian" and cfg.variant not in LABELLED:
            # Honest comparison across variants: the paper's fit under the target's TRUE sensitivity.
            from acn.corrector.sensitivity import control_jacobian

            true_j = control_jacobian(sims[2], val_d.target_state, val_d.target_action, list(OUTPUT_CHANNELS),
                                      eps=cfg.jacobian_eps)
            true_j = _tensor(true_j / norm.residual_std[None, :, None], torch.device("cpu"))
            metrics["val_objective_true_jacobian"] = objective(model, va_cpu, cfg, jacobian=true_j)
        elif cfg.variant == "mujoco-jacobian":
            metrics["val_objective_true_jacobian"] = metrics["val_objective"]
    if sims is not None and "val" in labels:
        from acn.corrector.evaluate import one_step

        v = labels["val"]
        if cfg.calibrate:
            calib = calibration_rows(val_all.episode)
            metrics["calibration"] = calibrate(model, sims[2], v.subset(calib), weights)
            v = v.subset(~calib)  # the one-step report is on rows the calibration did not see
            log(f"calibration on {int(calib.sum())} held-out rows: F scaled by {metrics['calibration']['scale']:g}")
        metrics["one_step"] = one_step(model, sims[2], v.state, v.action, v.goal, v.solution, _OUT, weights)
        o = metrics["one_step"]
        log(f"one-step same-state error on held-out rows: {o['error_no_correction']:.4f} -> corrector "
            f"{o['error_corrected']:.4f}, oracle {o['error_oracle']:.4f}: share_of_oracle={o['share_of_oracle']:.3f}")
    if cfg.eval_episodes > 0 and data.info.policy not in POLICIES:
        log(f"closed-loop evaluation skipped: the dataset's policy {data.info.policy!r} is not a built-in "
            "policy this command can run again (for a PPO policy: acn-ppo --eval POLICY --corrector DIR)")
    elif cfg.eval_episodes > 0:
        from acn.corrector.evaluate import closed_loop

        log(f"closed loop: {cfg.eval_episodes} held-out episodes of {cfg.eval_seconds:g} s: uncorrected, corrected"
            + (", same-state and tracking oracles" if cfg.oracles and sims is not None else ""))
        t = time.perf_counter()
        metrics["closed_loop"] = closed_loop(ccfg, model, cfg.eval_episodes,
                                             cfg.eval_seconds, list(OUTPUT_CHANNELS), spread,
                                             oracles=cfg.oracles and sims is not None, solver=cfg.oracle_solver(),
                                             log=log)
        timing["closed_loop_seconds"] = time.perf_counter() - t
    if sims is not None:
        sims[1].close()
        sims[2].close()
    metrics["total_seconds"] = time.perf_counter() - t0
    metrics["seconds"] = timing
    norm_dict = norm.as_dict()
    model.config.update({
        "fit": asdict(cfg),
        "normalisation": norm_dict,
        "training_data": {"datasets": data.sources, "fingerprint": fingerprint(data.sources),
                          "source": data.info.source.to_json(), "target": data.info.target.to_json(),
                          "target_effects": [e.to_json() for e in effects],
                          "action_mode": data.info.action_mode, "control_hz": data.info.control_hz,
                          "policy": data.info.policy},
        "action_channels": list(data.info.action_names),
        "metrics": _summary(metrics),
    })
    return model, metrics


def _rounds(model: Corrector, rows: Labelled, norm: Normaliser, sims, weights: np.ndarray,
            solver: SolveConfig, cfg: FitConfig, device: torch.device, log) -> list[dict]:
    """Closed-loop rounds (``acn.corrector.rounds``); one report per round."""
    from acn.corrector.evaluate import one_step, summarise
    from acn.corrector.rounds import relabel, visit

    ccfg, source, target = sims
    if ccfg.policy not in POLICIES:
        log(f"closed-loop rounds skipped: the dataset's policy {ccfg.policy!r} is not a built-in policy")
        return []
    reports = []
    for r in range(cfg.rounds):
        t = time.perf_counter()
        episodes = visit(ccfg, model, cfg.round_episodes, cfg.round_seconds, r)
        t_visit = time.perf_counter() - t
        new = relabel(episodes, source, target, _OUT, weights, solver)
        t_label = time.perf_counter() - t - t_visit
        before = one_step(model, target, new.state, new.action, new.goal, new.solution, _OUT, weights)
        closed = summarise({"corrected": episodes}, list(OUTPUT_CHANNELS), norm.state_spread)["runs"]["corrected"]
        new_rows = Labelled(new.state, new.action, new.goal, new.solution).usable()
        rows = rows + new_rows
        model.net.to(device)
        for p in model.net.parameters():
            p.requires_grad_(True)
        train(model, labelled_split(rows, norm, device), cfg, epochs=cfg.round_epochs)
        model.to("cpu").freeze()
        report = {"round": r + 1, "episodes": len(episodes), "rows_added": len(new_rows), "rows_total": len(rows),
                  "visit_seconds": t_visit, "label_seconds": t_label, "seconds": time.perf_counter() - t,
                  "one_step_on_visited_before_refit": before,
                  "closed_loop_on_visited": {k: closed[k] for k in ("divergence", "eps_transfer", "target_falls")}}
        reports.append(report)
        log(f"round {r + 1}: {len(new_rows)} visited rows labelled ({report['seconds']:.1f} s); on them the "
            f"corrector removed {before['corrected_removed']:.2f} of the one-step error (oracle "
            f"{before['oracle_removed']:.2f}); closed loop there: eps_transfer {closed['eps_transfer']:.1f}, "
            f"divergence {closed['divergence']:.3f}, {closed['target_falls']} target fall(s)")
    return reports


def _summary(m: dict) -> dict:
    out = {"val_objective": m["val_objective"], "rows": m["rows"]}
    for key in ("val_objective_true_jacobian", "one_step"):
        if key in m:
            out[key] = m[key]
    if "closed_loop" in m:
        cl = m["closed_loop"]
        out["closed_loop"] = {k: cl[k] for k in ("divergence_uncorrected", "divergence_corrected",
                                                 "divergence_reduction", "eps_transfer", "eps_transfer_uncorrected",
                                                 "delta_corr", "verdict") if k in cl}
        out["closed_loop"]["runs"] = {name: {k: run[k] for k in ("divergence", "eps_transfer", "target_falls")}
                                      for name, run in cl["runs"].items()}
    return strict_json(out)


def save(model: Corrector, metrics: dict, out: str | Path, overwrite: bool = False) -> Path:
    """Write the model directory atomically (hidden temp dir, then rename)."""
    import json

    out = Path(out).absolute()
    refuse_foreign(out, CORRECTOR, overwrite)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_beside(out)
    tmp.mkdir()
    try:
        model.save(tmp)
        (tmp / "metrics.json").write_text(json.dumps(strict_json(metrics), indent=2, allow_nan=False))
        return move_into_place(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
