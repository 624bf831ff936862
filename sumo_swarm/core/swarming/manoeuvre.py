"""One plan of the manoeuvre: grid, HV margins and prediction, the cell MIP, checks, references.

Pure: vehicle states, the road, the HVs' driver models and the settings in; a
:class:`PlanOutcome` out (with the plans.jsonl record). The HV model
(:mod:`sumo_swarm.core.hvmodel`) is used three ways here, the same way the lateral guard uses it:

* **margins** (eq. 15): an HV claims its footprint plus ``gap_behind_m`` ahead (no CAV may be
  there) and, ahead of that up to its *entry margin*, cells a CAV may not move into: the
  margin is the gap at which that HV, by its own car-following model, would brake at
  ``planner_share * b_safe`` for a CAV entering at the grid's speed;
* **prediction**: HVs are predicted lane by lane with their own models and their leaders;
* **blocking** (eqs. 16-17): once blockers are assigned, the HVs are predicted again with each
  blocker as the leader of the HV it blocks (holding its cell, then leaving at the cap), so the
  space a blocker makes is in the plan.

When a replan is infeasible the entry margins are relaxed to the guard's own b_safe
(``RELAXATION``), never further; the record and an event say so, and the target stays in the
problem at every level.
"""

from __future__ import annotations

import functools
import logging
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from sumo_swarm.core.grid import GridSettings, MovingGrid, build_grid
from sumo_swarm.core.hvmodel import (
    CarFollowingPredictor,
    DriverModel,
    braking_needed,
    min_block_gap,
    min_entry_gap,
)
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.planner import (
    CellPlanner,
    Plan,
    PlannerSettings,
    PlanningProblem,
    build_problem,
    shift_plan,
    solved_problem,
    validate_plan,
)
from sumo_swarm.core.planner.problem import LANE_END_PREFIX, Blocker
from sumo_swarm.core.trajectory import GridFrame, Reference, reference_from_cells

log = logging.getLogger(__name__)

# Margin levels tried in turn when a replan is infeasible: the planner's share of b_safe, then
# the guard's b_safe itself. Never less: a plan the guard would refuse is no plan.
RELAXATION = ("planner", "guard")
# With margin_rule = "headway", the levels scale the paper's headway instead.
HEADWAY_SCALE = {"planner": 1.0, "guard": 0.5}


@dataclass(frozen=True)
class ManoeuvreSettings:
    """Everything a plan needs besides the vehicles (see the scenario's sections)."""

    planner: PlannerSettings
    grid: GridSettings
    b_safe_mps2: float
    planner_share: float
    margin_rule: str  # "model" or "headway"
    predictor: str  # "car-following" or "constant-speed"
    target_b_mps2: float
    block_decel_share: float
    prediction_dt_s: float
    a_min_mps2: float
    a_max_mps2: float
    max_lateral_speed_mps: float
    entry_speed_gain_mps: float = 0.0  # [hvmodel]: 0 = entries at the grid's speed


@dataclass
class PlanOutcome:
    """The result of one planning attempt."""

    plan: Plan | None
    grid: MovingGrid | None
    problem: PlanningProblem | None
    record: dict[str, Any]
    references: dict[str, Reference] = field(default_factory=dict)
    predictor: CarFollowingPredictor | None = None  # None: [hvmodel] predictor = "constant-speed"
    relaxed: str | None = None  # the relaxation level used, when not the first

    @property
    def usable(self) -> bool:
        return self.plan is not None and self.plan.ok and not self.record.get("violations")


SPEED_QUANTUM_MPS = 0.1  # entry margins are computed for speeds rounded to this [m/s]
# Blocking and speed-matched entry margins depend on three speeds: coarser, so that a run
# computes a few hundred of them, not thousands (each is a simulated reaction) [m/s].
BLOCK_SPEED_QUANTUM_MPS = 0.5


# Entry margins are capped here [m]: an HV that would brake harder than allowed at any gap (it
# is far faster than the grid) claims this much of its lane ahead, not the whole road.
MAX_MARGIN_M = 150.0
MARGIN_TOL_M = 0.1  # margins are searched to this [m]


