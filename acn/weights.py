"""A torch module shared as a directory of two files: ``model.safetensors`` (the tensors, never
pickle) and ``config.json`` (what rebuilds the module). The frozen corrector (``acn-fit``) and the
walking policy (``acn-ppo``) are both written and read this way; each checks its own config."""

from __future__ import annotations

import json
from pathlib import Path

from safetensors.torch import save_file
from torch import nn

from acn.errors import UserError
from acn.jsonfile import read_json

WEIGHTS, CONFIG = "model.safetensors", "config.json"


def save_weights(directory: str | Path, module: nn.Module, config: dict, format: str) -> None:
    """Write ``module``'s tensors and ``config`` into ``directory`` (which must exist; callers
    build it beside its destination and move it into place whole)."""
    d = Path(directory)
    tensors = {k: v.detach().contiguous().cpu() for k, v in module.state_dict().items()}
    save_file(tensors, str(d / WEIGHTS), metadata={"format": format})
    (d / CONFIG).write_text(json.dumps(config, indent=2))


def read_config(directory: str | Path, what: str):
    """The parsed ``config.json`` of a ``what`` directory (e.g. "corrector"); a one-line
    ``UserError`` where the directory lacks either file or the JSON does not parse."""
    d = Path(directory)
    missing = f"{d} is not a {what} directory (needs {CONFIG} and {WEIGHTS})"
    if not (d / WEIGHTS).is_file():
        raise UserError(missing)
    return read_json(d / CONFIG, missing)


def corrupt_weights(directory: str | Path, error: Exception) -> UserError:
    """The one-line error for weights that fail to load into the module their config builds."""
    return UserError(f"{Path(directory) / WEIGHTS} is corrupt or does not match its config: "
                     f"{(str(error).splitlines() or [type(error).__name__])[0]}")
