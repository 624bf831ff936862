"""Plans, the solver-independent plan validator, warm-start shifting and replanning triggers."""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace

from sumo_swarm.core.grid import Cell
from sumo_swarm.core.planner.problem import (
    PlanningProblem,
    PlanStatus,
    move_allowed,
    stay_exempt,
)
from sumo_swarm.errors import ConfigError

Paths = tuple[tuple[Cell, ...], ...]


@dataclass(frozen=True)
class Plan:
    """Result of one planner call.

    ``cells[i][k]`` is the ``(row, col)`` of CAV ``cav_ids[i]`` at step ``k`` (``k = 0`` the
    initial cell, time ``t0_s + k * behaving_interval_s``); ``None`` unless a solution was found.
    ``objective`` is in the units of the weights; ``best_bound`` the solver's lower bound.
    ``solve_ms`` is the wall time of the whole call (model build included), ``build_ms`` the
    part spent building the model, ``cpu_ms`` the process time of the call: what it costs on
    one free core (wall time grows with whatever else the machine runs).
    """

    status: PlanStatus
    cells: Paths | None
    objective: float | None
    solve_ms: float
    backend: str
    blockers: dict[str, str] = field(default_factory=dict)  # cav id -> hv id
    message: str = ""
    cav_ids: tuple[str, ...] = ()
    best_bound: float | None = None
    build_ms: float = 0.0
    t0_s: float = 0.0
    behaving_interval_s: float = 3.0
    cpu_ms: float | None = None
    # The problem's blockers could not all be placed and the plan was solved without any
    # (PlanningSolver.retry_without_blockers): it is valid for ``problem.with_blockers(())``.
    blockers_dropped: bool = False

    @property
    def ok(self) -> bool:
        """A plan with cells (optimal, or feasible when the time ran out)."""
        return self.cells is not None

    @property
    def n_steps(self) -> int:
        return len(self.cells[0]) if self.cells else 0

    def cells_of(self, cav_id: str) -> tuple[Cell, ...]:
        """Cells of one CAV, step 0 first. Raises ``KeyError`` for an unknown CAV or no cells."""
        if self.cells is None:
            raise KeyError(f"plan ({self.status.value}) has no cells")
        try:
            return self.cells[self.cav_ids.index(cav_id)]
        except ValueError:
            raise KeyError(cav_id) from None

    def cell_at(self, cav_id: str, k: int) -> Cell:
        """Cell of ``cav_id`` at step ``k``; past the horizon the last cell (the CAV stays)."""
        path = self.cells_of(cav_id)
        return path[min(max(k, 0), len(path) - 1)]


def failed_plan(
    status: PlanStatus,
    problem: PlanningProblem,
    backend: str,
    solve_ms: float,
    message: str,
    build_ms: float = 0.0,
) -> Plan:
    """A plan without cells (infeasible, timeout or error)."""
    return Plan(
        status=status,
        cells=None,
        objective=None,
        solve_ms=solve_ms,
        backend=backend,
        blockers={},
        message=message,
        cav_ids=problem.cav_ids,
        build_ms=build_ms,
        t0_s=problem.t0_s,
        behaving_interval_s=problem.behaving_interval_s,
    )


def solved_problem(problem: PlanningProblem, plan: Plan) -> PlanningProblem:
    """The problem ``plan`` solves: ``problem`` itself, or ``problem`` without blockers where
    the solver had to drop them (``plan.blockers_dropped``). Judged against ``problem``, such a
    plan broke the blockers it was never asked to place, and the swarm refused a usable plan
    (a paper-scene variant gave its overtake up 10 s later)."""
    return problem.with_blockers(()) if plan.blockers_dropped else problem


def validate_plan(problem: PlanningProblem, plan: Plan) -> list[str]:
    """Check every constraint of ``problem`` on ``plan``; an empty list means valid.

    Independent of the solver and the flow encoding: one cell per CAV per step inside the
    grid (eqs. (6)-(7)), moves of at most one row or one column (eqs. (8)-(13)), no shared
    cell at steps >= 1 (eq. (14)), no HV-claimed cell at steps >= 1 (eq. (15)), no two CAVs
    trading cells, blockers in place (eqs. (16)-(17)) and the initial cells (eqs. (18)-(19)).
    """
    if plan.cells is None:
        return [f"plan has no cells (status {plan.status.value})"]
    errors: list[str] = []
    cells = plan.cells
    if tuple(plan.cav_ids) != tuple(problem.cav_ids):
        errors.append(f"plan CAVs {plan.cav_ids} differ from problem CAVs {problem.cav_ids}")
    if len(cells) != problem.n_cavs:
        return [*errors, f"plan has {len(cells)} paths for {problem.n_cavs} CAVs"]
    n_steps = problem.n_steps
    for i, path in enumerate(cells):
        if len(path) != n_steps:
            return [*errors, f"CAV {problem.cav_ids[i]} has {len(path)} steps, need {n_steps}"]
    n_rows, n_cols = problem.n_rows, problem.n_cols
    for i, path in enumerate(cells):
        cav = problem.cav_ids[i]
        if path[0] != problem.start_cells[i]:
            errors.append(f"CAV {cav} starts in {path[0]}, not {problem.start_cells[i]}")
        for k, cell in enumerate(path):
            if len(cell) != 2:
                errors.append(f"CAV {cav} step {k}: {cell!r} is not a (row, col) cell")
                continue
            row, col = cell
            if not (0 <= row < n_rows and 0 <= col < n_cols):
                errors.append(f"CAV {cav} step {k}: {cell} outside the grid")
            if k >= 1:
                kept = cell == path[k - 1] and stay_exempt(problem, k - 1, cell)  # see stay_exempt
                if cell in problem.blocked[k] and not kept:
                    errors.append(f"CAV {cav} step {k}: {cell} is claimed by an HV")
                elif not move_allowed(problem, k - 1, path[k - 1], cell):
                    errors.append(f"CAV {cav} step {k}: enters {cell} inside an HV's margin")
                prev_row, prev_col = path[k - 1]
                if abs(row - prev_row) + abs(col - prev_col) > 1:
                    errors.append(f"CAV {cav} step {k}: jump {path[k - 1]} -> {cell}")
    for k in range(1, n_steps):
        now: dict[Cell, int] = {}
        for i, path in enumerate(cells):
            other = now.setdefault(path[k], i)
            if other != i:
                errors.append(
                    f"step {k}: CAVs {problem.cav_ids[other]} and {problem.cav_ids[i]} "
                    f"share {path[k]}"
                )
        before: dict[Cell, list[int]] = {}
        for i, path in enumerate(cells):
            before.setdefault(path[k - 1], []).append(i)
        for i, path in enumerate(cells):
            src, dst = path[k - 1], path[k]
            if src == dst:
                continue
            for j in before.get(dst, ()):
                if i < j and cells[j][k] == src:
                    errors.append(
                        f"step {k}: CAVs {problem.cav_ids[i]} and {problem.cav_ids[j]} swap "
                        f"{src} <-> {dst}"
                    )
    for blocker in problem.blockers:
        path = cells[blocker.cav_index]
        for k in range(1, blocker.hold_steps + 1):
            if path[k] != blocker.cell:
                errors.append(
                    f"blocker {blocker.cav_id} is in {path[k]} at step {k}, not {blocker.cell}"
                )
    expected = {b.cav_id: b.hv_id for b in problem.blockers}
    if plan.blockers != expected:
        errors.append(f"plan blockers {plan.blockers} differ from the problem's {expected}")
    return errors


