"""``FitConfig``: every hyper-parameter of ``acn-fit``, and what a None field means per variant."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import torch

from acn.corrector.acn import LABELLED, VARIANTS
from acn.corrector.labels import SolveConfig
from acn.errors import UserError

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
    precision: str = "auto"         # bf16 matmuls in training (torch.autocast) where the CPU/GPU has bf16 natively
    # torch threads in training on a CPU (0: torch's default, all cores). One: these networks are
    # small, so more threads gain little on an idle machine and lose much on a shared one (2 cores,
    # another process busy: 3k samples/s on two threads, 33k on one)
    train_threads: int = 1
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
            raise UserError(f"--train-threads must be 0 (torch's default) or a count, got {self.train_threads}")
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
        """Whether training runs its matmuls in bf16: ``precision``, or for ``auto`` whether the
        device computes bf16 natively (elsewhere bf16 is emulated, slower than float32)."""
        if self.precision != "auto":
            return self.precision == "bf16"
        if self.device.startswith("cuda"):
            return torch.cuda.is_bf16_supported()
        return cpu_has_native_bf16()


def cpu_has_native_bf16() -> bool:
    """Whether this CPU has bf16 instructions (x86 AVX512-BF16 or AMX), from its flags in
    ``/proc/cpuinfo``; False where there is none to read (then training stays in float32)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return False
    flags = next((line.split(":", 1)[1].split() for line in text.splitlines() if line.startswith("flags")), [])
    return "avx512_bf16" in flags or "amx_bf16" in flags
