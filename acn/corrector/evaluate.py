"""Does a corrector work? Closed-loop divergence, the paper's reward metrics, oracle bounds.

Closed loop (``closed_loop``): the dataset's policy runs from held-out initial states in the
source and the target (the policy acts on the SOURCE state, as in the collector), once per
"run":

- ``uncorrected``: the target gets a;
- ``corrected``: the target gets a~ = a + F(s_target, a);
- ``same_state_oracle``: at every step, from the target's own state, the source simulator is
  re-simulated one control step with a, and delta_a is solved (Gauss-Newton on target
  re-simulations, ``acn.corrector.labels``) so the target's next state matches it: the best
  per-step corrector F(s, a) for the paper's objective (``acn.corrector.oracle``);
- ``tracking_oracle``: the same solve, matching the source trajectory's actual next state
  (it knows where the source is; no F(s, a) does).

The source trajectory is the same in every run (the target does not act back on it).
Divergence at step t is s_src - s_tgt (angles wrapped); per channel group it is the L2 norm in
the channels' units; the headline number is the L2 norm over the model's output channels, each
divided by its spread in the training data; both are averaged over the steps every run of
that episode survives (the common horizon). ``divergence_reduction = 1 - corrected /
uncorrected``. Falls (``target_fell``) and blow-ups are counted per run.

Reward (the paper's, ``acn.sim.reward``): r_t = 1.0 v_x - 0.01 |tau|^2 - 0.5 |(roll, pitch)|
- 0.1 |qdot|^2 from s_{t+1} and the applied torque. Per run, eps_transfer = mean_i (R_i^target
- R_i^source) with R^source the source's return over the whole episode (its longest trace);
delta_corr = mean_i (R_i^source - R_i^target,uncorrected); with mean, mode and expectation of
the per-step reward differences as in the paper's Table 1 (mode = centre of the fullest of 50
bins, expectation = histogram-weighted mean).

Each run is also compared with the reference run (``uncorrected``, or the model as given), episode
by episode from the same initial states (``versus``): how much closer its return is to the
source's (``reward_gap_closer_by``: mean of |R_ref - R_src| - |R_run - R_src|), how much lower its
divergence (``divergence_lower_by``), each with its standard error over the episodes, new falls,
and in words (``change``): a difference counts only beyond two standard errors. ``verdict``
says it in one sentence.

``same_state_oracle(sim, policy, initial_states, seconds)`` gives the same-state oracle's
per-step rewards for a policy that acts on the target's own state (e.g. a PPO policy), for
evaluations outside paired collection.
"""

from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from acn.datasets.reader import state_difference
from acn.corrector.acn import OUTPUT_CHANNELS
from acn.corrector.corrector import torch_threads
from acn.corrector.labels import SolveConfig
from acn.corrector.oracle import OUTPUT_INDEX, SameStateOracle, TrackingOracle
from acn.sim.collector import CollectConfig, Episode, PairedRollout, Trace, fallen
from acn.sim.reward import REWARD_WEIGHTS
from acn.sim.reward import reward as step_reward
from acn.sim.state import GROUPS, SLICES, STATE_NAMES

HELD_OUT_SEED_OFFSET = 1_000_003  # evaluation initial states are never training ones
RUNS: tuple[str, ...] = ("uncorrected", "corrected", "same_state_oracle", "tracking_oracle")
TARGET_FALLS = ("target_fell", "target_diverged")  # episode ends that count as the target falling

# Oracle channel weights when no training data is at hand: 1 / these typical spreads of the 33
# output channels (std over the target states of `make demo`'s trot data, rounded).
TYPICAL_SPREAD: dict[str, float] = {"base_pos": 0.01, "base_rpy": 0.07, "joint_pos": 0.2, "base_linvel": 0.17,
                                    "base_angvel": 0.9, "joint_vel": 2.0}


def typical_spread(channels: Sequence[str] = OUTPUT_CHANNELS) -> np.ndarray:
    group = {n: g for g, names in GROUPS.items() for n in names}
    return np.array([TYPICAL_SPREAD[group[c]] for c in channels])


