"""The diagnosis view: measurements against a model (``acn-view MEASURED --model MODEL.json``).

For every shown episode, from the measurements (``load_measurements``; the source side of a
paired dataset; velocities a log lacks are derived from positions, and a trunk position and
velocity it lacks by leg odometry, by ``fill_derived`` so the simulator can start, and are then
not compared):

- **the model's prediction** (trajectory ``model``): teacher-forced one step, i.e. the model set
  to each measured state s_t (with the actions before t, for latency), the measured action
  a_t applied; the predicted s_{t+1} is shown at frame t + 1 next to the measured s_{t+1}
  (3D robot, joint panels, divergence model - measured; no contacts: they are not predicted);
- **the residual per joint**, measured s_{t+1} - predicted s_{t+1} at frame t + 1, in physical
  units: ``residual/joint_pos/<joint>`` (rad) and ``residual/joint_vel/<joint>`` (rad/s);
- **the one-step error as effects are added**: for the model's effects E1..En in file order,
  stage k predicts with ``Model(backend, effects[:k])`` (stage 0: the nominal backend); its
  error at frame t + 1 is ``acn-diagnose``'s normalised RMS over the compared channels,
  sqrt(mean_c ((measured - predicted)_c / spread_c)^2) with spread_c the std of channel c's
  measured one-step change over the dataset (1 = as wrong as predicting no motion):
  ``effects/<k>_<name>`` (``effects/0_nominal`` first);
- **a text panel** ``diagnosis`` (markdown): the model, the mean error per stage, what was not
  measured, and, with ``--diagnosis FILE.json`` (``acn-diagnose --json``), its verdict, reason,
  ranking, where-summary and the decisions that led to the verdict.

Every stage of one episode is re-simulated in one ``Resimulator.run`` call (one row per
measured transition and stage, each row with its stage's model).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from acn.measurements.data import Measurements, load_measurements
from acn.datasets.reader import RecordedFrames, state_difference
from acn.errors import UserError
from acn.jsonfile import read_json
from acn.sim.backends import BACKENDS
from acn.sim.effects import Model
from acn.sim.resim import Resimulator
from acn.sim.state import FOOT_NAMES, GROUPS, JOINT_NAMES, SLICES, STATE_NAMES
from acn.viz.trajectories import COLORS, Document, EpisodeView, Panel, Series, Trajectory

VERDICTS = ("none", "effect", "unexplained")
# What a simulator must be started from: the pose and the velocities (after ``fill_derived``).
START_CHANNELS = np.concatenate([np.arange(SLICES[g].start, SLICES[g].stop) for g in
                                 ("base_pos", "base_rpy", "joint_pos", "base_linvel", "base_angvel", "joint_vel")])
RESIDUAL_GROUPS = {"joint_pos": ("joint position", "rad"), "joint_vel": ("joint velocity", "rad/s")}
# Residual series colours: a hue per leg, lighter from hip to calf.
LEG_COLORS = dict(zip(FOOT_NAMES, [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40)]))
TYPE_LIGHTEN = {"hip": 0.0, "thigh": 0.3, "calf": 0.55}
# Stage colours: the nominal model grey, the full model purple (as its trajectory), between them these.
NOMINAL_COLOR = (127, 127, 127)
STAGE_COLORS = [(255, 127, 14), (44, 160, 44), (214, 39, 40), (140, 86, 75), (227, 119, 194), (23, 190, 207)]
STAGE_WIDTH = 2.0  # ui points


@dataclass
class Stage:
    """One model of the effects ladder: the nominal backend plus the first k effects."""

    key: str      # entity name, "<k>_<name>": 0_nominal, 1_joint_damping, ...
    label: str    # legend text
    model: Model


@dataclass
class StagePrediction:
    """One episode's one-step predictions under every stage, at the predicted frames."""

    frame: np.ndarray        # (N,) frame of the predicted state (the measured row's frame + 1)
    measured: np.ndarray     # (N, 43) measured s_{t+1}
    predicted: np.ndarray    # (S, N, 43) predicted s_{t+1} per stage (NaN where diverged or not started)
    error: np.ndarray        # (S, N) normalised RMS over the compared channels (NaN where not predicted)
    diverged: np.ndarray     # (S,) rows whose re-simulation blew up, per stage
    skipped: int             # rows not re-simulated: the measured state is incomplete