@functools.lru_cache(maxsize=65536)
def _entry_gap(model: DriverModel, v_q: int, v_lead_q: int, b: float, step_s: float) -> float:
    v, v_lead = v_q * SPEED_QUANTUM_MPS, v_lead_q * SPEED_QUANTUM_MPS
    # A driver above its desired speed slows down on a free road too: only the braking the
    # entering vehicle adds counts against b.
    free = braking_needed(model, v, None, None, step_s)
    # Searched up to the cap only (a gap beyond it is the cap anyway), to a tenth of a metre
    # (cells are 15 m): a far larger search is what made open roads slow.
    gap = min_entry_gap(
        model, v, v_lead, b + free, step_s, tol_m=MARGIN_TOL_M, max_gap_m=MAX_MARGIN_M
    )
    return min(gap, MAX_MARGIN_M)


# Desired speeds are rounded down to this [m/s] before the margins are cached: SUMO draws a
# speedFactor per vehicle, so without it every HV of a flow has its own model and misses the
# cache (a slower desired speed makes IDM brake harder: the safe side).
DESIRED_SPEED_QUANTUM_MPS = 0.5


@functools.lru_cache(maxsize=4096)
def canonical_model(model: DriverModel) -> DriverModel:
    """``model`` with its desired speed rounded down and no speedFactor: one cache entry per
    vType and desired-speed class, not per vehicle (itself cached: a plan asks it for every HV
    at every step of its horizon)."""
    q = DESIRED_SPEED_QUANTUM_MPS
    v0 = math.floor(model.desired_speed_mps / q + 1e-9) * q
    if v0 == model.desired_speed_mps and model.speed_factor == 1.0:
        return model
    return replace(model, desired_speed_mps=max(v0, q), speed_factor=1.0)


def entry_gap(
    model: DriverModel, v_mps: float, v_lead_mps: float, b: float, step_s: float
) -> float:
    """:func:`~sumo_swarm.core.hvmodel.min_entry_gap`, cached; the follower's speed rounded up and
    the entering vehicle's rounded down (both on the safe side)."""
    return _entry_gap(
        canonical_model(model),
        math.ceil(v_mps / SPEED_QUANTUM_MPS - 1e-9),
        math.floor(max(v_lead_mps, 0.0) / SPEED_QUANTUM_MPS + 1e-9),
        b,
        step_s,
    )


@functools.lru_cache(maxsize=65536)
def _block_gap(
    model: DriverModel, v_q: int, v_enter_q: int, v_final_q: int, decel: float, b: float,
    step_s: float,
) -> float:  # fmt: skip
    q = BLOCK_SPEED_QUANTUM_MPS
    free = braking_needed(model, v_q * q, None, None, step_s)
    gap = min_block_gap(
        model, v_q * q, v_enter_q * q, v_final_q * q, decel, b + free, step_s,
        tol_m=MARGIN_TOL_M, max_gap_m=MAX_MARGIN_M,
    )  # fmt: skip
    return min(gap, MAX_MARGIN_M)


def block_gap(
    model: DriverModel, v_mps: float, v_enter_mps: float, v_final_mps: float, decel: float,
    b: float, step_s: float,
) -> float:  # fmt: skip
    """:func:`~sumo_swarm.core.hvmodel.min_block_gap`, cached, speeds rounded on the safe side
    (the HV's up, the entering and final ones down) to :data:`BLOCK_SPEED_QUANTUM_MPS`."""
    q = BLOCK_SPEED_QUANTUM_MPS
    return _block_gap(
        canonical_model(model), math.ceil(v_mps / q - 1e-9), math.floor(v_enter_mps / q + 1e-9),
        math.floor(max(v_final_mps, 0.0) / q + 1e-9), decel, b, step_s,
    )  # fmt: skip


