"""Closed loop: does the model with the added effects behave like the measured robot?

The one-step and k-step errors of the diagnosis say how well a model predicts the robot from
measured states; a policy cares about what happens when the model runs on its own. This runs
the robot and model side by side, in closed loop, from held-out initial states, the way
``acn-fit`` evaluates a corrector (``acn.corrector.evaluate``), so the two ways of closing a gap,
physics and a network, get the same numbers:

- the **robot**: the measured side of an ``acn-collect`` dataset, re-run: its simulator, its
  control settings and physical parameters, its policy acting on the ROBOT's state (as in the
  collector); with its hidden effects from ``DIR.answer.json`` when it has them (they drive the
  robot only, the way a real robot carries its physics; the model never sees them);
- ``uncorrected``: the model as given, driven with the robot's actions (``as given`` when the
  model file carries a corrector of its own);
- ``corrected``: the same model with a corrector applied (``--corrector DIR``): the network's answer;
- ``with effects``: the model after the diagnosis added its effects: the physics answer;
- ``same_state_oracle`` and ``tracking_oracle``: the bounds on any corrector of the given model
  (``acn.corrector.oracle``), when the model is a MuJoCo model and the robot has no hidden effects
  (the oracles re-simulate the robot one step from a set state, which loses what a latency or
  backlash carries from step to step).

Divergence (robot - model, headline over the 33 output channels each divided by the spread of
the measured states), eps_transfer = mean over episodes of (R_model - R_robot) with the paper's
reward, falls, and each run against the model as given, episode by episode (reward gap
|R_model - R_robot| closer by, divergence lower by, each +- its standard error): all as
``acn.corrector.evaluate.summarise``. Logs from other code (``acn-import``)
cannot be re-run: only the data's own simulator can stand in for the robot.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from acn.measurements.data import Measurements
from acn.errors import UserError
from acn.sim.effects import Model

WITH_EFFECTS = "with effects"
ORDER = ("uncorrected", "as given", "corrected", WITH_EFFECTS, "same_state_oracle", "tracking_oracle")


def robot_config(dataset: str | Path, data: Measurements, side: str, model: Model, episodes: int, seconds: float,
                 corrector_dir: str | Path | None = None):
    """The held-out closed-loop ``CollectConfig``: source = the robot, target = ``model``; checks
    everything a closed loop needs (called before the diagnosis, so a mistake costs nothing)."""
    from dataclasses import replace

    from acn.datasets.metadata import config_from_metadata
    from acn.corrector.evaluate import held_out
    from acn.sim.hidden import answer_path, sealed_robot
    from acn.sim.policies import POLICIES

    info = data.info
    if info.policy not in POLICIES or info.init_noise is None:
        raise UserError(f"--closed-loop re-runs the measured robot: {dataset} is a log (policy {info.policy!r}), "
                        "not an acn-collect dataset whose simulator and policy can be run again")
    if side != "source":
        raise UserError("--closed-loop needs --side source: the collected policy acts on the source's state")
    if model.corrector and corrector_dir:
        raise UserError(f"the model already has the corrector {model.corrector}; give --corrector only for a model "
                        "without one")
    cfg = config_from_metadata(info)
    answer = answer_path(dataset)
    hidden = sealed_robot(answer, backend=cfg.source).effects if answer.is_file() else []
    cfg = replace(cfg, target=model.backend, hidden_effects=hidden, target_effects=list(model.effects))
    return held_out(cfg, episodes, seconds)


def closed_loop_models(dataset: str | Path, data: Measurements, side: str, before: Model, after: Model | None,
                       corrector_dir: str | Path | None, episodes: int, seconds: float, oracles: bool = True,
                       log: Callable[[str], None] | None = None) -> dict:
    """Robot vs ``before`` (uncorrected), ``before`` + corrector, ``after``, and the oracles (module doc).

    Returns ``acn.corrector.evaluate.summarise``'s dict (``runs`` by name, in ``ORDER``) plus
    ``models`` (what each run ran) and ``robot`` (its simulator, hidden effects, policy, seed).
    """
    from dataclasses import replace

    from acn.corrector.acn import OUTPUT_CHANNELS
    from acn.corrector.corrector import Corrector
    from acn.corrector.evaluate import output_spread, run_episodes, run_oracles, summarise

    cfg = robot_config(dataset, data, side, before, episodes, seconds, corrector_dir)
    spread = output_spread(data.next_state)
    say = log or (lambda _: None)
    first = "as given" if before.corrector else "uncorrected"  # a model file may carry its own corrector
    runs, names = {}, {first: before.describe() + (f" + corrector {before.corrector}" if before.corrector else "")}

    def corrector_of(model: Model, extra=None):
        path = extra or model.corrector
        return Corrector.load(path) if path else None

    say(f"closed loop: the robot ({cfg.source}{' with its hidden effects' if cfg.hidden_effects else ''}) "
        f"and the model, {episodes} held-out episode(s) of {seconds:g} s")
    runs[first] = run_episodes(cfg, corrector_of(before), episodes)
    if corrector_dir:
        runs["corrected"] = run_episodes(cfg, corrector_of(before, corrector_dir), episodes)
        names["corrected"] = f"{before.describe()} + corrector {corrector_dir}"
    if after is not None and after.to_json() != before.to_json():
        if after.backend != before.backend:
            raise UserError("the model after the diagnosis has another backend than before")
        runs[WITH_EFFECTS] = run_episodes(replace(cfg, target_effects=list(after.effects)), corrector_of(after),
                                          episodes)
        names[WITH_EFFECTS] = after.describe()
    if oracles and before.backend == "mujoco" and not before.corrector and not cfg.hidden_effects:
        runs.update(run_oracles(cfg, episodes, spread))
        names["same_state_oracle"] = f"{before.describe()} + the best per-step correction F(s, a) (bound)"
        names["tracking_oracle"] = f"{before.describe()} + corrections that see the robot's next state"
    out = summarise(runs, list(OUTPUT_CHANNELS), spread, reference=first)
    out["runs"] = {k: out["runs"][k] for k in ORDER if k in out["runs"]}
    out["models"] = names
    out["robot"] = {"simulator": cfg.source, "hidden_effects": [e.to_json() for e in cfg.hidden_effects],
                    "policy": cfg.policy, "seed": cfg.seed}
    return out


def table(result: dict) -> str:
    """The closed-loop comparison as terminal text, one row per run."""
    from acn.sim.state import DYNAMIC_GROUPS

    groups = list(DYNAMIC_GROUPS)
    head = ["run", "divergence", *groups, "eps_transfer", "reward gap", "gap closer by", "falls"]
    rows = [head]
    for name, r in result["runs"].items():
        rows.append([name, f"{r['divergence']:.3g}", *(f"{r['divergence_by_group'][g]:.3g}" for g in groups),
                     f"{r['eps_transfer']:.1f}", f"{np.mean(r['reward_gap_per_episode']):.1f}", closer_by(r),
                     f"{r['target_falls']}/{len(r['ends'])}"])
    width = [max(len(row[i]) for row in rows) for i in range(len(head))]
    lines = [f"closed loop, model vs the robot (return of the robot {result['return_source']:.1f}; reward gap: "
             "mean |R_model - R_robot| per episode; gap closer by: how much smaller than the first run's, +- stderr):"]
    lines += ["  " + "  ".join(c.ljust(w) for c, w in zip(row, width)) for row in rows]
    lines += [f"  {k}: {v}" for k, v in result["models"].items()]
    return "\n".join(lines)


def closer_by(run: dict) -> str:
    """The run's reward gap against the first run's, as text: "37.1 +- 9.9 (narrower)"."""
    if "versus" not in run:
        return "-"
    v = run["versus"]
    g = v["reward_gap_closer_by"]
    return f"{g['mean']:.1f} +- {g['stderr']:.1f} ({v['change']['reward_gap']})"