def output_spread(states: np.ndarray, floor: float = 1e-8) -> np.ndarray:
    """(33,) spread (std) of each output channel over ``states`` (N, 43), NaN (missing channels)
    ignored, 1 where a channel does not vary: the channel scale of divergence and oracle weights."""
    std = np.nanstd(np.asarray(states, float)[:, OUTPUT_INDEX], axis=0)
    return np.where(np.isfinite(std) & (std > floor), std, 1.0)


def reward(trace: Trace) -> np.ndarray:
    """The paper's per-step reward for one simulator's trace, (T,) (``acn.sim.reward``)."""
    return step_reward(trace.next_state, trace.effort, REWARD_WEIGHTS)


def distribution_stats(x: np.ndarray, bins: int = 50) -> dict[str, float]:
    """mean, mode (fullest histogram bin's centre) and expectation (histogram-weighted mean)."""
    x = np.asarray(x, dtype=float)
    counts, edges = np.histogram(x, bins=bins)
    centres = (edges[:-1] + edges[1:]) / 2
    return {"mean": float(x.mean()), "mode": float(centres[np.argmax(counts)]),
            "expectation": float((counts * centres).sum() / counts.sum())}


def held_out(cfg: CollectConfig, episodes: int, seconds: float) -> CollectConfig:
    """``cfg`` moved to evaluation initial states (never training ones), without a corrector."""
    return CollectConfig(**{**cfg.__dict__, "seed": cfg.seed + HELD_OUT_SEED_OFFSET, "seconds": seconds,
                            "episodes": episodes, "corrector": None})


def run_episodes(cfg: CollectConfig, corrector, episodes: int, bind: Callable | None = None) -> list[Episode]:
    rollout = PairedRollout(cfg, corrector=corrector)
    try:
        if bind is not None:
            bind(rollout)
        with torch_threads(1):  # single-row corrector calls
            return [rollout.episode(i) for i in range(episodes)]
    finally:
        rollout.close()


def run_oracles(cfg: CollectConfig, episodes: int, channel_scale: np.ndarray,
                solver: SolveConfig | None = None) -> dict[str, list[Episode]]:
    """The two oracle runs of ``closed_loop`` (``cfg`` already held out)."""
    weights = 1.0 / np.asarray(channel_scale, float)
    same = SameStateOracle(cfg.source, cfg.source_sim, cfg.target, cfg.target_sim, weights, solver)
    track = TrackingOracle(cfg.target, cfg.target_sim, weights, solver=solver)
    try:
        def bind(rollout: PairedRollout) -> None:
            track.goal = rollout.source.get_state  # the source has stepped when the target is corrected
        return {"same_state_oracle": run_episodes(cfg, same, episodes),
                "tracking_oracle": run_episodes(cfg, track, episodes, bind)}
    finally:
        same.close()
        track.close()


def closed_loop(cfg: CollectConfig, corrector, episodes: int, seconds: float, output_channels: list[str],
                channel_scale: np.ndarray, oracles: bool = True, solver: SolveConfig | None = None,
                log: Callable[[str], None] | None = None) -> dict:
    """Run held-out episodes uncorrected, with ``corrector`` (if any) and the oracles; see module doc.

    Returns per-run metrics under ``runs`` and, for the corrector, the flat keys
    ``divergence_uncorrected``, ``divergence_corrected``, ``divergence_reduction``,
    ``eps_transfer``, ``eps_transfer_uncorrected``, ``delta_corr``.
    """
    import time

    cfg = held_out(cfg, episodes, seconds)
    runs: dict[str, list[Episode]] = {}
    seconds_per_run: dict[str, float] = {}
    t = time.perf_counter()
    runs["uncorrected"] = run_episodes(cfg, None, episodes)
    seconds_per_run["uncorrected"] = time.perf_counter() - t
    if corrector is not None:
        t = time.perf_counter()
        runs["corrected"] = run_episodes(cfg, corrector, episodes)
        seconds_per_run["corrected"] = time.perf_counter() - t
    if oracles and cfg.target is not None:
        t = time.perf_counter()
        runs.update(run_oracles(cfg, episodes, channel_scale, solver))
        seconds_per_run["oracles"] = time.perf_counter() - t
    if log:
        log("closed loop: " + ", ".join(f"{k} {v:.1f} s" for k, v in seconds_per_run.items()))
    out = summarise(runs, output_channels, channel_scale)
    out.update({"episodes": episodes, "seconds": seconds, "seed": cfg.seed, "wall_seconds": seconds_per_run})
    return out


