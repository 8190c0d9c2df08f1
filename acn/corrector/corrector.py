"""The frozen corrector: ``a~ = a + F(s, a)``, saved as ``model.safetensors`` + ``config.json``.

``Corrector.load(dir)`` returns a module in eval mode with gradients off, its card
(``config.json``, ``acn.corrector.card.CorrectorCard``) parsed once as ``corrector.card``.
``correct(state, action)`` takes the documented 43-channel state vector(s) and 12 action(s),
numpy or torch, one row or a batch, and returns the corrected action(s) in the same type and
shape. ``load_for_target`` also refuses a corrector fitted for another target.
Nothing is pickled: weights are safetensors, everything else is JSON.
"""

from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import numpy as np
import torch
from safetensors.torch import load_file
from torch import nn

from acn.corrector.acn import LEARNED_JACOBIAN, ActionCorrectionNetwork
from acn.corrector.card import FORMAT, CorrectorCard, TargetDescription
from acn.errors import UserError
from acn.outputs.kinds import Output, json_with_format
from acn.sim.state import ACTION_DIM, STATE_DIM, STATE_NAMES
from acn.weights import CONFIG, WEIGHTS, corrupt_weights, read_config, save_weights

# A corrector directory is recognised by its card (config.json with this format).
CORRECTOR = Output("corrector directory", directory=True,
                   recognise=lambda d: json_with_format(FORMAT)(d / CONFIG))


class Corrector(nn.Module):
    """Normalisation + ActionCorrectionNetwork, built from its card; see module docstring."""

    def __init__(self, card: CorrectorCard) -> None:
        super().__init__()
        self.card = card
        n_in, n_out = len(card.input_channels), len(card.output_channels)
        self.register_buffer("input_index", torch.tensor([STATE_NAMES.index(n) for n in card.input_channels]))
        self.register_buffer("state_mean", torch.zeros(n_in))
        self.register_buffer("state_std", torch.ones(n_in))
        self.register_buffer("action_mean", torch.zeros(ACTION_DIM))
        self.register_buffer("action_std", torch.ones(ACTION_DIM))
        self.register_buffer("residual_std", torch.ones(n_out))
        # Network output -> delta_a in action units (labelled variants: the labels' spread). From
        # the card, not a weight: corrector files without it load with scale 1.
        scale = card.delta_scale or [1.0] * ACTION_DIM
        self.register_buffer("delta_scale", torch.tensor(scale, dtype=torch.float32), persistent=False)
        self.net = ActionCorrectionNetwork(
            n_in=n_in + ACTION_DIM, n_out=n_out, n_action=ACTION_DIM, hidden=card.network.hidden,
            layers=card.network.layers, learn_jacobian=card.variant in LEARNED_JACOBIAN)

    def features(self, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """Normalised network input [s_in; a] from full state vectors and actions."""
        s = (state.index_select(-1, self.input_index) - self.state_mean) / self.state_std
        return torch.cat([s, (action - self.action_mean) / self.action_std], dim=-1)

    def delta(self, state: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """F(s, a): the correction delta_a, in action units."""
        return self.net(self.features(state, action))[0] * self.delta_scale

    def correct(self, state, action):
        """a~ = a + F(s, a), batched; numpy in -> numpy out, torch in -> torch out."""
        as_numpy = isinstance(action, np.ndarray) or not torch.is_tensor(action)
        dtype = self.state_std.dtype
        s = torch.as_tensor(np.asarray(state) if as_numpy else state, dtype=dtype)
        a = torch.as_tensor(np.asarray(action) if as_numpy else action, dtype=dtype)
        if s.shape[-1] != STATE_DIM or a.shape[-1] != ACTION_DIM or s.shape[:-1] != a.shape[:-1]:
            raise ValueError(f"correct() takes states (..., {STATE_DIM}) and actions (..., {ACTION_DIM}) "
                             f"with matching batch shape; got {tuple(s.shape)} and {tuple(a.shape)}")
        with torch.no_grad():
            out = a + self.delta(s.reshape(-1, STATE_DIM), a.reshape(-1, ACTION_DIM)).reshape(a.shape)
        if as_numpy:
            return out.numpy().astype(np.asarray(action).dtype if np.asarray(action).dtype.kind == "f" else np.float64)
        return out.to(action.dtype)

    def freeze(self) -> "Corrector":
        self.eval()
        for p in self.parameters():
            p.requires_grad_(False)
        return self

    # ----- files ----------------------------------------------------------------------------
    def save(self, directory: str | Path) -> None:
        """Write ``model.safetensors`` and ``config.json`` into ``directory`` (must exist)."""
        save_weights(directory, self, self.card.to_json(), FORMAT)

    @classmethod
    def load(cls, directory: str | Path) -> "Corrector":
        """Load a frozen corrector; a clear ``UserError`` for a missing, corrupt or foreign file."""
        d = Path(directory)
        card = CorrectorCard.from_json(read_config(d, "corrector"), where=str(d / CONFIG), directory=d)
        try:
            model = cls(card)
            tensors = load_file(str(d / WEIGHTS))
            model.load_state_dict(tensors, strict=True)
            probe = model.correct(np.zeros((1, STATE_DIM)), np.zeros((1, ACTION_DIM)))  # card and weights agree
        except Exception as e:  # noqa: BLE001 - a broken weights file can fail in many ways
            raise corrupt_weights(d, e) from None
        if not np.isfinite(probe).all():
            raise UserError(f"{d / WEIGHTS} gives non-finite corrections (corrupt weights or normalisation)")
        return model.freeze()


def load_for_target(directory: str | Path, target: TargetDescription) -> Corrector:
    """``Corrector.load``, refused in one line unless the corrector was fitted for ``target``
    (``CorrectorCard.refuse_unless_fits``): a network that learned what ground softness leaves,
    or one step of 20 ms, corrects the wrong thing elsewhere."""
    corrector = Corrector.load(directory)
    corrector.card.refuse_unless_fits(target, directory)
    return corrector


@contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """Run a block on ``n`` torch intra-op threads (None or 0: leave torch's setting). Single-row
    calls of a small network lose much on a busy machine with more threads (0.1 ms on one, 8 ms on
    two while the other core was busy)."""
    if not n:
        yield
        return
    before = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(before)
