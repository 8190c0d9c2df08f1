"""The ACN's networks, forward and backward written out, on one flat parameter buffer.

acn-fit's training step (``acn.corrector.fit.train``). The networks are small (a batch of 256 through
52 -> 256 -> 256 -> 12 and -> 396 is ~0.4 GFLOP), so on a CPU a step through autograd spends as
much time in its bookkeeping (graph nodes, gradient accumulation, one tensor per parameter, dtype
casts of each weight and gradient) as in the matmuls. Here:

- the parameters of every network are views of ONE flat buffer, laid out layer by layer, so the
  networks' first layers, which read the same input, are one (n_nets * hidden x n_in) matrix and
  run as one matmul (forward and weight gradient), their hidden-to-hidden layers one
  (n_nets, hidden, hidden) stack run as one batched matmul (a bf16 matmul call on a CPU costs
  about 25 us to set up, as much as it runs at batch 256: two calls per layer and pass were
  twice that), and Adam updates one tensor (``AdamStep``: its fused kernel, called directly);
- weights and activations are held in the training dtype (bf16 where the hardware has it); the
  gradients are written by ``torch.mm(..., out=)`` straight into a flat gradient buffer in that
  dtype and cast to the float32 master once per step;
- the loss is evaluated on the networks' outputs in float32, with its gradient written out where
  the variant's loss has one (``acn.corrector.fit._batch_loss_and_grads``; autograd's bookkeeping
  for the loss alone cost as much as the loss), through autograd otherwise (float32 leaves), so
  every variant's loss (``acn.corrector.fit._batch_loss``) works.

Only ``mlp`` networks (Linear, SiLU, ..., Linear) are handled; ``tests/test_fit.py`` checks the
gradients against autograd's.
"""

from __future__ import annotations

from typing import Callable

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F


def _linears(net: nn.Sequential) -> list[nn.Linear]:
    mods = list(net)  # Linear, SiLU, Linear, ..., SiLU, Linear
    if len(mods) < 3 or len(mods) % 2 == 0 or \
            not all(isinstance(m, nn.SiLU if k % 2 else nn.Linear) for k, m in enumerate(mods)):
        raise ValueError("backprop handles Linear-SiLU-...-Linear networks only")
    return mods[::2]


