"""Does a corrector work? Closed-loop divergence and the paper's reward metrics.

Closed loop: the dataset's policy runs from held-out initial states in the source and the
target, once with the target uncorrected and once with a~ = a + F(s_target, a). Divergence
at step t is s_src - s_tgt (angles wrapped); per channel group it is the L2 norm in the
channels' units; the headline number is the L2 norm over the model's output channels, each
divided by its spread in the training data, averaged over the common horizon of the two
runs. ``divergence_reduction = 1 - corrected / uncorrected``.

Reward (the paper's): r_t = 1.0 v_x - 0.01 |tau|^2 - 0.5 |(roll, pitch)| - 0.1 |qdot|^2, with v_x
the trunk's forward speed (body frame), tau the applied torque, from s_{t+1}.
eps_transfer = mean_i (R_i^target,corrected - R_i^source); delta_corr = mean_i (R_i^source -
R_i^target,uncorrected); with their mean, mode and expectation as in the paper's Table 1
(over per-step reward differences: mode = centre of the fullest of 50 bins, expectation =
histogram-weighted mean).
"""

from __future__ import annotations

import numpy as np

from acn.datasets.reader import state_difference
from acn.toolkit.collector import CollectConfig, Episode, PairedRollout, Trace
from acn.toolkit.reward import REWARD_WEIGHTS
from acn.toolkit.reward import reward as step_reward
from acn.toolkit.state import GROUPS, SLICES, STATE_NAMES

HELD_OUT_SEED_OFFSET = 1_000_003  # evaluation initial states are never training ones


def reward(trace: Trace) -> np.ndarray:
    """The paper's per-step reward for one simulator's trace, (T,) (``acn.toolkit.reward``)."""
    return step_reward(trace.next_state, trace.effort, REWARD_WEIGHTS)


def distribution_stats(x: np.ndarray, bins: int = 50) -> dict[str, float]:
    """mean, mode (fullest histogram bin's centre) and expectation (histogram-weighted mean)."""
    x = np.asarray(x, dtype=float)
    counts, edges = np.histogram(x, bins=bins)
    centres = (edges[:-1] + edges[1:]) / 2
    return {"mean": float(x.mean()), "mode": float(centres[np.argmax(counts)]),
            "expectation": float((counts * centres).sum() / counts.sum())}


def closed_loop(cfg: CollectConfig, corrector, episodes: int, seconds: float,
                output_channels: list[str], channel_scale: np.ndarray) -> dict:
    """Run held-out episodes with and without ``corrector``; see module docstring."""
    cfg = CollectConfig(**{**cfg.__dict__, "seed": cfg.seed + HELD_OUT_SEED_OFFSET, "seconds": seconds,
                           "episodes": episodes, "corrector": None})
    runs: dict[str, list[Episode]] = {}
    for name, corr in (("uncorrected", None), ("corrected", corrector)):
        rollout = PairedRollout(cfg, corrector=corr)
        runs[name] = [rollout.episode(i) for i in range(episodes)]
        rollout.close()
    index = np.array([STATE_NAMES.index(c) for c in output_channels])
    out: dict = {"episodes": episodes, "seconds": seconds, "seed": cfg.seed}
    for name, eps in runs.items():
        out[f"{name}_ends"] = [e.end for e in eps]
    headline, groups = {"uncorrected": [], "corrected": []}, {"uncorrected": {}, "corrected": {}}
    for u, c in zip(runs["uncorrected"], runs["corrected"]):
        horizon = min(len(u), len(c))
        for name, ep in (("uncorrected", u), ("corrected", c)):
            d = state_difference(ep.source.next_state[:horizon], ep.target.next_state[:horizon])
            headline[name].append(np.linalg.norm(d[:, index] / channel_scale, axis=1))
            for g in GROUPS:
                groups[name].setdefault(g, []).append(np.linalg.norm(d[:, SLICES[g]], axis=1))
    for name in headline:
        out[f"divergence_{name}"] = float(np.mean(np.concatenate(headline[name])))
        out[f"divergence_by_group_{name}"] = {g: float(np.mean(np.concatenate(v))) for g, v in groups[name].items()}
    out["divergence_reduction"] = 1.0 - out["divergence_corrected"] / out["divergence_uncorrected"]
    # Divergence over the horizon (mean over episodes at each step), for plots.
    h = min(len(x) for x in headline["uncorrected"] + headline["corrected"])
    out["divergence_curve_uncorrected"] = np.mean([x[:h] for x in headline["uncorrected"]], axis=0).tolist()
    out["divergence_curve_corrected"] = np.mean([x[:h] for x in headline["corrected"]], axis=0).tolist()

    r_src = [reward(e.source) for e in runs["uncorrected"]]
    r_unc = [reward(e.target) for e in runs["uncorrected"]]
    r_cor = [reward(e.target) for e in runs["corrected"]]
    R = {k: np.array([r.sum() for r in v]) for k, v in (("source", r_src), ("unc", r_unc), ("cor", r_cor))}
    step_diff = lambda tgt: np.concatenate([t[: min(len(t), len(s))] - s[: min(len(t), len(s))]  # noqa: E731
                                            for t, s in zip(tgt, r_src)])
    out["return_source"] = float(R["source"].mean())
    out["eps_transfer_uncorrected"] = float((R["unc"] - R["source"]).mean())
    out["eps_transfer"] = float((R["cor"] - R["source"]).mean())
    out["delta_corr"] = float((R["source"] - R["unc"]).mean())
    out["reward_difference_stats_uncorrected"] = distribution_stats(step_diff(r_unc))
    out["reward_difference_stats_corrected"] = distribution_stats(step_diff(r_cor))
    return out
