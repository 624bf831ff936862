"""The plan in force during an overtake: when to plan again, planning, and what it cost.

:class:`Replanner` owns the cell plan, its grid and references, and the replan trigger of the
paper's Fig. 4. Each step of an overtake :meth:`Replanner.maybe_replan` asks the trigger (a CAV
off its cell, an HV entering the grid that claims a planned cell, a plan running out), and each
behaving interval whether an HV drove far from where it was predicted or the plan only waits;
replans are rate-limited to one per behaving interval unless a safety check demands one. A
failed, timed-out or infeasible solve never raises: the last valid plan is kept while it lasts,
else the CAVs follow by CACC, and the event is recorded (``planner_fallback``).

:class:`PlanStats` counts the solves for the summary's ``planner`` block; :class:`BlockWatch`
follows the HVs a plan blocks (how long, and their strongest deceleration).
"""

from __future__ import annotations

import inspect
import math
from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from sumo_swarm.config import PlannerSettings
from sumo_swarm.controllers.decider import Decider
from sumo_swarm.controllers.lanes import LaneView
from sumo_swarm.controllers.reform import MAX_BLOCK_S
from sumo_swarm.core.grid import MovingGrid, cav_cell, hv_blocked_cells
from sumo_swarm.core.hvmodel import CarFollowingPredictor, DriverModel
from sumo_swarm.core.model import VehicleState
from sumo_swarm.core.neighbours import ordered_platoon, vehicle_ahead
from sumo_swarm.core.planner import Plan, ReplanTrigger
from sumo_swarm.core.planner.problem import PlanStatus, hvs_in_grid
from sumo_swarm.core.stats import summarise_ms
from sumo_swarm.core.swarming.decision import (
    Progress,
    behaving_interval_s,
    cavs_behind,
    keeps_cell,
    stranded_cavs,
    waiting_plan,
)
from sumo_swarm.core.swarming.manoeuvre import ManoeuvrePlanner, PlanOutcome
from sumo_swarm.core.swarming.planlog import PlanLog
from sumo_swarm.core.trajectory import Reference

States = Mapping[str, VehicleState]
# Replans that a safety check demands: they are not rate-limited.
URGENT_TRIGGERS = frozenset({"initial", "cav_set_changed", "plan_done", "conflict"})
# A plan found infeasible on a grid held this much above the target's speed [m/s] is tried
# again at the target's own speed (Replanner.replan).
GRID_RETRY_MPS = 0.1
# Replan when a CAV is more than this many cells from its planned cells (the paper's drift
# event; one cell is what tracking may lag by between two behaving steps) [rows].
DRIFT_ROWS = 1.0
# After a failed replan, wait this long before the next [s] (each solve costs up to the MIP's
# time limit; the last valid plan, or CACC, drives meanwhile).
RETRY_AFTER_S = 1.0
# Check the last plan's HV predictions (and idle or waiting plans) every this many behaving
# intervals, besides the paper's events: HVs entering the grid later bring new gaps (a 2-lane
# scene held a do-nothing plan for 18 s, then gave up, while gaps passed by) [intervals].
REPLAN_CHECK_INTERVALS = 1
# Replan when an HV in the grid is this far off its prediction [m] (about a third of a cell).
PREDICTION_ERROR_M = 4.0
# A plan that keeps every CAV behind the target in its cell this long [s] waits for a gap so
# far ahead that it may never come (no_way_past after GIVE_UP_WAITING_PLANS such plans).
GIVE_UP_WAITING_S = 12.0


@dataclass
class PlanStats:
    """What the planning calls of a run came to: the summary's ``planner`` block."""

    solve_ms: list[float] = field(default_factory=list)
    solve_cpu_ms: list[float] = field(default_factory=list)  # the same solves' process time
    statuses: Counter[str] = field(default_factory=Counter)
    triggers: Counter[str] = field(default_factory=Counter)
    fallbacks: int = 0
    relaxations: Counter[str] = field(default_factory=Counter)
    grid_retries: Counter[str] = field(default_factory=Counter)  # "tried", "planned"

    def add(self, other: PlanStats) -> None:
        """Count ``other``'s planning calls in with these (every swarm of a run)."""
        self.solve_ms += other.solve_ms
        self.solve_cpu_ms += other.solve_cpu_ms
        self.statuses += other.statuses
        self.triggers += other.triggers
        self.fallbacks += other.fallbacks
        self.relaxations += other.relaxations
        self.grid_retries += other.grid_retries

    def block(self) -> dict[str, Any]:
        return {
            "solves": len(self.solve_ms),
            **summarise_ms(self.solve_ms, prefix="solve_ms_"),
            **summarise_ms(self.solve_cpu_ms, prefix="solve_cpu_ms_"),
            "statuses": dict(self.statuses),
            "fallbacks": self.fallbacks,
            "relaxations": dict(self.relaxations),
            "grid_retries": {"tried": 0, "planned": 0, **self.grid_retries},
            "triggers": dict(self.triggers),
        }


