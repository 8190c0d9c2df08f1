"""Command-line entry points (installed as ``acn-*`` console scripts).

Every command prints a one-line error and exits with status 2 on bad input (an output another
run is writing included), with 1 where writing failed (a full disk, a read-only file system, a
permission), and with 130 when interrupted (Ctrl-C or SIGTERM). Library code raises; only this module prints and exits.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import shlex
import signal
import sys
import threading
from pathlib import Path
from typing import Callable, Iterator, NoReturn

from acn.errors import UserError
from acn.flags import (Flag, add_flags, comma_list, config_from_args, given, given_fields, nonneg_float, nonneg_int, number, positive_float,
                       positive_int, seconds)
from acn.outputs.checks import check_input_dir, check_output, check_space

EXIT_USAGE, EXIT_WRITE, EXIT_INTERRUPTED, EXIT_BROKEN_PIPE = 2, 1, 130, 141  # 141: 128 + SIGPIPE


class _Help(argparse.HelpFormatter):
    """Every option's help ends with its default (where it has one)."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        default = action.default
        if action.option_strings and default is not None and default is not False and default != [] \
                and default is not argparse.SUPPRESS and "%(default)" not in text and "default" not in text.lower():
            shown = ",".join(map(str, default)) if isinstance(default, tuple) else "%(default)s"
            text += f" (default: {shown})"
        return text


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, formatter_class=_Help, **kwargs)

    def error(self, message: str) -> NoReturn:  # one line instead of usage + error
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see --help)\n")


def _run(prog: str, body: Callable[[], int | None]) -> int:
    """Run a command's ``body``: SIGTERM stops it as Ctrl-C does, the locks it took on its outputs
    are given back however it ends, and every failure a user can act on is one line."""
    from acn.lifetime import end_with_runner_from_environment
    from acn.outputs.lock import release_all, set_program
    from acn.outputs.writing import WriteFailed, write_errno

    set_program(prog)
    end_with_runner_from_environment()
    said = _say_library_warnings(prog)
    previous = signal.signal(signal.SIGTERM, _interrupt) if threading.current_thread() is threading.main_thread() \
        else None
    try:
        return body() or 0
    except (UserError, ValueError, FileExistsError, FileNotFoundError) as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except WriteFailed as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return EXIT_WRITE
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # the reader of the output went away (`| head`): stop quietly, as a shell tool does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error when Python flushes it
        return EXIT_BROKEN_PIPE
    except OSError as e:  # a write outside any output (a temporary file, a log): still one line
        if write_errno(e) is None:
            raise
        print(f"{prog}: error: {e}", file=sys.stderr)
        return EXIT_WRITE
    finally:
        release_all()
        logging.getLogger("acn").removeHandler(said)
        logging.getLogger("acn").propagate = True
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


def _interrupt(signum, frame) -> NoReturn:
    raise KeyboardInterrupt


def _say_library_warnings(prog: str) -> logging.Handler:
    """The library's warnings (``logging``, e.g. the leftovers of dead runs it removed) as
    ``PROG: message`` lines on stderr."""
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter(f"{prog}: %(message)s"))
    handler.setLevel(logging.WARNING)
    logger = logging.getLogger("acn")
    logger.addHandler(handler)
    logger.propagate = False  # said once, even where a library has configured the root logger
    return handler


