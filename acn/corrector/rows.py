"""The rows acn-fit learns from, and the tensors it trains on.

- ``split_episodes``: train / validation by whole episodes;
- ``Labelled``: rows with same-state labels (``same_state_rows``: a Gauss-Newton solve per row,
  ``acn.corrector.labels``);
- ``Normaliser``: the training set's statistics, kept in the corrector;
- ``Split``: one split as tensors, normalised (``trajectory_split`` for the two-trajectory
  residual, ``labelled_split`` for labels).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from acn.corrector.acn import INPUT_CHANNELS
from acn.corrector.card import Normalisation
from acn.corrector.evaluate import output_spread
from acn.corrector.labels import Solution, SolveConfig, solve
from acn.corrector.oracle import OUTPUT_INDEX
from acn.corrector.sensitivity import channel_index
from acn.datasets.reader import PairedTransitions
from acn.errors import UserError

INPUT_INDEX = channel_index(INPUT_CHANNELS)  # the state channels of the paper's filter (the widest input)


def split_episodes(episodes: np.ndarray, val_fraction: float, seed: int) -> np.ndarray:
    """Boolean mask of validation rows: whole episodes, at least one, never all."""
    unique = np.unique(episodes)
    if len(unique) < 2:
        raise UserError("need at least 2 episodes to hold one out for validation")
    rng = np.random.default_rng(seed)
    n_val = min(len(unique) - 1, max(1, round(val_fraction * len(unique))))
    return np.isin(episodes, rng.permutation(unique)[:n_val])


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


def same_state_rows(d: PairedTransitions, resim, weights: np.ndarray, solver: SolveConfig) -> Labelled:
    """Labels at the SOURCE states of recorded rows: goal the recorded s'_src (``labels.solve``)."""
    return Labelled(d.state, d.action, d.next_state,
                    solve(resim, d.state, d.action, d.next_state, OUTPUT_INDEX, weights, solver))


class Normaliser:
    """Training-set statistics, stored in the corrector."""

    def __init__(self, states: np.ndarray, actions: np.ndarray, residual: np.ndarray, spread_states: np.ndarray,
                 delta: np.ndarray | None = None, channels: tuple[str, ...] = INPUT_CHANNELS) -> None:
        self.index = channel_index(channels)
        s = states[:, self.index]
        self.state_mean, self.state_std = s.mean(0), _safe_std(s)
        self.action_mean, self.action_std = actions.mean(0), _safe_std(actions)
        self.residual_std = _safe_std(residual)
        self.state_spread = output_spread(spread_states)  # channel scale: divergence, label weights
        self.delta_scale = None if delta is None else _safe_std(delta, floor=1e-6)

    def inputs(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
        s = (states[:, self.index] - self.state_mean) / self.state_std
        return np.concatenate([s, (actions - self.action_mean) / self.action_std], axis=1)

    def load_into(self, model) -> None:
        """Copy the statistics into a ``Corrector``'s buffers."""
        for name in ("state_mean", "state_std", "action_mean", "action_std", "residual_std"):
            getattr(model, name).copy_(torch.as_tensor(getattr(self, name), dtype=torch.float32))
        if self.delta_scale is not None:
            model.delta_scale.copy_(torch.as_tensor(self.delta_scale, dtype=torch.float32))

    def card(self) -> Normalisation:
        """The statistics as the corrector's card records them."""
        values = lambda v: tuple(np.asarray(v, dtype=float).tolist())  # noqa: E731
        return Normalisation(values(self.state_mean), values(self.state_std), values(self.action_mean),
                             values(self.action_std), values(self.residual_std), values(self.state_spread),
                             None if self.delta_scale is None else values(self.delta_scale))


def _safe_std(x: np.ndarray, floor: float = 1e-8) -> np.ndarray:
    std = x.std(0)
    return np.where(std > floor, std, 1.0)


def tensor(a: np.ndarray, device: torch.device) -> torch.Tensor:
    return torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float32, device=device)


def trajectory_split(d: PairedTransitions, norm: Normaliser, jacobian: np.ndarray | None,
                     device: torch.device) -> Split:
    """paper / mujoco-jacobian: the target's state and action in, the two-trajectory residual out."""
    jac = None if jacobian is None else tensor(jacobian / norm.residual_std[None, :, None], device)
    return Split(tensor(norm.inputs(d.target_state, d.target_action), device),
                 tensor(d.residual()[:, OUTPUT_INDEX] / norm.residual_std, device), jac)


def labelled_split(rows: Labelled, norm: Normaliser, device: torch.device) -> Split:
    """inverse: the labelled state and action in, delta_a* / delta_scale out (plus gap and J)."""
    s = rows.solution
    return Split(tensor(norm.inputs(rows.state, rows.action), device), tensor(s.residual / norm.residual_std, device),
                 tensor(s.jacobian / norm.residual_std[None, :, None], device),
                 tensor(s.delta / norm.delta_scale, device), tensor(norm.delta_scale, device))
