"""Command-line entry points (installed as ``acn-*`` console scripts).

Every command prints a one-line error and exits with status 2 on bad input; an interrupted
command exits with 130. Library code raises; only this module prints and exits.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Callable, NoReturn

from acn.errors import UserError

EXIT_USAGE, EXIT_INTERRUPTED = 2, 130


class _Parser(argparse.ArgumentParser):
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


def _positive_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if v < 1:
        raise argparse.ArgumentTypeError(f"expected a number >= 1, got {v}")
    return v


def _nonneg_int(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, got {v}")
    return v


def _positive_float(text: str) -> float:
    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not (v > 0 and v < float("inf")):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text}")
    return v


# ----------------------------------------------------------------------------- acn-collect
def collect_parser() -> argparse.ArgumentParser:
    from acn.toolkit.backends import ACTION_MODES, BACKENDS
    from acn.toolkit.policies import POLICIES

    p = _Parser(
        prog="acn-collect",
        description="Run the A1 in a source simulator (and, paired, in a target simulator from the "
        "same initial state with the same actions) and write a LeRobot v3.0 dataset.",
    )
    p.add_argument("--source", default="pybullet", choices=BACKENDS, help="simulator the policy acts on")
    p.add_argument("--target", default=None, choices=BACKENDS,
                   help="second simulator driven with the same actions (omit to record the source alone)")
    p.add_argument("--policy", default="trot", choices=list(POLICIES), help="built-in policy")
    p.add_argument("--episodes", type=_positive_int, default=4)
    p.add_argument("--seconds", type=_positive_float, default=10.0, help="episode length limit, s")
    p.add_argument("--seed", type=_nonneg_int, default=0, help="initial states and random policies")
    p.add_argument("--out", required=True, type=Path, help="dataset directory to create")
    p.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    p.add_argument("--workers", type=_positive_int, default=1, help="processes on this machine")
    p.add_argument("--action-mode", default="position", choices=ACTION_MODES,
                   help="position: joint targets, PD at the physics rate; torque: joint torques")
    p.add_argument("--control-hz", type=_positive_int, default=50)
    p.add_argument("--physics-hz", type=_positive_int, default=1000)
    p.add_argument("--kp", type=_positive_float, default=60.0, help="PD stiffness, N m/rad")
    p.add_argument("--kd", type=_positive_float, default=1.5, help="PD damping, N m s/rad")
    p.add_argument("--torque-limit", type=_positive_float, default=33.5, help="N m, every joint")
    p.add_argument("--corrector", type=Path, default=None,
                   help="frozen corrector directory (acn-fit output) applied to the target's actions")
    return p


def collect_config_from_args(args: argparse.Namespace):
    from acn.toolkit.backends import SimConfig
    from acn.toolkit.collector import CollectConfig

    if args.physics_hz % args.control_hz:
        raise UserError(f"--physics-hz ({args.physics_hz}) must be a multiple of --control-hz ({args.control_hz})")
    if args.corrector is not None and not args.corrector.is_dir():
        raise UserError(f"corrector directory {args.corrector} does not exist")
    sim = SimConfig(physics_dt=1.0 / args.physics_hz, substeps=args.physics_hz // args.control_hz,
                    action_mode=args.action_mode, kp=args.kp, kd=args.kd, torque_limit=args.torque_limit)
    return CollectConfig(source=args.source, target=args.target, policy=args.policy, episodes=args.episodes,
                         seconds=args.seconds, seed=args.seed, sim=sim,
                         corrector=str(args.corrector) if args.corrector else None)


def collect_main(argv: list[str] | None = None) -> int:
    args = collect_parser().parse_args(argv)

    def body() -> int:
        from acn.datasets.record import Interrupted, record

        cfg = collect_config_from_args(args)
        if args.out.exists() and not args.overwrite:
            raise UserError(f"output directory {args.out} exists (use --overwrite to replace it)")
        counts: dict[str, int] = {}

        def progress(ep) -> None:
            counts[ep.end] = counts.get(ep.end, 0) + 1
            print(f"episode {sum(counts.values())}/{cfg.episodes}: {len(ep)} steps, {ep.end}", file=sys.stderr)

        try:
            path = record(cfg, args.out, workers=args.workers, overwrite=args.overwrite, on_episode=progress)
        except Interrupted as e:
            where = f"kept {e.episodes} finished episode(s) in {e.path}" if e.path else "nothing was written"
            print(f"acn-collect: interrupted; {where}", file=sys.stderr)
            return EXIT_INTERRUPTED
        ends = ", ".join(f"{v} {k}" for k, v in sorted(counts.items()))
        print(f"wrote {sum(counts.values())} episode(s) ({ends}) to {path}")
        print(f"open it: LeRobotDataset('acn/{path.name}', root='{path}')  (set HF_HUB_OFFLINE=1)")
        return 0

    return _run("acn-collect", body)


if __name__ == "__main__":  # pragma: no cover
    os.environ.setdefault("HF_HUB_OFFLINE", "1")
    sys.exit(collect_main())
