"""Sensitivity, Gauss-Newton labels and the two oracles, on real PyBullet and MuJoCo (small sizes)."""

from __future__ import annotations

import numpy as np
import pytest

from acn.corrector.acn import OUTPUT_CHANNELS
from acn.corrector.evaluate import closed_loop, same_state_oracle, typical_spread
from acn.corrector.labels import SolveConfig, solve
from acn.corrector.oracle import OUTPUT_INDEX, SameStateOracle
from acn.corrector.sensitivity import control_jacobian
from acn.sim.backends import make_backend
from acn.sim.collector import CollectConfig
from acn.sim.policies import make_policy
from acn.sim.resim import Resimulator


@pytest.fixture(scope="module")
def rows(small_episodes):
    """Source rows of the small paired episodes: s_t, a_t, recorded s'_src."""
    src = [e.source for e in small_episodes]
    return (np.concatenate([t.state for t in src]), np.concatenate([t.action for t in src]),
            np.concatenate([t.next_state for t in src]))


def test_control_jacobian_matches_backend_steps(small_config, rows):
    """One batched Resimulator call gives the same J as stepping MuJoCo's Backend by hand."""
    states, actions, _ = rows
    pick = [3, 40]
    with Resimulator("mujoco", small_config.sim) as resim:
        jac = control_jacobian(resim, states[pick], actions[pick], list(OUTPUT_CHANNELS), eps=0.01)
    backend = make_backend("mujoco", small_config.sim)
    for k, i in enumerate(pick):
        for j in (1, 7):
            nxt = []
            for sign in (1, -1):
                backend.reset(states[i])
                a = actions[i].copy()
                a[j] += sign * 0.01
                backend.step(a)
                nxt.append(backend.get_state()[OUTPUT_INDEX])
            np.testing.assert_allclose(jac[k, :, j], (nxt[0] - nxt[1]) / 0.02, rtol=1e-6, atol=1e-6)
    backend.close()


def test_labels_cut_the_same_state_error(small_config, rows):
    """Same-state labels: from the SOURCE state, a + delta_a* brings MuJoCo's next state to the
    recorded PyBullet one. Measured on these rows: about 70 % of the weighted error removed."""
    states, actions, goals = rows
    pick = np.arange(0, len(states), 2)
    with Resimulator("mujoco", small_config.sim) as resim:
        sol = solve(resim, states[pick], actions[pick], goals[pick], OUTPUT_INDEX, 1.0 / typical_spread(),
                    SolveConfig(iterations=2, broyden=1))
    assert not sol.diverged.any() and np.isfinite(sol.delta).all()
    assert np.all(sol.error_after <= sol.error_before)  # each row keeps its best iterate, d = 0 included
    assert sol.removed > 0.5, sol.removed
    assert sol.jacobian.shape == (len(pick), len(OUTPUT_CHANNELS), 12)
    assert 0 < np.abs(sol.delta).mean() < 0.2  # rad: corrections, not new gaits


def test_oracles_run_beside_the_uncorrected_target(small_config):
    cl = closed_loop(small_config, None, episodes=1, seconds=0.4, output_channels=list(OUTPUT_CHANNELS),
                     channel_scale=typical_spread())
    runs = cl["runs"]
    assert set(runs) == {"uncorrected", "same_state_oracle", "tracking_oracle"}
    for r in runs.values():
        assert np.isfinite(r["divergence"]) and np.isfinite(r["eps_transfer"]) and r["target_falls"] == 0
    # Knowing where the source is, the tracking oracle follows it closer than the uncorrected target.
    assert runs["tracking_oracle"]["divergence"] < 0.5 * runs["uncorrected"]["divergence"]
    assert "corrected" not in runs and "divergence_reduction" not in cl


def test_same_state_oracle_one_step_and_for_a_policy(small_config, rows):
    states, actions, _ = rows
    oracle = SameStateOracle("pybullet", small_config.sim, "mujoco", small_config.sim, 1.0 / typical_spread())
    out = oracle.correct(states[10], actions[10])
    assert out.shape == (12,) and not np.allclose(out, actions[10])
    assert oracle.error_after[0] < oracle.error_before[0]
    oracle.close()
    # Matching the source's applied torque as well changes the correction (benchmarks/reward_gap.py).
    torque = SameStateOracle("pybullet", small_config.sim, "mujoco", small_config.sim, 1.0 / typical_spread(),
                             effort_weights=np.ones(12))
    assert not np.allclose(torque.correct(states[10], actions[10]), out)
    torque.close()
    # For a policy acting on the target's own state (acn-ppo's evaluations).
    rewards = same_state_oracle(small_config.sim, make_policy("trot"), [states[0]], seconds=0.2)
    assert len(rewards) == 1 and rewards[0].shape == (10,) and np.isfinite(rewards[0]).all()


def test_tracking_oracle_needs_a_source(small_config):
    from acn.corrector.oracle import TrackingOracle

    oracle = TrackingOracle("mujoco", small_config.sim, 1.0 / typical_spread())
    with pytest.raises(RuntimeError, match="not bound"):
        oracle.correct(np.zeros(43), np.zeros(12))
    oracle.close()


def test_collect_config_is_not_mutated(small_config):
    before = CollectConfig(**small_config.__dict__)
    closed_loop(small_config, None, episodes=1, seconds=0.1, output_channels=list(OUTPUT_CHANNELS),
                channel_scale=typical_spread(), oracles=False)
    assert small_config.__dict__ == before.__dict__


def test_matching_the_applied_torque_too(small_config, rows):
    """With goal efforts, the solve also matches the mean applied torque of the step."""
    states, actions, goals = rows
    pick = np.arange(5, 45, 4)
    with Resimulator("pybullet", small_config.sim) as source, Resimulator("mujoco", small_config.sim) as target:
        goal = source.run(states[pick], actions[pick])
        tau_scale = np.full(12, 5.0)  # N m
        plain = solve(target, states[pick], actions[pick], goals[pick], OUTPUT_INDEX, 1.0 / typical_spread())
        both = solve(target, states[pick], actions[pick], goals[pick], OUTPUT_INDEX, 1.0 / typical_spread(),
                     goal_effort=goal.effort[:, 0], effort_weights=3.0 / tau_scale)
        gap = lambda sol: np.abs(target.run(states[pick], actions[pick] + sol.delta).effort[:, 0]  # noqa: E731
                                 - goal.effort[:, 0]).mean()
        assert gap(both) < gap(plain)
        assert np.all(both.error_after <= both.error_before)
