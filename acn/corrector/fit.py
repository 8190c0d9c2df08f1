"""Fit an Action Correction Network from paired dataset files (``acn-fit``).

``fit`` runs these stages in order, one function each; where the variants differ, the stage asks
the variant's strategy (``acn.corrector.variants``):

1. ``load_data``: read the datasets through lerobot (non-finite rows skipped) and the target the
   corrector is fitted for;
2. ``split_rows``: train / validation by episode, then the paper's filter (an option; by default
   only for ``paper`` and ``mujoco-jacobian``): keep rows with ||s_src - s_tgt|| (input channels)
   below the training rows' ``filter_percentile``-th percentile (the same threshold for validation);
3. ``label_rows``: same-state labels by Gauss-Newton solves on target re-simulations started from
   the SOURCE state, goal the recorded s'_src (``acn.corrector.labels``): of the training rows
   for the labelled variants, of every held-out row for the one-step evaluation;
4. ``variant.targets``: what the networks learn (``paper``: the two recorded trajectories'
   residual delta_s = (s'_src - s_src) - (s'_tgt - s_tgt) from the target state;
   ``mujoco-jacobian``: the same with J from the target simulator; ``inverse``: the labels from
   the source state), normalised by the training rows' statistics (labels by their spread,
   ``delta_scale``, kept in the corrector's card);
5. ``train_network``: Adam on the variant's loss from tensors held whole (``acn.corrector.train``);
6. ``run_rounds`` (``inverse`` with ``rounds`` > 0): collect with the current corrector in the
   target, label the visited target states, add them, train further (``acn.corrector.rounds``);
7. ``evaluate``: the objective on held-out rows; ``calibrate`` (default for ``inverse``): F is
   scaled by the value of ``SHRINK_GRID`` that leaves the least one-step error (re-simulated) on
   the first half of the held-out episodes, so a corrector that does not generalise is shrunk
   towards "no correction" instead of making the target worse; the one-step same-state error
   against the oracle's (``evaluate.one_step``, on the held-out rows the calibration did not see);
   held-out closed-loop episodes beside both oracles (``evaluate.closed_loop``);
8. ``corrector_card``: the card (``config.json``) records the fit, the data and the metrics.

Fields of ``FitConfig`` left None take the variant's default (``VARIANT_DEFAULTS``).

On top of a physical model (``fit(..., target=Model)``, ``acn-fit --model MODEL.json``): the
target is the dataset's target simulator with that model's effects written in (e.g. what
``acn-diagnose --auto --save-model`` added), for labels, rounds, the one-step reference and the
closed loop, so the network learns what the physics leaves. Only ``inverse`` re-simulates every
target it learns from (``paper`` and ``mujoco-jacobian`` learn the recorded, nominal target's
residual). The corrector records the effects (``training_data.target_effects``) and is refused
where it would be applied to another model.

At deployment the corrector runs in the target and sees only the target's own state.
"""

from __future__ import annotations

import hashlib
import json
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import torch

from acn.corrector.acn import LABELLED, OUTPUT_CHANNELS
from acn.corrector.card import CorrectorCard, TrainingData
from acn.corrector.config import FitConfig
from acn.corrector.corrector import CORRECTOR, Corrector
from acn.corrector.evaluate import output_spread
from acn.corrector.rows import (INPUT_INDEX, OUTPUT_INDEX, Labelled, Normaliser, labelled_split, same_state_rows,
                                split_episodes)
from acn.corrector.train import train
from acn.corrector.variants import MIN_TRAIN_ROWS, Rows, Targets, Variant, objective, strategy
from acn.datasets.metadata import Simulator, config_from_metadata
from acn.datasets.reader import PairedTransitions, load_paired, percentile_filter
from acn.errors import UserError
from acn.jsonfile import strict_json
from acn.outputs.writing import Writing
from acn.sim.collector import CollectConfig
from acn.sim.policies import POLICIES
from acn.sim.resim import Resimulator

__all__ = ["SHRINK_GRID", "fit", "save", "calibrate", "calibration_rows",
           "fingerprint"]

