"""Cell planners: the flow model of :mod:`sumo_swarm.core.planner.flow` solved by CP-SAT or SCIP.

A planner never raises into the caller: a bad model, an infeasible problem, a timeout or an
exception inside OR-Tools all come back as a :class:`Plan` with that status.
"""

from __future__ import annotations

import functools
import logging
import time
from dataclasses import replace
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np

from sumo_swarm.core.planner.flow import (
    FlowModel,
    build_flow_model,
    extract_paths,
    hint_values,
    uncross_swaps,
)
from sumo_swarm.core.planner.network import NetworkResult, solve_network
from sumo_swarm.core.planner.plan import Plan, failed_plan
from sumo_swarm.core.planner.problem import (
    PlannerSettings,
    PlanningProblem,
    PlanStatus,
    evaluate_objective,
)
from sumo_swarm.errors import ConfigError

if TYPE_CHECKING:
    from ortools.sat.python import cp_model

# OR-Tools is imported when a solver is first made or used, not with this module: a run whose
# controller never plans (sumo-cacc, cacc) does not pay for the import (~0.15 s).

_LOG = logging.getLogger(__name__)


class CellPlanner(Protocol):
    """Anything that turns a planning problem into a plan."""

    def plan(self, problem: PlanningProblem, hint: Plan | None = None) -> Plan: ...


