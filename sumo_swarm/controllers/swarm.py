"""The swarm controller: the paper's method closed around SUMO, as a short coordinator.

Each SUMO step (after the step, acting on the next one):

1. *Cruise* as a CACC platoon (:mod:`~sumo_swarm.controllers.cruise`). The
   :mod:`~sumo_swarm.controllers.decider` names a target: the HV right ahead of the leader in
   its lane, slower than the cruise, worth passing, for ``swarm.trigger_after_s``; or a lane
   beside it that takes the platoon past faster than the cells would (a *lane pass*).
2. *Overtake*: the :mod:`~sumo_swarm.controllers.replanner` keeps a cell plan in force:
   :mod:`~sumo_swarm.core.swarming.manoeuvre` builds the moving grid, the HV margins and
   predictions from each HV's own driver model (:mod:`sumo_swarm.core.hvmodel`), solves the cell
   MIP and turns the cells into references; replans happen on the events of the paper's Fig. 4,
   at most one per behaving interval unless a safety check demands one. The
   :mod:`~sumo_swarm.controllers.follower` tracks the references with the MPCs, every command
   through the guards (:mod:`~sumo_swarm.core.swarming.guards`).
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

import logging
import math
from dataclasses import replace
from typing import Any

from sumo_swarm.controllers.base import RouteWatch, RunContext
from sumo_swarm.controllers.cacc import command_cacc
from sumo_swarm.controllers.cruise import Cruiser
from sumo_swarm.controllers.decider import Decider
from sumo_swarm.controllers.follower import PlanFollower
from sumo_swarm.controllers.lanes import LaneView
from sumo_swarm.controllers.reform import Reformer
from sumo_swarm.controllers.replanner import BlockWatch, PlanStats, Replanner
from sumo_swarm.core.hvmodel import DriverModel
from sumo_swarm.core.model import VehicleState
from sumo_swarm.core.neighbours import ordered_platoon
from sumo_swarm.core.planner import CellPlanner, Plan, make_planner
from sumo_swarm.core.stats import lateral_rms, summarise_ms
from sumo_swarm.core.swarming.account import (
    ManoeuvreBook,
    manoeuvres_from_events,
    overtake_counts,
    overtake_outcome,
)
from sumo_swarm.core.swarming.arbiter import ALONE
from sumo_swarm.core.swarming.decision import (
    LanePass,
    Mode,
    Progress,
    all_past,
    stopped_blocking,
)
from sumo_swarm.core.swarming.manoeuvre import ManoeuvrePlanner, ManoeuvreSettings
from sumo_swarm.core.swarming.planlog import PlanLog
from sumo_swarm.core.swarming.tracker import Tracker

__all__ = ["SwarmController"]

log = logging.getLogger(__name__)

# Give-ups after which the CAVs pass the target one by one ([swarm] pass_singly_s): plans that
# found no way past together. A planner that fails (no_feasible_plan) leaves the platoon behind
# the target, the safe fallback.
PASS_SINGLY_AFTER = frozenset({"cavs_stranded", "no_progress", "no_way_past"})
# Giving up a manoeuvre (Progress.give_up_reason): no progress for this many behaving
# intervals; only 3 once some CAVs are past and others stuck (those past wait at the target's
# speed in the passing lane, holding it back); this many fresh plans in a row that strand CAVs
# behind the target for the whole horizon (cavs_stranded) or keep every CAV behind it waiting
# for GIVE_UP_WAITING_S (no_way_past); without a usable plan for this long [s]. Two plans in a
# row, not one: a single plan may see the gap one interval late.
GIVE_UP_NO_PROGRESS_INTERVALS = 6
GIVE_UP_PARTIAL_INTERVALS = 3
GIVE_UP_STRANDED_PLANS = 2
GIVE_UP_WAITING_PLANS = 2
GIVE_UP_NO_PLAN_S = 10.0


class SwarmController:
    """The method of the paper: cruise, swarm past a slow vehicle, regroup, cruise."""

    name = "swarm"
    # Many swarms (controllers.fleet): a CAV alone is driven by SUMO (see the fleet module).
    alone_to_sumo = True

    def __init__(self, planner: CellPlanner | None = None, tracker: Tracker | None = None) -> None:
        """``planner`` and ``tracker`` replace the ones built from the scenario."""
        self._planlog_override = None
        self.ctx: RunContext | None = None
        self._planner_override = planner
        self._tracker_override = tracker
        self.mode = Mode.CRUISE
        self.target_id: str | None = None
        self.configured: set[str] = set()
        self.stats = PlanStats()
        self.blocks = BlockWatch()
        self.t_start_s: float | None = None
        self.targets: list[str] = []  # the target of each manoeuvre, in order
        self.book: ManoeuvreBook | None = None  # every manoeuvre, as events (made by attach)
        self.regroup_lane_used: int | None = None
        self.regroup_edge: str | None = None
        self.progress: Progress | None = None
        self._models: dict[str, tuple[str | None, DriverModel]] = {}
        self.lane_pass: LanePass | None = None  # a pass in a faster lane under way
        # Many swarms (controllers.fleet, ``may_part``): where the decision finds that nothing
        # the CAVs do together pays (it would follow, or each does better apart), the fleet
        # hands them back to SUMO (``nothing_pays``).
        self.may_part = False
        self.nothing_pays = False
        # The parts, made by attach (the run's context): see their modules.
        self.decider: Decider | None = None
        self.replanner: Replanner | None = None
        self.follower: PlanFollower | None = None
        self.cruiser: Cruiser | None = None
        self.reformer: Reformer | None = None
        self.routes = RouteWatch()  # CAVs whose routes part leave the platoon
        self.planlog: PlanLog | None = None  # plans.jsonl (made by attach)
        self.drawer = None  # a sumo-gui plan drawer, set by the session's side (sim.gui)

    # ------------------------------------------------------------------ set-up
    def attach(self, ctx: RunContext) -> None:
        self.ctx = ctx
        sc = ctx.scenario
        self.book = ManoeuvreBook(ctx.event, sc.cav.min_gap_m)
        self.planner_settings = sc.planner
        planner = self._planner_override or make_planner(self.planner_settings)
        # The HVs are predicted on SUMO's clock where it is coarser than the prediction's own:
        # SUMO moves them once a step (at 1 s, predicted in 0.25 s steps, they were off their
        # predictions by more than PREDICTION_ERROR_M six times as often as at 0.5 s, each a
        # replan).
        prediction_dt_s = max(sc.hvmodel.prediction_dt_s, ctx.dt_s)
        manoeuvre = ManoeuvrePlanner(
            planner,
            ManoeuvreSettings(
                planner=self.planner_settings, grid=sc.grid,
                b_safe_mps2=sc.hvmodel.b_safe_mps2, planner_share=sc.hvmodel.planner_share,
                margin_rule=sc.hvmodel.margin_rule, predictor=sc.hvmodel.predictor,
                prediction_dt_s=prediction_dt_s, target_b_mps2=sc.hvmodel.target_b_mps2,
                block_decel_share=sc.hvmodel.block_decel_share,
                entry_speed_gain_mps=sc.hvmodel.entry_speed_gain_mps,
                a_min_mps2=sc.cav.accel_min_mps2, a_max_mps2=sc.cav.accel_max_mps2,
                max_lateral_speed_mps=sc.cav.max_lateral_speed_mps,
            ),
        )  # fmt: skip
        steps = max(1, round(sc.swarm.control_interval_s / ctx.dt_s))
        self.tracker = self._tracker_override or Tracker(sc.longitudinal, sc.lateral, steps)
        self.planlog = self._planlog_override or PlanLog(ctx.out_dir)
        self.lanes = LaneView(ctx)
        self.reformer = Reformer(
            sc, self.model_of, ctx.event, speeds=ctx.speeds, hold=self.lanes.shift_hold,
            escape=self.lanes.end_escape, ends=self.lanes.ends_ahead,
        )  # fmt: skip
        self.decider = Decider(
            ctx, lanes=self.lanes, reformer=self.reformer, model_of=self.model_of,
            planner=self.planner_settings,
        )  # fmt: skip
        self.reformer.lane_wanted_right = self._lane_kept_free
        self.reformer.must_change = self.decider.must_change
        self.replanner = Replanner(
            ctx, manoeuvre, self.planner_settings, decider=self.decider, lanes=self.lanes,
            model_of=self.model_of, planlog=self.planlog, tracker_reset=self.tracker.reset,
            stats=self.stats, blocks=self.blocks,
        )  # fmt: skip
        self.follower = PlanFollower(ctx, self.tracker, self.lanes, self.model_of)
        self.cruiser = Cruiser(ctx, self.reformer, self.decider, self.lanes, self.tracker)
        self.drawer = None  # a sumo-gui plan drawer, set by the session's side (sim.gui)

    def use_planlog(self, planlog) -> None:
        """Write plans to ``planlog`` (a log shared by many swarms) instead of a file of its own;
        call before :meth:`attach`."""
        self._planlog_override = planlog

    # ------------------------------------------------------------------ many swarms
    def idle(self) -> bool:
        """Cruising with no manoeuvre of its own under way (no overtake, lane pass, passing one
        by one or wait ahead of a slow vehicle): its CAVs may change (controllers.fleet)."""
        reformer = self.reformer
        busy = reformer is not None and (reformer.singly is not None or reformer.waiting)
        return self.mode is Mode.CRUISE and self.lane_pass is None and not busy

    def forget(self, vid: str) -> None:
        """CAV ``vid`` left this swarm (controllers.fleet): set its modes again if it returns."""
        self.configured.discard(vid)
        self.routes.left.discard(vid)

    def planned_paths(self) -> dict[str, Any]:
        """Each CAV's planned front position ``s(t)`` [m] while a plan is in force (for the
        other swarms' predictions); empty otherwise."""
        if self.mode is not Mode.OVERTAKE or self.replanner is None:
            return {}
        states = self.ctx.session.states
        return {
            vid: _front_path(ref.s_at, 0.5 * states[vid].length_m)
            for vid, ref in (self.replanner.references or {}).items()
            if vid in states
        }

    def manoeuvre_region(self, t_s: float) -> tuple[float, float] | None:
        """The stretch of road [m] this swarm's manoeuvre takes now: its CAVs, its target and
        its grid; None while it cruises."""
        if self.idle() or self.ctx is None:
            return None
        states = self.ctx.session.states
        ids = [v for v in self.ctx.cav_ids if v in states]
        target = self.target_id if self.lane_pass is None else self.lane_pass.target_id
        if target in states:
            ids.append(target)
        if not ids:
            return None
        lo = min(states[v].rear_s_m for v in ids)
        hi = max(states[v].s_m for v in ids)
        grid = None if self.replanner is None else self.replanner.grid
        if grid is not None and self.mode is Mode.OVERTAKE:
            origin = grid.origin_at(t_s)
            lo, hi = min(lo, origin), max(hi, origin + grid.n_rows * grid.cell_length_m)
        return lo, hi

    def manoeuvres(self) -> list[dict[str, Any]]:
        """This swarm's manoeuvres (the summary's list, of its own events)."""
        if self.ctx is None:
            return []
        own = self.ctx.platoon_id
        return manoeuvres_from_events(e for e in self.ctx.events if e.get("platoon") == own)

    def swarms_counts(self) -> dict[str, int]:
        """This swarm's overtakes: started, completed, given up (of :meth:`manoeuvres`)."""
        return overtake_counts(self.manoeuvres())

    def dissolve(self, t_s: float) -> None:
        """The swarm has no CAV left (controllers.fleet): what it had under way ends."""
        if self.book is not None:
            self.book.end_all(t_s, "platoon_dissolved")

    @property
    def planner(self) -> CellPlanner:
        return self.replanner.manoeuvre.planner

    @property
    def plan(self) -> Plan | None:
        """The cell plan in force (None while cruising or after a failed solve)."""
        return None if self.replanner is None else self.replanner.plan

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
        edge = self.lanes.edge_of(vid)
        cached = self._models.get(vid)
        if cached is not None and cached[0] == edge:
            return cached[1]
        model = session.driver_model(vid)  # vanished: the cautious bound
        limits = session.speed_limits(vid)
        allowed = math.inf if limits is None else limits[1]
        if math.isfinite(allowed) and allowed > 0.0:
            model = replace(model, desired_speed_mps=min(model.desired_speed_mps, allowed))
        self._models[vid] = (edge, model)
        return model

    # ------------------------------------------------------------------ main step
    def control(self, t_s: float) -> None:
        try:
            self._control(t_s)
        except Exception:
            # A bug of ours: the manoeuvre ends in the books (abort reason controller_error),
            # then the error goes on to the run loop's StandDown: one warning, and from then
            # on only fallback() (a retry every step had logged a traceback each).
            if self.mode is Mode.OVERTAKE:
                try:
                    self._finish(t_s, completed=False, reason="controller_error")
                except Exception as exc:  # the bookkeeping failed too
                    log.debug("ending the manoeuvre failed at t = %.2f s: %s", t_s, exc)
                    self.mode = Mode.CRUISE
            raise

    def fallback(self, t_s: float) -> None:
        """The step after the swarm stood down (:class:`~sumo_swarm.controllers.base.StandDown`),
        with the least of our code: every CAV follows what drives ahead of it in its lane
        (CACC), no lateral move."""
        states = self.ctx.session.states
        command_cacc(self.ctx, ordered_platoon(states, self.ctx.cav_ids))

    def _control(self, t_s: float) -> None:
        ctx = self.ctx
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
        # One lane numbering, the leader's edge's: behind a lane drop the CAVs not past it
        # yet count their lane one higher, and the reformer sent them to the wrong lane.
        states = ctx.session.states_in_lanes_of(platoon[0])
        self.blocks.watch(t_s, states, self.replanner.interval())
        self.book.watch(t_s, states, platoon)
        if self.drawer is not None and self.mode is Mode.OVERTAKE:
            self.drawer.update(t_s)
        if self.mode is Mode.CRUISE:
            self._cruise_decision(t_s, states, platoon)
        if self.mode is Mode.OVERTAKE:
            self._overtake_step(t_s, states, platoon)
        if self.mode is Mode.OVERTAKE and self.plan is not None:
            self.follower.drive(t_s, states, platoon, self.replanner.references,
                                self.decider.cap_mps)  # fmt: skip
        else:
            self.cruiser.step(t_s, states, platoon)
            self._wait_over(t_s)

    def _cruise_decision(self, t_s: float, states, platoon: list[str]) -> None:
        """Follow a lane pass under way; else decide on a target: a lane pass or the cells."""
        target = self._lane_pass_target(t_s, states, platoon)
        if self.lane_pass is None and self._weighs():
            if target is None:  # (else its lane pass stalled: weighed again at once)
                if self.book.open:
                    return  # a manoeuvre the cruise drives is under way: it is seen through
                target = self.decider.decide(t_s, states, platoon)
            if target is None or not self._may_start(t_s, target, platoon):
                return
            best = self.decider.choose(target, states, platoon, apart=self.may_part)
            if best.kind in ALONE and self.may_part:
                self.nothing_pays = True
                return
            if best.kind == "lane_pass":
                self._start_lane_pass(t_s, target, best.lane, platoon)
            elif best.kind == "cells":
                self._start_overtake(t_s, target, platoon)
            elif best.kind == "one_by_one":
                self._start_one_by_one(t_s, target, platoon)
            else:  # follow, or wait for it to leave: asked again after trigger_after_s
                self.decider.watch.since_s = t_s
            return
        if target is None and self.lane_pass is None:
            target = self.decider.decide(t_s, states, platoon)
            lane = None if target is None else self.decider.lane_beats_plan(target, states, platoon)
            if lane is not None:
                if self._may_start(t_s, target, platoon):
                    self._start_lane_pass(t_s, target, lane, platoon)
                target = None
        if target is not None and self._may_start(t_s, target, platoon):
            self._start_overtake(t_s, target, platoon)

    def _may_start(self, t_s: float, target: VehicleState, platoon: list[str]) -> bool:
        """Whether no other swarm's manoeuvre takes the road from this platoon's last CAV to
        ``target`` (``ctx.may_start``, set by controllers.fleet; always, for one swarm)."""
        states = self.ctx.session.states
        rear = min(states[v].rear_s_m for v in platoon)
        return self.ctx.may_start(t_s, rear, target.s_m, target.vehicle_id)

    def _overtake_step(self, t_s: float, states, platoon: list[str]) -> None:
        """End the manoeuvre (done, the target no longer blocking, given up), or plan again."""
        sc = self.ctx.scenario
        target = states.get(self.target_id)
        cavs = {v: states[v] for v in platoon}
        stop = stopped_blocking(
            target, self.decider.target_changed_lane(target),
            slow_below_mps=self.decider.slow_below(),
        )  # fmt: skip
        if stop is not None and target is not None and all_past(target, cavs, sc.cav.min_gap_m):
            self._finish(t_s, completed=True)  # all past: the cruise re-forms the platoon
        elif stop == "target_changed_lane" and self._weighs():
            # It moved out of the way, still slower: the cruise drives the CAVs past it, the
            # manoeuvre goes on until every CAV is past (or the horizon runs out).
            self._finish(t_s, completed=False, reason=stop, handover=True)
        elif stop is not None:
            self._finish(t_s, completed=False, reason=stop)
        elif self.decider.passing_in_lane(target, cavs, states, self.replanner.grid,
                                          self.replanner.interval_s):  # fmt: skip
            # One platoon in a faster lane: the cruise takes it past at that lane's pace. The
            # manoeuvre goes on until every CAV is past (the book watches it).
            done = all_past(target, cavs, sc.cav.min_gap_m)
            self._finish(t_s, completed=done, reason="passing_lane", handover=not done)
        elif self._overtake_done(target, cavs):
            self._finish(t_s, completed=True)
        else:
            self.progress.update(t_s, target, list(cavs.values()), sc.cav.min_gap_m)
            interval = self.replanner.interval()
            give_up = self.progress.give_up_reason(
                t_s,
                GIVE_UP_NO_PROGRESS_INTERVALS * interval,
                GIVE_UP_NO_PLAN_S,
                self.plan is not None,
                partial_s=GIVE_UP_PARTIAL_INTERVALS * interval,
                n_cavs=len(cavs),
                stranding_plans=GIVE_UP_STRANDED_PLANS,
                waiting_plans=GIVE_UP_WAITING_PLANS,
            )
            if give_up is None:
                self.replanner.maybe_replan(t_s, states, platoon, self.target_id, self.progress)
                return
            self._finish(t_s, completed=False, reason=give_up)
            self.decider.watch.cool_down(t_s + sc.swarm.cooldown_s)
            waits = self.cruiser.waits_started
            self.cruiser.wait_if_split(t_s, target, cavs)
            if self.cruiser.waits_started > waits:
                # The CAVs past it wait ahead for the others: the wait ends it (_wait_over).
                self.book.start(t_s, "wait", self.target_id, platoon)
            singly = sc.swarm.pass_singly_s > 0.0 and give_up in PASS_SINGLY_AFTER
            if singly and self.may_part and self.book.current("wait") is None:
                # No way past together, where SUMO drives a CAV alone: the platoon parts, each
                # CAV passes as SUMO's driver (held one by one, two CAVs stayed behind a car
                # for 56 s and the others' delay doubled: corridor checks, 5 lanes, seed 3).
                # (Some CAVs past it wait for the others: that goes on, and ends regrouped.)
                self.nothing_pays = True
            elif singly:
                # No way past together: the CAVs pass it one by one, as SUMO's drivers do,
                # through the guards, and re-form the platoon ahead.
                until_s = t_s + sc.swarm.pass_singly_s
                self.reformer.singly = (self.target_id, until_s)
                if self.book.current("wait") is None:
                    self.book.start(t_s, "one_by_one", self.target_id, platoon, watched=True,
                                    until_s=until_s)  # fmt: skip

    def _lane_kept_free(
        self, vehicle: VehicleState, states: dict[str, VehicleState], t_s: float
    ) -> int | None:
        """The lane on the right of ``vehicle`` that a CAV passing on its own keeps out of: for
        the last manoeuvre's target, the lane the plan keeps closed while that target may still
        move there (:meth:`Decider.keep_right_closure`); for any other vehicle, the lane it is
        about to move into (:meth:`Decider.lane_wanted_right`). A give-up 3 s into a
        manoeuvre had the leader pass alone in the lane the plan had kept free for the truck.
        """
        if self.progress is not None and vehicle.vehicle_id == self.target_id:
            return self.decider.keep_right_closure(t_s, self.progress.started_s, vehicle, states)
        return self.decider.lane_wanted_right(vehicle, states, t_s)

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

    def _wait_over(self, t_s: float) -> None:
        """A wait the reformer ended (:meth:`Reformer.split_by`) ends its manoeuvre: completed
        once every CAV is past and in one lane (``rejoined``)."""
        wait = self.book.current("wait")
        if wait is None or self.reformer.waiting is not None:
            return
        how = self.reformer.last_wait_end or "reset"
        self.book.end(t_s, wait, completed=how == "rejoined", reason=how,
                      states=self.ctx.session.states)  # fmt: skip

    def _start_overtake(self, t_s: float, target: VehicleState, platoon: list[str]) -> None:
        self.mode = Mode.OVERTAKE
        self._count_manoeuvre(t_s, target.vehicle_id)
        self.replanner.start()
        self.progress = Progress(t_s)
        self.follower.new_manoeuvre()
        lane = self.planner_settings.regroup_lane
        # The target's lane, within the road: it may be beside it (an acceleration lane, as the
        # swarm's states count lanes: SumoSession.states_in_lanes_of).
        self.regroup_lane_used = self.ctx.road.nearest_lane(target.lane) if lane is None else lane
        self.regroup_edge = self.reformer.edge  # whose lane numbering that lane is in
        self.reformer.prefer = None
        self.decider.new_target()
        self.book.start(t_s, "cells", target.vehicle_id, platoon,
                        speed_cap_mps=self.decider.cap_mps)  # fmt: skip

    def _finish(
        self, t_s: float, completed: bool, reason: str = "completed", handover: bool = False
    ) -> None:
        """The cell plan ends: ``completed`` (every CAV past), given up or stopped
        (``reason``), or ``handover`` to the cruise passing in one faster lane, its manoeuvre
        going on until every CAV is past (watched by the book)."""
        self.mode = Mode.CRUISE
        self.reformer.reset()  # the platoon's lane chosen afresh from where the CAVs are now
        if self.drawer is not None:
            self.drawer.clear()
        self.replanner.clear()
        self.decider.watch.candidate_id = self.decider.watch.since_s = None
        if completed and reason == "completed" and self.regroup_lane_used is not None:
            self.reformer.prefer = (self.regroup_lane_used, self.regroup_edge)
        cells = self.book.current("cells")
        if handover and cells is not None:
            self._hand_over(t_s, cells, reason)
            return
        self.book.end(t_s, cells, completed=completed, reason=reason,
                      states=self.ctx.session.states)  # fmt: skip

    def _weighs(self) -> bool:
        """Does the swarm weigh its manoeuvres (``[swarm] decide = "weigh"``)?"""
        return self.ctx.scenario.swarm.decide == "weigh"

    def _hand_over(self, t_s: float, m, reason: str) -> None:
        """Manoeuvre ``m`` goes on driven by the cruise: the book ends it once every CAV is past
        its target (completed), the target is gone, or, with decide = "weigh", once
        ``horizon_s`` has run out (timeout): a target that moved out of the way and sped up is
        not passed."""
        m.watched = True
        if self._weighs():
            m.until_s = t_s + self.ctx.scenario.swarm.horizon_s
        self.ctx.event("overtake_handover", target=m.target_id, kind=m.kind,
                       manoeuvre=m.number, reason=reason)  # fmt: skip

    def _overtake_done(self, target: VehicleState, cavs: dict[str, VehicleState]) -> bool:
        """Every CAV past the target: the cruise mode re-forms the platoon. (The paper's step 4,
        the plan regrouping them in a grid at the target's speed, slowed CAVs already past a
        truck to its speed and below; on the stress sweep v2 it completed fewer scenes.)"""
        return all_past(target, cavs, self.ctx.scenario.cav.min_gap_m)

    def _start_one_by_one(self, t_s: float, target: VehicleState, platoon: list[str]) -> None:
        """The CAVs pass ``target`` one by one, each through the guards when its gap comes, and
        re-form the platoon ahead (the reformer's passing alone); the book sees it through."""
        self._count_manoeuvre(t_s, target.vehicle_id)
        self.decider.new_target()
        until_s = t_s + self.ctx.scenario.swarm.pass_singly_s
        self.reformer.singly = (target.vehicle_id, until_s)
        self.book.start(t_s, "one_by_one", target.vehicle_id, platoon, watched=True,
                        until_s=until_s)  # fmt: skip

    # ------------------------------------------------------------------ passing in a lane
    def _start_lane_pass(
        self, t_s: float, target: VehicleState, lane: int, platoon: list[str]
    ) -> None:
        """The platoon moves over to ``lane`` as a unit, each CAV through the lateral guard,
        entering speeding up, and passes ``target`` there (the cruise's re-forming)."""
        self._count_manoeuvre(t_s, target.vehicle_id)
        self.lane_pass = LanePass(target.vehicle_id, lane, t_s)
        self.decider.new_target()
        self.reformer.move_to = (lane, self.lanes.edge_of(platoon[0]))
        self.book.start(t_s, "lane_pass", target.vehicle_id, platoon,
                        speed_cap_mps=self.decider.cap_mps, how="lane", lane=lane)  # fmt: skip

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
        stop = stopped_blocking(target, self.decider.target_changed_lane(target),
                                slow_below_mps=self.decider.slow_below())  # fmt: skip
        if (
            stop == "target_changed_lane" and self._weighs()
            and self.ctx.road.lane_of(target) != self.lane_pass.lane
        ):  # fmt: skip
            # Out of the way, not into the lane passed in: the cruise drives past it.
            self.lane_pass = None
            self.reformer.move_to = None
            self._hand_over(t_s, self.book.current("lane_pass"), stop)
            return None
        if stop is not None:  # it moved over (perhaps into the lane the platoon moves to)
            self._end_lane_pass(t_s, completed=False, reason=stop)
            return None
        if how == "stalled":
            self.decider.lane_pass_stalled_on = self.lane_pass.target_id
            self._end_lane_pass(t_s, completed=False, reason="lane_pass_stalled")
            return target
        return None

    def _end_lane_pass(self, t_s: float, *, completed: bool, reason: str) -> None:
        self.lane_pass = None
        self.reformer.move_to = None
        self.book.end(t_s, self.book.current("lane_pass"), completed=completed, reason=reason,
                      states=self.ctx.session.states, how="lane")  # fmt: skip

    # ------------------------------------------------------------------ outputs
    def _swarms_block(self) -> dict[str, int]:
        """summary.json's ``swarms`` counts: one swarm, every CAV of the run."""
        formed = int(self.ctx is not None and bool(self.ctx.cav_ids))
        return {"platoons_formed": formed, "max_concurrent": formed, **self.swarms_counts()}

    def close(self) -> None:
        """Close plans.jsonl (the run is over or the swarm was detached)."""
        if self.planlog is not None:  # never attached: nothing to close
            self.planlog.close()

    def tracking_samples(self) -> tuple[list[float], list[float]]:
        """(lateral tracking errors [m], MPC solve times [ms]) of its CAVs so far."""
        if self.ctx is None:
            return [], []
        return self.follower.lat_errors, self.tracker.solve_ms

    def summary(self) -> dict[str, Any]:
        if self.ctx is None:  # never attached: the manoeuvre counters only, no parts yet
            interval, unit, speeds = None, 3.0, {"cap_mps": None, "cap_sources": {}}
            follower = PlanFollower(None, None, None, None)  # nothing counted
            waits, mpc_ms = {"started": 0, "ended": {}}, []
        else:
            interval = self.replanner.interval_s
            unit = interval or self.planner_settings.behaving_interval_s
            cap = self.decider.cap_mps
            speeds = {
                **self.ctx.speeds_block(),
                "cap_mps": cap if math.isfinite(cap) else None,
                "cap_sources": dict(self.decider.cap_sources),
            }
            follower = self.follower
            waits = {"started": self.cruiser.waits_started, "ended": dict(self.reformer.wait_ends)}
            mpc_ms = self.tracker.solve_ms
        manoeuvres = self.manoeuvres()
        return {
            "manoeuvres": manoeuvres,  # the one account; the outcome fields below are of it
            "overtake": {
                **overtake_outcome(manoeuvres, unit),
                "regroup_lane": self.regroup_lane_used,
                "targets": [m["target"] for m in manoeuvres],
                "behaving_interval_s": interval,
                "manoeuvres": len(manoeuvres),
                "lateral_holds": follower.holds,
                "lateral_yields": follower.yields,
                # waits ahead of a target that split the platoon at a give-up (WAIT_AHEAD_S)
                "waits_ahead": waits,
                "lateral_holds_per_manoeuvre": list(follower.holds_per_manoeuvre),
                "blocked_hv_min_accel_mps2": self.blocks.strongest(),
                "blocked_hvs": sorted(self.blocks.min_accel),
            },
            "swarms": self._swarms_block(),
            "planner": self.stats.block(),
            "speeds": speeds,
            "lat_error_rms_m": lateral_rms(follower.lat_errors),
            "mpc": summarise_ms(mpc_ms, prefix="solve_ms_per_cav_"),
        }


def _front_path(centre_at, half_length_m: float):
    """The front position ``s(t)`` [m] of a CAV whose centre follows ``centre_at``."""
    return lambda t_s: centre_at(t_s) + half_length_m
