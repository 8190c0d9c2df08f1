"""Fit an Action Correction Network from paired dataset files (``acn-fit``).

From files to a frozen corrector, top to bottom:

1. ``load_paired``: read the datasets through lerobot, skip non-finite rows;
2. split train / validation by episode;
3. the paper's filter: keep rows with ||s_src - s_tgt|| (input channels) below the training
   rows' ``filter_percentile``-th percentile (the same threshold for validation);
4. normalise: inputs by their training mean / std, residuals delta_s by their training std;
5. ``mujoco-jacobian`` only: J from the target simulator (``control_jacobian``);
6. train from tensors held whole (no per-sample Python);
7. evaluate on held-out data and held-out closed-loop episodes (``acn.models.evaluate``).

The network sees the TARGET state: at deployment the corrector runs in the target and sees
only its own state (the paper writes F(s, a) with s_src ~ s_tgt after filtering).
"""

from __future__ import annotations

import hashlib
import shutil
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from acn.atomic import move_into_place, temporary_beside
from acn.datasets.reader import PairedTransitions, load_paired, percentile_filter
from acn.errors import UserError
from acn.models.acn import INPUT_CHANNELS, OUTPUT_CHANNELS, VARIANTS, acn_loss
from acn.models.corrector import Corrector, default_config
from acn.toolkit.state import STATE_NAMES

MIN_TRAIN_ROWS = 64


@dataclass
class FitConfig:
    """Every hyper-parameter of acn-fit; defaults are the paper's where it gives one."""

    variant: str = "paper"
    hidden: int = 256               # paper
    layers: int = 2                 # hidden layers per network
    lambda_l1: float = 0.01         # paper
    lr: float = 1e-3                # paper, Adam
    batch_size: int = 256           # paper
    epochs: int = 30
    filter_percentile: float = 70.0  # paper
    val_fraction: float = 0.2       # of episodes
    seed: int = 0
    device: str = "cpu"
    precision: str = "auto"         # bf16 autocast where the CPU/GPU has native bf16, else fp32
    jacobian_eps: float = 0.01      # action units (rad for joint targets)
    eval_episodes: int = 4          # closed-loop episodes from held-out initial states
    eval_seconds: float = 5.0

    def validate(self) -> None:
        if self.variant not in VARIANTS:
            raise UserError(f"unknown variant {self.variant!r}; choose from {', '.join(VARIANTS)}")
        if not 0 < self.val_fraction < 1:
            raise UserError(f"--val-fraction must be in (0, 1), got {self.val_fraction}")
        if self.device.startswith("cuda") and not torch.cuda.is_available():
            raise UserError("--device cuda: no CUDA device is available")
        if self.precision not in ("auto", "bf16", "fp32"):
            raise UserError(f"--precision must be auto, bf16 or fp32, got {self.precision!r}")

    def use_bf16(self) -> bool:
        if self.precision != "auto":
            return self.precision == "bf16"
        if self.device.startswith("cuda"):
            return torch.cuda.is_bf16_supported()
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())


@dataclass
class Split:
    """Tensors of one split; ``jacobian`` only for the mujoco-jacobian variant."""

    x: torch.Tensor          # (N, 52) normalised [s_in; a]
    residual: torch.Tensor   # (N, 33) normalised delta_s
    jacobian: torch.Tensor | None  # (N, 33, 12) normalised J

    def __len__(self) -> int:
        return len(self.x)


_IN = np.array([STATE_NAMES.index(c) for c in INPUT_CHANNELS])
_OUT = np.array([STATE_NAMES.index(c) for c in OUTPUT_CHANNELS])


def split_episodes(episodes: np.ndarray, val_fraction: float, seed: int) -> np.ndarray:
    """Boolean mask of validation rows: whole episodes, at least one, never all."""
    unique = np.unique(episodes)
    if len(unique) < 2:
        raise UserError("need at least 2 episodes to hold one out for validation")
    rng = np.random.default_rng(seed)
    n_val = min(len(unique) - 1, max(1, round(val_fraction * len(unique))))
    return np.isin(episodes, rng.permutation(unique)[:n_val])


def fingerprint(paths: list[str]) -> str:
    """sha256 over each dataset's meta/info.json and data files: which data trained a model."""
    h = hashlib.sha256()
    for root in paths:
        files = [Path(root) / "meta" / "info.json", *sorted((Path(root) / "data").rglob("*.parquet"))]
        for f in files:
            h.update(f.relative_to(root).as_posix().encode())
            with open(f, "rb") as fh:
                for block in iter(lambda: fh.read(1 << 20), b""):
                    h.update(block)
    return "sha256:" + h.hexdigest()