SHRINK_GRID = (0.0, 0.25, 0.5, 0.75, 1.0)  # candidate scales of F for the calibration
Log = Callable[[str], None]


@dataclass
class FitData:
    """The paired rows of one fit and the target they are fitted for."""

    paired: PairedTransitions
    collect: CollectConfig  # the datasets' collection; its target with ``effects``
    effects: list           # AppliedEffect: the target model's effects ([]: the target as recorded)

    @property
    def target_simulator(self) -> str | None:
        return self.collect.target


@dataclass
class Resimulators:
    """The source and target simulators re-run from recorded states (labels, Jacobians, oracles)."""

    collect: CollectConfig
    source: Resimulator
    target: Resimulator


def fit(paths: list[str | Path], cfg: FitConfig, log: Log = print, target=None) -> tuple[Corrector, dict]:
    """The stages of the module docstring; returns the frozen corrector and its metrics.
    ``target``: an ``acn.sim.effects.Model`` of the target simulator whose effects the target
    gets (module docstring); None: the dataset's target as recorded."""
    cfg = cfg.resolved()
    variant = strategy(cfg.variant)
    t0 = time.perf_counter()
    torch.manual_seed(cfg.seed)
    data = load_data(paths, cfg, target, log)
    rows = split_rows(data.paired, cfg, log)
    timing: dict[str, float] = {}
    with resimulators(data, cfg.threads) as sims:
        rows = label_rows(rows, sims, variant, cfg, timing, log)
        t = time.perf_counter()
        targets = variant.targets(rows, None if sims is None else sims.target, cfg, torch.device(cfg.device), log)
        timing["jacobian_seconds"] = time.perf_counter() - t
        model = new_corrector(cfg, targets.norm)
        val_before, history = train_network(model, targets, variant, cfg, timing, log)
        reports = run_rounds(model, rows, targets.norm, sims, cfg, timing, log) if cfg.rounds else None
        metrics = evaluate(model, data, rows, targets, variant, sims, cfg, timing, log,
                           trained={"val_objective_before": val_before, "train_history": history}, rounds=reports)
    metrics["total_seconds"] = time.perf_counter() - t0
    metrics["seconds"] = timing
    model.card = corrector_card(model, cfg, targets.norm, data, metrics)
    return model, metrics


# ----- 1. data ----------------------------------------------------------------------------------
def load_data(paths: list[str | Path], cfg: FitConfig, target, log: Log) -> FitData:
    """The paired datasets, refused for a variant that needs MuJoCo as their target, and the
    target model's effects."""
    paired = load_paired([str(p) for p in paths])
    target_sim = paired.info.target.simulator if paired.info.target else None
    if cfg.variant != "paper" and target_sim != "mujoco":
        raise UserError(f"variant {cfg.variant} needs datasets whose target simulator is mujoco")
    effects = _target_effects(target, cfg.variant, target_sim)
    if effects:
        log(f"target: {target.describe()} (the network learns what these effects leave)")
    collect = config_from_metadata(paired.info, target_effects=effects,
                                   hidden_effects=_source_effects(paths, paired.info.source.simulator))
    return FitData(paired, collect, effects)


def _source_effects(paths: list[str | Path], backend: str) -> list:
    """The effects the datasets' source was collected with (the answer beside each dataset,
    ``acn.sim.hidden``: a model with effects or a robot with hidden ones as ``acn-collect --source``):
    the rounds and the closed loop run the source again with them."""
    from acn.sim.hidden import answer_path, sealed_robot

    found = [sealed_robot(answer_path(p), backend).effects if answer_path(p).is_file() else [] for p in paths]
    as_json = [[e.to_json() for e in effects] for effects in found]
    if any(j != as_json[0] for j in as_json[1:]):
        raise UserError("the datasets' sources were collected with different effects (their answer files differ); "
                        "fit them separately")
    return found[0]


