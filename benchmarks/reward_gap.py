"""Where the PyBullet -> MuJoCo reward gap comes from, and what the same-state oracle closes of it.

On held-out starts of a paired dataset (``make demo``'s ``out/trot_pb_mj`` by default), in
closed loop as ``acn-fit`` evaluates (``acn.corrector.evaluate``): MuJoCo uncorrected, the
same-state oracle under two channel weightings (1 / the dataset's MuJoCo state spread, as
``acn-fit``; 1 / ``evaluate.TYPICAL_SPREAD``), and the oracle that also matches the source's
applied torque from the same state (``SameStateOracle(effort_weights=1 / N m)``). Per run,
eps_transfer = mean over episodes of (R_MuJoCo - R_PyBullet) and its four reward terms
(forward speed, torque, tilt, joint speed; each already weighted, so they sum to it).

Usage: python benchmarks/reward_gap.py [DATASET] [--episodes 4] [--seconds 5]
Prints name=value lines: ``<run>_eps_transfer``, ``<run>_eps_<term>``, ``<run>_divergence``.
"""

from __future__ import annotations

import argparse

import numpy as np

from acn.measurements.data import load_measurements
from acn.datasets.reader import read_card
from acn.datasets.metadata import config_from_metadata
from acn.corrector.acn import OUTPUT_CHANNELS
from acn.corrector.evaluate import held_out, output_spread, run_episodes, summarise, typical_spread
from acn.corrector.oracle import SameStateOracle
from acn.sim.reward import REWARD_WEIGHTS, reward_terms

TERMS = ("forward_speed", "torque", "tilt", "joint_speed")


def term_gap(episodes) -> np.ndarray:
    """Mean over episodes of the weighted reward terms' sums, target minus source."""
    sign = np.array([1.0, -1.0, -1.0, -1.0]) * np.array(REWARD_WEIGHTS)
    return np.mean([(reward_terms(e.target.next_state, e.target.effort) * sign).sum(0)
                    - (reward_terms(e.source.next_state, e.source.effort) * sign).sum(0) for e in episodes], axis=0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", nargs="?", default="out/trot_pb_mj")
    ap.add_argument("--episodes", type=int, default=4)
    ap.add_argument("--seconds", type=float, default=5.0)
    args = ap.parse_args()
    cfg = held_out(config_from_metadata(read_card(args.dataset).acn), args.episodes, args.seconds)
    target = load_measurements(args.dataset, side="target")
    spread = output_spread(target.state)
    oracles = {"oracle_dataset_weights": dict(weights=1 / spread),
               "oracle_typical_weights": dict(weights=1 / typical_spread()),
               "oracle_matching_torque": dict(weights=1 / spread, effort_weights=np.ones(12))}
    runs = {"uncorrected": run_episodes(cfg, None, args.episodes)}
    for name, kw in oracles.items():
        oracle = SameStateOracle(cfg.source, cfg.source_sim, cfg.target, cfg.target_sim, **kw)
        try:
            runs[name] = run_episodes(cfg, oracle, args.episodes)
        finally:
            oracle.close()
    out = summarise(runs, list(OUTPUT_CHANNELS), spread)
    for name, eps in runs.items():
        r = out["runs"][name]
        print(f"{name}_eps_transfer={r['eps_transfer']:.1f}")
        for term, v in zip(TERMS, term_gap(eps)):
            print(f"{name}_eps_{term}={v:.1f}")
        print(f"{name}_divergence={r['divergence']:.3f}")
        print(f"{name}_falls={r['target_falls']}")


if __name__ == "__main__":
    main()
