"""acn-fit's three variants as strategies: the targets each learns from and the loss it minimises.

``acn.corrector.fit`` runs the same stages for every variant and asks the variant where they
differ (the variants themselves: ``acn.corrector.acn``):

- ``targets``: the normalisation and the training and validation tensors (``Split``) from the
  filtered rows: the two-trajectory residual (``paper``), with the target's control Jacobian from
  MuJoCo (``mujoco-jacobian``), or same-state Gauss-Newton labels (``inverse``);
- ``loss``: the training loss of a batch, from the networks' outputs;
- ``jacobian``: the J under which the paper's fit term is reported (learned, or the target's);
- ``true_jacobian_objective``: the validation objective under the target's true J, where the
  variant's own J may not be it.

``objective`` evaluates a variant's loss and the paper's fit term on a split.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass, replace
from typing import Callable, ClassVar

import numpy as np
import torch

from acn.corrector.acn import OUTPUT_CHANNELS, acn_loss, input_channels, regression_loss
from acn.corrector.config import FitConfig
from acn.corrector.rows import OUTPUT_INDEX, Labelled, Normaliser, Split, labelled_split, tensor, trajectory_split
from acn.corrector.sensitivity import control_jacobian
from acn.datasets.reader import PairedTransitions
from acn.errors import UserError
from acn.sim.resim import Resimulator

MIN_TRAIN_ROWS = 64


@dataclass
class Rows:
    """The paired rows of one fit, split and filtered, and their same-state labels."""

    train: PairedTransitions      # training rows after the filter
    val: PairedTransitions        # held-out rows after the filter
    val_all: PairedTransitions    # every held-out row: the one-step evaluation and the calibration
    spread: np.ndarray            # (33,) each output channel's spread over every training row (1 / label weights)
    filter_threshold: float       # the filter's source-target gap (inf: no filter)
    train_labels: Labelled | None = None  # labelled variants: the training rows' labels (usable ones)
    val_labels: Labelled | None = None    # every held-out row's labels (the oracle's solve)


@dataclass
class Targets:
    """What the networks train and are validated on, and the statistics that normalise it."""

    norm: Normaliser
    train: Split
    val: Split


class Variant(ABC):
    """One variant of acn-fit (module docstring)."""

    name: ClassVar[str]
    labelled: ClassVar[bool] = False  # learns from same-state labels of its training rows

    @abstractmethod
    def targets(self, rows: Rows, resim: Resimulator | None, cfg: FitConfig, device: torch.device,
                log: Callable[[str], None]) -> Targets:
        """The normalisation and tensors; ``resim``: the target's Resimulator (None without MuJoCo)."""

    @abstractmethod
    def loss(self, delta_out: torch.Tensor, j_pred: torch.Tensor | None, batch: Split,
             cfg: FitConfig) -> torch.Tensor:
        """The training loss on ``batch`` from ActionNet's output and JacobianNet's (or None)."""

    def jacobian(self, j_pred: torch.Tensor | None, batch: Split) -> torch.Tensor:
        """The J of the paper's fit term: the target's, carried by the split."""
        return batch.jacobian

    def true_jacobian_objective(self, model, targets: Targets, rows: Rows, resim: Resimulator | None,
                                cfg: FitConfig) -> dict | None:
        """The validation objective under the target's true J; None where the variant reports none."""
        return None


class _TrajectoryResidual(Variant):
    """The paper's loss on the two recorded trajectories' residual, seen from the target's state."""

    def targets(self, rows: Rows, resim: Resimulator | None, cfg: FitConfig, device: torch.device,
                log: Callable[[str], None]) -> Targets:
        d = rows.train
        norm = Normaliser(d.target_state, d.target_action, d.residual()[:, OUTPUT_INDEX], d.target_state,
                          channels=input_channels(self.name, cfg.sensor_inputs))
        jac_train, jac_val = self.target_jacobians(rows, resim, cfg, log)
        return Targets(norm, trajectory_split(rows.train, norm, jac_train, device),
                       trajectory_split(rows.val, norm, jac_val, device))

    def target_jacobians(self, rows: Rows, resim: Resimulator | None, cfg: FitConfig,
                         log: Callable[[str], None]) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The target's J of the training and validation rows, where the loss uses it."""
        return None, None

    def loss(self, delta_out: torch.Tensor, j_pred: torch.Tensor | None, batch: Split,
             cfg: FitConfig) -> torch.Tensor:
        return acn_loss(delta_out, self.jacobian(j_pred, batch), batch.residual, cfg.lambda_l1)[0]


