"""A ``Diagnosis`` as a user reads it: JSON (``--json``), terminal tables, an HTML report.

JSON keys (the machine-readable contract):

- ``format``: ``"acn-diagnosis/1"`` (how the toolkit recognises a file it may replace);
- ``verdict``: ``"none"``, ``"effect"`` or ``"unexplained"``; ``reason`` in words;
- ``data_checks``: the measurements' own consistency findings (``acn.measurements.checks``), each
  ``check``, ``channels``, ``message``; empty when consistent;
- ``accelerometer``: how the logged accelerometer is read (``accelerometer`` module): ``kind``
  (``"mean"`` over the control step, the schema's, or ``"instant"``), ``stated`` (by the dataset; else
  judged), ``instant_share`` and ``instant_better`` (judged: the instant reading's one-step
  accelerometer MSE over the mean one's, and the share of rows it predicts better; null otherwise),
  ``judged_again`` (judged under the model with the effects added, and the diagnosis run again),
  ``integration`` (judged: the model-free test, ``gamma`` 0 for the mean and about 1 for instants,
  its ``stderr``, the ``velocity`` integrated against (``"logged"`` or ``"legs'"``), ``rows``, whether
  it ``decides``, and with a logged velocity the same test against the ``legs``' velocity; null
  where it could not run);
- ``headline_error``: its definition and the value before and after the added effects;
- ``step``: one diagnosis step, ``control_steps`` and ``seconds`` (``DiagnoseConfig.step_seconds``), and
  ``check_horizon``: the steps of the open-loop check (``compare.informative_horizon``);
- ``error``: horizon (diagnosis steps, as a string) -> channel group -> normalised RMS;
- ``noise_floor``: MSE, share of the error, per channel group;
- ``where``: the breakdown (``where`` module) with its ``summary``;
- ``ranking``: best first, each ``name``, ``params`` (as in a model file), ``granularity``,
  ``free_parameters`` (``value``, ``stderr`` and ``identified`` each: false when the standard
  error exceeds half the largest realistic magnitude, ``policy.unidentified``), ``explained``
  (share 0..1 of the error above the noise floor), ``removed`` (share of the whole error),
  ``z``, ``significant``, ``significant_by`` (``"one step"``, ``"longest horizon"``: ``policy.uneven``;
  null when not significant), ``score``, ``implausible`` (why it cannot be the explanation, "" if it
  can: ``policy.doubt``), ``plausibility`` (what its fitted values' size says:
  ``policy.Plausibility``, ``"plausible"``, ``"contradicted by the measurements"``, ``"at a bound"``,
  ``"too large"``, ``"too small"``), ``longest_horizon_removed`` (share of the open-loop error at the
  check's horizon, ``step.check_horizon``, it removes; null where not checked: ``policy.screen``);
- ``added`` (with ``--add`` / ``--auto``): in order, ``name``, ``params``, ``granularity``,
  ``refines`` (the granularity of an effect added before and fitted finer in this step, else
  null), ``same_physics_as`` (the effect in the words of those it reproduces while the PD is
  unsaturated, ``EffectTraits.alike``: PD gains as motor strength and joint damping; else null),
  ``one_step_ties`` (``--auto``'s effects and the first one ``--add`` names: the candidate it was
  added as, then those of the same ranking the held-out one step could not tell from it,
  ``policy.tied_either_way``, each ``name``, ``params`` of its ranking fit, ``removed`` and
  ``longest_horizon_removed`` as in ``ranking``; [] if none),
  ``error_before`` and ``error_after`` (horizon -> group), ``headline_before``,
  ``headline_after``, ``explained``;
- ``same_physics_together``: effects of the final model that together are the same physics as one
  catalogue effect not in it while the PD is unsaturated (``EffectTraits.together``: motor strength +
  joint damping as PD gains), each ``effects`` and ``as``; [] if none;
- ``model`` and ``final_model``: the model files before and after; ``named_model``: the one the
  verdict stands for (``--save-model`` writes it: the final model, or the model as given where
  the added effects do not hold on two halves of the episodes);
- ``halves`` (``--auto`` with effects added, else []): each added effect fitted again on two
  halves of the episodes (``acn.diagnosis.halves``): ``effect``, ``parameters``, ``first``,
  ``second``, ``stderr_first``, ``stderr_second``, ``chi2``;
- ``decisions``: every decision of the selection in the order made (``acn.diagnosis.decisions``):
  ``rule`` (the deciding function of ``policy``), ``inputs`` (the figures and thresholds it
  compared, by name), ``outcome`` (a few words), ``sentence`` (the same in words, from those
  inputs), ``within`` (the search: "" for the chain first built, "chain started with X", "revisit
  X") and ``reported`` (one of the decisions that built and judged the model reported:
  ``reported_decisions``; the report and ``acn-view`` show these);
- ``seconds``: ``compare``, ``rank``, ``add`` (every stage after the ranking) and ``total``;
  ``stages``: every stage's wall time in the order run (``compare``, ``rank``, ``add EFFECT``,
  ``rank beside EFFECTS``, ``finer look``, ``revisit``, ``other starts``, ``final refit``,
  ``halves``);
- ``closed_loop`` (with ``--closed-loop``, else null): the robot re-run beside the model from
  held-out initial states (``transfer``): ``runs`` by name (``uncorrected`` = the model as
  given, or ``as given`` when its file carries a corrector; ``corrected`` = with
  ``--corrector``, ``with effects`` = the final model, the oracles), each with ``divergence``, ``divergence_by_group``, ``divergence_curve``,
  ``eps_transfer``, ``target_falls``, ``reward_gap_per_episode`` and (all but the first run)
  ``versus``: against the first run, episode by episode (``acn.corrector.evaluate.versus``);
  ``models`` (what each run ran), ``robot``;
- ``limits`` (with ``--limits``, else null): per parameter with a realistic range of each effect not
  in the final model (``acn.diagnosis.limits``): ``effect``, ``parameter``, ``unit``,
  ``nominal``, ``limit`` (the smallest value ``--auto`` would name beside the final model; null:
  none scanned), ``realistic``, ``realistic_missable`` (the part of the realistic range below the
  limit), ``inert`` (alone, the effect's other parameters nominal, it changes nothing), and the scan:
  ``sizes``, ``removed``, ``z``, ``detected`` (``removed`` and ``z`` with the final model's effects
  moved to explain the effect at the sizes where that can move the limit, else without it); with
  ``--limits-per-joint``, a per-joint parameter also has ``one_joint`` (the same keys, and
  ``joint``: the scan on the one joint the log shows least) and ``by_joint`` (joint name -> the
  smallest size scanned it is shown at alone, null: none).
"""

