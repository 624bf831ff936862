"""Swarming manoeuvre planner: the moving-cell MIP of paper Sec. II-B-2 (pure, no SUMO).

Public API::

    from sumo_swarm.core.planner import (
        PlanStatus, PlannerWeights, PlannerSettings, PlanningProblem, Blocker, build_problem,
        Plan, CellPlanner, CpSatPlanner, ScipPlanner, make_planner,
        validate_plan, shift_plan, ReplanTrigger, evaluate_objective,
    )
"""

from sumo_swarm.core.planner.plan import (
    Plan,
    ReplanTrigger,
    shift_plan,
    solved_problem,
    validate_plan,
)
from sumo_swarm.core.planner.problem import (
    Blocker,
    PlannerSettings,
    PlannerWeights,
    PlanningProblem,
    PlanStatus,
    assign_blockers,
    build_problem,
    evaluate_objective,
)
from sumo_swarm.core.planner.solvers import CellPlanner, CpSatPlanner, ScipPlanner, make_planner

__all__ = [
    "Blocker",
    "CellPlanner",
    "CpSatPlanner",
    "Plan",
    "PlanStatus",
    "PlannerSettings",
    "PlannerWeights",
    "PlanningProblem",
    "ReplanTrigger",
    "ScipPlanner",
    "assign_blockers",
    "build_problem",
    "evaluate_objective",
    "make_planner",
    "shift_plan",
    "solved_problem",
    "validate_plan",
]