class Paper(_TrajectoryResidual):
    """J learned by JacobianNet beside ActionNet (degenerate: ``acn.corrector.acn``)."""

    name = "paper"

    def jacobian(self, j_pred: torch.Tensor | None, batch: Split) -> torch.Tensor:
        return j_pred

    def true_jacobian_objective(self, model, targets: Targets, rows: Rows, resim: Resimulator | None,
                                cfg: FitConfig) -> dict | None:
        """An honest comparison across variants: the paper's fit under the target's TRUE sensitivity."""
        if resim is None:
            return None
        true_j = control_jacobian(resim, rows.val.target_state, rows.val.target_action, list(OUTPUT_CHANNELS),
                                  eps=cfg.jacobian_eps)
        val = replace(targets.val.to("cpu"),
                      jacobian=tensor(true_j / targets.norm.residual_std[None, :, None], torch.device("cpu")))
        return objective(model, val, MujocoJacobian(), cfg)


class MujocoJacobian(_TrajectoryResidual):
    """J the target simulator's own control Jacobian, by finite differences in MuJoCo."""

    name = "mujoco-jacobian"

    def target_jacobians(self, rows: Rows, resim: Resimulator | None, cfg: FitConfig,
                         log: Callable[[str], None]) -> tuple[np.ndarray | None, np.ndarray | None]:
        t = time.perf_counter()
        jac = [control_jacobian(resim, d.target_state, d.target_action, list(OUTPUT_CHANNELS), eps=cfg.jacobian_eps)
               for d in (rows.train, rows.val)]
        log(f"control Jacobians from MuJoCo: {len(rows.train) + len(rows.val)} rows in {time.perf_counter() - t:.1f} s")
        return jac[0], jac[1]

    def true_jacobian_objective(self, model, targets: Targets, rows: Rows, resim: Resimulator | None,
                                cfg: FitConfig) -> dict | None:
        """Its own J is the target's: the validation objective itself."""
        return None if resim is None else objective(model, targets.val.to("cpu"), self, cfg)


class Inverse(Variant):
    """ActionNet regresses same-state labels delta_a* (scaled by their training spread)."""

    name = "inverse"
    labelled = True

    def targets(self, rows: Rows, resim: Resimulator | None, cfg: FitConfig, device: torch.device,
                log: Callable[[str], None]) -> Targets:
        train = rows.train_labels
        if len(train) < MIN_TRAIN_ROWS:
            raise UserError(f"too little data: {len(train)} labelled training rows (need >= {MIN_TRAIN_ROWS})")
        norm = Normaliser(train.state, train.action, train.solution.residual, rows.train.target_state,
                          delta=train.solution.delta, channels=input_channels(self.name, cfg.sensor_inputs))
        val = rows.val_labels.usable()
        return Targets(norm, labelled_split(train, norm, device), labelled_split(val, norm, device))

    def loss(self, delta_out: torch.Tensor, j_pred: torch.Tensor | None, batch: Split,
             cfg: FitConfig) -> torch.Tensor:
        """The labels' regression, plus ``jacobian_weight`` times the paper's fit term under the
        target's J and ``label_state_weight`` times the label error as the next state sees it."""
        loss = regression_loss(delta_out, batch.label)
        if cfg.jacobian_weight:
            fit = acn_loss(delta_out * batch.scale, batch.jacobian, batch.residual, 0.0)[1]
            loss = loss + cfg.jacobian_weight * fit
        if cfg.label_state_weight:  # (delta_a - delta_a*) as the next state sees it, to first order
            seen = torch.bmm(batch.jacobian, ((delta_out - batch.label) * batch.scale).unsqueeze(-1)).squeeze(-1)
            loss = loss + cfg.label_state_weight * seen.pow(2).mean()
        return loss


STRATEGIES: dict[str, Variant] = {v.name: v for v in (Inverse(), Paper(), MujocoJacobian())}


def strategy(name: str) -> Variant:
    """The strategy of the variant ``name`` (one of ``acn.corrector.acn.VARIANTS``)."""
    return STRATEGIES[name]


@torch.no_grad()
def objective(model, split: Split, variant: Variant, cfg: FitConfig) -> dict:
    """The variant's loss on ``split`` and the paper's fit term (under the variant's J)."""
    delta_out, j_pred = model.net(split.x)
    delta = delta_out if split.scale is None else delta_out * split.scale
    _, fit = acn_loss(delta, variant.jacobian(j_pred, split), split.residual, 0.0)
    out = {"loss": float(variant.loss(delta_out, j_pred, split, cfg)), "fit": float(fit),
           "fit_no_correction": float(split.residual.pow(2).mean()), "mean_abs_delta_a": float(delta.abs().mean())}
    if split.label is not None:
        out["label_mse"] = float(regression_loss(delta_out, split.label))
        out["label_mse_no_correction"] = float(split.label.pow(2).mean())
    return out