from __future__ import annotations

import html
import json
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from acn.diagnosis.compare import Comparison, group_errors
from acn.diagnosis.pipeline import Diagnosis
from acn.diagnosis.decisions import Decision
from acn.diagnosis.policy import THRESHOLDS, Thresholds, doubt, plausibility, significant, unidentified
from acn.diagnosis.results import Added, Candidate, longer_gain
from acn.diagnosis.traits import traits
from acn.diagnosis.transfer import closer_by, table as closed_loop_table
from acn.jsonfile import strict_json
from acn.outputs.kinds import Output, json_with_format
from acn.outputs.writing import write_file
from acn.sim.effects import EFFECT_NAMES, get_effect

FORMAT = "acn-diagnosis/1"
GENERATOR = "acn-diagnose report"


def _is_report(path: Path) -> bool:
    """An HTML report this toolkit wrote: its head names the generator."""
    try:
        with open(path, "rb") as f:
            head = f.read(2048)
    except OSError:
        return False
    return f'<meta name="generator" content="{GENERATOR}">'.encode() in head


DIAGNOSIS_JSON = Output("diagnosis JSON", directory=False, recognise=json_with_format(FORMAT))
REPORT = Output("diagnosis report", directory=False, recognise=_is_report)

HEADLINE = ("one-step teacher-forced prediction error on held-out rows: RMS over every compared channel of "
            "(measured - predicted) / spread of the measured one-step change (1 = as wrong as predicting no motion)")


def _errors(c: Comparison) -> dict:
    return {str(h): {g: round(v, 6) for g, v in e.items()} for h, e in sorted(c.error.items())}


def _free(fit, t: Thresholds = THRESHOLDS) -> list[dict]:
    loose = set(unidentified(fit, t=t))
    return [{"name": n, "value": float(v), "stderr": float(e), "identified": n not in loose}
            for n, v, e in zip(fit.names, fit.x, fit.stderr)]


