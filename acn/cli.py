"""Command-line entry points (installed as ``acn-*`` console scripts).

Every command prints a one-line error and exits with status 2 on bad input; an interrupted
command exits with 130. Library code raises; only this module prints and exits.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shlex
import sys
from pathlib import Path
from typing import Callable, Iterator, NoReturn

from acn.errors import UserError
from acn.outputs import check_input_dir, check_output

EXIT_USAGE, EXIT_INTERRUPTED, EXIT_BROKEN_PIPE = 2, 130, 141  # 141: 128 + SIGPIPE


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
    try:
        return body() or 0
    except (UserError, ValueError, FileExistsError, FileNotFoundError) as e:
        print(f"{prog}: error: {e}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # the reader of the output went away (`| head`): stop quietly, as a shell tool does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error when Python flushes it
        return EXIT_BROKEN_PIPE


def _number(kind: type, minimum: float, inclusive: bool, maximum: float = 1e9) -> Callable[[str], float]:
    """An argparse type: a finite ``kind`` (int or float) >= or > ``minimum`` and <= ``maximum``
    (by default 1e9: past it every setting of this toolkit is a typo, and some overflow)."""
    word = "a whole number" if kind is int else "a number"
    bound = f"{'>=' if inclusive else '>'} {minimum:g} and <= {maximum:g}"

    def parse(text: str):
        try:
            v = kind(text)
        except (ValueError, OverflowError):
            raise argparse.ArgumentTypeError(f"expected {word}, got {text!r:.40}") from None
        if not (v == v and abs(v) != float("inf")) or v < minimum or (v == minimum and not inclusive) or v > maximum:
            raise argparse.ArgumentTypeError(f"expected a finite number {bound}, got {text:.40}")
        return v

    return parse


def _out_path(text: str) -> Path:
    """An argparse type for an output path: not empty (``Path("")`` would be the working directory)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty path")
    return Path(text)


_positive_int = _number(int, 1, inclusive=True)
_nonneg_int = _number(int, 0, inclusive=True)
_positive_float = _number(float, 0, inclusive=False)
_nonneg_float = _number(float, 0, inclusive=True)
_seconds = _number(float, 0, inclusive=False, maximum=86_400)  # an episode: up to a day


def _joint_gains(minimum: float, inclusive: bool) -> Callable[[str], "float | tuple[float, ...]"]:
    """An argparse type for a PD gain: one number for every joint, three (hip, thigh, calf: the
    same on every leg) or twelve (the schema's joint order FR, FL, RR, RL; hip, thigh, calf)."""
    number = _number(float, minimum, inclusive)

    def parse(text: str):
        values = [number(t.strip()) for t in text.split(",")]
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


def _given(args: argparse.Namespace, parser: argparse.ArgumentParser) -> set[str]:
    """The options the user set to something other than their default."""
    return {k for k, v in vars(args).items() if v != parser.get_default(k)}


_GAINS_HELP = "; one number for every joint, or hip,thigh,calf (every leg), or 12 in the order FR, FL, RR, RL"


