"""acn-fit's training loop on a GPU: a step replayed from a CUDA graph trains exactly as the same
step launched from Python. Skipped where no GPU is present (CI); needs no simulator, so it also runs
with ``pytest --noconftest tests/test_fit_cuda.py`` on a machine with only torch."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch

from acn.corrector.card import CorrectorCard
from acn.corrector.config import FitConfig
from acn.corrector.corrector import Corrector
from acn.corrector.rows import Split
from acn.corrector.train import train

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")


def _split(variant: str, n: int, n_in: int) -> Split:
    g = torch.Generator().manual_seed(1)
    x, r = torch.randn(n, n_in, generator=g), torch.randn(n, 33, generator=g)
    if variant == "paper":
        return Split(x, r, None).to("cuda")
    return Split(x, r, torch.randn(n, 33, 12, generator=g), torch.randn(n, 12, generator=g), torch.ones(12)).to("cuda")


@pytest.mark.parametrize("precision", ["fp32", "bf16"])
@pytest.mark.parametrize("variant", ["paper", "inverse"])
def test_graphed_steps_train_as_eager_ones(variant, precision):
    # 1000 rows: full batches replayed, the last partial batch of each epoch launched eagerly;
    # inverse: its cosine learning rate, read by the graph from a tensor. bf16: matmuls in bf16
    # under torch.autocast, float32 weights and Adam (the same kernels either way).
    if precision == "bf16" and not torch.cuda.is_bf16_supported():
        pytest.skip("no bf16 on this GPU")
    cfg = FitConfig(variant=variant, epochs=3, device="cuda", precision=precision, hidden=64,
                    batch_size=128)
    params, losses = {}, {}
    for graphed in (True, False):
        model = Corrector(CorrectorCard.untrained(variant, 64, 2))
        torch.manual_seed(0)
        for p in model.net.parameters():
            torch.nn.init.normal_(p, std=0.1)
        model.net.to("cuda")
        split = _split(variant, 1000, model.net.action_net[0].in_features)
        history = train(model, split, replace(cfg, cuda_graph=graphed))
        params[graphed] = torch.cat([p.detach().flatten() for p in model.net.parameters()])
        losses[graphed] = [h["train_loss"] for h in history]
    assert losses[True][-1] < losses[True][0]  # it learns
    rel = 1e-4 if precision == "fp32" else 1e-2  # cuBLAS may pick other bf16 kernels inside a graph
    assert losses[True] == pytest.approx(losses[False], rel=rel)
    torch.testing.assert_close(params[True], params[False], rtol=rel, atol=rel / 10)
    assert not torch.equal(params[True], torch.zeros_like(params[True]))
