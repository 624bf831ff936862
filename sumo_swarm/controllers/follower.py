"""Driving the plan: each CAV tracks its reference, every command through the guards.

:class:`PlanFollower` asks the tracker (the MPCs) for each CAV's acceleration and lateral move,
then the guards of :mod:`sumo_swarm.core.swarming.guards`: a lane change waits for a swarm CAV
clearing the lane (a *yield*), is refused where an HV would brake harder than b_safe (a *hold*,
counted once per episode and per manoeuvre), and is held near a lane shift or a lane that ends;
the speed is bounded by the gap ahead, matched to a faster lane being entered, and brought down
to the cap gently (``CAP_DECEL_MPS2``). Commands go to SUMO as ``setSpeed`` and
``changeSublane``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import replace
from typing import Any

from sumo_swarm.controllers.base import lateral_guard
from sumo_swarm.controllers.lanes import LaneView
from sumo_swarm.controllers.reform import clip
from sumo_swarm.core.hvmodel import DriverModel
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.neighbours import Snapshot, snapshot_of, vehicle_ahead
from sumo_swarm.core.stepsafe import STEP_SAFE_MARGIN_M, leader_cap, net_applies
from sumo_swarm.core.swarming.guards import (
    gap_accel_limit,
    gentle_for_follower,
    lane_speed_match,
    yields_to_cav,
)
from sumo_swarm.core.swarming.tracker import Tracker
from sumo_swarm.core.trajectory import Reference

# A CAV matches the speed of the lane its reference enters this far ahead [s]: about the time
# a lane change takes (3.2 m at 2 m/s: 1.6 s), so that it arrives at that lane's speed.
MATCH_LOOKAHEAD_S = 2.0
# A CAV above the speed cap slows to it at this rate [m/s^2] (well inside the 4 m/s^2 line).
CAP_DECEL_MPS2 = 2.0
HOLD_EPISODE_S = 1.0  # holds of one CAV closer together than this are one episode [s]


class PlanFollower:
    """The CAVs' commands while a plan is in force, and the guards' holds and yields."""

    def __init__(
        self,
        ctx: Any,
        tracker: Tracker,
        lanes: LaneView,
        model_of: Callable[[str], DriverModel],
    ) -> None:
        self.ctx = ctx
        self.tracker = tracker
        self.lanes = lanes
        self.model_of = model_of
        self.lat_errors: list[float] = []
        self.holds = 0
        self.yields = 0  # waits for a swarm CAV clearing a lane (tracker timing)
        self.holds_per_manoeuvre: list[int] = []
        self._yielding: dict[str, float] = {}
        self._holding: dict[str, float] = {}

    def new_manoeuvre(self) -> None:
        self.holds_per_manoeuvre.append(0)

    def drive(
        self,
        t_s: float,
        states: Mapping[str, VehicleState],
        platoon: list[str],
        references: Mapping[str, Reference],
        cap_mps: float,
    ) -> None:
        """Command every CAV of ``platoon`` with a reference for the next step."""
        ctx = self.ctx
        sc = ctx.scenario
        road = ctx.road
        dt = ctx.dt_s
        others = snapshot_of(states, road)
        solve = self.tracker.tick()
        cap = cap_mps if math.isfinite(cap_mps) else ctx.cav.max_speed_mps
        gentle = sc.hvmodel.planner_share * sc.hvmodel.b_safe_mps2
        commanded: dict[str, float] = {}  # this step's speeds, front to back
        for vid in platoon:
            ego = states[vid]
            ref = references.get(vid)
            if ref is None:
                continue
            cmd = self.tracker.command(t_s, ego, ref, road, dt, solve)
            self.lat_errors.append(cmd.lat_error_m)
            y = road.y_of(ego.lane, ego.lat_m)
            step_m = sc.cav.max_lateral_speed_mps * dt
            if net_applies(dt) and abs(cmd.dlat_m) > step_m:
                # At steps where a command holds long enough to matter, the guards judge the
                # move the CAV makes within the step, not the tracker's whole wish: at 1 s the
                # tracker asked 9.95 m across, the guards judged its end three lanes over and
                # passed it, and the CAV moved into the truck beside it.
                cmd = replace(cmd, dlat_m=clip(cmd.dlat_m, step_m))
            escape = self.lanes.end_escape(ego, cmd.dlat_m, step_m)
            if escape != cmd.dlat_m:
                cmd = replace(cmd, dlat_m=escape)
            waits_for = yields_to_cav(
                ego, y, cmd.dlat_m, others, road, min_gap_m=sc.cav.min_gap_m,
                width_m=sc.cav.width_m, settings=sc.guards,
            )  # fmt: skip
            refusal = None
            if waits_for is None:
                refusal = self._refusal(ego, y, cmd.dlat_m, others, road, dt)
            else:
                self._count_yield(vid, t_s)
            shift = self.lanes.shift_hold(ego, y, cmd.dlat_m)
            dlat = 0.0 if refusal or waits_for is not None else cmd.dlat_m
            if shift:  # back to the lane centre: never straddle two lanes near the junction
                dlat = clip(road.lane_centre_y(road.road_lane_of_y(y)) - y, step_m)
                if dlat and self._refusal(ego, y, dlat, others, road, dt) is not None:
                    dlat = 0.0  # not into a vehicle alongside (as the reformer's centring)
            self._count_hold(vid, refusal, road.lane_of_y(y + cmd.dlat_m), t_s)
            self.tracker.commit(ego, cmd, dlat != cmd.dlat_m, road, dt)
            accel = cmd.accel_mps2
            # Into a faster lane at that lane's speed (up to the cap); with an HV close behind,
            # slow down only gently (that is how a blocker brings a lane down to its speed).
            lane_to = road.lane_of_y(ref.y_at_s(ego.centre_s_m + MATCH_LOOKAHEAD_S * ego.speed_mps))
            accel = max(
                accel, lane_speed_match(ego, lane_to, others, road, sc.cav.width_m, cap, sc.guards)
            )
            accel = max(
                accel, gentle_for_follower(ego, others, road, sc.cav.width_m, gentle, sc.guards)
            )
            limit = gap_accel_limit(
                ego, y, y + dlat, others, road, sc.cav.min_gap_m, sc.cav.width_m, sc.guards,
                step_s=dt, speeds_now=commanded,
            )  # fmt: skip
            accel = min(max(min(accel, limit), sc.cav.accel_min_mps2), sc.cav.accel_max_mps2)
            # Above the cap (a CAV that departed faster, a lower limit ahead) it comes down to
            # it gently, never by a jump in the commanded speed (SUMO would brake at decel).
            floor = ego.speed_mps - CAP_DECEL_MPS2 * dt
            v_cmd = min(ego.speed_mps + accel * dt, max(cap, floor))
            if net_applies(dt):
                # What the step-safety net will let it drive behind the vehicles the gap guard
                # looks at (SumoSession.flush_commands): the speed handed on to the CAVs behind
                # is then the one SUMO gets (a CAV commanded 21.8 m/s, capped to 19.5 behind the
                # truck ahead, was taken at 21.8 by the CAV behind it, which closed to 3.6 m).
                v_cmd = min(v_cmd, self._net_cap(ego, {y, y + dlat}, others, road, commanded))
            commanded[vid] = max(v_cmd, 0.0)
            ctx.session.set_speed(vid, commanded[vid])
            ctx.session.change_sublane(vid, dlat)

    def _net_cap(
        self,
        ego: VehicleState,
        ys: set[float],
        others: Snapshot,
        road: RoadSection,
        commanded: Mapping[str, float],
    ) -> float:
        """The step-safety net's cap [m/s] (:func:`~sumo_swarm.core.stepsafe.leader_cap`) on
        ego behind the nearest vehicle ahead at each of ``ys``, a CAV commanded this step at
        its command."""
        sc = self.ctx.scenario
        dt = self.ctx.dt_s
        own = -sc.cav.accel_min_mps2
        cap = math.inf
        for y in ys:
            ahead = vehicle_ahead(ego, others, road, y_m=y, width_m=sc.cav.width_m)
            if ahead is None or ahead[1] <= 0.0:  # alongside: the lateral guards' to judge
                continue
            lead, gap = ahead
            decel = own if lead.is_cav else self.model_of(lead.vehicle_id).decel_mps2
            command = commanded.get(lead.vehicle_id)
            cap = min(
                cap, leader_cap(gap - STEP_SAFE_MARGIN_M, lead.speed_mps, command, decel, own, dt)
            )
        return cap

    def _refusal(
        self,
        ego: VehicleState,
        y: float,
        dlat: float,
        others: Snapshot,
        road: RoadSection,
        step_s: float,
    ) -> str | None:
        """The lateral guard (:func:`~sumo_swarm.controllers.base.lateral_guard`) on ego's
        move ``dlat`` [m] from ``y``."""
        return lateral_guard(self.ctx.scenario, self.model_of, ego, y, dlat, others, road, step_s)

    def _new_episode(self, seen: dict[str, float], vid: str, t_s: float) -> bool:
        """Record ``vid`` in ``seen`` at ``t_s``: a new episode unless it was there within
        ``HOLD_EPISODE_S``."""
        last = seen.get(vid)
        seen[vid] = t_s
        return last is None or t_s - last > HOLD_EPISODE_S

    def _count_yield(self, vid: str, t_s: float) -> None:
        """One yield per episode: a CAV waiting for a swarm CAV to clear a lane."""
        if self._new_episode(self._yielding, vid, t_s):
            self.yields += 1

    def _count_hold(self, vid: str, refusal: str | None, lane: int, t_s: float) -> None:
        """One ``lateral_hold`` per episode: a CAV held, not held again within HOLD_EPISODE_S."""
        if refusal is None or not self._new_episode(self._holding, vid, t_s):
            return
        self.holds += 1
        if self.holds_per_manoeuvre:
            self.holds_per_manoeuvre[-1] += 1
        self.ctx.event("lateral_hold", vehicle=vid, lane=lane, reason=refusal)
