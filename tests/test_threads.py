"""Training's torch thread count: chosen by timing the loop, without changing what it learns."""

from __future__ import annotations

import time

import pytest
import torch

from acn.corrector.corrector import Corrector, default_config
from acn.corrector.fit import FitConfig, Split, train
from acn.corrector.threads import AdaptiveThreads, thread_candidates


def test_candidates_are_one_then_powers_of_two_up_to_all():
    assert thread_candidates(1) == (1,)
    assert thread_candidates(2) == (1, 2)
    assert thread_candidates(6) == (1, 2, 4, 6)
    assert thread_candidates(8) == (1, 2, 4, 8)


def sleeper(seconds: dict[int, float]):
    """A step that takes ``seconds[count]`` on each torch thread count: a loop whose speed
    depends on the count, as training's does."""
    return lambda: time.sleep(seconds[torch.get_num_threads()])


def test_the_faster_count_is_chosen_and_followed_when_the_load_changes():
    seconds = {1: 0.0005, 2: 0.01}  # far apart: on a loaded machine a 0.5 ms sleep takes a few ms
    before = torch.get_num_threads()
    with AdaptiveThreads(candidates=(1, 2), settle=1, window_s=0.01, every_s=0.1) as threads:
        threads(sleeper(seconds))
        while threads.chosen == 0:  # the first probe: every step belongs to it
            threads(sleeper(seconds))
        assert threads.chosen == 1 and threads.steps[2] == 4  # one settling, three timed steps on the slow count
        threads(sleeper(seconds))
        assert torch.get_num_threads() == 1
        seconds.update({1: 0.01, 2: 0.0005})  # the load changes: now two threads are faster
        deadline = time.perf_counter() + 5.0
        while threads.chosen != 2 and time.perf_counter() < deadline:
            threads(sleeper(seconds))
        assert threads.chosen == 2
    assert torch.get_num_threads() == before  # torch's setting is restored


def test_a_slow_candidate_is_left_at_once_and_a_kept_choice_is_probed_less_often():
    seconds = {1: 0.0005, 2: 0.03}  # far apart: on a loaded machine a 0.5 ms sleep takes a few ms
    # slow_down off: on a loaded test machine the chosen count's own steps vary; that rule has its own test
    with AdaptiveThreads(candidates=(1, 2), settle=1, window_s=0.005, every_s=0.05, most_every_s=0.2,
                         slow_down=1e9) as threads:
        while threads.chosen == 0:
            threads(sleeper(seconds))
        first, probes, intervals = threads.steps[2], 0, []
        deadline = time.perf_counter() + 1.5
        while time.perf_counter() < deadline:
            idle = not threads._pending
            threads(sleeper(seconds))
            probes += idle and bool(threads._pending)  # a probe started with this step
            if not threads._pending and (not intervals or intervals[-1] != threads._interval):
                intervals.append(threads._interval)
        # every later probe left two threads after one step (far slower than the chosen count)
        assert threads.chosen == 1 and probes >= 3 and threads.steps[2] == first + probes
        assert intervals[0] == 0.05 and intervals[-1] == 0.2  # doubled while the choice stayed, up to most_every_s


def test_a_chosen_count_that_slows_down_is_probed_again_at_once():
    seconds = {1: 0.0005, 2: 0.005}
    with AdaptiveThreads(candidates=(1, 2), settle=1, window_s=0.005, every_s=60.0) as threads:
        while threads.chosen == 0:
            threads(sleeper(seconds))
        assert threads.chosen == 1
        seconds[1] = 0.02  # another process takes the core: the next probe is not 60 s away
        deadline = time.perf_counter() + 2.0
        while threads.chosen != 2 and time.perf_counter() < deadline:
            threads(sleeper(seconds))
        assert threads.chosen == 2


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
