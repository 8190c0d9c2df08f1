"""The Action Correction Network (``acn-fit``): a per-step action correction learned from paired
trajectories, saved as a frozen corrector, and judged in closed loop beside its oracles.

``acn.py`` holds the networks and their losses; ``fit.py`` fits them from a paired dataset in
named stages (``config.py`` its hyper-parameters), asking the variant's strategy
(``variants.py``) where the variants differ; ``rows.py`` the rows and tensors it learns from;
``train.py`` the training loop; ``labels.py``, ``rounds.py`` and ``sensitivity.py`` make the
training targets by re-simulation; ``oracle.py`` the two oracle correctors; ``evaluate.py`` the
closed-loop judgement; ``corrector.py`` the frozen corrector a user shares
(``model.safetensors`` + ``config.json``, its card: ``card.py``).
"""

from acn.corrector.corrector import Corrector

__all__ = ["Corrector"]
