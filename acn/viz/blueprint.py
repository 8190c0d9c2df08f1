"""The viewer layout, built in one place: one tab per episode, nothing to arrange by hand.

Each episode's tab (entities: ``acn.viz.log``):

    +------------------------+------------------------------------------+
    | A1 in 3D: every        | joint angle per joint (rows: legs FR FL   |
    | trajectory overlaid,   | RR RL, columns: hip thigh calf), one line |
    | contacts, trunk path   | per trajectory                            |
    +------------------------+------------------------------------------+
    | stance / swing bands   | divergence per channel group | extra ... |
    +------------------------+------------------------------------------+
    | text (a diagnosis)     |                                          |
    +------------------------+------------------------------------------+

Extra time-series panels (``EpisodeView.panels``, e.g. a diagnosis's residuals) join the
divergence panels at the bottom right, in two rows when there are more than three; text
panels go under the stance / swing bands.
"""

from __future__ import annotations

import math

import rerun.blueprint as rrb

from acn.sim.state import FOOT_NAMES, JOINT_NAMES
from acn.viz.trajectories import EpisodeView


def episode_tab(episode: EpisodeView) -> rrb.Container:
    """The tab of one episode (see module docstring)."""
    root = episode.root
    robot = rrb.Spatial3DView(origin=root, contents=["$origin/robots/**"], name="A1: " + ", ".join(
        t.label for t in episode.trajectories), line_grid=rrb.archetypes.LineGrid3D(visible=True, spacing=0.1))
    lanes = ", ".join(f"{k} {f}" for k, f in enumerate(FOOT_NAMES))
    gait = rrb.TimeSeriesView(origin=f"{root}/gait", name=f"stance (band) / swing (gap); lanes {lanes}",
                              plot_legend=rrb.PlotLegend(visible=False),
                              axis_y=rrb.ScalarAxis(range=(-0.5, len(FOOT_NAMES) - 0.2), zoom_lock=True))
    joints = rrb.Grid(*[rrb.TimeSeriesView(origin=f"{root}/joints/{j}", name=f"{j} angle, rad",
                                           plot_legend=rrb.PlotLegend(visible=k == 0))  # colours: one legend
                        for k, j in enumerate(JOINT_NAMES)], grid_columns=3)
    bottom = [rrb.TimeSeriesView(origin=f"{root}/divergence/{t.name}",
                                 name=f"divergence {t.name} - {episode.reference}, per channel group")
              for t in episode.trajectories if episode.reference and t.name != episode.reference]
    bottom += [rrb.TimeSeriesView(origin=f"{root}/{p.origin}", name=p.title,
                                  plot_legend=rrb.PlotLegend(visible=p.legend))
               for p in episode.panels if p.kind == "series"]
    texts = [rrb.TextDocumentView(origin=f"{root}/{p.origin}", name=p.title)
             for p in episode.panels if p.kind == "text"]
    if len(bottom) > 3:  # two rows
        right = rrb.Vertical(joints, rrb.Grid(*bottom, grid_columns=math.ceil(len(bottom) / 2)), row_shares=[3, 2.4])
    else:
        right = rrb.Vertical(joints, rrb.Horizontal(*bottom), row_shares=[3, 1.2]) if bottom else joints
    left = rrb.Vertical(robot, gait, *texts, row_shares=[2.4, 0.9] + [2.7] * len(texts)) if texts else \
        rrb.Vertical(robot, gait, row_shares=[3, 1])
    return rrb.Horizontal(left, right, column_shares=[1, 1.4], name=f"episode {episode.index}")


def build_blueprint(episodes: list[EpisodeView]) -> rrb.Blueprint:
    """Tabs of all episodes, the first one open, time panel on ``sim_time``."""
    return rrb.Blueprint(
        rrb.Tabs(*[episode_tab(e) for e in episodes], active_tab=0),
        rrb.BlueprintPanel(state="collapsed"),
        rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(timeline="sim_time", state="collapsed"),  # the play bar; the panels get the height
        auto_layout=False, auto_views=False,
    )