def _noise_fit_text(a: Added, decisions: Sequence[Decision]) -> str:
    """The warning the trace holds for an effect added with ``--add`` that lowers the one-step error
    only (``policy.added_fits_noise``), "" where it holds none."""
    warned = [x for x in decisions if x.rule == "one_step_only" and x.outcome == "warned"
              and x.inputs.get("effect") == a.name]
    return warned[-1].sentence.removeprefix(f"{a.name} (--add): ") if warned else ""


def reported_decisions(d: Diagnosis) -> list[Decision]:
    """The decisions that built and judged the model the diagnosis reports: those of the first
    chain and the verdict (``within`` ""), and those of the chain that replaced it (``within``
    "chain started with X"), in the order made; the other searches' are in the JSON."""
    kept = next((c.start for c in d.chains if c.kept), None)
    replaced_by = f"chain started with {kept}" if kept is not None and d.chains and not d.chains[0].kept else None
    return [x for x in d.decisions if not x.within or x.within == replaced_by]


def _kd(d: Diagnosis) -> float:
    """The commanded derivative gain, N m s/rad (mean over joints)."""
    return float(np.mean(np.atleast_1d(d.problem.control.kd)))


def _alike(a: Added, kd: float, t: Thresholds = THRESHOLDS) -> str:
    alike = traits(a.name).alike
    return alike(a.fit.values, kd, t.smallest_share) if alike else ""


def _alike_text(a: Added, kd: float, t: Thresholds = THRESHOLDS) -> str:
    """The added effect in the words of those it reproduces (``EffectTraits.alike``), "" if none."""
    said = _alike(a, kd, t)
    return f"while the PD is unsaturated, the same physics as: {said}" if said else ""


def _own_params(fit) -> str:
    """The effect's own fitted values ("scale=0.9027"; "value=12 values 0.1..0.3"), without those of
    effects refitted with it."""
    said = []
    for name, v in fit.effect.to_json(fit.values).items():
        said.append(f"{name}={len(v)} values {min(v):.4g}..{max(v):.4g}" if isinstance(v, list) else f"{name}={v:.4g}")
    return ", ".join(said)


def _tie(c: Candidate, horizon: int) -> str:
    longer = "" if c.longer_gain is None else f" and {c.longer_gain:.0%} of the {horizon}-step one"
    return f"{c.name} ({_own_params(c.fit)}) removed {c.judgement.removed:.1%} of the one-step error{longer}"


def _ties_text(a: Added) -> str:
    """The candidates the held-out one step could not tell the added effect from (``Added.ties``),
    each with its ranking fit, "" if none: what the data leave open."""
    if not a.ties:
        return ""
    h = a.before.check
    return (f"the held-out one step could not tell it from {'; '.join(_tie(c, h) for c in a.ties[1:])} "
            f"(ranked, {_tie(a.ties[0], h)})")


def _together(d: Diagnosis) -> list[dict]:
    """Effects of the final model that together are the same physics as one catalogue effect not in
    it, while the PD is unsaturated (``EffectTraits.together``: motor strength + joint damping are PD
    gains): each ``effects`` and ``as``, the reading."""
    held = {t.name: t.values for t in d.final.model.effects}
    out = []
    for effect in map(get_effect, EFFECT_NAMES):
        together = traits(effect.name).together
        if together and effect.name not in held and effect.reproduces and set(effect.reproduces) <= set(held):
            said = together({n: held[n] for n in effect.reproduces}, _kd(d))
            if said:
                out.append({"effects": list(effect.reproduces), "as": said})
    return out


def _together_text(d: Diagnosis) -> list[str]:
    return [f"{' + '.join(t['effects'])} together, while the PD is unsaturated, the same physics as: {t['as']}"
            for t in _together(d)]


def _ties_json(a: Added) -> list[dict]:
    return [{"name": c.name, "params": c.fit.effect.to_json(c.fit.values), "removed": round(c.judgement.removed, 4),
             "longest_horizon_removed": None if c.longer_gain is None else round(c.longer_gain, 4)} for c in a.ties]


def _notes(a: Added, kd: float, t: Thresholds = THRESHOLDS, decisions: Sequence[Decision] = ()) -> list[str]:
    """What the report says under an added effect besides its numbers (``decisions``: the trace's)."""
    return [said for said in (_unidentified_text(a.fit, t), _noise_fit_text(a, decisions), _longer_text(a, t),
                              _alike_text(a, kd, t), _ties_text(a)) if said]