class ManoeuvrePlanner:
    """Builds and solves the cell MIP for the current situation."""

    def __init__(self, planner: CellPlanner, settings: ManoeuvreSettings) -> None:
        self.planner = planner
        self.settings = settings

    def plan(
        self,
        t_s: float,
        reason: str,
        states: Mapping[str, VehicleState],
        platoon: Sequence[str],
        target_id: str,
        road: RoadSection,
        *,
        obstacles: Sequence[VehicleState],
        model_of: Callable[[str], DriverModel],
        grid_speed_mps: float,
        cap_mps: float,
        interval_s: float,
        step_s: float,
        block_budget: Mapping[str, int] | None = None,
        previous: tuple[Plan, MovingGrid] | None = None,
        relax_to: str = "guard",
        closed_lane: int | None = None,
        stranded: bool = False,
        known_paths: Mapping[str, Callable[[float], float]] | None = None,
    ) -> PlanOutcome:
        """Plan the manoeuvre past ``target_id`` (margins relaxed up to ``relax_to`` while
        infeasible). ``closed_lane``: a lane whose cells beside and behind the target the plan
        may not enter (:func:`close_beside`; the lane a target that keeps right may move into).
        ``stranded``: the plan in force keeps a CAV behind the target in its cell to its end
        (``[planner] release_idle_holds = "stranded"`` releases idle holds only then).
        ``known_paths``: vehicles whose front position ``s(t)`` [m] is known (another swarm's
        CAVs, from that swarm's plan): predicted on it, not by a car-following model."""
        st = self.settings
        target = states[target_id]
        cavs = [states[v] for v in platoon]
        hvs = [s for v, s in states.items() if not s.is_cav and v != target_id]
        hvs += list(obstacles)
        release = st.planner.release_idle_holds
        settings = replace(
            st.planner, behaving_interval_s=interval_s,
            release_idle_holds=stranded if release == "stranded" else release,
        )  # fmt: skip
        horizon_s = interval_s * settings.n_steps
        models = {h.vehicle_id: model_of(h.vehicle_id) for h in [*hvs, target] if
                  not h.vehicle_id.startswith(LANE_END_PREFIX)}  # fmt: skip
        # HVs are predicted behind CAVs that keep their cells (the grid's speed), the motion
        # the plan starts from; a CAV's current speed would make its follower run into cells
        # the plan keeps the CAV in.
        everyone = [
            replace(st, speed_mps=grid_speed_mps) if st.is_cav else st for st in states.values()
        ]
        everyone += list(obstacles)
        record: dict[str, Any] = {
            "time_s": t_s, "trigger": reason, "grid_speed_mps": grid_speed_mps,
            "behaving_interval_s": interval_s, "speed_cap_mps": cap_mps,
        }  # fmt: skip
        if st.predictor == "car-following":
            predictor = CarFollowingPredictor(
                everyone, models, road, t_s, horizon_s, st.prediction_dt_s,
                leaders_override=known_paths,
            )  # fmt: skip
        else:
            predictor = None
        outcome = PlanOutcome(None, None, None, record, predictor=predictor)
        levels = RELAXATION[: RELAXATION.index(relax_to) + 1]
        # No margin of _front_margin is larger (its gaps are capped at MAX_MARGIN_M): HVs that
        # stay farther than this from the grid are left out of the margins (build_problem).
        margin_bound = max(MAX_MARGIN_M, st.grid.gap_behind_m,
                           *(m.min_gap_m for m in models.values()))  # fmt: skip
        try:
            for level in levels:
                front_margin = self._front_margin(
                    level, models, grid_speed_mps, step_s, target_id, cap_mps
                )
                target_margin = front_margin(target)[1] if front_margin else None
                gs = st.grid
                if st.margin_rule == "headway":  # the paper's constant headway, scaled down
                    scale = HEADWAY_SCALE[level]
                    gs = replace(gs, headway_s=gs.headway_s * scale,
                                 gap_behind_m=gs.gap_behind_m * scale)  # fmt: skip
                grid = build_grid(cavs, target, road, t_s, grid_speed_mps, gs, target_margin)
                blocked_predictor = None
                if predictor is not None:
                    blocked_predictor = self._blocked_predictor(
                        everyone, models, road, t_s, horizon_s, grid, cavs, cap_mps, interval_s,
                        known_paths,
                    )  # fmt: skip
                problem = build_problem(
                    grid, cavs, hvs, target, t_s, settings, gs, predictor,
                    front_margin=front_margin, blocked_predictor=blocked_predictor,
                    block_budget=block_budget,
                    block_margin=self._block_margin(level, models, grid_speed_mps, cap_mps,
                                                    step_s),
                    margin_bound_m=None if front_margin is None else margin_bound,
                )  # fmt: skip
                if closed_lane is not None:
                    problem = close_beside(problem, grid, target, t_s, closed_lane)
                    record["closed_lane"] = closed_lane
                hint = _hint(previous, grid, t_s, platoon)
                plan = (
                    self.planner.plan(problem, hint=hint)
                    if hint is not None
                    else self.planner.plan(problem)
                )
                outcome.plan, outcome.grid, outcome.problem = plan, grid, problem
                record["margin_level"] = level
                if level != levels[0]:
                    outcome.relaxed = level
                if plan.ok or plan.status.value != "infeasible":
                    break
            plan = outcome.plan
            if plan.ok:  # judged, driven and reported as the problem it solves
                outcome.problem = solved_problem(outcome.problem, plan)
            violations = validate_plan(outcome.problem, plan) if plan.ok else []
            grid = outcome.grid
            record.update(
                status=plan.status.value, solve_ms=plan.solve_ms, build_ms=plan.build_ms,
                cpu_ms=plan.cpu_ms,
                objective=plan.objective, best_bound=getattr(plan, "best_bound", None),
                blockers=plan.blockers, violations=violations, message=plan.message,
                block_steps={b.cav_id: b.hold_steps for b in outcome.problem.blockers},
                cells={c: list(map(list, plan.cells_of(c))) for c in plan.cav_ids}
                if plan.ok else None,
                grid={"origin_s_m": grid.origin_s_m, "t0_s": grid.t0_s,
                      "speed_mps": grid.speed_mps, "cell_length_m": grid.cell_length_m,
                      "n_rows": grid.n_rows, "n_cols": grid.n_cols},
            )  # fmt: skip
        except Exception as exc:  # a planner bug must never stop the simulation
            log.exception("planning failed")
            outcome.plan = None
            record.update(status="error", message=f"{type(exc).__name__}: {exc}")
            return outcome
        if outcome.usable:
            outcome.references = self._references(outcome, states, platoon, road, t_s, cap_mps)
        return outcome

    # ------------------------------------------------------------------ parts
    def _front_margin(
        self,
        level: str,
        models: Mapping[str, DriverModel],
        v_cav: float,
        step_s: float,
        target_id: str,
        cap_mps: float = math.inf,
    ) -> Callable[[VehicleState], tuple[float, float]] | None:
        """(hard, entry) margins in front of an HV: the hard one is its own minGap (no CAV is
        ever planned closer), the entry one the gap at which it would brake at the level's
        share of b_safe for a CAV entering at the grid's speed, or, in front of a faster HV, for
        a CAV that matched speed by up to ``entry_speed_gain_mps`` and then slows to the grid's
        speed as a blocker does."""
        st = self.settings
        if st.margin_rule == "headway":
            return None
        b = st.b_safe_mps2 * (st.planner_share if level == "planner" else 1.0)

        def margin(hv: VehicleState) -> tuple[float, float]:
            model = models.get(hv.vehicle_id)
            if model is None:  # a lane end or other standing obstacle
                return st.grid.gap_behind_m, st.grid.gap_behind_m
            if hv.vehicle_id == target_id:
                gap = entry_gap(model, hv.speed_mps, v_cav, min(b, st.target_b_mps2), step_s)
                return model.min_gap_m, max(gap, model.min_gap_m)
            v_enter = min(hv.speed_mps, cap_mps, v_cav + st.entry_speed_gain_mps)
            if v_enter <= v_cav + SPEED_QUANTUM_MPS:
                gap = entry_gap(model, hv.speed_mps, v_cav, b, step_s)
            else:
                gap = block_gap(
                    model, hv.speed_mps, v_enter, v_cav, st.block_decel_share * b, b, step_s
                )
            return model.min_gap_m, max(gap, model.min_gap_m)

        return margin

    def _block_margin(
        self, level: str, models: Mapping[str, DriverModel], v_grid: float, cap: float,
        step_s: float,
    ) -> Callable[[VehicleState], float] | None:  # fmt: skip
        """Gap a blocker needs in front of an HV: it enters at the HV's speed (at most the cap)
        and then slows the lane to the grid's speed at ``block_decel_share`` of b."""
        st = self.settings
        if st.margin_rule == "headway":
            return None
        b = st.b_safe_mps2 * (st.planner_share if level == "planner" else 1.0)

        def margin(hv: VehicleState) -> float:
            model = models.get(hv.vehicle_id)
            if model is None:
                return st.grid.gap_behind_m
            v_enter = min(hv.speed_mps, cap)
            if v_enter <= v_grid:
                return max(entry_gap(model, hv.speed_mps, v_grid, b, step_s), model.min_gap_m)
            gap = block_gap(
                model, hv.speed_mps, v_enter, v_grid, st.block_decel_share * b, b, step_s
            )
            return max(gap, model.min_gap_m)

        return margin

    def _blocked_predictor(
        self,
        everyone: Sequence[VehicleState],
        models: Mapping[str, DriverModel],
        road: RoadSection,
        t_s: float,
        horizon_s: float,
        grid: MovingGrid,
        cavs: Sequence[VehicleState],
        cap_mps: float,
        interval_s: float,
        known_paths: Mapping[str, Callable[[float], float]] | None = None,
    ) -> Callable[[Sequence[Blocker]], CarFollowingPredictor]:
        st = self.settings
        half = 0.5 * st.grid.cav_length_m
        cav_by_id = {c.vehicle_id: c for c in cavs}

        def predictor(blockers: Sequence[Blocker]) -> CarFollowingPredictor:
            moved = {}
            overrides = dict(known_paths or {})
            for b in blockers:
                row, col = b.cell
                cav = cav_by_id[b.cav_id]
                moved[b.cav_id] = replace(cav, lane=col, lat_m=0.0)
                release_s = t_s + b.hold_steps * interval_s
                s_release = grid.cell_centre_s(row, release_s) + half
                speed = min(cap_mps, grid.speed_mps + grid.cell_length_m / interval_s)

                def front(t: float, row=row, release_s=release_s, s_release=s_release,
                          speed=speed) -> float:  # fmt: skip
                    if t <= release_s:
                        return grid.cell_centre_s(row, t) + half
                    return s_release + speed * (t - release_s)

                overrides[b.cav_id] = front
            states = [moved.get(v.vehicle_id, v) for v in everyone]
            return CarFollowingPredictor(
                states, models, road, t_s, horizon_s, st.prediction_dt_s, leaders_override=overrides
            )

        return predictor

    def _references(
        self,
        outcome: PlanOutcome,
        states: Mapping[str, VehicleState],
        platoon: Sequence[str],
        road: RoadSection,
        t_s: float,
        cap_mps: float,
    ) -> dict[str, Reference]:
        st = self.settings
        grid, plan = outcome.grid, outcome.plan
        frame = GridFrame(
            grid.origin_s_m, t_s, grid.speed_mps, grid.cell_length_m,
            outcome.problem.behaving_interval_s, road,
        )  # fmt: skip
        refs = {}
        for vid in platoon:
            ego = states[vid]
            refs[vid] = reference_from_cells(
                plan.cells_of(vid), frame, road,
                a_min=st.a_min_mps2, a_max=st.a_max_mps2,
                v_max=cap_mps if math.isfinite(cap_mps) else 40.0,
                max_lat_speed_mps=0.9 * st.max_lateral_speed_mps,
                t_now=t_s, s_now=ego.centre_s_m, y_now=road.y_of(ego.lane, ego.lat_m),
                v_now=ego.speed_mps, a_now=ego.accel_mps2,
            )  # fmt: skip
        return refs


