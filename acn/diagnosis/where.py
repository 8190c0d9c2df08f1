"""Where the model fails: the one-step error broken down, and said in plain words.

Breakdowns of the held-out one-step residuals (normalised RMS): by channel group and horizon,
by joint, by leg, by gait phase (a leg is in stance when its foot's measured contact is on),
by time in the episode, and against state variables: a joint's error against its speed, the
torque it applies (logged effort, else the control law's commanded torque) and how much its
action changed since the last step (what latency feeds on). Trends are Spearman rank
correlations between the variable and the joint's error, over all rows and joints.
"""

from __future__ import annotations

import numpy as np

from acn.diagnosis.compare import Comparison
from acn.diagnosis.problem import Problem
from acn.sim.backends.base import pd_torque
from acn.sim.state import FOOT_NAMES, JOINT_NAMES, SLICES

TREND = 0.3  # rank correlation from which a trend is worth saying


def _rms(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x ** 2))) if x.size else float("nan")


def _spearman(x: np.ndarray, y: np.ndarray) -> float:
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < 10 or np.ptp(x[ok]) == 0 or np.ptp(y[ok]) == 0:
        return 0.0
    rx, ry = np.argsort(np.argsort(x[ok])), np.argsort(np.argsort(y[ok]))
    return float(np.corrcoef(rx, ry)[0, 1])


def _binned(x: np.ndarray, y: np.ndarray, bins: int = 4) -> list[dict]:
    """RMS of y in quantile bins of x."""
    ok = np.isfinite(x) & np.isfinite(y)
    if ok.sum() < bins * 5:
        return []
    edges = np.quantile(x[ok], np.linspace(0, 1, bins + 1))
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = ok & (x >= lo) & (x <= hi)
        out.append({"from": float(lo), "to": float(hi), "error": _rms(y[sel]), "rows": int(sel.sum())})
    return out


def joint_errors(problem: Problem, residual: np.ndarray) -> np.ndarray:
    """(N, 12) RMS of each joint's compared channels (position, velocity) per row."""
    names = problem.channel_names
    out = np.full((len(residual), len(JOINT_NAMES)), np.nan)
    for j, joint in enumerate(JOINT_NAMES):
        cols = [names.index(c) for c in (f"{joint}_pos", f"{joint}_vel") if c in names]
        if cols:
            out[:, j] = np.sqrt(np.mean(residual[:, cols] ** 2, axis=1))
    return out


def breakdown(problem: Problem, comparison: Comparison) -> dict:
    """Every breakdown (module docstring) and a ``summary`` in plain words."""
    d, rows, r = problem.data, comparison.rows, comparison.residual
    je = joint_errors(problem, r)
    by_joint = {j: _rms(je[:, k]) for k, j in enumerate(JOINT_NAMES)}
    by_leg = {leg: _rms(je[:, 3 * k:3 * k + 3]) for k, leg in enumerate(FOOT_NAMES)}
    by_type = {t: _rms(je[:, k::3]) for k, t in enumerate(("hip", "thigh", "calf"))}

    contact = d.state[rows][:, SLICES["contact"]]
    phase: dict = {}
    if np.isfinite(contact).all():
        for k, leg in enumerate(FOOT_NAMES):
            stance = contact[:, k] > 0.5
            phase[leg] = {"stance": _rms(je[stance, 3 * k:3 * k + 3]), "swing": _rms(je[~stance, 3 * k:3 * k + 3]),
                          "stance_share": float(stance.mean())}
        st = np.concatenate([je[contact[:, k] > 0.5, 3 * k:3 * k + 3].ravel() for k in range(4)])
        sw = np.concatenate([je[contact[:, k] <= 0.5, 3 * k:3 * k + 3].ravel() for k in range(4)])
        phase["all"] = {"stance": _rms(st), "swing": _rms(sw)}

    seconds = d.frame[rows] * problem.control.control_dt
    row_error = np.sqrt(np.mean(r ** 2, axis=1))
    by_time = _binned(seconds, row_error, bins=5)

    q = d.state[rows][:, SLICES["joint_pos"]]
    qd = d.state[rows][:, SLICES["joint_vel"]]
    a = d.action[rows]
    prev = d.previous_actions(rows, 1, targets=True)[:, 0]
    effort = d.effort[rows]
    if not np.isfinite(effort).all():
        c = problem.control
        effort = a if c.action_mode == "torque" else pd_torque(a, q, qd, c)
    against = {"joint_speed": np.abs(qd), "torque": np.abs(effort), "action_change": np.abs(d.targets[rows] - prev)}
    trends = {k: {"rank_correlation": _spearman(v.ravel(), je.ravel()), "bins": _binned(v.ravel(), je.ravel())}
              for k, v in against.items()}

    out = {"by_group": {str(h): e for h, e in comparison.error.items()},
           "by_channel": dict(zip(problem.channel_names, map(float, comparison.channel_error[1]))),
           "by_joint": by_joint, "by_leg": by_leg, "by_joint_type": by_type, "by_phase": phase,
           "by_time": by_time, "trends": trends}
    out["summary"] = summarise(out, comparison)
    return out


