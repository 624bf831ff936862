"""The swarm's decisions while it cruises: which vehicle to overtake, how, and the speed cap.

:class:`Decider` asks the pure tests of :mod:`sumo_swarm.core.swarming.decision` with what the
run's session can tell (driver models, keep-right, speed limits, lanes that end) and says each
decision once as an event. It holds only what must last from one step to the next: the target
being watched (:class:`TargetWatch`), the target's lane at the decision, the speed cap and its
sources, and the vehicles already reported as not worth passing or keeping right.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

from sumo_swarm.config import PlannerSettings
from sumo_swarm.controllers.lanes import LaneView
from sumo_swarm.controllers.reform import Reformer
from sumo_swarm.core.grid import MovingGrid
from sumo_swarm.core.hvmodel import DriverModel
from sumo_swarm.core.model import VehicleState
from sumo_swarm.core.neighbours import Snapshot, snapshot_of
from sumo_swarm.core.swarming.arbiter import Outlook, PlatoonView, choose
from sumo_swarm.core.swarming.decision import (
    TargetWatch,
    behaving_interval_s,
    held_by,
    lane_for_pass,
    lane_pass_pace,
    lane_speeds,
    only_catching_up,
    passing_lane,
    right_lane_free,
    right_lane_opens_within,
    secure_gap_m,
    speed_cap_mps,
)

States = Mapping[str, VehicleState]


# A blocked lane-change wish of a slow vehicle is waited for this long [s] (then it is passed):
# about twice SUMO's keep-right build-up, time for a gap to come by.
WISH_BLOCKED_S = 10.0

# How long [s] an answer of Decider.moves_right_soon holds: the sampling step of its
# prediction (decision.right_lane_opens_within).
RECHECK_S = 0.5


class Decider:
    """Targets, lane passes and the speed cap for one swarm (see the module docstring).

    ``ctx`` is the run's context (``scenario``, ``session``, ``road``, ``event``);
    ``reformer`` gives the platoon's lane and the desired speeds of the vehicles around;
    ``model_of`` an HV's driver model.
    """

    def __init__(
        self,
        ctx: Any,
        *,
        lanes: LaneView,
        reformer: Reformer | None,
        model_of: Callable[[str], DriverModel],
        planner: PlannerSettings,
    ) -> None:
        self.ctx = ctx
        self.lanes = lanes
        self.reformer = reformer
        self.model_of = model_of
        self.planner = planner
        self.watch = TargetWatch(ctx.scenario.swarm.trigger_after_s)
        self.cap_mps = math.inf
        self.cap_sources: dict[str, float] = {}
        # A target whose lane pass stalled: no lane pass on it again.
        self.lane_pass_stalled_on: str | None = None
        self._no_gain_target: str | None = None
        self._keep_right_target: str | None = None
        self._moves_right: dict[str, tuple[float, bool]] = {}  # vehicle -> (time, answer)
        self._target_lane: tuple[str | None, int] | None = None
        self._weighed: tuple[str, str, int | None] | None = None  # the last choice said
        self._wish_since: dict[str, float] = {}  # vehicle -> when its lane-change wish began

    # ------------------------------------------------------------------ speeds
    def slow_below(self) -> float:
        """Below this speed [m/s] a vehicle ahead is slow (``trigger_speed_ratio`` of the
        cruise)."""
        return self.ctx.cav.cruising_speed_mps * self.ctx.scenario.swarm.trigger_speed_ratio

    def speed_cap(self, platoon: list[str]) -> float:
        """The lowest of cav.max_speed_mps, the CAVs' vType maxSpeed and allowed lane speed
        (``platoon``: the CAVs to ask; the leader alone while cruising)."""
        sources = {"cav.max_speed_mps": self.ctx.cav.max_speed_mps}
        for vid in platoon:
            limits = self.ctx.session.speed_limits(vid)
            if limits is None:  # vanished this step, or SUMO cannot tell
                continue
            vtype_max, allowed = limits
            sources["vType maxSpeed"] = min(sources.get("vType maxSpeed", math.inf), vtype_max)
            sources["lane limit"] = min(sources.get("lane limit", math.inf), allowed)
        self.cap_sources = sources
        self.cap_mps = speed_cap_mps(list(sources.values()))
        return self.cap_mps

    def secure_gap(self, follower: VehicleState, v_lead_mps: float) -> float:
        """SUMO's secure gap [m] of ``follower`` (an HV by its own model; a CAV by the swarm's
        braking) behind a vehicle at ``v_lead_mps``."""
        if follower.is_cav:
            cav = self.ctx.scenario.cav
            return secure_gap_m(0.0, -cav.accel_min_mps2, follower.speed_mps, v_lead_mps)
        model = self.model_of(follower.vehicle_id)
        return secure_gap_m(model.tau_s, model.decel_mps2, follower.speed_mps, v_lead_mps)

    # ------------------------------------------------------------------ the target
    def decide(self, t_s: float, states: States, platoon: list[str]) -> VehicleState | None:
        """The vehicle to overtake, once it has been one for ``trigger_after_s``; else None."""
        ctx = self.ctx
        sw = ctx.scenario.swarm
        if ctx.road.n_lanes < 2 or t_s < sw.start_after_s:
            return None
        leader = states[self.leader(states, platoon)]
        # Sorted once for both look-ups (the vehicle ahead of the leader, then the line ahead of
        # a candidate): every cruise step asks, a plain list scanned every vehicle each time.
        vehicles = snapshot_of(states, ctx.road)
        candidate = held_by(
            leader, vehicles, ctx.road, sw, cruise_mps=ctx.cav.cruising_speed_mps,
            cap_mps=self.speed_cap(platoon[:1]), width_m=ctx.scenario.cav.width_m,
        )  # fmt: skip
        # Never another swarm's CAV (many swarms: each sees the others' CAVs as vehicles): a
        # platoon behind one merges with it, or waits for it to overtake.
        if candidate is not None and ctx.session.kinds.get(candidate.vehicle_id) == "cav":
            candidate = None
        # Not in a lane that ends within reach plus two 3 s intervals at the cruise (an
        # acceleration lane, a lane drop): everyone leaves that lane anyway.
        reach = sw.detect_range_m + 2.0 * 3.0 * ctx.cav.cruising_speed_mps
        if candidate is not None and leader.lane in self.lanes.ending(leader, platoon[0], reach):
            candidate = None
        if sw.decide == "weigh":  # catching up, side lanes, keeping right: weighed (choose)
            return self.watch.update(t_s, candidate)
        if candidate is not None and self._catching_up(candidate, vehicles):
            candidate = None
        if candidate is not None and not self._side_lane_pays(leader, candidate, states):
            candidate = None
        wait_s = 0.0
        if candidate is not None and self.may_keep_right(candidate, states):
            wait_s = sw.keep_right_wait_s
        return self.watch.update(t_s, candidate, wait_s)

    def choose(
        self, target: VehicleState, states: States, platoon: list[str], *, apart: bool = False
    ) -> Outlook:
        """What to do about ``target`` (``[swarm] decide = "weigh"``): the best of following,
        waiting for it to leave the lane, a lane pass beside and the cells, for everyone on the
        road (:func:`~sumo_swarm.core.swarming.arbiter.choose`). An event
        ``overtake_weighed`` gives each candidate's prediction when the choice changes."""
        ctx = self.ctx
        sc, road = ctx.scenario, ctx.road
        sw = sc.swarm
        leader = states[self.leader(states, platoon)]
        tail = min((states[v] for v in platoon), key=lambda st: st.rear_s_m)
        wish, blocked = ctx.session.lane_wish(target.vehicle_id)
        # A driver that keeps right, the lane on its right free for it by the time its wish
        # builds up (SUMO's keep-right model, read through libsumo), moves there.
        keeps_right = (
            road.lane_of(target) > 0
            and self.ctx.session.keeps_right(target.vehicle_id)
            and self._right_lane_free(target, states)
        )
        if keeps_right and not wish:
            wish, blocked = -1, False
        # Its route leaves the road within the horizon (an exit ahead): it goes, as a wish.
        target_left_m = self._road_left_m(target)
        exits = target_left_m is not None and target_left_m <= sw.horizon_s * max(
            target.speed_mps, 1.0
        )
        lane = road.lane_of(leader)
        side = [q for q in (lane - 1, lane + 1) if 0 <= q < road.n_lanes]
        ending = self.lanes.ends_ahead(leader)  # a pass there would end at the lane's end
        # Not the lane the target is about to move into: it would take the lane passed in.
        wished = road.lane_of(target) + wish if wish else None
        side = [q for q in side if q not in ending and q != wished]
        interval = behaving_interval_s(
            self.planner.behaving_interval_s, sc.cell_length_m, target.speed_mps,
            self.cap_mps, sw.interval_rule,
        )  # fmt: skip
        cells_mps = sc.cell_length_m / interval if math.isfinite(interval) else None
        view = PlatoonView(
            front=leader, tail=tail, n_cavs=len(platoon),
            cavs=tuple(sorted((states[v] for v in platoon), key=lambda st: -st.s_m)),
            cruise_mps=min(ctx.cav.cruising_speed_mps, self.cap_mps),
            lateral_speed_mps=sc.cav.max_lateral_speed_mps,
            lane_width_m=road.lane_width_m(lane),
        )  # fmt: skip
        members = set(platoon)
        # Predicted until the platoon's own road ends (or it leaves it), if that is sooner:
        # on a short stretch of road left no manoeuvre is seen through.
        left_m = self._road_left_m(leader)
        horizon_s = sw.horizon_s
        if left_m is not None:
            horizon_s = max(0.0, min(horizon_s, left_m / max(leader.speed_mps, 1.0)))
        choice = choose(
            view, target, [st for v, st in states.items() if v not in members], road,
            side_lanes=side, leaves=self._wish_holds(target.vehicle_id, wish, blocked) or exits,
            cells_pace_mps=cells_mps,
            desired_of=self.reformer.desired_speed, horizon_s=horizon_s,
            range_m=sw.detect_range_m + 2.0 * sc.cell_length_m,
            others_weight=sw.others_weight, min_gain_mps=sw.min_speed_gain_mps, apart=apart,
            pass_lanes=[] if target.vehicle_id == self.lane_pass_stalled_on else None,
        )  # fmt: skip
        said = (target.vehicle_id, choice.best.kind, choice.best.lane)
        if said != self._weighed:
            self._weighed = said
            ctx.event("overtake_weighed", target=target.vehicle_id, chosen=choice.best.kind,
                      lane=choice.best.lane, target_speed_mps=round(target.speed_mps, 2),
                      scores_m={o.kind + ("" if o.lane is None else f"@{o.lane}"):
                                [round(o.gain_m, 1), round(o.loss_m, 1)]
                                for o in choice.weighed})  # fmt: skip
        return choice.best

    def _wish_holds(self, vid: str, wish: int, blocked: bool) -> bool:
        """Is a lane-change wish of ``vid`` (``wish``: +1, -1; 0 none) one it will act on: free
        to move, or blocked for less than WISH_BLOCKED_S since the wish was first seen (a truck
        that wants to keep right moves once the gap on its right comes; one blocked for long
        by a dense right lane is passed)."""
        if not wish:
            self._wish_since.pop(vid, None)
            return False
        since = self._wish_since.setdefault(vid, self.ctx.session.time_s)
        return not blocked or self.ctx.session.time_s - since <= WISH_BLOCKED_S

    def _road_left_m(self, vehicle: VehicleState) -> float | None:
        """How far [m] ``vehicle`` still drives on the road (the session's route frame): to
        where its route leaves it, or else to its route's end (it arrives); None where SUMO
        cannot tell."""
        session = self.ctx.session
        frame = session.frame
        route = session.route_of(vehicle.vehicle_id)
        if frame is None or route is None:
            return None
        edges, index = route
        parting = session.distance_to_parting_m(
            vehicle.vehicle_id, edges, index, frozenset(frame.route_edges)
        )
        if parting is None:
            position = session.lane_positions.get(vehicle.vehicle_id, 0.0)
            parting = sum(frame.net.lane_length_m(f"{e}_0") for e in edges[index:]) - position
        return max(parting, 0.0)

    def leader(self, states: States, platoon: list[str]) -> str:
        """The CAV whose leader decides: the front CAV in the lane the platoon re-forms in.
        A CAV ahead of it in another lane is merging back (or passing on its own): a slow
        vehicle in front of it is not the platoon's. (After a target moved into the lane of
        the front CAV, the swarm took that CAV as its leader and overtook the same truck again,
        in a lane full of traffic, while the plain platoon drove on.)"""
        lane = self.reformer.lane_id
        if lane is not None and self.reformer.edge == self.lanes.edge_of(platoon[0]):
            road = self.ctx.road
            for vid in platoon:
                if road.lane_of(states[vid]) == lane:
                    return vid
        return platoon[0]

    def _catching_up(self, candidate: VehicleState, vehicles: Snapshot) -> bool:
        """Is ``candidate`` only catching up (:func:`only_catching_up`)? An event
        ``overtake_not_worth`` (reason ``catching_up``) says so once per vehicle."""
        ctx = self.ctx
        desired = self.reformer.desired_speed
        if not only_catching_up(
            candidate, vehicles, ctx.road, desired_of=desired,
            slow_below_mps=self.slow_below(), width_m=ctx.scenario.cav.width_m,
            ahead_m=ctx.scenario.swarm.catching_up_ahead_m,
        ):  # fmt: skip
            return False
        if self._no_gain_target != candidate.vehicle_id:
            self._no_gain_target = candidate.vehicle_id
            ctx.event("overtake_not_worth", target=candidate.vehicle_id,
                      target_speed_mps=candidate.speed_mps, reason="catching_up",
                      desired_speed_mps=desired(candidate))  # fmt: skip
        return True

    def _side_lane_pays(self, leader: VehicleState, target: VehicleState, states: States) -> bool:
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

    def new_target(self) -> None:
        """A manoeuvre starts: the target's lane is read afresh (:meth:`target_changed_lane`)."""
        self._target_lane = None

    def target_changed_lane(self, target: VehicleState | None) -> bool:
        """Has the target changed lanes on its own since the decision? Lane indices change
        where a lane ends or one is added on the right (netconvert numbers from the right), so
        only a new lane on the same edge, with the target settled in it, counts: its lane on
        its own edge (:meth:`LaneView.own`). The swarm's states number lanes as on its lead
        CAV's edge, which changes when the lead CAV passes such a place: read there, a target
        driving on past an on-ramp "changed lanes" as the CAVs behind it reached the
        acceleration lane (all seven manoeuvres that ended so in 40 corridor runs)."""
        if target is None:
            return False
        edge = self.lanes.edge_of(target.vehicle_id)
        own = self.lanes.own(target)
        if self._target_lane is None or self._target_lane[0] != edge:
            self._target_lane = (edge, own.lane)
            return False
        return own.lane != self._target_lane[1] and abs(own.lat_m) < 0.5

    # ------------------------------------------------------------------ keeping right
    def may_keep_right(self, target: VehicleState, states: States) -> bool:
        """Will ``target`` soon move to the lane on its right of its own accord (a driver that
        keeps right, with that lane free now, or once before for a target in the leftmost
        lane)? An event says so once per target."""
        sc = self.ctx.scenario
        if sc.swarm.keep_right_wait_s <= 0.0:
            return False
        leftmost = self.ctx.road.lane_of(target) == self.ctx.road.n_lanes - 1
        if sc.swarm.keep_right_middle != "wait" and not leftmost:
            return False  # passed at once (on its left only, with "left")
        if not self.ctx.session.keeps_right(target.vehicle_id):
            return False
        free = self._right_lane_free(target, states)
        if free and self._keep_right_target != target.vehicle_id:
            self._keep_right_target = target.vehicle_id
            self.ctx.event("target_may_keep_right", target=target.vehicle_id,
                           wait_s=sc.swarm.keep_right_wait_s)  # fmt: skip
        # Once seen free, the wait holds while that lane is taken for a moment, for a target in
        # the leftmost lane: every pass of it would take the lane it is to move into.
        return free or (leftmost and self._keep_right_target == target.vehicle_id)

    def keep_right_closure(
        self, t_s: float, started_s: float, target: VehicleState, states: States
    ) -> int | None:
        """The lane on the right of a target that keeps right with a lane on its left, closed
        to the cell plan beside and behind it (``[swarm] keep_right_middle = "left"``) while
        the target is about to move there (:meth:`lane_wanted_right`), or, for the first
        ``keep_right_wait_s`` of the manoeuvre that started at ``started_s``, while that lane
        is free for it to move into (:func:`right_lane_free`, as for the wait); None: nothing
        closed. (Closed whether free or not, it cost paper-scene variants whose truck could
        not move over up to 4 m/s: the CAVs could not use that lane while it was open.)"""
        sw, road = self.ctx.scenario.swarm, self.ctx.road
        if sw.keep_right_middle != "left" or sw.keep_right_wait_s <= 0.0:
            return None
        wanted = self.lane_wanted_right(target, states, t_s)
        if wanted is not None:
            return wanted
        lane = road.lane_of(target)
        if not 0 < lane < road.n_lanes - 1:
            return None  # no lane on its right, or the leftmost lane (waited for instead)
        if t_s - started_s > sw.keep_right_wait_s:
            return None
        keeps_right = self.ctx.session.keeps_right(target.vehicle_id)
        if not keeps_right or not self._right_lane_free(target, states):
            return None
        return lane - 1

    def lane_wanted_right(self, vehicle: VehicleState, states: States, t_s: float) -> int | None:
        """The lane on the right of ``vehicle``, with a lane on its left too, that it is about
        to move into (:meth:`moves_right_soon`); None otherwise. Neither the plan
        (:meth:`keep_right_closure`) nor a CAV passing on its own uses it."""
        road = self.ctx.road
        lane = road.lane_of(vehicle)
        if 0 < lane < road.n_lanes - 1 and self.moves_right_soon(vehicle, states, t_s):
            return lane - 1
        return None

    def must_change(self, vid: str, direction: int) -> bool:
        """Does vehicle ``vid`` need to move one lane ``direction`` (+1 left) for its route
        (SUMO's strategic wish, read through libsumo)? False when TraCI cannot tell."""
        return bool(self.ctx.session.must_change(vid, direction))

    def moves_right_soon(self, target: VehicleState, states: States, t_s: float) -> bool:
        """Does ``target`` keep right, want to move right now (:meth:`wants_right`), and will
        the lane there open for it soon (:meth:`_right_lane_opens`)? Worked out afresh at most
        every ``RECHECK_S`` per vehicle: every step of a manoeuvre asks, and working it out
        each time took a tenth of the controller's time in a stream scene."""
        seen = self._moves_right.get(target.vehicle_id)
        if seen is not None and 0.0 <= t_s - seen[0] < RECHECK_S:
            return seen[1]
        answer = (
            self.ctx.session.keeps_right(target.vehicle_id)
            and self.wants_right(target)
            and self._right_lane_opens(target, states)
        )
        self._moves_right[target.vehicle_id] = (t_s, answer)
        return answer

    def wants_right(self, target: VehicleState) -> bool:
        """Does ``target``'s driver want to move right to keep right now, the lane there free
        or not (SUMO's lane-change state, read through libsumo)? False with ``[swarm]
        keep_right_wish`` off, or when TraCI cannot tell."""
        return self.ctx.scenario.swarm.keep_right_wish and bool(
            self.ctx.session.wants_right(target.vehicle_id)
        )

    def _follower_gap(self, follower: VehicleState) -> float:
        """The minimum gap [m] SUMO's lane-change check leaves in front of ``follower``: an
        HV's own minGap, the CAVs' minimum gap."""
        if follower.is_cav:
            return self.ctx.scenario.cav.min_gap_m
        return self.model_of(follower.vehicle_id).min_gap_m

    def _keep_right_due_s(self, target: VehicleState) -> float | None:
        """Seconds until ``target``'s keep-right wish shows, read from SUMO's lane-change
        model (``SumoSession.keep_right_due_s``); None with ``[swarm] keep_right_due`` off or
        where SUMO cannot tell."""
        if not self.ctx.scenario.swarm.keep_right_due:
            return None
        return self.ctx.session.keep_right_due_s(target.vehicle_id)

    def _right_lane_opens(self, target: VehicleState, states: States) -> bool:
        """Will the lane on ``target``'s right open for it within ``[swarm] keep_right_soon_s``
        (:func:`right_lane_opens_within`; HVs only: where the CAVs go is the plan's to say)?
        Always, with keep_right_soon_s = 0."""
        sw = self.ctx.scenario.swarm
        if sw.keep_right_soon_s <= 0.0:
            return True
        hvs = [st for st in states.values() if not st.is_cav]
        return right_lane_opens_within(
            target, hvs, self.ctx.road, within_s=sw.keep_right_soon_s,
            move_s=sw.keep_right_move_s, ahead_s=sw.keep_right_ahead_s,
            min_gap_m=self.ctx.scenario.cav.min_gap_m, secure_gap=self.secure_gap,
        ) is not None  # fmt: skip

    def _right_lane_free(self, target: VehicleState, states: States) -> bool:
        """Is the lane on ``target``'s right free for it to move into (:func:`right_lane_free`)
        by the time it will move: ``keep_right_move_s`` from now, or sooner where SUMO's
        driver model says its wish will show sooner (:meth:`_keep_right_due_s`)?"""
        sc = self.ctx.scenario
        move_s = sc.swarm.keep_right_move_s
        due_s = self._keep_right_due_s(target)
        if due_s is not None:
            move_s = min(move_s, due_s)
        # Timed by SUMO's build-up, the followers are judged as SUMO's check will see them.
        follower_gap = None if due_s is None else self._follower_gap
        return right_lane_free(
            target, states.values(), self.ctx.road, move_s=move_s,
            ahead_s=sc.swarm.keep_right_ahead_s, min_gap_m=sc.cav.min_gap_m,
            secure_gap=self.secure_gap, follower_gap=follower_gap,
        )  # fmt: skip

    # ------------------------------------------------------------------ passing in a lane
    def passing_in_lane(
        self,
        target: VehicleState,
        cavs: Mapping[str, VehicleState],
        states: States,
        grid: MovingGrid | None,
        interval_s: float | None,
    ) -> bool:
        """Has every CAV left the target's lane for one lane, faster than the target by
        ``[swarm] min_speed_gain_mps`` ahead of the front CAV (``hand_over_in_lane``)?
        ``grid`` and ``interval_s`` are the plan's (None before the first plan)."""
        sc = self.ctx.scenario
        sw, road = sc.swarm, self.ctx.road
        if not sw.hand_over_in_lane or len(cavs) < 1:
            return False
        lane = passing_lane(target, list(cavs.values()), road, tolerance_m=sw.in_lane_tolerance_m)
        front = max(cavs.values(), key=lambda c: c.s_m)
        if lane is None or lane in self.lanes.ending(front, front.vehicle_id):
            return False
        others = [st for v, st in states.items() if v not in cavs]
        speeds = lane_speeds(
            front, others, road, [lane], range_m=sw.detect_range_m, cap_mps=self.cap_mps,
            desired_of=self.reformer.desired_speed,
        )  # fmt: skip
        # The cruise must pay: faster than the plan's pace (one cell per behaving interval
        # above the grid) by the gain; with the cruise barely above the target (the paper's
        # 20 m/s beside an 18 m/s HV) the plan passes faster, up to the cap.
        interval = interval_s or self.planner.behaving_interval_s
        grid_speed = grid.speed_mps if grid is not None else target.speed_mps
        pace = max(grid_speed, target.speed_mps) + sc.cell_length_m / interval
        cruise = min(speeds[lane], self.ctx.cav.cruising_speed_mps)
        return cruise - pace >= sw.min_speed_gain_mps

    def lane_beats_plan(
        self, target: VehicleState, states: States, platoon: list[str]
    ) -> int | None:
        """The lane the platoon moves over to and passes ``target`` in (``[swarm] lane_pass``,
        :func:`lane_for_pass`), or None: the cells."""
        sc = self.ctx.scenario
        road, sw = self.ctx.road, sc.swarm
        if not sw.lane_pass or target.vehicle_id == self.lane_pass_stalled_on:
            return None
        leader = states[self.leader(states, platoon)]
        lane = road.lane_of(leader)
        side = [q for q in (lane - 1, lane + 1) if 0 <= q < road.n_lanes]
        side = [q for q in side if q not in self.lanes.ending(leader, leader.vehicle_id)]
        interval = behaving_interval_s(
            self.planner.behaving_interval_s, sc.cell_length_m, target.speed_mps,
            self.cap_mps, sw.interval_rule,
        )  # fmt: skip
        return lane_for_pass(
            leader, states[platoon[-1]], target, [st for st in states.values() if not st.is_cav],
            road, side, n_cavs=len(platoon), cell_length_m=sc.cell_length_m,
            range_m=sw.detect_range_m, cap_mps=self.cap_mps,
            cruise_mps=self.ctx.cav.cruising_speed_mps,
            pace_mps=target.speed_mps + sc.cell_length_m / interval,
            free_pace_mps=lane_pass_pace(
                target.speed_mps, sc.cell_length_m / interval,
                cruise_mps=self.ctx.cav.cruising_speed_mps,
                min_gain_mps=sw.min_speed_gain_mps, rule=sw.lane_pass_beats,
            ),
            min_gain_mps=sw.min_speed_gain_mps, tolerance_m=sw.in_lane_tolerance_m,
            desired_of=self.reformer.desired_speed,
        )  # fmt: skip
