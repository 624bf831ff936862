"""What the swarm reads off the road ahead: lanes that end, places where lane indices shift.

The controller's states count lanes as on the leader's edge (``states_in_lanes_of``); what is
read on a CAV's own edge (its lane count, the lanes ending ahead of it) is read from its own
state; the thresholds are the constants below. :class:`LaneView`
holds nothing but the run's context: every answer is read afresh from
the session, so it is safe to ask at any step.
"""

from __future__ import annotations

from typing import Any

from sumo_swarm.core.model import VehicleState
from sumo_swarm.core.planner.problem import LANE_END_PREFIX
from sumo_swarm.core.swarming.guards import entering_lane

LANE_END_LENGTH_M = 1000.0  # length of the pseudo-obstacle standing for a lane that ends [m]
# No CAV moves into a lane that ends within this many seconds at its speed (at least
# LANE_END_MIN_M ahead); a CAV whose lane ends within LANE_END_ESCAPE_S heads out of it.
LANE_END_HOLD_S = 12.0
LANE_END_ESCAPE_S = 8.0
LANE_END_MIN_M = 300.0  # an on-ramp's acceleration lane is 250 m in netbuild's motorway
# No lane change this close to a place where lane indices shift (see LaneView.shift_hold) [m].
LANE_SHIFT_HOLD_M = 40.0


class LaneView:
    """Lane ends and lane shifts ahead of the CAVs, read through the run's session.

    ``ctx`` is the run's context (:class:`~sumo_swarm.controllers.base.RunContext`). Where
    the session cannot tell a vehicle's edge, no lane ends ahead of it.
    """

    def __init__(self, ctx: Any) -> None:
        self.ctx = ctx

    def edge_of(self, vid: str) -> str | None:
        """The edge ``vid`` is on (None if unknown)."""
        return self.ctx.session.edges.get(vid)

    def own(self, ego: VehicleState) -> VehicleState:
        """``ego`` with its lane index on its own edge (the controller's states count lanes as
        on the leader's edge: ``states_in_lanes_of``), for what is read on that edge."""
        return self.ctx.session.states.get(ego.vehicle_id, ego)

    def ending(self, leader: VehicleState, vid: str, range_m: float | None = None) -> set[int]:
        """Lanes that end within ``range_m`` (default ``[swarm] detect_range_m``) ahead of the
        vehicle ``vid`` whose state is ``leader``."""
        edge = self.edge_of(vid)
        if edge is None:
            return set()
        if range_m is None:
            range_m = self.ctx.scenario.swarm.detect_range_m
        reach = leader.s_m + range_m
        return {lane for lane, _ in self.ctx.session.lanes_ending(edge, leader.rear_s_m, reach)}

    def ending_within(
        self, ego: VehicleState, horizon_s: float, speed_mps: float | None = None
    ) -> set[int]:
        """Lanes of ``ego``'s own edge that end within ``horizon_s`` at its speed (or at
        ``speed_mps``; at least ``LANE_END_MIN_M``) ahead of it."""
        speed = ego.speed_mps if speed_mps is None else speed_mps
        reach_m = max(LANE_END_MIN_M, horizon_s * speed)
        return self.ending(ego, ego.vehicle_id, reach_m)

    def ends_ahead(self, ego: VehicleState) -> set[int]:
        """Lanes no pass of ``ego`` goes in: those that end within ``[swarm] horizon_s`` (the
        weighing's horizon) ahead of it at the cruise, or at its speed if faster, numbered as
        ``ego``'s lane is (the leader's edge's numbering). A pass there ends at the lane's end:
        a CAV that passed a car in a lane dropping 550 m ahead met the next car beside it,
        found no way back among the cars there and stood at the lane's end (the OSM Autobahn
        at 40 % CAVs)."""
        own = self.own(ego)
        shift = ego.lane - own.lane
        speed = max(own.speed_mps, self.ctx.cav.cruising_speed_mps)
        ending = self.ending_within(own, self.ctx.scenario.swarm.horizon_s, speed)
        return {lane + shift for lane in ending}

    def lane_count(self, ego: VehicleState) -> int:
        """Lanes of ``ego``'s own edge (the road's, where the session cannot tell)."""
        frame = self.ctx.session.frame
        edge = self.edge_of(ego.vehicle_id)
        if frame is None or not edge:  # "": off the lanes
            return self.ctx.road.n_lanes
        return frame.lane_count(edge)

    def shift_hold(self, ego: VehicleState, y: float, dlat: float) -> bool:
        """Hold a lane change near a place where lane indices shift (a lane added or dropped
        on the right: on-ramps, lane drops): there the vehicles on either side of the junction
        count their lanes differently, so the neighbour look-ups cannot be trusted. Also hold
        one into a lane that ends ahead (an acceleration lane, a lane drop) within
        ``LANE_END_HOLD_S`` at the CAV's speed: a CAV moved into an on-ramp's
        acceleration lane, which the plan's columns took for a through lane, and stopped at its
        end."""
        sc = self.ctx.scenario
        if entering_lane(self.ctx.road, y, dlat, sc.guards) is None:
            return False
        ego = self.own(ego)
        entering = ego.lane + (1 if dlat > 0 else -1)
        if entering in self.ending_within(ego, LANE_END_HOLD_S):
            return True
        return self.ctx.session.near_lane_shift(ego.s_m, LANE_SHIFT_HOLD_M + ego.length_m)

    def end_escape(self, ego: VehicleState, dlat: float, step_m: float) -> float:
        """The lateral move [m] of ``ego`` this step: ``dlat``, unless its lane ends within
        ``LANE_END_ESCAPE_S``: then towards the neighbouring lane that goes on (left
        first: lanes end on the right at on-ramps), through the lateral guard like any other
        move."""
        ego = self.own(ego)
        ending = self.ending_within(ego, LANE_END_ESCAPE_S)
        if ego.lane not in ending:
            return dlat
        n_lanes = self.lane_count(ego)
        for side in (1, -1):
            lane = ego.lane + side
            if 0 <= lane < n_lanes and lane not in ending:
                return side * step_m
        return dlat

    def end_obstacles(self, edge: str | None, s_from_m: float, s_to_m: float) -> list[VehicleState]:
        """Lanes of ``edge``'s route that end between ``s_from_m`` and ``s_to_m`` (a later
        route edge has fewer lanes), as standing obstacles for the cell plan."""
        if not edge:
            return []
        return [
            VehicleState(f"{LANE_END_PREFIX}{lane}@{end:.0f}", end + LANE_END_LENGTH_M,
                         lane, 0.0, 0.0, LANE_END_LENGTH_M)
            for lane, end in self.ctx.session.lanes_ending(edge, s_from_m, s_to_m)
        ]  # fmt: skip