# ----------------------------------------------------------------------------- --ray (optional extra)
def _add_ray_arguments(p: argparse.ArgumentParser, what: str) -> None:
    p.add_argument("--ray", nargs="?", const="", default=None, metavar="ADDRESS",
                   help=f"run {what} on Ray: alone, a local Ray instance (this machine's CPUs or --ray-cpus); "
                   "ADDRESS (auto, or HOST:PORT from `ray start --head`) joins a cluster; needs pip install -e '.[ray]'")
    p.add_argument("--ray-cpus", type=_positive_int, default=None, metavar="N",
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
def collect_parser() -> argparse.ArgumentParser:
    from acn.sim.backends import ACTION_MODES, BACKENDS
    from acn.sim.policies import POLICIES

    p = _Parser(
        prog="acn-collect",
        description="Run the A1 in a source simulator (and, paired, in a target simulator from the "
        "same initial state with the same actions) and write a LeRobot v3.0 dataset. Ctrl-C keeps the finished "
        "episodes as a dataset in a new --out; over an existing dataset (--overwrite) it leaves that dataset as it was.",
    )
    p.add_argument("--source", default="pybullet", choices=BACKENDS, help="simulator the policy acts on")
    p.add_argument("--target", default=None, choices=BACKENDS,
                   help="second simulator driven with the same actions (omit to record the source alone)")
    p.add_argument("--policy", default="trot", choices=list(POLICIES), help="built-in policy")
    p.add_argument("--episodes", type=_positive_int, default=4, help="episodes to record")
    p.add_argument("--seconds", type=_seconds, default=10.0, help="episode length limit, s")
    p.add_argument("--seed", type=_nonneg_int, default=0, help="initial states and random policies")
    p.add_argument("--out", required=True, type=_out_path, help="dataset directory to create")
    p.add_argument("--overwrite", action="store_true", help="replace --out if it is a dataset this toolkit wrote (nothing else is ever replaced)")
    p.add_argument("--workers", type=_positive_int, default=1, help="processes on this machine")
    p.add_argument("--action-mode", default="position", choices=ACTION_MODES,
                   help="position: joint targets, PD at the physics rate; torque: joint torques")
    p.add_argument("--control-hz", type=_positive_int, default=50, help="control rate, Hz (one action per step)")
    p.add_argument("--physics-hz", type=_positive_int, default=None,
                   help="physics rate (default: the multiple of --control-hz nearest 1 kHz)")
    p.add_argument("--kp", type=_joint_gains(0, False), default=60.0, help="PD stiffness, N m/rad" + _GAINS_HELP)
    p.add_argument("--kd", type=_joint_gains(0, False), default=1.5, help="PD damping, N m s/rad" + _GAINS_HELP)
    p.add_argument("--torque-limit", type=_positive_float, default=33.5, help="N m, every joint")
    p.add_argument("--corrector", type=Path, default=None,
                   help="frozen corrector directory (acn-fit output) applied to the target's actions")
    p.add_argument("--hidden-effect", action="append", default=[], metavar="NAME[:param=value,...]|random",
                   help="apply a physical effect to the source (the measured robot) at a realistic magnitude "
                   "(random: a random catalogue effect); the answer goes to OUT.answer.json, never into the "
                   "dataset; repeat for several effects")
    _add_ray_arguments(p, "the episodes (one Ray task each, written in episode order)")
    p.add_argument("--shards", type=_positive_int, default=1, metavar="K",
                   help="with --ray: K writers in parallel (contiguous episode ranges), merged into --out")
    return p


def collect_config_from_args(args: argparse.Namespace):
    from acn.sim.backends import SimConfig
    from acn.sim.backends.base import physics_hz_for
    from acn.sim.collector import CollectConfig

    physics_hz = physics_hz_for(args.control_hz, args.physics_hz)
    if args.corrector is not None:
        from acn.corrector.corrector import load_for_target

        load_for_target(args.corrector, [])  # the collected target is the simulator as is
    sim = SimConfig(physics_dt=1.0 / physics_hz, substeps=physics_hz // args.control_hz,
                    action_mode=args.action_mode, kp=args.kp, kd=args.kd, torque_limit=args.torque_limit)
    return CollectConfig(source=args.source, target=args.target, policy=args.policy, episodes=args.episodes,
                         seconds=args.seconds, seed=args.seed, sim=sim,
                         corrector=str(args.corrector) if args.corrector else None,
                         hidden_effects=_hidden_effects(args.hidden_effect, args.seed, sim))


def _hidden_effects(specs: list[str], seed: int, sim) -> list:
    """``--hidden-effect`` arguments -> effects with values, drawn from ``seed``; no name twice."""
    import numpy as np

    from acn.sim.hidden import parse_hidden

    rng = np.random.default_rng([seed, 0x41])
    out: list = []
    for spec in specs:
        for _ in range(100):
            effect = parse_hidden(spec, rng, sim)
            if effect.name not in {e.name for e in out}:
                break
            if spec != "random":
                raise UserError(f"--hidden-effect {effect.name} is given twice")
        out.append(effect)
    return out


def collect_main(argv: list[str] | None = None) -> int:
    args = collect_parser().parse_args(argv)

    def body() -> int:
        from acn.datasets.record import Interrupted, record
        from acn.datasets.schema import DATASET
        from acn.sim.hidden import ANSWER, answer_path

        check_output(args.out, DATASET, overwrite=args.overwrite, inputs=[args.corrector])
        check_input_dir(args.corrector, "corrector directory")
        cfg = collect_config_from_args(args)
        if cfg.hidden_effects:
            check_output(answer_path(args.out), ANSWER, flag="the answer beside --out")
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

            print(f"hidden effect(s) applied to the {cfg.source} robot; the answer is in {answer_path(path)}")
        print(f"open it: LeRobotDataset('acn/{path.name}', root='{path}')  (set HF_HUB_OFFLINE=1)")
        return 0

    return _run("acn-collect", body)


# ----------------------------------------------------------------------------- acn-fit
def fit_parser() -> argparse.ArgumentParser:
    from acn.corrector.acn import VARIANTS
    from acn.corrector.fit import FitConfig

    d = FitConfig()
    p = _Parser(prog="acn-fit", description="Fit the Action Correction Network from paired datasets written by "
                "acn-collect; write a frozen corrector (model.safetensors + config.json + metrics.json).")
    p.add_argument("datasets", nargs="+", type=Path, help="paired dataset directories")
    p.add_argument("--out", required=True, type=_out_path, help="model directory to create")
    p.add_argument("--overwrite", action="store_true", help="replace --out if it is a corrector this toolkit wrote (nothing else is ever replaced)")
    p.add_argument("--model", default=None, metavar="MODEL.json",
                   help="fit on top of this model of the target simulator (e.g. acn-diagnose --save-model's): its "
                   "effects are written into the target, and the network learns what they leave (inverse only)")
    p.add_argument("--variant", default=d.variant, choices=VARIANTS,
                   help="inverse: regress Gauss-Newton labels delta_a* from same-state re-simulations (default); "
                   "paper: learned Jacobian (the paper's, degenerate); mujoco-jacobian: J from the target")
    p.add_argument("--epochs", type=_positive_int, default=d.epochs, help="default: 30 (paper), 60 (inverse)")
    p.add_argument("--batch-size", type=_positive_int, default=d.batch_size, help="default: 256 (paper), 64 (inverse)")
    p.add_argument("--lr", type=_positive_float, default=d.lr, help="Adam learning rate")
    p.add_argument("--lr-schedule", default=d.lr_schedule, choices=("constant", "cosine"),
                   help="default: constant (paper), cosine (inverse)")
    p.add_argument("--lambda-l1", type=_nonneg_float, default=d.lambda_l1, help="weight of |delta_a|_1")
    p.add_argument("--hidden", type=_positive_int, default=d.hidden, help="default: 256 (paper), 512 (inverse)")
    p.add_argument("--layers", type=_positive_int, default=d.layers, help="hidden layers per network")
    p.add_argument("--filter-percentile", type=_positive_float, default=d.filter_percentile,
                   help="keep rows whose source-target gap is below this percentile (100: keep all; "
                   "default: 70 for paper and mujoco-jacobian, 100 for inverse)")
    p.add_argument("--val-fraction", type=_positive_float, default=d.val_fraction, help="of episodes")
    p.add_argument("--seed", type=_nonneg_int, default=d.seed, help="initialisation, batches and the validation split")
    p.add_argument("--device", default=d.device, help="cpu or cuda")
    p.add_argument("--precision", default=d.precision, choices=("auto", "bf16", "fp32"),
                   help="matmul precision in training (auto: bf16 where the hardware has it natively)")
    p.add_argument("--jacobian-eps", type=_positive_float, default=d.jacobian_eps,
                   help="finite-difference step on actions (mujoco-jacobian)")
    p.add_argument("--eval-episodes", type=_nonneg_int, default=d.eval_episodes,
                   help="closed-loop evaluation episodes from held-out initial states (0: skip)")
    p.add_argument("--eval-seconds", type=_seconds, default=d.eval_seconds, help="closed-loop evaluation episode length, s")
    p.add_argument("--no-oracles", action="store_true",
                   help="skip the same-state and tracking oracles in the closed-loop evaluation")
    p.add_argument("--label-iterations", type=_positive_int, default=d.label_iterations,
                   help="inverse: Gauss-Newton steps with a finite-difference Jacobian per label")
    p.add_argument("--label-broyden", type=_nonneg_int, default=d.label_broyden,
                   help="inverse: further quasi-Newton (Broyden) steps per label")
    p.add_argument("--label-damping", type=_nonneg_float, default=d.label_damping,
                   help="inverse: Levenberg-Marquardt ridge, relative to the mean diagonal of J^T J")
    p.add_argument("--jacobian-weight", type=_nonneg_float, default=d.jacobian_weight,
                   help="inverse: add this times the paper's fit term under the target's true J")
    p.add_argument("--label-state-weight", type=_nonneg_float, default=d.label_state_weight,
                   help="inverse: add this times the label error seen through the target's true J")
    p.add_argument("--oracle-iterations", type=_positive_int, default=d.oracle_iterations,
                   help="Gauss-Newton steps of the oracles (closed loop and the held-out one-step reference)")
    p.add_argument("--rounds", type=_nonneg_int, default=d.rounds,
                   help="inverse: closed-loop rounds (collect with the corrector, label the visited states, refit; "
                   "default 4)")
    p.add_argument("--round-episodes", type=_positive_int, default=d.round_episodes, help="inverse: episodes collected per round")
    p.add_argument("--round-seconds", type=_seconds, default=d.round_seconds, help="inverse: length of a round's episodes, s")
    p.add_argument("--round-epochs", type=_positive_int, default=d.round_epochs, help="inverse: epochs of each round's refit")
    p.add_argument("--label-fd-eps", type=_positive_float, default=d.label_fd_eps,
                   help="inverse: finite-difference step on actions in the label solve (action units)")
    p.add_argument("--sensor-inputs", action=argparse.BooleanOptionalAction, default=d.sensor_inputs,
                   help="F also reads the contact and IMU readings (default: on for paper and mujoco-jacobian)")
    p.add_argument("--threads", type=_positive_int, default=d.threads, help="re-simulation threads")
    p.add_argument("--train-threads", type=_nonneg_int, default=d.train_threads,
                   help="torch threads in training on a CPU (default 0: whichever count is fastest, timed every "
                   "few seconds while training; more threads are faster only on an otherwise idle machine)")
    p.add_argument("--cuda-graph", action=argparse.BooleanOptionalAction, default=d.cuda_graph,
                   help="with --device cuda: replay each full-batch training step as one CUDA graph (default on)")
    p.add_argument("--calibrate", action=argparse.BooleanOptionalAction, default=d.calibrate,
                   help="scale F by 0, 0.25, ... 1, whichever leaves the least one-step error on half of the held-out "
                   "episodes (default: on for inverse)")
    _add_ray_arguments(p, "the re-simulation batches (Jacobians, labels; rows in chunks)")
    return p


def fit_main(argv: list[str] | None = None) -> int:
    args = fit_parser().parse_args(argv)

    def body() -> int:
        from acn.corrector.corrector import CORRECTOR
        from acn.corrector.fit import FitConfig, fit, save

        check_output(args.out, CORRECTOR, overwrite=args.overwrite, inputs=[*args.datasets, args.model])
        for d in args.datasets:
            check_input_dir(d, "dataset directory")
        _check_device(args.device)
        cfg = FitConfig(variant=args.variant, hidden=args.hidden, layers=args.layers, lambda_l1=args.lambda_l1,
                        lr=args.lr, batch_size=args.batch_size, epochs=args.epochs,
                        filter_percentile=args.filter_percentile, val_fraction=args.val_fraction, seed=args.seed,
                        device=args.device, precision=args.precision, jacobian_eps=args.jacobian_eps, eval_episodes=args.eval_episodes,
                        eval_seconds=args.eval_seconds, oracles=not args.no_oracles,
                        label_iterations=args.label_iterations, label_broyden=args.label_broyden,
                        label_damping=args.label_damping, jacobian_weight=args.jacobian_weight, rounds=args.rounds,
                        label_state_weight=args.label_state_weight, oracle_iterations=args.oracle_iterations,
                        lr_schedule=args.lr_schedule,
                        round_episodes=args.round_episodes, round_seconds=args.round_seconds,
                        round_epochs=args.round_epochs, threads=args.threads, calibrate=args.calibrate,
                        label_fd_eps=args.label_fd_eps, sensor_inputs=args.sensor_inputs,
                        train_threads=args.train_threads, cuda_graph=args.cuda_graph)
        target = None
        if args.model is not None:
            from acn.sim.effects import Model

            target = Model.parse(args.model)
        with _ray_executor(args, "acn-fit"):
            model, metrics = fit(args.datasets, cfg, log=lambda line: print(line, file=sys.stderr), target=target)
        path = save(model, metrics, args.out, overwrite=args.overwrite)
        simulator = (model.config["training_data"]["target"] or {}).get("simulator")
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
def ppo_parser() -> argparse.ArgumentParser:
    from acn.corrector.acn import VARIANTS
    from acn.rl.ppo import PPOConfig

    d = PPOConfig()
    p = _Parser(prog="acn-ppo", description="Train a walking policy with PPO in PyBullet (a residual on the trot) "
                "and evaluate it in MuJoCo with and without the frozen corrector pi_corr(s) = pi(s) + F(s, pi(s)), "
                "which is applied in the TARGET (MuJoCo) only; every --refit-every episodes F is refitted on paired "
                "data of the current policy (the paper's Algorithm 2). Or, with --eval, reload and evaluate.")
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument("--timesteps", type=_positive_int, help="train for this many PyBullet control steps in all; fewer than one rollout (n_steps x envs, "
                      "2048 by default) is a quick trial: those steps, a 2-epoch refit on two 2 s paired episodes and a "
                      "final evaluation of 2 episodes of 2 s (options you set are kept)")
    mode.add_argument("--eval", type=Path, metavar="POLICY", help="evaluate a saved policy directory (DIR/policy)")
    p.add_argument("--out", type=_out_path, help="run directory to create (training); --eval: a JSON file to write")
    p.add_argument("--corrector", type=Path, default=None,
                   help="frozen corrector directory (acn-fit output); training: F until the first refit")
    p.add_argument("--refit-every", type=_nonneg_int, default=d.refit_every, help="episodes; 0: never refit")
    p.add_argument("--eval-every", type=_nonneg_int, default=d.eval_every, help="episodes; 0: only at the end")
    p.add_argument("--eval-episodes", type=_nonneg_int, default=d.eval_episodes, help="per evaluation in training")
    p.add_argument("--final-eval-episodes", type=_positive_int, default=d.final_eval_episodes, help="episodes of the final evaluation, per simulator")
    p.add_argument("--variant", default=d.corrector_variant, choices=VARIANTS, help="acn-fit variant for refits")
    p.add_argument("--envs", type=_positive_int, default=d.n_envs, help="PyBullet environment processes")
    p.add_argument("--seed", type=_nonneg_int, default=d.seed, help="PPO, environments and evaluation starts")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="any other PPOConfig field, e.g. --set n_steps=512 --set hidden=64,64")
    p.add_argument("--resume", action="store_true", help="continue the run in --out from its checkpoint")
    p.add_argument("--overwrite", action="store_true", help="replace --out if it is a PPO run this toolkit wrote, once the new run is complete")
    p.add_argument("--episodes", type=_positive_int, default=20, help="--eval: episodes per simulator")
    p.add_argument("--seconds", type=_seconds, default=None, help="--eval: episode limit (default: the policy's)")
    p.add_argument("--oracle-episodes", type=_nonneg_int, default=0,
                   help="--eval: also the same-state oracle bound on this many episodes (optional, slow)")
    return p


