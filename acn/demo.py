"""The summary ``make demo`` ends with: what was found, how well, and where every file is.

``python -m acn.demo OUT STARTED`` reads the files the demo wrote into ``OUT`` (``STARTED``: the
Unix time the demo began) and prints at most 15 lines:

- the hidden-effect log: the effects ``acn-diagnose --auto`` added, beside the sealed answer
  (``hidden.answer.json``, opened only here), and the one-step error before and after;
- the PyBullet -> MuJoCo trot gap in closed loop, the same held-out starts for each: MuJoCo as
  is, with the corrector, with the effects the diagnosis found, and the corrector's oracle;
- where every file is, the ``rerun`` command for the recording, and the demo's own time.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

from acn.errors import UserError
from acn.jsonfile import read_json


@dataclass(frozen=True)
class DemoFiles:
    """Every file the demo writes (the Makefile's ``demo`` target names the same paths)."""

    trot: Path              # the paired PyBullet -> MuJoCo dataset
    corrector: Path         # acn-fit's default corrector on it
    trot_diagnosis: Path    # the same gap answered with physics, beside the corrector
    trot_report: Path
    hidden: Path            # measurements with a sealed hidden effect
    answer: Path            # the sealed answer beside them
    hidden_diagnosis: Path
    hidden_report: Path
    recording: Path         # acn-view's .rrd of the hidden log against the fitted model

    @classmethod
    def under(cls, out: Path) -> "DemoFiles":
        return cls(trot=out / "trot_pb_mj", corrector=out / "acn_inverse", trot_diagnosis=out / "trot_pb_mj.diagnosis.json",
                   trot_report=out / "trot_pb_mj.report.html", hidden=out / "hidden", answer=out / "hidden.answer.json",
                   hidden_diagnosis=out / "hidden.diagnosis.json", hidden_report=out / "hidden.report.html",
                   recording=out / "hidden.rrd")


def _effects(effects: list[dict]) -> str:
    def value(v) -> str:
        if isinstance(v, list):
            return f"{min(v):.3g}..{max(v):.3g}" if min(v) != max(v) else f"{v[0]:.3g}"
        return f"{v:.3g}"

    return ", ".join(f"{e['name']} ({', '.join(f'{k} {value(v)}' for k, v in e['params'].items())})"
                     for e in effects) or "none"


def _run(loop: dict, name: str) -> str:
    r = loop["runs"].get(name)
    if r is None:
        return f"{name}: not run"
    return f"{r['eps_transfer']:+.1f} (divergence {r['divergence']:.3f}, falls {r['target_falls']})"


def summary(out: Path, started: float) -> list[str]:
    f = DemoFiles.under(out)
    hidden = read_json(f.hidden_diagnosis, f"{f.hidden_diagnosis} is missing: run make demo")
    answer = read_json(f.answer, f"{f.answer} is missing: run make demo")
    trot = read_json(f.trot_diagnosis, f"{f.trot_diagnosis} is missing: run make demo")
    fitted = read_json(f.corrector / "metrics.json", f"{f.corrector}/metrics.json is missing: run make demo")
    head = hidden["headline_error"]
    loop = trot["closed_loop"] or {"runs": {}}
    oracle = fitted.get("closed_loop", {}).get("runs", {}).get("same_state_oracle")
    lines = [
        f"hidden-effect log: verdict {hidden['verdict']}; added {_effects(hidden['added'])}",
        f"  the sealed answer: {_effects(answer['hidden_effects'])}",
        f"  one-step error {head['before']:.3f} -> {head['after']:.3f} (1 = as wrong as predicting no motion)",
        "PyBullet -> MuJoCo trot, closed loop from held-out starts: eps_transfer (0 = MuJoCo earns PyBullet's reward)",
        f"  MuJoCo as is        {_run(loop, 'uncorrected')}",
        f"  + corrector F       {_run(loop, 'corrected')}",
        f"  + found physics     {_run(loop, 'with effects')}: {_effects(trot['added'])}",
    ]
    if oracle is not None:
        lines.append(f"  F's own bound       {oracle['eps_transfer']:+.1f} (same-state oracle, in acn-fit's evaluation)")
    lines += [
        f"files: {f.trot} (paired dataset), {f.corrector} (corrector), {f.hidden} (measurements)",
        f"       {f.trot_report}, {f.hidden_report} (HTML reports); *.diagnosis.json, *.model.json beside them",
        f"recording: rerun {f.recording}",
        f"make demo took {(time.time() - started) / 60:.1f} min after the install",
    ]
    return lines


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 2:
        print("usage: python -m acn.demo OUT STARTED_UNIX_TIME", file=sys.stderr)
        return 2
    try:
        print("\n".join(summary(Path(args[0]), float(args[1]))))
    except (UserError, KeyError, TypeError, ValueError) as e:
        print(f"acn.demo: error: the demo's files are incomplete ({e}); run make demo", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
