"""Planner settings and the cell-level planning problem (paper Sec. II-B-2).

A :class:`PlanningProblem` is pure cell arithmetic: grid size, horizon, start cells, the cells
HVs block at each step, the target HV's rows (for the goal region and the paper's delta),
the regroup lane, blocker assignments and weights. :func:`build_problem` derives it from
vehicle states and a :class:`~sumo_swarm.core.grid.MovingGrid`.

Steps are numbered ``k = 0 .. n_steps - 1`` here; step 0 is the paper's ``k = 1`` (the
initial cells, eqs. (18)-(19)).
"""

from __future__ import annotations

import functools
import math
import typing
from collections import Counter
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from enum import Enum
from typing import Literal

import numpy as np

from sumo_swarm.checks import check_fields, require_number
from sumo_swarm.core.grid import (
    Cell,
    ConstantSpeedPredictor,
    GridSettings,
    HvPredictor,
    MovingGrid,
    cav_cell,
    hv_blocked_cells,
    hv_blocked_rows,
    hv_columns,
)
from sumo_swarm.core.model import VehicleState
from sumo_swarm.errors import ConfigError

Backend = Literal["cp-sat", "scip"]
TargetForm = Literal["paper", "distance"]
DeltaMode = Literal["swarm", "cav"]
BACKENDS: tuple[str, ...] = typing.get_args(Backend)
TARGET_FORMS: tuple[str, ...] = typing.get_args(TargetForm)
DELTA_MODES: tuple[str, ...] = typing.get_args(DeltaMode)


class PlanStatus(str, Enum):  # noqa: UP042 - the integrator asked for str + Enum
    """Outcome of one planner call."""

    OPTIMAL = "optimal"
    FEASIBLE = "feasible"
    INFEASIBLE = "infeasible"
    TIMEOUT = "timeout"
    ERROR = "error"


@dataclass(frozen=True)
class PlannerWeights:
    """Weights of the objective, eq. (5) (dimensionless cost per step or per move).

    ``w_tar`` is charged per CAV per step spent behind the goal region (or per row behind it,
    ``target_form="distance"``); a move of one row costs ``2 * w_lon`` and a move of one
    column ``2 * w_lat`` (the one-hot squared differences of eq. (5) sum to 2 per move); a CAV
    ``d`` columns off the regroup lane costs ``w_lat * d**2`` per step once no CAV is impeded.

    Attributes
    ----------
    w_tar
        Cost per CAV per step (or row) behind the goal region, eq. (5) [1].
    w_lon
        Half the cost of a move of one row, eq. (5) [1].
    w_lat
        Half the cost of a move of one column, eq. (5) [1].
    """

    w_tar: float = 30.0
    w_lon: float = 1.0
    w_lat: float = 3.0

    def __post_init__(self) -> None:
        for name in ("w_tar", "w_lon", "w_lat"):
            require_number(f"PlannerWeights.{name}", getattr(self, name), ge=0.0)


