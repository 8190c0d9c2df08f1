"""The transfer study (``acn-transfer``): train where, correct how, and how well does the policy
then walk on the robot? ``study`` runs the toolkit's own commands in order; ``table`` turns their
evaluations into the paper's Table 1 layout, the share of the gap each route closes and a verdict;
``plot`` draws it."""

from acn.transfer.study import TransferConfig, run_study
from acn.transfer.table import ROUTES, Route, TransferTable

__all__ = ["ROUTES", "Route", "TransferConfig", "TransferTable", "run_study"]
