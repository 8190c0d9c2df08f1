"""The Action Correction Network (``acn-fit``): a per-step action correction learned from paired
trajectories, saved as a frozen corrector, and judged in closed loop beside its oracles.

``acn.py`` holds the networks; ``fit.py`` trains them from a paired dataset in named stages;
``labels.py``, ``rounds.py`` and ``sensitivity.py`` make the training targets by re-simulation;
``oracle.py`` the two oracle correctors; ``evaluate.py`` the closed-loop judgement;
``corrector.py`` the frozen corrector a user shares (``model.safetensors`` + ``config.json``).
"""

from acn.corrector.corrector import Corrector

__all__ = ["Corrector"]