def ppo_main(argv: list[str] | None = None) -> int:
    args = ppo_parser().parse_args(argv)

    def body() -> int:
        if args.eval is not None:
            return _ppo_eval(args)
        from dataclasses import replace

        from tqdm import tqdm

        from acn.rl.ppo import PPO_RUN, PPOConfig, Trainer, format_table, parse_overrides

        if args.out is None:
            raise UserError("--timesteps needs --out DIR")
        if not args.resume:
            check_output(args.out, PPO_RUN, overwrite=args.overwrite, inputs=[args.corrector])
        elif args.overwrite:
            raise UserError("--resume continues the run in --out; --overwrite would replace it: give one")
        check_input_dir(args.corrector, "corrector directory")
        cfg = replace(PPOConfig(), timesteps=args.timesteps, refit_every=args.refit_every, eval_every=args.eval_every,
                      eval_episodes=args.eval_episodes, final_eval_episodes=args.final_eval_episodes,
                      corrector_variant=args.variant, n_envs=args.envs, seed=args.seed)
        cfg = parse_overrides(cfg, args.set)
        cfg = cfg.sized_for_run(keep=_given(args, ppo_parser()) | {item.partition("=")[0].strip().replace("-", "_")
                                                                  for item in args.set})
        trainer = Trainer(cfg, args.out, corrector_dir=args.corrector, resume=args.resume, overwrite=args.overwrite,
                          log=lambda line: tqdm.write(line, file=sys.stderr))
        m = trainer.run()
        t = m["training"]
        print(format_table(m["final_evaluation"]))
        recent = t["train_return_last_100_episodes"]
        print(f"trained {t['timesteps']} steps ({t['episodes']} episodes) in {t['wall_seconds_this_session']:.0f} s; "
              + (f"mean training return of the last 100 episodes {recent:.1f}" if recent is not None
                 else "no training episode finished"))
        print(f"corrector frozen (tensor sha256 unchanged while in use): {m['corrector_frozen']}")
        out = args.out.absolute()
        corrector = out / "corrector" if (out / "corrector").is_dir() else None
        print(f"wrote {out / 'policy'} (safetensors + JSON), {f'{corrector}, ' if corrector else ''}"
              f"{out / 'metrics.json'}, {out / 'curves.png'}; {out / 'checkpoint'} resumes training (--resume)")
        print(f"evaluate again: acn-ppo --eval {out / 'policy'}" + (f" --corrector {corrector}" if corrector else ""))
        return 0

    return _run("acn-ppo", body)