@dataclass(frozen=True)
class PlannerSettings:
    """Settings of the cell planner, checked once at set-up.

    Attributes
    ----------
    n_steps
        Horizon N in behaving steps, the initial step included.
    behaving_interval_s
        Duration of one behaving step, Delta T [s].
    backend
        ``"cp-sat"`` (OR-Tools CP-SAT) or ``"scip"`` (OR-Tools linear solver, SCIP).
    time_limit_s
        Wall-clock budget of one planner call, model build included [s]: when it runs out the
        best plan found so far is returned (status ``feasible``), a timeout only without one.
        A safety net for a loaded machine (issue 11: max 250 ms per call): the budgets that
        bind are ``network_work`` and, when CP-SAT runs, ``work_limit`` (at most ~0.75 s of
        wall time: with CP-SAT alone, raise this to keep its plans load-independent; the
        ``scip`` backend, a cross-check without the network search, needs ~1 s).
    work_limit
        CP-SAT's deterministic time budget of one solve [CP-SAT work units] (about 2-3 s of
        wall time per unit on the project's machine): the plan returned is the same however
        loaded the machine is, so runs are reproducible. 0.25 covers every solve measured on
        the paper scene (at most 0.1) with room; ``None``: the wall budget only.
    weights
        :class:`PlannerWeights`, or a mapping with keys ``w_tar``, ``w_lon``, ``w_lat``.
    regroup_lane
        Lane ``l_index`` to regroup in [lane]; ``None`` = the target HV's lane (the lane where the
        platoon was impeded, i.e. its original lane).
    target_form
        ``"paper"``: ``w_tar`` per step behind the goal region (eq. (5)); ``"distance"``:
        ``w_tar`` per row behind it.
    delta_mode
        ``"swarm"``: the paper's delta, 1 at a step while any CAV is impeded; ``"cav"``: each
        CAV's own (it pays the regroup term once it is past, whatever the others do).
    block_steps
        Steps (from step 1) a blocker holds its blocking cell, eqs. (16)-(17): the paper's 1 by
        default. A blocker that holds its row keeps the gap to the HV behind it as it is; the
        space for the others to cut in opens when it moves on, faster than the HV can follow
        (the prediction of the blocked HV follows the blocker, see the swarm's manoeuvre).
        ``"auto"``: one step per CAV still to cut through behind the blocker.
    max_blockers
        How many front CAVs may be assigned as blockers (one per adjacent lane) [CAVs].
    release_idle_holds
        A hold is *idle* when no CAV still to pass the target, in a lane beside the HV's, is
        more than ``idle_hold_rows`` ahead of that HV (:func:`hold_useful`): the space in
        front of it is of no use to any of them, and they can only get past once it has gone
        on. With ``True`` no blocker is assigned to such an HV, and a CAV in front of it in its
        lane pays ``w_lat`` per step (:func:`idle_hold_cells`), as does a CAV in the first
        ``idle_clear_rows`` rows of the regroup lane ahead of the target: a CAV already past
        leaves the HV's lane and merges ahead of the target. ``"stranded"``: the same, but only
        in a replan made while the plan in force keeps a CAV behind the target in its cell to
        its end (a stall that otherwise ends in a ``cavs_stranded`` give-up). ``False``
        (default, the paper): delta waives every lateral term while a CAV is impeded, so the
        CAVs already past sit in the side lanes at the grid's speed and hold the HVs behind
        them whether or not that makes space for anyone. Measured on 150 paper-scene variants,
        the stress sweep and the users' roads (README "Variant sweep", 2026-12-04): ``True``
        slows the upstream HVs 10-25 % less with the CAVs as fast, but 2 of the 40 repository
        variants and 2 stress scenes lose their regroup; ``"stranded"`` changes few runs and
        passes one held-out and one stress scene more, but one repository variant no longer
        regroups before the road ends and the users' CAV-flow road is 2.2 m/s slower over
        SUMO's seeds 1-3. Neither is the default.
    idle_hold_rows
        How far [rows, continuous, centre to centre] a CAV still to pass, in a lane beside a
        held HV's, must be ahead of that HV for the hold to count as making space for it. A
        held HV slows to the grid's speed behind its blocker and falls back a little while the
        CAVs beside it keep theirs: one row (15 m) is enough to cut in front of it; 1.5 rows
        released a hold that was letting a CAV in (held-out variant, seed 47 scene 6).
    idle_clear_rows
        Rows of the regroup lane from the goal row that charge for an idle hold too: a CAV
        that merged into the target's lane just ahead of it (the goal row) slowed the truck
        from 13.4 to 12.8 m/s (IDM brakes for a car 25 m ahead at its own speed), and the CAVs
        behind it fell back out of the grid (repository variant 17). 0: merge anywhere.
    num_workers
        CP-SAT search workers (keep 1 on a shared machine) [threads].
    network_work
        Work budget [arcs x flows] of the exact network search
        (:mod:`sumo_swarm.core.planner.network`:
        min-cost flows, branch and bound over the paper's delta) run before CP-SAT: flows are
        solved while the sum of their networks' arc counts stays within it (a flow costs about
        1.5 us of cpu per arc). A problem with every delta fixed takes one flow and is proved
        at once; the paper scene's (6 CAVs, 1700-2400 arcs) need 15-16 flows (26000-36000) to
        be proved; a 12-CAV one (3000-3700 arcs) gets about 6 flows. 20000 keeps the solve
        within 50 ms of CPU (p95 over the 40-scene variant sweep: 45.8 ms CPU against 70.3 ms
        at 36000, mean CAV speed the same: +0.02 m/s) at a price in proofs: on the stored
        swarm problems 12 of 50 proved (17 at 36000) and plans at most 4.2 % above the best
        known objective. 16000 was tried (twenty-second session): the same plan for all 50
        stored problems at CPU p95 / max 22.8 / 28.1 ms against 27.3 / 32.7 (alternated in one
        process), but in closed loop it planned 9-10 CAVs worse: 7 of the 200 stress scenes
        slower by 0.11-1.75 m/s, 3 of them no longer regrouped; 20000 stays. (The 150 s variant
        runs where 20000 had a per-run planner CPU p95 of 52-58 ms were on a machine that took
        51 ms at p95 for those 50 problems.) ``sumo-swarm reproduce`` gives the swarm 150000
        (every plan of the paper scene proved). A search that finishes proves the optimum (or
        infeasibility) and CP-SAT is not called. A count, not a time: the plan does not depend
        on the machine's load. 0: CP-SAT only, as before.
    network_ref_cavs
        The CAV count ``network_work`` is meant for [CAVs]: above it a search that has found a plan
        stops at ``network_work * network_ref_cavs / n_cavs`` (one without a plan goes on
        within ``network_work``: a 12-CAV problem found none in 3 flows). A flow carries one
        augmenting path per CAV, so its cost grows with both arcs and CAVs: 10-CAV stress
        problems (about 2900 arcs) took 8-9 ms a flow, 7 flows within 20000, up to 61 ms of
        CPU (7 runs of 200 above 50 ms at p95); the paper scene's 6 CAVs take 2-3 ms a flow.
        6: the paper scene and anything smaller plan as before, 10 CAVs stop at 12000 (4
        flows). A count: the plan is still the same on every machine. 0: ``network_work``
        whatever the CAVs.
    network_only
        When the network search does not finish, return its best plan (``feasible``, with the
        search's lower bound) instead of calling CP-SAT (``false``: CP-SAT continues from that
        plan within the time budget, the way to prove more plans optimal at a cost in time).
    """

    n_steps: int = 14
    behaving_interval_s: float = 3.0
    backend: Backend = "cp-sat"
    time_limit_s: float = 0.25
    work_limit: float | None = 0.25
    weights: PlannerWeights = field(default_factory=PlannerWeights)
    regroup_lane: int | None = None
    target_form: TargetForm = "distance"
    delta_mode: DeltaMode = "swarm"
    block_steps: int | Literal["auto"] = 1
    max_blockers: int = 2
    release_idle_holds: bool | Literal["stranded"] = False
    idle_hold_rows: float = 1.0
    idle_clear_rows: int = 2
    num_workers: int = 1
    network_work: int = 20_000
    network_only: bool = True
    network_ref_cavs: int = 6

    def __post_init__(self) -> None:
        if isinstance(self.weights, Mapping):
            unknown = set(self.weights) - {"w_tar", "w_lon", "w_lat"}
            if unknown:
                raise ConfigError(f"PlannerSettings.weights: unknown keys {sorted(unknown)}")
            object.__setattr__(self, "weights", PlannerWeights(**self.weights))
        elif not isinstance(self.weights, PlannerWeights):
            raise ConfigError(
                f"PlannerSettings.weights must be PlannerWeights or a mapping, "
                f"got {type(self.weights).__name__}"
            )
        _require_int("n_steps", self.n_steps, minimum=2, maximum=MAX_PLAN_STEPS)
        if self.block_steps != "auto":
            _require_int("block_steps", self.block_steps, minimum=1)
        _require_int("max_blockers", self.max_blockers, minimum=0)
        _require_int("idle_clear_rows", self.idle_clear_rows, minimum=0)
        _require_int("num_workers", self.num_workers, minimum=1)
        _require_int("network_work", self.network_work, minimum=0)
        _require_int("network_ref_cavs", self.network_ref_cavs, minimum=0)
        require_number("PlannerSettings.idle_hold_rows", self.idle_hold_rows, ge=0.0)
        if not isinstance(self.release_idle_holds, bool) and self.release_idle_holds != "stranded":
            raise ConfigError(
                'PlannerSettings.release_idle_holds must be true, false or "stranded", '
                f"got {self.release_idle_holds!r}"
            )
        if not isinstance(self.network_only, bool):
            raise ConfigError(
                f"PlannerSettings.network_only must be true or false, got {self.network_only!r}"
            )
        if self.block_steps != "auto" and self.block_steps >= self.n_steps:
            raise ConfigError(
                f"PlannerSettings.block_steps must be < n_steps ({self.n_steps}), "
                f"got {self.block_steps}"
            )
        check_fields(self, "work_limit", gt=0.0)
        for name in ("behaving_interval_s", "time_limit_s"):
            require_number(f"PlannerSettings.{name}", getattr(self, name), gt=0.0)
        if self.backend not in BACKENDS:
            raise ConfigError(
                f"PlannerSettings.backend must be one of {BACKENDS}, got {self.backend!r}"
            )
        if self.target_form not in TARGET_FORMS:
            raise ConfigError(
                f"PlannerSettings.target_form must be one of {TARGET_FORMS}, "
                f"got {self.target_form!r}"
            )
        if self.delta_mode not in DELTA_MODES:
            raise ConfigError(
                f"PlannerSettings.delta_mode must be one of {DELTA_MODES}, got {self.delta_mode!r}"
            )
        check_fields(self, "regroup_lane", ge=0, integer=True)


def _require_int(name: str, value: object, minimum: int, maximum: int | None = None) -> None:
    require_number(f"PlannerSettings.{name}", value, ge=minimum, le=maximum, integer=True)


