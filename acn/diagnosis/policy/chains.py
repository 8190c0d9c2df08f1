"""``--auto``: the greedy chain, each added effect judged again beside the others
(``revisit``), and the chains started from other candidates (``other_starts``), compared by how
they predict the held-out rows (``improvement``, ``predicts_better``, ``predicts_as_well``).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from acn.diagnosis import heldout
from acn.diagnosis.clock import StageClock
from acn.diagnosis.compare import Comparison
from acn.diagnosis.decisions import record, share, within
from acn.diagnosis.policy.adding import add_effect, greedy, nothing_left, out_of_time, refine_chain
from acn.diagnosis.policy.judging import doubt
from acn.diagnosis.policy.ranking import rank, ties_of
from acn.diagnosis.policy.thresholds import THRESHOLDS, Thresholds
from acn.diagnosis.problem import DiagnoseConfig, Problem
from acn.diagnosis.results import Added, Candidate, Chain, names
from acn.diagnosis.traits import traits
from acn.sim.effects import Model, get_effect


def auto(problem: Problem, first: Comparison, cfg: DiagnoseConfig, judge_rows: np.ndarray, base_residual: np.ndarray,
         floor_mse: float, ranking: list[Candidate], progress=None, t: Thresholds = THRESHOLDS,
         clock: StageClock | None = None) -> tuple[list[Added], list[Chain], dict[str, str]]:
    """``greedy`` then ``revisit``, from the best candidate and (``other_starts``) from the next
    ``cfg.auto_alternatives`` ones; the added effects of the chain kept, every chain tried, and the
    candidates the first chain set aside on their final fit (name -> why).

    The other starts are tried whatever the chain leaves: once one effect has stood in for two,
    the one-step error can sit at the noise floor (nothing left to rank) while the open-loop
    error is still three times what the right pair leaves (payload + damping below)."""
    clock = clock or StageClock()
    steps, set_aside = greedy(problem, first, cfg, judge_rows, base_residual, floor_mse, ranking, progress, t=t,
                              clock=clock)
    deadline = StageClock(started=clock.started)  # the search's bound, without nesting the stages it times
    with clock.stage("revisit"):
        chain = revisit(problem, first, cfg, judge_rows, base_residual, steps, progress, t=t, clock=deadline)
    with clock.stage("other starts"):
        return (*other_starts(problem, first, cfg, judge_rows, base_residual, floor_mse, ranking, chain, progress, t=t,
                              clock=deadline),
                set_aside)


def improvement(new: list[Added], old: list[Added]) -> dict:
    """How much better the final model of chain ``new`` predicts than that of ``old``
    (``heldout.improvement_between``, on the same judge rows): the share of ``old``'s held-out
    one-step error it removes, its paired z (blocks of rows), the share of ``old``'s open-loop
    error at the longest horizon it removes, and at each open-loop horizon compared
    (``horizons_removed``: steps -> share)."""
    return heldout.improvement_between(new[-1].judgement.row_errors, old[-1].judgement.row_errors,
                                       old[-1].after, new[-1].after)


def horizon_votes(v: dict, t: Thresholds = THRESHOLDS) -> tuple[int, int]:
    """Of the horizons an ``improvement`` ``v`` compares, at how many the new chain predicts
    better and at how many worse: by ``auto_min_removed`` of the one-step error with paired
    |z| >= ``parsimony_z``, by ``auto_min_longer`` at each open-loop horizon."""
    one, z = v["one_step_removed"], v["z"]
    better = int(one >= t.auto_min_removed and z >= t.parsimony_z)
    worse = int(one <= -t.auto_min_removed and z <= -t.parsimony_z)
    for share in v["horizons_removed"].values():
        better, worse = better + (share >= t.auto_min_longer), worse + (share <= -t.auto_min_longer)
    return better, worse


def predicts_better(v: dict, t: Thresholds = THRESHOLDS) -> bool:
    """Whether a chain whose ``improvement`` over the kept one is ``v`` replaces it.

    Either it predicts the held-out one step significantly better (z >= ``parsimony_z``) and
    lowers the longest-horizon error too, by ``auto_min_removed`` at one step or
    ``auto_min_longer`` at the longest horizon: an extra effect that fits the noise in the start
    states does neither. Or, where the horizons disagree, it predicts better at two of them or
    more (so at an open-loop one), at more than worse (``horizon_votes``), and by more than it
    loses: the product of its error ratios over the horizons is below 1 (each horizon's relative
    change weighs alike; a chain 30 % worse at 25 steps is not kept for 8 % and 10 % better at 1
    and 5). One horizon alone is not enough: a fresh draw (a payload beside an 11 ms delay) had
    a chain with an extra actuator lag 10 % better at 25 steps and even elsewhere.

    Under a closed-loop controller the actions carry the sensor noise of the states they follow,
    and neither horizon alone decides. Fresh draws under attitude feedback: kp x0.63 with a
    19.6 N m limit, the true pair (torque limit + PD gains) predicted one step 6.3 % better
    (z 7.7) and 5 steps 9 % better than motor strength + joint damping, 25 steps 6 % worse; kp
    x0.67 with an 11 ms lag, the true lag (the gains as strength + damping beside it) predicted 5
    and 25 steps 14 % and 38 % better than PD gains + armature, one step 8 % worse (z -5.9). An
    effect that only fits the noise wins the one step alone.
    """
    longer = v["longest_horizon_removed"]
    if (v["z"] >= t.parsimony_z and (longer is None or longer > 0)
            and (v["one_step_removed"] >= t.auto_min_removed or (longer or 0.0) >= t.auto_min_longer)):
        return True
    better, worse = horizon_votes(v, t=t)
    return better >= 2 and better > worse and _error_ratio(v) < 1.0


def predicts_as_well(v: dict, t: Thresholds = THRESHOLDS) -> bool:
    """Whether a chain whose ``improvement`` over the kept one is ``v`` predicts at least as well:
    at no horizon worse by the margins of ``horizon_votes``, and the product of its error ratios
    over the horizons at most 1. With fewer or simpler effects it replaces the kept chain (one
    rule for ``other_starts`` and ``revisit``): the kept one's extra effect does not improve the
    held-out prediction (a fresh draw of kp x0.85 with an 11 ms delay: with an actuator lag added
    beside them the chain predicted 1, 5 and 25 steps 0.4 %, 3.5 % and 3.9 % worse than without
    it, and the delay was fitted 14 % short)."""
    return horizon_votes(v, t=t)[1] == 0 and _error_ratio(v) <= 1.0


def _error_ratio(v: dict) -> float:
    """The product over the horizons of the new chain's error over the kept one's."""
    return float(np.prod([1.0 - v["one_step_removed"], *(1.0 - s for s in v["horizons_removed"].values())]))


def other_starts(problem: Problem, first: Comparison, cfg: DiagnoseConfig, judge_rows: np.ndarray,
                 base_residual: np.ndarray, floor_mse: float, ranking: list[Candidate], chain: list[Added],
                 progress=None, t: Thresholds = THRESHOLDS,
                 clock: StageClock | None = None) -> tuple[list[Added], list[Chain]]:
    """The greedy chain started from each of the next ``cfg.auto_alternatives`` plausible,
    significant candidates of the first ranking, re-ranking only the ``shortlist`` best of them.
    Another chain adds at most one effect more than the kept one holds: it stands for two effects that one of the kept
    chain stood in for, or for the same effects in another order (below); longer, it is a chain
    of flexible effects (on a log with calves 10 % long, up to four effects, the other chain took
    four fifths of the diagnosis's time). None is started where the kept chain leaves nothing
    another could explain (``nothing_left``).

    Adding greedily, one effect can stand in for two: payload 2 kg + joint damping 0.4 came out as
    both PD gains scaled (0.89 / 1.17: a higher derivative gain is damping, a lower proportional
    gain sags like a heavier trunk), after which neither true effect removed 5 % of what was
    left, although the pair predicts the held-out rows better (one-step error 4.7 % lower) and
    the 25-step open-loop error 61 % lower. Another chain replaces the one kept when its final
    model predicts better (``predicts_better``): at one step significantly and at the longest
    horizon too, by the margins ``greedy`` asks of an added effect, or, where the horizons
    disagree, at more of them than worse; or, with fewer effects, as well (``predicts_as_well``).
    A chain of the same effects in another order is judged
    alike: fitted from other starting points, its values can be better (a fresh draw under
    feedback: armature 0.0327 added first, 0.0254 added after the torque limit, for 0.0253; one
    step 2.4 % better, z 7.0, 5 and 25 steps 12 % and 11 %).

    Where another chain may replace the kept one (it predicts some horizon better, or none
    worse), the two are compared refined (``refine_chain``; a no-op on a chain without an effect
    that moves the start state), as the diagnosis would report them: twelve encoder offsets
    chosen by forward differences are 20-40 % off, and another effect can make up for that. On
    the benchmark's offsets log behind a 10 ms velocity filter, the chain ground_softness +
    encoder_offset predicted one step 5.7 % better (z 7.8), 5 and 25 steps 2 % and 4 % better
    than the offsets alone, both unrefined, and was kept (softness 0.025 s once refined, offsets
    11.4 % off). Both refined, it predicts one step 6.7 % better (z 7.7) but 5 and 25 steps 4 %
    and 25 % worse, and the offsets alone are kept, 8.3 % off.
    """
    if not chain:
        return chain, []
    kept = Chain(chain, chain[0].name, kept=True, why="the best candidate first")
    tried = [kept]
    if nothing_left(chain[-1].after, chain[-1].judgement.mse_after, first, float(np.mean(base_residual ** 2)),
                    floor_mse, t=t, then="no other start tried"):
        return kept.steps, tried  # no other chain can explain a share of the error this one leaves
    pool = [c for c in ranking if c.judgement.significant and not doubt(c, t=t)]
    shortlist = replace(cfg, candidates=tuple(c.name for c in pool[:t.shortlist]),
                        auto_max=min(cfg.auto_max, len(names(chain)) + 1))
    clock = clock or StageClock()
    starts = [c for c in pool if c.name != chain[0].name][:cfg.auto_alternatives]
    for i, c in enumerate(starts):
        if out_of_time(cfg, clock, f"the chains started with {', '.join(s.name for s in starts[i:])}"):
            break
        if progress:
            progress(f"trying {c.name} first", None)
        with within(f"chain started with {c.name}"):
            steps, _ = greedy(problem, first, shortlist, judge_rows, base_residual, floor_mse, [c], progress, t=t,
                              clock=clock)
            if steps and steps[0].name == c.name:  # its ties in the first ranking, which this chain started past
                steps[0].ties = ties_of(c, ranking, t=t)
            steps = revisit(problem, first, cfg, judge_rows, base_residual, steps, progress, t=t, clock=clock)
        other = Chain(steps, c.name)
        tried.append(other)
        if not steps:
            other.why = f"{c.name} is not added on its own final fit"
            record("other_starts", "nothing added", f"the chain started with {other.why}", start=c.name)
            continue
        better, worse = horizon_votes(improvement(steps, kept.steps), t=t)
        if better or not worse:  # it may replace the kept chain: compare the two as they would be reported
            if any(traits(s.name).moves_start for s in kept.steps + steps) and out_of_time(
                    cfg, clock, f"comparing the chain started with {c.name}, {other.label}, refined with the kept one"):
                other.why = "not compared: the search's time bound"
                break
            kept.steps = refine_chain(problem, first, kept.steps, cfg, judge_rows, base_residual, t=t)
            other.steps = steps = refine_chain(problem, first, steps, cfg, judge_rows, base_residual, t=t)
        # The same effects added in another order are fitted from other starting points: the
        # chain that predicts better by the same rule keeps its values.
        same = " (the same effects, fitted otherwise)" if sorted(other.names) == sorted(kept.names) else ""
        other.versus = v = improvement(steps, kept.steps)
        gains = f"{_versus_text(v)} against {kept.label}{same}"
        better = predicts_better(v, t=t)
        figures = dict(start=c.name, chain=other.label, against=kept.label, one_step_removed=v["one_step_removed"],
                       z=v["z"], longest_horizon_removed=v["longest_horizon_removed"], parsimony_z=t.parsimony_z,
                       auto_min_removed=t.auto_min_removed, auto_min_longer=t.auto_min_longer)
        if better or (len(other.names) < len(kept.names) and predicts_as_well(v, t=t)):
            kept.kept, kept.why = False, f"replaced by the chain started with {c.name}"
            said = "predicts better" if better else "predicts as well with fewer effects"
            kept, other.kept, other.why = other, True, f"{said}: {gains}"
            record("predicts_better" if better else "predicts_as_well", f"{other.label} kept",
                   f"the chain started with {c.name}, {other.label}, is kept: it {said}: {gains}", **figures)
        else:
            other.why = f"not clearly better: {gains}"
            record("predicts_better", f"{kept.label} kept",
                   f"the chain started with {c.name}, {other.label}, is not clearly better: {gains}", **figures)
    return kept.steps, tried


def _size(name: str) -> int:
    """Free parameters of an effect fitted at its default granularity."""
    effect = get_effect(name)
    return len(effect.parameters) * (12 if traits(effect.name).granularity == "joint" else 1)


def revisit(problem: Problem, first: Comparison, cfg: DiagnoseConfig, judge_rows: np.ndarray,
            base_residual: np.ndarray, added: list[Added], progress=None, t: Thresholds = THRESHOLDS,
            clock: StageClock | None = None) -> list[Added]:
    """Each of two or more added effects judged again beside the others.

    Adding greedily, a richer effect can absorb part of one added after it (both PD gains scaled
    soaking up joint friction where the motors are weak: strength 0.85 and friction 0.2 came out
    as gains 0.87 / 0.97 and friction 0.31). Beside the others, the effect is ranked against the
    simpler candidates not in the model (fewer parameters at their default granularity), with
    ``rank``'s simpler-explanation rule; where one takes its place, the chain is refitted in the
    same order from ``first`` (each effect once: ``choose_fit`` chooses its granularity again).

    The refitted chain, simpler or shorter, is kept only where it predicts as well
    (``predicts_as_well``): judged beside the others, a richer effect is fitted again from its nominal
    values and can land elsewhere. A fresh draw under attitude feedback (floor friction 0.67 and
    a 1.55 kg payload 7.8 cm ahead of the trunk): the payload, added second at 1.47 kg and
    com_x 9 cm, was fitted again at 1.07 kg and com_x 13.6 cm (implausible), and motor strength
    took its place; that chain predicted 1, 5 and 25 steps 3.6 % (z -7.3), 26 % and 93 % worse
    (mean squares) than the payload's.

    An effect is left out where neither it nor a simpler one is significant beside the others:
    added first, an effect can stand in for one added after it and end, once that one
    is refitted beside it, near its nominal values. A fresh draw of floor friction 0.27 with
    motor strength 0.89: the ground's softness, added first at 34.4 ms, ended at 18.8 ms (nominal
    20 ms) beside both; judged again it removed 1.8 % of the one-step error (not significant),
    and left out it changed the 1-, 5- and 25-step errors by +1.2 %, +0.1 % and -9 %. A chain
    with an effect left out is kept where it predicts as well (``predicts_as_well``); where every
    effect would be left out (each standing in for another), the chain stays as it is.
    """
    effects = names(added)
    if len(effects) < 2 or out_of_time(cfg, clock, f"judging {' + '.join(effects)} again beside each other (revisit)"):
        return added
    chosen: list[str | None] = list(effects)
    final = added[-1].after.model
    for i, a in enumerate(next(s for s in added if s.name == n) for n in effects):
        simpler = tuple(n for n in cfg.candidates if n not in chosen and n not in effects and _size(n) < _size(a.name))
        others = Model(final.backend, [t for t in final.effects if t.name != a.name], final.corrector)
        residual = problem.residual_of(others.sim_config(problem.control), judge_rows)
        if progress:
            progress(f"judging {a.name} again beside the other added effects", None)
        with within(f"revisit {a.name}"):
            again = rank(problem, others, replace(cfg, candidates=(a.name, *simpler)), judge_rows, residual, t=t)
        top = next((c for c in again if c.judgement.significant and not doubt(c, t=t)), None)
        chosen[i] = top.name if top is not None else None
        if top is None:
            record("revisit", f"{a.name} left out", (
                f"{a.name} judged again beside the other added effects: neither it nor a simpler candidate is "
                "significant and plausible there"), effect=a.name, simpler=", ".join(simpler))
        elif top.name != a.name:
            record("revisit", f"{top.name} in {a.name}'s place", (
                f"{a.name} judged again beside the other added effects: the simpler {top.name} goes first there"),
                effect=a.name, simpler=", ".join(simpler), instead=top.name)
    kept = [n for n in chosen if n is not None]
    if kept == effects or not kept:
        if not kept:
            record("revisit", "kept as added", "every added effect would be left out (each stands in for another): "
                   "the chain stays as added", effects=" + ".join(effects))
        return added
    chain, current, residual = [], first, base_residual
    for name in kept:
        if progress:
            progress(f"adding {name}", None)
        step = add_effect(problem, current.model, name, cfg, judge_rows, residual, current, t=t)
        step.ties = next((s.ties for s in added if s.name == name), [])  # an effect kept: as it was added
        chain.append(step)
        current, residual = step.after, step.judgement.residual_after
    v = improvement(chain, added)
    figures = dict(one_step_removed=v["one_step_removed"], z=v["z"], longest_horizon_removed=v["longest_horizon_removed"],
                   auto_min_removed=t.auto_min_removed, auto_min_longer=t.auto_min_longer, parsimony_z=t.parsimony_z)
    if not predicts_as_well(v, t=t):
        if progress:
            progress(f"{' + '.join(names(chain))} predicts worse: kept {' + '.join(effects)}", None)
        record("predicts_as_well", "kept as added", (
            f"{' + '.join(names(chain))} predicts the held-out rows worse than {' + '.join(effects)} "
            f"({_versus_text(v)}): kept as added"), **figures)
        return added
    record("predicts_as_well", f"{' + '.join(names(chain))} instead", (
        f"{' + '.join(names(chain))} in place of {' + '.join(effects)}: it predicts as well with "
        f"{'fewer' if len(kept) < len(effects) else 'simpler'} effects ({_versus_text(v)})"), **figures)
    return chain


def _versus_text(v: dict) -> str:
    """An ``improvement`` in words: the one-step error's change with its z, then each open-loop horizon's."""
    said = f"one-step error {-v['one_step_removed']:+.1%} (z {v['z']:.1f})"
    return said + "".join(f", {h}-step error {-removed:+.0%}" for h, removed in v["horizons_removed"].items())
