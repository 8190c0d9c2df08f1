"""The verdict: ``effect``, ``unexplained`` or ``none``, from what the ranking and the chain
found, and the halves check that turns an effect away whose fits on two halves of the episodes
disagree (``holds_on_halves``).
"""

from __future__ import annotations

from acn.diagnosis.compare import Comparison
from acn.diagnosis.decisions import record
from acn.diagnosis.halves import HalfFits, chi2_quantile
from acn.diagnosis.heldout import explained_share, longest_removed, structured_share
from acn.diagnosis.policy.judging import doubt, evidence, implausible, one_step_only
from acn.diagnosis.policy.thresholds import THRESHOLDS, Thresholds
from acn.diagnosis.results import Added, Candidate, names


def does_not_hold(fits: list[HalfFits], t: Thresholds = THRESHOLDS) -> str:
    """Why the added effects do not hold on two halves of the episodes ("" where they do): an
    effect whose two fits differ beyond their standard errors (chi^2 above its quantile at
    ``halves_z``, ``acn.diagnosis.halves``)."""
    off = [f for f in fits if f.chi2 > chi2_quantile(len(f.names), t.halves_z)]
    return "; ".join(f"{f.worst()} (chi^2 {f.chi2:.0f} on {len(f.names)} values)" for f in off)


def verdict(before: Comparison, mse: float, floor_mse: float, ranking: list[Candidate], added: list[Added],
            automatic: bool, set_aside: dict[str, str] | None = None,
            t: Thresholds = THRESHOLDS) -> tuple[str, str, tuple[str, ...]]:
    """(verdict, reason in words, the effects it names); see module docstring. ``set_aside``:
    candidates ``--auto`` did not add on their final fit (name -> why); never named."""
    v, reason, named = _verdict(before, mse, floor_mse, ranking, added, automatic, set_aside or {}, t)
    record("verdict", v, f"verdict {v}: {reason}", named=" + ".join(named), headline=before.headline, exact=t.exact,
           structured=structured_share(mse, floor_mse), structured_share=t.structured_share,
           effect_share=t.effect_share)
    return v, reason, named


def holds_on_halves(judged: tuple[str, str, tuple[str, ...]], fits: list[HalfFits], added: list[Added], mse: float,
                    floor_mse: float, t: Thresholds = THRESHOLDS) -> tuple[str, str, tuple[str, ...]]:
    """The verdict ``judged`` (``verdict``'s) once the added effects are fitted on two halves of the
    episodes (``fits``): where they do not agree (``does_not_hold``), the effects only paper over
    structure the catalogue lacks and the verdict is ``unexplained``."""
    why = does_not_hold(fits, t=t)
    worst = max((f.chi2 for f in fits), default=0.0)
    if not why:
        record("does_not_hold", "holds", (
            f"the fits of {' + '.join(names(added))} on two halves of the episodes agree within their standard errors "
            f"(chi^2 at most its {t.halves_z:g}-sigma quantile)"), largest_chi2=worst, halves_z=t.halves_z)
        return judged
    reason = (f"{structured_share(mse, floor_mse):.0%} of the error is structured (above the noise floor); "
              f"{' + '.join(names(added))} would explain it, but not alike on two halves of the episodes: {why}")
    record("does_not_hold", "unexplained", f"verdict unexplained: {reason}", largest_chi2=worst, halves_z=t.halves_z)
    return "unexplained", reason, ()


NOT_ADDED = "is not added by --auto (too little to add)"  # a candidate --auto declined, in a reason


def _verdict(before: Comparison, mse: float, floor_mse: float, ranking: list[Candidate], added: list[Added],
             automatic: bool, set_aside: dict[str, str], t: Thresholds) -> tuple[str, str, tuple[str, ...]]:
    if before.headline < t.exact:
        return "none", f"the model reproduces the measurements (headline error {before.headline:.2g})", ()
    structured = 1.0 - floor_mse / mse if mse > 0 else 0.0
    if automatic and added:
        part = explained_share(mse, added[-1].judgement.mse_after, floor_mse)
        effects = tuple(names(added))
        explain = f"{' + '.join(effects)} explains" if len(effects) == 1 else f"{' + '.join(effects)} explain"
        if part >= t.effect_share:
            return "effect", f"{explain} {part:.0%} of the error above the noise floor", \
                effects
        after = added[-1].judgement.mse_after
        left = 1.0 - floor_mse / after if after > 0 else 0.0
        if min(structured, left) < t.structured_share:  # what is left is noise, by the rule that gives "none"
            longer = longest_removed(before, added[-1].after)
            gain = f" (the {before.check}-step open-loop error falls by {longer:.0%})" if longer and longer > 0 else ""
            why = (f"the one-step error is mostly sensor noise (only {max(structured, 0):.0%} of it is predictable "
                   f"from the state and actions)" if structured < t.structured_share else
                   f"only {max(left, 0):.0%} of the one-step error left is predictable from the state and actions, "
                   f"against {structured:.0%} before")
            return "effect", (f"{explain} {part:.0%} of the error above the noise floor{gain}, and what is "
                              f"left matches within the noise: {why}"), effects
    # With --auto its chain is the answer: a candidate it did not add (too little to, or set aside) is not named
    declined = {c.name for c in ranking if c.name not in names(added)} if automatic else set()
    plausible = [c for c in ranking if c.judgement.significant and not doubt(c, t=t) and c.name not in set_aside
                 and c.name not in declined]
    top = plausible[0] if plausible else None
    aside = "".join(f"; {name} set aside: {why}" for name, why in set_aside.items())
    if top is not None and top.judgement.explained(floor_mse) >= t.effect_share:
        skipped = [c.name for c in ranking[: ranking.index(top)] if c.name not in set_aside]
        also = f"; ranked above it but set aside: {', '.join(skipped)}" if skipped else ""
        also += aside
        return "effect", (f"{top.name} explains {top.judgement.explained(floor_mse):.0%} of the error above the noise "
                          f"floor ({evidence(top, t=t)}){also}"), (top.name,)
    best = ranking[0] if ranking else None
    if structured >= t.structured_share:
        why = ("no candidate improves held-out predictions significantly" if best is None
               or not best.judgement.significant else
               f"the best plausible candidate, {top.name}, explains only {top.judgement.explained(floor_mse):.0%} of it"
               if top is not None else
               f"the best candidate, {best.name}, {doubt(best, t=t) or set_aside.get(best.name, '') or NOT_ADDED}")
        return "unexplained", f"{structured:.0%} of the error is structured (above the noise floor); {why}{aside}", ()
    extra = f"; the best candidate, {best.name}, removes {best.judgement.removed:.1%} of it" if best else ""
    if best is not None and (implausible(best.fit, t=t) or best.name in set_aside or best.name in declined):
        extra += f" but {implausible(best.fit, t=t) or set_aside.get(best.name) or NOT_ADDED}"
    noise = sorted((c for c in ranking if one_step_only(c, t=t)),
                   key=lambda c: -c.judgement.removed)  # the most convincing first
    if noise:
        extra += f"; {noise[0].name} {one_step_only(noise[0], t=t)}"
    return "none", (f"the model matches within the noise: only {max(structured, 0):.0%} of the error is predictable "
                    f"from the state and actions and no plausible effect explains it{extra}"), ()
