"""Cell planners: the flow model of :mod:`sumo_swarm.planner.flow` solved by CP-SAT or SCIP.

A planner never raises into the caller: a bad model, an infeasible problem, a timeout or an
exception inside OR-Tools all come back as a :class:`Plan` with that status.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from typing import Protocol

from ortools.linear_solver import pywraplp
from ortools.sat.python import cp_model

from sumo_swarm.errors import ConfigError
from sumo_swarm.planner.flow import FlowModel, build_flow_model, extract_paths, hint_values
from sumo_swarm.planner.plan import Plan, failed_plan
from sumo_swarm.planner.problem import PlannerSettings, PlanningProblem, PlanStatus

_LOG = logging.getLogger(__name__)


class CellPlanner(Protocol):
    """Anything that turns a planning problem into a plan."""

    def plan(self, problem: PlanningProblem, hint: Plan | None = None) -> Plan: ...


class _FlowPlanner:
    """Shared plumbing: build the flow model, solve, split paths, time everything."""

    backend = "?"

    def __init__(self, time_limit_s: float, retry_without_blockers: bool = True) -> None:
        if not time_limit_s > 0:
            raise ConfigError(f"{type(self).__name__}: time_limit_s must be > 0")
        self.time_limit_s = float(time_limit_s)
        self.retry_without_blockers = retry_without_blockers

    def plan(self, problem: PlanningProblem, hint: Plan | None = None) -> Plan:
        started = time.perf_counter()
        try:
            result = self._plan_once(problem, hint, started)
            if (
                result.status is PlanStatus.INFEASIBLE
                and problem.blockers
                and self.retry_without_blockers
            ):
                # Space making is a means, not a goal: plan without blockers rather than not at all.
                retry = self._plan_once(problem.with_blockers(()), hint, started)
                if retry.ok:
                    return replace(retry, message=f"blockers dropped: {result.message}")
            return result
        except Exception as exc:  # the simulation loop must survive any solver failure
            _LOG.exception("%s planner failed", self.backend)
            elapsed = (time.perf_counter() - started) * 1e3
            return failed_plan(PlanStatus.ERROR, problem, self.backend, elapsed, repr(exc))

    def _plan_once(self, problem: PlanningProblem, hint: Plan | None, started: float) -> Plan:
        model = build_flow_model(problem)
        build_ms = (time.perf_counter() - started) * 1e3
        if model.infeasible_reason is not None:
            return failed_plan(
                PlanStatus.INFEASIBLE,
                problem,
                self.backend,
                build_ms,
                model.infeasible_reason,
                build_ms,
            )
        remaining = self.time_limit_s - (time.perf_counter() - started)
        if remaining <= 0:
            return failed_plan(
                PlanStatus.TIMEOUT, problem, self.backend, build_ms, "no time left", build_ms
            )
        hints = hint_values(model, hint.cells) if hint is not None and hint.cells else None
        status, edge_values, objective, bound, message = self._solve(model, remaining, hints)
        elapsed = (time.perf_counter() - started) * 1e3
        if edge_values is None:
            return failed_plan(status, problem, self.backend, elapsed, message, build_ms)
        cells = extract_paths(model, edge_values)
        return Plan(
            status=status,
            cells=cells,
            objective=objective / model.scale,
            solve_ms=elapsed,
            backend=self.backend,
            blockers={b.cav_id: b.hv_id for b in problem.blockers},
            message=message,
            cav_ids=problem.cav_ids,
            best_bound=None if bound is None else bound / model.scale,
            build_ms=build_ms,
            t0_s=problem.t0_s,
            behaving_interval_s=problem.behaving_interval_s,
        )

    def _solve(
        self, model: FlowModel, time_limit_s: float, hints: dict[int, int] | None
    ) -> tuple[PlanStatus, list[int] | None, float, float | None, str]:
        raise NotImplementedError


class CpSatPlanner(_FlowPlanner):
    """OR-Tools CP-SAT on the flow model; ``num_workers=1`` keeps it on one core."""

    backend = "cp-sat"

    def __init__(
        self, time_limit_s: float = 1.0, num_workers: int = 1, retry_without_blockers: bool = True
    ) -> None:
        super().__init__(time_limit_s, retry_without_blockers)
        self.num_workers = int(num_workers)

    def _solve(self, model, time_limit_s, hints):
        cp = cp_model.CpModel()
        x = [cp.new_bool_var(f"v{v}") for v in range(model.n_vars)]
        for kind, variables, coefs, rhs in model.constraints:
            if kind == "le" and len(variables) == 2 and rhs in (0, 1):
                a, b = x[variables[0]], x[variables[1]]
                if coefs == [1, -1] and rhs == 0:
                    cp.add_implication(a, b)
                    continue
                if coefs == [1, 1] and rhs == 1:
                    cp.add_at_most_one(a, b)
                    continue
            expr = cp_model.LinearExpr.weighted_sum([x[v] for v in variables], coefs)
            if kind == "eq":
                cp.add(expr == rhs)
            elif kind == "le":
                cp.add(expr <= rhs)
            else:
                cp.add(expr >= rhs)
        for var, value in model.fixed.items():
            cp.add(x[var] == value)
        terms = list(model.objective.items())
        cp.minimize(
            cp_model.LinearExpr.weighted_sum([x[v] for v, _ in terms], [c for _, c in terms])
        )
        if hints:
            for var, value in hints.items():
                cp.add_hint(x[var], value)
        solver = cp_model.CpSolver()
        solver.parameters.max_time_in_seconds = time_limit_s
        solver.parameters.num_workers = self.num_workers
        params = solver.parameters
        # The flow relaxation is nearly integral: give the LP every constraint up front
        # (linearization 2, not lazily) and skip presolve, which rewrites the flow
        # equalities into clauses the LP no longer sees (measured: 10 s -> ~60 ms).
        params.linearization_level = 2
        params.add_lp_constraints_lazily = False
        params.cp_model_presolve = False
        params.search_branching = cp_model.LP_SEARCH
        code = solver.solve(cp)
        status = {
            cp_model.OPTIMAL: PlanStatus.OPTIMAL,
            cp_model.FEASIBLE: PlanStatus.FEASIBLE,
            cp_model.INFEASIBLE: PlanStatus.INFEASIBLE,
            cp_model.UNKNOWN: PlanStatus.TIMEOUT,
        }.get(code, PlanStatus.ERROR)
        message = solver.status_name(code)
        if status not in (PlanStatus.OPTIMAL, PlanStatus.FEASIBLE):
            return status, None, 0.0, None, message
        values = [int(solver.boolean_value(x[j])) for j in range(len(model.edges))]
        return status, values, solver.objective_value, solver.best_objective_bound, message


class ScipPlanner(_FlowPlanner):
    """SCIP through OR-Tools' linear solver wrapper (HiGHS if SCIP is not compiled in)."""

    def __init__(self, time_limit_s: float = 1.0, retry_without_blockers: bool = True) -> None:
        super().__init__(time_limit_s, retry_without_blockers)
        self._solver_id = "SCIP"
        if pywraplp.Solver.CreateSolver("SCIP") is None:
            self._solver_id = "HIGHS"
        self.backend = self._solver_id.lower()

    def _solve(self, model, time_limit_s, hints):
        solver = pywraplp.Solver.CreateSolver(self._solver_id)
        if solver is None:
            return PlanStatus.ERROR, None, 0.0, None, f"{self._solver_id} unavailable"
        solver.SetNumThreads(1)
        n_edges = len(model.edges)
        aux = {var for _, var, _ in model.aux}
        # q and z follow from the edges and delta (each is a minimum of 0-1 values with a
        # negative cost); continuous keeps the branching on edges and deltas.
        x = [
            solver.NumVar(0.0, 1.0, "") if v >= n_edges and v in aux else solver.BoolVar("")
            for v in range(model.n_vars)
        ]
        for kind, variables, coefs, rhs in model.constraints:
            lower, upper = {
                "eq": (rhs, rhs),
                "le": (-solver.infinity(), rhs),
                "ge": (rhs, solver.infinity()),
            }[kind]
            row = solver.Constraint(lower, upper)
            for var, coef in zip(variables, coefs, strict=True):
                row.SetCoefficient(x[var], coef)
        for var, value in model.fixed.items():
            x[var].SetBounds(value, value)
        objective = solver.Objective()
        for var, coef in model.objective.items():
            objective.SetCoefficient(x[var], coef)
        objective.SetMinimization()
        if hints:
            solver.SetHint([x[v] for v in hints], [float(h) for h in hints.values()])
        solver.SetTimeLimit(max(1, int(time_limit_s * 1e3)))
        code = solver.Solve()
        if code == pywraplp.Solver.OPTIMAL:
            status = PlanStatus.OPTIMAL
        elif code == pywraplp.Solver.FEASIBLE:
            status = PlanStatus.FEASIBLE
        elif code == pywraplp.Solver.INFEASIBLE:
            status = PlanStatus.INFEASIBLE
        elif code == pywraplp.Solver.NOT_SOLVED:
            status = PlanStatus.TIMEOUT
        else:
            status = PlanStatus.ERROR
        message = f"{self._solver_id} status {code}"
        if status not in (PlanStatus.OPTIMAL, PlanStatus.FEASIBLE):
            return status, None, 0.0, None, message
        values = [round(x[j].solution_value()) for j in range(n_edges)]
        return status, values, objective.Value(), objective.BestBound(), message


def make_planner(settings: PlannerSettings) -> CellPlanner:
    """The planner the settings name (``backend``), with their time limit."""
    if settings.backend == "cp-sat":
        return CpSatPlanner(settings.time_limit_s, num_workers=settings.num_workers)
    if settings.backend == "scip":
        return ScipPlanner(settings.time_limit_s)
    raise ConfigError(f"unknown planner backend {settings.backend!r}")