def _ppo_eval(args: argparse.Namespace) -> int:
    if args.resume or args.set:
        raise UserError("--eval takes --corrector, --episodes, --seconds, --seed, --oracle-episodes and --out only")
    check_input_dir(args.eval, "policy directory")
    check_input_dir(args.corrector, "corrector directory")
    from acn.rl.ppo import EVAL_FORMAT, PPO_EVAL, evaluate_saved, format_table, write_json

    check_output(args.out, PPO_EVAL, inputs=[args.eval, args.corrector])
    ev = evaluate_saved(args.eval, args.corrector, args.episodes, args.seconds, args.seed, args.oracle_episodes)
    print(format_table(ev))
    if args.out is not None:
        write_json(args.out, {"format": EVAL_FORMAT, **ev})
        print(f"wrote {args.out}")
    return 0


# ----------------------------------------------------------------------------- acn-view
def view_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="acn-view", description="Show a dataset in the Rerun viewer: the A1 in 3D per trajectory, "
                "joint angles, divergence per channel group and stance/swing, one tab per episode. Opens the "
                "viewer when there is a display and no --save; otherwise writes a .rrd.")
    p.add_argument("dataset", type=Path, help="dataset directory written by acn-collect (paired or not)")
    p.add_argument("--episodes", default=None, metavar="0,3,...", help="episodes to show (default: all)")
    p.add_argument("--corrector", type=Path, default=None,
                   help="frozen corrector directory (acn-fit output): also show the target re-simulated with it")
    p.add_argument("--model", default=None, metavar="MODEL.json",
                   help="mujoco, pybullet or a model JSON (acn-diagnose --save-model): measured against the model's "
                   "one-step prediction, residuals per joint, the error as the model's effects are added")
    p.add_argument("--diagnosis", type=Path, default=None, metavar="FILE.json",
                   help="acn-diagnose --json result: its verdict, ranking and where-summary as text (with --model)")
    p.add_argument("--save", type=_out_path, default=None, metavar="OUT.rrd", help="write a .rrd instead of opening a viewer")
    return p


