"""Closed-loop rounds (DAgger-style): label the states the CORRECTED robot visits.

A corrector trained on rows of the uncorrected target meets other states once it acts. Each
round (``visit`` then ``relabel``):

1. collect paired episodes (the dataset's policy on the source state, fresh initial states)
   with the current corrector applied in the target: a~ = a + F(s_target, a);
2. for every visited target state s with the policy's action a: re-simulate the SOURCE one
   control step from s with a (the goal), and solve delta_a* (``acn.corrector.labels.solve``) so
   the target from s reaches it: the same-state label at a state the corrected robot visits;
3. the caller adds these rows to the training set and trains further.

The collection of step 1 is itself a closed-loop run of the current corrector (on training
seeds), so each round reports how that corrector did there (``acn.corrector.evaluate.summarise``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from acn.corrector.labels import Solution, SolveConfig, solve
from acn.sim.collector import CollectConfig, Episode
from acn.sim.resim import Resimulator

ROUND_SEED_OFFSET = 7_000_001  # round r collects from seed + ROUND_SEED_OFFSET + r (never held-out seeds)


@dataclass
class VisitedRows:
    """Rows of one round: target states the corrected robot visited, labelled."""

    state: np.ndarray     # (N, 43) s_t of the corrected target
    action: np.ndarray    # (N, 12) the policy's a_t (before correction)
    goal: np.ndarray      # (N, 43) the source re-simulated one step from s_t with a_t
    solution: Solution    # delta_a* and errors (``labels.solve``)

    def __len__(self) -> int:
        return len(self.state)


def visit(cfg: CollectConfig, corrector, episodes: int, seconds: float, round_index: int) -> list[Episode]:
    """Step 1: ``episodes`` paired episodes with ``corrector`` in the target, from round seeds."""
    cfg = CollectConfig(**{**cfg.__dict__, "seed": cfg.seed + ROUND_SEED_OFFSET + round_index, "seconds": seconds,
                           "episodes": episodes, "corrector": None})
    from acn.corrector.evaluate import run_episodes

    return run_episodes(cfg, corrector, episodes)


def relabel(episodes: list[Episode], source: Resimulator, target: Resimulator, channels: np.ndarray,
            weights: np.ndarray, solver: SolveConfig | None = None) -> VisitedRows:
    """Step 2: same-state labels at the visited target states (rows whose goal diverged dropped)."""
    state = np.concatenate([e.target.state for e in episodes])
    action = np.concatenate([e.source.action for e in episodes])
    pred = source.run(state, action)
    keep = ~pred.diverged
    state, action, goal = state[keep], action[keep], pred.state[keep, 0]
    sol = solve(target, state, action, goal, channels, weights, solver)
    return VisitedRows(state, action, goal, sol)