class Normaliser:
    """Training-set statistics, stored in the corrector."""

    def __init__(self, train: PairedTransitions) -> None:
        s = train.target_state[:, _IN]
        self.state_mean, self.state_std = s.mean(0), _safe_std(s)
        self.action_mean, self.action_std = train.target_action.mean(0), _safe_std(train.target_action)
        self.residual_std = _safe_std(train.residual()[:, _OUT])
        self.state_spread = _safe_std(train.target_state[:, _OUT])  # for the divergence metric

    def inputs(self, d: PairedTransitions) -> np.ndarray:
        s = (d.target_state[:, _IN] - self.state_mean) / self.state_std
        return np.concatenate([s, (d.target_action - self.action_mean) / self.action_std], axis=1)

    def residual(self, d: PairedTransitions) -> np.ndarray:
        return d.residual()[:, _OUT] / self.residual_std

    def load_into(self, model: Corrector) -> None:
        for name in ("state_mean", "state_std", "action_mean", "action_std", "residual_std"):
            getattr(model, name).copy_(torch.as_tensor(getattr(self, name), dtype=torch.float32))

    def as_dict(self) -> dict:
        return {k: np.asarray(v).tolist() for k, v in vars(self).items()}


def _safe_std(x: np.ndarray) -> np.ndarray:
    std = x.std(0)
    return np.where(std > 1e-8, std, 1.0)


def make_split(d: PairedTransitions, norm: Normaliser, cfg: FitConfig, device: torch.device) -> Split:
    jac = None
    if cfg.variant == "mujoco-jacobian":
        from acn.datasets.record import config_from_metadata
        from acn.models.sensitivity import control_jacobian

        sim = config_from_metadata(d.info).sim
        j = control_jacobian(sim, d.target_state, d.target_action, list(OUTPUT_CHANNELS), eps=cfg.jacobian_eps)
        jac = torch.as_tensor(j / norm.residual_std[None, :, None], dtype=torch.float32, device=device)
    t = lambda a: torch.as_tensor(a, dtype=torch.float32, device=device)  # noqa: E731
    return Split(t(norm.inputs(d)), t(norm.residual(d)), jac)


def train(model: Corrector, tr: Split, cfg: FitConfig, on_epoch=None) -> list[dict]:
    """Adam on the paper's loss; batches are index slices of tensors held whole.

    Speed (benchmarks/fit.py): fused Adam (one kernel for all parameters) and, where the
    hardware has native bf16, bf16 autocast for the matmuls (weights and loss stay fp32).
    """
    net = model.net
    net.train()
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, fused=True)
    device_type = tr.x.device.type
    bf16 = cfg.use_bf16()
    gen = torch.Generator(device="cpu").manual_seed(cfg.seed)
    history, n, b = [], len(tr), cfg.batch_size
    for epoch in range(cfg.epochs):
        perm = torch.randperm(n, generator=gen).to(tr.x.device)
        total, count = torch.zeros((), device=tr.x.device), 0
        for i in range(0, n, b):
            idx = perm[i:i + b]
            with torch.autocast(device_type, dtype=torch.bfloat16, enabled=bf16):
                delta_a, j_pred = net(tr.x[idx])
            jac = j_pred.float() if j_pred is not None else tr.jacobian[idx]
            loss, _ = acn_loss(delta_a.float(), jac, tr.residual[idx], cfg.lambda_l1)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            total += loss.detach() * len(idx)
            count += len(idx)
        history.append({"epoch": epoch + 1, "train_loss": float(total) / count})
        if on_epoch:
            on_epoch(history[-1])
    net.eval()
    return history


@torch.no_grad()
def objective(model: Corrector, split: Split, cfg: FitConfig, jacobian: torch.Tensor | None = None) -> dict:
    """The paper's objective on ``split`` with the model's J (or the given J)."""
    delta_a, j_pred = model.net(split.x)
    j = jacobian if jacobian is not None else (j_pred if j_pred is not None else split.jacobian)
    total, fit = acn_loss(delta_a, j, split.residual, cfg.lambda_l1)
    zero = split.residual.pow(2).mean()  # the fit term of "no correction"
    return {"loss": float(total), "fit": float(fit), "fit_no_correction": float(zero),
            "mean_abs_delta_a": float(delta_a.abs().mean())}


