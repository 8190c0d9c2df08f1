"""Rerun views of recorded trajectories (``acn-view``).

``view.py`` runs the command; ``trajectories.py`` says what is shown (episodes, named
trajectories, extra series and panels); ``kinematics.py`` and ``meshes.py`` give the A1's link
poses and meshes; ``log.py`` logs columnar; ``blueprint.py`` is the layout.
"""

from acn.viz.trajectories import EpisodeView, Panel, Series, Trajectory

__all__ = ["EpisodeView", "Panel", "Series", "Trajectory"]
