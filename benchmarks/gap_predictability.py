"""How much of the one-step same-state gap ANY corrector F(s, a) could learn from a paired dataset.

The same-state oracle knows each held-out row's gap; a corrector sees only (s, a). Here the gap
itself is regressed on (s, a): the weighted same-state residual W (s'_src - T_mujoco(s_src, a)) on
the 33 output channels (W = 1 / the training spread, as acn-fit's labels and one-step error),
labelled by the oracle's solve (``acn.corrector.fit.same_state_rows``), inputs the 33 dynamic state
channels and the action, episodes split as acn-fit splits them. Two regressions, trained on the
first quarter, half and all of the training episodes:

- ``linear``: ridge regression (lambda 1 on standardised inputs);
- ``mlp``: ``acn.corrector.acn.mlp`` (2 x 256, SiLU), Adam 1e-3, batch 128, 40 epochs; the BEST
  held-out R^2 over the epochs is printed (chosen on the held-out rows themselves: optimistic).

``--foot-kinematics`` adds what the contact sees, which an MLP would have to learn from the joint
angles and trunk pose: each foot's height above the ground and its world velocity (MuJoCo forward
kinematics of the state, ``mj_objectVelocity`` of the foot sphere), 16 more inputs.

R^2 on held-out episodes is the share of the gap's variance a function of (s, a) learned from
these rows reproduces: a ceiling for what a learned corrector can remove, where the oracle's
share is a ceiling only for a corrector that knows the row. If it stays low and grows slowly
with the data, the gap is not a function of (s, a) that these data pin down.

``--gap-only`` takes the gap from one re-simulation per row instead of the oracle's solve (the
solve's first step computes exactly that), so large datasets cost seconds; ``--save-rows F.npz``
keeps the rows, and an .npz given instead of a dataset trains on them where only torch is
installed (``--device cuda``, ``--hidden``, ``--epochs``, ``--fractions``).

Usage: python benchmarks/gap_predictability.py [--foot-kinematics] [--gap-only] DATASET|ROWS.npz ...
Prints name=value lines per dataset (its directory name as prefix).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from acn.corrector.acn import DYNAMIC_INPUT_CHANNELS, OUTPUT_CHANNELS, mlp
from acn.sim.state import GROUPS, STATE_NAMES


def r2(pred: np.ndarray, y: np.ndarray, mean: np.ndarray) -> float:
    """1 - SSE / SST over every channel, SST about the training mean."""
    return float(1.0 - ((pred - y) ** 2).sum() / ((y - mean) ** 2).sum())


def ridge(x_tr: np.ndarray, y_tr: np.ndarray, x: np.ndarray, lam: float = 1.0) -> np.ndarray:
    z_tr, z = (np.c_[a, np.ones(len(a))] for a in (x_tr, x))
    return z @ np.linalg.solve(z_tr.T @ z_tr + lam * np.eye(z.shape[1]), z_tr.T @ y_tr)


def foot_kinematics(states: np.ndarray) -> np.ndarray:
    """(T, 16): the 4 feet's heights above the ground (m), then their world velocities (m/s)."""
    import mujoco

    from acn.sim.backends.mujoco_backend import PhysicsLayout
    from acn.sim.kinematics import FOOT_RADIUS, RobotKinematics

    kin = RobotKinematics()
    m, d = kin.model, kin.data
    layout = PhysicsLayout(m)
    physics = layout.to_physics(states, np.zeros(12))  # [time, qpos, qvel] rows, as the backend writes them
    out, vel = np.empty((len(states), 16)), np.empty(6)
    for i, row in enumerate(physics):
        d.qpos[:], d.qvel[:] = row[1:1 + layout.nq], row[1 + layout.nq:]
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_comVel(m, d)
        for f, geom in enumerate(kin.foot_geoms):
            out[i, f] = d.geom_xpos[geom, 2] - FOOT_RADIUS
            mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_GEOM, geom, vel, 0)
            out[i, 4 + 3 * f:7 + 3 * f] = vel[3:]
    return out