@dataclass
class BlockWatch:
    """The HVs the plans block: since when, until when, and how hard each braked meanwhile."""

    since_s: dict[str, float] = field(default_factory=dict)
    until_s: dict[str, float] = field(default_factory=dict)
    min_accel: dict[str, float] = field(default_factory=dict)  # over the whole run

    def new_manoeuvre(self) -> None:
        self.since_s = {}
        self.until_s = {}

    def blocked(self, hv_id: str, t_s: float, until_s: float) -> None:
        """A plan made at ``t_s`` blocks ``hv_id`` until ``until_s``."""
        self.since_s.setdefault(hv_id, t_s)
        self.until_s[hv_id] = max(self.until_s.get(hv_id, 0.0), until_s)

    def budget(self, t_s: float, max_block_s: float, interval_s: float) -> dict[str, int]:
        """Behaving steps each blocked HV may still be held (``max_block_s``: ``MAX_BLOCK_S``)."""
        return {
            hv: max(0, math.floor((max_block_s - (t_s - since)) / interval_s + 1e-9))
            for hv, since in self.since_s.items()
        }

    def watch(self, t_s: float, states: States, grace_s: float) -> None:
        """Strongest deceleration of each HV while (and ``grace_s`` after) it is blocked."""
        for hv, until in self.until_s.items():
            st = states.get(hv)
            if st is not None and t_s <= until + grace_s:
                self.min_accel[hv] = min(self.min_accel.get(hv, 0.0), st.accel_mps2)

    def strongest(self) -> float | None:
        return min(self.min_accel.values()) if self.min_accel else None