def _longer_text(a: Added, t: Thresholds = THRESHOLDS) -> str:
    """Where the added effect is significant by its longest-horizon gain alone (``policy.significant``,
    ``policy.uneven``), that gain and its one-step figures; "" otherwise."""
    if a.judgement.significant or not significant(a, t=t):
        return ""
    return (f"significant by its {a.before.check}-step prediction: it removes {longer_gain(a):.0%} of that "
            f"open-loop error, {a.judgement.removed:.1%} of the one-step error ({a.judgement.z:.1f} standard errors, "
            "not significant at one step)")


def _unidentified_text(fit, t: Thresholds = THRESHOLDS) -> str:
    loose = unidentified(fit, t=t)
    return (f"not identified by these data (standard error above half the largest realistic magnitude): "
            f"{', '.join(loose)}") if loose else ""


def _set_aside_because(d: Diagnosis, c: Candidate) -> str:
    """Why a significant candidate is not the explanation: ``policy.doubt`` on its ranking fit, or
    (``--auto``) its final fit; "" otherwise."""
    if not c.judgement.significant:
        return ""
    return doubt(c, t=d.thresholds) or (f"--auto: {d.set_aside[c.name]}" if c.name in d.set_aside else "")


def _params_text(fit, most: int = 4, t: Thresholds = THRESHOLDS) -> str:
    """The fitted free parameters with their standard errors; those of effects refitted with it
    (``fitting.Together``: named "effect.parameter") after "refitted with it", apart, since their
    units differ."""
    free = _free(fit, t)
    own, partners = [f for f in free if "." not in f["name"]], [f for f in free if "." in f["name"]]
    text = _values_text(own, most)
    return f"{text}; refitted with it: {_values_text(partners, most)}" if partners else text


def _values_text(free: list[dict], most: int) -> str:
    if len(free) > most:  # 12 per-joint values: the spread, the rest is in the JSON
        v = np.array([f["value"] for f in free])
        return f"{len(free)} values {v.min():.3g}..{v.max():.3g} (see --json)"
    return ", ".join(f"{f['name']}={f['value']:.4g} +- {_number(f['stderr'], '.2g')}" for f in free)


def _number(x: float | None, spec: str, missing: str = "not identified") -> str:
    """``x`` formatted, or ``missing`` where it is not a finite number (a diagnosis never prints nan)."""
    return format(x, spec) if x is not None and np.isfinite(x) else missing


def _longer(c: Candidate) -> str:
    """The candidate's share of the longest-horizon open-loop error removed ("" if not checked)."""
    return "" if c.longer_gain is None else f"{c.longer_gain:+.0%}"


def _significant(c: Candidate) -> str:
    """yes / no, and "yes (longest horizon)" for an effect significant by its long prediction only."""
    return ("yes (longest horizon)" if c.judgement.by_longest else "yes") if c.judgement.significant else "no"


def _candidate(c: Candidate, floor_mse: float, t: Thresholds = THRESHOLDS) -> dict:
    j = c.judgement
    return {"name": c.name, "params": c.fit.effect.to_json(c.fit.values), "granularity": c.fit.granularity,
            "free_parameters": _free(c.fit, t), "explained": round(j.explained(floor_mse), 4),
            "removed": round(j.removed, 4), "z": round(j.z, 2), "significant": j.significant,
            "significant_by": ("longest horizon" if j.by_longest else "one step") if j.significant else None,
            "implausible": doubt(c, t=t), "plausibility": plausibility(c.fit, t=t)[0].value,
            "score": round(c.score, 4),
            "longest_horizon_removed": None if c.longer_gain is None else round(c.longer_gain, 4)}


def _step(a: Added) -> str:
    """"added joint_damping (shared)", or "refined joint_damping (shared -> type)" for a finer fit."""
    if a.refines:
        return f"refined {a.name} ({a.refines} -> {a.fit.granularity})"
    return f"added {a.name} ({a.fit.granularity})"


