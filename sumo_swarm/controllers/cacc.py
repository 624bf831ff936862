"""The paper's baseline: a longitudinal-only CACC platoon (no lane change of its own; SUMO makes
the ones its route needs, where its lane ends).

The same law drives the swarm's cruise mode. It is a constant-spacing CACC with feedforward of
the predecessor's acceleration, bounded by the free-road law towards the cruising speed.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from sumo_swarm.config import CaccSettings, CavSettings
from sumo_swarm.controllers.base import LC_MODE_STRATEGIC, RouteWatch, RunContext
from sumo_swarm.core.model import VehicleState
from sumo_swarm.core.neighbours import Snapshot, snapshot_of, vehicle_ahead


def cacc_accel(
    speed_mps: float,
    gap_m: float | None,
    ahead_speed_mps: float,
    ahead_accel_mps2: float,
    cav: CavSettings,
    law: CaccSettings,
    *,
    ahead_is_cav: bool = True,
    cruising_speed_mps: float | None = None,
) -> float:
    """Commanded acceleration [m/s^2] of a CACC vehicle.

    ``gap_m`` is the bumper-to-bumper gap to the vehicle ahead (None: free road). The desired
    gap is ``cav.desired_gap_m + time_gap * v``; the result is the smaller of the following
    law and the cruise law, clipped to ``[cav.accel_min_mps2, cav.accel_max_mps2]``.
    """
    v_cruise = cav.cruising_speed_mps if cruising_speed_mps is None else cruising_speed_mps
    desired = cav.desired_gap_m
    if gap_m is not None:
        time_gap = law.time_gap_s + (0.0 if ahead_is_cav else law.hv_time_gap_s)
        desired = cav.desired_gap_m + time_gap * speed_mps
        if ahead_is_cav and gap_m > desired:
            v_cruise = min(cav.max_speed_mps, v_cruise + law.k_close * (gap_m - desired))
    accel = law.k_cruise * (v_cruise - speed_mps)
    if gap_m is not None:
        follow = (
            law.k_gap * (gap_m - desired)
            + law.k_speed * (ahead_speed_mps - speed_mps)
            + (law.k_accel * ahead_accel_mps2 if ahead_is_cav else 0.0)
        )
        # Below the minimum gap, close no further whatever the feedforward says.
        if gap_m < cav.min_gap_m:
            follow = min(follow, ahead_speed_mps - speed_mps - 0.5)
        accel = min(accel, follow)
    return min(max(accel, cav.accel_min_mps2), cav.accel_max_mps2)


# A CAV that SUMO changes lanes for (one released to take its exit) but whose speed our CACC
# commands, in a lane that does not go on along its route: it slows for that lane's end as if
# to stop LANE_END_STOP_M before it, braking LANE_END_DECEL_MPS2 (what SUMO's drivers do when
# they cannot change lanes yet: slow down, let a gap come, stop at the end if none does).
# Commanded at the CACC speed instead, an exiting CAV that found no gap into the deceleration
# lane ran into its lane's end at 19 m/s and SUMO stopped it dead; the CAV behind hit it
# (the penetration study, 10 % CAVs at 1000 veh/h/lane).
LANE_END_DECEL_MPS2 = 2.0
LANE_END_STOP_M = 8.0
# Such a CAV in a lane that goes on along the road (a through lane beside the deceleration
# lane) misses its exit and drives on (SumoSession.miss_exit, an ``exit_missed`` event), as a
# driver who found no gap does, once it has stood within MISS_EXIT_WITHIN_M of where it must
# stop for MISS_EXIT_AFTER_S, two lanes or more from the lane it needs (and for twice that one
# lane from it). Standing two lanes off, it held up its lane and SUMO's drivers beside it
# stopped to let it in: the corridor jammed behind the off-ramp for five minutes with the road
# ahead empty (40 % CAVs at 1800 veh/h/lane). Given up at once instead, a CAV that would have
# got in after a few seconds' wait missed its exit (tests/test_corridor.py, exits).
MISS_EXIT_WITHIN_M = LANE_END_STOP_M + 15.0
MISS_EXIT_AFTER_S = 15.0


def lane_end_accel(ctx: RunContext, vid: str, speed_mps: float) -> float | None:
    """Upper bound [m/s^2] of the acceleration of ``vid`` for the end of a lane it must leave
    (see :data:`LANE_END_DECEL_MPS2`); None when its lane goes on along its route."""
    session = ctx.session
    need = session.lane_change_need(vid)
    if need is None:
        return None
    distance, lanes = need
    if distance <= MISS_EXIT_WITHIN_M:
        wait_s = MISS_EXIT_AFTER_S * (1.0 if lanes >= 2 else 2.0)
        if session.standing_s(vid) >= wait_s and _miss_exit(ctx, vid):
            return None
    room = max(0.0, distance - LANE_END_STOP_M)
    v_cap = math.sqrt(2.0 * LANE_END_DECEL_MPS2 * room)
    return (v_cap - speed_mps) / ctx.dt_s


def _miss_exit(ctx: RunContext, vid: str) -> bool:
    """Give up ``vid``'s exit where its lane goes on along the road (see
    :data:`MISS_EXIT_WITHIN_M`); True if it now drives on."""
    missed = ctx.session.miss_exit(vid)
    if missed is None:
        return False
    ctx.event("exit_missed", vehicle=vid, exit=missed)
    return True


def held_share(settings: CaccSettings, dt_s: float) -> float:
    """The share of the CACC law's acceleration a command held for a whole step of ``dt_s`` [s]
    takes. The law closes a speed error at ``k_speed`` [1/s]; a command held for a step closes
    ``k_speed * dt`` of it, all of it or more once that reaches 1 (a step of 0.91 s and longer
    at the default gain): the platoon then overshoots and oscillates (at 1 s its CAVs braked at
    4 m/s^2 one step and accelerated the next, and the human drivers around braked hard). There
    the command closes what the law would over the step, ``1 - exp(-k_speed * dt)``; below, the
    law as it is (on the 40 paper-scene variants at 0.5 s the exact share everywhere cost the
    worst scene 2 points against cacc)."""
    x = settings.k_speed * dt_s
    return 1.0 if x < 1.0 else (1.0 - math.exp(-x)) / x


def command_cacc(
    ctx: RunContext,
    platoon: list[str],
    leader_cruise_mps: float | None = None,
    accel_limits: Mapping[str, float] | None = None,
    accel_floors: Mapping[str, float] | None = None,
    states: Mapping[str, VehicleState] | None = None,
    cruise_mps: float | None = None,
    cruise_of: Mapping[str, float] | None = None,
    everyone: Snapshot | None = None,
) -> None:
    """Command one CACC step for every CAV of ``platoon`` (front-most first when
    ``leader_cruise_mps`` is given: that CAV cruises at that speed instead). ``accel_limits``:
    upper bounds [m/s^2] of some CAVs' acceleration (a CAV making room to change lanes);
    ``accel_floors``: lower bounds of some (a CAV running up to a faster lane's speed), never
    above the CAV's upper bound. ``states``: the vehicles as the caller sees them (default
    the session's); ``cruise_mps``: the other CAVs' cruising speed (default the scenario's);
    ``cruise_of``: some CAVs' own cruising speed instead (never the leader's); ``everyone``:
    ``states`` as a :class:`Snapshot`, if the caller has one."""
    if states is None:
        states = ctx.session.states
    # sorted once: a look-up per CAV below
    others = snapshot_of(states, ctx.road) if everyone is None else everyone
    sc, cav = ctx.scenario, ctx.cav  # the CAVs' speeds in force
    released = ctx.session.released
    step_s = ctx.dt_s * held_share(sc.cacc, ctx.dt_s)  # what one held command covers [s]
    for vid in platoon:
        ego = states[vid]
        cruise = leader_cruise_mps if vid == platoon[0] else cruise_mps
        if cruise_of is not None and vid in cruise_of and vid != platoon[0]:
            cruise = cruise_of[vid]
        ahead = vehicle_ahead(ego, others, ctx.road)
        if ahead is None:
            a = cacc_accel(ego.speed_mps, None, 0.0, 0.0, cav, sc.cacc,
                           cruising_speed_mps=cruise)  # fmt: skip
        else:
            lead, gap = ahead
            a = cacc_accel(
                ego.speed_mps, gap, lead.speed_mps, lead.accel_mps2, cav, sc.cacc,
                ahead_is_cav=lead.is_cav, cruising_speed_mps=cruise,
            )  # fmt: skip
        if accel_limits is not None and vid in accel_limits:
            a = max(min(a, accel_limits[vid]), cav.accel_min_mps2)
        if accel_floors is not None and vid in accel_floors:
            a = min(max(a, accel_floors[vid]), cav.accel_max_mps2)
        if vid in released:  # SUMO makes its lane changes: its lane may end before its exit
            bound = lane_end_accel(ctx, vid, ego.speed_mps)
            if bound is not None:
                a = max(min(a, bound), cav.accel_min_mps2)
        ctx.session.set_speed(vid, ego.speed_mps + a * step_s)


class CaccController:
    """Every CAV follows the vehicle ahead in its lane with :func:`cacc_accel`."""

    name = "cacc"

    def __init__(self) -> None:
        self.ctx: RunContext | None = None
        self._configured: set[str] = set()
        self.routes = RouteWatch()  # CAVs whose routes part leave the platoon

    def attach(self, ctx: RunContext) -> None:
        self.ctx = ctx

    def _configure_new(self) -> None:
        ctx = self.ctx
        for vid in ctx.cav_ids:
            if vid in ctx.session.states and vid not in self._configured:
                ctx.configure_cav(vid, lane_change_mode=LC_MODE_STRATEGIC)
                self._configured.add(vid)

    def control(self, t_s: float) -> None:
        ctx = self.ctx
        self._configure_new()
        states = ctx.session.states
        present = self.routes.members(ctx, t_s, [v for v in ctx.cav_ids if v in states])
        self.routes.follow(ctx, command_cacc)
        ctx.follow_world_speeds(present)
        command_cacc(ctx, present)

    def summary(self) -> dict[str, Any]:
        if self.ctx is None:
            return {}
        formed = int(bool(self.ctx.cav_ids))  # one platoon: every CAV of the run
        return {
            "speeds": self.ctx.speeds_block(),
            "swarms": {"platoons_formed": formed, "max_concurrent": formed},
        }