def view_main(argv: list[str] | None = None) -> int:
    args = view_parser().parse_args(argv)

    def body() -> int:
        from acn.viz.view import RECORDING, ViewConfig, view

        check_input_dir(args.dataset, "dataset directory")
        check_output(args.save, RECORDING, flag="--save", inputs=[args.dataset, args.corrector, args.model,
                                                                 args.diagnosis])
        path = view(ViewConfig(dataset=args.dataset, episodes=args.episodes, corrector=args.corrector,
                               model=args.model, diagnosis=args.diagnosis, save=args.save))
        if path is not None:
            print(f"wrote {path}; open it with:")
            print(f"rerun {path}")
        return 0

    return _run("acn-view", body)


# ----------------------------------------------------------------------------- acn-import
def import_parser() -> argparse.ArgumentParser:
    from acn.sim.backends import ACTION_MODES, IMU_ACC_KINDS
    from acn.sim.state import FOOT_NAMES

    p = _Parser(prog="acn-import", description="Turn a robot log (CSV, Parquet, JSON lines, HDF5 or .npz, one row per control "
                "step) into a measurement dataset (LeRobot v3.0, the schema of acn-collect) that acn-diagnose reads.")
    p.add_argument("log", type=Path, nargs="+", help="the log file (.csv, .parquet, .jsonl, .h5 or .npz); several (one per run, "
                   "the same columns): read one after the other, each file's episodes apart")
    p.add_argument("--out", required=True, type=_out_path, help="dataset directory to create")
    p.add_argument("--control-hz", required=True, type=_positive_int, help="control rate the log was recorded at")
    p.add_argument("--kp", required=True, type=_joint_gains(0, True),
                   help="joint PD stiffness the robot ran with, N m/rad" + _GAINS_HELP + "; a log with action_kp.* "
                   "columns (a hybrid command, with action_kd.*, action_vel.*, action_torque.*) sends its own per row")
    p.add_argument("--kd", required=True, type=_joint_gains(0, True), help="joint PD damping, N m s/rad" + _GAINS_HELP)
    p.add_argument("--torque-limit", required=True, type=_positive_float, help="N m, every joint")
    p.add_argument("--action-mode", default="position", choices=ACTION_MODES, help="what the log's actions are: joint targets (position) or torques")
    p.add_argument("--physics-hz", type=_positive_int, default=None,
                   help="physics rate a model simulates it at (default: the multiple of --control-hz nearest 1 kHz)")
    p.add_argument("--map", type=Path, default=None, dest="map_file", metavar="MAP.json",
                   help='rename and scale columns: {"FR_hip_pos": "q0", "FR_thigh_pos": {"column": "q1_deg", '
                   '"scale": 0.0174533, "offset": 0.0}}; foot forces as contact flags: '
                   '{"FR_contact": {"column": "force0", "threshold": 20}}')
    p.add_argument("--dt-tolerance", type=_positive_float, default=0.1,
                   help="a time step may differ from the control period by this fraction before the episode is split")
    p.add_argument("--linvel-frame", choices=("body", "world"), default="body",
                   help="the frame the log's base_linvel_* are in (world: rotated into the body frame the schema uses)")
    p.add_argument("--angvel-frame", choices=("body", "world"), default="body", help="the same for base_angvel_*")
    p.add_argument("--leg-order", type=_leg_order, default=FOOT_NAMES, metavar="FL,FR,RL,RR",
                   help="the order of the legs in the log's columns, if not the schema's FR,FL,RR,RL "
                   "(legged_gym and Isaac Gym: FL,FR,RL,RR)")
    p.add_argument("--shift-actions", type=int, default=0, metavar="ROWS",
                   help="pair each state with the command this many rows later in its episode (1: the log writes the "
                   "last action sent with the new observation, as the action_row check finds)")
    p.add_argument("--imu-acc", choices=IMU_ACC_KINDS, default=None,
                   help="what the logged accelerometer reads: the mean specific force over the control step before "
                   "the row (mean, the schema's) or at the row's instant (instant: a sensor sampled then, as "
                   "MuJoCo's accelerometer); default: not stated, acn-diagnose judges it from the log")
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
        cfg = ImportConfig(control_hz=args.control_hz, kp=args.kp, kd=args.kd, torque_limit=args.torque_limit,
                           action_mode=args.action_mode, physics_hz=args.physics_hz, dt_tolerance=args.dt_tolerance,
                           linvel_frame=args.linvel_frame, angvel_frame=args.angvel_frame, leg_order=args.leg_order,
                           shift_actions=args.shift_actions, imu_acc=args.imu_acc)
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
def diagnose_parser() -> argparse.ArgumentParser:
    from acn.diagnosis import DiagnoseConfig

    d = DiagnoseConfig()
    p = _Parser(prog="acn-diagnose", description="Compare a model with measurements, show where it fails, rank "
                "which physical effect is missing, add it and watch the error fall.")
    p.add_argument("measured", nargs="?", type=Path, help="measurement dataset (acn-import or acn-collect)")
    p.add_argument("--model", default="mujoco", help="mujoco, pybullet or a model JSON file (default: mujoco)")
    p.add_argument("--side", default="source", choices=("source", "target"), help="which side of a paired dataset")
    p.add_argument("--add", action="append", default=[], metavar="EFFECT", help="fit and add this effect (repeatable)")
    p.add_argument("--auto", action="store_true", help="repeat rank -> add while the error falls by more than the noise")
    p.add_argument("--auto-alternatives", type=_nonneg_int, default=d.auto_alternatives, metavar="N",
                   help="with --auto: also start from the next N candidates and keep a chain that predicts clearly "
                   "better (one effect can stand in for two)")
    p.add_argument("--finest", default=d.finest, metavar="{shared,type,leg,joint}",
                   help="the finest granularity an added per-joint effect may get: one value for every joint, one "
                   "per joint type, leg or joint (a finer one is kept where it predicts significantly better; "
                   f"coarser is quicker; default {d.finest})")
    p.add_argument("--save-model", type=_out_path, default=None, metavar="FILE", help="write the updated model JSON")
    p.add_argument("--json", type=_out_path, default=None, metavar="FILE", help="write the machine-readable result")
    p.add_argument("--report", type=_out_path, default=None, metavar="FILE.html", help="write the HTML report")
    p.add_argument("--explain-corrector", type=Path, default=None, metavar="DIR",
                   help="explain a corrector from acn-fit: which effects its corrections look like")
    p.add_argument("--list-effects", action="store_true", help="print the catalogue of effects and exit")
    p.add_argument("--limits", action="store_true",
                   help="then the smallest size of each effect not named that this log would show: what it rules out")
    p.add_argument("--limits-per-joint", action="store_true",
                   help="--limits, and each per-joint effect also on one joint alone (a worn gearbox, a weak motor): "
                   "the size it shows at on the joint the log shows least")
    p.add_argument("--closed-loop", type=_nonneg_int, default=0, metavar="N",
                   help="then re-run the measured robot (an acn-collect dataset) from N held-out initial states beside "
                   "the model as given, with --corrector and with the added effects: divergence, eps_transfer, falls")
    p.add_argument("--closed-loop-seconds", type=_seconds, default=5.0, help="episode length, s")
    p.add_argument("--corrector", type=Path, default=None, metavar="DIR",
                   help="with --closed-loop: also run the model with this corrector (acn-fit output)")
    p.add_argument("--no-oracles", action="store_true", help="with --closed-loop: skip the oracle bounds")
    p.add_argument("--horizons", default=",".join(map(str, d.horizons)),
                   help="open-loop horizons, in diagnosis steps (--step-seconds each)")
    p.add_argument("--step-seconds", type=float, default=d.step_seconds,
                   help="one diagnosis step, s of control steps (rounded, at least one; 0: one control step): "
                   "at high control rates one control step moves the robot less than its sensor noise")
    p.add_argument("--effects", default=None, help="comma-separated candidates (default: the whole catalogue)")
    p.add_argument("--seed", type=_nonneg_int, default=d.seed, help="the held-out split and random starts")
    _add_ray_arguments(p, "the re-simulation batches (measured states, candidate fits; rows in chunks)")
    return p


