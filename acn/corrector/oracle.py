"""Two oracle correctors: what the best per-step correction could do, for comparison.

Both are correctors (``correct(state, action)``, batched) that solve for delta_a at every
control step with the Gauss-Newton solve of ``acn.corrector.labels.solve`` on target
re-simulations (channel weights 1 / training spread, the 33 output channels):

- ``SameStateOracle``: from the TARGET's own state s, the SOURCE simulator is re-simulated one
  control step with a (``set_state`` + ``step``; ``Resimulator`` on the source's model) and
  delta_a makes the target's next state match that prediction. This is the best any
  corrector F(s, a) can do for the paper's objective (it needs both simulators at every step).
  With ``effort_weights`` (1 / N m per joint) it matches the source's applied torque too.
- ``TrackingOracle``: delta_a makes the target's next state match the source TRAJECTORY's
  actual next state (it knows where the source is, which no F(s, a) does); ``goal`` is a
  callable returning it, e.g. ``rollout.source.get_state`` of a ``PairedRollout``, whose
  source has already stepped when the target's action is corrected.

Neither keeps an action history, so with actuator latency in a model the re-simulations take
the earlier actions equal to the current one.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from acn.corrector.acn import OUTPUT_CHANNELS
from acn.corrector.labels import SolveConfig, solve
from acn.corrector.sensitivity import channel_index
from acn.sim.backends import SimConfig
from acn.sim.resim import Resimulator
from acn.sim.state import ACTION_DIM, STATE_DIM

OUTPUT_INDEX = channel_index(OUTPUT_CHANNELS)


class _Oracle:
    def __init__(self, target: str, target_sim: SimConfig, weights: np.ndarray, solver: SolveConfig | None,
                 threads: int | None) -> None:
        self.target = Resimulator(target, target_sim, threads=threads)
        self.weights = np.asarray(weights, float)
        self.effort_weights: np.ndarray | None = None  # 1 / N m per joint: match the goal's torque too
        self.solver = solver or SolveConfig()
        self.error_before: list[float] = []  # per corrected step, || W (goal - T(s, a)) ||^2
        self.error_after: list[float] = []   # ... with the oracle's action

    def _goals(self, states: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """(goal next states, the torque applied reaching them or None if unknown)."""
        raise NotImplementedError

    def correct(self, state, action):
        """a~ = a + delta_a for one (43,) / (12,) row or a batch (N, 43) / (N, 12); numpy out."""
        s = np.asarray(state, float).reshape(-1, STATE_DIM)
        a = np.asarray(action, float).reshape(-1, ACTION_DIM)
        goals, effort = self._goals(s, a)
        sol = solve(self.target, s, a, goals, OUTPUT_INDEX, self.weights, self.solver, goal_effort=effort,
                    effort_weights=self.effort_weights)
        self.error_before.extend(sol.error_before.tolist())
        self.error_after.extend(sol.error_after.tolist())
        return (a + sol.delta).reshape(np.shape(action))

    def close(self) -> None:
        self.target.close()


class SameStateOracle(_Oracle):
    """delta_a so that the target from s matches the SOURCE re-simulated from the same s."""

    def __init__(self, source: str, source_sim: SimConfig, target: str, target_sim: SimConfig, weights: np.ndarray,
                 solver: SolveConfig | None = None, threads: int | None = None,
                 effort_weights: np.ndarray | None = None) -> None:
        super().__init__(target, target_sim, weights, solver, threads)
        self.source = Resimulator(source, source_sim, threads=threads)
        self.effort_weights = None if effort_weights is None else np.broadcast_to(effort_weights, (ACTION_DIM,))

    def _goals(self, states: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        p = self.source.run(states, actions)
        return p.state[:, 0], p.effort[:, 0]

    def close(self) -> None:
        super().close()
        self.source.close()


class TrackingOracle(_Oracle):
    """delta_a so that the target matches the source trajectory's next state (``goal()``)."""

    def __init__(self, target: str, target_sim: SimConfig, weights: np.ndarray,
                 goal: Callable[[], np.ndarray] | None = None, solver: SolveConfig | None = None,
                 threads: int | None = None) -> None:
        super().__init__(target, target_sim, weights, solver, threads)
        self.goal = goal

    def _goals(self, states: np.ndarray, actions: np.ndarray) -> tuple[np.ndarray, None]:
        if self.goal is None:
            raise RuntimeError("TrackingOracle.goal is not bound to a source trajectory")
        return np.asarray(self.goal(), float).reshape(len(states), STATE_DIM), None