# The most behaving steps a plan may span: the model grows with them (cells x steps x CAVs),
# and a count of 10**9 would fill the memory at the first plan. 14 plan the paper's overtake;
# 1000 steps of 3 s are 50 minutes.
MAX_PLAN_STEPS = 1000


@dataclass(frozen=True)
class Blocker:
    """A CAV told to block an HV: in ``cell`` at steps ``1 .. hold_steps`` (eqs. (16)-(17))."""

    cav_index: int
    cav_id: str
    hv_id: str
    cell: Cell
    hold_steps: int = 1


@dataclass(frozen=True)
class PlanningProblem:
    """The cell MIP's data, independent of vehicles and solvers.

    Attributes
    ----------
    n_rows, n_cols, n_steps
        Grid size and horizon (steps ``0 .. n_steps - 1``, 0 = initial).
    cav_ids, start_cells
        CAVs leader first and their cells at step 0 (eqs. (18)-(19)).
    blocked
        Per step, cells HVs claim (eq. (15)); step 0 is informative only, not enforced.
    goal_rows
        Per step, the first row ahead of the target HV's footprint, clipped to
        ``[0, n_rows]``; a CAV below it is *impeded* (the paper's delta) and pays ``w_tar``.
    regroup_lane
        ``l_index`` of eq. (5).
    entry_blocked
        Per step (empty = none), cells a CAV may not *enter* sideways or from ahead: in front of
        an HV, farther than its hard margin but closer than the gap at which that HV would
        brake harder than the safe deceleration (a CAV already there may stay or move on).
        A lateral move at step ``k -> k + 1`` needs its new cell free of entry at both steps.
    """

    n_rows: int
    n_cols: int
    n_steps: int
    cav_ids: tuple[str, ...]
    start_cells: tuple[Cell, ...]
    blocked: tuple[frozenset[Cell], ...]
    goal_rows: tuple[int, ...]
    regroup_lane: int
    weights: PlannerWeights = field(default_factory=PlannerWeights)
    target_form: str = "distance"
    delta_mode: str = "swarm"
    blockers: tuple[Blocker, ...] = ()
    hv_ids: tuple[str, ...] = ()
    target_id: str | None = None
    target_col: int | None = None
    t0_s: float = 0.0
    behaving_interval_s: float = 3.0
    entry_blocked: tuple[frozenset[Cell], ...] = ()
    # Moves (step, from, to) exempt from the entry margins: a blocker's move in front of the
    # HV it blocks, checked against the blocking margin instead (it matches the lane's speed).
    exempt_moves: frozenset[tuple[int, Cell, Cell]] = frozenset()
    # Where each HV is, as a continuous row of its centre per step, with its column: a CAV may
    # not pass an HV within a column (15 m cells would let it jump a short vehicle).
    hv_tracks: tuple[tuple[int, tuple[float, ...]], ...] = ()
    # The CAVs' continuous rows at step 0 (their start cells' rows, refined).
    start_rows: tuple[float, ...] = ()
    # Start cells a CAV may keep for the first step although an HV's hard margin covers the
    # cell: the CAV itself, where it really is, is clear of every HV at step 1 (15 m cells
    # are coarse: a cell's centre may sit in a margin that the car in it is not in).
    stay_ok: frozenset[Cell] = frozenset()
    # The same for later steps: ``stay_on[k]`` holds the start cells a CAV that has kept its
    # start cell so far may keep from step k to k + 1 (k >= 1; index 0 is unused, see stay_ok)
    # while an HV's hard margin covers them: keeping the grid's speed, the CAV is still clear
    # of every HV covering its lane at step k + 1, on the same side of each as at the start
    # (_clear_keeping), and within pass_limits. A car following the target closer than the cells'
    # margins (the CACC gap) may follow on instead of having to fall back.
    stay_on: tuple[frozenset[Cell], ...] = ()
    # Per step (empty = none), the cells where a CAV pays ``w_lat`` per step whatever delta:
    # in front of an HV it would hold for nothing, and in the target's lane just ahead of it
    # while such a hold is to be left (:func:`idle_hold_cells`).
    idle_holds: tuple[frozenset[Cell], ...] = ()

    def __post_init__(self) -> None:
        if self.entry_blocked and len(self.entry_blocked) != self.n_steps:
            raise ConfigError("PlanningProblem: entry_blocked needs one entry per step")
        if self.n_rows < 1 or self.n_cols < 1 or self.n_steps < 2:
            raise ConfigError(
                f"PlanningProblem: need n_rows, n_cols >= 1 and n_steps >= 2, got "
                f"{self.n_rows}, {self.n_cols}, {self.n_steps}"
            )
        if not self.cav_ids or len(self.cav_ids) != len(self.start_cells):
            raise ConfigError("PlanningProblem: one start cell per CAV, at least one CAV")
        if len(set(self.cav_ids)) != len(self.cav_ids):
            raise ConfigError("PlanningProblem: duplicate CAV ids")
        for cav_id, (row, col) in zip(self.cav_ids, self.start_cells, strict=True):
            if not (0 <= row < self.n_rows and 0 <= col < self.n_cols):
                raise ConfigError(
                    f"PlanningProblem: CAV {cav_id} starts outside the grid at {(row, col)}"
                )
        if len(self.blocked) != self.n_steps or len(self.goal_rows) != self.n_steps:
            raise ConfigError("PlanningProblem: blocked and goal_rows need one entry per step")
        if not 0 <= self.regroup_lane < self.n_cols:
            raise ConfigError(f"PlanningProblem: regroup_lane {self.regroup_lane} not a column")
        if self.target_form not in TARGET_FORMS:
            raise ConfigError(f"PlanningProblem: target_form {self.target_form!r} unknown")
        if self.delta_mode not in DELTA_MODES:
            raise ConfigError(f"PlanningProblem: delta_mode {self.delta_mode!r} unknown")
        for blocker in self.blockers:
            if blocker.hold_steps >= self.n_steps:
                raise ConfigError("PlanningProblem: blocker hold_steps must be < n_steps")

    @property
    def n_cavs(self) -> int:
        return len(self.cav_ids)

    @functools.cached_property
    def pass_limits(self) -> np.ndarray:
        """``[k, col, row]``: the lowest row a CAV in ``row`` at step ``k`` may not reach at step
        ``k + 1`` within its column without passing an HV (``inf``: none)."""
        limits = np.full((self.n_steps, self.n_cols, self.n_rows), np.inf)
        rows = np.arange(self.n_rows)
        for col, track in self.hv_tracks:
            if not 0 <= col < self.n_cols:
                continue
            track = np.asarray(track, dtype=float)
            # [k, row]: the HV's row at k + 1 where the row is behind it at k (all steps at once).
            step = np.where(rows[None, :] < track[:-1, None], track[1:, None], np.inf)
            limits[:-1, col] = np.minimum(limits[:-1, col], step)
        return limits

    @functools.cached_property
    def start_pass_limits(self) -> dict[Cell, float]:
        """The same at step 0, from where the CAVs really are in their start cells."""
        out: dict[Cell, float] = {}
        for pos, cell in zip(self.start_rows, self.start_cells, strict=True):
            limit = math.inf
            for col, track in self.hv_tracks:
                if col == cell[1] and pos < track[0]:
                    limit = min(limit, track[1])
            out[cell] = min(out.get(cell, math.inf), limit)
        return out

    def with_blockers(self, blockers: Sequence[Blocker]) -> PlanningProblem:
        """The same problem with other blocker assignments (e.g. none)."""
        return replace(self, blockers=tuple(blockers))


