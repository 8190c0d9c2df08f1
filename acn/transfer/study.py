"""The transfer study: from measurements on a robot to policies that walk on it, two routes compared.

``run_study(TransferConfig(robot=..., sim=...), out)`` runs, in order, every stage a toolkit
command of its own (a subprocess; its output goes to ``OUT/logs/STEP.log``, its time is printed):

1. measurements (``acn-collect``): the excitation and the trot, the built-in policy acting on SIM
   and the same actions replayed on ROBOT from the same starts (the robot is the TARGET, where a
   corrector is applied). With ``hidden_effects`` the robot is first made: ROBOT with those
   effects, sealed in ``OUT/robot.answer.json`` (simulated by every command, printed by none);
2. physics (``acn-diagnose --auto``): SIM against both measurements, the robot's side; the model
   M it saves (the model as given where nothing is found);
3. corrector F (``acn-fit`` on the trot, the robot re-simulated with its own physics,
   ``--model ROBOT``): it makes the robot act like SIM;
4. policies (``acn-ppo --refit-every 0``, plain PPO, the same sizes): pi_sim trained in SIM, pi_M
   in M, pi_robot on the robot (the bound); and F_M for pi_M (``acn-collect`` of the trot M ->
   ROBOT, ``acn-fit``): the robot made to act like M. These four are independent: with ``ray``
   they run as Ray tasks;
5. evaluation (``acn-ppo --eval``, ``episodes`` each, the same held-out starts): pi_sim with and
   without F, pi_M with and without F_M, pi_robot, on the robot and in each policy's own model;
6. the table (``acn.transfer.table``), ``transfer.json``, ``transfer.png``.

The study's own files are in ``OUT`` only. It is written in place (its files name paths inside
it) under one lock for the whole study (``acn.outputs.writing``, ``Layout.IN_PLACE``): an
existing ``OUT`` is replaced only where it is a study this toolkit wrote (``TRANSFER_STUDY``), a
study that fails leaves what its stages wrote there, with their logs, for a look, and a stage's
command ends with the study, however the study ends.
"""

from __future__ import annotations

import json
import shlex
import signal
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from acn.errors import UserError
from acn.jsonfile import strict_json
from acn.lifetime import child_environment
from acn.outputs.kinds import Output, json_with_format
from acn.outputs.writing import Layout, Writing, write_file
from acn.sim.backends import SimConfig
from acn.sim.hidden import draw_hidden, load_model, write_answer
from acn.transfer.table import TransferTable

STUDY_FORMAT = "acn-transfer/1"
STUDY_FILE = "transfer.json"


def _is_study(path: Path) -> bool:
    return json_with_format(STUDY_FORMAT)(path / STUDY_FILE) or (path / "study.started").is_file()


TRANSFER_STUDY = Output("transfer study directory", directory=True, recognise=_is_study)
# The toolkit's commands by name: each runs as ``python -c`` on its entry point, so the study needs
# no console script on PATH and every stage is the command a user would type.
COMMANDS = {"acn-collect": "collect_main", "acn-diagnose": "diagnose_main", "acn-fit": "fit_main",
            "acn-ppo": "ppo_main"}