def _added(a: Added, floor_mse: float, kd: float, t: Thresholds = THRESHOLDS) -> dict:
    return {"name": a.name, "params": a.fit.effect.to_json(a.fit.values), "granularity": a.fit.granularity,
            "refines": a.refines or None, "same_physics_as": _alike(a, kd, t) or None,
            "one_step_ties": _ties_json(a),
            "free_parameters": _free(a.fit, t), "error_before": _errors(a.before), "error_after": _errors(a.after),
            "headline_before": a.before.headline, "headline_after": a.after.headline,
            "explained": a.judgement.explained(floor_mse), "removed": a.judgement.removed}


def _decisions_json(d: Diagnosis) -> list[dict]:
    reported = {id(x) for x in reported_decisions(d)}
    return [{**x.to_json(), "reported": id(x) in reported} for x in d.decisions]


def to_json(d: Diagnosis) -> dict:
    p = d.problem
    groups = group_errors(p, np.sqrt(d.floor)[None, :])
    return {
        "format": FORMAT,
        "verdict": d.verdict, "reason": d.reason, "measurements": d.measurements,
        "data_checks": [f.to_json() for f in d.data_checks],
        "accelerometer": d.accelerometer.to_json() if d.accelerometer else None,
        "rows": {"transitions": len(p.data), "fit": len(p.fit_rows), "held_out": len(p.held_rows),
                 "compared": len(d.before.rows), "diverged": d.before.diverged},
        "derived_channels": p.derived,
        "headline_error": {"definition": HEADLINE, "before": d.before.headline, "after": d.final.headline},
        "step": {"control_steps": p.unit, "seconds": p.unit * p.control.control_dt, "check_horizon": d.before.check},
        "error": _errors(d.before),
        "noise_floor": {"mse": d.floor_mse, "share_of_error": 1.0 - d.structured_share,
                        "by_group": {g: round(v, 6) for g, v in groups.items()}},
        "where": d.where,
        "ranking": [_candidate(c, d.floor_mse, d.thresholds) for c in d.ranking],
        "added": [_added(a, d.floor_mse, _kd(d), d.thresholds) for a in d.added],
        "same_physics_together": _together(d),
        "chains": [c.to_json() for c in d.chains],
        "set_aside_on_final_fit": d.set_aside,
        "model": d.before.model.to_json(), "final_model": d.final.model.to_json(),
        "named_model": d.model.to_json(),
        "halves": [h.to_json() for h in d.halves],
        "decisions": _decisions_json(d),
        "seconds": d.seconds, "stages": d.stages,
        "closed_loop": d.closed_loop,
        "limits": [x.to_json() for x in d.limits] if d.limits is not None else None,
    }


def json_text(d: Diagnosis) -> str:
    """The diagnosis JSON file's text."""
    return json.dumps(strict_json(to_json(d)), indent=2, allow_nan=False) + "\n"


def write_json(d: Diagnosis, path: str | Path) -> Path:
    return write_file(path, json_text(d), DIAGNOSIS_JSON)


# ----- terminal -------------------------------------------------------------------------------
def _table(header: list[str], rows: list[list[str]]) -> str:
    widths = [max(len(str(x)) for x in col) for col in zip(header, *rows)]
    line = lambda r: "  ".join(str(x).ljust(w) for x, w in zip(r, widths))  # noqa: E731
    return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, rows)])


def error_table(before: Comparison, after: Comparison | None = None) -> str:
    hs = sorted(before.error)
    groups = list(before.error[1])
    head = ["group"] + [f"{h} step{'s' if h > 1 else ''}" for h in hs]
    rows = []
    for g in groups:
        cells = []
        for h in hs:
            b = _number(before.error[h].get(g), ".4f", "-")
            cells.append(b if after is None else f"{b} -> {_number(after.error[h].get(g), '.4f', '-')}")
        rows.append([g] + cells)
    return _table(head, rows)


