"""Models fitted from collected datasets: the Action Correction Network and its frozen corrector."""

from acn.models.corrector import Corrector

__all__ = ["Corrector"]
