"""The swarm controller: the paper's method closed around SUMO, as a short coordinator.

Each SUMO step (after the step, acting on the next one):

1. *Cruise* as a CACC platoon. :mod:`~sumo_swarm.core.swarming.decision` names a target: the HV
   right ahead of the leader in its lane, slower than the cruise, worth passing, for
   ``swarm.trigger_after_s``.
2. *Overtake*: :mod:`~sumo_swarm.core.swarming.manoeuvre` builds the moving grid, the HV margins
   and predictions from each HV's own driver model (:mod:`sumo_swarm.core.hvmodel`), solves the cell
   MIP and turns the cells into references; :mod:`~sumo_swarm.core.swarming.tracker` follows them
   with the MPCs; :mod:`~sumo_swarm.core.swarming.guards` checks every command. Replans happen on
   the events of the paper's Fig. 4, at most one per behaving interval unless a safety check
   demands one.
3. The manoeuvre ends when every CAV is past the target and back in the regroup lane, when the
   target stops blocking (left the lane, sped up, vanished), or when it is given up (no progress,
   no feasible plan): then the swarm cruises again, after a cool-down if it gave up.

Command path (why speed + sublane moves, not moveToXY): ``setSpeed`` makes SUMO integrate the
CAV's true speed, so IDM followers see a real leader and brake for a CAV that moves in ahead of
them (that is how blocking works), and ``changeSublane`` moves the CAV sideways through the
sublane model. See docs/closed-loop.md. Every speed command is capped at the swarm's speed cap
(``cav.max_speed_mps``, the CAVs' vType maxSpeed and their allowed speed on the lane).
"""

from __future__ import annotations

import inspect
import itertools
import logging
import math
from collections import Counter
from collections.abc import Iterable
from dataclasses import replace
from typing import Any

from sumo_swarm.controllers.base import RouteWatch, RunContext
from sumo_swarm.controllers.cacc import command_cacc
from sumo_swarm.controllers.reform import Reformer, clip
from sumo_swarm.core.grid import MovingGrid, cav_cell, hv_blocked_cells
from sumo_swarm.core.hvmodel import DriverModel
from sumo_swarm.core.model import VehicleState
from sumo_swarm.core.neighbours import Snapshot, ordered_platoon, vehicle_ahead
from sumo_swarm.core.planner import CellPlanner, Plan, ReplanTrigger, make_planner
from sumo_swarm.core.planner.problem import LANE_END_PREFIX, hvs_in_grid
from sumo_swarm.core.stats import lateral_rms, summarise_ms
from sumo_swarm.core.swarming.decision import (
    REGROUPED_GAP_FACTOR,
    LanePass,
    Mode,
    Progress,
    TargetWatch,
    all_past,
    behaving_interval_s,
    cavs_behind,
    keeps_cell,
    lane_for_pass,
    lane_pass_pace,
    lane_speeds,
    leader_ease_cap,
    one_platoon,
    only_catching_up,
    passing_lane,
    right_lane_free,
    secure_gap_m,
    slow_vehicle_ahead,
    speed_cap_mps,
    stopped_blocking,
    straggler_cruise,
    stranded_cavs,
    waiting_plan,
)
from sumo_swarm.core.swarming.guards import (
    entering_lane,
    gap_accel_limit,
    gentle_for_follower,
    lane_speed_match,
    lateral_refusal,
    yields_to_cav,
)
from sumo_swarm.core.swarming.manoeuvre import ManoeuvrePlanner, ManoeuvreSettings, PlanOutcome
from sumo_swarm.core.swarming.planlog import PlanLog
from sumo_swarm.core.swarming.tracker import Tracker
from sumo_swarm.core.trajectory import Reference

log = logging.getLogger(__name__)

# Give-ups after which the CAVs pass the target one by one ([swarm] pass_singly_s): plans that
# found no way past together. A planner that fails (no_feasible_plan) leaves the platoon behind
# the target, the safe fallback.
PASS_SINGLY_AFTER = frozenset({"cavs_stranded", "no_progress", "no_way_past"})
# No lane change this close to a place where lane indices shift (see lane_shift_hold) [m].
LANE_SHIFT_HOLD_M = 40.0
# A keep-right driver starts moving over this long [s] after the lane to its right is free
# for it (SUMO's LC2013/SL2015: the wish builds over KEEP_RIGHT_TIME = 5 s at lcKeepRight 1),
# if the follower there is then at least at its secure gap; the swarm waits for it only where
# that holds with the follower closing in at its speed till then (decision.right_lane_free),
# and nothing slower is within KEEP_RIGHT_AHEAD_S [s] ahead there.
KEEP_RIGHT_MOVE_S = 5.0
KEEP_RIGHT_AHEAD_S = 4.0
# No CAV moves into a lane that ends within this many seconds at its speed (at least
# LANE_END_MIN_M ahead); a CAV whose lane ends within LANE_END_ESCAPE_S heads out of it.
LANE_END_HOLD_S = 12.0
LANE_END_ESCAPE_S = 8.0
LANE_END_MIN_M = 300.0  # an on-ramp's acceleration lane is 250 m in netbuild's motorway
# A CAV above the speed cap slows to it at this rate [m/s^2] (well inside the 4 m/s^2 line).
CAP_DECEL_MPS2 = 2.0

LANE_END_LENGTH_M = 1000.0  # length of the pseudo-obstacle standing for a lane that ends [m]
# Replans that a safety check demands: they are not rate-limited.
URGENT_TRIGGERS = frozenset({"initial", "cav_set_changed", "plan_done", "conflict"})
# A plan found infeasible on a grid held this much above the target's speed [m/s] is tried
# again at the target's own speed (SwarmController._replan).
GRID_RETRY_MPS = 0.1