def stay_exempt(problem: PlanningProblem, k: int, cell: Cell) -> bool:
    """May a CAV in ``cell`` at step ``k`` keep it at step ``k + 1`` whatever HV margin covers
    it? At step 0, the cells of ``stay_ok``; later, those of ``stay_on[k]`` while an HV's margin
    has covered the cell since the start (so the CAV in it can only be the one that started
    there and kept it)."""
    if k == 0:
        return cell in problem.stay_ok
    return k < len(problem.stay_on) and cell in problem.stay_on[k] and cell in problem.blocked[k]


def move_allowed(problem: PlanningProblem, k: int, src: Cell, dst: Cell) -> bool:
    """May a CAV go from ``src`` at step ``k`` to ``dst`` at step ``k + 1``? (eq. (15) and the
    entry margins in front of HVs; moves of one row or column are checked elsewhere)."""
    exempt = src == dst and stay_exempt(problem, k, src)
    if exempt and k == 0:
        return True
    if dst in problem.blocked[k + 1] and not exempt:
        return False
    if dst[1] == src[1] and dst[0] >= src[0] and problem.hv_tracks:
        limit = problem.pass_limits[k, src[1], src[0]]
        if k == 0:
            limit = min(limit, problem.start_pass_limits.get(src, limit))
        if dst[0] >= limit:
            return False  # it would pass an HV in its own lane
    if not problem.entry_blocked or (k, src, dst) in problem.exempt_moves:
        return True
    if dst[1] != src[1]:  # sideways: the new cell must be free of HVs over the whole move
        return not (
            dst in problem.entry_blocked[k + 1]
            or dst in problem.entry_blocked[k]
            or dst in problem.blocked[k]
        )
    if dst[0] < src[0]:  # falling back towards an HV behind
        return dst not in problem.entry_blocked[k + 1]
    return True


LANE_END_PREFIX = "lane_end:"  # ids of the standing obstacles that stand for lanes that end

# Moves of one behaving step as (row, column) offsets: stay, forward, back, left, right.
MOVES = ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1))


def cell_mask(cells_per_step: Sequence[frozenset[Cell]], shape: tuple[int, int, int]) -> np.ndarray:
    """``[k, row, col]``: is the cell in ``cells_per_step[k]``? (cells off ``shape`` dropped)."""
    mask = np.zeros(shape, dtype=bool)
    for k, cells in enumerate(cells_per_step):
        for row, col in cells:
            if 0 <= row < shape[1] and 0 <= col < shape[2]:
                mask[k, row, col] = True
    return mask


def move_masks(problem: PlanningProblem) -> np.ndarray:
    """``[m, k, row, col]``: may a CAV in ``(row, col)`` at step ``k`` make move ``MOVES[m]``?

    The rules of :func:`move_allowed` for every cell at once (moves off the grid are False; the
    last step has no moves). Used by the flow model to build only allowed edges.
    """
    n_steps, n_rows, n_cols = problem.n_steps, problem.n_rows, problem.n_cols
    shape = (n_steps, n_rows, n_cols)
    hard = cell_mask(problem.blocked, shape)
    entry = cell_mask(problem.entry_blocked, shape) if problem.entry_blocked else None
    rows = np.arange(n_rows)[:, None]
    limits = problem.pass_limits if problem.hv_tracks else None
    out = np.zeros((len(MOVES), *shape), dtype=bool)
    for m, (dr, dc) in enumerate(MOVES):
        for k in range(n_steps - 1):
            ok = np.zeros((n_rows, n_cols), dtype=bool)
            src = (slice(max(0, -dr), n_rows - max(0, dr)), slice(max(0, -dc), n_cols - max(0, dc)))
            dst = (slice(max(0, dr), n_rows + min(0, dr)), slice(max(0, dc), n_cols + min(0, dc)))
            allowed = ~hard[k + 1][dst]
            if dc == 0 and dr >= 0 and limits is not None:
                allowed &= (rows[src[0]] + dr) < limits[k][:, src[0]].T[:, src[1]]
            if entry is not None:
                if dc != 0:
                    allowed &= ~(entry[k + 1][dst] | entry[k][dst] | hard[k][dst])
                elif dr < 0:
                    allowed &= ~entry[k + 1][dst]
            ok[src] = allowed
            out[m, k] = ok
    # Exceptions, cell by cell: a kept start cell, blockers' entries, refined start rows.
    for cell in problem.stay_ok:
        out[0, 0, cell[0], cell[1]] = True
    for k in range(1, min(len(problem.stay_on), n_steps - 1)):
        for cell in problem.stay_on[k]:  # not past an HV in its lane (pass_limits) either
            if stay_exempt(problem, k, cell) and (
                limits is None or cell[0] < limits[k, cell[1], cell[0]]
            ):
                out[0, k, cell[0], cell[1]] = True
    for m, (dr, dc) in enumerate(MOVES):
        for cell in set(problem.start_cells):
            dst = (cell[0] + dr, cell[1] + dc)
            if 0 <= dst[0] < n_rows and 0 <= dst[1] < n_cols:
                out[m, 0, cell[0], cell[1]] = move_allowed(problem, 0, cell, dst)
    for k, src, dst in problem.exempt_moves:
        move = (dst[0] - src[0], dst[1] - src[1])
        if move in MOVES and 0 <= dst[0] < n_rows and 0 <= dst[1] < n_cols:
            out[MOVES.index(move), k, src[0], src[1]] = move_allowed(problem, k, src, dst)
    return out


def target_cost(problem: PlanningProblem, row: int, k: int) -> float:
    """Forward-target cost of one CAV in ``row`` at step ``k`` (first term of eq. (5))."""
    behind = problem.goal_rows[k] - row
    if behind <= 0:
        return 0.0
    w_tar = problem.weights.w_tar
    return w_tar if problem.target_form == "paper" else w_tar * behind


def step_impeded(problem: PlanningProblem, cells_at_k: Sequence[Cell], k: int) -> bool:
    """The paper's delta at step ``k``: is any CAV still behind the target's footprint?"""
    goal = problem.goal_rows[k]
    return any(row < goal for row, _ in cells_at_k)