def _target_effects(target, variant: str, target_sim: str | None) -> list:
    """The effects of the target model ``fit`` is given (``[]``: the dataset's own target)."""
    if target is None:
        return []
    if target.corrector:
        raise UserError(f"--model carries a corrector ({target.corrector}); give a model with effects only")
    if target.backend != target_sim:
        raise UserError(f"--model is a {target.backend} model; the datasets' target simulator is {target_sim}")
    if target.effects and variant not in LABELLED:
        raise UserError(f"--model with effects needs a variant that re-simulates the target ({', '.join(LABELLED)}); "
                        f"{variant} learns the recorded target's residual")
    return list(target.effects)


@contextmanager
def resimulators(data: FitData, threads: int | None) -> Iterator[Resimulators | None]:
    """The dataset's source and target (with the fit's effects) as Resimulators, closed after the
    block; None where the target is not MuJoCo (nothing is re-simulated then)."""
    if data.target_simulator != "mujoco":
        yield None
        return
    c = data.collect
    with Resimulator(c.source, c.source_sim, threads=threads) as source, \
            Resimulator(c.target, c.target_sim, threads=threads) as target:
        yield Resimulators(c, source, target)


# ----- 2. split and filter ----------------------------------------------------------------------
def split_rows(data: PairedTransitions, cfg: FitConfig, log: Log) -> Rows:
    """Whole episodes held out, then the paper's filter on both splits (the training rows' threshold)."""
    is_val = split_episodes(data.episode, cfg.val_fraction, cfg.seed)
    train_d, val_all = data.subset(~is_val), data.subset(is_val)
    gap_train = train_d.gap(INPUT_INDEX)
    pct = cfg.filter_percentile
    threshold = float(np.percentile(gap_train, pct)) if pct < 100 else np.inf
    rows = Rows(train_d.subset(percentile_filter(gap_train, pct)), val_all.subset(val_all.gap(INPUT_INDEX) < threshold),
                val_all, spread=output_spread(train_d.target_state), filter_threshold=threshold)
    if len(rows.train) < MIN_TRAIN_ROWS or len(rows.val) == 0:
        raise UserError(f"too little data after filtering: {len(rows.train)} training / {len(rows.val)} validation "
                        f"rows (need >= {MIN_TRAIN_ROWS} / 1); collect more episodes or raise --filter-percentile")
    log(f"data: {len(data)} rows from {len(data.sources)} dataset(s), {data.skipped_nonfinite} non-finite skipped; "
        f"after the {pct:g}th-percentile filter {len(rows.train)} train / {len(rows.val)} val")
    return rows


# ----- 3. same-state labels ---------------------------------------------------------------------
def label_rows(rows: Rows, sims: Resimulators | None, variant: Variant, cfg: FitConfig, timing: dict,
               log: Log) -> Rows:
    """Same-state labels: the training rows' (labelled variants, usable ones), and every held-out
    row's with the oracle's solve (their validation; every variant's one-step evaluation)."""
    if sims is None or not (variant.labelled or cfg.one_step):
        return rows
    t = time.perf_counter()
    weights, solver = 1.0 / rows.spread, cfg.solver()
    train_labels = same_state_rows(rows.train, sims.target, weights, solver).usable() if variant.labelled else None
    val_labels = same_state_rows(rows.val_all, sims.target, weights, cfg.oracle_solver())
    labelled = [x for x in (train_labels, val_labels) if x is not None]
    seconds = time.perf_counter() - t
    n_rows = sum(len(x) for x in labelled)
    timing["label_seconds"] = seconds
    timing["label_rows_per_s"] = n_rows / max(seconds, 1e-9)
    timing["label_simulator_share"] = sum(x.solution.resim_seconds for x in labelled) / max(seconds, 1e-9)
    log(f"same-state labels: {n_rows} rows in {seconds:.1f} s ({solver.resims_per_row} re-simulations per "
        f"training row, {cfg.oracle_solver().resims_per_row} per held-out row): "
        f"label_rows_per_s={timing['label_rows_per_s']:.0f} "
        f"label_simulator_share={timing['label_simulator_share']:.2f}")
    return replace(rows, train_labels=train_labels, val_labels=val_labels)


