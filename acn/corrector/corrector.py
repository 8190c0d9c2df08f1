"""The frozen corrector: ``a~ = a + F(s, a)``, saved as ``model.safetensors`` + ``config.json``.

``Corrector.load(dir)`` returns a module in eval mode with gradients off. ``correct(state,
action)`` takes the documented 43-channel state vector(s) and 12 action(s), numpy or torch,
one row or a batch, and returns the corrected action(s) in the same type and shape.
Nothing is pickled: weights are safetensors, everything else is JSON.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch
from safetensors.torch import load_file, save_file
from torch import nn

from acn.errors import UserError
from acn.jsonfile import read_json
from acn.outputs import Output, json_with_format
from acn.corrector.acn import LEARNED_JACOBIAN, OUTPUT_CHANNELS, ActionCorrectionNetwork, input_channels
from acn.sim.state import ACTION_DIM, STATE_DIM, STATE_NAMES

WEIGHTS, CONFIG = "model.safetensors", "config.json"
FORMAT = "acn-corrector/1"
# A corrector directory is recognised by its card (config.json with this format).
CORRECTOR = Output("corrector directory", directory=True,
                   recognise=lambda d: json_with_format(FORMAT)(d / CONFIG))


class Corrector(nn.Module):
    """Normalisation + ActionCorrectionNetwork; see module docstring."""

    def __init__(self, config: dict) -> None:
        super().__init__()
        self.config = config
        net = config["network"]
        self.register_buffer("input_index", torch.tensor([STATE_NAMES.index(n) for n in config["input_channels"]]))
        self.register_buffer("state_mean", torch.zeros(len(config["input_channels"])))
        self.register_buffer("state_std", torch.ones(len(config["input_channels"])))
        self.register_buffer("action_mean", torch.zeros(ACTION_DIM))
        self.register_buffer("action_std", torch.ones(ACTION_DIM))
        self.register_buffer("residual_std", torch.ones(len(config["output_channels"])))
        # Network output -> delta_a in action units (labelled variants: the labels' spread). From
        # config.json, not a weight: corrector files written before it existed still load.
        scale = config.get("delta_scale") or [1.0] * ACTION_DIM
        self.register_buffer("delta_scale", torch.tensor(scale, dtype=torch.float32), persistent=False)
        self.net = ActionCorrectionNetwork(
            n_in=len(config["input_channels"]) + ACTION_DIM, n_out=len(config["output_channels"]),
            n_action=ACTION_DIM, hidden=net["hidden"], layers=net["layers"],
            learn_jacobian=config["variant"] in LEARNED_JACOBIAN)

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
        d = Path(directory)
        tensors = {k: v.detach().contiguous().cpu() for k, v in self.state_dict().items()}
        save_file(tensors, str(d / WEIGHTS), metadata={"format": FORMAT})
        (d / CONFIG).write_text(json.dumps({"format": FORMAT, **self.config}, indent=2))

    @classmethod
    def load(cls, directory: str | Path) -> "Corrector":
        """Load a frozen corrector; a clear ``UserError`` for a missing, corrupt or foreign file."""
        d = Path(directory)
        missing = f"{d} is not a corrector directory (needs {CONFIG} and {WEIGHTS})"
        if not (d / WEIGHTS).is_file():
            raise UserError(missing)
        config = read_json(d / CONFIG, missing)
        if not isinstance(config, dict) or config.get("format") != FORMAT:
            raise UserError(f"{d / CONFIG} is not an acn corrector config (format {FORMAT!r} expected)")
        try:
            model = cls(config)
            tensors = load_file(str(d / WEIGHTS))
            model.load_state_dict(tensors, strict=True)
            probe = model.correct(np.zeros((1, STATE_DIM)), np.zeros((1, ACTION_DIM)))  # config and weights agree
        except Exception as e:  # noqa: BLE001 - a broken config or weights file can fail in many ways
            raise UserError(f"{d / WEIGHTS} is corrupt or does not match its config: "
                            f"{(str(e).splitlines() or [type(e).__name__])[0]}") from None
        if not np.isfinite(probe).all():
            raise UserError(f"{d / WEIGHTS} gives non-finite corrections (corrupt weights or normalisation)")
        return model.freeze()

    @property
    def target_effects(self) -> list[dict]:
        """The physical effects (JSON, ``AppliedEffect.to_json``) of the target model it was fitted
        on top of (``acn-fit --model``); [] for the target simulator as recorded."""
        return list((self.config.get("training_data") or {}).get("target_effects") or [])


def load_for_target(directory: str | Path, effects: list[dict]) -> Corrector:
    """``Corrector.load``, refused in one line unless the corrector was fitted for a target with
    exactly ``effects`` (JSON; [] the simulator as is): a network that learned what ground
    softness leaves corrects the wrong thing on a model without it."""
    corrector = Corrector.load(directory)
    if corrector.target_effects != list(effects):
        def text(e: list[dict]) -> str:
            return " + ".join(x.get("name", "?") for x in e) or "nothing"

        raise UserError(f"corrector {directory} was fitted for a target with {text(corrector.target_effects)} added; "
                        f"here the target has {text(effects)} added (fit one for it: acn-fit --model MODEL.json)")
    return corrector


def default_config(variant: str, hidden: int, layers: int, sensors: bool | None = None) -> dict:
    return {
        "variant": variant,
        "network": {"hidden": hidden, "layers": layers, "activation": "SiLU"},
        "input_channels": list(input_channels(variant, sensors)),
        "output_channels": list(OUTPUT_CHANNELS),
        "action_channels": None,
        "delta_scale": None,  # labelled variants: the labels' spread per action channel
    }