def joint_color(joint: str) -> tuple[int, int, int]:
    leg, kind = joint.split("_")
    base, t = np.array(LEG_COLORS[leg], float), TYPE_LIGHTEN[kind]
    return tuple(int(round(x)) for x in base + t * (255 - base))


def stage_color(k: int, count: int) -> tuple[int, int, int]:
    if k == 0:
        return NOMINAL_COLOR
    if k == count - 1:
        return COLORS["model"]
    return STAGE_COLORS[(k - 1) % len(STAGE_COLORS)]


def effect_stages(model: Model) -> list[Stage]:
    """The nominal model, then the effects added one at a time in file order (the last: ``model``)."""
    out = [Stage("0_nominal", f"{model.backend} (nominal)", Model(model.backend, [], model.corrector))]
    for k, term in enumerate(model.effects, 1):
        out.append(Stage(f"{k}_{term.name}", f"+ {term.name}",
                         Model(model.backend, model.effects[:k], model.corrector)))
    return out


def load_diagnosis(path: str | Path) -> dict:
    """An ``acn-diagnose --json`` result, checked for what the view reads; else a one-line error."""
    p = Path(path)
    d = read_json(p, f"diagnosis file {p} does not exist")
    what = (f"{p} is not an acn-diagnose --json result (it needs 'verdict' ({', '.join(VERDICTS)}), 'reason', "
            "'ranking' with 'name' and 'explained', and 'where' with 'summary')")
    if not isinstance(d, dict) or d.get("verdict") not in VERDICTS or not isinstance(d.get("reason"), str):
        raise UserError(what)
    if not isinstance(d.get("where"), dict) or not isinstance(d["where"].get("summary"), str):
        raise UserError(what)
    ranking = d.get("ranking")
    if not isinstance(ranking, list) or not all(
            isinstance(c, dict) and isinstance(c.get("name"), str) and isinstance(c.get("explained"), (int, float))
            for c in ranking):
        raise UserError(what)
    return d


def prepared_measurements(path: Path, model: Model, side: str = "source"):
    """The measurements with derived velocities, and what the diagnosis compares: the
    ``acn.diagnosis.problem.Problem`` (channels, their spreads, previous actions per row)."""
    from acn.diagnosis.problem import DiagnoseConfig, prepare

    data = load_measurements(path, side)
    return prepare(data, model, DiagnoseConfig(horizons=(1,), step_seconds=None))


def predict_episode(problem, sim: Resimulator, stages: list[Stage], episode: int, corrector=None) -> StagePrediction:
    """One-step predictions of one episode's transitions under every stage (one ``run`` call)."""
    d: Measurements = problem.data
    rows = np.flatnonzero(d.episode == episode)
    rows = rows[np.argsort(d.frame[rows], kind="stable")]
    start = np.isfinite(d.state[np.ix_(rows, START_CHANNELS)]).all(axis=1)
    ok = rows[start]
    s, n = len(stages), len(ok)
    actions = d.action[ok]
    if corrector is not None:
        from acn.diagnosis.problem import corrected

        actions = corrected(corrector, d.state[ok], actions)
    model = np.repeat(np.arange(s), n)
    pred = sim.run(problem.starts(sim, np.tile(ok, s), sim.configs, model), np.tile(actions, (s, 1)),
                   np.tile(d.previous_actions(ok, problem.history), (s, 1, 1)), model=model)
    predicted = np.full((s, len(rows), len(STATE_NAMES)), np.nan)
    predicted[:, start] = pred.state[:, 0].reshape(s, n, -1)
    measured = d.next_state[rows]
    residual = state_difference(measured[None], predicted)[..., problem.channels] / problem.scale[1]
    with np.errstate(invalid="ignore"):
        error = np.sqrt(np.mean(residual ** 2, axis=-1))  # NaN where a compared channel is missing
    return StagePrediction(d.frame[rows] + 1, measured, predicted, error, pred.diverged.reshape(s, n).sum(axis=1),
                           int((~start).sum()))


def _rms(x: np.ndarray) -> float:
    x = x[np.isfinite(x)]
    return float(np.sqrt(np.mean(x ** 2))) if x.size else float("nan")


