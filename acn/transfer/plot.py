"""The study's picture: each route's return on the robot and in its training model (mean and
standard error), pi_sim and pi_robot as the two lines every route sits between, the share of the
gap closed and the falls under each route's name, and how fast each walks on the robot."""

from __future__ import annotations

from pathlib import Path

from acn.outputs.writing import replacing
from acn.transfer.table import BASE, BOUND, TransferTable


def plot_study(table: TransferTable, path: Path, title: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = table.rows
    x = range(len(rows))
    fig, (a, b) = plt.subplots(1, 2, figsize=(13, 4.6), gridspec_kw={"width_ratios": [3, 2]})
    a.bar([i - 0.2 for i in x], [r.on_robot.mean for r in rows], 0.4, yerr=[r.on_robot.se for r in rows], capsize=3,
          color="tab:red", label="on the robot")
    a.bar([i + 0.2 for i in x], [r.in_training_model.mean for r in rows], 0.4,
          yerr=[r.in_training_model.se for r in rows], capsize=3, color="tab:gray", alpha=0.6,
          label="in its training model")
    for name, style in ((BASE, ":"), (BOUND, "--")):
        a.axhline(table.row(name).on_robot.mean, color="tab:red", linestyle=style, linewidth=1,
                  label=f"{name} on the robot")
    labels = []
    for r in rows:  # the falls and the share closed under each route's name
        share = "" if r.share_closed is None else f"\n{r.share_closed.text(0, 100, ' %')} of the gap"
        labels.append(f"{r.route}{share}\n{r.falls}/{r.episodes} fell")
    a.set_xticks(list(x), labels, fontsize=8)
    a.set(ylabel="episode return (training reward)", title=title)
    a.legend(fontsize=7, loc="best")
    b.bar(list(x), [r.forward_speed.mean for r in rows], yerr=[r.forward_speed.se for r in rows], capsize=3,
          color="tab:blue")
    b.set_xticks(list(x), [r.route for r in rows])
    b.set(ylabel="forward speed on the robot, m/s", title="how fast each walks on the robot")
    fig.suptitle(table.verdict, fontsize=8, wrap=True)
    fig.tight_layout(rect=(0, 0, 1, 0.93))
    with replacing(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return path