@dataclass
class TransferConfig:
    """Every size of the study; each is an option of ``acn-transfer`` (``measure_episodes``:
    ``--measure-episodes``). Training sizes are chosen once: see ``docs/transfer.md``."""

    robot: str = "mujoco"             # where the policies must walk: a model, or a robot with hidden effects
    sim: str = "pybullet"             # where a policy is trained without measurements
    hidden_effects: tuple[str, ...] = ()  # make the robot: ROBOT with these effects, sealed (--hidden-effect)
    timesteps: int = 200_000          # PPO control steps per policy, the same for all three
    episodes: int = 20                # evaluation episodes per policy, the same held-out starts
    seconds: float = 10.0             # episode length of training and evaluation, s
    measure_episodes: int = 6         # measured episodes per motion (excitation, trot), and of M -> robot
    measure_seconds: float = 8.0      # their length, s
    envs: int = 2                     # PPO environment processes per training
    seed: int = 0                     # measurements, PPO, evaluation starts
    effects: tuple[str, ...] = ()     # the diagnosis' candidates (acn-diagnose --effects; (): the catalogue)
    finest: str = "shared"            # acn-diagnose --finest: one value of a per-joint effect for every joint
    auto_alternatives: int = 0        # acn-diagnose --auto-alternatives: one chain of effects
    auto_seconds: float = 0.0         # acn-diagnose --auto-seconds (0: no bound, so the study's physics is the same
    # on any machine; a bound in seconds stops the search where a slower machine has done less)
    fit_epochs: int = 0               # acn-fit --epochs for F and F_M (0: acn-fit's default)
    fit_rounds: int = -1              # acn-fit --rounds (-1: acn-fit's default)

    def validate(self) -> None:
        from acn.diagnosis.fitting import GRANULARITIES

        if self.finest not in GRANULARITIES:
            raise UserError(f"--finest must be one of {', '.join(GRANULARITIES)}, got {self.finest!r}")
        for name in ("timesteps", "episodes", "measure_episodes", "envs"):
            if getattr(self, name) < 1:
                raise UserError(f"--{name.replace('_', '-')} must be >= 1, got {getattr(self, name)}")
        for name in ("seconds", "measure_seconds"):
            if not (np.isfinite(getattr(self, name)) and getattr(self, name) > 0):
                raise UserError(f"--{name.replace('_', '-')} must be > 0, got {getattr(self, name)}")
        robot, sim = load_model(self.robot), load_model(self.sim)
        for model, flag in ((robot, "--robot"), (sim, "--sim")):
            if model.corrector:
                raise UserError(f"{flag} carries a corrector ({model.corrector}); give a model with effects only")
        if robot.backend != "mujoco":
            raise UserError(f"--robot is a {robot.backend} model: the corrector's labels re-simulate the robot with "
                            "MuJoCo (acn-fit's inverse variant), so the robot must be a MuJoCo model")
        if self.hidden_effects and (robot.sealed or robot.effects):
            raise UserError("--hidden-effect makes the robot from a plain simulator: give --robot mujoco with it")
        if sim.sealed:
            raise UserError("--sim is a sealed robot: a simulator is trained in openly; give a model you can read")
        draw_hidden(self.hidden_effects, self.seed, SimConfig())  # a bad --hidden-effect fails here, before any work


@dataclass
class StepResult:
    name: str
    command: str
    seconds: float


@dataclass
class Step:
    """One toolkit command of the study."""

    name: str        # the log's name: OUT/logs/NAME.log
    prog: str        # a key of COMMANDS
    args: list[str]

    def command(self) -> str:
        return shlex.join([self.prog, *self.args])

    def run(self, out: Path) -> StepResult:
        fn = COMMANDS[self.prog]
        argv = [sys.executable, "-c", f"import sys; from acn.cli import {fn}; sys.exit({fn}(sys.argv[1:]))", *self.args]
        log = out / "logs" / f"{self.name}.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        t0 = time.perf_counter()
        with open(log, "w") as f:
            f.write(f"$ {self.command()}\n")
            f.flush()
            # The command ends with the study however the study ends: stopped here, or killed
            # (it watches this process: acn.lifetime).
            child = subprocess.Popen(argv, stdout=f, stderr=subprocess.STDOUT, cwd=out,
                                     env={**child_environment(), "HF_HUB_OFFLINE": "1", "PYTHONUNBUFFERED": "1"})
            try:
                code = child.wait()
            except BaseException:
                stop(child)
                raise
        if code != 0:
            lines = log.read_text(errors="replace").splitlines()
            said = next((line for line in reversed(lines) if line.strip()), "")
            raise StudyFailed(f"{self.prog} ({self.name}) exited with {code}: {said.strip()[:300]} (all of it: {log})")
        return StepResult(self.name, self.command(), time.perf_counter() - t0)


class StudyFailed(UserError):
    """A stage's command failed; its log says why."""


def run_steps(steps: list[Step], out: str) -> list[StepResult]:
    """Run ``steps`` in order (one Ray task, or here)."""
    return [s.run(Path(out)) for s in steps]