def evaluate_objective(problem: PlanningProblem, cells: Sequence[Sequence[Cell]]) -> float:
    """Objective (5) of a plan, as the solvers define it (initial-step constants omitted).

    ``cells[i][k]`` is CAV ``i``'s cell at step ``k``. Terms: target cost at steps ``1..N-1``;
    ``2 w_lon`` per row moved; ``2 w_lat delta_k`` per column moved from step ``k`` to
    ``k + 1``; ``(1 - delta_k) w_lat (l_index - col)^2`` at steps ``1..N-1``; and ``w_lat``
    per CAV per step ``1..N-1`` in a cell of ``idle_holds``, whatever delta.
    """
    weights = problem.weights
    total = 0.0
    for k in range(problem.n_steps):
        at_k = [path[k] for path in cells]
        swarm_delta = step_impeded(problem, at_k, k)
        for i, (row, col) in enumerate(at_k):
            delta = swarm_delta if problem.delta_mode == "swarm" else row < problem.goal_rows[k]
            if k >= 1:
                total += target_cost(problem, row, k)
                if pays_idle_hold(problem, k, (row, col)):
                    total += weights.w_lat
                if not delta:
                    total += weights.w_lat * (problem.regroup_lane - col) ** 2
            if k + 1 < problem.n_steps:
                next_row, next_col = cells[i][k + 1]
                total += 2 * weights.w_lon * abs(next_row - row)
                if delta:
                    total += 2 * weights.w_lat * abs(next_col - col)
    return total


def pays_idle_hold(problem: PlanningProblem, k: int, cell: Cell) -> bool:
    """Does a CAV in ``cell`` at step ``k`` pay for an idle hold (``w_lat``)?"""
    return k < len(problem.idle_holds) and cell in problem.idle_holds[k]


def hold_useful(
    hv_row: float, hv_col: int, impeded: Iterable[tuple[float, int]], ahead_rows: float
) -> bool:
    """Can holding an HV whose centre is in (continuous) row ``hv_row`` of column ``hv_col``
    make space for a CAV still to pass (``impeded``: their rows and columns)? Only for one in
    a lane beside the HV's and more than ``ahead_rows`` ahead of it
    (``PlannerSettings.idle_hold_rows``): a CAV level with the HV, or behind it, can only get
    past once it has gone on; a CAV in the HV's own lane ahead of it is in front of it
    already."""
    return any(abs(col - hv_col) == 1 and row - hv_row > ahead_rows for row, col in impeded)


def _impeded_at_start(problem: PlanningProblem) -> list[tuple[float, int]]:
    """Rows (continuous) and columns of the CAVs still to pass the target at step 0."""
    return [
        (pos, col) for pos, (row, col) in zip(problem.start_rows, problem.start_cells, strict=True)
        if row < problem.goal_rows[0]
    ]  # fmt: skip


def idle_hold_cells(
    problem: PlanningProblem, ahead_rows: float, clear_rows: int
) -> tuple[frozenset[Cell], ...]:
    """Per step ``k >= 1``, the cells that charge ``w_lat`` per step for an idle hold (see
    ``PlannerSettings.release_idle_holds``): in the lane of an HV that no CAV still to pass is
    far enough ahead of at step 0 (:func:`hold_useful`), the rows ahead of that HV's predicted
    row and at or past the goal row; and, where there is such an HV, the first ``clear_rows``
    rows of the regroup lane from the goal row, so that a CAV leaving the hold merges that far
    ahead of the target (a human driver slows behind a car close ahead even at its own speed,
    IDM's gap term, and the CAVs behind the target with it)."""
    if not problem.start_rows or not problem.hv_tracks:
        return ()
    impeded = _impeded_at_start(problem)
    if not impeded:
        return ()
    out: list[set[Cell]] = [set() for _ in range(problem.n_steps)]
    for col, track in problem.hv_tracks:
        if col in (problem.regroup_lane, problem.target_col) or not 0 <= col < problem.n_cols:
            continue
        if hold_useful(track[0], col, impeded, ahead_rows):
            continue
        for k in range(1, problem.n_steps):
            first = max(problem.goal_rows[k], math.floor(track[k]) + 1, 0)
            out[k].update((row, col) for row in range(first, problem.n_rows))
    if not any(out):
        return ()
    lane = problem.regroup_lane
    for k in range(1, problem.n_steps):
        goal = problem.goal_rows[k]
        out[k].update((row, lane) for row in range(goal, min(goal + clear_rows, problem.n_rows)))
    return tuple(frozenset(cells) for cells in out)


def _goal_row(
    grid: MovingGrid, target: VehicleState, t_s: float, gs: GridSettings, margin: float | None
) -> int:
    rows = hv_blocked_rows(grid, target, t_s, gs, margin)
    top = rows[-1] if rows else grid.row_of(target.centre_s_m, t_s)
    return min(max(top + 1, 0), grid.n_rows)


# Margins of an HV [m] from its predicted state: (hard, entry). No CAV may be within the hard
# margin in front of it; no CAV may move into the entry margin (it may stay there).
FrontMargin = Callable[[VehicleState], tuple[float, float]]


def hvs_in_grid(grid: MovingGrid, hvs: Iterable[VehicleState], t_s: float) -> list[str]:
    """Ids of the vehicles whose centre is in one of the grid's rows at ``t_s``.

    The planner's ``hv_ids`` and the controller's new-HV check both use this, so an HV the
    planner knows is never reported as new.
    """
    return sorted(hv.vehicle_id for hv in hvs if 0 <= grid.row_of(hv.centre_s_m, t_s) < grid.n_rows)


@dataclass(frozen=True)
class _HvCells:
    blocked: tuple[frozenset[Cell], ...]
    entry_blocked: tuple[frozenset[Cell], ...]
    goal_rows: tuple[int, ...]
    # Per HV, its entry cells at steps 0 and 1 (to check a blocker against the others).
    early_entry: dict[str, tuple[frozenset[Cell], frozenset[Cell]]]
    early_states: dict[str, tuple[VehicleState, VehicleState]]
    tracks: tuple[tuple[int, tuple[float, ...]], ...]


def _swept_cells(
    grid: MovingGrid,
    before: VehicleState,
    after: VehicleState,
    t0_s: float,
    t1_s: float,
    gs: GridSettings,
    front_margin: FrontMargin | None,
) -> frozenset[Cell]:
    """Cells an HV drives through between its predicted states ``before`` (at ``t0_s``) and
    ``after`` (at ``t1_s``), relative to the moving grid: its footprint and hard margin at one
    sample per row it moves (none when it moves less than a row)."""
    row0 = (before.centre_s_m - grid.origin_at(t0_s)) / grid.cell_length_m
    row1 = (after.centre_s_m - grid.origin_at(t1_s)) / grid.cell_length_m
    samples = math.ceil(abs(row1 - row0))
    if samples < 2:
        return frozenset()
    cells: set[Cell] = set()
    for j in range(1, samples):
        share = j / samples
        t = t0_s + share * (t1_s - t0_s)
        state = replace(after, s_m=before.s_m + share * (after.s_m - before.s_m))
        margin = None if front_margin is None else front_margin(state)[0]
        cells |= hv_blocked_cells(grid, state, t, gs, margin)
    return frozenset(cells)


