"""The swarm's one decision principle (pure): weigh what it could do about a slow vehicle, take
the best for everyone on the road.

When a slow vehicle holds the platoon (the decision point), each candidate is predicted over a
horizon of ``horizon_s`` with plain kinematics, and scored in vehicle-metres:

    score = gain of the CAVs over following - others_weight * loss of everyone else

- **follow**: the platoon stays behind the slow vehicle: the reference, score 0. Its pace is
  the slow vehicle's, rising to what the lane ahead of it allows (a car catching up with a
  line ahead is not slow for long).
- **wait**: the slow vehicle's driver will leave the lane: SUMO shows the wish (whatever the
  reason: keeping right, its route, a faster lane), or it is held back below its desired
  speed and a lane beside is faster by ``HV_SPEED_GAIN_MPS`` (SUMO's speed-gain model weighs
  the same): only a vehicle slow by its driver's own choice stays to be passed.
  It does so within ``LEAVE_S`` and the platoon then drives at the pace ahead of it. Nobody
  else loses, and nothing else is weighed: a target that leaves is not passed (whatever passing
  it gains, waiting gains too; on a motorway, manoeuvres on such targets ended when they left).
  Taken where many swarms share the road, the swarm parts, as for **apart**: each CAV gains
  the same waiting on its own.
- **lane_pass**: the platoon moves over to a lane beside it and drives at that lane's pace,
  once the vehicles beside it there (or too close behind it) have passed: the guards let them
  by, and a lane whose vehicles never pass (no faster than the platoon) is not weighed. The
  vehicles further behind lose the road the platoon takes: each drops back to its secure gap by
  what exceeds its spare room (:func:`insertion_loss_m`).
- **one_by_one**: each CAV moves over where it is and passes in its fastest lane beside, the
  others losing what each CAV's own length takes; ahead, the platoon re-forms, each CAV but the
  first giving up a vehicle's spacing to close up.
- **apart** (in its place where many swarms share the road, ``apart``: there a CAV alone is
  SUMO's driver): each CAV moves over where SUMO's lane-change model lets it (in front of a
  vehicle only at that one's secure gap, speed difference included) and stays apart, each
  first dropping back from the platoon's short gap to a driver's own. Taken, the swarm parts
  (controllers.fleet): what the CAVs do together did not pay more.
- **cells**: the paper's manoeuvre: the CAVs move up one cell per behaving interval past the
  slow vehicle, blocking the side lanes' vehicles to the grid's speed while they pass, then
  drive at the pace ahead of it. The blocked vehicles lose the speed they give up for as long
  as the pass lasts.

The best candidate is taken when its score beats following by ``min_gain_mps`` per CAV for
half the horizon (MOBIL's incentive threshold for the platoon as a whole); else the platoon
follows (or, with ``apart``, parts), and the vehicles around are no worse off than under
SUMO's own drivers. Units: m, s, m/s.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from sumo_swarm.core.hvmodel import SUMO_DEFAULTS
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.swarming.decision import secure_gap_m

__all__ = [
    "Choice",
    "Outlook",
    "PlatoonView",
    "choose",
    "insertion_loss_m",
    "lane_pace_mps",
    "mean_speed_mps",
]

# How long [s] a driver that wants to leave its lane takes to be out of it: SUMO's default
# lane-change duration (lcDuration... the sublane model moves at maxSpeedLat 1 m/s over half a
# 3.2-3.5 m lane before the vehicle counts in the next) plus a second to find its gap.
LEAVE_S = 3.0
# An HV's acceleration while it rises to the pace ahead [m/s^2] (IDM's a is 0.73-1.5, SUMO's
# default passenger accel 2.6 less its comfortable use).
HV_ACCEL_MPS2 = 1.0
# A vehicle's spacing in a lane at speed v: its length plus this standstill gap [m] plus a
# one-second headway (SUMO's default tau), for the secure gap the others keep.
MIN_GAP_M = SUMO_DEFAULTS.min_gap_m
HEADWAY_S = SUMO_DEFAULTS.tau_s
# A driver moves to a lane beside for this much more speed [m/s]: one driver changes lanes for
# less than a platoon needs to coordinate a manoeuvre (min_gain_mps); with the platoon's 2 m/s,
# targets moved into the lane the platoon was passing in within 1-4 s of the start.
HV_SPEED_GAIN_MPS = 1.0
# Vehicles in a lane behind an entry point that can lose road to it: this far behind [m].
BEHIND_M = 150.0
# The deceleration SUMO's drivers take for a follower's secure gap [m/s^2] (its default
# passenger vType's decel).
SUMO_DECEL_MPS2 = SUMO_DEFAULTS.decel_mps2
# What the CAVs do without acting together: follow, wait for the target to leave the lane
# (what that gains, each CAV gains as well on its own), or (many swarms) each on its own.
ALONE = frozenset({"follow", "wait", "apart"})


@dataclass(frozen=True)
class PlatoonView:
    """The platoon as the arbiter sees it."""

    front: VehicleState
    tail: VehicleState
    n_cavs: int
    cavs: tuple[VehicleState, ...]  # front first
    cruise_mps: float  # the platoon's cruise, capped
    lateral_speed_mps: float
    lane_width_m: float


@dataclass(frozen=True)
class Outlook:
    """A candidate's prediction: what the CAVs gain over following and what the others lose
    [vehicle-metres over the horizon]."""

    kind: str  # follow, wait, lane_pass, cells
    lane: int | None
    gain_m: float
    loss_m: float
    score_m: float


@dataclass(frozen=True)
class Choice:
    """The candidate taken and every candidate weighed (for the decision's event)."""

    best: Outlook
    weighed: tuple[Outlook, ...]


def mean_speed_mps(v0_mps: float, v1_mps: float, horizon_s: float, accel_mps2: float) -> float:
    """Mean speed [m/s] over ``horizon_s`` of a vehicle going from ``v0_mps`` to ``v1_mps`` at
    ``accel_mps2`` (braking at once)."""
    if horizon_s <= 0.0:
        return v0_mps
    if v1_mps <= v0_mps:
        return v1_mps
    t_up = (v1_mps - v0_mps) / accel_mps2
    if t_up >= horizon_s:
        return v0_mps + 0.5 * accel_mps2 * horizon_s
    return v1_mps - 0.5 * (v1_mps - v0_mps) * t_up / horizon_s


def _ahead_in_lane(
    s_m: float, others: Sequence[VehicleState], road: RoadSection, lane: int, range_m: float
) -> list[VehicleState]:
    """The vehicles in ``lane`` (by their centre) whose front is ahead of ``s_m`` within
    ``range_m``, nearest first."""
    found = [
        o for o in others
        if s_m < o.s_m <= s_m + range_m and road.lane_of(o) == lane
    ]  # fmt: skip
    return sorted(found, key=lambda o: o.s_m)


def lane_pace_mps(
    s_m: float,
    others: Sequence[VehicleState],
    road: RoadSection,
    lane: int,
    *,
    cap_mps: float,
    range_m: float,
    desired_of: Callable[[VehicleState], float],
    horizon_s: float,
) -> float:
    """The mean speed [m/s] over ``horizon_s`` of a platoon whose front is at ``s_m`` in
    ``lane``: ``cap_mps`` on a free lane; else the nearest vehicle's, rising (at most
    ``HV_ACCEL_MPS2``) to the lowest desired speed of the vehicles ahead of it within
    ``range_m`` of it (a line it is catching up with holds it to that line's speed). A slower
    vehicle further ahead that the platoon reaches within the horizon holds it from then on
    (:func:`_met_ahead_mps`): a lane is as fast as the traffic the platoon would meet in it."""
    ahead = _ahead_in_lane(s_m, others, road, lane, range_m)
    if not ahead:
        pace = cap_mps
    else:
        nearest = ahead[0]
        line = [o for o in ahead if o.s_m - nearest.s_m <= range_m]
        eventual = min(min(desired_of(o), o.speed_mps if o is not nearest else math.inf)
                       for o in line)  # fmt: skip
        eventual = min(max(eventual, nearest.speed_mps), cap_mps)
        pace = min(cap_mps, mean_speed_mps(max(nearest.speed_mps, 0.0), eventual, horizon_s,
                                           HV_ACCEL_MPS2))  # fmt: skip
    return min(pace, _met_ahead_mps(s_m, range_m, others, road, lane, pace, horizon_s))


def _met_ahead_mps(
    s_m: float,
    range_m: float,
    others: Sequence[VehicleState],
    road: RoadSection,
    lane: int,
    pace_mps: float,
    horizon_s: float,
) -> float:
    """The mean speed [m/s] over ``horizon_s`` of a platoon whose front is at ``s_m``, driving
    at ``pace_mps``, that meets the vehicles of ``lane`` beyond ``range_m`` ahead: at its pace
    until it reaches the first slower one it catches (at that one's secure gap behind it), at
    that one's speed from then on."""
    mean = pace_mps
    for o in _ahead_in_lane(s_m + range_m, others, road, lane, pace_mps * horizon_s):
        v = max(o.speed_mps, 0.0)
        if v >= mean:
            continue
        catch_s = max(0.0, o.rear_s_m - s_m - secure_room_m(v)) / (pace_mps - v)
        if catch_s < horizon_s:
            mean = min(mean, (pace_mps * catch_s + v * (horizon_s - catch_s)) / horizon_s)
    return mean


def secure_room_m(speed_mps: float) -> float:
    """The gap [m] a vehicle at ``speed_mps`` keeps to its leader at the same speed."""
    return MIN_GAP_M + HEADWAY_S * max(speed_mps, 0.0)


def insertion_loss_m(
    others: Sequence[VehicleState],
    road: RoadSection,
    lane: int,
    front_s_m: float,
    rear_s_m: float,
) -> float:
    """The road [vehicle-metres] the vehicles of ``lane`` give up when a platoon spanning
    ``rear_s_m`` to ``front_s_m`` moves in there: the nearest one behind its front drops back
    to its secure gap behind the platoon's rear; each one behind it drops back by what that
    exceeds its own spare room (its gap less the gap it keeps); the first with room to spare
    stops it."""
    behind = sorted(
        (o for o in others
         if front_s_m - BEHIND_M < o.s_m <= front_s_m and road.lane_of(o) == lane),
        key=lambda o: -o.s_m,
    )  # fmt: skip
    loss, push, ahead_rear = 0.0, 0.0, rear_s_m
    for i, o in enumerate(behind):
        if i == 0:
            push = max(0.0, o.s_m + secure_room_m(o.speed_mps) - rear_s_m)
        else:
            spare = ahead_rear - o.s_m - secure_room_m(o.speed_mps)
            push = max(0.0, push - max(0.0, spare))
        if push <= 0.0:
            break
        loss += push
        ahead_rear = o.rear_s_m
    return loss


def choose(
    platoon: PlatoonView,
    target: VehicleState,
    others: Sequence[VehicleState],
    road: RoadSection,
    *,
    side_lanes: Sequence[int],
    leaves: bool,
    cells_pace_mps: float | None,
    desired_of: Callable[[VehicleState], float],
    horizon_s: float,
    range_m: float,
    others_weight: float,
    min_gain_mps: float,
    apart: bool = False,
    pass_lanes: Sequence[int] | None = None,
) -> Choice:
    """Weigh following, waiting (``leaves``: the target's driver wants to leave the lane), a
    lane pass in each of ``side_lanes`` (or of ``pass_lanes``: none where a lane pass on this
    target stalled) and the cells (``cells_pace_mps``: the plan's pace past the target above
    the target's speed; None: no cell plan possible) and take the best (see the module
    docstring). ``others``: every vehicle but the platoon's CAVs."""
    n = platoon.n_cavs
    cavs = platoon.cavs
    cap = platoon.cruise_mps
    others = [o for o in others if o.vehicle_id != target.vehicle_id]
    pace = dict(
        cap_mps=cap, range_m=range_m, desired_of=desired_of, horizon_s=horizon_s
    )  # fmt: skip
    # The road ahead of the target, once the platoon is past it or it has gone.
    ahead_lane = road.road_lane_of(target)  # (a target merging from beside the road)
    beyond = lane_pace_mps(target.s_m, others, road, ahead_lane, **pace)
    follow_mps = min(
        cap,
        mean_speed_mps(
            max(target.speed_mps, 0.0), min(desired_of(target), beyond), horizon_s,
            HV_ACCEL_MPS2,
        ),
    )  # fmt: skip
    weighed = [Outlook("follow", None, 0.0, 0.0, 0.0)]
    # The target's driver, too, moves to a faster lane beside it when it gains there (MOBIL's
    # incentive, as SUMO's speed-gain model weighs it, for one driver): held back below its
    # desired speed, it takes a lane beside that is faster, as seen from it or from the
    # platoon's front, by HV_SPEED_GAIN_MPS; it leaves. Only a vehicle slow by its driver's own
    # choice stays to be passed.
    here = ahead_lane
    held_back = desired_of(target) - target.speed_mps >= HV_SPEED_GAIN_MPS
    for q in (here - 1, here + 1):
        if not 0 <= q < road.n_lanes or not held_back:
            continue
        faster = max(
            lane_pace_mps(target.rear_s_m, others, road, q, **pace),
            lane_pace_mps(platoon.front.s_m, others, road, q, **pace),
        )
        if min(desired_of(target), faster) - target.speed_mps >= HV_SPEED_GAIN_MPS:
            leaves = True

    def add(kind: str, lane: int | None, gain: float, loss: float) -> None:
        weighed.append(Outlook(kind, lane, gain, loss, gain - others_weight * loss))

    if leaves:
        # A target that leaves is not passed: whatever passing it gains, waiting gains too, and
        # a manoeuvre on it ends when it goes (on a motorway most of them did).
        rest = max(0.0, horizon_s - LEAVE_S)
        # Half: the platoon rises to the pace ahead over the rest of the horizon.
        add("wait", None, n * max(0.0, beyond - follow_mps) * rest * 0.5, 0.0)
        return Choice(weighed[-1], tuple(weighed))
    move_s = 0.5 * platoon.lane_width_m / max(platoon.lateral_speed_mps, 0.1)

    def move_over(
        front: VehicleState, rear_s_m: float, lane: int, after_s: float, *, alone: bool = False
    ):
        """``(gain per CAV, loss)`` of moving the CAVs from ``front`` back to ``rear_s_m``
        over to ``lane`` at ``after_s`` into the horizon; None: not within it. They move where
        nobody must brake for them: a vehicle beside them there, or closer behind than its own
        secure gap, passes first (the guards wait for it); one no faster than them never
        does. The vehicles further behind lose the road they take (:func:`insertion_loss_m`).
        ``alone``: a CAV SUMO drives moves where SUMO's lane-change model lets it, in front of
        a vehicle only at that one's secure gap behind it at its own speed (SUMO's
        getSecureGap: a follower much faster than the CAV needs far more room)."""

        def room(o: VehicleState) -> float:
            if alone:
                v = o.speed_mps
                return MIN_GAP_M + secure_gap_m(HEADWAY_S, SUMO_DECEL_MPS2, v, front.speed_mps)
            return secure_room_m(o.speed_mps)

        first = [
            o for o in others
            if road.lane_of(o) == lane and o.rear_s_m < front.s_m + MIN_GAP_M
            and o.s_m > rear_s_m - room(o)
        ]  # fmt: skip
        clear_s = max(
            (
                (front.s_m + MIN_GAP_M - o.rear_s_m) / (o.speed_mps - follow_mps)
                if o.speed_mps > follow_mps + 0.5
                else math.inf
                for o in first
            ),
            default=0.0,
        )
        left_s = horizon_s - after_s - move_s - clear_s
        if left_s <= 0.0:
            return None
        lane_mps = lane_pace_mps(front.s_m, others, road, lane, **pace)
        lane_mps = min([lane_mps, *(min(o.speed_mps, desired_of(o)) for o in first)])
        rest = [o for o in others if o not in first]
        return (lane_mps - follow_mps) * left_s, insertion_loss_m(
            rest, road, lane, front.s_m, rear_s_m
        )

    for lane in side_lanes if pass_lanes is None else pass_lanes:
        moved = move_over(platoon.front, platoon.tail.rear_s_m, lane, 0.0)
        if moved is not None:
            add("lane_pass", lane, n * moved[0], moved[1])
    # One by one: each CAV moves over on its own, into the lane beside that pays it most (as a
    # lane pass of one). ``apart`` (many swarms, where SUMO drives a CAV alone): each does so
    # as SUMO's driver, when it can, and stays apart. Else one lane move after the other, and
    # ahead the platoon re-forms, each CAV but the first giving up a vehicle's spacing to
    # close up again.
    if n > 1 and side_lanes:
        gain = loss = 0.0
        for i, cav in enumerate(cavs):
            after_s = 0.0 if apart else move_s * i
            options = [move_over(cav, cav.rear_s_m, q, after_s, alone=apart) for q in side_lanes]
            best = max((o for o in options if o is not None),
                       key=lambda o: o[0] - others_weight * o[1], default=None)  # fmt: skip
            if best is not None:
                gain, loss = gain + best[0], loss + best[1]
        if apart:
            # ...each first dropping back from the platoon's short gap to the gap a driver
            # keeps alone (the fleet hands it to SUMO there).
            drop = sum(
                max(0.0, secure_room_m(b.speed_mps) - (a.rear_s_m - b.s_m))
                for a, b in itertools.pairwise(cavs)
            )  # fmt: skip
            add("apart", None, gain - drop, loss)
        else:
            regroup = (n - 1) * (platoon.front.length_m + secure_room_m(follow_mps))
            add("one_by_one", None, gain - regroup, loss)
    # The cells pass through the same lanes beside (none usable: no way through).
    if cells_pace_mps is not None and cells_pace_mps > 0.0 and side_lanes:
        # The grid moves with the target: at its predicted pace (a target speeding up takes
        # the grid, and the CAVs in it, along; passing it then gains little).
        grid_mps = follow_mps
        # The CAVs pass at the plan's pace above the grid, no faster than the lanes they pass
        # in let them (blocking holds back who is behind, not who is ahead).
        side_mps = max(
            lane_pace_mps(platoon.front.s_m, others, road, q, **pace) for q in side_lanes
        )  # fmt: skip
        through_mps = min(cap, grid_mps + cells_pace_mps, max(side_mps, grid_mps))
        # Each CAV moves up past the target and the CAVs ahead of it: the platoon's footprint
        # plus the target's length, at that pace above the grid (timed at the plan's pace, a
        # pass held to the grid's speed by the lanes beside was weighed as over in seconds:
        # on the corridors such cells ran out of time).
        closing_mps = through_mps - grid_mps
        if closing_mps > 0.0:
            pass_s = (platoon.front.s_m - platoon.tail.rear_s_m + target.length_m) / closing_mps
            # ...once the first of them has moved over, as in any pass.
            during = min(pass_s, max(0.0, horizon_s - move_s))
            after = max(0.0, horizon_s - move_s - pass_s)
            # Every CAV moves up at once (the front ones are through sooner: a lower bound).
            gain = n * ((through_mps - follow_mps) * during + (beyond - follow_mps) * after)
            loss = 0.0
            lo, hi = platoon.tail.rear_s_m - range_m, target.s_m + range_m
            for o in others:
                if lo < o.s_m < hi and road.lane_of(o) in side_lanes:
                    loss += max(0.0, min(o.speed_mps, desired_of(o)) - grid_mps) * during
            add("cells", None, gain, loss)
    threshold = n * min_gain_mps * 0.5 * horizon_s
    best = max(weighed, key=lambda o: o.score_m)
    if best.kind != "follow" and best.score_m < threshold:
        best = weighed[0]
    return Choice(best, tuple(weighed))