@dataclass
class Plan:
    """The study's paths and commands, written down before anything runs."""

    cfg: TransferConfig
    out: Path
    robot: str = ""                     # the robot as every command is given it
    stages: list[tuple[str, list[list[Step]]]] = field(default_factory=list)  # (stage, independent step lists)

    def __post_init__(self) -> None:
        c, o = self.cfg, self.out
        self.robot = str(o / "robot.answer.json") if c.hidden_effects else c.robot
        m = o / "physics" / "model.json"
        collect = ["--episodes", str(c.measure_episodes), "--seconds", f"{c.measure_seconds:g}", "--seed", str(c.seed),
                   "--workers", "2"]
        # The study judges correctors by the policies' returns on the robot: acn-fit's own closed loop
        # stays (its record), its oracle bounds (most of its time) are left out.
        fit = ["--no-oracles"] + ([] if c.fit_epochs == 0 else ["--epochs", str(c.fit_epochs)]) + \
              ([] if c.fit_rounds < 0 else ["--rounds", str(c.fit_rounds)])
        effects = ["--effects", ",".join(c.effects)] if c.effects else []

        def measure(name: str, policy: str, source: str) -> Step:
            return Step(f"collect_{name}", "acn-collect", ["--source", source, "--target", self.robot, "--policy", policy,
                                                           *collect, "--out", str(o / "measurements" / name)])

        # A training's own final evaluation is a 2-episode check without the oracle bound: the
        # evaluation stage is the study's judgement.
        def train(name: str, model: str) -> Step:
            return Step(f"train_{name}", "acn-ppo", [
                "--train", model, "--robot", self.robot, "--timesteps", str(c.timesteps), "--seconds", f"{c.seconds:g}",
                "--eval-seconds", f"{c.seconds:g}", "--refit-every", "0", "--eval-every", "0",
                "--final-eval-episodes", "2", "--oracle-episodes", "0", "--envs", str(c.envs), "--seed", str(c.seed),
                "--out", str(o / "policies" / name)])

        def evaluate(name: str, corrector: Path | None) -> Step:
            return Step(f"evaluate_{name}", "acn-ppo", [
                "--eval", str(o / "policies" / name / "policy"), "--robot", self.robot, "--episodes", str(c.episodes),
                "--seconds", f"{c.seconds:g}", "--seed", str(c.seed),
                *(["--corrector", str(corrector)] if corrector else []), "--out", str(o / "evaluations" / f"{name}.json")])

        self.stages = [
            ("1. measurements", [[measure("excite", "excite", c.sim), measure("trot", "trot", c.sim)]]),
            ("2. physics", [[Step("diagnose", "acn-diagnose", [
                str(o / "measurements" / "excite"), str(o / "measurements" / "trot"), "--side", "target",
                "--model", c.sim, "--auto", "--finest", c.finest, "--auto-alternatives", str(c.auto_alternatives),
                "--auto-seconds", f"{c.auto_seconds:g}",
                *effects, "--json", str(o / "physics" / "diagnosis.json"),
                "--report", str(o / "physics" / "report.html"), "--save-model", str(m)])]]),
            ("3. corrector F", [[Step("fit_F", "acn-fit", [str(o / "measurements" / "trot"), "--model", self.robot,
                                                            *fit, "--out", str(o / "correctors" / "F")])]]),
            ("4. policies, and F_M", [
                [train("sim", c.sim)], [train("model", str(m))], [train("robot", self.robot)],
                [measure("trot_model", "trot", str(m)),
                 Step("fit_F_M", "acn-fit", [str(o / "measurements" / "trot_model"), "--model", self.robot, *fit,
                                             "--out", str(o / "correctors" / "F_M")])]]),
            ("5. evaluation", [[evaluate("sim", o / "correctors" / "F"), evaluate("model", o / "correctors" / "F_M"),
                                evaluate("robot", None)]]),
        ]


def make_robot(cfg: TransferConfig, out: Path) -> Path:
    """The robot: MuJoCo with ``cfg.hidden_effects`` drawn from ``cfg.seed``, sealed in
    ``OUT/robot.answer.json`` (the answer ``acn-collect --hidden-effect`` writes; nothing printed)."""
    return write_answer(out / "robot", "mujoco", draw_hidden(cfg.hidden_effects, cfg.seed, SimConfig()), cfg.seed)


