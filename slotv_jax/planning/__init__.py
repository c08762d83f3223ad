"""Legible motion planning for the Panda with any observer model (:mod:`.planner`: the
objective and the planner of one problem; :mod:`.compiled`: batches of problems, observers
and fitted families in one compiled program; :mod:`.caution`: planning for a lower confidence
bound over an ensemble of fits).

This package re-exports the planner's public names.
"""

from slotv_jax.planning.caution import lower_bound_observer
from slotv_jax.planning.compiled import (
    check_problems,
    make_family_planner,
    make_planner,
    straight_lines,
)
from slotv_jax.planning.planner import (
    MAX_RESIDUAL,
    Diagnostics,
    Observer,
    ObserverLike,
    PlannerConfig,
    PlanResult,
    Problem,
    check_observer,
    labeler_observer,
    legibility,
    metric_inverse,
    objective,
    plan,
    predictability_cost,
    stop_log_probs,
    straight_line,
)

__all__ = [
    "MAX_RESIDUAL",
    "Diagnostics",
    "Observer",
    "ObserverLike",
    "PlanResult",
    "PlannerConfig",
    "Problem",
    "check_observer",
    "check_problems",
    "labeler_observer",
    "legibility",
    "lower_bound_observer",
    "make_family_planner",
    "make_planner",
    "metric_inverse",
    "objective",
    "plan",
    "predictability_cost",
    "stop_log_probs",
    "straight_line",
    "straight_lines",
]