def fit(paths: list[str | Path], cfg: FitConfig, log=print) -> tuple[Corrector, dict]:
    """Steps 1-7 of the module docstring; returns the frozen corrector and its metrics."""
    cfg.validate()
    t0 = time.perf_counter()
    device = torch.device(cfg.device)
    torch.manual_seed(cfg.seed)
    data = load_paired([str(p) for p in paths])
    if cfg.variant == "mujoco-jacobian" and (data.info["target"] or {}).get("simulator") != "mujoco":
        raise UserError("variant mujoco-jacobian needs datasets whose target simulator is mujoco")
    is_val = split_episodes(data.episode, cfg.val_fraction, cfg.seed)
    train_d, val_d = data.subset(~is_val), data.subset(is_val)
    gap_train = train_d.gap(_IN)
    threshold = float(np.percentile(gap_train, cfg.filter_percentile)) if cfg.filter_percentile < 100 else np.inf
    keep_train = percentile_filter(gap_train, cfg.filter_percentile)
    train_d, val_d = train_d.subset(keep_train), val_d.subset(val_d.gap(_IN) < threshold)
    if len(train_d) < MIN_TRAIN_ROWS or len(val_d) == 0:
        raise UserError(f"too little data after filtering: {len(train_d)} training / {len(val_d)} validation rows "
                        f"(need >= {MIN_TRAIN_ROWS} / 1); collect more episodes or raise --filter-percentile")
    log(f"data: {len(data)} rows from {len(paths)} dataset(s), {data.skipped_nonfinite} non-finite skipped; "
        f"after the {cfg.filter_percentile:g}th-percentile filter {len(train_d)} train / {len(val_d)} val")

    norm = Normaliser(train_d)
    model = Corrector(default_config(cfg.variant, cfg.hidden, cfg.layers))
    norm.load_into(model)
    model.to(device)
    t1 = time.perf_counter()
    tr, va = make_split(train_d, norm, cfg, device), make_split(val_d, norm, cfg, device)
    t_jac = time.perf_counter() - t1
    if cfg.variant == "mujoco-jacobian":
        log(f"control Jacobians from MuJoCo: {len(tr) + len(va)} rows in {t_jac:.1f} s")
    val_before = objective(model, va, cfg)
    t2 = time.perf_counter()
    history = train(model, tr, cfg, on_epoch=lambda h: log(f"epoch {h['epoch']}: train loss {h['train_loss']:.5f}")
                    if h["epoch"] % max(1, cfg.epochs // 5) == 0 or h["epoch"] == cfg.epochs else None)
    t_train = time.perf_counter() - t2
    model.to("cpu").freeze()
    va_cpu = Split(va.x.cpu(), va.residual.cpu(), None if va.jacobian is None else va.jacobian.cpu())
    metrics: dict = {
        "rows": {"read": len(data), "skipped_nonfinite": data.skipped_nonfinite, "train": len(tr), "val": len(va),
                 "filter_threshold": threshold if np.isfinite(threshold) else None},  # None: no filter
        "val_objective_before": val_before,
        "val_objective": objective(model, va_cpu, cfg),
        "train_history": history,
        "train_seconds": t_train,
        "train_samples_per_s": len(tr) * cfg.epochs / t_train,
    }
    if (data.info["target"] or {}).get("simulator") == "mujoco":
        # Honest comparison across variants: the fit under the target's TRUE sensitivity.
        true_j = va_cpu.jacobian
        if true_j is None:
            true_j = make_split(val_d, norm, FitConfig(**{**asdict(cfg), "variant": "mujoco-jacobian"}),
                                torch.device("cpu")).jacobian
        metrics["val_objective_true_jacobian"] = objective(model, va_cpu, cfg, jacobian=true_j)
    if cfg.eval_episodes > 0:
        from acn.datasets.record import config_from_metadata
        from acn.models.evaluate import closed_loop

        log(f"closed loop: {cfg.eval_episodes} held-out episodes of {cfg.eval_seconds:g} s, with and without")
        metrics["closed_loop"] = closed_loop(config_from_metadata(data.info), model, cfg.eval_episodes,
                                             cfg.eval_seconds, list(OUTPUT_CHANNELS), norm.state_spread)
    metrics["total_seconds"] = time.perf_counter() - t0
    model.config.update({
        "fit": asdict(cfg),
        "normalisation": norm.as_dict(),
        "training_data": {"datasets": data.sources, "fingerprint": fingerprint(data.sources),
                          "source": data.info["source"], "target": data.info["target"],
                          "action_mode": data.info["action_mode"], "control_hz": data.info["control_hz"],
                          "policy": data.info["policy"]},
        "action_channels": data.info["action_names"],
        "metrics": _summary(metrics),
    })
    return model, metrics


def _summary(m: dict) -> dict:
    out = {"val_objective": m["val_objective"], "rows": m["rows"]}
    if "val_objective_true_jacobian" in m:
        out["val_objective_true_jacobian"] = m["val_objective_true_jacobian"]
    if "closed_loop" in m:
        cl = m["closed_loop"]
        out["closed_loop"] = {k: cl[k] for k in ("divergence_uncorrected", "divergence_corrected",
                                                 "divergence_reduction", "eps_transfer", "eps_transfer_uncorrected",
                                                 "delta_corr")}
    return out


def save(model: Corrector, metrics: dict, out: str | Path, overwrite: bool = False) -> Path:
    """Write the model directory atomically (hidden temp dir, then rename)."""
    import json

    out = Path(out).absolute()
    if out.exists() and not overwrite:
        raise UserError(f"model directory {out} exists (use --overwrite to replace it)")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_beside(out)
    tmp.mkdir()
    try:
        model.save(tmp)
        (tmp / "metrics.json").write_text(json.dumps(metrics, indent=2, default=_json_default))
        return move_into_place(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _json_default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o))