def run_study(cfg: TransferConfig, out: Path, ray=None, say: Callable[[str], None] = print,
              overwrite: bool = False) -> dict:
    """The study of the module docstring in ``out``; returns what ``transfer.json`` holds.
    ``ray``: a ``RayConfig`` to run stage 4's trainings as Ray tasks; ``overwrite``: replace a
    study this toolkit wrote there."""
    cfg.validate()
    output = Writing(out, TRANSFER_STUDY, overwrite, layout=Layout.IN_PLACE)
    try:
        result = _study(cfg, output.out, ray, say)
    except BaseException as e:
        raise output.fail(e) from None
    output.commit()
    return result


def _study(cfg: TransferConfig, out: Path, ray, say: Callable[[str], None]) -> dict:
    out.mkdir(parents=True, exist_ok=True)
    write_file(out / "study.started", json.dumps({"format": STUDY_FORMAT, "config": asdict(cfg)}) + "\n")
    if cfg.hidden_effects:
        path = make_robot(cfg, out)
        say(f"the robot: mujoco with {len(cfg.hidden_effects)} hidden effect(s), sealed in {path}")
    plan = Plan(cfg, out)
    for folder in ("measurements", "physics", "correctors", "policies", "evaluations", "logs"):
        (out / folder).mkdir(exist_ok=True)
    stage_seconds: dict[str, float] = {}
    steps: list[StepResult] = []
    t_start = time.perf_counter()
    for stage, groups in plan.stages:
        say(f"{stage}:")
        t0 = time.perf_counter()
        for s in (s for g in groups for s in g):
            say(f"  {s.command()}")
        if ray is not None and len(groups) > 1:
            results = on_ray(groups, out, ray, cfg.envs)
        else:
            results = [r for g in groups for r in run_steps(g, str(out))]
        for r in results:
            say(f"    {r.name}: {r.seconds:.0f} s")
        steps += results
        stage_seconds[stage] = time.perf_counter() - t0
        say(f"  {stage} took {stage_seconds[stage] / 60:.1f} min")
    evaluations = {name: json.loads((out / "evaluations" / f"{name}.json").read_text())
                   for name in ("sim", "model", "robot")}
    table = TransferTable.from_evaluations(evaluations)
    diagnosis = json.loads((out / "physics" / "diagnosis.json").read_text())
    total = time.perf_counter() - t_start
    result = {
        "format": STUDY_FORMAT, "config": asdict(cfg), "robot": plan.robot, "sim": cfg.sim,
        "model": {"file": str(out / "physics" / "model.json"), "described": load_model(out / "physics" / "model.json").describe(),
                  "verdict": diagnosis.get("verdict")},
        "table": table.to_json(), "evaluations": {k: str(out / "evaluations" / f"{k}.json") for k in evaluations},
        "stages_seconds": stage_seconds, "steps": [asdict(s) for s in steps], "seconds": total,
    }
    write_file(out / STUDY_FILE, json.dumps(strict_json(result), indent=2, allow_nan=False) + "\n")
    (out / "study.started").unlink(missing_ok=True)
    from acn.transfer.plot import plot_study

    plot_study(table, out / "transfer.png", title=f"trained in {load_model(cfg.sim).describe()}, robot "
               f"{load_model(plan.robot).describe()}")
    result["table_text"] = table.text()
    return result


def on_ray(groups: list[list[Step]], out: Path, ray_config, envs: int) -> list[StepResult]:
    """Each group of steps as one Ray task (a training takes ``envs`` + 1 CPUs where the cluster has
    them); the results in the groups' order. ``out`` must be on a filesystem every node sees."""
    from acn.sim.parallel import ray_session

    with ray_session(ray_config) as ray:
        cpus = max(1.0, min(float(envs + 1), ray.cluster_resources().get("CPU", 1.0)))
        task = ray.remote(run_steps)
        refs = [task.options(num_cpus=cpus if any(s.prog == "acn-ppo" for s in g) else 1).remote(g, str(out))
                for g in groups]
        return [r for rs in ray.get(refs) for r in rs]


def stop(child: subprocess.Popen, grace_s: float = 30.0) -> None:
    """End a stage's command as Ctrl-C would (it removes what it was building), or at once after
    ``grace_s``."""
    if child.poll() is None:
        child.send_signal(signal.SIGINT)
        try:
            child.wait(grace_s)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