class Replanner:
    """The plan in force and when it is made again (see the module docstring).

    ``decider`` gives the speed cap and the lane closed for a target that may keep right;
    ``lanes`` the lanes that end ahead (obstacles of the plan); ``tracker_reset`` is called on
    every new plan (the MPCs start afresh).
    """

    def __init__(
        self,
        ctx: Any,
        manoeuvre: ManoeuvrePlanner,
        planner: PlannerSettings,
        *,
        decider: Decider,
        lanes: LaneView,
        model_of: Callable[[str], DriverModel],
        planlog: PlanLog,
        tracker_reset: Callable[[], None],
        stats: PlanStats,
        blocks: BlockWatch,
    ) -> None:
        self.ctx = ctx
        self.manoeuvre = manoeuvre
        self.settings = planner
        self.decider = decider
        self.lanes = lanes
        self.model_of = model_of
        self.planlog = planlog
        self.tracker_reset = tracker_reset
        self.stats = stats
        self.blocks = blocks
        self.hints = "hint" in inspect.signature(manoeuvre.planner.plan).parameters
        self.plan: Plan | None = None
        self.grid: MovingGrid | None = None
        self.references: dict[str, Reference] = {}
        self.interval_s: float | None = None
        self.replan_not_before_s = -math.inf
        self.last_plan_s = -math.inf
        self.last_check_s = -math.inf
        self.prediction: tuple[float, CarFollowingPredictor | None] | None = None  # (made at, by)
        self.closed_lane: int | None = None  # the lane the last plan was asked to keep out of
        self.trigger = self._new_trigger()

    def _new_trigger(self) -> ReplanTrigger:
        return ReplanTrigger(drift_cells=DRIFT_ROWS, retry_interval_s=RETRY_AFTER_S)

    def interval(self) -> float:
        """The behaving interval [s] in force (the planner's setting before the first plan)."""
        return self.interval_s or self.settings.behaving_interval_s

    def start(self) -> None:
        """A manoeuvre starts: no plan yet, a fresh trigger, no HV blocked."""
        self.plan = None
        self.closed_lane = None
        self.trigger = self._new_trigger()
        self.blocks.new_manoeuvre()

    def clear(self) -> None:
        """The manoeuvre ended: no plan in force."""
        self.plan = None
        self.references = {}

    # ------------------------------------------------------------------ when
    def maybe_replan(
        self, t_s: float, states: States, platoon: list[str], target_id: str, progress: Progress
    ) -> None:
        """Plan again if the trigger, a prediction gone wrong, or an idle or waiting plan
        asks for it (rate-limited unless ``URGENT_TRIGGERS``)."""
        ctx = self.ctx
        grid = self.grid
        reason = "initial"
        if self.plan is not None and grid is not None:
            hvs = [s for s in states.values() if not s.is_cav]
            cells = {vid: cav_cell(grid, states[vid], ctx.road, t_s) for vid in platoon}
            in_grid = hvs_in_grid(grid, hvs, t_s)  # once per step: trigger, known set, errors
            reason = self.trigger.check(t_s, cells, in_grid)
            if reason == "new_hv":
                # Every HV around was predicted when the plan was made, inside the grid or not:
                # one entering the grid matters only if it claims a cell a CAV is planned in.
                if self._new_hv_conflicts(t_s, hvs):
                    reason = "conflict"
                else:
                    self.trigger.known_hvs = frozenset(in_grid)
                    reason = None
            if set(platoon) != set(self.plan.cav_ids):
                ctx.event("cav_set_changed", planned=list(self.plan.cav_ids), present=platoon)
                reason = "cav_set_changed"
            if (
                reason is None
                and t_s - self.last_check_s
                >= REPLAN_CHECK_INTERVALS * (self.interval_s or 0.0) - 1e-9
            ):
                self.last_check_s = t_s
                if self._prediction_off(t_s, states, in_grid):
                    reason = "prediction"
                elif plan_is_idle(self.plan, self.trigger.current_step(t_s)):
                    # A plan that keeps every CAV in its cell to its end waits for a gap the
                    # plan could not see: HVs that enter the grid later (a flow in the passing
                    # lane) bring new gaps, so ask again each interval (a 2-lane scene held a
                    # do-nothing plan for 18 s, then gave up, while gaps passed by).
                    reason = "idle_plan"
                elif self._still_waiting(t_s, states, target_id):
                    reason = "waiting_plan"  # the same for a gap it sees far ahead in time
            if reason is None and self._lane_to_close(t_s, states, target_id, progress):
                reason = "keep_right"
        elif self.plan is None and self.trigger.plan is not None:
            reason = self.trigger.check(t_s, {}, ())  # "initial" once the retry time has passed
        if reason is None or t_s < self.replan_not_before_s:
            return
        if reason not in URGENT_TRIGGERS and t_s - self.last_plan_s < self.interval():
            return
        self.replan(t_s, reason, states, platoon, target_id, progress)

    def _lane_to_close(
        self, t_s: float, states: States, target_id: str, progress: Progress
    ) -> bool:
        """Is the target's right lane to be closed to the plan now (it wants to move there,
        :meth:`Decider.keep_right_closure`) while the plan in force was made with it open?
        The wish shows seconds after the start (SUMO's keep-right drivers build it over 5 s),
        and a CAV planned into that lane beside or behind the target keeps it from moving."""
        target = states.get(target_id)
        if self.closed_lane is not None or target is None:
            return False
        return self.decider.keep_right_closure(t_s, progress.started_s, target, states) is not None

    def _still_waiting(self, t_s: float, states: States, target_id: str) -> bool:
        """Does the rest of the plan keep every CAV behind the target waiting (see
        :func:`waiting_plan`)?"""
        target = states.get(target_id)
        if target is None or not self.plan.ok:
            return False
        step = max(self.trigger.current_step(t_s), 0)
        planned = [states[v] for v in self.plan.cav_ids if v in states]
        behind = cavs_behind(target, planned, self.ctx.scenario.cav.min_gap_m)
        cells = {v: self.plan.cells_of(v)[step:] for v in self.plan.cav_ids}
        return waiting_plan(cells, behind, self.waiting_steps())

    def _prediction_off(self, t_s: float, states: States, in_grid: list[str]) -> bool:
        """Is an HV in the grid (``in_grid``) farther from where the last plan predicted it than
        allowed?"""
        if self.prediction is None or self.prediction[1] is None:  # no car-following predictor
            return False
        near = {vid: states[vid] for vid in in_grid}
        errors = self.prediction[1].error_against(near, t_s)
        return any(abs(e) > PREDICTION_ERROR_M for e in errors.values())

    def _new_hv_conflicts(self, t_s: float, hvs: list[VehicleState]) -> bool:
        """Does an HV the plan did not know claim a cell a CAV is planned in (next 2 steps)?"""
        grid, plan = self.grid, self.plan
        known = self.trigger.known_hvs
        step = self.trigger.current_step(t_s)
        gs = self.ctx.scenario.grid
        for hv in hvs:
            if hv.vehicle_id in known:
                continue
            for k in (step, step + 1):
                t_k = plan.t0_s + k * plan.behaving_interval_s
                moved = replace(hv, s_m=hv.s_m + hv.speed_mps * (t_k - t_s))
                claimed = hv_blocked_cells(grid, moved, t_k, gs, gs.gap_behind_m)
                if any(plan.cell_at(c, k) in claimed for c in plan.cav_ids):
                    return True
        return False

    def waiting_steps(self) -> int:
        """Behaving steps in ``GIVE_UP_WAITING_S`` (a plan that keeps every CAV behind the
        target in its cell that long waits)."""
        return max(1, math.ceil(GIVE_UP_WAITING_S / self.interval() - 1e-9))

    # ------------------------------------------------------------------ planning
    def replan(
        self,
        t_s: float,
        reason: str,
        states: States,
        platoon: list[str],
        target_id: str,
        progress: Progress,
    ) -> None:
        """Solve the cell MIP for the platoon around ``target_id`` now and put it in force."""
        ctx = self.ctx
        sc = ctx.scenario
        target = states[target_id]
        cavs = [states[v] for v in platoon]
        # Paper II-B-1, Step 4: the grid moves with the front HV while the swarm overtakes it
        # (until every CAV is past it: the cruise mode regroups them, SwarmController).
        grid_speed = max(target.speed_mps, 0.0)
        if self.grid is not None and self._cav_ahead_of(target, states):
            # CAVs just ahead of the target set its pace: never let them pull the grid down.
            grid_speed = max(grid_speed, self.grid.speed_mps)
        cap = self.decider.speed_cap(platoon)

        def interval_at(speed: float) -> float:
            return behaving_interval_s(
                self.settings.behaving_interval_s, sc.cell_length_m, speed, cap,
                sc.swarm.interval_rule,
            )  # fmt: skip

        interval = interval_at(grid_speed)
        self.stats.triggers[reason] += 1
        if not math.isfinite(interval):
            record = {"time_s": t_s, "trigger": reason, "status": "undrivable",
                      "speed_cap_mps": cap, "grid_speed_mps": grid_speed}  # fmt: skip
            self._fail(t_s, reason, record, progress)
            return
        previous = None
        if self.hints and self.plan is not None and self.grid is not None:
            previous = (self.plan, self.grid)  # the warm start of the next solve
        budget = self.blocks.budget(t_s, MAX_BLOCK_S, interval)
        closed = self.decider.keep_right_closure(t_s, progress.started_s, target, states)
        self.closed_lane = closed
        own = max(target.speed_mps, 0.0)
        tries = [(grid_speed, interval)]
        if grid_speed > own + GRID_RETRY_MPS:
            # Held above the target's speed by the CAVs ahead of it, the grid leaves the target
            # behind: the CAVs queued behind it must fall back row by row over the horizon, and
            # with the tail CAV in row 0 they may have nowhere to go (variant 17: 5 CAVs behind
            # a truck 0.8 m/s slower than the grid). A plan found infeasible is tried once more
            # at the target's own speed (the paper's Step 4).
            own_interval = interval_at(own)
            if math.isfinite(own_interval):
                tries.append((own, own_interval))
        obstacles = self._lane_ends(cavs[-1].rear_s_m, target.s_m + 400.0)
        stranded = False  # asked only by [planner] release_idle_holds = "stranded"
        if sc.planner.release_idle_holds == "stranded" and self.plan is not None and self.plan.ok:
            in_force = dict(zip(self.plan.cav_ids, self.plan.cells, strict=True))
            stranded = bool(stranded_cavs(in_force, cavs_behind(target, cavs, sc.cav.min_gap_m)))
        known = ctx.planned_paths()  # the other swarms' plans (many swarms; one: none)
        for n, (speed, speed_interval) in enumerate(tries):
            outcome = self.manoeuvre.plan(
                t_s, reason, states, platoon, target_id, ctx.road,
                obstacles=obstacles, model_of=self.model_of, grid_speed_mps=speed, cap_mps=cap,
                interval_s=speed_interval, step_s=ctx.dt_s, block_budget=budget,
                previous=previous, closed_lane=closed, stranded=stranded,
                known_paths=known,
            )  # fmt: skip
            if n:
                outcome.record["grid_speed_rule"] = "target"
                self.stats.grid_retries["tried"] += 1
                self.stats.grid_retries["planned"] += int(outcome.usable)
            self._log_outcome(t_s, reason, outcome, states, prediction_error=not n)
            interval = speed_interval
            if outcome.plan is None or outcome.plan.status.value != "infeasible":
                break
        if not outcome.usable:
            self._fail(t_s, reason, None, progress)
            return
        plan = outcome.plan
        self.plan, self.grid, self.references = plan, outcome.grid, outcome.references
        self.interval_s = interval
        self.last_plan_s = self.last_check_s = t_s
        self.prediction = (t_s, outcome.predictor)
        self.trigger.planned(plan, t_s, outcome.problem.hv_ids)
        self.tracker_reset()
        progress.planned(t_s)
        behind = cavs_behind(target, cavs, sc.cav.min_gap_m)
        cells = dict(zip(plan.cav_ids, plan.cells, strict=True))
        progress.plan_strands(stranded_cavs(cells, behind), len(cavs))
        progress.plan_waits(waiting_plan(cells, behind, self.waiting_steps()))
        for blocker in outcome.problem.blockers:
            self.blocks.blocked(blocker.hv_id, t_s, t_s + (blocker.hold_steps + 1) * interval)

    def _log_outcome(
        self,
        t_s: float,
        reason: str,
        outcome: PlanOutcome,
        states: States,
        *,
        prediction_error: bool,
    ) -> None:
        """Count one planning call's outcome and write its record to plans.jsonl (with the
        last plan's prediction error against ``states`` when ``prediction_error``)."""
        record = outcome.record
        if prediction_error and self.prediction is not None and self.prediction[1] is not None:
            errors = self.prediction[1].error_against(
                {v: s for v, s in states.items() if not s.is_cav}, t_s
            )
            if errors:
                values = [abs(e) for e in errors.values()]
                record["prediction_error_m"] = {
                    "made_at_s": self.prediction[0], "max": max(values),
                    "mean": sum(values) / len(values), "hvs": len(values),
                }  # fmt: skip
        stats = self.stats
        if outcome.plan is not None:
            stats.solve_ms.append(outcome.plan.solve_ms)
            if outcome.plan.cpu_ms is not None:
                stats.solve_cpu_ms.append(outcome.plan.cpu_ms)
            stats.statuses[outcome.plan.status.value] += 1
        else:
            stats.statuses["error"] += 1
        if outcome.relaxed is not None:
            stats.relaxations[outcome.relaxed] += 1
            self.ctx.event("margins_relaxed", level=outcome.relaxed, trigger=reason)
        self.planlog.write(record)

    def _cav_ahead_of(self, target: VehicleState, states: States) -> bool:
        """Is a CAV the vehicle right ahead of the target, within three cells?"""
        sc = self.ctx.scenario
        ahead = vehicle_ahead(target, list(states.values()), self.ctx.road, width_m=sc.cav.width_m)
        return ahead is not None and ahead[0].is_cav and ahead[1] < 3 * sc.cell_length_m

    def _fail(
        self, t_s: float, reason: str, record: dict[str, Any] | None, progress: Progress | None
    ) -> None:
        """Failed, timed out or invalid: keep the last valid plan while it lasts, else CACC."""
        if record is not None:
            self.stats.statuses[record["status"]] += 1
            self.planlog.write(record)
        self.stats.fallbacks += 1
        if progress is not None:
            progress.failed()
        self.replan_not_before_s = t_s + RETRY_AFTER_S
        # A plan some CAV has drifted away from is not kept: that CAV would chase its cell at
        # full braking (a stale plan braked a CAV at 3.5 m/s^2, the CAV behind it came within
        # 4.9 m); the CAVs follow by CACC until a replan succeeds.
        keep = self.plan is not None and reason not in ("plan_done", "drift")
        self.ctx.event("planner_fallback", trigger=reason, kept_last_plan=keep)
        if keep:
            self.trigger.planned(self.plan, self.trigger.planned_at_s or t_s,
                                 self.trigger.known_hvs)  # fmt: skip
            return
        self.plan = None
        self.trigger.planned(_no_plan(t_s), t_s, ())

    def _lane_ends(self, s_from_m: float, s_to_m: float) -> list[VehicleState]:
        """Lanes that end ahead of the front CAV's edge, as standing obstacles."""
        platoon = ordered_platoon(self.ctx.session.states, self.ctx.cav_ids)
        edge = self.lanes.edge_of(platoon[0]) if platoon else None
        return self.lanes.end_obstacles(edge, s_from_m, s_to_m)


def plan_is_idle(plan: Plan, step: int) -> bool:
    """Does ``plan`` keep every CAV in the cell it is planned in at ``step``, to the end?"""
    if not plan.ok:
        return False
    return all(keeps_cell(plan.cells_of(cav)[max(step, 0) :]) for cav in plan.cav_ids)


def _no_plan(t_s: float) -> Plan:
    """A cell-less plan that tells the trigger when the last solve failed."""
    return Plan(status=PlanStatus.INFEASIBLE, cells=None, objective=None, solve_ms=0.0,
                backend="none", t0_s=t_s)  # fmt: skip