# ----- 4-5. the network and its training --------------------------------------------------------
def new_corrector(cfg: FitConfig, norm: Normaliser) -> Corrector:
    """An untrained corrector of the variant's shape, with the training statistics, on ``cfg.device``."""
    card = CorrectorCard.untrained(cfg.variant, cfg.hidden, cfg.layers, cfg.sensor_inputs)
    card = replace(card, delta_scale=None if norm.delta_scale is None else tuple(norm.delta_scale.tolist()))
    model = Corrector(card)
    norm.load_into(model)
    return model.to(torch.device(cfg.device))


def train_network(model: Corrector, targets: Targets, variant: Variant, cfg: FitConfig, timing: dict,
                  log: Log) -> tuple[dict, list[dict]]:
    """(validation objective before training, the training history); the model ends frozen on the CPU."""
    val_before = objective(model, targets.val, variant, cfg)

    def log_epoch(h: dict) -> None:
        if h["epoch"] % max(1, cfg.epochs // 5) == 0 or h["epoch"] == cfg.epochs:
            log(f"epoch {h['epoch']}: train loss {h['train_loss']:.5f}"
                + (f" ({h['threads']} torch thread{'s' if h['threads'] > 1 else ''})" if "threads" in h else ""))

    t = time.perf_counter()
    history = train(model, targets.train, cfg, on_epoch=log_epoch)
    timing["train_seconds"] = time.perf_counter() - t
    model.to("cpu").freeze()
    return val_before, history


# ----- 6. closed-loop rounds --------------------------------------------------------------------
def run_rounds(model: Corrector, rows: Rows, norm: Normaliser, sims: Resimulators, cfg: FitConfig, timing: dict,
               log: Log) -> list[dict]:
    """Closed-loop rounds (``acn.corrector.rounds``); one report per round."""
    from acn.corrector.evaluate import one_step, summarise
    from acn.corrector.rounds import relabel, visit

    t0 = time.perf_counter()
    if sims.collect.policy not in POLICIES:
        log(f"closed-loop rounds skipped: the dataset's policy {sims.collect.policy!r} is not a built-in policy")
        timing["rounds_seconds"] = time.perf_counter() - t0
        return []
    weights, solver, device = 1.0 / rows.spread, cfg.solver(), torch.device(cfg.device)
    labelled, reports = rows.train_labels, []
    for r in range(cfg.rounds):
        t = time.perf_counter()
        episodes = visit(sims.collect, model, cfg.round_episodes, cfg.round_seconds, r)
        t_visit = time.perf_counter() - t
        new = relabel(episodes, sims.source, sims.target, OUTPUT_INDEX, weights, solver)
        t_label = time.perf_counter() - t - t_visit
        before = one_step(model, sims.target, new.state, new.action, new.goal, new.solution, OUTPUT_INDEX, weights)
        closed = summarise({"corrected": episodes}, list(OUTPUT_CHANNELS), norm.state_spread)["runs"]["corrected"]
        new_rows = Labelled(new.state, new.action, new.goal, new.solution).usable()
        labelled = labelled + new_rows
        model.net.to(device)
        for p in model.net.parameters():
            p.requires_grad_(True)
        train(model, labelled_split(labelled, norm, device), cfg, epochs=cfg.round_epochs)
        model.to("cpu").freeze()
        report = {"round": r + 1, "episodes": len(episodes), "rows_added": len(new_rows), "rows_total": len(labelled),
                  "visit_seconds": t_visit, "label_seconds": t_label, "seconds": time.perf_counter() - t,
                  "one_step_on_visited_before_refit": before,
                  "closed_loop_on_visited": {k: closed[k] for k in ("divergence", "eps_transfer", "target_falls")}}
        reports.append(report)
        log(f"round {r + 1}: {len(new_rows)} visited rows labelled ({report['seconds']:.1f} s); on them the "
            f"corrector removed {before['corrected_removed']:.2f} of the one-step error (oracle "
            f"{before['oracle_removed']:.2f}); closed loop there: eps_transfer {closed['eps_transfer']:.1f}, "
            f"divergence {closed['divergence']:.3f}, {closed['target_falls']} target fall(s)")
    timing["rounds_seconds"] = time.perf_counter() - t0
    return reports


# ----- 7. evaluation ----------------------------------------------------------------------------
def evaluate(model: Corrector, data: FitData, rows: Rows, targets: Targets, variant: Variant,
             sims: Resimulators | None, cfg: FitConfig, timing: dict, log: Log, trained: dict,
             rounds: list[dict] | None) -> dict:
    """The metrics (``metrics.json``): rows, objectives, training, labels, rounds, calibration,
    one-step and closed-loop evaluation on held-out data."""
    val = targets.val.to("cpu")
    metrics: dict = {
        "variant": cfg.variant,
        "rows": {"read": len(data.paired), "skipped_nonfinite": data.paired.skipped_nonfinite,
                 "train": len(targets.train), "val": len(targets.val), "filter_percentile": cfg.filter_percentile,
                 "filter_threshold": rows.filter_threshold if np.isfinite(rows.filter_threshold) else None},
        "val_objective_before": trained["val_objective_before"],
        "val_objective": objective(model, val, variant, cfg),
        "train_history": trained["train_history"],
        "train_seconds": timing["train_seconds"],
        "train_samples_per_s": len(targets.train) * cfg.epochs / timing["train_seconds"],
    }
    if variant.labelled:
        metrics["labels"] = {"train_removed": rows.train_labels.solution.removed,
                             "val_removed_by_oracle": rows.val_labels.solution.removed,
                             "solver": asdict(cfg.solver()), "oracle_solver": asdict(cfg.oracle_solver()),
                             "seconds": timing["label_seconds"], "label_rows_per_s": timing["label_rows_per_s"],
                             "simulator_share": timing["label_simulator_share"]}
    if rounds is not None:
        metrics["rounds"] = rounds
    true_j = variant.true_jacobian_objective(model, targets, rows, None if sims is None else sims.target, cfg)
    if true_j is not None:
        metrics["val_objective_true_jacobian"] = true_j
    if sims is not None and rows.val_labels is not None:
        metrics.update(one_step_metrics(model, rows, sims, cfg, log))
    if cfg.eval_episodes > 0 and data.paired.info.policy not in POLICIES:
        log(f"closed-loop evaluation skipped: the dataset's policy {data.paired.info.policy!r} is not a "
            "built-in policy this command can run again (for a PPO policy: acn-ppo --eval POLICY --corrector DIR)")
    elif cfg.eval_episodes > 0:
        from acn.corrector.evaluate import closed_loop

        log(f"closed loop: {cfg.eval_episodes} held-out episodes of {cfg.eval_seconds:g} s: uncorrected, corrected"
            + (", same-state and tracking oracles" if cfg.oracles and sims is not None else ""))
        t = time.perf_counter()
        metrics["closed_loop"] = closed_loop(data.collect, model, cfg.eval_episodes, cfg.eval_seconds,
                                             list(OUTPUT_CHANNELS), rows.spread,
                                             oracles=cfg.oracles and sims is not None, solver=cfg.oracle_solver(),
                                             log=log)
        timing["closed_loop_seconds"] = time.perf_counter() - t
    return metrics


def one_step_metrics(model: Corrector, rows: Rows, sims: Resimulators, cfg: FitConfig, log: Log) -> dict:
    """``calibration`` (with ``cfg.calibrate``, on the first half of the held-out episodes) and the
    ``one_step`` same-state error against the oracle's on the held-out rows it did not see."""
    from acn.corrector.evaluate import one_step

    out: dict = {}
    weights, v = 1.0 / rows.spread, rows.val_labels
    if cfg.calibrate:
        calib = calibration_rows(rows.val_all.episode)
        out["calibration"] = calibrate(model, sims.target, v.subset(calib), weights)
        v = v.subset(~calib)
        log(f"calibration on {int(calib.sum())} held-out rows: F scaled by {out['calibration']['scale']:g}")
    o = out["one_step"] = one_step(model, sims.target, v.state, v.action, v.goal, v.solution, OUTPUT_INDEX, weights)
    log(f"one-step same-state error on held-out rows: {o['error_no_correction']:.4f} -> corrector "
        f"{o['error_corrected']:.4f}, oracle {o['error_oracle']:.4f}: share_of_oracle={o['share_of_oracle']:.3f}")
    return out


def calibration_rows(episodes: np.ndarray) -> np.ndarray:
    """Mask of the held-out rows that calibrate: the first half of the held-out episodes (or, with
    one episode, the first half of its rows); the rest report."""
    unique = np.unique(episodes)
    if len(unique) > 1:
        return np.isin(episodes, unique[: (len(unique) + 1) // 2])
    mask = np.zeros(len(episodes), dtype=bool)
    mask[: len(episodes) // 2] = True
    return mask


def calibrate(model: Corrector, resim: Resimulator, rows: Labelled, weights: np.ndarray) -> dict:
    """Scale F by the ``SHRINK_GRID`` value with the least one-step error on ``rows`` (re-simulated)."""
    from acn.corrector.evaluate import one_step

    base = model.delta_scale.clone()
    errors = {}
    for k in SHRINK_GRID:
        model.delta_scale.copy_(base * k)
        errors[k] = one_step(model, resim, rows.state, rows.action, rows.goal, rows.solution, OUTPUT_INDEX,
                             weights)["error_corrected"]
    best = min(errors, key=errors.get)
    model.delta_scale.copy_(base * best)
    model.card = replace(model.card, delta_scale=tuple(model.delta_scale.tolist()))
    return {"scale": best, "rows": len(rows), "error_by_scale": {str(k): v for k, v in errors.items()}}


# ----- 8. the card ------------------------------------------------------------------------------
def corrector_card(model: Corrector, cfg: FitConfig, norm: Normaliser, data: FitData, metrics: dict) -> CorrectorCard:
    """The model's card with the record of the fit: hyper-parameters, statistics, data, metrics."""
    info = data.paired.info

    def simulator(s) -> Simulator | None:
        return None if s is None else Simulator(simulator=s.simulator, version=s.version)  # not the log's files

    training_data = TrainingData(
        datasets=tuple(data.paired.sources), fingerprint=fingerprint(data.paired.sources),
        source=simulator(info.source), target=simulator(info.target),
        target_effects=tuple(e.to_json() for e in data.effects), action_mode=info.action_mode,
        control_hz=info.control_hz, policy=info.policy)
    return replace(model.card, action_channels=info.action_names, fit=asdict(cfg),
                   normalisation=norm.card(), training_data=training_data, metrics=_summary(metrics))


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


def _summary(m: dict) -> dict:
    out = {"val_objective": m["val_objective"], "rows": m["rows"]}
    for key in ("val_objective_true_jacobian", "one_step"):
        if key in m:
            out[key] = m[key]
    if "closed_loop" in m:
        cl = m["closed_loop"]
        out["closed_loop"] = {k: cl[k] for k in ("divergence_uncorrected", "divergence_corrected",
                                                 "divergence_reduction", "eps_transfer", "eps_transfer_uncorrected",
                                                 "delta_corr", "verdict") if k in cl}
        out["closed_loop"]["runs"] = {name: {k: run[k] for k in ("divergence", "eps_transfer", "target_falls")}
                                      for name, run in cl["runs"].items()}
    return strict_json(out)


def save(model: Corrector, metrics: dict, out: str | Path, overwrite: bool = False) -> Path:
    """Write the corrector directory whole or not at all (``acn.outputs.writing.Writing``)."""
    with Writing(out, CORRECTOR, overwrite) as output:
        output.path.mkdir()
        model.save(output.path)
        (output.path / "metrics.json").write_text(json.dumps(strict_json(metrics), indent=2, allow_nan=False))
    return output.out