def summarise(w: dict, comparison: Comparison) -> str:
    """The breakdown in a few plain sentences."""
    groups = w["by_group"]["1"]
    ranked = sorted(groups.items(), key=lambda kv: -kv[1])
    median = float(np.median(list(groups.values())))
    s = [f"At one step the model is worst in {ranked[0][0]} (normalised error {ranked[0][1]:.3g}"
         + (f", {ranked[0][1] / median:.1f}x the median group)" if median > 0 else ")")]
    joints = sorted(((v, j) for j, v in w["by_joint"].items() if np.isfinite(v)), reverse=True)
    if joints:
        types = sorted(w["by_joint_type"].items(), key=lambda kv: -kv[1])
        legs = sorted(w["by_leg"].items(), key=lambda kv: -kv[1])
        worst = ", ".join(j for _, j in joints[:3])
        s.append(f"worst joints {worst}; by type {types[0][0]} joints ({types[0][1]:.3g} vs "
                 f"{types[-1][0]} {types[-1][1]:.3g}), by leg {legs[0][0]} ({legs[0][1]:.3g} vs {legs[-1][0]} "
                 f"{legs[-1][1]:.3g})")
    if "all" in w["by_phase"]:
        st, sw = w["by_phase"]["all"]["stance"], w["by_phase"]["all"]["swing"]
        if np.isfinite(st) and np.isfinite(sw) and min(st, sw) > 0:
            where = "swing" if sw > st else "stance"
            s.append(f"legs are {max(st, sw) / min(st, sw):.1f}x worse in {where} than in "
                     f"{'stance' if where == 'swing' else 'swing'}")
    words = {"joint_speed": "joint speed", "torque": "applied torque", "action_change": "the change of the action "
             "since the last step"}
    grows = [f"{words[k]} ({v['rank_correlation']:.2f})" for k, v in w["trends"].items()
             if v["rank_correlation"] >= TREND]
    falls = [f"{words[k]} ({v['rank_correlation']:.2f})" for k, v in w["trends"].items()
             if v["rank_correlation"] <= -TREND]
    if grows:
        s.append("the error grows with " + " and with ".join(grows))
    if falls:
        s.append("the error shrinks with " + " and with ".join(falls))
    t = [b["error"] for b in w["by_time"]]
    if len(t) >= 2 and min(t) > 0:
        if t[-1] / t[0] > 1.5:
            s.append(f"it grows over the episode ({t[0]:.3g} early, {t[-1]:.3g} late)")
        elif t[0] / t[-1] > 1.5:
            s.append(f"it is largest early in the episode ({t[0]:.3g} early, {t[-1]:.3g} late)")
    if len(comparison.error) > 1:
        hs = sorted(comparison.error)
        head = {h: _rms(np.array(list(comparison.error[h].values()))) for h in hs}
        s.append("over horizons " + ", ".join(f"{h} step{'s' if h > 1 else ''}: {head[h]:.3g}" for h in hs))
    return "; ".join(s) + "."
