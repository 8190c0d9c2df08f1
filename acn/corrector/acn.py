"""The Action Correction Network (Geroev & Gerget 2025) and a well-posed variant.

Both networks read the same input x = [normalised s; normalised a]:

- ActionNet   x -> delta_a (12), the action correction in the action's own units;
- JacobianNet x -> J (n_out x 12), J ~ d s'/d a in normalised residual units per action unit.

Loss per batch (the paper's, Algorithm 1):  mean_c (J . delta_a - delta_s)_c^2 + lambda |delta_a|_1,
with delta_s the normalised residual (``acn.datasets.reader.PairedTransitions.residual``).

Variants (``VARIANTS``):

- ``paper``: J is learned by JacobianNet. Degenerate: J and delta_a are both free, so J can
  absorb any scale of delta_a and nothing ties J to the target's real sensitivity.
- ``mujoco-jacobian``: J is the target simulator's own control Jacobian d s_{t+1} / d a over
  the control step, computed by finite differences in MuJoCo (``acn.corrector.sensitivity``);
  only ActionNet is trained. The problem is then well posed: delta_a is the action change
  that, to first order, makes the target's transition match the source's.
- ``inverse``: an inverse model, as in Grounded Action Transformation. Each training row gets
  a label delta_a* from a Gauss-Newton solve on target re-simulations (``acn.corrector.labels``):
  the correction that makes the target, started from the SOURCE state s_t with a_t + delta_a*,
  land on the recorded source s'_src (the same-state gap, not the difference of two drifted
  trajectories). ActionNet regresses delta_a* (``regression_loss``, labels scaled by their
  training spread), optionally plus ``jacobian_weight`` times the paper's fit term under the
  target's true J at delta_a = 0.
"""

from __future__ import annotations

import torch
from torch import nn

from acn.sim.state import DYNAMIC_GROUPS, GROUPS, STATE_NAMES

VARIANTS: tuple[str, ...] = ("inverse", "paper", "mujoco-jacobian")
LEARNED_JACOBIAN = ("paper",)
LABELLED = ("inverse",)  # variants that regress Gauss-Newton labels

# Absolute position in the plane and heading carry no dynamics: the network does not see them.
_EXCLUDED = ("base_pos_x", "base_pos_y", "base_yaw")
INPUT_CHANNELS: tuple[str, ...] = tuple(n for n in STATE_NAMES if n not in _EXCLUDED)           # 40
OUTPUT_CHANNELS: tuple[str, ...] = tuple(n for g in DYNAMIC_GROUPS for n in GROUPS[g] if n not in _EXCLUDED)  # 33
# What determines a simulated transition: the dynamic channels (no sensor readings, which differ
# between simulators for the same state: the labelled variants see only these).
DYNAMIC_INPUT_CHANNELS: tuple[str, ...] = OUTPUT_CHANNELS  # 33


def input_channels(variant: str, sensors: bool | None = None) -> tuple[str, ...]:
    """The state channels F reads: with the contact and IMU readings (``sensors``; default: all
    variants but the labelled ones) or the dynamic channels only."""
    if sensors is None:
        sensors = variant not in LABELLED
    return INPUT_CHANNELS if sensors else DYNAMIC_INPUT_CHANNELS


def mlp(n_in: int, hidden: int, n_out: int, layers: int = 2) -> nn.Sequential:
    """``layers`` hidden layers of width ``hidden`` with SiLU, then a linear output."""
    mods: list[nn.Module] = []
    for i in range(layers):
        mods += [nn.Linear(n_in if i == 0 else hidden, hidden), nn.SiLU()]
    mods.append(nn.Linear(hidden, n_out))
    return nn.Sequential(*mods)


class ActionCorrectionNetwork(nn.Module):
    """ActionNet and (for the ``paper`` variant) JacobianNet on one normalised input."""

    def __init__(self, n_in: int, n_out: int, n_action: int, hidden: int = 256, layers: int = 2,
                 learn_jacobian: bool = True) -> None:
        super().__init__()
        self.n_out, self.n_action = n_out, n_action
        self.action_net = mlp(n_in, hidden, n_action, layers)
        self.jacobian_net = mlp(n_in, hidden, n_out * n_action, layers) if learn_jacobian else None
        nn.init.zeros_(self.action_net[-1].weight)  # start from "no correction"
        nn.init.zeros_(self.action_net[-1].bias)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
        delta_a = self.action_net(x)
        if self.jacobian_net is None:
            return delta_a, None
        return delta_a, self.jacobian_net(x).view(-1, self.n_out, self.n_action)


def acn_loss(delta_a: torch.Tensor, jacobian: torch.Tensor, residual: torch.Tensor,
             lambda_l1: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(total, residual term): mean_c (J delta_a - delta_s)^2 + lambda * mean_batch |delta_a|_1."""
    fit = (torch.bmm(jacobian, delta_a.unsqueeze(-1)).squeeze(-1) - residual).pow(2).mean()
    return fit + lambda_l1 * delta_a.abs().sum() / len(delta_a), fit


def regression_loss(delta_a: torch.Tensor, label: torch.Tensor) -> torch.Tensor:
    """mean over rows and channels of (delta_a - delta_a*)^2, both scaled by the labels' spread."""
    return (delta_a - label).pow(2).mean()