def episode_stats(x: np.ndarray) -> dict:
    """mean, std, stderr and n of per-episode values (std and stderr 0 for one episode)."""
    x = np.asarray(x, float)
    n = len(x)
    std = float(x.std(ddof=1)) if n > 1 else 0.0
    return {"mean": float(x.mean()), "std": std, "stderr": float(std / np.sqrt(n)) if n > 1 else 0.0, "n": int(n)}


SIGNIFICANT_STDERR = 2.0  # a paired per-episode difference counts beyond this many standard errors


def change(stats: dict, better: str, worse: str) -> str:
    """``better`` / ``worse`` where the mean paired difference exceeds ``SIGNIFICANT_STDERR``
    standard errors (positive: better), else "no clear change" (always with one episode)."""
    if stats["n"] < 2 or abs(stats["mean"]) <= SIGNIFICANT_STDERR * stats["stderr"]:
        return "no clear change"
    return better if stats["mean"] > 0 else worse


def summarise(runs: dict[str, list[Episode]], output_channels: list[str], channel_scale: np.ndarray,
              reference: str = "uncorrected") -> dict:
    """Metrics of each run against the shared source trajectory, and of each run against
    ``reference`` (``versus``) when it is among the runs (module docstring)."""
    index = np.array([STATE_NAMES.index(c) for c in output_channels])
    names = [r for r in RUNS if r in runs] + [r for r in runs if r not in RUNS]
    n_ep = len(runs[names[0]])
    # The source is the same in every run: its longest trace is the whole episode.
    source = [max((runs[r][i] for r in names), key=len).source for i in range(n_ep)]
    r_src = [reward(s) for s in source]
    horizon = [min(len(runs[r][i]) for r in names) for i in range(n_ep)]
    out: dict = {"runs": {}, "horizon_steps": horizon, "return_source": float(np.mean([r.sum() for r in r_src]))}
    for name in names:
        eps = runs[name]
        headline, groups = [], {g: [] for g in GROUPS}
        for ep, h in zip(eps, horizon):
            d = state_difference(ep.source.next_state[:h], ep.target.next_state[:h])
            headline.append(np.linalg.norm(d[:, index] / channel_scale, axis=1))
            for g in GROUPS:
                groups[g].append(np.linalg.norm(d[:, SLICES[g]], axis=1))
        r_tgt = [reward(e.target) for e in eps]
        R_tgt, R_src = np.array([r.sum() for r in r_tgt]), np.array([r.sum() for r in r_src])
        diffs = np.concatenate([t[:min(len(t), len(s))] - s[:min(len(t), len(s))] for t, s in zip(r_tgt, r_src)])
        h_min = min(horizon) if horizon else 0
        out["runs"][name] = {
            "divergence": float(np.mean(np.concatenate(headline))),
            "divergence_by_group": {g: float(np.mean(np.concatenate(v))) for g, v in groups.items()},
            "divergence_curve": np.mean([x[:h_min] for x in headline], axis=0).tolist(),
            "return_target": float(R_tgt.mean()),
            "eps_transfer": float((R_tgt - R_src).mean()),
            "reward_difference_stats": distribution_stats(diffs),
            "ends": [e.end for e in eps],
            "target_falls": sum(e.end in TARGET_FALLS for e in eps),
            "steps": [len(e) for e in eps],
            "reward_gap_per_episode": np.abs(R_tgt - R_src).tolist(),  # |R_target - R_source|
            "divergence_per_episode": [float(x.mean()) for x in headline],
        }
    if reference in out["runs"]:
        ref = out["runs"][reference]
        for name, run in out["runs"].items():
            if name != reference:
                run["versus"] = versus(ref, run, reference)
    if "uncorrected" not in out["runs"]:
        return out
    unc = out["runs"]["uncorrected"]
    out["eps_transfer_uncorrected"] = unc["eps_transfer"]
    out["delta_corr"] = -unc["eps_transfer"]
    out["divergence_uncorrected"] = unc["divergence"]
    out["divergence_by_group_uncorrected"] = unc["divergence_by_group"]
    out["reward_difference_stats_uncorrected"] = unc["reward_difference_stats"]
    out["uncorrected_ends"] = unc["ends"]
    if "corrected" in out["runs"]:
        cor = out["runs"]["corrected"]
        out["eps_transfer"] = cor["eps_transfer"]
        out["divergence_corrected"] = cor["divergence"]
        out["divergence_by_group_corrected"] = cor["divergence_by_group"]
        out["divergence_reduction"] = 1.0 - cor["divergence"] / unc["divergence"]
        out["reward_difference_stats_corrected"] = cor["reward_difference_stats"]
        out["corrected_ends"] = cor["ends"]
        out["verdict"] = verdict(out)
    return out