class _FlowPlanner:
    """Shared plumbing: build the flow model, solve, split paths, time everything.

    ``time_limit_s`` is the wall budget of one call, model building included: when it runs
    out the best plan found so far comes back ``FEASIBLE`` (``TIMEOUT`` only without one).
    """

    backend = "?"

    def __init__(
        self,
        time_limit_s: float,
        retry_without_blockers: bool = True,
        network_work: int = 0,
        network_only: bool = False,
        network_ref_cavs: int = 0,
    ) -> None:
        if not time_limit_s > 0:
            raise ConfigError(f"{type(self).__name__}: time_limit_s must be > 0")
        if not isinstance(network_ref_cavs, int) or network_ref_cavs < 0:
            raise ConfigError(f"{type(self).__name__}: network_ref_cavs must be an int >= 0")
        if not isinstance(network_work, int) or network_work < 0:
            raise ConfigError(f"{type(self).__name__}: network_work must be an int >= 0")
        self.time_limit_s = float(time_limit_s)
        self.retry_without_blockers = retry_without_blockers
        # Work (arcs x flows) of the exact network search (core/planner/network.py) before the
        # MIP solver is called (0: the MIP solver only); with ``network_only`` a search that
        # does not finish returns its best plan (FEASIBLE) instead of calling the solver.
        self.network_work = network_work
        self.network_only = network_only
        self.network_ref_cavs = network_ref_cavs  # see PlannerSettings.network_ref_cavs

    def plan(self, problem: PlanningProblem, hint: Plan | None = None) -> Plan:
        """Solve ``problem``; ``hint`` (e.g. the shifted last plan) is a warm start only."""
        started = time.perf_counter()
        cpu_started = time.process_time()
        plan = self._plan_timed(problem, hint, started)
        return replace(plan, cpu_ms=(time.process_time() - cpu_started) * 1e3)

    def _plan_timed(self, problem: PlanningProblem, hint: Plan | None, started: float) -> Plan:
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
                    return replace(
                        retry, message=f"blockers dropped: {result.message}", blockers_dropped=True
                    )
            return result
        except Exception as exc:  # the simulation loop must survive any solver failure
            _LOG.exception("%s planner failed", self.backend)
            elapsed = (time.perf_counter() - started) * 1e3
            return failed_plan(PlanStatus.ERROR, problem, self.backend, elapsed, repr(exc))

    def _plan_work(self, problem: PlanningProblem) -> int | None:
        """The work after which the network search returns the plan it has: ``network_work``
        shrunk in proportion above ``network_ref_cavs`` CAVs (None: not shrunk)."""
        ref, n_cavs = self.network_ref_cavs, problem.n_cavs
        if ref and n_cavs > ref:
            return self.network_work * ref // n_cavs
        return None

    def _plan_once(self, problem: PlanningProblem, hint: Plan | None, started: float) -> Plan:
        # The network search needs no constraint rows; the MIP solver's model gets them.
        model = build_flow_model(problem, rows=not self.network_work)
        if model.infeasible_reason is not None:
            build_ms = (time.perf_counter() - started) * 1e3
            return failed_plan(
                PlanStatus.INFEASIBLE,
                problem,
                self.backend,
                build_ms,
                model.infeasible_reason,
                build_ms,
            )
        network = None
        hints = _usable_hint(model, hint)
        if self.network_work:
            remaining = self.time_limit_s - (time.perf_counter() - started)
            if remaining <= 0:
                build_ms = (time.perf_counter() - started) * 1e3
                return failed_plan(
                    PlanStatus.TIMEOUT, problem, self.backend, build_ms, "no time left", build_ms
                )
            build_ms = (time.perf_counter() - started) * 1e3
            network = solve_network(
                model, remaining, hint=hints, max_work=self.network_work,
                plan_work=self._plan_work(problem),
            )  # fmt: skip
        if network is not None and (
            network.status in ("optimal", "infeasible") or self.network_only
        ):
            status, edge_values, objective, bound, message = _network_outcome(network)
        else:
            if network is not None:
                model = build_flow_model(problem)  # now with the rows (same nodes and edges)
                hints = _usable_hint(model, hint)
                if network.edge_values is not None:
                    hints = _network_hint(model, network.edge_values)  # the best plan so far
            prepared = self._prepare(model, hints)
            build_ms = (time.perf_counter() - started) * 1e3
            remaining = self.time_limit_s - (time.perf_counter() - started)
            if remaining <= 0:
                return failed_plan(
                    PlanStatus.TIMEOUT, problem, self.backend, build_ms, "no time left", build_ms
                )
            status, edge_values, objective, bound, message = self._solve(model, prepared, remaining)
            if network is not None:
                status, edge_values, objective, bound, message = _better(
                    (status, edge_values, objective, bound, message), network
                )
        if edge_values is None:
            elapsed = (time.perf_counter() - started) * 1e3
            return failed_plan(status, problem, self.backend, elapsed, message, build_ms)
        edge_values, swaps = uncross_swaps(model, edge_values)
        cells = extract_paths(model, edge_values)
        objective /= model.scale
        if swaps:
            # Uncrossing never costs more; a non-optimal solution may even get cheaper.
            objective = evaluate_objective(problem, cells)
        elapsed = (time.perf_counter() - started) * 1e3
        return Plan(
            status=status,
            cells=cells,
            objective=objective,
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

    def _prepare(self, model: FlowModel, hints: list[int] | None) -> Any:
        """The backend's model (built before the clock of the search starts)."""
        raise NotImplementedError

    def _solve(
        self, model: FlowModel, prepared: Any, time_limit_s: float
    ) -> tuple[PlanStatus, list[int] | None, float, float | None, str]:
        """Status, edge values, integer objective and bound, message."""
        raise NotImplementedError


def _network_outcome(
    network: NetworkResult,
) -> tuple[PlanStatus, list[int] | None, float, float | None, str]:
    """The network search's result in the form of ``_solve``."""
    status = {
        "optimal": PlanStatus.OPTIMAL,
        "feasible": PlanStatus.FEASIBLE,
        "infeasible": PlanStatus.INFEASIBLE,
    }.get(network.status, PlanStatus.TIMEOUT)
    message = f"network: {network.message} after {network.branches} flows"
    if network.edge_values is None:
        return status, None, 0.0, None, message
    return status, network.edge_values, float(network.objective), network.bound, message


def _better(
    solved: tuple[PlanStatus, list[int] | None, float, float | None, str],
    network: NetworkResult,
) -> tuple[PlanStatus, list[int] | None, float, float | None, str]:
    """The MIP solver's outcome, or the network's best plan where the solver found no better
    one; the bound is the higher of the two (both are valid lower bounds)."""
    status, values, objective, bound, message = solved
    if network.bound is not None:
        bound = network.bound if bound is None else max(bound, network.bound)
    if network.edge_values is not None and (values is None or network.objective < objective):
        return (
            PlanStatus.FEASIBLE, network.edge_values, float(network.objective), bound,
            f"{message}; network plan kept",
        )  # fmt: skip
    if status is PlanStatus.TIMEOUT and network.status == "infeasible":
        return PlanStatus.INFEASIBLE, None, 0.0, None, message
    return status, values, objective, bound, message


def _network_hint(model: FlowModel, edge_values: list[int]) -> list[int]:
    """Every variable's value for the network's flow (a complete, feasible solver hint)."""
    values, _ = uncross_swaps(model, edge_values)
    return hint_values(model, extract_paths(model, values))


def _usable_hint(model: FlowModel, hint: Plan | None) -> list[int] | None:
    """Variable values of ``hint``'s cells (CAV order does not matter to the flow)."""
    if hint is None or not hint.cells:
        return None
    try:
        return hint_values(model, hint.cells)
    except (TypeError, ValueError, IndexError):  # a malformed hint must not spoil the solve
        _LOG.warning("planner hint ignored: cells are not (row, col) paths")
        return None


def _join(values: list[int]) -> str:
    return ",".join(map(str, values))


def cp_sat_constraints_text(model: FlowModel) -> str:
    """The flow model's constraints in CP-SAT's protobuf text format.

    Parsing one string in C++ is several times faster than adding ~1000 rows one Python call
    at a time (each row costs 4-5 calls into the protobuf wrapper).
    """
    parts = []
    rows = model.linear
    var_text, coef_text = list(map(str, rows.vars)), list(map(str, rows.coefs))
    for i in range(len(rows)):
        a, b = rows.start[i], rows.start[i + 1]
        parts.append(
            f"constraints{{linear{{vars:[{','.join(var_text[a:b])}] "
            f"coeffs:[{','.join(coef_text[a:b])}] domain:[{rows.lo[i]},{rows.hi[i]}]}}}}"
        )
    parts.extend(f"constraints{{at_most_one{{literals:[{_join(s)}]}}}}" for s in model.at_most_one)
    parts.extend(
        f"constraints{{enforcement_literal:{a} bool_and{{literals:[{b}]}}}}"
        for a, b in model.implies
    )
    return "".join(parts)


@functools.cache
def _boolean() -> Any:
    """The proto of a 0-1 variable, copied into every model."""
    from ortools.sat.python import cp_model_helper

    boolean = cp_model_helper.IntegerVariableProto()
    boolean.domain.extend([0, 1])
    return boolean


def fill_cp_sat_model(cp: cp_model.CpModel, model: FlowModel, hints: list[int] | None) -> None:
    """Replace the content of ``cp`` by the flow model (and its hint)."""
    proto = cp.proto
    if not proto.parse_text_format(cp_sat_constraints_text(model)):
        raise RuntimeError("CP-SAT rejected the model text")
    # Whole lists go through one call each: copies of one Boolean, then the few fixings.
    proto.variables.extend([_boolean()] * model.n_vars)
    for var in np.flatnonzero((model.lower != 0) | (model.upper != 1)).tolist():
        domain = proto.variables[var].domain
        domain[0], domain[1] = int(model.lower[var]), int(model.upper[var])
    terms = np.flatnonzero(model.objective)
    proto.objective.vars.extend(terms.tolist())
    proto.objective.coeffs.extend(model.objective[terms].tolist())
    if hints is not None:
        proto.solution_hint.vars.extend(range(len(hints)))
        proto.solution_hint.values.extend(hints)


class CpSatPlanner(_FlowPlanner):
    """OR-Tools CP-SAT on the flow model; ``num_workers=1`` keeps it on one core."""

    backend = "cp-sat"

    def __init__(
        self,
        time_limit_s: float = 1.0,
        num_workers: int = 1,
        retry_without_blockers: bool = True,
        work_limit: float | None = None,
        network_work: int = 0,
        network_only: bool = False,
        network_ref_cavs: int = 0,
    ) -> None:
        super().__init__(
            time_limit_s, retry_without_blockers, network_work, network_only, network_ref_cavs
        )
        self.num_workers = int(num_workers)
        if work_limit is not None and not work_limit > 0:
            raise ConfigError(f"CpSatPlanner: work_limit must be > 0, got {work_limit!r}")
        self.work_limit = work_limit
        self._cp: cp_model.CpModel | None = None

    def _prepare(self, model, hints):
        # One CpModel per planner, its proto replaced by every parse: constructing a CpModel
        # costs ~0.5 ms of Python set-up each time.
        if self._cp is None:
            from ortools.sat.python import cp_model

            self._cp = cp_model.CpModel()
        fill_cp_sat_model(self._cp, model, hints)
        return self._cp

    def _solve(self, model, prepared, time_limit_s):
        from ortools.sat.python import cp_model

        solver = cp_model.CpSolver()
        params = solver.parameters
        params.max_time_in_seconds = time_limit_s
        if self.work_limit is not None:  # load-independent: the same plan on any machine state
            params.max_deterministic_time = self.work_limit
        params.num_workers = self.num_workers
        # The flow relaxation is nearly integral: give the LP every constraint up front
        # (linearization 2, not lazily) and skip presolve, which rewrites the flow
        # equalities into clauses the LP no longer sees (measured: 10 s -> ~60 ms).
        params.linearization_level = 2
        params.add_lp_constraints_lazily = False
        params.cp_model_presolve = False
        # Probing and symmetry detection cost ~15 ms per call and never paid off here; cuts
        # doubled the time of the hardest random scene (9 CAVs, 5 lanes) without closing
        # its gap faster. Search: the default (not LP_SEARCH), which proves that scene in
        # ~0.15 s instead of running into the 1 s limit.
        params.cp_model_probing_level = 0
        params.symmetry_level = 0
        params.cut_level = 0
        code = solver.solve(prepared)
        status = {
            cp_model.OPTIMAL: PlanStatus.OPTIMAL,
            cp_model.FEASIBLE: PlanStatus.FEASIBLE,
            cp_model.INFEASIBLE: PlanStatus.INFEASIBLE,
            cp_model.UNKNOWN: PlanStatus.TIMEOUT,
        }.get(code, PlanStatus.ERROR)
        message = solver.status_name(code)
        if status not in (PlanStatus.OPTIMAL, PlanStatus.FEASIBLE):
            return status, None, 0.0, None, message
        values = list(solver.response_proto.solution)[: model.n_edges]
        return status, values, solver.objective_value, solver.best_objective_bound, message


class ScipPlanner(_FlowPlanner):
    """SCIP through OR-Tools' linear solver wrapper (HiGHS if SCIP is not compiled in)."""

    def __init__(self, time_limit_s: float = 1.0, retry_without_blockers: bool = True) -> None:
        from ortools.linear_solver import pywraplp

        super().__init__(time_limit_s, retry_without_blockers)
        self._solver_id = "SCIP"
        if pywraplp.Solver.CreateSolver("SCIP") is None:
            self._solver_id = "HIGHS"
        self.backend = self._solver_id.lower()

    def _prepare(self, model, hints):
        from ortools.linear_solver import pywraplp

        solver = pywraplp.Solver.CreateSolver(self._solver_id)
        if solver is None:
            raise RuntimeError(f"{self._solver_id} unavailable")
        solver.SetNumThreads(1)
        aux = {var for var, _ in model.q_vars} | {var for var, _ in model.z_vars}
        lower, upper = model.lower.tolist(), model.upper.tolist()
        # q and z follow from the edges and delta (each is a minimum of 0-1 values with a
        # negative cost); continuous keeps the branching on edges and deltas.
        x = [
            solver.NumVar(lower[v], upper[v], "")
            if v in aux
            else solver.IntVar(lower[v], upper[v], "")
            for v in range(model.n_vars)
        ]
        rows = model.linear
        for i in range(len(rows)):
            variables, coefs, lo, hi = rows.row(i)
            row = solver.Constraint(lo, hi)
            for var, coef in zip(variables, coefs, strict=True):
                row.SetCoefficient(x[var], coef)
        for group in model.at_most_one:
            row = solver.Constraint(-solver.infinity(), 1)
            for var in group:
                row.SetCoefficient(x[var], 1)
        for a, b in model.implies:
            row = solver.Constraint(-solver.infinity(), 0)
            row.SetCoefficient(x[a], 1)
            row.SetCoefficient(x[b], -1)
        objective = solver.Objective()
        for var in np.flatnonzero(model.objective).tolist():
            objective.SetCoefficient(x[var], int(model.objective[var]))
        objective.SetMinimization()
        if hints:
            solver.SetHint(x, [float(h) for h in hints])
        return solver, x

    def _solve(self, model, prepared, time_limit_s):
        from ortools.linear_solver import pywraplp

        solver, x = prepared
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
        values = [round(x[j].solution_value()) for j in range(model.n_edges)]
        objective = solver.Objective()
        return status, values, objective.Value(), objective.BestBound(), message


def make_planner(settings: PlannerSettings) -> CellPlanner:
    """The planner the settings name (``backend``), with their time limit."""
    if settings.backend == "cp-sat":
        return CpSatPlanner(
            settings.time_limit_s, num_workers=settings.num_workers, work_limit=settings.work_limit,
            network_work=settings.network_work, network_only=settings.network_only,
            network_ref_cavs=settings.network_ref_cavs,
        )  # fmt: skip
    if settings.backend == "scip":
        return ScipPlanner(settings.time_limit_s)
    raise ConfigError(f"unknown planner backend {settings.backend!r}")