def shift_plan(plan: Plan, executed_steps: int, row_offset: int = 0) -> Plan:
    """The rest of ``plan`` after ``executed_steps`` steps, padded by staying (a warm-start hint).

    The horizon keeps its length; ``t0_s`` moves on by the executed steps. ``row_offset`` is
    how many rows the new grid's row 0 lies ahead of the old one's at the new ``t0_s`` (a
    replan builds its grid at the tail CAV again), so the cells land in the new grid's rows;
    cells that fall off the grid only make the hint partial.
    """
    if plan.cells is None or (executed_steps <= 0 and row_offset == 0):
        return plan
    steps = max(executed_steps, 0)
    shifted = tuple(
        tuple(
            (path[min(k, len(path) - 1)][0] - row_offset, path[min(k, len(path) - 1)][1])
            for k in range(steps, steps + len(path))
        )
        for path in plan.cells
    )
    return replace(
        plan,
        cells=shifted,
        t0_s=plan.t0_s + steps * plan.behaving_interval_s,
        message=f"shifted by {steps} steps and {row_offset} rows",
    )


class ReplanTrigger:
    """Event-triggered replanning (paper Fig. 4), plus a drift check.

    Call :meth:`check` every control step with the CAVs' current cells (in the grid the plan
    was made in) and the ids of the HVs now in the grid; it returns why to replan or ``None``.
    After replanning call :meth:`planned`.

    Reasons: ``"initial"`` (no usable plan yet, or the last solve failed and
    ``retry_interval_s`` has passed), ``"new_hv"`` (an HV not seen at planning time is in the
    grid), ``"plan_done"`` (every planned step has been executed), ``"drift"`` (a CAV is more
    than ``drift_cells`` cells, Manhattan, from both its cell of the current step and of the
    next, or a CAV is not in the plan).
    """

    def __init__(self, drift_cells: int = 1, retry_interval_s: float = 3.0) -> None:
        if drift_cells < 0 or not math.isfinite(retry_interval_s) or retry_interval_s < 0:
            raise ConfigError("ReplanTrigger: drift_cells and retry_interval_s must be >= 0")
        self.drift_cells = drift_cells
        self.retry_interval_s = retry_interval_s
        self.plan: Plan | None = None
        self.planned_at_s: float | None = None
        self.known_hvs: frozenset[str] = frozenset()

    def planned(self, plan: Plan, now_s: float, hv_ids: Iterable[str]) -> None:
        """Record a new plan and the HVs that were in the grid when it was made."""
        self.plan = plan
        self.planned_at_s = now_s
        self.known_hvs = frozenset(hv_ids)

    def current_step(self, now_s: float) -> int:
        """Index of the plan step being executed at ``now_s`` (0 right after planning)."""
        if self.plan is None:
            return 0
        return math.floor((now_s - self.plan.t0_s) / self.plan.behaving_interval_s + 1e-9)

    def check(
        self, now_s: float, cav_cells: Mapping[str, Cell], hv_ids: Iterable[str]
    ) -> str | None:
        """Why to replan now, or ``None`` to keep executing the plan."""
        plan = self.plan
        if plan is None:
            return "initial"
        if plan.cells is None:
            waited = now_s - (self.planned_at_s if self.planned_at_s is not None else -math.inf)
            return "initial" if waited >= self.retry_interval_s else None
        if not frozenset(hv_ids) <= self.known_hvs:
            return "new_hv"
        step = self.current_step(now_s)
        if step >= plan.n_steps - 1:
            return "plan_done"
        for cav_id, (row, col) in cav_cells.items():
            if cav_id not in plan.cav_ids:
                return "drift"
            path = plan.cells_of(cav_id)
            near = min(abs(row - r) + abs(col - c) for r, c in (path[max(step, 0)], path[step + 1]))
            if near > self.drift_cells:
                return "drift"
        return None