def terminal(d: Diagnosis) -> str:
    out = [f"measurements: {d.measurements}; model: {d.before.model.describe()}"]
    out += [f"data check ({f.check}): {f.message}" for f in d.data_checks]
    if d.accelerometer and d.accelerometer.describe():
        out += [d.accelerometer.describe()]
    if d.problem.unit > 1:
        out += [f"one step = {d.problem.unit} control steps ({d.problem.unit * d.problem.control.control_dt:.3g} s: "
                "--step-seconds), so sensor noise does not swamp what an effect does in one control step"]
    out += [f"headline error (one step, normalised): {d.before.headline:.4f}; noise floor "
            f"{1 - d.structured_share:.0%} of it", "", "error per channel group and horizon (normalised RMS, held-out "
            "rows):", error_table(d.before), "", "where: " + d.where["summary"], "", "candidate effects, best first:"]
    rows = []
    for c in d.ranking:
        j = c.judgement
        params = _params_text(c.fit, t=d.thresholds)
        rows.append([c.name, c.fit.granularity, f"{j.explained(d.floor_mse):.0%}", f"{j.removed:+.1%}", f"{j.z:.1f}",
                     _significant(c), _longer(c), params])
    out.append(_table(["effect", "fitted as", "explained", "error removed", "z", "significant",
                       f"{d.before.check}-step removed", "parameters"], rows))
    out += [f"set aside: {c.name} {doubt(c, t=d.thresholds)}" for c in d.ranking
            if c.judgement.significant and doubt(c, t=d.thresholds)]
    out += [f"set aside by --auto: {name} {why}" for name, why in d.set_aside.items()]
    for a in d.added:
        out += ["", f"{_step(a)}: {a.fit.effect.to_json(a.fit.values)}"]
        out += _notes(a, _kd(d), d.thresholds, d.decisions)
        out += [f"headline {a.before.headline:.4f} -> {a.after.headline:.4f}", error_table(a.before, a.after)]
    together = _together_text(d)
    out += ["", *together] if together else []
    if len(d.chains) > 1:
        out += ["", "chains of effects tried by --auto (started with):"]
        out += [f"  {c.start}: {c.label}; {'KEPT, ' if c.kept else ''}{c.why}"
                for c in d.chains]
    decided = reported_decisions(d)
    if decided:
        out += ["", "how it decided:", *(f"  {x.sentence}" for x in decided)]
    out += ["", f"verdict: {d.verdict} ({d.reason})"]
    out += [f"  on a bounded search: {x.sentence}" for x in decided if x.rule == "out_of_time"]
    if d.limits:
        one = _one_joint(d.limits)
        out += ["", f"what this log rules out: {LIMITS}" + (f"; {ONE_JOINT}" if one else ""),
                _table(_limit_header(one), [_limit_row(x, one) for x in d.limits if not x.inert])]
    if d.closed_loop:
        out += ["", closed_loop_table(d.closed_loop)]
    return "\n".join(out)


LIMITS = ("the smallest size of each effect not in the final model that --auto would name beside it, one step "
          "ahead (the final model's effects moved one Gauss-Newton step to explain it first; optimistic: a fit "
          "that finds it exactly, nothing else standing in for it, no noise bias; every joint "
          "alike, the effect's other parameters nominal; a parameter that alone changes nothing, such as a payload's "
          "centre of mass, is left out)")  # under the heading "what this log rules out"


ONE_JOINT = ("one joint alone: the same on one joint, the other eleven nominal, on the joint the log shows least "
             "(shown at or beyond it on any joint)")  # with --limits-per-joint


def _one_joint(limits) -> bool:
    return any(x.one_joint is not None for x in limits)


def _limit_header(one_joint: bool) -> list[str]:
    return (["effect", "parameter", "shown from", "realistic", "could be missed"]
            + (["one joint alone: shown from", "could be missed"] if one_joint else []))


def _limit_row(x, one_joint: bool = False) -> list[str]:
    row = [x.effect, x.parameter, x.describe(), x.realistic_text(), x.missable()]
    if one_joint:
        j = x.one_joint
        row += [f"{j.describe()} ({j.joint})", j.missable()] if j is not None else ["", ""]
    return row


# ----- HTML -----------------------------------------------------------------------------------
def write_html(d: Diagnosis, path: str | Path) -> Path:
    return write_file(path, html_text(d), REPORT)


