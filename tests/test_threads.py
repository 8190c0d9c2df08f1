"""Training's torch thread count: chosen by timing the loop, without changing what it learns."""

from __future__ import annotations

import time

import pytest
import torch

from acn.models.corrector import Corrector, default_config
from acn.models.fit import FitConfig, Split, train
from acn.models.threads import AdaptiveThreads, thread_candidates


def test_candidates_are_one_then_powers_of_two_up_to_all():
    assert thread_candidates(1) == (1,)
    assert thread_candidates(2) == (1, 2)
    assert thread_candidates(6) == (1, 2, 4, 6)
    assert thread_candidates(8) == (1, 2, 4, 8)


def test_the_faster_count_is_chosen_and_followed_when_the_load_changes():
    """A step that is slow on one count and fast on the other, then the other way round: the
    chooser runs on the fast one, and after the next probe on the new fast one."""
    slow_on = {"count": 2}

    def step():
        time.sleep(0.004 if torch.get_num_threads() == slow_on["count"] else 0.0005)

    before = torch.get_num_threads()
    with AdaptiveThreads(candidates=(1, 2), window=3, settle=1, every_s=0.15) as threads:
        for _ in range(12):  # the first probe (8 steps), then on the chosen count
            threads(step)
        assert threads.chosen == 1 and torch.get_num_threads() == 1
        assert threads.steps[2] == 4  # only the probe's steps ran on the slow count
        slow_on["count"] = 1
        deadline = time.perf_counter() + 5.0
        while threads.chosen != 2 and time.perf_counter() < deadline:
            threads(step)
        assert threads.chosen == 2
    assert torch.get_num_threads() == before  # torch's setting is restored


@pytest.mark.parametrize("variant, hidden", [("paper", 64), ("inverse", 128)])
def test_one_or_two_threads_train_the_same_weights(variant, hidden):
    """What AdaptiveThreads relies on: the count changes the speed, not the result (oneDNN and
    torch split rows and columns among threads, not sums)."""
    torch.manual_seed(0)
    x, r = torch.randn(600, 52 if variant == "paper" else 45), torch.randn(600, 33)
    split = Split(x, r, torch.randn(600, 33, 12), torch.randn(600, 12), torch.ones(12)) if variant == "inverse" \
        else Split(x, r, None)
    weights = []
    for threads in (1, 2, 0):
        torch.manual_seed(1)
        model = Corrector(default_config(variant, hidden, 2))
        history = train(model, split, FitConfig(variant=variant, epochs=2, train_threads=threads))
        assert all(h["threads"] in (1, 2, torch.get_num_threads()) for h in history)
        weights.append(torch.cat([p.detach().flatten() for p in model.parameters()]))
    assert torch.equal(weights[0], weights[1]) and torch.equal(weights[0], weights[2])