def _out_path(text: str) -> Path:
    """An argparse type for an output path: not empty (``Path("")`` would be the working directory)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path")
    return Path(text)


def _joint_gains(minimum: float, inclusive: bool) -> Callable[[str], "float | tuple[float, ...]"]:
    """An argparse type for a PD gain: one number for every joint, three (hip, thigh, calf: the
    same on every leg) or twelve (the schema's joint order FR, FL, RR, RL; hip, thigh, calf)."""
    parse_one = number(float, minimum, inclusive)

    def parse(text: str):
        values = [parse_one(t.strip()) for t in text.split(",")]
        if len(values) == 1:
            return values[0]
        if len(values) == 3:
            return tuple(values * 4)
        if len(values) == 12:
            return tuple(values)
        raise argparse.ArgumentTypeError(f"expected 1, 3 (hip,thigh,calf) or 12 comma-separated numbers, "
                                         f"got {len(values)} in {text!r}")

    return parse


def _leg_order(text: str) -> tuple[str, ...]:
    """An argparse type: the four legs FR, FL, RR, RL in some order, comma-separated."""
    from acn.sim.state import FOOT_NAMES

    order = tuple(t.strip() for t in text.split(","))
    if sorted(order) != sorted(FOOT_NAMES):
        raise argparse.ArgumentTypeError(f"expected FR, FL, RR and RL once each, comma-separated; got {text!r}")
    return order


def _check_device(device: str) -> None:
    """``--device``: cpu, or cuda (cuda:N) where torch sees a GPU; one line otherwise."""
    import torch

    try:
        kind = torch.device(device).type
    except (RuntimeError, ValueError):
        raise UserError(f"--device {device!r:.40} is not a device: give cpu or cuda") from None
    if kind not in ("cpu", "cuda"):
        raise UserError(f"--device {device!r:.40}: acn-fit trains on cpu or cuda")
    if kind == "cuda" and not torch.cuda.is_available():
        raise UserError(f"--device {device}: torch sees no CUDA GPU on this machine; use --device cpu")


_GAINS_HELP = "; one number for every joint, or hip,thigh,calf (every leg), or 12 in the order FR, FL, RR, RL"


# ----------------------------------------------------------------------------- --ray (optional extra)
def _add_ray_arguments(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--ray", nargs="?", const="", default=None, metavar="ADDRESS",
                   help=f"run {what} on Ray: alone, a local Ray instance (this machine's CPUs or --ray-cpus); "
                   "ADDRESS (auto, or HOST:PORT from `ray start --head`) joins a cluster; needs pip install -e '.[ray]'")
    p.add_argument("--ray-cpus", type=positive_int, default=None, metavar="N",
                   help="--ray without ADDRESS: CPUs of the local Ray instance (default: all of this machine's)")


def _ray_config(args: argparse.Namespace):
    """``--ray [ADDRESS]`` and ``--ray-cpus`` as a ``RayConfig`` (None: no Ray); one-line errors."""
    if args.ray is None:
        if args.ray_cpus is not None:
            raise UserError("--ray-cpus needs --ray")
        return None
    if args.ray and Path(args.ray).exists():
        raise UserError(f"--ray took {args.ray!r} as a cluster address; write --ray=ADDRESS or put --ray after it")
    from acn.sim.parallel import RayConfig, import_ray

    import_ray()
    config = RayConfig(address=args.ray or None, cpus=args.ray_cpus)
    config.validate()
    return config


@contextlib.contextmanager
def _ray_executor(args: argparse.Namespace, prog: str) -> Iterator[None]:
    """Re-simulation batches on Ray within the block (``acn.sim.parallel``), or a no-op."""
    config = _ray_config(args)
    if config is None:
        yield
        return
    from acn.sim.parallel import ray_executor

    with ray_executor(config.address, config.cpus) as executor:
        yield
    print(f"{prog}: {executor.batches} re-simulation batch(es) ran on Ray ({executor.workers} CPUs), "
          "smaller ones here", file=sys.stderr)


# ----------------------------------------------------------------------------- acn-collect
def _sim_flags() -> dict[str, Flag]:
    """SimConfig's control settings on the command line (``acn-collect``)."""
    from acn.sim.backends import ACTION_MODES

    return {"action_mode": Flag("position: joint targets, PD at the physics rate; torque: joint torques",
                                choices=ACTION_MODES),
            "kp": Flag("PD stiffness, N m/rad" + _GAINS_HELP, _joint_gains(0, False)),
            "kd": Flag("PD damping, N m s/rad" + _GAINS_HELP, _joint_gains(0, False)),
            "torque_limit": Flag("N m, every joint", positive_float)}


def _collect_defaults():
    """acn-collect's defaults: CollectConfig's, recording the source alone unless --target is given."""
    from dataclasses import replace

    from acn.sim.collector import CollectConfig

    return replace(CollectConfig(), target=None)


_MODEL_HELP = ("pybullet, mujoco, a model JSON file (acn-diagnose --save-model) or a robot with hidden effects (its "
               "OUT.answer.json or its dataset: simulated, never shown)")


def _collect_flags() -> dict[str, Flag]:
    """CollectConfig's fields on the command line (``acn-collect``)."""
    from acn.sim.policies import POLICIES

    return {"source": Flag("robot the policy acts on: " + _MODEL_HELP + "; its effects are written beside the "
                           "dataset (OUT.answer.json), never into it", metavar="MODEL"),
            "target": Flag("second robot driven with the same actions (omit to record the source alone): "
                           + _MODEL_HELP, metavar="MODEL"),
            "policy": Flag("built-in policy", choices=list(POLICIES)),
            "episodes": Flag("episodes to record", positive_int),
            "seconds": Flag("episode length limit, s", seconds),
            "seed": Flag("initial states and random policies", nonneg_int)}


def collect_parser() -> argparse.ArgumentParser:
    from acn.sim.backends import SimConfig

    p = _Parser(
        prog="acn-collect",
        description="Run the A1 in a source simulator (and, paired, in a target simulator from the "
        "same initial state with the same actions) and write a LeRobot v3.0 dataset. Ctrl-C keeps the finished "
        "episodes as a dataset in a new --out; over an existing dataset (--overwrite) it leaves that dataset as it was.",
    )
    add_flags(p, _collect_defaults(), _collect_flags())
    p.add_argument("--out", required=True, type=_out_path, help="dataset directory to create")
    p.add_argument("--overwrite", action="store_true", help="replace --out if it is a dataset this toolkit wrote (nothing else is ever replaced)")
    p.add_argument("--workers", type=positive_int, default=1, help="processes on this machine")
    p.add_argument("--control-hz", type=positive_int, default=50, help="control rate, Hz (one action per step)")
    p.add_argument("--physics-hz", type=positive_int, default=None,
                   help="physics rate (default: the multiple of --control-hz nearest 1 kHz)")
    add_flags(p, SimConfig(), _sim_flags())
    p.add_argument("--corrector", type=Path, default=None,
                   help="frozen corrector directory (acn-fit output) applied to the target's actions")
    p.add_argument("--hidden-effect", action="append", default=[], metavar="NAME[:param=value,...]|random",
                   help="apply a physical effect to the source (the measured robot) at a realistic magnitude "
                   "(random: a random catalogue effect); the answer goes to OUT.answer.json, never into the "
                   "dataset; repeat for several effects")
    _add_ray_arguments(p, "the episodes (one Ray task each, written in episode order)")
    p.add_argument("--shards", type=positive_int, default=1, metavar="K",
                   help="with --ray: K writers in parallel (contiguous episode ranges), merged into --out")
    return p


def collect_config_from_args(args: argparse.Namespace):
    from acn.sim.backends import SimConfig
    from acn.sim.backends.base import physics_hz_for

    from acn.sim.hidden import draw_hidden, load_model

    physics_hz = physics_hz_for(args.control_hz, args.physics_hz)
    source = load_model(args.source)
    target = load_model(args.target) if args.target is not None else None
    for model, flag in ((source, "--source"), (target, "--target")):
        if model is not None and model.corrector:
            raise UserError(f"{flag} carries a corrector ({model.corrector}); give --corrector for the target instead")
    if args.corrector is not None and target is not None:
        from acn.corrector.card import TargetDescription
        from acn.corrector.corrector import load_for_target

        load_for_target(args.corrector, TargetDescription(target.backend, args.action_mode, args.control_hz,
                                                          effects=tuple(e.to_json() for e in target.effects)))
    sim = config_from_args(args, SimConfig(), _sim_flags(), physics_dt=1.0 / physics_hz,
                           substeps=physics_hz // args.control_hz)
    return config_from_args(args, _collect_defaults(), _collect_flags(), sim=sim, source=source.backend,
                            target=target.backend if target is not None else None,
                            corrector=str(args.corrector) if args.corrector else None,
                            hidden_effects=draw_hidden(args.hidden_effect, args.seed, sim, source.effects),
                            target_effects=list(target.effects) if target is not None else [])


def collect_main(argv: list[str] | None = None) -> int:
    args = collect_parser().parse_args(argv)

    def body() -> int:
        from acn.datasets.record import record
        from acn.datasets.stream import Interrupted
        from acn.datasets.schema import DATASET
        from acn.sim.hidden import ANSWER, answer_path

        check_output(args.out, DATASET, overwrite=args.overwrite, inputs=[args.corrector])
        check_input_dir(args.corrector, "corrector directory")
        cfg = collect_config_from_args(args)
        if cfg.hidden_effects:
            check_output(answer_path(args.out), ANSWER, flag="the answer beside --out")
        from acn.datasets.schema import least_bytes

        check_space(args.out, least_bytes(cfg.episodes * cfg.steps_per_episode, cfg.paired), "collection")
        ray = _ray_config(args)
        if ray is None and args.shards > 1:
            raise UserError("--shards needs --ray (the shards are written by Ray tasks)")
        if ray is not None and args.workers > 1:
            raise UserError("--workers sets this machine's processes; with --ray, Ray places the work "
                            "(--ray-cpus for a local instance)")
        counts: dict[str, int] = {}

        def progress(ep) -> None:
            counts[ep.end] = counts.get(ep.end, 0) + 1
            print(f"episode {sum(counts.values())}/{cfg.episodes}: {len(ep)} steps, {ep.end}", file=sys.stderr)

        try:
            from acn.corrector.corrector import Corrector  # the CLI loads; the collector applies

            path = record(cfg, args.out, workers=args.workers, overwrite=args.overwrite, on_episode=progress,
                          ray=ray, shards=args.shards, load_corrector=Corrector.load)
        except Interrupted as e:
            where = f"kept {e.episodes} finished episode(s) in {e.path}" if e.path else (
                f"the dataset in {args.out} is as it was" if args.out.exists() else "nothing was written")
            print(f"acn-collect: interrupted; {where}", file=sys.stderr)
            return EXIT_INTERRUPTED
        ends = ", ".join(f"{v} {k}" for k, v in sorted(counts.items()))
        print(f"wrote {sum(counts.values())} episode(s) ({ends}) to {path}")
        if cfg.hidden_effects:
            from acn.sim.hidden import answer_path

            print(f"the {cfg.source} robot's effects (hidden) are in {answer_path(path)}")
        print(f"open it: LeRobotDataset('acn/{path.name}', root='{path}')  (set HF_HUB_OFFLINE=1)")
        return 0

    return _run("acn-collect", body)


# ----------------------------------------------------------------------------- acn-fit
def _fit_flags() -> dict[str, Flag]:
    """FitConfig's fields on the command line (``acn-fit``)."""
    from acn.corrector.acn import VARIANTS

    return {
        "variant": Flag("inverse: regress Gauss-Newton labels delta_a* from same-state re-simulations (default); "
                        "paper: learned Jacobian (the paper's, degenerate); mujoco-jacobian: J from the target",
                        choices=VARIANTS),
        "epochs": Flag("default: 30 (paper), 60 (inverse)", positive_int),
        "batch_size": Flag("default: 256 (paper), 64 (inverse)", positive_int),
        "lr": Flag("Adam learning rate", positive_float),
        "lr_schedule": Flag("default: constant (paper), cosine (inverse)", choices=("constant", "cosine")),
        "lambda_l1": Flag("weight of |delta_a|_1", nonneg_float),
        "hidden": Flag("default: 256 (paper), 512 (inverse)", positive_int),
        "layers": Flag("hidden layers per network", positive_int),
        "filter_percentile": Flag("keep rows whose source-target gap is below this percentile (100: keep all; "
                                  "default: 70 for paper and mujoco-jacobian, 100 for inverse)", positive_float),
        "val_fraction": Flag("of episodes", positive_float),
        "seed": Flag("initialisation, batches and the validation split", nonneg_int),
        "device": Flag("cpu or cuda"),
        "precision": Flag("matmul precision in training (auto: bf16 where the hardware has it natively)",
                          choices=("auto", "bf16", "fp32")),
        "jacobian_eps": Flag("finite-difference step on actions (mujoco-jacobian)", positive_float),
        "eval_episodes": Flag("closed-loop evaluation episodes from held-out initial states (0: skip)", nonneg_int),
        "eval_seconds": Flag("closed-loop evaluation episode length, s", seconds),
        "oracles": Flag("run the same-state and tracking oracles beside the corrector in the closed-loop evaluation"),
        "label_iterations": Flag("inverse: Gauss-Newton steps with a finite-difference Jacobian per label", positive_int),
        "label_broyden": Flag("inverse: further quasi-Newton (Broyden) steps per label", nonneg_int),
        "label_damping": Flag("inverse: Levenberg-Marquardt ridge, relative to the mean diagonal of J^T J", nonneg_float),
        "jacobian_weight": Flag("inverse: add this times the paper's fit term under the target's true J", nonneg_float),
        "label_state_weight": Flag("inverse: add this times the label error seen through the target's true J",
                                   nonneg_float),
        "oracle_iterations": Flag("Gauss-Newton steps of the oracles (closed loop and the held-out one-step reference)",
                                  positive_int),
        "rounds": Flag("inverse: closed-loop rounds (collect with the corrector, label the visited states, refit; "
                       "default 4)", nonneg_int),
        "round_episodes": Flag("inverse: episodes collected per round", positive_int),
        "round_seconds": Flag("inverse: length of a round's episodes, s", seconds),
        "round_epochs": Flag("inverse: epochs of each round's refit", positive_int),
        "label_fd_eps": Flag("inverse: finite-difference step on actions in the label solve (action units)",
                             positive_float),
        "sensor_inputs": Flag("F also reads the contact and IMU readings (default: on for paper and mujoco-jacobian)"),
        "threads": Flag("re-simulation threads", positive_int),
        "train_threads": Flag("torch threads in training on a CPU (0: torch's default, all cores; default 1: more "
                              "threads are faster only on an otherwise idle machine)", nonneg_int),
        "cuda_graph": Flag("with --device cuda: replay each full-batch training step as one CUDA graph (default on)"),
        "calibrate": Flag("scale F by 0, 0.25, ... 1, whichever leaves the least one-step error on half of the held-out "
                          "episodes (default: on for inverse)"),
    }


def fit_parser() -> argparse.ArgumentParser:
    from acn.corrector.config import FitConfig

    d = FitConfig()
    p = _Parser(prog="acn-fit", description="Fit the Action Correction Network from paired datasets written by "
                "acn-collect; write a frozen corrector (model.safetensors + config.json + metrics.json).")
    p.add_argument("datasets", nargs="+", type=Path, help="paired dataset directories")
    p.add_argument("--out", required=True, type=_out_path, help="model directory to create")
    p.add_argument("--overwrite", action="store_true", help="replace --out if it is a corrector this toolkit wrote (nothing else is ever replaced)")
    p.add_argument("--model", default=None, metavar="MODEL",
                   help="fit on top of this model of the target simulator (e.g. acn-diagnose --save-model's, or a "
                   "robot with hidden effects: its answer file or dataset, never shown): its effects are written "
                   "into the target, and the network learns what they leave (inverse only)")
    add_flags(p, d, _fit_flags())
    _add_ray_arguments(p, "the re-simulation batches (Jacobians, labels; rows in chunks)")
    return p


def fit_main(argv: list[str] | None = None) -> int:
    args = fit_parser().parse_args(argv)

    def body() -> int:
        from acn.corrector.corrector import CORRECTOR
        from acn.corrector.config import FitConfig
        from acn.corrector.fit import fit, save

        check_output(args.out, CORRECTOR, overwrite=args.overwrite, inputs=[*args.datasets, args.model])
        for d in args.datasets:
            check_input_dir(d, "dataset directory")
        _check_device(args.device)
        cfg = config_from_args(args, FitConfig(), _fit_flags())
        target = None
        if args.model is not None:
            from acn.sim.hidden import load_model

            target = load_model(args.model)
        with _ray_executor(args, "acn-fit"):
            model, metrics = fit(args.datasets, cfg, log=lambda line: print(line, file=sys.stderr), target=target)
        path = save(model, metrics, args.out, overwrite=args.overwrite)
        simulator = model.card.training_data.target.simulator
        physics = shlex.join(["acn-diagnose", str(args.datasets[0]), "--side", "source", "--model",
                              str(args.model or simulator),
                              "--auto", "--closed-loop", "4", "--corrector", str(path)]) \
            if len(args.datasets) == 1 else None
        _print_fit_summary(metrics, path, physics)
        return 0

    return _run("acn-fit", body)


def _print_fit_summary(m: dict, path: Path, physics: str | None) -> None:
    """The fit's metrics as text; ``physics``: the acn-diagnose command that answers the same gap
    with physical effects, suggested where the corrector does not narrow it."""
    v = m["val_objective"]
    print(f"validation objective {v['loss']:.4f} (fit {v['fit']:.4f}; no correction {v['fit_no_correction']:.4f})")
    if "val_objective_true_jacobian" in m:
        t = m["val_objective_true_jacobian"]
        print(f"validation fit under the target's true Jacobian {t['fit']:.4f} (no correction {t['fit_no_correction']:.4f})")
    if "one_step" in m:
        o = m["one_step"]
        print(f"one-step same-state error on held-out rows {o['error_no_correction']:.4f} -> corrected "
              f"{o['error_corrected']:.4f} (same-state oracle {o['error_oracle']:.4f}): "
              f"share_of_oracle={o['share_of_oracle']:.3f}")
    if "closed_loop" in m:
        from acn.corrector.evaluate import format_closed_loop

        c = m["closed_loop"]
        print(format_closed_loop(c))
        print(f"closed-loop divergence {c['divergence_uncorrected']:.4f} -> {c['divergence_corrected']:.4f}: "
              f"divergence_reduction={c['divergence_reduction']:.3f}")
        print(f"eps_transfer {c['eps_transfer_uncorrected']:.3f} -> {c['eps_transfer']:.3f}; "
              f"delta_corr {c['delta_corr']:.3f}")
        print(f"verdict: {c['verdict']}")
        if physics and c["runs"]["corrected"]["versus"]["change"]["reward_gap"] != "narrower":
            print(f"the same gap answered with physics, beside this corrector: {physics}")
    print(f"train_samples_per_s={m['train_samples_per_s']:.0f}")
    print(f"wrote the frozen corrector to {path} (load: acn.corrector.Corrector.load('{path}'))")


# ----------------------------------------------------------------------------- acn-ppo
def _ppo_flags() -> dict[str, Flag]:
    """PPOConfig's fields on the command line (``acn-ppo``), every one of them."""
    from acn.corrector.acn import VARIANTS
    from acn.sim.backends import ACTION_MODES
    from acn.sim.policies import POLICIES

    return {
        # run
        "timesteps": Flag("train for this many control steps in all; fewer than one rollout (n_steps x envs, "
                          "2048 by default) is a quick trial: those steps, a 2-epoch refit on two 2 s paired episodes "
                          "and a final evaluation of 2 episodes of 2 s (options you set are kept)", positive_int),
        "seed": Flag("PPO, environments and evaluation starts", nonneg_int),
        "n_envs": Flag("training environment processes", positive_int, option="--envs"),
        "torch_threads": Flag("torch threads of PPO's own process (the simulators run in the others)", positive_int),
        "checkpoint_every": Flag("timesteps between resumable checkpoints", positive_int),
        # task
        "train": Flag("the model the policy is trained in: " + _MODEL_HELP + " (--eval: the policy's own unless "
                      "given)", _model_spec, metavar="MODEL"),
        "robot": Flag("where the policy is deployed and the corrector applied: " + _MODEL_HELP, _model_spec,
                      metavar="MODEL"),
        "seconds": Flag("episode time limit, s (--eval: default the policy's own)", seconds),
        "base_policy": Flag("built-in gait the policy is a residual on", choices=list(POLICIES)),
        "residual_scale": Flag("rad of joint target per unit of the policy's action", positive_float),
        "train_reward_weights": Flag("PPO's weights of the paper's four reward terms (velocity, torque, height, "
                                     "joint speed); the evaluations report the paper's", metavar="W1,W2,W3,W4"),
        "alive_bonus": Flag("training reward per step that does not end in a fall", nonneg_float),
        "action_mode": Flag("what the robot's actions are", choices=ACTION_MODES),
        "control_hz": Flag("control rate, Hz", positive_int),
        "physics_hz": Flag("physics rate, Hz", positive_int),
        "kp": Flag("PD stiffness, N m/rad", positive_float),
        "kd": Flag("PD damping, N m s/rad", positive_float),
        "torque_limit": Flag("N m, every joint", positive_float),
        # PPO (stable-baselines3)
        "learning_rate": Flag("Adam learning rate", positive_float),
        "n_steps": Flag("steps per environment per rollout", positive_int),
        "batch_size": Flag("minibatch size", positive_int),
        "n_epochs": Flag("passes over each rollout", positive_int),
        "gamma": Flag("discount", positive_float),
        "gae_lambda": Flag("GAE lambda", nonneg_float),
        "clip_range": Flag("PPO's policy clip", positive_float),
        "ent_coef": Flag("entropy bonus weight", nonneg_float),
        "vf_coef": Flag("value loss weight", nonneg_float),
        "max_grad_norm": Flag("gradient clip", positive_float),
        "target_kl": Flag("stop a rollout's epochs at this KL (0: never)", nonneg_float),
        "hidden": Flag("hidden layer widths of the actor and of the critic", metavar="W,W"),
        "log_std_init": Flag("initial log standard deviation of the policy's actions (exploration)"),
        "norm_reward": Flag("normalise PPO's rewards by their running scale"),
        "clip_obs": Flag("clip normalised observations at this many standard deviations", positive_float),
        # Algorithm 2
        "refit_every": Flag("episodes between corrector refits; 0: never refit", nonneg_int),
        "eval_every": Flag("episodes between MuJoCo evaluations; 0: only the final one", nonneg_int),
        "eval_episodes": Flag("episodes per evaluation in training", nonneg_int),
        "final_eval_episodes": Flag("episodes of the final evaluation, per simulator", positive_int),
        "eval_seconds": Flag("evaluation episode length, s", seconds),
        "refit_episodes": Flag("paired PyBullet -> MuJoCo episodes collected per refit", positive_int),
        "refit_seconds": Flag("length of a refit's paired episodes, s", seconds),
        "refit_window": Flag("a refit fits on the latest this-many paired datasets", positive_int),
        "corrector_variant": Flag("acn-fit variant for refits", option="--variant", choices=VARIANTS),
        "fit_epochs": Flag("epochs of each refit", positive_int),
        "oracle_episodes": Flag("episodes of the same-state oracle bound in the final evaluation (slow; "
                                "--eval: 0 unless given)", nonneg_int),
    }


def ppo_parser() -> argparse.ArgumentParser:
    from acn.rl.ppo import PPOConfig

    d = PPOConfig()
    p = _Parser(prog="acn-ppo", description="Train a walking policy with PPO in --train (PyBullet by default; a "
                "residual on the trot) and evaluate it on --robot (MuJoCo by default) with and without the frozen "
                "corrector pi_corr(s) = pi(s) + F(s, pi(s)), which is applied on the robot (the TARGET) only; every "
                "--refit-every episodes F is refitted on paired data of the current policy (the paper's Algorithm 2; "
                "--refit-every 0 without --corrector: plain PPO). Or, with --eval, reload and evaluate on --robot.")
    mode = p.add_mutually_exclusive_group()
    flags = _ppo_flags()
    add_flags(mode, d, {"timesteps": flags.pop("timesteps")})  # training, or --eval
    mode.add_argument("--eval", type=Path, metavar="POLICY", help="evaluate a saved policy directory (DIR/policy)")
    p.add_argument("--out", type=_out_path, help="run directory to create (training); --eval: a JSON file to write")
    p.add_argument("--corrector", type=Path, default=None,
                   help="frozen corrector directory (acn-fit output); training: F until the first refit")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its checkpoint")
    p.add_argument("--overwrite", action="store_true", help="replace --out if it is a PPO run this toolkit wrote, once the new run is complete")
    p.add_argument("--episodes", type=positive_int, default=20, help="--eval: episodes per simulator")
    add_flags(p, d, flags)
    return p


def ppo_main(argv: list[str] | None = None) -> int:
    args = ppo_parser().parse_args(argv)

    def body() -> int:
        if args.eval is not None:
            return _ppo_eval(args)
        from tqdm import tqdm

        from acn.rl.ppo import PPO_RUN, PPOConfig, Trainer, format_table

        if args.out is None:
            raise UserError("training needs --out DIR (or give --eval POLICY)")
        if not args.resume:
            check_output(args.out, PPO_RUN, overwrite=args.overwrite, inputs=[args.corrector, args.train, args.robot])
        elif args.overwrite:
            raise UserError("--resume continues the run in --out; --overwrite would replace it: give one")
        check_input_dir(args.corrector, "corrector directory")
        flags = _ppo_flags()
        cfg = config_from_args(args, PPOConfig(), flags)
        cfg = cfg.sized_for_run(keep=given_fields(args, ppo_parser(), flags))
        trainer = Trainer(cfg, args.out, corrector_dir=args.corrector, resume=args.resume, overwrite=args.overwrite,
                          log=lambda line: tqdm.write(line, file=sys.stderr))
        m = trainer.run()
        t = m["training"]
        print(format_table(m["final_evaluation"]))
        recent = t["train_return_last_100_episodes"]
        print(f"trained {t['timesteps']} steps ({t['episodes']} episodes) in {t['wall_seconds_this_session']:.0f} s; "
              + (f"mean training return of the last 100 episodes {recent:.1f}" if recent is not None
                 else "no training episode finished"))
        if m["corrector_frozen"] is not None:
            print(f"corrector frozen (tensor sha256 unchanged while in use): {m['corrector_frozen']}")
        out = args.out.absolute()
        corrector = out / "corrector" if (out / "corrector").is_dir() else None
        print(f"wrote {out / 'policy'} (safetensors + JSON), {f'{corrector}, ' if corrector else ''}"
              f"{out / 'metrics.json'}, {out / 'curves.png'}; {out / 'checkpoint'} resumes training (--resume)")
        print(f"evaluate again: acn-ppo --eval {out / 'policy'} --robot {shlex.quote(trainer.cfg.robot)}"
              + (f" --corrector {corrector}" if corrector else ""))
        return 0

    return _run("acn-ppo", body)


def _model_spec(text: str) -> str:
    """A model on the command line, kept as given: a backend name, or a file or directory as an
    absolute path (a run records it and resumes from another directory)."""
    from acn.sim.backends import BACKENDS

    return text if text in BACKENDS else os.path.abspath(text)


def _ppo_eval(args: argparse.Namespace) -> int:
    allowed = ("eval", "robot", "train", "corrector", "episodes", "seconds", "seed", "oracle_episodes", "out")
    settings = given(args, ppo_parser()) - set(allowed)
    if settings:
        raise UserError(f"--eval takes {', '.join('--' + a.replace('_', '-') for a in allowed[1:])} only, "
                        f"not --{sorted(settings)[0].replace('_', '-')}")
    chosen = given(args, ppo_parser())
    limit = args.seconds if "seconds" in chosen else None
    oracle_episodes = args.oracle_episodes if "oracle_episodes" in chosen else 0
    check_input_dir(args.eval, "policy directory")
    check_input_dir(args.corrector, "corrector directory")
    from acn.rl.ppo import EVAL_FORMAT, PPO_EVAL, evaluate_saved, format_table, write_json

    check_output(args.out, PPO_EVAL, inputs=[args.eval, args.corrector])
    ev = evaluate_saved(args.eval, args.corrector, args.episodes, limit, args.seed, oracle_episodes, robot=args.robot,
                        sim=args.train if "train" in chosen else None)
    print(format_table(ev))
    if args.out is not None:
        write_json(args.out, {"format": EVAL_FORMAT, **ev})
        print(f"wrote {args.out}")
    return 0


# ----------------------------------------------------------------------------- acn-view
def _view_flags() -> dict[str, Flag]:
    """ViewConfig's fields on the command line (``acn-view``)."""
    return {
        "dataset": Flag("dataset directory written by acn-collect (paired or not)", option="dataset"),
        "episodes": Flag("episodes to show (default: all)", metavar="0,3,..."),
        "corrector": Flag("frozen corrector directory (acn-fit output): also show the target re-simulated with it"),
        "model": Flag("mujoco, pybullet or a model JSON (acn-diagnose --save-model): measured against the model's "
                      "one-step prediction, residuals per joint, the error as the model's effects are added",
                      metavar="MODEL.json"),
        "diagnosis": Flag("acn-diagnose --json result: its verdict, ranking and where-summary as text (with --model)",
                          metavar="FILE.json"),
        "save": Flag("write a .rrd instead of opening a viewer", _out_path, metavar="OUT.rrd"),
        "mesh_cell": Flag("m, the grid the A1's meshes are simplified on (0: the original meshes)", nonneg_float),
    }


def view_parser() -> argparse.ArgumentParser:
    from acn.viz.view import ViewConfig

    p = _Parser(prog="acn-view", description="Show a dataset in the Rerun viewer: the A1 in 3D per trajectory, "
                "joint angles, divergence per channel group and stance/swing, one tab per episode. Opens the "
                "viewer when there is a display and no --save; otherwise writes a .rrd.")
    add_flags(p, ViewConfig, _view_flags())
    return p


def view_main(argv: list[str] | None = None) -> int:
    args = view_parser().parse_args(argv)

    def body() -> int:
        from acn.viz.view import RECORDING, ViewConfig, view

        check_input_dir(args.dataset, "dataset directory")
        check_output(args.save, RECORDING, flag="--save", inputs=[args.dataset, args.corrector, args.model,
                                                                 args.diagnosis])
        path = view(config_from_args(args, ViewConfig, _view_flags()))
        if path is not None:
            print(f"wrote {path}; open it with:")
            print(f"rerun {path}")
        return 0

    return _run("acn-view", body)


# ----------------------------------------------------------------------------- acn-import
def _import_flags() -> dict[str, Flag]:
    """ImportConfig's fields on the command line (``acn-import``)."""
    from acn.sim.backends import ACTION_MODES, IMU_ACC_KINDS

    return {
        "control_hz": Flag("control rate the log was recorded at", positive_int),
        "kp": Flag("joint PD stiffness the robot ran with, N m/rad" + _GAINS_HELP + "; a log with action_kp.* columns "
                   "(a hybrid command, with action_kd.*, action_vel.*, action_torque.*) sends its own per row",
                   _joint_gains(0, True)),
        "kd": Flag("joint PD damping, N m s/rad" + _GAINS_HELP, _joint_gains(0, True)),
        "torque_limit": Flag("N m, every joint", positive_float),
        "action_mode": Flag("what the log's actions are: joint targets (position) or torques", choices=ACTION_MODES),
        "physics_hz": Flag("physics rate a model simulates it at (default: the multiple of --control-hz nearest 1 kHz)",
                           positive_int),
        "dt_tolerance": Flag("a time step may differ from the control period by this fraction before the episode is "
                             "split", positive_float),
        "linvel_frame": Flag("the frame the log's base_linvel_* are in (world: rotated into the body frame the schema "
                             "uses)", choices=("body", "world")),
        "angvel_frame": Flag("the same for base_angvel_*", choices=("body", "world")),
        "leg_order": Flag("the order of the legs in the log's columns, if not the schema's FR,FL,RR,RL "
                          "(legged_gym and Isaac Gym: FL,FR,RL,RR)", _leg_order, metavar="FL,FR,RL,RR"),
        "shift_actions": Flag("pair each state with the command this many rows later in its episode (1: the log writes "
                              "the last action sent with the new observation, as the action_row check finds)",
                              number(int, -1e9, inclusive=True), metavar="ROWS"),
        "imu_acc": Flag("what the logged accelerometer reads: the mean specific force over the control step before the "
                        "row (mean, the schema's) or at the row's instant (instant: a sensor sampled then, as MuJoCo's "
                        "accelerometer); default: not stated, acn-diagnose judges it from the log",
                        choices=IMU_ACC_KINDS),
    }


def import_parser() -> argparse.ArgumentParser:
    from acn.measurements.importer import ImportConfig

    p = _Parser(prog="acn-import", description="Turn a robot log (CSV, Parquet, JSON lines, HDF5 or .npz, one row per control "
                "step) into a measurement dataset (LeRobot v3.0, the schema of acn-collect) that acn-diagnose reads.")
    p.add_argument("log", type=Path, nargs="+", help="the log file (.csv, .parquet, .jsonl, .h5 or .npz); several (one per run, "
                   "the same columns): read one after the other, each file's episodes apart")
    p.add_argument("--out", required=True, type=_out_path, help="dataset directory to create")
    add_flags(p, ImportConfig, _import_flags())
    p.add_argument("--map", type=Path, default=None, dest="map_file", metavar="MAP.json",
                   help='rename and scale columns: {"FR_hip_pos": "q0", "FR_thigh_pos": {"column": "q1_deg", '
                   '"scale": 0.0174533, "offset": 0.0}}; foot forces as contact flags: '
                   '{"FR_contact": {"column": "force0", "threshold": 20}}')
    p.add_argument("--overwrite", action="store_true", help="replace --out if it is a dataset this toolkit wrote (nothing else is ever replaced)")
    return p


def _estimated(missing: list[str]) -> str:
    """How ``fill_derived`` estimates the missing dynamic channels, in words ("" if none is missing)."""
    from acn.sim.state import GROUPS

    lacks = {g for g, names in GROUPS.items() if set(names) & set(missing)}
    odometry = "base_pos" in lacks
    how = {"joint_vel": "joint_vel from the joint angles", "base_angvel": "base_angvel from the orientation",
           "base_pos": "base_pos by leg odometry",
           "base_linvel": f"base_linvel {'by leg odometry' if odometry else 'from the positions'}"}
    return ", ".join(text for g, text in how.items() if g in lacks)


def import_main(argv: list[str] | None = None) -> int:
    args = import_parser().parse_args(argv)

    def body() -> int:
        from acn.measurements import naming
        from acn.measurements.importer import ImportConfig, import_log
        from acn.datasets.schema import DATASET
        from acn.sim.backends.base import PHYSICS_HZ, physics_hz_for

        check_output(args.out, DATASET, overwrite=args.overwrite, inputs=[*args.log, args.map_file])
        cfg = config_from_args(args, ImportConfig, _import_flags())
        path, r = import_log(args.log, args.out, cfg, args.map_file, overwrite=args.overwrite)
        print(f"read {r.rows} rows: {r.transitions} transitions in {r.episodes} episode(s); cut {r.cut_nonfinite} "
              f"row(s) with non-finite values, split at {r.time_breaks} wrong time step(s), dropped "
              f"{r.dropped_short} one-row segment(s)")
        if r.cut_implausible:
            print(f"cut {r.cut_implausible} row(s) with values no A1 can produce (first: {r.implausible_example}; "
                  "the bounds: acn.sim.plausible)")
        if r.malformed:
            lines = ", ".join(r.malformed[:5]) + (", ..." if len(r.malformed) > 5 else "")
            print(f"set aside {len(r.malformed)} row(s) with another number of fields than the header "
                  f"(line(s) {lines}): a row cut off where the logger stopped, or garbled")
        if r.text_rows:
            print(f"{r.text_rows} row(s) with text among the numbers (first: {r.text_example}; a header written again, "
                  "a mark for a lost reading): read as missing values")
        if r.hybrid:
            print(f"a hybrid command ({', '.join(r.hybrid)}): stored with the actions (action.hybrid: kp, kd, "
                  "velocity target and feedforward torque), which the model's PD runs as sent (--kp, --kd for a kind of gain "
                  "the log does not send)")
        if args.physics_hz is None and (hz := physics_hz_for(args.control_hz)) != PHYSICS_HZ:
            print(f"the model simulates it at {hz} Hz, the multiple of {args.control_hz} Hz nearest {PHYSICS_HZ} Hz "
                  "(--physics-hz sets it)")
        hint = r.tolerance_hint(args.dt_tolerance)
        if hint:
            print(hint)
        if r.partial_effort:
            print(f"efforts of {len(r.partial_effort)} of 12 joints ({', '.join(r.partial_effort)}): not stored; "
                  "applied torques are all 12 joints' or none")
        if r.suggested_map:
            print(f"columns named like channels the log lacks, as a --map file (check units and leg order"
                  f"{naming.arrays_read(r.suggested_map)}; import again with it): {json.dumps(r.suggested_map)}")
        for note in r.map_notes:
            print(note)
        if r.unused:
            print(f"columns no channel reads ({len(r.unused)}): {', '.join(r.unused[:12])}"
                  f"{', ...' if len(r.unused) > 12 else ''} (--map names a column for a channel)")
        if r.missing:
            print(f"not in the log (stored as NaN, not compared): {', '.join(r.missing)}")
            if _estimated(r.missing):
                print(f"a diagnosis starts its model from estimates of them: {_estimated(r.missing)}")
        for f in r.findings:
            print(f"check ({f.check}): {f.message}")
        if hint := r.quaternion_hint():
            print(hint)
        if r.findings:
            print(f"{len(r.findings)} consistency finding(s): a model compared with these data would explain them as "
                  "physics; fix the map and import again, or diagnose knowing them")
        print(f"wrote {path}; diagnose it: acn-diagnose {path} --model mujoco")
        return 0

    return _run("acn-import", body)


# ----------------------------------------------------------------------------- acn-diagnose
def _seconds_or_none(text: str) -> float | None:
    """Seconds >= 0, where 0 means None (``--step-seconds``: one control step; ``--auto-seconds``: no bound)."""
    value = nonneg_float(text)
    return value if value > 0 else None


def _diagnose_flags() -> dict[str, Flag]:
    """DiagnoseConfig's fields on the command line (``acn-diagnose``)."""
    from acn.diagnosis.fitting import GRANULARITIES

    return {
        "auto_alternatives": Flag("with --auto: also start from the next N candidates and keep a chain that predicts "
                                  "clearly better (one effect can stand in for two)", nonneg_int, metavar="N"),
        "auto_max": Flag("with --auto: add at most N effects", positive_int, metavar="N"),
        "auto_seconds": Flag("with --auto: start no new step of the search after S s of the diagnosis (the step "
                             "running ends, then the halves check), and say what was left untried; 0: no bound",
                             _seconds_or_none, metavar="S"),
        "finest": Flag("the finest granularity an added per-joint effect may get: one value for every joint, one per "
                       "joint type, leg or joint (a finer one is kept where it predicts significantly better; coarser "
                       "is quicker)", choices=GRANULARITIES),
        "horizons": Flag("open-loop horizons, in diagnosis steps (--step-seconds each)",
                         lambda text: tuple(sorted(set(comma_list(positive_int)(text)))), metavar="1,5,25"),
        "step_seconds": Flag("one diagnosis step, s of control steps (rounded, at least one; 0: one control step): at "
                             "high control rates one control step moves the robot less than its sensor noise",
                             _seconds_or_none),
        "candidates": Flag("comma-separated candidates (default: the whole catalogue)", comma_list(str),
                           option="--effects", metavar="EFFECT,..."),
        "seed": Flag("the held-out split and random starts", nonneg_int),
    }


def diagnose_parser() -> argparse.ArgumentParser:
    from acn.diagnosis import DiagnoseConfig

    p = _Parser(prog="acn-diagnose", description="Compare a model with measurements, show where it fails, rank "
                "which physical effect is missing, add it and watch the error fall.")
    p.add_argument("measured", nargs="*", type=Path,
                   help="measurement dataset(s) of one robot (acn-import or acn-collect), diagnosed together")
    p.add_argument("--model", default="mujoco", help=_MODEL_HELP + " (default: mujoco)")
    p.add_argument("--side", default="source", choices=("source", "target"), help="which side of a paired dataset")
    p.add_argument("--add", action="append", default=[], metavar="EFFECT", help="fit and add this effect (repeatable)")
    p.add_argument("--auto", action="store_true", help="repeat rank -> add while the error falls by more than the noise")
    add_flags(p, DiagnoseConfig(), _diagnose_flags())
    p.add_argument("--save-model", type=_out_path, default=None, metavar="FILE", help="write the updated model JSON")
    p.add_argument("--json", type=_out_path, default=None, metavar="FILE", help="write the machine-readable result")
    p.add_argument("--report", type=_out_path, default=None, metavar="FILE.html", help="write the HTML report")
    p.add_argument("--explain-corrector", type=Path, default=None, metavar="DIR",
                   help="explain a corrector from acn-fit: which effects its corrections look like")
    p.add_argument("--list-effects", action="store_true", help="print the catalogue of effects and exit")
    p.add_argument("--verbose", action="store_true", help="print the time of every stage as it ends")
    p.add_argument("--limits", action="store_true",
                   help="then the smallest size of each effect not named that this log would show: what it rules out")
    p.add_argument("--limits-per-joint", action="store_true",
                   help="--limits, and each per-joint effect also on one joint alone (a worn gearbox, a weak motor): "
                   "the size it shows at on the joint the log shows least")
    p.add_argument("--closed-loop", type=nonneg_int, default=0, metavar="N",
                   help="then re-run the measured robot (an acn-collect dataset) from N held-out initial states beside "
                   "the model as given, with --corrector and with the added effects: divergence, eps_transfer, falls")
    p.add_argument("--closed-loop-seconds", type=seconds, default=5.0, help="episode length, s")
    p.add_argument("--corrector", type=Path, default=None, metavar="DIR",
                   help="with --closed-loop: also run the model with this corrector (acn-fit output)")
    p.add_argument("--no-oracles", action="store_true", help="with --closed-loop: skip the oracle bounds")
    _add_ray_arguments(p, "the re-simulation batches (measured states, candidate fits; rows in chunks)")
    return p


def _check_diagnose_outputs(args: argparse.Namespace) -> None:
    """``--json``, ``--report`` and ``--save-model``: each a path of its own, checked before the run."""
    from acn.diagnosis.report import DIAGNOSIS_JSON, REPORT
    from acn.sim.backends import BACKENDS
    from acn.sim.effects.model import MODEL_FILE

    inputs = [*args.measured, args.corrector, args.explain_corrector]
    if args.model not in BACKENDS:
        inputs.append(args.model)
    named: dict[Path, str] = {}
    for flag, path, kind in (("--json", args.json, DIAGNOSIS_JSON), ("--report", args.report, REPORT),
                             ("--save-model", args.save_model, MODEL_FILE)):
        if check_output(path, kind, flag=flag, inputs=inputs) is None:
            continue
        key = Path(os.path.abspath(path))
        if key in named:
            raise UserError(f"{flag} and {named[key]} name the same file {path}; give each its own")
        named[key] = flag


def diagnose_main(argv: list[str] | None = None) -> int:
    args = diagnose_parser().parse_args(argv)

    def body() -> int:
        from acn.sim.effects import describe_catalogue, get_effect

        if args.list_effects:
            print(describe_catalogue())
            return 0
        if not args.measured:
            raise UserError("give the measurement dataset (or --list-effects)")
        from acn.measurements.data import load_measurement_sets
        from acn.diagnosis import ClosedLoop, DiagnoseConfig, Stages, run
        from acn.diagnosis.clock import StageClock
        from acn.diagnosis.report import DIAGNOSIS_JSON, REPORT, html_text, json_text, terminal
        from acn.outputs.writing import write_files
        from acn.sim.effects.model import MODEL_FILE
        from acn.sim.hidden import load_model

        cfg = config_from_args(args, DiagnoseConfig(), _diagnose_flags())
        for name in (*cfg.candidates, *args.add):
            get_effect(name)
        for measured in args.measured:
            check_input_dir(measured, "measurement dataset")
        _check_diagnose_outputs(args)
        if args.corrector is not None and not args.closed_loop:
            raise UserError("--corrector is run in closed loop: give --closed-loop N as well")
        limits = args.limits or args.limits_per_joint
        if limits and args.explain_corrector is not None:
            raise UserError("--limits and --explain-corrector are separate questions: ask one at a time")
        if args.closed_loop and args.explain_corrector is not None:
            raise UserError("--closed-loop and --explain-corrector are separate questions: ask one at a time")
        for corrector in (args.corrector, args.explain_corrector):
            check_input_dir(corrector, "corrector directory")
        model = load_model(args.model)
        cfg.validate()
        if args.closed_loop and len(args.measured) > 1:
            raise UserError("--closed-loop re-runs one measured robot's collection: give one dataset")
        closed_loop = ClosedLoop(args.measured[0], args.side, args.closed_loop, args.closed_loop_seconds, args.corrector,
                                 oracles=not args.no_oracles) if args.closed_loop else None
        stages = Stages(add=tuple(args.add), automatic=args.auto, explain_corrector=args.explain_corrector,
                        limits=limits, limits_per_joint=args.limits_per_joint, closed_loop=closed_loop)
        data = load_measurement_sets(args.measured, side=args.side)
        stages.check(data, model)  # refuse what cannot run before the diagnosis, not after
        from tqdm import tqdm

        with _ray_executor(args, "acn-diagnose"), tqdm(total=100, file=sys.stderr, bar_format="{l_bar}{bar}| {elapsed} {postfix}",
                                       disable=None) as bar:
            def say(message: str, fraction: float | None = None) -> None:
                bar.set_description_str(message)
                if fraction is not None:
                    bar.update(int(round(100 * fraction)) - bar.n)

            clock = StageClock(verbose=(lambda line: bar.write(f"  {line}")) if args.verbose else None)
            result = run(data, model, cfg, stages, progress=say, clock=clock)
        print(terminal(result))
        if args.verbose:
            print("stages: " + ", ".join(f"{name} {s:.1f} s" for name, s in result.stages.items())
                  + f"; total {result.seconds['total']:.1f} s")
        # The files of one diagnosis are written together: all of them, or (a full disk) none.
        files = [(path, text(), kind) for path, text, kind in (
            (args.json, lambda: json_text(result), DIAGNOSIS_JSON), (args.report, lambda: html_text(result), REPORT),
            (args.save_model, result.model.to_text, MODEL_FILE)) if path is not None]
        write_files(files)
        if args.json:
            print(f"wrote {args.json}")
        if args.report:
            print(f"wrote the report {args.report}")
        if args.save_model:
            print(f"wrote the model {args.save_model}"
                  + (" (as given: the effects added do not hold)" if result.model is not result.final.model else ""))
        return 0

    return _run("acn-diagnose", body)


# ----------------------------------------------------------------------------- acn-transfer
def _transfer_flags() -> dict[str, Flag]:
    """TransferConfig's fields on the command line (``acn-transfer``)."""
    return {
        "robot": Flag("where the policies must walk: " + _MODEL_HELP, _model_spec, metavar="MODEL"),
        "sim": Flag("where a policy is trained without measurements: pybullet, mujoco or a model JSON file",
                    _model_spec, metavar="MODEL"),
        "hidden_effects": Flag("make the robot: --robot mujoco with this effect, sealed in OUT/robot.answer.json and "
                               "never printed (acn-collect's syntax: NAME, NAME:param=value,... or random); repeat for "
                               "several", option="--hidden-effect", metavar="EFFECT"),
        "timesteps": Flag("PPO control steps per policy (pi_sim, pi_M, pi_robot alike)", positive_int),
        "episodes": Flag("evaluation episodes per policy, the same held-out starts for all", positive_int),
        "seconds": Flag("episode length of training and evaluation, s", seconds),
        "measure_episodes": Flag("measured episodes per motion (the excitation, the trot)", positive_int),
        "measure_seconds": Flag("their length, s", seconds),
        "envs": Flag("PPO environment processes per training", positive_int),
        "seed": Flag("measurements, PPO and the evaluation starts", nonneg_int),
        "effects": Flag("the diagnosis' candidate effects (default: the whole catalogue)", comma_list(str),
                        metavar="EFFECT,..."),
        "finest": Flag("acn-diagnose --finest: the finest granularity of an added per-joint effect (shared: a third "
                       "of the time of the full search; joint: the full search)", metavar="GRANULARITY"),
        "auto_alternatives": Flag("acn-diagnose --auto-alternatives: other chains of effects to try", nonneg_int),
        "auto_seconds": Flag("acn-diagnose --auto-seconds: the search's bound, s (0: none, the same physics on any "
                             "machine)", nonneg_float, metavar="S"),
        "fit_epochs": Flag("acn-fit --epochs for the correctors (0: acn-fit's default)", nonneg_int),
        "fit_rounds": Flag("acn-fit --rounds for the correctors (-1: acn-fit's default)",
                           number(int, -1, inclusive=True)),
    }


def transfer_parser() -> argparse.ArgumentParser:
    from acn.transfer import TransferConfig

    p = _Parser(prog="acn-transfer", description="Train where, correct how, and how well does the policy then walk on "
                "the robot? Measures the robot (acn-collect), identifies its physics (acn-diagnose --auto: model M), "
                "fits the corrector F (acn-fit), trains pi_sim in --sim, pi_M in M and pi_robot on the robot "
                "(acn-ppo), and evaluates pi_sim, pi_sim + F, pi_M, pi_M + F_M and pi_robot on the robot from the "
                "same held-out starts: the paper's Table 1 layout, the share of the gap each route closes, a "
                "verdict, OUT/transfer.json and OUT/transfer.png.")
    p.add_argument("--out", required=True, type=_out_path, help="study directory to create")
    p.add_argument("--overwrite", action="store_true",
                   help="remove --out first if it is a study this toolkit wrote (nothing else is ever removed)")
    flags = _transfer_flags()
    hidden = flags.pop("hidden_effects")
    add_flags(p, TransferConfig(), flags)
    p.add_argument(hidden.option, action="append", default=[], metavar=hidden.metavar, help=hidden.help)
    _add_ray_arguments(p, "the independent trainings (pi_sim, pi_M, pi_robot and F_M) as Ray tasks")
    return p


def transfer_main(argv: list[str] | None = None) -> int:
    args = transfer_parser().parse_args(argv)

    def body() -> int:
        from acn.transfer import TransferConfig, run_study
        from acn.transfer.study import TRANSFER_STUDY

        cfg = config_from_args(args, TransferConfig(), _transfer_flags(), hidden_effects=tuple(args.hidden_effect))
        check_output(args.out, TRANSFER_STUDY, overwrite=args.overwrite, inputs=[args.robot, args.sim])
        cfg.validate()
        ray = _ray_config(args)
        result = run_study(cfg, args.out, ray=ray, overwrite=args.overwrite)
        out = args.out.absolute()
        print()
        print(result["table_text"])
        print()
        print(result["table"]["verdict"])
        for line in result["table"]["by_term"]:
            print(f"  {line}")
        print(f"M, the physics the diagnosis identified: {result['model']['described']}")
        print("stages: " + ", ".join(f"{k} {v / 60:.1f} min" for k, v in result["stages_seconds"].items())
              + f"; total {result['seconds'] / 60:.1f} min")
        print(f"wrote {out / 'transfer.json'}, {out / 'transfer.png'}; every command's output is in {out / 'logs'}")
        return 0

    return _run("acn-transfer", body)


if __name__ == "__main__":  # pragma: no cover
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    sys.exit(collect_main())