def _out_of_reach(
    grid: MovingGrid,
    predicted: Sequence[VehicleState],
    times: Sequence[float],
    gs: GridSettings,
    margin_m: float,
) -> bool:
    """Whether an HV at these predicted states claims no row of the grid at any of them, with
    a front margin of ``margin_m``, and stays on one side of it (ahead at every step, or behind
    at every step: the grid and the HV move linearly in between, so the rows it sweeps between
    two steps are out of the grid too)."""
    ahead = behind = True
    for state, t in zip(predicted, times, strict=True):
        rows = hv_blocked_rows(grid, state, t, gs, margin_m)
        ahead = ahead and rows.start >= grid.n_rows
        behind = behind and rows.stop <= 0
        if not (ahead or behind):
            return False
    return True


def _hv_cells(
    grid: MovingGrid,
    all_hvs: Mapping[str, VehicleState],
    target: VehicleState,
    now_s: float,
    times: Sequence[float],
    gs: GridSettings,
    predictor: HvPredictor,
    front_margin: FrontMargin | None,
    margin_bound_m: float | None = None,
) -> _HvCells:
    """Each HV's claims on the grid over the horizon. With ``margin_bound_m`` (no margin
    ``front_margin`` gives is larger), an HV whose footprint and that margin stay ahead of the
    grid, or behind it, at every step claims no cell: only its track is kept, and its
    margins are never asked for (on a corridor, every HV of the road was, at every step)."""
    n_steps = len(times)
    hard: list[set[Cell]] = [set() for _ in range(n_steps)]
    entry: list[set[Cell]] = [set() for _ in range(n_steps)]
    goal_rows = []
    early_entry: dict[str, tuple[frozenset[Cell], frozenset[Cell]]] = {}
    early_states: dict[str, tuple[VehicleState, VehicleState]] = {}
    tracks = []
    for hv_id, hv in all_hvs.items():
        predicted = [predictor.predict(hv, now_s, t) for t in times]
        if not hv_id.startswith(LANE_END_PREFIX):
            rows = [(st.centre_s_m - grid.origin_at(t)) / grid.cell_length_m - 0.5
                    for st, t in zip(predicted, times, strict=True)]  # fmt: skip
            tracks.append((hv_columns(grid, hv, gs)[0], tuple(rows)))
        if (
            margin_bound_m is not None
            and hv_id != target.vehicle_id
            and not hv_id.startswith(LANE_END_PREFIX)
            and _out_of_reach(grid, predicted, times, gs, margin_bound_m)
        ):
            continue
        first: list[frozenset[Cell]] = []
        first_states: list[VehicleState] = []
        previous: VehicleState | None = None
        for k, t in enumerate(times):
            state = predicted[k]
            if gs.hv_sweep and previous is not None:
                swept = _swept_cells(grid, previous, state, times[k - 1], t, gs, front_margin)
                hard[k - 1] |= swept
                hard[k] |= swept
            previous = state
            if front_margin is None:
                hard[k] |= hv_blocked_cells(grid, state, t, gs)
                margin = None
            else:
                hard_margin, margin = front_margin(state)
                hard[k] |= hv_blocked_cells(grid, state, t, gs, hard_margin)
                cells = hv_blocked_cells(grid, state, t, gs, margin)
                entry[k] |= cells
                if k < 2:
                    first.append(cells)
            if k < 2:
                first_states.append(state)
            if hv_id == target.vehicle_id:
                goal_rows.append(_goal_row(grid, state, t, gs, margin))
        if len(first) == 2:
            early_entry[hv_id] = (first[0], first[1])
        if len(first_states) == 2:
            early_states[hv_id] = (first_states[0], first_states[1])
    entry_blocked = (
        ()
        if front_margin is None
        else tuple(frozenset(e - h) for e, h in zip(entry, hard, strict=True))
    )
    return _HvCells(
        tuple(frozenset(h) for h in hard), entry_blocked, tuple(goal_rows), early_entry,
        early_states, tuple(tracks),
    )  # fmt: skip


def build_problem(
    grid: MovingGrid,
    cavs: Sequence[VehicleState],
    hvs: Sequence[VehicleState],
    target: VehicleState,
    now_s: float,
    settings: PlannerSettings,
    grid_settings: GridSettings,
    predictor: HvPredictor | None = None,
    *,
    front_margin: FrontMargin | None = None,
    blocked_predictor: Callable[[Sequence[Blocker]], HvPredictor] | None = None,
    block_budget: Mapping[str, int] | None = None,
    block_margin: Callable[[VehicleState], float] | None = None,
    margin_bound_m: float | None = None,
) -> PlanningProblem:
    """Turn vehicle states into a :class:`PlanningProblem` (CAVs ordered leader first).

    HVs are predicted at ``now_s + k * behaving_interval_s`` with ``predictor`` (default
    constant speed); the target HV blocks cells whether or not it is in ``hvs``, and is always
    in ``hv_ids`` (as is every HV whose centre is in the grid now, see :func:`hvs_in_grid`).

    ``front_margin`` gives each HV's (hard, entry) margins from its predicted state (the HV
    model); the HV then claims its footprint plus the hard margin ahead and, up to the entry
    margin, cells a CAV may not enter (``entry_blocked``). Without it, the paper's constant
    headway.
    ``blocked_predictor`` re-predicts the HVs once blockers are assigned (a blocked HV follows its
    blocker); ``block_budget`` limits, per HV, the steps it may still be held this manoeuvre;
    ``block_margin`` gives the gap a blocker needs in front of an HV when it enters at that HV's
    speed (then slows gently): its entry is checked against that instead of the entry margin.
    ``margin_bound_m``: no margin of ``front_margin`` is larger; HVs that stay out of the
    grid's reach with it are then not asked for theirs (the same problem, built faster).
    CAVs outside the grid raise :class:`ConfigError` (build the grid from the same CAVs).
    """
    predictor = predictor or ConstantSpeedPredictor()
    n_steps = settings.n_steps
    times = [now_s + k * settings.behaving_interval_s for k in range(n_steps)]
    all_hvs = {hv.vehicle_id: hv for hv in hvs}
    all_hvs[target.vehicle_id] = target
    cells = _hv_cells(grid, all_hvs, target, now_s, times, grid_settings, predictor, front_margin,
                      margin_bound_m)  # fmt: skip
    in_grid = set(hvs_in_grid(grid, all_hvs.values(), now_s)) | {target.vehicle_id}

    start_cells = tuple(cav_cell(grid, cav, grid.road, now_s) for cav in cavs)
    target_col = hv_columns(grid, target, grid_settings)[0]
    regroup_lane = settings.regroup_lane if settings.regroup_lane is not None else target_col
    if regroup_lane >= grid.n_cols:
        raise ConfigError(
            f"PlannerSettings.regroup_lane {regroup_lane} is not a lane of a "
            f"{grid.n_cols}-lane road"
        )
    problem = PlanningProblem(
        n_rows=grid.n_rows,
        n_cols=grid.n_cols,
        n_steps=n_steps,
        cav_ids=tuple(cav.vehicle_id for cav in cavs),
        start_cells=start_cells,
        blocked=cells.blocked,
        goal_rows=cells.goal_rows,
        regroup_lane=regroup_lane,
        weights=settings.weights,
        target_form=settings.target_form,
        delta_mode=settings.delta_mode,
        hv_ids=tuple(sorted(in_grid)),
        target_id=target.vehicle_id,
        target_col=target_col,
        t0_s=now_s,
        behaving_interval_s=settings.behaving_interval_s,
        entry_blocked=cells.entry_blocked,
        hv_tracks=cells.tracks,
        start_rows=tuple(
            (cav.centre_s_m - grid.origin_at(now_s)) / grid.cell_length_m - 0.5 for cav in cavs
        ),
    )
    problem = replace(
        problem,
        stay_ok=_stay_ok(grid, cavs, start_cells, all_hvs, predictor, now_s, times[1],
                         grid_settings, front_margin),
    )  # fmt: skip
    final_predictor = predictor
    side_hvs = [all_hvs[h] for h in sorted(in_grid) if h != target.vehicle_id]
    side_hvs += [
        hv for h, hv in all_hvs.items() if h.startswith(LANE_END_PREFIX) and h not in in_grid
    ]
    blockers = assign_blockers(
        problem, grid, side_hvs, now_s, grid_settings, settings, block_budget,
        _blocker_entry_check(grid, cells, times, grid_settings, block_margin),
    )  # fmt: skip
    problem = replace(problem, exempt_moves=_exempt(problem, blockers))
    if blockers and blocked_predictor is not None:
        final_predictor = blocked_predictor(blockers)
        cells = _hv_cells(
            grid, all_hvs, target, now_s, times, grid_settings, final_predictor, front_margin,
            margin_bound_m,
        )  # fmt: skip
        problem = replace(
            problem,
            exempt_moves=_exempt(problem, blockers),
            blocked=cells.blocked,
            entry_blocked=cells.entry_blocked,
            hv_tracks=cells.tracks,
            goal_rows=cells.goal_rows,
        )
        blockers = tuple(b for b in blockers if _blocker_free(problem, b))
    problem = replace(
        problem,
        stay_on=_stay_on(problem, grid, cavs, all_hvs, final_predictor, now_s, times,
                         grid_settings, front_margin),
    )  # fmt: skip
    if settings.release_idle_holds is True:
        idle = idle_hold_cells(problem, settings.idle_hold_rows, settings.idle_clear_rows)
        problem = replace(problem, idle_holds=idle)
    return problem.with_blockers(blockers)