def close_beside(
    problem: PlanningProblem, grid: MovingGrid, target: VehicleState, t_s: float, col: int
) -> PlanningProblem:
    """``problem`` with the cells of column ``col`` from row 0 up to one row ahead of the
    target's front claimed at every step >= 1 (eq. (15)): the plan passes the target on its
    other side. Unchanged where a CAV starts in that column (it must be free to move on) or
    ``col`` is not a column of the grid."""
    if not 0 <= col < problem.n_cols or any(c == col for _, c in problem.start_cells):
        return problem
    top = min(grid.row_of(target.s_m, t_s) + 1, problem.n_rows - 1)
    if top < 0:
        return problem
    closed = frozenset((r, col) for r in range(top + 1))
    blocked = (problem.blocked[0], *(cells | closed for cells in problem.blocked[1:]))
    return replace(problem, blocked=blocked)


def _hint(
    previous: tuple[Plan, MovingGrid] | None, grid: MovingGrid, t_s: float, platoon: Sequence[str]
) -> Plan | None:
    """Warm start: the rest of the last plan, shifted by the steps executed and mapped into the
    new grid's rows (``None`` if there is no usable last plan for the same CAVs)."""
    if previous is None:
        return None
    plan, old = previous
    if not plan.ok or set(plan.cav_ids) != set(platoon) or old.cell_length_m != grid.cell_length_m:
        return None
    executed = max(0, math.floor((t_s - plan.t0_s) / plan.behaving_interval_s + 1e-9))
    offset = round((grid.origin_s_m - old.origin_at(t_s)) / grid.cell_length_m)
    return shift_plan(plan, executed, offset)