class SwarmController:
    """The method of the paper: cruise, swarm past a slow vehicle, regroup, cruise."""

    name = "swarm"

    def __init__(self, planner: CellPlanner | None = None, tracker: Tracker | None = None) -> None:
        """``planner`` and ``tracker`` replace the ones built from the scenario."""
        self.ctx: RunContext | None = None
        self._planner_override = planner
        self._tracker_override = tracker
        self.mode = Mode.CRUISE
        self.target_id: str | None = None
        self.plan: Plan | None = None
        self.grid: MovingGrid | None = None
        self.references: dict[str, Reference] = {}
        self.configured: set[str] = set()
        self.solve_ms: list[float] = []
        self.solve_cpu_ms: list[float] = []  # the same solves' process time (one core)
        self.statuses: Counter[str] = Counter()
        self.triggers: Counter[str] = Counter()
        self.fallbacks = 0
        self.relaxations: Counter[str] = Counter()
        self.grid_retries: Counter[str] = Counter()  # "tried", "planned" (see _replan)
        self.lat_errors: list[float] = []
        self.t_start_s: float | None = None
        self.t_done_s: float | None = None
        self.targets: list[str] = []  # the target of each manoeuvre, in order
        self.aborts: Counter[str] = Counter()
        self.lateral_holds = 0
        self.lateral_yields = 0  # waits for a swarm CAV clearing a lane (tracker timing)
        self.waits_started = 0  # waits ahead of a target splitting the platoon (wait_ahead_s)
        self._yielding: dict[str, float] = {}
        self.holds_per_manoeuvre: list[int] = []
        self._holding: dict[str, float] = {}
        self.regroup_lane_used: int | None = None
        self.regroup_edge: str | None = None
        self.replan_not_before_s = -math.inf
        self.last_plan_s = -math.inf
        self.last_check_s = -math.inf
        self.interval_s: float | None = None
        self.cap_mps = math.inf
        self.cap_sources: dict[str, float] = {}
        self.progress: Progress | None = None
        self.blocked_until_s: dict[str, float] = {}
        self.blocked_since_s: dict[str, float] = {}
        self.blocked_min_accel: dict[str, float] = {}
        self.prediction: tuple[float, Any] | None = None
        self._models: dict[str, tuple[str | None, DriverModel]] = {}
        self._no_gain_target: str | None = None
        self._keep_right_target: str | None = None
        self._target_lane: tuple[str | None, int] | None = None
        self.lane_pass: LanePass | None = None  # a pass in a faster lane under way
        self._cells_for: str | None = None  # a target whose lane pass stalled: cells only

    # ------------------------------------------------------------------ set-up
    def attach(self, ctx: RunContext) -> None:
        self.ctx = ctx
        sc = ctx.scenario
        self.planner_settings = sc.planner
        if sc.swarm.regroup_lane is not None:
            self.planner_settings = replace(sc.planner, regroup_lane=sc.swarm.regroup_lane)
        planner = self._planner_override or make_planner(self.planner_settings)
        self._hints = "hint" in inspect.signature(planner.plan).parameters
        self.manoeuvre = ManoeuvrePlanner(
            planner,
            ManoeuvreSettings(
                planner=self.planner_settings, grid=sc.grid,
                b_safe_mps2=sc.hvmodel.b_safe_mps2, planner_share=sc.hvmodel.planner_share,
                margin_rule=sc.hvmodel.margin_rule, predictor=sc.hvmodel.predictor,
                prediction_dt_s=sc.hvmodel.prediction_dt_s, target_b_mps2=sc.hvmodel.target_b_mps2,
                block_decel_share=sc.hvmodel.block_decel_share,
                entry_speed_gain_mps=sc.hvmodel.entry_speed_gain_mps,
                a_min_mps2=sc.cav.accel_min_mps2, a_max_mps2=sc.cav.accel_max_mps2,
                max_lateral_speed_mps=sc.cav.max_lateral_speed_mps,
            ),
        )  # fmt: skip
        steps = sc.swarm.control_interval_steps or max(
            1, round(sc.swarm.control_interval_s / ctx.dt_s)
        )
        self.tracker = self._tracker_override or Tracker(sc.longitudinal, sc.lateral, steps)
        self.trigger = self._new_trigger()
        self.watch = TargetWatch(sc.swarm.trigger_after_s)
        self.planlog = PlanLog(ctx.out_dir)
        self.routes = RouteWatch()
        self.reformer = Reformer(
            sc, self.model_of, ctx.event, hold=self.lane_shift_hold, escape=self.lane_end_escape,
            ends=self._ends_ahead,
        )  # fmt: skip
        self.drawer = None  # a sumo-gui plan drawer, set by the session's side (sim.gui)

    @property
    def planner(self) -> CellPlanner:
        return self.manoeuvre.planner

    def _new_trigger(self) -> ReplanTrigger:
        sw = self.ctx.scenario.swarm
        return ReplanTrigger(drift_cells=sw.drift_rows, retry_interval_s=sw.retry_after_s)

    def _configure_new(self, states: dict[str, VehicleState]) -> None:
        for vid in self.ctx.cav_ids:
            if vid in states and vid not in self.configured:
                self.ctx.configure_cav(vid)
                self.configured.add(vid)
                self.tracker.add(vid)

    def model_of(self, vid: str) -> DriverModel:
        """The driver model of an HV, read from SUMO once per vehicle and edge: its desired
        speed is SUMO's, ``min(maxSpeed, lane limit * speedFactor)`` on the edge it is on."""
        session = self.ctx.session
        edge = self._edge_of(vid)
        cached = self._models.get(vid)
        if cached is not None and cached[0] == edge:
            return cached[1]
        try:
            model = session.driver_model(vid)
        except Exception:  # vanished, or a session without the call: a cautious default
            model = DriverModel(model="unknown")
        limits = getattr(session, "speed_limits", None)
        if limits is not None:
            try:
                allowed = limits(vid)[1]
            except Exception:
                allowed = math.inf
            if math.isfinite(allowed) and allowed > 0.0:
                model = replace(model, desired_speed_mps=min(model.desired_speed_mps, allowed))
        self._models[vid] = (edge, model)
        return model

    # ------------------------------------------------------------------ main step
    def control(self, t_s: float) -> None:
        try:
            self._control(t_s)
        except Exception as exc:  # never let a bug of ours crash the user's simulation
            log.exception("swarm controller failed at t = %.2f s", t_s)
            self.ctx.event("controller_error", message=f"{type(exc).__name__}: {exc}")
            if self.mode is Mode.OVERTAKE:
                try:
                    self._finish(t_s, completed=False, reason="controller_error")
                except Exception:  # the bookkeeping failed too: the CACC step below is safe
                    log.exception("ending the manoeuvre failed at t = %.2f s", t_s)
                    self.mode = Mode.CRUISE
            # The safe behaviour, with the least of our code: every CAV follows what drives
            # ahead of it in its lane (CACC), no lateral move.
            states = self.ctx.session.states
            command_cacc(self.ctx, ordered_platoon(states, self.ctx.cav_ids))

    def _control(self, t_s: float) -> None:
        ctx = self.ctx
        sc = ctx.scenario
        states = ctx.session.states
        self._configure_new(states)
        platoon = self.routes.members(ctx, t_s, ordered_platoon(states, ctx.cav_ids))
        self.routes.follow(ctx, command_cacc)
        if not platoon:
            return
        ctx.follow_world_speeds(platoon)
        road = ctx.session.road_at(platoon[0])
        if road is not None:
            ctx.road = road
        in_lanes = getattr(ctx.session, "states_in_lanes_of", None)
        if in_lanes is not None:
            # One lane numbering, the leader's edge's: behind a lane drop the CAVs not past it
            # yet count their lane one higher, and the reformer sent them to the wrong lane.
            states = in_lanes(platoon[0])
        self._watch_blocked(t_s, states)
        if self.drawer is not None and self.mode is Mode.OVERTAKE:
            self.drawer.update(t_s)
        if self.mode is Mode.CRUISE:
            target = self._lane_pass_target(t_s, states, platoon)
            if target is None and self.lane_pass is None:
                target = self._decide(t_s, states, platoon)
                lane = None if target is None else self._lane_beats_plan(target, states, platoon)
                if lane is not None:
                    self._start_lane_pass(t_s, target, lane, platoon)
                    target = None
            if target is not None:
                self._start_overtake(t_s, target)
        if self.mode is Mode.OVERTAKE:
            target = states.get(self.target_id)
            cavs = {v: states[v] for v in platoon}
            stop = stopped_blocking(
                target, self._target_changed_lane(target),
                slow_below_mps=self._slow_below(),
            )  # fmt: skip
            if stop is not None and target is not None and all_past(target, cavs, sc.cav.min_gap_m):
                self._finish(t_s, completed=True)  # all past: the cruise re-forms the platoon
            elif stop is not None:
                self._finish(t_s, completed=False, reason=stop)
            elif self._passing_in_lane(target, cavs, states):
                # One platoon in a faster lane: the cruise takes it past at that lane's pace.
                done = all_past(target, cavs, sc.cav.min_gap_m)
                self._finish(t_s, completed=done, reason="passing_lane", abort=False)
            elif self._overtake_done(target, cavs, states.values()):
                self._finish(t_s, completed=True)
            else:
                self.progress.update(t_s, target, list(cavs.values()), sc.cav.min_gap_m)
                interval = self.interval_s or self.planner_settings.behaving_interval_s
                give_up = self.progress.give_up_reason(
                    t_s,
                    sc.swarm.give_up_no_progress_intervals * interval,
                    sc.swarm.give_up_no_plan_s,
                    self.plan is not None,
                    partial_s=sc.swarm.give_up_partial_intervals * interval,
                    n_cavs=len(cavs),
                    stranding_plans=sc.swarm.give_up_stranded_plans,
                    waiting_plans=sc.swarm.give_up_waiting_plans,
                )
                if give_up is not None:
                    self._finish(t_s, completed=False, reason=give_up)
                    self.watch.cool_down(t_s + sc.swarm.cooldown_s)
                    self._wait_if_split(t_s, target, cavs)
                    if sc.swarm.pass_singly_s > 0.0 and give_up in PASS_SINGLY_AFTER:
                        # No way past together: the CAVs pass it one by one, as SUMO's
                        # drivers do, through the guards, and re-form the platoon ahead.
                        self.reformer.singly = (self.target_id, t_s + sc.swarm.pass_singly_s)
                else:
                    self._maybe_replan(t_s, states, platoon)
        if self.mode is Mode.OVERTAKE and self.plan is not None:
            self._track(t_s, states, platoon)
        else:
            self._cruise(t_s, states, platoon)

    # ------------------------------------------------------------------ decision
    def _slow_below(self) -> float:
        sw, cav = self.ctx.scenario.swarm, self.ctx.scenario.cav
        return cav.cruising_speed_mps * sw.trigger_speed_ratio

    def _speed_cap(self, platoon: list[str]) -> float:
        """The lowest of cav.max_speed_mps, the CAVs' vType maxSpeed and allowed lane speed
        (``platoon``: the CAVs to ask; the leader alone while cruising)."""
        sources = {"cav.max_speed_mps": self.ctx.scenario.cav.max_speed_mps}
        limits = getattr(self.ctx.session, "speed_limits", None)
        if limits is not None:
            for vid in platoon:
                try:
                    vtype_max, allowed = limits(vid)
                except Exception:
                    continue
                sources["vType maxSpeed"] = min(sources.get("vType maxSpeed", math.inf), vtype_max)
                sources["lane limit"] = min(sources.get("lane limit", math.inf), allowed)
        self.cap_sources = sources
        self.cap_mps = speed_cap_mps(list(sources.values()))
        return self.cap_mps

    def _decide(self, t_s: float, states, platoon: list[str]) -> VehicleState | None:
        ctx = self.ctx
        sw = ctx.scenario.swarm
        if ctx.road.n_lanes < 2 or t_s < sw.start_after_s:
            return None
        leader = states[self._decision_leader(states, platoon)]
        # Sorted once for both look-ups (the vehicle ahead of the leader, then the line ahead of
        # a candidate): every cruise step asks, a plain list scanned every vehicle each time.
        vehicles = Snapshot(states.values(), ctx.road)
        candidate = slow_vehicle_ahead(
            leader, vehicles, ctx.road,
            slow_below_mps=self._slow_below(), detect_range_m=sw.detect_range_m,
            cap_mps=self._speed_cap(platoon[:1]),
            min_gain_mps=sw.min_speed_gain_mps, width_m=ctx.scenario.cav.width_m,
        )  # fmt: skip
        # Not in a lane that ends within reach plus two 3 s intervals at the cruise (an
        # acceleration lane, a lane drop): everyone leaves that lane anyway.
        reach = sw.detect_range_m + 2.0 * 3.0 * ctx.scenario.cav.cruising_speed_mps
        if candidate is not None and leader.lane in self._ending_lanes(leader, platoon[0], reach):
            candidate = None
        if candidate is not None and self._catching_up(candidate, vehicles):
            candidate = None
        if candidate is not None and not self._side_lane_pays(leader, candidate, states):
            candidate = None
        wait_s = 0.0
        if candidate is not None and self._may_keep_right(candidate, states):
            wait_s = sw.keep_right_wait_s
        return self.watch.update(t_s, candidate, wait_s)

    def _catching_up(self, candidate: VehicleState, vehicles: Snapshot) -> bool:
        """Is ``candidate`` only catching up (:func:`only_catching_up`)? An event
        ``overtake_not_worth`` (reason ``catching_up``) says so once per vehicle."""
        ctx = self.ctx
        desired = self.reformer.desired_speed
        if not only_catching_up(
            candidate, vehicles, ctx.road, desired_of=desired,
            slow_below_mps=self._slow_below(), width_m=ctx.scenario.cav.width_m,
        ):  # fmt: skip
            return False
        if self._no_gain_target != candidate.vehicle_id:
            self._no_gain_target = candidate.vehicle_id
            ctx.event("overtake_not_worth", target=candidate.vehicle_id,
                      target_speed_mps=candidate.speed_mps, reason="catching_up",
                      desired_speed_mps=desired(candidate))  # fmt: skip
        return True

    def _secure_gap(self, follower: VehicleState, v_lead_mps: float) -> float:
        """SUMO's secure gap [m] of ``follower`` (an HV by its own model; a CAV by the swarm's
        braking) behind a vehicle at ``v_lead_mps``."""
        if follower.is_cav:
            cav = self.ctx.scenario.cav
            return secure_gap_m(0.0, -cav.accel_min_mps2, follower.speed_mps, v_lead_mps)
        model = self.model_of(follower.vehicle_id)
        return secure_gap_m(model.tau_s, model.decel_mps2, follower.speed_mps, v_lead_mps)

    def _may_keep_right(self, target: VehicleState, states) -> bool:
        """Will ``target`` soon move to the lane on its right of its own accord (a driver that
        keeps right, with that lane free now, or once before for a target in the leftmost
        lane)? An event says so once per target."""
        sc = self.ctx.scenario
        if sc.swarm.keep_right_wait_s <= 0.0:
            return False
        leftmost = self.ctx.road.lane_of(target) == self.ctx.road.n_lanes - 1
        if sc.swarm.keep_right_middle != "wait" and not leftmost:
            return False  # passed at once (on its left only, with "left")
        if not self._keeps_right(target):
            return False
        free = self._right_lane_free(target, states)
        if free and self._keep_right_target != target.vehicle_id:
            self._keep_right_target = target.vehicle_id
            self.ctx.event("target_may_keep_right", target=target.vehicle_id,
                           wait_s=sc.swarm.keep_right_wait_s)  # fmt: skip
        # Once seen free, the wait holds while that lane is taken for a moment, for a target in
        # the leftmost lane: every pass of it would take the lane it is to move into.
        return free or (leftmost and self._keep_right_target == target.vehicle_id)

    def _keep_right_closure(self, t_s: float, target: VehicleState, states) -> int | None:
        """The lane on the right of a target that keeps right with a lane on its left, while
        that lane is free for it to move into (:func:`right_lane_free`, as for the wait), closed
        to the cell plan beside and behind it for the first ``keep_right_wait_s`` of the
        manoeuvre (``[swarm] keep_right_middle = "left"``); None: nothing closed. (Closed
        whether free or not, it cost paper-scene variants whose truck could not move over up
        to 4 m/s: the CAVs could not use that lane while it was open.)"""
        sw, road = self.ctx.scenario.swarm, self.ctx.road
        if sw.keep_right_middle != "left" or sw.keep_right_wait_s <= 0.0:
            return None
        lane = road.lane_of(target)
        if not 0 < lane < road.n_lanes - 1:
            return None  # no lane on its right, or the leftmost lane (waited for instead)
        if t_s - self.progress.started_s > sw.keep_right_wait_s:
            return None
        if not self._keeps_right(target) or not self._right_lane_free(target, states):
            return None
        return lane - 1

    def _keeps_right(self, target: VehicleState) -> bool:
        """Does ``target``'s lane-change model keep right (read through libsumo)? False when
        it vanished or TraCI cannot tell."""
        keeps_right = getattr(self.ctx.session, "keeps_right", None)
        try:
            return keeps_right is not None and bool(keeps_right(target.vehicle_id))
        except Exception:
            return False

    def _right_lane_free(self, target: VehicleState, states) -> bool:
        """Is the lane on ``target``'s right free for it to move into now
        (:func:`right_lane_free`)?"""
        return right_lane_free(
            target, states.values(), self.ctx.road, move_s=KEEP_RIGHT_MOVE_S,
            ahead_s=KEEP_RIGHT_AHEAD_S, min_gap_m=self.ctx.scenario.cav.min_gap_m,
            secure_gap=self._secure_gap,
        )  # fmt: skip

    def _decision_leader(self, states, platoon: list[str]) -> str:
        """The CAV whose leader decides: the front CAV in the lane the platoon re-forms in.
        A CAV ahead of it in another lane is merging back (or passing on its own): a slow
        vehicle in front of it is not the platoon's. (After a target moved into the lane of
        the front CAV, the swarm took that CAV as its leader and overtook the same truck again,
        in a lane full of traffic, while the plain platoon drove on.)"""
        lane = self.reformer.lane_id
        if lane is not None and self.reformer.edge == self._edge_of(platoon[0]):
            road = self.ctx.road
            for vid in platoon:
                if road.lane_of(states[vid]) == lane:
                    return vid
        return platoon[0]

    def _side_lane_pays(self, leader: VehicleState, target: VehicleState, states) -> bool:
        """Is a lane beside the leader's faster than the target by ``min_speed_gain_mps``? The
        swarm passes in the lanes beside it: when they are as slow as the target (dense
        traffic), overtaking gains nothing and only disturbs them (MOBIL's incentive)."""
        ctx = self.ctx
        road, sw = ctx.road, ctx.scenario.swarm
        lane = road.lane_of(leader)
        side = [q for q in (lane - 1, lane + 1) if 0 <= q < road.n_lanes]
        others = [st for st in states.values() if not st.is_cav]
        reach = sw.detect_range_m + 2.0 * ctx.scenario.cell_length_m
        speeds = lane_speeds(leader, others, road, side, range_m=reach, cap_mps=self.cap_mps,
                             desired_of=self.reformer.desired_speed)  # fmt: skip
        best = max(speeds.values(), default=-math.inf)
        pays = best - target.speed_mps >= sw.min_speed_gain_mps
        if not pays and self._no_gain_target != target.vehicle_id:
            self._no_gain_target = target.vehicle_id
            ctx.event("overtake_not_worth", target=target.vehicle_id,
                      target_speed_mps=target.speed_mps,
                      lane_speeds_mps={str(k): round(v, 2) for k, v in speeds.items()})  # fmt: skip
        return pays

    def _target_changed_lane(self, target: VehicleState | None) -> bool:
        """Has the target changed lanes on its own since the decision? Lane indices change
        where a lane ends (netconvert drops the rightmost), so only a new lane on the same edge,
        with the target settled in it, counts."""
        if target is None:
            return False
        edge = self.ctx.session.edges.get(target.vehicle_id)
        if self._target_lane is None or self._target_lane[0] != edge:
            self._target_lane = (edge, target.lane)
            return False
        return target.lane != self._target_lane[1] and abs(target.lat_m) < 0.5

    # ------------------------------------------------------------------ cruise
    def _cruise(self, t_s: float, states: dict[str, VehicleState], platoon: list[str]) -> None:
        """CACC following in the current lane, drifting back to the lane centre."""
        ctx = self.ctx
        sc = ctx.scenario
        # A stretched platoon regroups from both ends: followers may exceed the cruising speed
        # (cacc_accel), and the leader eases off by k_close per metre of excess gap behind it,
        # which is what closes up a platoon whose CAVs cannot go faster than the cruise speed.
        stretch = 0.0
        for front, back in itertools.pairwise(platoon):
            f, b = states[front], states[back]
            if f.lane == b.lane:
                stretch += max(0.0, f.rear_s_m - b.s_m - sc.cav.desired_gap_m)
        # The leader eases off only by what the followers cannot make up above the cruise
        # (up to the cap): with room above it, easing off slowed the whole re-formed platoon
        # by up to 2 m/s for 20 s after a target left the lane, where cacc drove on.
        reformer, road = self.reformer, ctx.road
        reformer.scenario = sc  # the speeds may follow the world
        cap = self._speed_cap(platoon[:1])
        room = max(min(cap, sc.cav.max_speed_mps) - sc.cav.cruising_speed_mps, 0.0)
        leader_cruise = sc.cav.cruising_speed_mps - min(
            self._leader_ease_cap(states, platoon), max(sc.cacc.k_close * stretch - room, 0.0)
        )
        # Never re-form in a lane that ends within 10 s at the cruise (an acceleration lane).
        reach = sc.swarm.detect_range_m + 10.0 * sc.cav.cruising_speed_mps
        ending = self._ending_lanes(states[platoon[0]], platoon[0], reach)
        edge = self._edge_of(platoon[0])
        waits_at = reformer.split_by(t_s, states, platoon, road, ending)
        lane = reformer.lane(states, platoon, road, ending=ending, cap_mps=cap, edge=edge)
        goals = reformer.goals(t_s, states, platoon, road, lane, cap_mps=cap)
        moves = reformer.moves(states, platoon, road, lane, goals, ctx.dt_s)
        cruise = None
        boost = reformer.pull_away(states, platoon, road, lane, cap_mps=cap)
        if boost > 0.0:  # an HV following the platoon keeps a CAV out of its lane
            cruise = sc.cav.cruising_speed_mps + boost
            leader_cruise = max(leader_cruise, cruise)
        base = sc.cav.cruising_speed_mps if cruise is None else cruise
        catch_up = straggler_cruise(
            states, platoon, road, cruise_mps=base, cap_mps=min(cap, sc.cav.max_speed_mps),
            desired_gap_m=sc.cav.desired_gap_m, k_close=sc.cacc.k_close,
            slow_below_mps=sc.cav.cruising_speed_mps - sc.swarm.min_speed_gain_mps,
            reach_m=sc.swarm.detect_range_m, width_m=sc.cav.width_m,
        ) if sc.swarm.catch_up_across_lanes else {}  # fmt: skip
        if waits_at is not None and boost <= 0.0:
            wait = reformer.wait_cruise(states, platoon, road, waits_at, base)
            catch_up = {**catch_up, **{v: min(catch_up.get(v, base), w) for v, w in wait.items()}}
            if platoon[0] in wait:
                leader_cruise = min(leader_cruise, wait[platoon[0]])
        command_cacc(ctx, platoon, leader_cruise,
                     accel_limits={vid: m[1] for vid, m in moves.items()},
                     accel_floors=reformer.floors, states=states, cruise_mps=cruise,
                     cruise_of=catch_up)  # fmt: skip
        for vid, (dlat, _) in moves.items():
            ctx.session.change_sublane(vid, dlat)
        self.tracker.straighten(platoon)

    def _wait_if_split(
        self, t_s: float, target: VehicleState | None, cavs: dict[str, VehicleState]
    ) -> None:
        """After a give-up: wait for the CAVs behind ``target`` if it splits the platoon
        (``[swarm] wait_ahead_s``, :meth:`Reformer.split_by`; a ``wait_start`` event)."""
        wait_s = self.ctx.scenario.swarm.wait_ahead_s
        if wait_s <= 0.0 or target is None:
            return
        past = sum(self.reformer.past(c, target) for c in cavs.values())
        if 0 < past < len(cavs):
            self.waits_started += 1
            self.reformer.waiting = (target.vehicle_id, t_s, t_s + wait_s)
            self.ctx.event("wait_start", slow=target.vehicle_id, past=past,
                           behind=len(cavs) - past, until_s=round(t_s + wait_s, 2))  # fmt: skip

    def _leader_ease_cap(self, states: dict[str, VehicleState], platoon: list[str]) -> float:
        """How much [m/s] the cruising leader may slow to let a stretched platoon close up
        (:func:`leader_ease_cap`)."""
        sc = self.ctx.scenario
        return leader_ease_cap(
            states, platoon, self.ctx.road, width_m=sc.cav.width_m,
            reach_m=sc.swarm.detect_range_m, ease_mps=sc.swarm.max_leader_ease_mps,
            regroup_ease_mps=sc.swarm.regroup_ease_mps,
        )  # fmt: skip

    def lane_shift_hold(self, ego: VehicleState, y: float, dlat: float) -> bool:
        """Hold a lane change near a place where lane indices shift (a lane added or dropped
        on the right: on-ramps, lane drops): there the vehicles on either side of the junction
        count their lanes differently, so the neighbour look-ups cannot be trusted. Also hold
        one into a lane that ends ahead (an acceleration lane, a lane drop) within
        LANE_END_HOLD_S at the CAV's speed: a CAV moved into an on-ramp's acceleration lane,
        which the plan's columns took for a through lane, and stopped at its end."""
        if entering_lane(self.ctx.road, y, dlat, self.ctx.scenario.guards) is None:
            return False
        ego = self._own(ego)
        entering = ego.lane + (1 if dlat > 0 else -1)
        if entering in self._lanes_ending_ahead(ego, LANE_END_HOLD_S):
            return True
        near = getattr(self.ctx.session, "near_lane_shift", None)
        return near is not None and near(ego.s_m, LANE_SHIFT_HOLD_M + ego.length_m)

    def _own(self, ego: VehicleState) -> VehicleState:
        """``ego`` with its lane index on its own edge (the controller's states count lanes as
        on the leader's edge: ``states_in_lanes_of``), for what is read on that edge."""
        return self.ctx.session.states.get(ego.vehicle_id, ego)

    def _ends_ahead(self, ego: VehicleState) -> set[int]:
        """Lanes that end within LANE_END_HOLD_S ahead of ``ego``, numbered as ``ego``'s lane
        is (the leader's edge's numbering), for the reformer."""
        own = self._own(ego)
        shift = ego.lane - own.lane
        return {lane + shift for lane in self._lanes_ending_ahead(own, LANE_END_HOLD_S)}

    def _lanes_ending_ahead(self, ego: VehicleState, horizon_s: float) -> set[int]:
        """Lanes of ``ego``'s own edge that end within ``horizon_s`` at its speed (at least
        LANE_END_MIN_M) ahead of it."""
        reach_m = max(LANE_END_MIN_M, horizon_s * ego.speed_mps)
        return self._ending_lanes(ego, ego.vehicle_id, reach_m)

    def lane_end_escape(self, ego: VehicleState, dlat: float, step_m: float) -> float:
        """The lateral move [m] of ``ego`` this step: ``dlat``, unless its lane ends within
        LANE_END_ESCAPE_S: then towards the neighbouring lane that goes on (left first: lanes
        end on the right at on-ramps), through the lateral guard like any other move."""
        ego = self._own(ego)
        ending = self._lanes_ending_ahead(ego, LANE_END_ESCAPE_S)
        if ego.lane not in ending:
            return dlat
        n_lanes = self._lane_count(ego)
        for side in (1, -1):
            lane = ego.lane + side
            if 0 <= lane < n_lanes and lane not in ending:
                return side * step_m
        return dlat

    def _lane_count(self, ego: VehicleState) -> int:
        frame = getattr(self.ctx.session, "frame", None)
        edge = self._edge_of(ego.vehicle_id)
        if frame is None or edge is None:
            return self.ctx.road.n_lanes
        try:
            return frame.lane_count(edge)
        except Exception:
            return self.ctx.road.n_lanes

    def _edge_of(self, vid: str) -> str | None:
        """The edge ``vid`` is on (None if unknown, or a session without edges)."""
        edges = getattr(self.ctx.session, "edges", None)
        return None if edges is None else edges.get(vid)

    def _ending_lanes(
        self, leader: VehicleState, vid: str, range_m: float | None = None
    ) -> set[int]:
        """Lanes that end within ``range_m`` (default ``[swarm] detect_range_m``) ahead of the
        leader ``vid``."""
        session = self.ctx.session
        edge = self._edge_of(vid)
        if edge is None or not hasattr(session, "lanes_ending"):
            return set()
        if range_m is None:
            range_m = self.ctx.scenario.swarm.detect_range_m
        reach = leader.s_m + range_m
        return {lane for lane, _ in session.lanes_ending(edge, leader.rear_s_m, reach)}

    # ------------------------------------------------------------------ overtake
    def _count_manoeuvre(self, t_s: float, target_id: str) -> None:
        """A manoeuvre on ``target_id`` starts: the summary's overtake block describes the
        first one (its target and decision time), ``targets`` lists them all. (It gave the
        last manoeuvre's target with the first one's decision time: after a second overtake,
        of a car the platoon met past the truck, a run was judged on that car.)"""
        self.target_id = target_id
        self.targets.append(target_id)
        if self.t_start_s is None:
            self.t_start_s = t_s

    def _start_overtake(self, t_s: float, target: VehicleState) -> None:
        self.mode = Mode.OVERTAKE
        self._count_manoeuvre(t_s, target.vehicle_id)
        self.plan = None
        self.trigger = self._new_trigger()
        self.progress = Progress(t_s)
        self.holds_per_manoeuvre.append(0)
        self.blocked_until_s = {}
        self.blocked_since_s = {}
        lane = self.planner_settings.regroup_lane
        self.regroup_lane_used = target.lane if lane is None else lane
        self.regroup_edge = self.reformer.edge  # whose lane numbering that lane is in
        self.reformer.prefer = None
        self._target_lane = None
        self.ctx.event("overtake_start", target=target.vehicle_id, speed_cap_mps=self.cap_mps)

    def _passing_in_lane(self, target: VehicleState, cavs: dict[str, VehicleState], states) -> bool:
        """Has every CAV left the target's lane for one lane, faster than the target by
        ``[swarm] min_speed_gain_mps`` ahead of the front CAV (``hand_over_in_lane``)?"""
        sc = self.ctx.scenario
        sw, road = sc.swarm, self.ctx.road
        if not sw.hand_over_in_lane or len(cavs) < 1:
            return False
        lane = passing_lane(target, list(cavs.values()), road, tolerance_m=sw.in_lane_tolerance_m)
        front = max(cavs.values(), key=lambda c: c.s_m)
        if lane is None or lane in self._ending_lanes(front, front.vehicle_id):
            return False
        others = [st for v, st in states.items() if v not in cavs]
        speeds = lane_speeds(
            front, others, road, [lane], range_m=sw.detect_range_m, cap_mps=self.cap_mps,
            desired_of=self.reformer.desired_speed,
        )  # fmt: skip
        # The cruise must pay: faster than the plan's pace (one cell per behaving interval
        # above the grid) by the gain; with the cruise barely above the target (the paper's
        # 20 m/s beside an 18 m/s HV) the plan passes faster, up to the cap.
        interval = self.interval_s or self.planner_settings.behaving_interval_s
        grid_speed = self.grid.speed_mps if self.grid is not None else target.speed_mps
        pace = max(grid_speed, target.speed_mps) + sc.cell_length_m / interval
        cruise = min(speeds[lane], sc.cav.cruising_speed_mps)
        return cruise - pace >= sw.min_speed_gain_mps

    # ------------------------------------------------------------------ passing in a lane
    def _lane_beats_plan(self, target: VehicleState, states, platoon: list[str]) -> int | None:
        """The lane the platoon moves over to and passes ``target`` in (``[swarm] lane_pass``,
        :func:`lane_for_pass`), or None: the cells."""
        ctx = self.ctx
        sc = ctx.scenario
        road, sw = ctx.road, sc.swarm
        if not sw.lane_pass or target.vehicle_id == self._cells_for:
            return None
        leader = states[self._decision_leader(states, platoon)]
        lane = road.lane_of(leader)
        side = [q for q in (lane - 1, lane + 1) if 0 <= q < road.n_lanes]
        side = [q for q in side if q not in self._ending_lanes(leader, leader.vehicle_id)]
        interval = behaving_interval_s(
            self.planner_settings.behaving_interval_s, sc.cell_length_m, target.speed_mps,
            self.cap_mps, sw.speed_margin_mps, sw.interval_rule,
        )  # fmt: skip
        return lane_for_pass(
            leader, states[platoon[-1]], target, [st for st in states.values() if not st.is_cav],
            road, side, n_cavs=len(platoon), cell_length_m=sc.cell_length_m,
            range_m=sw.detect_range_m, cap_mps=self.cap_mps,
            cruise_mps=sc.cav.cruising_speed_mps,
            pace_mps=target.speed_mps + sc.cell_length_m / interval,
            free_pace_mps=lane_pass_pace(
                target.speed_mps, sc.cell_length_m / interval, cruise_mps=sc.cav.cruising_speed_mps,
                min_gain_mps=sw.min_speed_gain_mps, rule=sw.lane_pass_beats,
            ),
            min_gain_mps=sw.min_speed_gain_mps, tolerance_m=sw.in_lane_tolerance_m,
            desired_of=self.reformer.desired_speed,
        )  # fmt: skip

    def _start_lane_pass(
        self, t_s: float, target: VehicleState, lane: int, platoon: list[str]
    ) -> None:
        """The platoon moves over to ``lane`` as a unit, each CAV through the lateral guard,
        entering speeding up, and passes ``target`` there (the cruise's re-forming)."""
        self._count_manoeuvre(t_s, target.vehicle_id)
        self.lane_pass = LanePass(target.vehicle_id, lane, t_s)
        self._target_lane = None
        self.reformer.move_to = (lane, self._edge_of(platoon[0]))
        self.ctx.event("overtake_start", target=target.vehicle_id, speed_cap_mps=self.cap_mps,
                       how="lane", lane=lane)  # fmt: skip

    def _lane_pass_target(self, t_s: float, states, platoon: list[str]) -> VehicleState | None:
        """Follow a lane pass (:class:`LanePass`): its end once every CAV is past, the target
        gone or no longer blocking; the target, for the cells, once it stalls; else None."""
        if self.lane_pass is None:
            return None
        sc = self.ctx.scenario
        target = states.get(self.lane_pass.target_id)
        how = self.lane_pass.update(
            t_s, target, [states[v] for v in platoon], self.ctx.road,
            min_gap_m=sc.cav.min_gap_m, stall_s=sc.swarm.lane_pass_stall_s,
        )  # fmt: skip
        if how in ("completed", "target_left"):
            self._end_lane_pass(t_s, completed=how == "completed", reason=how)
            return None
        stop = stopped_blocking(target, self._target_changed_lane(target),
                                slow_below_mps=self._slow_below())  # fmt: skip
        if stop is not None:  # it moved over (perhaps into the lane the platoon moves to)
            self._end_lane_pass(t_s, completed=False, reason=stop)
            return None
        if how == "stalled":
            self._cells_for = self.lane_pass.target_id
            self._end_lane_pass(t_s, completed=False, reason="lane_pass_stalled")
            return target
        return None

    def _end_lane_pass(self, t_s: float, *, completed: bool, reason: str) -> None:
        self.lane_pass = None
        self.reformer.move_to = None
        if completed and self.t_done_s is None:
            self.t_done_s = t_s
        self.ctx.event("overtake_end", target=self.target_id, completed=completed,
                       reason=reason, how="lane")  # fmt: skip

    def _finish(
        self, t_s: float, completed: bool, reason: str = "completed", abort: bool = True
    ) -> None:
        self.mode = Mode.CRUISE
        self.reformer.reset()  # the platoon's lane chosen afresh from where the CAVs are now
        if self.drawer is not None:
            self.drawer.clear()
        self.plan = None
        self.references = {}
        self.watch.candidate_id = self.watch.since_s = None
        if completed and self.t_done_s is None:
            self.t_done_s = t_s
        if completed and reason == "completed" and self.regroup_lane_used is not None:
            self.reformer.prefer = (self.regroup_lane_used, self.regroup_edge)
        if not completed and abort:
            self.aborts[reason] += 1
        self.ctx.event("overtake_end", target=self.target_id, completed=completed, reason=reason)

    def _overtake_done(
        self,
        target: VehicleState,
        cavs: dict[str, VehicleState],
        others: Iterable[VehicleState] = (),
    ) -> bool:
        road = self.ctx.road
        sc = self.ctx.scenario
        if not all_past(target, cavs, sc.cav.min_gap_m):
            return False
        if sc.swarm.regroup_by == "cruise":
            return True  # the cruise mode re-forms the platoon
        tol = sc.swarm.in_lane_tolerance_m
        if sc.swarm.regroup_anywhere and one_platoon(
            list(cavs.values()), others, road, tolerance_m=tol,
            max_gap_m=REGROUPED_GAP_FACTOR * sc.cav.desired_gap_m,
        ):  # fmt: skip
            return True
        y_lane = road.lane_centre_y(self.regroup_lane_used)
        return all(abs(road.y_of(c.lane, c.lat_m) - y_lane) <= tol for c in cavs.values())

    def _maybe_replan(self, t_s: float, states: dict[str, VehicleState], platoon: list[str]):
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
                if self._new_hv_conflicts(t_s, states, hvs):
                    reason = "conflict"
                else:
                    self.trigger.known_hvs = frozenset(in_grid)
                    reason = None
            if set(platoon) != set(self.plan.cav_ids):
                ctx.event("cav_set_changed", planned=list(self.plan.cav_ids), present=platoon)
                reason = "cav_set_changed"
            every = ctx.scenario.swarm.replan_every_intervals
            if (
                reason is None
                and every
                and t_s - self.last_check_s >= every * (self.interval_s or 0.0) - 1e-9
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
                elif self._still_waiting(t_s, states):
                    reason = "waiting_plan"  # the same for a gap it sees far ahead in time
        elif self.plan is None and self.trigger.plan is not None:
            reason = self.trigger.check(t_s, {}, ())  # "initial" once the retry time has passed
        if reason is None or t_s < self.replan_not_before_s:
            return
        min_gap = ctx.scenario.swarm.replan_min_interval_s
        interval = self.interval_s or self.planner_settings.behaving_interval_s
        min_gap = interval if min_gap is None else min_gap
        if reason not in URGENT_TRIGGERS and t_s - self.last_plan_s < min_gap:
            return
        self._replan(t_s, reason, states, platoon)

    def _still_waiting(self, t_s: float, states) -> bool:
        """Does the rest of the plan keep every CAV behind the target waiting (see
        :func:`waiting_plan`)? Only counted when ``[swarm] give_up_waiting_plans`` is on."""
        target = states.get(self.target_id)
        if not self.ctx.scenario.swarm.give_up_waiting_plans or target is None or not self.plan.ok:
            return False
        step = max(self.trigger.current_step(t_s), 0)
        planned = [states[v] for v in self.plan.cav_ids if v in states]
        behind = cavs_behind(target, planned, self.ctx.scenario.cav.min_gap_m)
        cells = {v: self.plan.cells_of(v)[step:] for v in self.plan.cav_ids}
        return waiting_plan(cells, behind, self._waiting_steps())

    def _prediction_off(self, t_s: float, states, in_grid: list[str]) -> bool:
        """Is an HV in the grid (``in_grid``) farther from where the last plan predicted it than
        allowed?"""
        if self.prediction is None or not hasattr(self.prediction[1], "error_against"):
            return False
        near = {vid: states[vid] for vid in in_grid}
        errors = self.prediction[1].error_against(near, t_s)
        limit = self.ctx.scenario.swarm.prediction_error_m
        return any(abs(e) > limit for e in errors.values())

    def _new_hv_conflicts(self, t_s: float, states, hvs: list[VehicleState]) -> bool:
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

    def _replan(self, t_s: float, reason: str, states: dict[str, VehicleState], platoon):
        ctx = self.ctx
        sc = ctx.scenario
        target = states[self.target_id]
        cavs = [states[v] for v in platoon]
        # Paper II-B-1, Step 4: the grid moves with the front HV while the swarm overtakes it,
        # at the cruising speed otherwise (here: once every CAV is past it, to regroup).
        cruise_grid = sc.swarm.regroup_grid_speed == "cruise" and all_past(
            target, {v: states[v] for v in platoon}, sc.cav.min_gap_m
        )
        grid_speed = sc.cav.cruising_speed_mps if cruise_grid else max(target.speed_mps, 0.0)
        if not cruise_grid and self.grid is not None and self._cav_ahead_of(target, states):
            # CAVs just ahead of the target set its pace: never let them pull the grid down.
            grid_speed = max(grid_speed, self.grid.speed_mps)
        cap = self._speed_cap(platoon)

        def interval_at(speed: float) -> float:
            return behaving_interval_s(
                self.planner_settings.behaving_interval_s, sc.cell_length_m, speed, cap,
                sc.swarm.speed_margin_mps, sc.swarm.interval_rule,
            )  # fmt: skip

        interval = interval_at(grid_speed)
        self.triggers[reason] += 1
        if not math.isfinite(interval):
            record = {"time_s": t_s, "trigger": reason, "status": "undrivable",
                      "speed_cap_mps": cap, "grid_speed_mps": grid_speed}  # fmt: skip
            self._fail(t_s, reason, record)
            return
        previous = None
        if self._hints and self.plan is not None and self.grid is not None:
            previous = (self.plan, self.grid)  # the warm start of the next solve
        max_block = sc.swarm.max_block_s
        budget = {
            hv: max(0, math.floor((max_block - (t_s - since)) / interval + 1e-9))
            for hv, since in self.blocked_since_s.items()
        }
        closed = self._keep_right_closure(t_s, target, states)
        own = max(target.speed_mps, 0.0)
        tries = [(grid_speed, interval)]
        if not cruise_grid and grid_speed > own + GRID_RETRY_MPS:
            # Held above the target's speed by the CAVs ahead of it, the grid leaves the target
            # behind: the CAVs queued behind it must fall back row by row over the horizon, and
            # with the tail CAV in row 0 they may have nowhere to go (variant 17: 5 CAVs behind
            # a truck 0.8 m/s slower than the grid). A plan found infeasible is tried once more
            # at the target's own speed (the paper's Step 4).
            own_interval = interval_at(own)
            if math.isfinite(own_interval):
                tries.append((own, own_interval))
        obstacles = self._lane_ends(cavs[-1].rear_s_m, target.s_m + 400.0)
        for n, (speed, speed_interval) in enumerate(tries):
            outcome = self.manoeuvre.plan(
                t_s, reason, states, platoon, self.target_id, ctx.road,
                obstacles=obstacles, model_of=self.model_of, grid_speed_mps=speed, cap_mps=cap,
                interval_s=speed_interval, step_s=ctx.dt_s, block_budget=budget,
                previous=previous, closed_lane=closed,
            )  # fmt: skip
            if n:
                outcome.record["grid_speed_rule"] = "target"
                self.grid_retries["tried"] += 1
                self.grid_retries["planned"] += int(outcome.usable)
            self._log_outcome(t_s, reason, outcome, states, prediction_error=not n)
            interval = speed_interval
            if outcome.plan is None or outcome.plan.status.value != "infeasible":
                break
        if not outcome.usable:
            self._fail(t_s, reason, None)
            return
        plan = outcome.plan
        self.plan, self.grid, self.references = plan, outcome.grid, outcome.references
        self.interval_s = interval
        self.last_plan_s = self.last_check_s = t_s
        self.prediction = (t_s, outcome.predictor)
        self.trigger.planned(plan, t_s, outcome.problem.hv_ids)
        self.tracker.reset()
        self.progress.planned(t_s)
        behind = cavs_behind(target, cavs, sc.cav.min_gap_m)
        cells = dict(zip(plan.cav_ids, plan.cells, strict=True))
        self.progress.plan_strands(stranded_cavs(cells, behind), len(cavs))
        self.progress.plan_waits(waiting_plan(cells, behind, self._waiting_steps()))
        for blocker in outcome.problem.blockers:
            self.blocked_since_s.setdefault(blocker.hv_id, t_s)
            until = t_s + (blocker.hold_steps + 1) * interval
            self.blocked_until_s[blocker.hv_id] = max(self.blocked_until_s.get(blocker.hv_id, 0.0),
                                                      until)  # fmt: skip

    def _log_outcome(
        self,
        t_s: float,
        reason: str,
        outcome: PlanOutcome,
        states: dict[str, VehicleState],
        *,
        prediction_error: bool,
    ) -> None:
        """Count one planning call's outcome and write its record to plans.jsonl (with the
        last plan's prediction error against ``states`` when ``prediction_error``)."""
        ctx = self.ctx
        record = outcome.record
        if (
            prediction_error
            and self.prediction is not None
            and hasattr(self.prediction[1], "error_against")
        ):
            errors = self.prediction[1].error_against(
                {v: s for v, s in states.items() if not s.is_cav}, t_s
            )
            if errors:
                values = [abs(e) for e in errors.values()]
                record["prediction_error_m"] = {
                    "made_at_s": self.prediction[0], "max": max(values),
                    "mean": sum(values) / len(values), "hvs": len(values),
                }  # fmt: skip
        if outcome.plan is not None:
            self.solve_ms.append(outcome.plan.solve_ms)
            if outcome.plan.cpu_ms is not None:
                self.solve_cpu_ms.append(outcome.plan.cpu_ms)
            self.statuses[outcome.plan.status.value] += 1
        else:
            self.statuses["error"] += 1
        if outcome.relaxed is not None:
            self.relaxations[outcome.relaxed] += 1
            ctx.event("margins_relaxed", level=outcome.relaxed, trigger=reason)
        self.planlog.write(record)

    def _waiting_steps(self) -> int:
        """Behaving steps in ``[swarm] give_up_waiting_s`` (a plan that keeps every CAV
        behind the target in its cell that long waits)."""
        interval = self.interval_s or self.planner_settings.behaving_interval_s
        return max(1, math.ceil(self.ctx.scenario.swarm.give_up_waiting_s / interval - 1e-9))

    def _cav_ahead_of(self, target: VehicleState, states: dict[str, VehicleState]) -> bool:
        """Is a CAV the vehicle right ahead of the target, within three cells?"""
        sc = self.ctx.scenario
        ahead = vehicle_ahead(target, list(states.values()), self.ctx.road, width_m=sc.cav.width_m)
        return ahead is not None and ahead[0].is_cav and ahead[1] < 3 * sc.cell_length_m

    def _fail(self, t_s: float, reason: str, record: dict[str, Any] | None) -> None:
        """Failed, timed out or invalid: keep the last valid plan while it lasts, else CACC."""
        if record is not None:
            self.statuses[record["status"]] += 1
            self.planlog.write(record)
        self.fallbacks += 1
        if self.progress is not None:
            self.progress.failed()
        self.replan_not_before_s = t_s + self.ctx.scenario.swarm.retry_after_s
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
        """Lanes that end ahead (a later route edge has fewer lanes), as standing obstacles."""
        session = self.ctx.session
        platoon = ordered_platoon(session.states, self.ctx.cav_ids)
        edge = session.edges.get(platoon[0]) if platoon else None
        out = []
        for lane, end in session.lanes_ending(edge, s_from_m, s_to_m) if edge else []:
            out.append(
                VehicleState(f"{LANE_END_PREFIX}{lane}@{end:.0f}", end + LANE_END_LENGTH_M,
                             lane, 0.0, 0.0, LANE_END_LENGTH_M)
            )  # fmt: skip
        return out

    def _watch_blocked(self, t_s: float, states: dict[str, VehicleState]) -> None:
        """Strongest deceleration of each HV while (and one interval after) it is blocked."""
        grace = self.interval_s or self.planner_settings.behaving_interval_s
        for hv, until in self.blocked_until_s.items():
            st = states.get(hv)
            if st is not None and t_s <= until + grace:
                self.blocked_min_accel[hv] = min(self.blocked_min_accel.get(hv, 0.0), st.accel_mps2)

    # ------------------------------------------------------------------ tracking
    def _track(self, t_s: float, states: dict[str, VehicleState], platoon: list[str]) -> None:
        ctx = self.ctx
        sc = ctx.scenario
        road = ctx.road
        dt = ctx.dt_s
        others = Snapshot(states.values(), road)
        solve = self.tracker.tick()
        cap = self.cap_mps if math.isfinite(self.cap_mps) else sc.cav.max_speed_mps
        gentle = sc.hvmodel.planner_share * sc.hvmodel.b_safe_mps2
        for vid in platoon:
            ego = states[vid]
            ref = self.references.get(vid)
            if ref is None:
                continue
            cmd = self.tracker.command(t_s, ego, ref, road, dt, solve)
            self.lat_errors.append(cmd.lat_error_m)
            y = road.y_of(ego.lane, ego.lat_m)
            step_m = sc.cav.max_lateral_speed_mps * dt
            escape = self.lane_end_escape(ego, cmd.dlat_m, step_m)
            if escape != cmd.dlat_m:
                cmd = replace(cmd, dlat_m=escape)
            waits_for = yields_to_cav(
                ego, y, cmd.dlat_m, others, road, min_gap_m=sc.cav.min_gap_m,
                width_m=sc.cav.width_m, settings=sc.guards,
            )  # fmt: skip
            refusal = None
            if waits_for is None:
                refusal = lateral_refusal(
                    ego, y, cmd.dlat_m, others, road, min_gap_m=sc.cav.min_gap_m,
                    width_m=sc.cav.width_m, model_of=self.model_of,
                    b_safe_mps2=sc.hvmodel.b_safe_mps2, step_s=dt, settings=sc.guards,
                    brake_mps2=-sc.cav.accel_min_mps2,
                )  # fmt: skip
            else:
                self._count_yield(vid, t_s)
            shift = self.lane_shift_hold(ego, y, cmd.dlat_m)
            dlat = 0.0 if refusal or waits_for is not None else cmd.dlat_m
            if shift:  # back to the lane centre: never straddle two lanes near the junction
                step = sc.cav.max_lateral_speed_mps * dt
                dlat = clip(road.lane_centre_y(road.lane_of_y(y)) - y, step)
            self._count_hold(vid, refusal, road.lane_of_y(y + cmd.dlat_m), t_s)
            self.tracker.commit(ego, cmd, dlat != cmd.dlat_m, road, dt)
            accel = cmd.accel_mps2
            # Into a faster lane at that lane's speed (up to the cap); with an HV close behind,
            # slow down only gently (that is how a blocker brings a lane down to its speed).
            lane_to = road.lane_of_y(
                ref.y_at_s(ego.centre_s_m + sc.swarm.match_lookahead_s * ego.speed_mps)
            )
            accel = max(
                accel, lane_speed_match(ego, lane_to, others, road, sc.cav.width_m, cap, sc.guards)
            )
            accel = max(
                accel, gentle_for_follower(ego, others, road, sc.cav.width_m, gentle, sc.guards)
            )
            limit = gap_accel_limit(
                ego, y, y + dlat, others, road, sc.cav.min_gap_m, sc.cav.width_m, sc.guards
            )
            accel = min(max(min(accel, limit), sc.cav.accel_min_mps2), sc.cav.accel_max_mps2)
            # Above the cap (a CAV that departed faster, a lower limit ahead) it comes down to
            # it gently, never by a jump in the commanded speed (SUMO would brake at decel).
            v_cmd = min(ego.speed_mps + accel * dt, max(cap, ego.speed_mps - CAP_DECEL_MPS2 * dt))
            ctx.session.set_speed(vid, max(v_cmd, 0.0))
            ctx.session.change_sublane(vid, dlat)

    def _new_episode(self, seen: dict[str, float], vid: str, t_s: float) -> bool:
        """Record ``vid`` in ``seen`` at ``t_s``: a new episode unless it was there within
        ``[swarm] hold_episode_s``."""
        last = seen.get(vid)
        seen[vid] = t_s
        return last is None or t_s - last > self.ctx.scenario.swarm.hold_episode_s

    def _count_yield(self, vid: str, t_s: float) -> None:
        """One ``lateral_yields`` per episode: a CAV waiting for a swarm CAV to clear a lane."""
        if self._new_episode(self._yielding, vid, t_s):
            self.lateral_yields += 1

    def _count_hold(self, vid: str, refusal: str | None, lane: int, t_s: float) -> None:
        """One ``lateral_hold`` per episode: a CAV held, not held again within hold_episode_s."""
        if refusal is None or not self._new_episode(self._holding, vid, t_s):
            return
        self.lateral_holds += 1
        if self.holds_per_manoeuvre:
            self.holds_per_manoeuvre[-1] += 1
        self.ctx.event("lateral_hold", vehicle=vid, lane=lane, reason=refusal)

    # ------------------------------------------------------------------ outputs
    def close(self) -> None:
        """Close plans.jsonl (the run is over or the swarm was detached)."""
        if getattr(self, "planlog", None) is not None:  # never attached: nothing to close
            self.planlog.close()

    def summary(self) -> dict[str, Any]:
        interval = self.planner_settings.behaving_interval_s if self.ctx else 3.0
        interval = self.interval_s or interval
        steps = None
        if self.t_start_s is not None and self.t_done_s is not None:
            steps = math.ceil((self.t_done_s - self.t_start_s) / interval - 1e-9)
        blocked = min(self.blocked_min_accel.values()) if self.blocked_min_accel else None
        return {
            "overtake": {
                "regroup_lane": self.regroup_lane_used,
                "triggered": self.t_start_s is not None,
                "target": self.targets[0] if self.targets else None,
                "targets": list(self.targets),
                "t_start_s": self.t_start_s,
                "behaving_steps": steps,
                "behaving_interval_s": self.interval_s,
                "manoeuvres": len(self.targets),
                "aborted": sum(self.aborts.values()),
                "abort_reasons": dict(self.aborts),
                "lateral_holds": self.lateral_holds,
                "lateral_yields": self.lateral_yields,
                # waits ahead of a target that split the platoon at a give-up (wait_ahead_s)
                "waits_ahead": {
                    "started": self.waits_started,
                    "ended": dict(self.reformer.wait_ends) if self.ctx else {},
                },
                "lateral_holds_per_manoeuvre": list(self.holds_per_manoeuvre),
                "blocked_hv_min_accel_mps2": blocked,
                "blocked_hvs": sorted(self.blocked_min_accel),
            },
            "planner": {
                "solves": len(self.solve_ms),
                **summarise_ms(self.solve_ms, prefix="solve_ms_"),
                **summarise_ms(self.solve_cpu_ms, prefix="solve_cpu_ms_"),
                "statuses": dict(self.statuses),
                "fallbacks": self.fallbacks,
                "relaxations": dict(self.relaxations),
                "grid_retries": {"tried": 0, "planned": 0, **self.grid_retries},
                "triggers": dict(self.triggers),
            },
            "speeds": {
                **(self.ctx.speeds_block() if self.ctx else {}),
                "cap_mps": self.cap_mps if math.isfinite(self.cap_mps) else None,
                "cap_sources": dict(self.cap_sources),
            },
            "lat_error_rms_m": lateral_rms(self.lat_errors),
            "mpc": summarise_ms(
                self.tracker.solve_ms if self.ctx else [], prefix="solve_ms_per_cav_"
            ),
        }


def plan_is_idle(plan: Plan, step: int) -> bool:
    """Does ``plan`` keep every CAV in the cell it is planned in at ``step``, to the end?"""
    if not plan.ok:
        return False
    return all(keeps_cell(plan.cells_of(cav)[max(step, 0) :]) for cav in plan.cav_ids)


def _no_plan(t_s: float) -> Plan:
    """A cell-less plan that tells the trigger when the last solve failed."""
    from sumo_swarm.core.planner.problem import PlanStatus

    return Plan(status=PlanStatus.INFEASIBLE, cells=None, objective=None, solve_ms=0.0,
                backend="none", t0_s=t_s)  # fmt: skip
