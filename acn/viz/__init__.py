"""Rerun views of recorded trajectories (``acn-view``).

``view.py`` runs the command; ``trajectories.py`` says what is shown (episodes, named
trajectories, extra series, panels and text); ``diagnosis.py`` adds a model's one-step
predictions, residuals and error per added effect (``--model``, ``--diagnosis``);
``kinematics.py`` and ``meshes.py`` give the A1's link poses and meshes; ``log.py`` logs
columnar; ``blueprint.py`` is the layout.
"""

from acn.viz.trajectories import Document, EpisodeView, Panel, Series, Trajectory

__all__ = ["Document", "EpisodeView", "Panel", "Series", "Trajectory"]
