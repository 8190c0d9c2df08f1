"""acn-fit's training loop: plain PyTorch (autograd, ``torch.optim.Adam``) on tensors held whole.

What makes it faster than a per-sample ``Dataset`` + ``DataLoader`` loop (``benchmarks/fit.py``):

- the split's tensors are held whole on the device; a batch is one index gather, no per-sample
  Python or collation;
- Adam is ``torch.optim.Adam(fused=True)``, one kernel over every parameter, on the devices torch
  has the fused kernel for (``FUSED_ADAM_DEVICES``), ``foreach`` elsewhere;
- the networks' matmuls run in bf16 under ``torch.autocast`` where the hardware computes bf16
  natively (``FitConfig.use_bf16``), with float32 weights, optimiser and loss;
- the loss is summed on the device, read once per epoch;
- on a GPU each full-batch step (gather, forward, backward, Adam) is captured once as a CUDA
  graph and replayed (``GraphedStep``): a step of these small networks is ~100 short kernels
  whose launches from Python cost more than they run.

On a CPU the step runs on ``FitConfig.train_threads`` torch threads (0: torch's default).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Callable, Iterable

import torch

from acn.corrector.config import FitConfig
from acn.corrector.corrector import Corrector, torch_threads
from acn.corrector.rows import Split
from acn.corrector.variants import strategy

FUSED_ADAM_DEVICES = ("cpu", "cuda")  # devices whose fused Adam kernel torch has (CPU since torch 2.4)


def adam(params: Iterable[torch.nn.Parameter], lr: float, device: torch.device, capturable: bool = False
         ) -> torch.optim.Adam:
    """Adam, fused where torch has the kernel for ``device``, foreach elsewhere. ``capturable``
    (a CUDA graph replays its steps): the learning rate is a tensor the graph reads."""
    fused = device.type in FUSED_ADAM_DEVICES
    return torch.optim.Adam(params, lr=torch.tensor(lr, device=device) if capturable else lr,
                            fused=fused or None, foreach=None if fused else True, capturable=capturable)


def set_lr(opt: torch.optim.Optimizer, lr: float) -> None:
    for group in opt.param_groups:
        if isinstance(group["lr"], torch.Tensor):
            group["lr"].fill_(lr)  # in place: a captured graph reads this tensor
        else:
            group["lr"] = lr


def train(model: Corrector, tr: Split, cfg: FitConfig, on_epoch: Callable[[dict], None] | None = None,
          epochs: int | None = None) -> list[dict]:
    """Adam on the variant's loss (``acn.corrector.variants``) over ``epochs`` (default
    ``cfg.epochs``) of shuffled batches; one history entry per epoch. The model's float32
    parameters are trained in place; it is left in eval mode."""
    cfg = cfg.resolved()
    epochs = cfg.epochs if epochs is None else epochs
    with torch_threads(cfg.train_threads if tr.x.device.type == "cpu" else 0):
        return _train(model, tr, cfg, epochs, on_epoch)


def _train(model: Corrector, tr: Split, cfg: FitConfig, epochs: int, on_epoch) -> list[dict]:
    net, dev = model.net, tr.x.device
    loss_of = strategy(cfg.variant).loss
    graphed = dev.type == "cuda" and cfg.cuda_graph
    opt = adam(net.parameters(), cfg.lr, dev, capturable=graphed)
    rows = {k: t for k in ("x", "residual", "jacobian", "label") if (t := getattr(tr, k)) is not None}
    bf16 = cfg.use_bf16()
    total = torch.zeros((), device=dev)                                 # the epoch's summed loss
    index = torch.empty(cfg.batch_size, dtype=torch.long, device=dev)   # a graph's input: the batch's rows

    def step(idx: torch.Tensor) -> None:
        """One Adam step on rows ``idx``; adds the batch's summed loss to ``total``."""
        batch = replace(tr, **{k: t.index_select(0, idx) for k, t in rows.items()})
        with torch.autocast(dev.type, dtype=torch.bfloat16, enabled=bf16, cache_enabled=False):
            delta_out, j_pred = net(batch.x)
        loss = loss_of(delta_out.float(), None if j_pred is None else j_pred.float(), batch, cfg)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        total.add_(loss.detach(), alpha=len(idx))

    full_batch = GraphedStep(lambda: step(index)) if graphed else None
    gen = torch.Generator(device="cpu").manual_seed(cfg.seed)
    n, b = len(tr), cfg.batch_size
    steps, k, history = epochs * math.ceil(n / b), 0, []
    net.train()
    try:
        for epoch in range(epochs):
            perm = torch.randperm(n, generator=gen).to(dev)
            total.zero_()
            for i in range(0, n, b):
                if cfg.lr_schedule == "cosine":  # CosineAnnealingLR's closed form (eta_min 0, T_max = all steps)
                    set_lr(opt, cfg.lr * 0.5 * (1.0 + math.cos(math.pi * k / steps)))
                idx = perm[i:i + b]
                if full_batch is not None and len(idx) == b:
                    index.copy_(idx)
                    full_batch()
                else:
                    step(idx)
                k += 1
            history.append({"epoch": epoch + 1, "train_loss": float(total) / n})
            if dev.type == "cpu":
                history[-1]["threads"] = torch.get_num_threads()
            if on_epoch:
                on_epoch(history[-1])
    finally:
        opt.zero_grad(set_to_none=True)
        net.eval()
    return history


class GraphedStep:
    """``fn()`` (one training step reading its rows from a tensor that lives across calls) run
    through a CUDA graph, as torch documents whole-network capture: the first ``warmup`` calls
    run eagerly on a side stream (real steps: they create Adam's state), the next captures the
    step once (the gradients it allocates come from the graph's own memory) and replays it, as
    does every call after."""

    def __init__(self, fn: Callable[[], None], warmup: int = 3) -> None:
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