def _stay_ok(
    grid: MovingGrid,
    cavs: Sequence[VehicleState],
    start_cells: Sequence[Cell],
    all_hvs: Mapping[str, VehicleState],
    predictor: HvPredictor,
    now_s: float,
    t1_s: float,
    gs: GridSettings,
    front_margin: FrontMargin | None,
) -> frozenset[Cell]:
    """Start cells whose CAV, keeping the grid's speed, is clear at step 1 of the hard margins of
    every HV in its lane (``gap_behind_m`` behind an HV ahead, the HV's hard margin ahead of an
    HV behind)."""
    clear: dict[Cell, bool] = {}
    for cav, cell in zip(cavs, start_cells, strict=True):  # a shared cell: every CAV in it
        clear[cell] = clear.get(cell, True) and _clear_keeping(
            grid, cav, cell[1], all_hvs, predictor, now_s, t1_s, gs, front_margin
        )
    return frozenset(cell for cell, ok in clear.items() if ok)


def _stay_on(
    problem: PlanningProblem,
    grid: MovingGrid,
    cavs: Sequence[VehicleState],
    all_hvs: Mapping[str, VehicleState],
    predictor: HvPredictor,
    now_s: float,
    times: Sequence[float],
    gs: GridSettings,
    front_margin: FrontMargin | None,
) -> tuple[frozenset[Cell], ...]:
    """``stay_on`` (see :class:`PlanningProblem`): for each start cell in ``stay_ok`` that an
    HV's margin goes on covering, the steps k >= 1 through which its CAV, keeping the grid's
    speed, is still clear at step k + 1 (the :func:`_stay_ok` test, step after step)."""
    n = problem.n_steps
    sharing = Counter(problem.start_cells)
    on: list[set[Cell]] = [set() for _ in range(n - 1)]
    for cav, cell in zip(cavs, problem.start_cells, strict=True):
        if cell not in problem.stay_ok or sharing[cell] > 1:
            continue
        for k in range(1, n - 1):
            if cell not in problem.blocked[k] or cell not in problem.blocked[k + 1]:
                break  # free at k (the usual rules apply from there) or at k + 1 (no need)
            if not _clear_keeping(grid, cav, cell[1], all_hvs, predictor, now_s, times[k + 1],
                                  gs, front_margin):  # fmt: skip
                break
            on[k].add(cell)
    if not any(on):
        return ()
    return tuple(frozenset(cells) for cells in on)


def _clear_keeping(
    grid: MovingGrid,
    cav: VehicleState,
    col: int,
    all_hvs: Mapping[str, VehicleState],
    predictor: HvPredictor,
    now_s: float,
    t_s: float,
    gs: GridSettings,
    front_margin: FrontMargin | None,
) -> bool:
    """Is ``cav``, keeping the grid's speed from where it is, clear at ``t_s`` of the hard
    margins of every HV that covers column ``col`` (its own lane, or leaning into it):
    ``gap_behind_m`` behind an HV ahead, the HV's hard margin (``front_margin``, else the
    paper's ``headway_s``) ahead of an HV behind, and on the same side of each HV as now (a
    CAV clear at both ends may have driven through an HV between them)?"""
    front = cav.s_m + grid.speed_mps * (t_s - now_s)
    rear = front - cav.length_m
    for hv in all_hvs.values():
        state = predictor.predict(hv, now_s, t_s)
        if col not in hv_columns(grid, state, gs):
            continue
        if (hv.s_m >= cav.s_m) != (state.s_m >= front):
            return False
        if state.s_m >= front:
            clear = state.rear_s_m - front >= gs.gap_behind_m
        else:
            hard = front_margin(state)[0] if front_margin else gs.headway_s * state.speed_mps
            clear = rear - state.s_m >= hard
        if not clear:
            return False
    return True


def _exempt(
    problem: PlanningProblem, blockers: Sequence[Blocker]
) -> frozenset[tuple[int, Cell, Cell]]:
    if not problem.entry_blocked:
        return frozenset()
    return frozenset((0, problem.start_cells[b.cav_index], b.cell) for b in blockers)


def _blocker_entry_check(
    grid: MovingGrid,
    cells: _HvCells,
    times: Sequence[float],
    gs: GridSettings,
    block_margin: Callable[[VehicleState], float] | None,
) -> Callable[[str, Cell], bool] | None:
    """Whether a blocker may move into ``cell`` in front of HV ``hv_id`` at step 0 -> 1: clear
    of every other HV's entry margin and of that HV's blocking margin at steps 0 and 1."""
    if block_margin is None or not cells.entry_blocked:
        return None

    def check(hv_id: str, cell: Cell) -> bool:
        for other, early in cells.early_entry.items():
            if other != hv_id and (cell in early[0] or cell in early[1]):
                return False
        for k, state in enumerate(cells.early_states.get(hv_id, ())):
            rows = hv_blocked_rows(grid, state, times[k], gs, block_margin(state))
            if cell[0] in rows:
                return False
        return True

    return check


