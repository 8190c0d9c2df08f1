"""Model against measurements: where it fails, which physical effect is missing, add it, watch
the error fall (``acn-diagnose``). Stages: ``compare`` -> ``where`` -> ``rank`` -> ``add``,
run together by ``diagnose``; ``report`` turns a ``Diagnosis`` into JSON, tables and HTML."""

from acn.diagnosis.pipeline import Diagnosis, diagnose, explain_corrector
from acn.diagnosis.problem import DiagnoseConfig

__all__ = ["DiagnoseConfig", "Diagnosis", "diagnose", "explain_corrector"]