def versus(ref: dict, run: dict, reference: str) -> dict:
    """``run`` against ``ref`` (two ``summarise`` runs), episode by episode (module docstring)."""
    gap = episode_stats(np.subtract(ref["reward_gap_per_episode"], run["reward_gap_per_episode"]))
    div = episode_stats(np.subtract(ref["divergence_per_episode"], run["divergence_per_episode"]))
    fell = lambda r: np.isin(r["ends"], TARGET_FALLS)  # noqa: E731
    return {"reference": reference, "reward_gap_closer_by": gap, "divergence_lower_by": div,
            "new_falls": int((fell(run) & ~fell(ref)).sum()),
            "change": {"reward_gap": change(gap, "narrower", "wider"), "divergence": change(div, "lower", "higher")}}


def verdict(cl: dict) -> str:
    """One sentence: the corrected run against the uncorrected one in ``cl`` (``summarise``'s
    result): reward gap, divergence, falls, and the share of the same-state oracle's reward-gap
    reduction it reaches."""
    r = cl["runs"]["corrected"]
    v = r["versus"]
    ref = cl["runs"][v["reference"]]
    g, d = v["reward_gap_closer_by"], v["divergence_lower_by"]
    mean = lambda x: float(np.mean(x))  # noqa: E731
    helps = v["change"]["reward_gap"] == "narrower" and not v["new_falls"]
    text = (f"the corrector {'narrows' if helps else 'does not narrow'} the transfer gap on {g['n']} held-out episode(s): "
            f"reward gap |R_target - R_source| {mean(ref['reward_gap_per_episode']):.1f} -> "
            f"{mean(r['reward_gap_per_episode']):.1f} per episode ({v['change']['reward_gap']}: closer by "
            f"{g['mean']:.1f} +- {g['stderr']:.1f} stderr), divergence {ref['divergence']:.3g} -> {r['divergence']:.3g} "
            f"({v['change']['divergence']}: lower by {d['mean']:.3g} +- {d['stderr']:.2g}), "
            f"{v['new_falls'] or 'no'} new fall(s)")
    oracle = cl["runs"].get("same_state_oracle")
    if oracle is not None:
        reach = mean(ref["reward_gap_per_episode"]) - mean(oracle["reward_gap_per_episode"])
        text += f"; the same-state oracle's reward gap {mean(oracle['reward_gap_per_episode']):.1f}"
        if reach > 0:
            text += f" ({g['mean'] / reach:.0%} of its reduction reached)"
    return text


def same_state_oracle(sim, policy, initial_states: Sequence[np.ndarray], seconds: float, source: str = "pybullet",
                      target: str = "mujoco", source_sim=None, channel_scale: np.ndarray | None = None,
                      solver: SolveConfig | None = None) -> list[np.ndarray]:
    """Per episode, the target's per-step paper rewards with the same-state oracle in the loop.

    ``policy`` (``acn.sim.policies.Policy``: ``reset(rng)``, ``__call__(state, t)``) acts on
    the TARGET's own state; each action a is replaced by the oracle's a + delta_a (from the
    target's state: the source re-simulated one step with a, delta_a solved so the target
    matches it). ``sim``: the target's ``SimConfig`` (``source_sim``: the source's, default the
    same). Channel weights 1 / ``channel_scale`` (default ``typical_spread()``). An episode
    ends at ``seconds``, a fall (``collector.fallen``) or a blow-up (that step is dropped).
    The policy is reset with ``np.random.default_rng(0)`` at each episode start.
    """
    from acn.sim.backends import SimulationDiverged, make_backend
    from acn.sim.policies import policy_action

    scale = typical_spread() if channel_scale is None else np.asarray(channel_scale, float)
    oracle = SameStateOracle(source, source_sim or sim, target, sim, 1.0 / scale, solver)
    backend = make_backend(target, sim)
    steps = int(round(seconds / sim.control_dt))
    out: list[np.ndarray] = []
    try:
        for s0 in initial_states:
            s = backend.reset(np.asarray(s0, float))
            policy.reset(np.random.default_rng(0))
            rewards = []
            for k in range(steps):
                a = oracle.correct(s, policy_action(policy, s, k * sim.control_dt, sim))
                try:
                    tau = backend.step(a)
                except SimulationDiverged:
                    break
                s = backend.get_state()
                rewards.append(float(step_reward(s, tau, REWARD_WEIGHTS)))
                if fallen(s):
                    break
            out.append(np.array(rewards))
    finally:
        oracle.close()
        backend.close()
    return out


