"""Model against measurements: where it fails, which physical effect is missing, add it, watch
the error fall (``acn-diagnose``). The engine fits an effect and judges a model on held-out rows
(``problem``, ``fitting``, ``heldout``, ``compare``, ``where``, ``noise``); ``policy`` chooses
which candidates to rank first, which to add, when to stop and which verdict, by its
``Thresholds``; ``traits`` is what the diagnosis knows of each effect beyond its physics;
``pipeline`` runs the stages (``diagnose``; ``run`` with what the log rules out and the closed
loop); ``report`` turns a ``Diagnosis`` into JSON, tables and HTML."""

from acn.diagnosis.pipeline import ClosedLoop, Diagnosis, Stages, diagnose, explain_corrector, run
from acn.diagnosis.policy import THRESHOLDS, Thresholds
from acn.diagnosis.problem import DiagnoseConfig

__all__ = ["THRESHOLDS", "ClosedLoop", "DiagnoseConfig", "Diagnosis", "Stages", "Thresholds", "diagnose",
           "explain_corrector", "run"]