def _check_diagnose_outputs(args: argparse.Namespace) -> None:
    """``--json``, ``--report`` and ``--save-model``: each a path of its own, checked before the run."""
    from acn.diagnosis.report import DIAGNOSIS_JSON, REPORT
    from acn.sim.backends import BACKENDS
    from acn.sim.effects.model import MODEL_FILE

    inputs = [args.measured, args.corrector, args.explain_corrector]
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
        if args.measured is None:
            raise UserError("give the measurement dataset (or --list-effects)")
        from acn.measurements.data import load_measurements
        from acn.diagnosis import ClosedLoop, DiagnoseConfig, Stages, run
        from acn.diagnosis.report import terminal, write_html, write_json
        from acn.sim.effects import EFFECT_NAMES, Model

        try:
            horizons = tuple(sorted({int(h) for h in args.horizons.split(",")}))
        except ValueError:
            raise UserError(f"--horizons must be whole numbers separated by commas, got {args.horizons!r}") from None
        candidates = EFFECT_NAMES if args.effects is None else tuple(args.effects.split(","))
        for name in (*candidates, *args.add):
            get_effect(name)
        check_input_dir(args.measured, "measurement dataset")
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
        model = Model.parse(args.model)
        cfg = DiagnoseConfig(horizons=horizons, candidates=candidates, seed=args.seed,
                             step_seconds=args.step_seconds if args.step_seconds != 0 else None,
                             auto_alternatives=args.auto_alternatives, finest=args.finest)
        cfg.validate()
        closed_loop = ClosedLoop(args.measured, args.side, args.closed_loop, args.closed_loop_seconds, args.corrector,
                                 oracles=not args.no_oracles) if args.closed_loop else None
        stages = Stages(add=tuple(args.add), automatic=args.auto, explain_corrector=args.explain_corrector,
                        limits=limits, limits_per_joint=args.limits_per_joint, closed_loop=closed_loop)
        data = load_measurements(args.measured, side=args.side)
        stages.check(data, model)  # refuse what cannot run before the diagnosis, not after
        from tqdm import tqdm

        with _ray_executor(args, "acn-diagnose"), tqdm(total=100, file=sys.stderr, bar_format="{l_bar}{bar}| {elapsed} {postfix}",
                                       disable=None) as bar:
            def say(message: str, fraction: float | None = None) -> None:
                bar.set_description_str(message)
                if fraction is not None:
                    bar.update(int(round(100 * fraction)) - bar.n)

            result = run(data, model, cfg, stages, progress=say)
        print(terminal(result))
        if args.json:
            print(f"wrote {write_json(result, args.json)}")
        if args.report:
            print(f"wrote the report {write_html(result, args.report)}")
        if args.save_model:
            print(f"wrote the model {result.final.model.save(args.save_model)}")
        return 0

    return _run("acn-diagnose", body)


if __name__ == "__main__":  # pragma: no cover
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    sys.exit(collect_main())