def html_text(d: Diagnosis) -> str:
    """A self-contained report (plotly.js inline): error breakdown, ranking, error falling."""
    import plotly.graph_objects as go
    import plotly.io as pio

    figs = []
    hs = sorted(d.before.error)
    fig = go.Figure([go.Bar(name=f"{h} step{'s' if h > 1 else ''}", x=list(d.before.error[h]),
                            y=list(d.before.error[h].values())) for h in hs])
    fig.update_layout(title="Error per channel group and horizon (normalised RMS, held-out rows)", barmode="group",
                      yaxis_title="normalised RMS")
    figs.append(fig)
    w = d.where
    fig = go.Figure(go.Bar(x=list(w["by_joint"]), y=list(w["by_joint"].values())))
    fig.update_layout(title="One-step error by joint (position and velocity channels)", yaxis_title="normalised RMS")
    figs.append(fig)
    if "all" in w["by_phase"]:
        legs = [k for k in w["by_phase"] if k != "all"]
        fig = go.Figure([go.Bar(name=ph, x=legs, y=[w["by_phase"][k][ph] for k in legs]) for ph in ("stance", "swing")])
        fig.update_layout(title="Leg joints' error by gait phase", barmode="group", yaxis_title="normalised RMS")
        figs.append(fig)
    fig = go.Figure()
    for name, t in w["trends"].items():
        if t["bins"]:
            fig.add_trace(go.Scatter(x=[f"Q{i + 1}" for i in range(len(t["bins"]))], y=[b["error"] for b in t["bins"]],
                                     text=[f"{b['from']:.3g}..{b['to']:.3g}" for b in t["bins"]],
                                     mode="lines+markers", name=f"{name} (rank correlation {t['rank_correlation']:.2f})"))
    fig.update_layout(title="Joint error against its speed, torque and action change (quartiles of each, low to high)",
                      xaxis_title="quartile of the variable (hover: its range)", yaxis_title="normalised RMS")
    figs.append(fig)
    fig = go.Figure(go.Bar(x=[c.name for c in d.ranking], y=[c.judgement.explained(d.floor_mse) for c in d.ranking],
                           marker_color=["#2a9d8f" if c.judgement.significant else "#bbbbbb" for c in d.ranking]))
    fig.update_layout(title="Share of the error above the noise floor each candidate explains (grey: not significant)",
                      yaxis_range=[0, 1.05], yaxis_title="explained")
    figs.append(fig)
    if d.added:
        steps = ["model"] + [f"+ {a.name}" for a in d.added]
        fig = go.Figure()
        for h in hs:
            fig.add_trace(go.Scatter(x=steps, y=[_headline(d.before, h)] + [_headline(a.after, h) for a in d.added],
                                     mode="lines+markers", name=f"{h} step{'s' if h > 1 else ''}"))
        fig.add_hline(y=float(np.sqrt(d.floor_mse)), line_dash="dot", annotation_text="noise floor (one step)")
        fig.update_layout(title="The error falling as effects are added", yaxis_title="normalised RMS (all channels)")
        figs.append(fig)
    loop = d.closed_loop
    if loop:
        fig = go.Figure([go.Scatter(y=r["divergence_curve"], x=np.arange(len(r["divergence_curve"])) * d.problem.control.control_dt,
                                    mode="lines", name=name) for name, r in loop["runs"].items()])
        fig.update_layout(title="Closed loop: divergence of each model from the robot (mean over held-out episodes)",
                          xaxis_title="time, s", yaxis_title="normalised L2 over the 33 output channels")
        figs.append(fig)
    parts = [pio.to_html(f, full_html=False, include_plotlyjs=(i == 0)) for i, f in enumerate(figs)]
    loop_rows = "".join(
        f"<tr><td>{html.escape(name)}</td><td>{r['divergence']:.3g}</td><td>{r['eps_transfer']:.1f}</td>"
        f"<td>{np.mean(r['reward_gap_per_episode']):.1f}</td><td>{html.escape(closer_by(r))}</td>"
        f"<td>{r['target_falls']}/{len(r['ends'])}</td><td>{html.escape(loop['models'].get(name, ''))}</td></tr>"
        for name, r in loop["runs"].items()) if loop else ""
    loop_html = (f"<h2>Closed loop: the model beside the robot</h2><p>{len(loop['horizon_steps'])} held-out episode(s); "
                 f"the robot's return {loop['return_source']:.1f}; eps_transfer = mean (R_model - R_robot), the paper's "
                 "reward; reward gap = mean |R_model - R_robot| per episode; closer by = how much smaller the reward gap "
                 "is than the first run's, episode by episode from the same starts, +- its standard error.</p><table><tr><th>run</th><th>divergence</th>"
                 "<th>eps_transfer</th><th>reward gap</th><th>closer by</th><th>falls</th><th>model</th>"
                 f"</tr>{loop_rows}</table>") if loop else ""
    ranking = "".join(
        f"<tr><td>{c.name}</td><td>{c.fit.granularity}</td><td>{c.judgement.explained(d.floor_mse):.0%}</td>"
        f"<td>{c.judgement.removed:+.1%}</td><td>{c.judgement.z:.1f}</td><td>{_longer(c)}</td>"
        f"<td>{html.escape(_params_text(c.fit, t=d.thresholds))}</td><td>{html.escape(_set_aside_because(d, c))}</td>"
        "</tr>" for c in d.ranking)
    added = "".join(f"<li>{html.escape(_step(a))} {html.escape(_params_text(a.fit, t=d.thresholds))}: headline "
                    f"{a.before.headline:.4f} &rarr; {a.after.headline:.4f}"
                    + "".join(f"<br><i>{html.escape(t)}</i>" for t in _notes(a, _kd(d), d.thresholds, d.decisions))
                    + "</li>"
                    for a in d.added) + "".join(f"<li><i>{html.escape(t)}</i></li>" for t in _together_text(d))
    chains = "".join(f"<li>started with {c.start}: <b>{html.escape(c.label)}</b>"
                     f"{' (kept)' if c.kept else ''}: {html.escape(c.why)}</li>" for c in d.chains) if len(d.chains) > 1 else ""
    checks_html = ("<p><b>Data checks</b> (the measurements' own consistency, before any model, and with the "
                   "model whether each state has the action that drove it and the log the model's time step; a "
                   "model compared with them explains these as physics):</p><ul>"
                   + "".join(f"<li>{html.escape(f.message)}</li>" for f in d.data_checks) + "</ul>") if d.data_checks else ""
    if d.accelerometer and d.accelerometer.describe():
        checks_html += f"<p>{html.escape(d.accelerometer.describe())}.</p>"
    decided = "".join(f"<li>{html.escape(x.sentence)}</li>" for x in reported_decisions(d))
    decided_html = ("<h2>How it decided</h2><p>Each rule that decided the course of this diagnosis, in order, with "
                    "the figures it compared and its threshold (every decision, the other searches' too, is in the "
                    f"JSON's <code>decisions</code>):</p><ol>{decided}</ol>") if decided else ""
    body = f"""<!doctype html><html><head><meta charset="utf-8"><meta name="generator" content="{GENERATOR}"><title>acn-diagnose: {html.escape(d.measurements)}</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:4px 8px}}</style></head><body>
<h1>Diagnosis of {html.escape(d.measurements)}</h1>
<p><b>Verdict: {d.verdict}</b> &mdash; {html.escape(d.reason)}.</p>
{checks_html}<p>Model: {html.escape(d.before.model.describe())}. Headline error {d.before.headline:.4f} &rarr; {d.final.headline:.4f}
({html.escape(HEADLINE)}). Noise floor: {1 - d.structured_share:.0%} of the error.</p>
<p><b>Where:</b> {html.escape(d.where['summary'])}</p>
<h2>Candidate effects</h2><table><tr><th>effect</th><th>fitted as</th><th>explained</th><th>error removed</th><th>z</th>
<th>{d.before.check}-step error removed</th><th>parameters</th><th>set aside because</th></tr>{ranking}</table>
{'<h2>Added</h2><ul>' + added + '</ul>' if added else ''}
{'<p>Chains of effects tried by --auto (one effect can stand in for two):</p><ul>' + chains + '</ul>' if chains else ''}
{decided_html}
{_limits_html(d)}{loop_html}
<h2>Plots</h2>{''.join(parts)}</body></html>"""
    return body


def _limits_html(d: Diagnosis) -> str:
    if not d.limits:
        return ""
    one = _one_joint(d.limits)
    rows = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in _limit_row(x, one)) + "</tr>"
                   for x in d.limits if not x.inert)
    head = "".join(f"<th>{html.escape(c)}</th>" for c in _limit_header(one))
    also = f" {html.escape(ONE_JOINT[0].upper() + ONE_JOINT[1:])}." if one else ""
    return (f"<h2>What this log rules out</h2><p>{html.escape(LIMITS[0].upper() + LIMITS[1:])}.{also}</p>"
            f"<table><tr>{head}</tr>{rows}</table>")


def _headline(c: Comparison, h: int) -> float:
    return float(np.sqrt(np.mean(np.array(list(c.error[h].values())) ** 2)))