class FlatMLPs:
    """Networks reading the same input, trained on one flat float32 master copy of their
    parameters (``master``, the tensor Adam updates); ``step`` is one forward and backward."""

    def __init__(self, nets: list[nn.Sequential], dtype: torch.dtype) -> None:
        self.layers = [_linears(n) for n in nets]
        depth = {len(ls) for ls in self.layers}
        widths = {ls[0].out_features for ls in self.layers}
        if len(depth) != 1 or len(widths) != 1:
            raise ValueError("networks of equal depth and width only")
        self.hidden = widths.pop()
        # Layer-major order: layer l's weights of every network, then their biases.
        self.params: list[nn.Parameter] = [getattr(ls[l], kind) for l in range(depth.pop())
                                           for kind in ("weight", "bias") for ls in self.layers]
        self.dtype = dtype
        self.master = torch.cat([p.detach().reshape(-1) for p in self.params]).float()
        self.master.grad = torch.empty_like(self.master)
        self.work = self.master if dtype == torch.float32 else self.master.to(dtype)
        self.grad = self.master.grad if dtype == torch.float32 else torch.empty_like(self.work)
        views, grads = self._views(self.work), self._views(self.grad)
        for p, w in zip(self.params, views):
            p.data, p.grad = w, None
        # Layer l of every network, where all have it alike (the first, the hidden-to-hidden ones):
        # their weights lie side by side in the layer-major buffer, then their biases, so they are
        # one stack, (n, out, in) and (n, out).
        n, depth = len(nets), len(self.layers[0])
        offsets = np.cumsum([0] + [p.numel() for p in self.params])

        def stack(l: int, t: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
            w, b = int(offsets[2 * n * l]), int(offsets[2 * n * l + n])
            out, inp = self.layers[0][l].weight.shape
            return t[w:b].view(n, out, inp), t[b:b + n * out].view(n, out)

        # The first layers, which read the same input: one (n * H, n_in) matrix.
        (self.w0, self.b0), (self.g0, self.gb0) = ((w.flatten(0, 1), b.flatten()) for w, b in
                                                   (stack(0, self.work), stack(0, self.grad)))
        self.hidden_w = [stack(l, self.work) for l in range(1, depth - 1)]
        self.hidden_g = [stack(l, self.grad) for l in range(1, depth - 1)]
        index = {id(p): k for k, p in enumerate(self.params)}
        self.out_w = [(views[index[id(ls[-1].weight)]], views[index[id(ls[-1].bias)]]) for ls in self.layers]
        self.out_g = [(grads[index[id(ls[-1].weight)]], grads[index[id(ls[-1].bias)]]) for ls in self.layers]

    def _views(self, flat: torch.Tensor) -> list[torch.Tensor]:
        return [v.view_as(p) for v, p in zip(flat.split([p.numel() for p in self.params]), self.params)]

    def step(self, x: torch.Tensor, loss_of: Callable[[list[torch.Tensor]], torch.Tensor] | None = None,
             grads_of: Callable[[list[torch.Tensor]], tuple[torch.Tensor, list[torch.Tensor]]] | None = None
             ) -> torch.Tensor:
        """Forward ``x`` (rows x n_in, training dtype) through every network, the loss on their
        float32 outputs, backward into ``master.grad``; returns the loss. The loss is ``loss_of``
        through autograd, or ``grads_of``: (loss, its gradient for each output) written out.

        Every network's first layers are one matmul; their hidden-to-hidden layers one batched
        matmul (``baddbmm`` / ``bmm`` over the networks: one call instead of one per network, which
        on a CPU costs about as much to set up as to run at these sizes); the output layers, whose
        widths differ, one matmul each."""
        n, h0, rows = len(self.layers), self.hidden, len(x)
        z0 = torch.addmm(self.b0, x, self.w0.t())        # (rows, n * H): all networks' first layers
        h = F.silu(z0).view(rows, n, h0).transpose(0, 1)  # (n, rows, H)
        acts, pre = [h], []                              # each hidden layer's input, pre-activation
        for w, b in self.hidden_w:
            pre.append(torch.baddbmm(b.unsqueeze(1), h, w.transpose(1, 2)))
            h = F.silu(pre[-1])
            acts.append(h)
        outs = [torch.addmm(b, h[i], w.t()) for i, (w, b) in enumerate(self.out_w)]
        if grads_of is not None:
            loss, g_outs = grads_of([o.float() for o in outs])
        else:
            leaves = [o.float().requires_grad_() for o in outs]
            loss = loss_of(leaves)
            loss.backward()
            g_outs = [leaf.grad for leaf in leaves]
        g = h.new_empty((n, rows, h0))                   # d loss / d the last hidden layer's output
        for i, (g_out, (w, _), (gw, gb)) in enumerate(zip(g_outs, self.out_w, self.out_g)):
            g_out = g_out.to(self.dtype)
            torch.mm(g_out.t(), h[i], out=gw)
            torch.sum(g_out, 0, out=gb)
            torch.mm(g_out, w, out=g[i])
        for (w, _), (gw, gb), z, a in zip(reversed(self.hidden_w), reversed(self.hidden_g), reversed(pre),
                                          reversed(acts[:-1])):
            g = torch.ops.aten.silu_backward(g, z)
            torch.bmm(g.transpose(1, 2), a, out=gw)
            torch.sum(g, 1, out=gb)
            g = torch.bmm(g, w)
        g = torch.ops.aten.silu_backward(g.transpose(0, 1).reshape(rows, n * h0), z0)
        torch.mm(g.t(), x, out=self.g0)
        torch.sum(g, 0, out=self.gb0)
        if self.grad is not self.master.grad:
            self.master.grad.copy_(self.grad)
        return loss.detach()

    def sync(self) -> None:
        """Weights back from the master after an optimiser step."""
        if self.work is not self.master:
            self.work.copy_(self.master)

    def restore(self) -> None:
        """Give each parameter its own float32 tensor again (the master's values)."""
        for p, m in zip(self.params, self._views(self.master.detach())):
            p.data, p.grad = m.clone(), None


class AdamStep:
    """``opt.step()`` for a fused Adam (``torch.optim.Adam(fused=True)``) on one CPU tensor, the
    flat master, calling its kernel (``torch._fused_adam_``) directly: the same kernel on the same
    state tensors, so the same weights to the bit (``tests/test_fit.py``).

    Through ``opt.step()`` the optimiser's Python (hooks, grouping tensors by device and dtype)
    costs as much as the kernel on the paper's 264k parameters (165 against 82 us a step on two
    cores here; training ran 10 % faster without it). The first step (which creates the state),
    any other optimiser and a torch without the kernel (or whose kernel refuses these arguments)
    go through ``opt.step()``; the learning rate is read from the optimiser's group at every step
    (a schedule sets it there)."""

    def __init__(self, opt: torch.optim.Optimizer) -> None:
        group = opt.param_groups[0]
        self.opt, self.group = opt, group
        self.direct = (isinstance(opt, torch.optim.Adam) and len(opt.param_groups) == 1 and len(group["params"]) == 1
                       and group["fused"] and not group["capturable"] and not group["amsgrad"]
                       and not group["maximize"] and group["weight_decay"] == 0
                       and not isinstance(group["lr"], torch.Tensor) and group["params"][0].device.type == "cpu"
                       and hasattr(torch, "_fused_adam_"))
        self.state: tuple | None = None

    def __call__(self) -> None:
        if not self.direct or self.state is None:
            self.opt.step()
            if self.direct:
                (p,) = self.group["params"]
                s = self.opt.state[p]
                self.state = ([p], [p.grad], [s["exp_avg"]], [s["exp_avg_sq"]], [s["step"]])
            return
        params, grads, exp_avgs, exp_avg_sqs, steps = self.state
        g = self.group
        steps[0].add_(1)  # as torch.optim.Adam's fused path: the count, then the kernel
        try:
            torch._fused_adam_(params, grads, exp_avgs, exp_avg_sqs, [], steps, amsgrad=False, lr=g["lr"],
                               beta1=g["betas"][0], beta2=g["betas"][1], weight_decay=0.0, eps=g["eps"],
                               maximize=False, grad_scale=None, found_inf=None)
        except (TypeError, RuntimeError):  # a torch whose kernel takes other arguments: refused before it runs
            steps[0].sub_(1)
            self.direct = False
            self.opt.step()