def one_step(corrector, resim, states: np.ndarray, actions: np.ndarray, goals: np.ndarray, solution,
             channels: np.ndarray, weights: np.ndarray) -> dict:
    """The one-step same-state error on held-out rows: no correction, ``corrector``, the oracle.

    Per row, error = || W (goal - T_tgt(s, action)) ||^2 over ``channels`` with W = diag(weights);
    the oracle's action is a + delta_a* of ``solution`` (``acn.corrector.labels.solve`` on the same
    rows), the corrector's is ``corrector.correct(s, a)``; T_tgt is one re-simulated control
    step. ``share_of_oracle`` = (no correction - corrector) / (no correction - oracle), summed
    over the rows no re-simulation lost.
    """
    from acn.corrector.sensitivity import channel_difference

    corrected = np.asarray(corrector.correct(states, actions), float)
    pred = resim.run(states, corrected)
    r = channel_difference(np.asarray(goals, float)[:, channels], pred.state[:, 0, channels], channels)
    e_cor = ((np.asarray(weights) * r) ** 2).sum(axis=1)
    ok = ~solution.diverged & ~pred.diverged & np.isfinite(solution.error_after)
    e0, eo, ec = solution.error_before[ok].sum(), solution.error_after[ok].sum(), e_cor[ok].sum()
    n = max(int(ok.sum()), 1)
    return {"rows": int(ok.sum()), "error_no_correction": float(e0 / n), "error_oracle": float(eo / n),
            "error_corrected": float(ec / n), "oracle_removed": float(1 - eo / e0) if e0 > 0 else 0.0,
            "corrected_removed": float(1 - ec / e0) if e0 > 0 else 0.0,
            "share_of_oracle": float((e0 - ec) / (e0 - eo)) if e0 > eo else float("nan"),
            "mean_abs_delta_oracle": float(np.abs(solution.delta[ok]).mean()) if ok.any() else 0.0,
            "mean_abs_delta_corrected": float(np.abs(corrected - actions)[ok].mean()) if ok.any() else 0.0}


RUN_LABELS = {"uncorrected": "uncorrected", "corrected": "corrected", "same_state_oracle": "same-state oracle",
              "tracking_oracle": "tracking oracle"}
TABLE_GROUPS = ("base_pos", "base_rpy", "base_linvel", "base_angvel", "joint_pos", "joint_vel")


def format_closed_loop(cl: dict) -> str:
    """``closed_loop``'s runs side by side, as text (divergence per group in the groups' units)."""
    head = f"{'run':<19}{'divergence':>11}" + "".join(f"{g:>12}" for g in TABLE_GROUPS) \
        + f"{'return':>10}{'eps_transfer':>13}{'falls':>7}"
    lines = [f"closed loop, {cl['episodes']} held-out episodes x {cl['seconds']:g} s (divergence over the common "
             f"horizon; return of the source {cl['return_source']:.1f}):", head]
    for name, r in cl["runs"].items():
        lines.append(f"{RUN_LABELS.get(name, name):<19}{r['divergence']:>11.3f}"
                     + "".join(f"{r['divergence_by_group'][g]:>12.4f}" for g in TABLE_GROUPS)
                     + f"{r['return_target']:>10.1f}{r['eps_transfer']:>13.2f}{r['target_falls']:>7d}")
    return "\n".join(lines)