def _missing_text(missing: list[str]) -> str:
    """Channel names, a whole group said once."""
    out, left = [], list(missing)
    for group, names in GROUPS.items():
        if names and all(n in left for n in names):
            out.append(f"{group} (all {len(names)})")
            left = [n for n in left if n not in names]
    return ", ".join(out + left)


def model_markdown(name: str, model: Model, measurements: str, episode: int, stages: list[Stage],
                   p: StagePrediction, problem) -> str:
    """The model part of the text panel: what is compared and the mean error per stage."""
    means = [_rms(e) for e in p.error]
    rows = [f"| {st.label} | {m:.4f} | {'' if k == 0 else f'{(m / means[0] - 1) * 100:+.1f} %'} | {int(dv)} |"
            for k, (st, m, dv) in enumerate(zip(stages, means, p.diverged))]
    legs = ", ".join(f"{leg} {hue}" for leg, hue in zip(FOOT_NAMES, ("blue", "orange", "green", "red")))
    lines = [f"**Model** `{name}`: {model.describe()}", "",
             f"**Measurements** {measurements}, episode {episode}: {len(p.frame)} transitions, each predicted one "
             "step from the measured state (previous actions for latency, the measured action applied).", "",
             "| model | one-step error | vs nominal | diverged |", "|---|---|---|---|", *rows, "",
             f"One-step error: normalised RMS over the {len(problem.channels)} compared channels (1 = as wrong as "
             "predicting no motion), mean over this episode. Residuals: measured - model (last row), joint position "
             f"in rad, joint velocity in rad/s; colours {legs}, lighter from hip to calf."]
    notes = []
    if problem.data.missing:
        notes.append(f"Not measured, not compared: {_missing_text(problem.data.missing)}.")
    if problem.derived:
        notes.append("Derived to start the simulation (velocities from positions; a trunk position the log lacks by "
                     f"leg odometry), not compared: {_missing_text(problem.derived)}.")
    if p.skipped:
        notes.append(f"{p.skipped} transitions not predicted: their measured state is incomplete.")
    return "\n".join(lines + ([""] + notes if notes else []))


def diagnosis_markdown(name: str, d: dict) -> str:
    """The ``acn-diagnose --json`` part of the text panel: verdict, reason, where, ranking, added, the
    decisions that led there (the JSON's ``decisions`` marked ``reported``) and, with ``--limits``,
    what the log rules out."""
    rows = [f"| {k} | {c['name']} | {c['explained']:.0%} | {'yes' if c.get('significant') else 'no'} |"
            for k, c in enumerate(d["ranking"], 1)]
    of = f" of {d['measurements']}" if isinstance(d.get("measurements"), str) else ""
    lines = [f"**Diagnosis** `{name}`{of}: verdict **{d['verdict']}** ({d['reason']})", "",
             f"**Where:** {d['where']['summary']}", "",
             "| rank | effect | explained (of the error above the noise floor) | significant |", "|---|---|---|---|",
             *rows]
    checks = [c["message"] for c in d.get("data_checks") or [] if isinstance(c, dict) and "message" in c]
    if checks:
        lines[1:1] = ["", "**Data checks** (the measurements' own consistency):", *(f"- {m}" for m in checks)]
    added = [a for a in d.get("added") or [] if isinstance(a, dict) and "name" in a]
    if added:
        lines += ["", "**Added:** " + "; ".join(
            f"{a['name']} (headline error {a.get('headline_before', float('nan')):.4f} -> "
            f"{a.get('headline_after', float('nan')):.4f})" for a in added)]
    decided = [x["sentence"] for x in d.get("decisions") or []
               if isinstance(x, dict) and x.get("reported") and isinstance(x.get("sentence"), str)]
    if decided:
        lines += ["", "**How it decided** (each rule that decided, with its figures and threshold):",
                  *(f"{k}. {sentence}" for k, sentence in enumerate(decided, 1))]
    every = [x for x in d.get("limits") or [] if isinstance(x, dict)]
    limits = _missable(every)
    if limits:
        lines += ["", "**What this log could miss** (`--limits`: the smallest size `--auto` would name, optimistic; "
                  "effects whose whole realistic range it shows left out):", *map(_limit_line, limits)]
    one = _missable([x["one_joint"] for x in every if isinstance(x.get("one_joint"), dict)])
    if one:
        lines += ["", "**On one joint alone it could miss** (`--limits-per-joint`: on the joint it shows least):",
                  *map(_limit_line, one)]
    return "\n".join(lines)