def mlp_best(x_tr: np.ndarray, y_tr: np.ndarray, x_va: np.ndarray, y_va: np.ndarray, epochs: int = 40,
             seed: int = 0, hidden: int = 256, device: str = "cpu") -> tuple[float, int]:
    """(best held-out R^2, its epoch) of acn's MLP regressing y on x."""
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    net = mlp(x_tr.shape[1], hidden, y_tr.shape[1]).to(device)
    opt = torch.optim.Adam(net.parameters(), lr=1e-3)
    xt, yt, xv = (torch.tensor(a, dtype=torch.float32, device=device) for a in (x_tr, y_tr, x_va))
    best = (-np.inf, 0)
    for epoch in range(1, epochs + 1):
        for b in torch.randperm(len(xt), generator=gen).to(device).split(128):
            loss = (net(xt[b]) - yt[b]).pow(2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        with torch.no_grad():
            score = r2(net(xv).cpu().numpy(), y_va, y_tr.mean(0))
        best = max(best, (score, epoch))
    return best


def gap_rows(path: str, foot: bool, gap_only: bool) -> dict[str, np.ndarray]:
    """Inputs (33 dynamic state channels, action[, foot kinematics]) and weighted same-state gap of
    every row of a paired dataset, with its episode, held-out mask and usable mask.

    ``gap_only``: the gap from one re-simulation per row (what the solve computes first), not the
    oracle's solve: 40x fewer re-simulations, no ``oracle_removed``.
    """
    from acn.datasets.reader import load_paired
    from acn.datasets.metadata import config_from_metadata
    from acn.corrector.evaluate import output_spread
    from acn.corrector.config import FitConfig
    from acn.corrector.rows import same_state_rows, split_episodes
    from acn.corrector.oracle import OUTPUT_INDEX
    from acn.corrector.sensitivity import channel_difference
    from acn.sim.resim import Resimulator

    fit_cfg = FitConfig().resolved()
    data = load_paired([path])
    is_val = split_episodes(data.episode, fit_cfg.val_fraction, fit_cfg.seed)
    weights = 1.0 / output_spread(data.subset(~is_val).target_state)
    cfg = config_from_metadata(data.info)
    out = {}
    with Resimulator(cfg.target, cfg.sim) as resim:
        if gap_only:
            p = resim.run(data.state, data.action)
            residual = channel_difference(data.next_state[:, OUTPUT_INDEX], p.state[:, 0, OUTPUT_INDEX], OUTPUT_INDEX)
            diverged = p.diverged
        else:
            rows = same_state_rows(data, resim, weights, fit_cfg.oracle_solver())
            residual, diverged = rows.solution.residual, rows.solution.diverged
            va = is_val & ~diverged
            out["oracle_removed"] = np.array(1 - rows.solution.error_after[va].sum() / rows.solution.error_before[va].sum())
    gap = residual * weights
    x = np.c_[data.state[:, [STATE_NAMES.index(c) for c in DYNAMIC_INPUT_CHANNELS]], data.action]
    if foot:
        x = np.c_[x, foot_kinematics(data.state)]
    ok = np.isfinite(gap).all(1) & ~diverged
    return out | {"x": x.astype(np.float32), "gap": np.nan_to_num(gap).astype(np.float32), "episode": data.episode,
                  "is_val": is_val, "ok": ok}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sources", nargs="+", help="paired datasets, or .npz files of rows written by --save-rows")
    ap.add_argument("--foot-kinematics", action="store_true", help="add foot heights and velocities as inputs")
    ap.add_argument("--gap-only", action="store_true", help="gap from one re-simulation per row, no oracle solve")
    ap.add_argument("--save-rows", help="write each dataset's rows to this .npz (one dataset) and go on")
    ap.add_argument("--fractions", default="0.25,0.5,1", help="shares of the training episodes to train on")
    ap.add_argument("--hidden", type=int, default=256, help="MLP width")
    ap.add_argument("--epochs", type=int, default=40)
    ap.add_argument("--device", default="cpu", help="where the MLP trains")
    args = ap.parse_args()
    for path in args.sources:
        if path.endswith(".npz"):
            with np.load(path) as f:
                rows = dict(f)
        else:
            rows = gap_rows(path, args.foot_kinematics, args.gap_only)
            if args.save_rows:
                np.savez_compressed(args.save_rows, **rows)
        name = Path(path).name.removesuffix(".npz")
        x, gap, episode, ok = rows["x"].astype(np.float64), rows["gap"].astype(np.float64), rows["episode"], rows["ok"]
        va = ok & rows["is_val"]
        train_episodes = np.unique(episode[ok & ~rows["is_val"]])
        mean, std = x[ok & ~rows["is_val"]].mean(0), x[ok & ~rows["is_val"]].std(0) + 1e-9
        x = (x - mean) / std
        if "oracle_removed" in rows:
            print(f"{name}_oracle_removed={float(rows['oracle_removed']):.3f}")
        print(f"{name}_heldout_rows={int(va.sum())}")
        for frac in (float(f) for f in args.fractions.split(",")):
            tr = ok & np.isin(episode, train_episodes[: max(1, round(frac * len(train_episodes)))])
            k = f"{name}_{frac * 100:g}pct"
            score, epoch = mlp_best(x[tr], gap[tr], x[va], gap[va], args.epochs, hidden=args.hidden, device=args.device)
            print(f"{k}_train_rows={int(tr.sum())}")
            print(f"{k}_gap_r2_linear={r2(ridge(x[tr], gap[tr], x[va]), gap[va], gap[tr].mean(0)):.3f}")
            print(f"{k}_gap_r2_mlp={score:.3f}")
            print(f"{k}_gap_r2_mlp_epoch={epoch}", flush=True)
        total = (gap[va] ** 2).sum()
        for g in ("base_linvel", "base_angvel", "joint_pos", "joint_vel"):
            cols = [i for i, c in enumerate(OUTPUT_CHANNELS) if c in GROUPS[g]]
            print(f"{name}_{g}_share_of_gap={(gap[va][:, cols] ** 2).sum() / total:.3f}")


if __name__ == "__main__":
    main()
