"""Planning robot translations for calibration, with the accuracy predicted (issue 12).

:func:`plan` chooses the translations, :func:`evaluate_plan` predicts what given ones
achieve; both from the Cramér–Rao bound of a scene model (:mod:`.model`). The package is
named ``planning`` (not ``plan``) so that the subpackage never shadows the function
``transcalib.plan``.
"""

from .model import CRITERIA, PlanOptions, view_rotation
from .patterns import PATTERNS
from .plan import Evaluation, Plan, evaluate_plan, plan

__all__ = ["plan", "evaluate_plan", "Plan", "Evaluation", "PlanOptions", "PATTERNS", "CRITERIA", "view_rotation"]