def _missable(limits: list[dict]) -> list[dict]:
    """The ``--limits`` entries with a realistic range the log could miss (read defensively)."""
    return [x for x in limits if not x.get("inert") and isinstance(x.get("limit"), (int, float, type(None)))
            and x.get("realistic_missable") not in (None, "none")]


def _limit_line(x: dict) -> str:
    unit = "" if x.get("unit") in (None, "1") else f" {x['unit']}"
    at = f" on {x['joint']}" if isinstance(x.get("joint"), str) else ""
    shown = f"shown from {x['limit']:.3g}{unit}" if x["limit"] is not None else "not shown at any size scanned"
    return f"- {x.get('effect')} {x.get('parameter')}{at}: {shown}, realistic values it could miss: " \
        f"{x['realistic_missable']}"


def add_diagnosis_view(model_spec: str | Path, frames: RecordedFrames, episodes: list[EpisodeView],
                       diagnosis: Path | None = None) -> None:
    """Add the model's trajectory, residual and effects series, panels and text to ``episodes``
    (see module docstring). ``model_spec``: a backend name or a model JSON file; a model's
    corrector, if it names one, corrects the measured actions of every stage (as in
    ``acn-diagnose``)."""
    model = Model.parse(model_spec)
    report = load_diagnosis(diagnosis) if diagnosis is not None else None
    problem = prepared_measurements(frames.path, model)
    stages = effect_stages(model)
    corrector = None
    if model.corrector:
        from acn.corrector.corrector import Corrector

        corrector = Corrector.load(model.corrector)
    nominal = str(model_spec) in BACKENDS
    name = model.backend if nominal else Path(model_spec).name
    label = f"model ({model.backend}, nominal)" if nominal else f"model ({name})"
    configs = [st.model.sim_config(problem.control) for st in stages]
    compared = set(problem.channels.tolist())
    with Resimulator(model.backend, configs, threads=problem.threads) as sim:
        for ep in episodes:
            p = predict_episode(problem, sim, stages, ep.index, corrector)
            show_prediction(ep, p, stages, label, compared, problem.control.control_dt)
            text = model_markdown(name, model, problem.data.description, ep.index, stages, p, problem)
            if report is not None:
                text += "\n\n" + diagnosis_markdown(Path(diagnosis).name, report)
            ep.documents.append(Document("diagnosis", text))
            ep.panels.append(Panel("diagnosis", "diagnosis", kind="text"))


def show_prediction(ep: EpisodeView, p: StagePrediction, stages: list[Stage], label: str, compared: set[int],
                    dt: float) -> None:
    """The last stage as trajectory ``model``; residuals of the compared joint channels; the
    error of every stage; their panels (error first: it is what a user looks for)."""
    _extend_timeline(ep, p.frame, dt)
    ep.trajectories.append(Trajectory("model", label, p.predicted[-1], p.frame))
    for k, st in enumerate(stages):
        ep.series.append(Series(f"effects/{st.key}", st.label, p.error[k], p.frame, stage_color(k, len(stages)),
                                width=STAGE_WIDTH))
    ep.panels.append(Panel("one-step error as effects are added, normalised RMS", "effects"))
    residual = state_difference(p.measured, p.predicted[-1])
    for group, (what, unit) in RESIDUAL_GROUPS.items():
        shown = [j for j, joint in enumerate(JOINT_NAMES) if SLICES[group].start + j in compared]
        for j in shown:
            ep.series.append(Series(f"residual/{group}/{JOINT_NAMES[j]}", JOINT_NAMES[j],
                                    residual[:, SLICES[group].start + j], p.frame, joint_color(JOINT_NAMES[j])))
        if shown:  # 12 joints: no legend (colours are said in the text, names show on hover)
            ep.panels.append(Panel(f"{what} residual (measured - model), {unit}", f"residual/{group}", legend=False))


def _extend_timeline(episode: EpisodeView, frame: np.ndarray, dt: float) -> None:
    """Timestamps for predicted frames past the last recorded one (s_{t+1} of the last row)."""
    need = int(frame.max()) + 1 if len(frame) else 0
    have = len(episode.timestamp)
    if need > have:
        last = episode.timestamp[-1] if have else -dt
        episode.timestamp = np.concatenate([episode.timestamp, last + dt * np.arange(1, need - have + 1)])