def _blocker_free(problem: PlanningProblem, blocker: Blocker) -> bool:
    """The blocker can move into its cell at step 1 and hold it (eqs. (16)-(17))."""
    start = problem.start_cells[blocker.cav_index]
    path = [start] + [blocker.cell] * blocker.hold_steps
    return all(move_allowed(problem, k, path[k], path[k + 1]) for k in range(len(path) - 1))


def assign_blockers(
    problem: PlanningProblem,
    grid: MovingGrid,
    hvs: Sequence[VehicleState],
    now_s: float,
    grid_settings: GridSettings,
    settings: PlannerSettings,
    block_budget: Mapping[str, int] | None = None,
    entry_check: Callable[[str, Cell], bool] | None = None,
) -> tuple[Blocker, ...]:
    """Space making, eqs. (16)-(17): CAVs block HVs in the lanes beside the platoon.

    Only while some CAV is impeded, and per lane next to the platoon's lane (the regroup lane)
    only while a CAV still has to cut through it: one in the regroup lane, behind the blocker.

    * A CAV already in that lane with an HV following it (it cut in earlier) *holds*: it stays
      in its cell, so the HV behind it stays at the grid's speed while the others cut in.
    * Otherwise, as in the paper: take the frontmost HV whose centre row is at or behind the
      leader's row; the frontmost unassigned CAV among the first ``max_blockers`` that sits
      next to that lane, ahead of the HV's footprint, moves into it keeping its row, onto a
      cell that no HV claims while it holds it (nor inside another HV's entry margin, and
      ``entry_check`` for the blocked HV) and no other CAV starts in.

    A blocker holds for ``block_steps`` steps (``"auto"``: one per CAV still to cut through
    behind it), at most what is left of the HV's ``block_budget``; an HV with no budget left is
    not blocked again.
    """
    if settings.max_blockers == 0 or not step_impeded(problem, problem.start_cells, 0):
        return ()
    lane = problem.regroup_lane
    cells = problem.start_cells
    leader_row = cells[0][0]
    side_hvs: dict[int, list[VehicleState]] = {}
    hv_top_row: dict[str, int] = {}
    ending: set[int] = set()  # lanes that end ahead: no CAV is sent there to block
    for hv in hvs:
        col = hv_columns(grid, hv, grid_settings)[0]
        if hv.vehicle_id.startswith(LANE_END_PREFIX):
            ending.add(col)
            continue
        if abs(col - lane) != 1:
            continue
        side_hvs.setdefault(col, []).append(hv)
        rows = hv_blocked_rows(grid, hv, now_s, grid_settings)
        hv_top_row[hv.vehicle_id] = rows[-1] if rows else grid.row_of(hv.centre_s_m, now_s)
    for col in ending:
        side_hvs.pop(col, None)
    start_cells = set(cells)
    blockers: list[Blocker] = []
    used: set[int] = set()
    impeded = _impeded_at_start(problem) if problem.start_rows else []

    def idle(hv: VehicleState) -> bool:
        """Would holding ``hv`` make space for no CAV (``release_idle_holds``)?"""
        if settings.release_idle_holds is not True or not problem.start_rows:
            return False
        row = (hv.centre_s_m - grid.origin_at(now_s)) / grid.cell_length_m - 0.5
        col = hv_columns(grid, hv, grid_settings)[0]
        return not hold_useful(row, col, impeded, settings.idle_hold_rows)

    def to_cut_through(row: int) -> int:
        """CAVs in the regroup lane, behind ``row`` and not past the target yet."""
        return sum(
            c == lane and r < row and r < problem.goal_rows[0]
            for i, (r, c) in enumerate(cells)
            if i not in used
        )

    def hold_for(hv_id: str, row: int) -> int:
        needed = max(1, to_cut_through(row))
        hold = needed if settings.block_steps == "auto" else settings.block_steps
        budget = (block_budget or {}).get(hv_id)
        return min(hold, problem.n_steps - 1, budget if budget is not None else hold)

    def budget_left(hv_id: str) -> bool:
        budget = (block_budget or {}).get(hv_id)
        return budget is None or budget > 0

    # Holders first: a CAV in a side lane with an HV right behind it.
    for col in sorted(side_hvs, reverse=True):
        if len(blockers) >= settings.max_blockers:
            break
        in_lane = sorted(
            (i for i, (r, c) in enumerate(cells) if c == col and i not in used),
            key=lambda i: cells[i][0],
        )
        for i in in_lane:  # rearmost first: the one whose follower is the HV to hold
            row = cells[i][0]
            behind = [h for h in side_hvs[col] if hv_top_row[h.vehicle_id] < row]
            if not behind or to_cut_through(row) == 0:
                continue
            hv = max(behind, key=lambda h: h.s_m)
            if not budget_left(hv.vehicle_id) or idle(hv):
                break
            blocker = Blocker(i, problem.cav_ids[i], hv.vehicle_id, cells[i],
                              hold_for(hv.vehicle_id, row))  # fmt: skip
            if _blocker_free(problem, blocker):
                blockers.append(blocker)
                used.add(i)
            break
    # Then the paper's blockers, in the lanes that have no holder.
    held = {cells[b.cav_index][1] for b in blockers}
    frontmost: dict[int, VehicleState] = {}
    for col, lane_hvs in side_hvs.items():
        if col in held:
            continue
        for hv in lane_hvs:
            if grid.row_of(hv.centre_s_m, now_s) > leader_row:
                continue
            if col not in frontmost or hv.s_m > frontmost[col].s_m:
                frontmost[col] = hv
    # A lane whose frontmost HV would be held for nothing is not blocked: a blocker in front
    # of an HV behind it would hold that one too.
    frontmost = {col: hv for col, hv in frontmost.items() if not idle(hv)}
    # Frontmost HV first; on a tie the left lane first (the paper's leader blocks left).
    order = sorted(frontmost.items(), key=lambda item: (-item[1].s_m, -item[0]))
    candidates = [i for i in range(min(settings.max_blockers, problem.n_cavs)) if i not in used]
    for col, hv in order:
        if len(blockers) >= settings.max_blockers or not budget_left(hv.vehicle_id):
            continue
        for i in candidates:
            row, cav_col = cells[i]
            cell = (row, col)
            if abs(cav_col - col) != 1 or cell in start_cells or row <= hv_top_row[hv.vehicle_id]:
                continue
            if settings.block_steps == "auto" and to_cut_through(row) == 0 and cav_col != lane:
                continue
            blocker = Blocker(i, problem.cav_ids[i], hv.vehicle_id, cell,
                              hold_for(hv.vehicle_id, row))  # fmt: skip
            if entry_check is not None:
                free = entry_check(hv.vehicle_id, cell) and _blocker_free(
                    replace(problem, exempt_moves=frozenset({(0, cells[i], cell)})), blocker
                )
            else:
                free = _blocker_free(problem, blocker)
            if not free:
                continue
            blockers.append(blocker)
            candidates.remove(i)
            used.add(i)
            break
    return tuple(blockers)
