"""Rerun views of recorded trajectories (``acn-view``).

``view.py`` runs the command; ``trajectories.py`` says what is shown (episodes, named
trajectories, extra series, panels and text); ``diagnosis.py`` adds a model's one-step
predictions, residuals and error per added effect (``--model``, ``--diagnosis``);
``meshes.py`` gives the A1's meshes (link poses come from ``acn.sim.kinematics``); ``log.py`` logs
columnar; ``blueprint.py`` is the layout.
"""

from acn.viz.trajectories import Document, EpisodeView, Panel, Series, Trajectory

__all__ = ["Document", "EpisodeView", "Panel", "Series", "Trajectory"]
