"""When the swarm overtakes, whom, whether it still pays, and when it gives up (pure).

* :func:`slow_vehicle_ahead` names the candidate: the vehicle right ahead of the platoon's
  leader in the leader's own lane, human-driven, slower than the cruise, and worth passing
  (the swarm's speed cap exceeds its speed by ``min_speed_gain_mps``: MOBIL's incentive
  criterion for the platoon as a whole).
* :func:`lane_speeds` estimates how fast the platoon could drive in each lane (the lanes it
  would pass in, or re-form in), from the vehicles seen ahead.
* :class:`TargetWatch` turns a candidate into a decision once it has held the leader back for
  ``trigger_after_s`` (longer for one about to keep right: :func:`right_lane_free`), and keeps
  the swarm from deciding again during a cool-down.
* :func:`stopped_blocking` says why a target no longer needs overtaking (it left the swarm's
  lane, sped up, or vanished).
* :class:`Progress` measures a manoeuvre (CAVs past the target, rows gained) and says when it
  has stalled or had no usable plan for too long.
"""

from __future__ import annotations

import itertools
import math
from bisect import bisect_left, bisect_right
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from enum import Enum
from typing import TYPE_CHECKING

from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.neighbours import Snapshot, vehicle_ahead, vehicle_behind

if TYPE_CHECKING:
    from sumo_swarm.config import SwarmSettings

# Default of [swarm] accelerating_mps2 (see config.SwarmSettings).
ACCELERATING_MPS2 = 0.5
# Progress of a manoeuvre includes the CAVs behind the target getting this much closer to
# passing it [m] (Progress): a stuck CAV closing in on the truck by 4 m is progress.
GAIN_STEP_M = 3.0


class Mode(Enum):
    """What the swarm is doing."""

    CRUISE = "cruise"  # a CACC platoon in its lane
    OVERTAKE = "overtake"  # swarming past a target (plan, track, regroup)


def speed_cap_mps(limits: Sequence[float]) -> float:
    """The swarm's speed cap: the lowest of the limits given (config, vTypes, lanes) [m/s]."""
    finite = [v for v in limits if v is not None and math.isfinite(v) and v > 0]
    return min(finite) if finite else math.inf


def behaving_interval_s(
    configured_s: float,
    cell_length_m: float,
    grid_speed_mps: float,
    cap_mps: float,
    rule: str,
) -> float:
    """Behaving interval [s] of a plan: long enough that a one-row move per interval needs no
    speed above the cap (``rule = "drivable"``), never shorter than the configured one."""
    if rule != "drivable":
        return configured_s
    room = cap_mps - grid_speed_mps
    if room <= 0:
        return math.inf
    return max(configured_s, cell_length_m / room)


def lane_speeds(
    front: VehicleState,
    others: Sequence[VehicleState],
    road: RoadSection,
    lanes: Sequence[int],
    *,
    range_m: float,
    cap_mps: float,
    desired_of: Callable[[VehicleState], float] | None = None,
) -> dict[int, float]:
    """How fast [m/s] a platoon led by ``front`` could drive in each of ``lanes``: ``cap_mps``
    where the lane is free for ``range_m`` ahead of ``front``'s bumper, else the speed of the
    nearest vehicle ahead there or alongside ``front`` (by its centre's lane, so a vehicle
    half-way out of a lane no longer counts for it), at most its desired speed
    (``desired_of``) and the cap. A vehicle alongside counts: to use that lane ``front`` gets
    in behind it or passes it first (a CAV beside a 12.8 m/s truck, behind a 14.8 m/s car,
    took the truck's lane for free and slowed to 10 m/s to get in behind it)."""
    nearest: dict[int, VehicleState] = {}
    wanted = set(lanes)
    for other in others:
        if other.s_m <= front.rear_s_m or other.s_m - front.s_m > range_m:
            continue
        lane = road.lane_of(other)
        if lane in wanted and (lane not in nearest or other.s_m < nearest[lane].s_m):
            nearest[lane] = other
    speeds = {}
    for lane in lanes:
        lead = nearest.get(lane)
        speed = cap_mps if lead is None else min(cap_mps, max(lead.speed_mps, 0.0))
        if lead is not None and desired_of is not None:
            speed = min(speed, desired_of(lead))
        speeds[lane] = speed
    return speeds


def slow_vehicle_ahead(
    leader: VehicleState,
    others: Sequence[VehicleState],
    road: RoadSection,
    *,
    slow_below_mps: float,
    detect_range_m: float,
    cap_mps: float,
    min_gain_mps: float,
    width_m: float,
    accelerating_mps2: float = ACCELERATING_MPS2,
) -> VehicleState | None:
    """The vehicle holding the leader back, if it is one worth overtaking (else ``None``).

    It must be the nearest vehicle ahead in the leader's lane (by lateral overlap, so a vehicle
    in a neighbouring lane never qualifies), human-driven, within ``detect_range_m``, slower than
    ``slow_below_mps`` while the leader is too, slower than the cap by ``min_gain_mps``, and not
    accelerating harder than ``accelerating_mps2`` (getting up to speed, not slow).
    """
    ahead = vehicle_ahead(leader, others, road, width_m=width_m)
    if ahead is None:
        return None
    vehicle, gap = ahead
    if vehicle.is_cav or gap > detect_range_m:
        return None
    if vehicle.speed_mps >= slow_below_mps or leader.speed_mps >= slow_below_mps:
        return None
    if cap_mps - vehicle.speed_mps < min_gain_mps:
        return None
    if vehicle.lane != leader.lane:
        # In another lane, or still changing into the leader's: a car merging from a ramp is
        # slow only while it merges, it becomes a candidate (with persistence) once in the lane.
        return None
    if vehicle.accel_mps2 > accelerating_mps2:
        return None  # speeding up (e.g. after merging): not a slow vehicle
    return vehicle


def held_by(
    leader: VehicleState,
    others: Sequence[VehicleState],
    road: RoadSection,
    swarm: SwarmSettings,
    *,
    cruise_mps: float,
    cap_mps: float,
    width_m: float,
) -> VehicleState | None:
    """:func:`slow_vehicle_ahead` by the swarm's settings (``[swarm]``): slow below
    ``trigger_speed_ratio`` of ``cruise_mps``, within ``detect_range_m``, ``min_speed_gain_mps``
    below ``cap_mps``, not speeding up beyond ``accelerating_mps2``. One test for the decision
    and for where swarms form (controllers.fleet)."""
    return slow_vehicle_ahead(
        leader, others, road,
        slow_below_mps=cruise_mps * swarm.trigger_speed_ratio,
        detect_range_m=swarm.detect_range_m, cap_mps=cap_mps,
        min_gain_mps=swarm.min_speed_gain_mps, width_m=width_m,
        accelerating_mps2=swarm.accelerating_mps2,
    )  # fmt: skip


# A slow vehicle is only catching up when the vehicles ahead of it in its lane, this far [m] and
# at most this many, all want the trigger speed too (see only_catching_up).
CHAIN_AHEAD_M = 300.0
CHAIN_AHEAD_VEHICLES = 12


def only_catching_up(
    candidate: VehicleState,
    vehicles: Sequence[VehicleState],
    road: RoadSection,
    *,
    desired_of: Callable[[VehicleState], float],
    slow_below_mps: float,
    width_m: float,
    ahead_m: float = CHAIN_AHEAD_M,
) -> bool:
    """Is ``candidate`` slow only for now: it wants at least ``slow_below_mps`` (its model's
    desired speed, ``desired_of``), and so does every vehicle ahead of it in its lane within
    ``ahead_m`` (``[swarm] catching_up_ahead_m``; none holds the lane back for good)? Such a
    car speeds up on its own; it is not "persistently slower than the cruise" (a car at 18.9
    m/s, in a line of cars closing in on 19.7 m/s at IDM's slow pace, was overtaken by a swarm
    cruising at 20: stress scene 0).
    """
    ahead = candidate
    for _ in range(CHAIN_AHEAD_VEHICLES):
        if desired_of(ahead) < slow_below_mps:
            return False  # this one holds the lane back: a slow vehicle for good
        found = vehicle_ahead(ahead, vehicles, road, width_m=width_m)
        if found is None or found[0].s_m - candidate.s_m > ahead_m:
            return True
        ahead = found[0]
    return True


# SUMO's keep-right wish (LC2013 and SL2015) builds up over KEEP_RIGHT_TIME = 5 s at most: its
# keepRightProbability grows by at most threshold / 5 per second, and the wish shows once it
# passes the threshold (2 * lcKeepRight / lcSpeedGain, compared with probability * lcKeepRight).
KEEP_RIGHT_BUILD_S = 5.0


def keep_right_due_s(
    probability: float,
    before: tuple[float, float] | None,
    t_s: float,
    *,
    keep_right: float,
    speed_gain: float,
) -> float:
    """Seconds until a SUMO driver's keep-right wish shows, from its lane-change model's
    keepRightProbability now (``probability``, read at ``t_s``; its sign differs between
    LC2013 and SL2015, so only its size counts) and an earlier reading ``before`` = (time,
    probability), or None. The rate is the one seen between the two readings (at least 0.2 s
    apart), else the fastest the model builds it (over :data:`KEEP_RIGHT_BUILD_S`); inf when
    it is not building up, or the driver does not keep right (``keep_right`` = lcKeepRight 0).
    0 once it has shown."""
    if keep_right <= 0.0:
        return math.inf
    needed = 2.0 / max(speed_gain, 1e-6)  # the threshold over lcKeepRight, in the reading's units
    now = abs(probability)
    if now >= needed:
        return 0.0
    rate = needed * keep_right / KEEP_RIGHT_BUILD_S
    if before is not None and t_s - before[0] >= 0.2:
        rate = (now - abs(before[1])) / (t_s - before[0])
    return (needed - now) / rate if rate > 1e-9 else math.inf


def right_lane_free(
    target: VehicleState,
    others: Iterable[VehicleState],
    road: RoadSection,
    *,
    move_s: float,
    ahead_s: float,
    min_gap_m: float,
    secure_gap: Callable[[VehicleState, float], float],
    follower_gap: Callable[[VehicleState], float] | None = None,
) -> bool:
    """Will the lane to the right of ``target`` stay free for it to move into within
    ``move_s`` [s] (the time a keep-right driver takes to decide and move over)? Nothing there
    alongside it; every follower there, closing in at its speed for ``move_s``, still at least
    ``min_gap_m`` plus its ``secure_gap(follower, target speed)`` [m] behind it (SUMO lets a
    driver change lanes only in front of a follower at its secure gap); and nothing slower
    than it within ``ahead_s`` [s] at its speed ahead (moving over would gain it nothing).
    False where there is no lane to its right.

    With ``follower_gap`` (a follower's own minimum gap [m], as SUMO's check takes it, in
    place of ``min_gap_m``) a follower speeding up is judged as it will be when the target
    moves: closing in faster by its acceleration for ``move_s``, its secure gap at its speed
    then."""
    right = _right_lane(target, others, road, min_gap_m, secure_gap, follower_gap, move_s)
    return right is not None and _clear_at(
        target, 0.0, right, move_s=move_s, ahead_s=ahead_s, min_gap_m=min_gap_m
    )


def right_lane_opens_within(
    target: VehicleState,
    others: Iterable[VehicleState],
    road: RoadSection,
    *,
    within_s: float,
    step_s: float = 0.5,
    move_s: float,
    ahead_s: float,
    min_gap_m: float,
    secure_gap: Callable[[VehicleState, float], float],
) -> float | None:
    """The first time [s] from now, within ``within_s``, at which the lane to the right of
    ``target`` is free for it to move into (:func:`right_lane_free`), everyone driving on at
    constant speed (sampled every ``step_s``); None: not within, or no lane there. A stream
    passing a slow truck opens no gap a keep-right driver accepts (the follower's secure gap
    at 23 m/s behind 13 m/s is about 60 m): the lane opens when its last car has passed."""
    right = _right_lane(target, others, road, min_gap_m, secure_gap)
    if right is None:
        return None
    for k in range(int(within_s / step_s + 1e-9) + 1):
        t = k * step_s
        if _clear_at(target, t, right, move_s=move_s, ahead_s=ahead_s, min_gap_m=min_gap_m):
            return t
    return None


# A vehicle in the lane to the right of a target: front [m], length [m], speed [m/s], and the
# gap [m] it needs behind the target for the target to move in front of it.
_RightVehicle = tuple[float, float, float, float]


def _right_lane(
    target: VehicleState,
    others: Iterable[VehicleState],
    road: RoadSection,
    min_gap_m: float,
    secure_gap: Callable[[VehicleState, float], float],
    follower_gap: Callable[[VehicleState], float] | None = None,
    move_s: float = 0.0,
) -> list[_RightVehicle] | None:
    """The vehicles in the lane to the right of ``target`` (None: there is no such lane), the
    gap each needs judged as :func:`right_lane_free` says."""
    lane = road.lane_of(target)
    if lane <= 0:  # (beside the road, right of it: an acceleration lane)
        return None
    v = target.speed_mps
    right = []
    for o in others:
        if o.vehicle_id == target.vehicle_id or road.lane_of(o) != lane - 1:
            continue
        if follower_gap is None:
            right.append((o.s_m, o.length_m, o.speed_mps, min_gap_m + secure_gap(o, v)))
            continue
        speeding_up = max(0.0, o.accel_mps2) * move_s  # [m/s] more when the target moves
        then = replace(o, speed_mps=o.speed_mps + speeding_up) if speeding_up > 0.0 else o
        closer = 0.5 * speeding_up * move_s  # [m] closed in by speeding up meanwhile
        needed = follower_gap(o) + secure_gap(then, v) + closer
        right.append((o.s_m, o.length_m, o.speed_mps, needed))
    return right


def _clear_at(
    target: VehicleState,
    t_s: float,
    right: list[_RightVehicle],
    *,
    move_s: float,
    ahead_s: float,
    min_gap_m: float,
) -> bool:
    """:func:`right_lane_free` ``t_s`` [s] from now, everyone at constant speed."""
    v = target.speed_mps
    front = target.s_m + v * t_s
    rear = front - target.length_m
    for s_m, length_m, speed, needed_m in right:
        s_m += speed * t_s
        if s_m <= rear:  # behind it
            if rear - s_m - max(0.0, speed - v) * move_s < needed_m:
                return False
        elif s_m - length_m <= front + min_gap_m:  # alongside
            return False
        elif speed < v and s_m - length_m - front < min_gap_m + ahead_s * v:
            return False  # slower ahead there
    return True


def secure_gap_m(
    tau_s: float,
    decel_mps2: float,
    v_mps: float,
    v_lead_mps: float,
    lead_decel_mps2: float | None = None,
) -> float:
    """SUMO's secure gap [m] of a follower at ``v_mps`` (headway ``tau_s``, deceleration
    ``decel_mps2``) behind a leader at ``v_lead_mps`` that brakes at ``lead_decel_mps2`` (the
    deceleration SUMO assumes of it, its apparentDecel; None: the follower's): its headway
    distance plus its braking distance less the leader's (never negative; SUMO's
    ``vehicle.getSecureGap``)."""
    b = max(decel_mps2, 0.1)
    b_lead = b if lead_decel_mps2 is None else max(lead_decel_mps2, 0.1)
    return max(
        0.0, tau_s * v_mps + v_mps * v_mps / (2.0 * b) - v_lead_mps * v_lead_mps / (2.0 * b_lead)
    )


@dataclass
class TargetWatch:
    """Persistence of the overtaking decision, and the cool-down after a give-up."""

    trigger_after_s: float
    candidate_id: str | None = None
    since_s: float | None = None
    cooldown_until_s: float = -math.inf

    def update(
        self, t_s: float, candidate: VehicleState | None, wait_s: float = 0.0
    ) -> VehicleState | None:
        """The target once the same candidate has held the platoon back long enough
        (``trigger_after_s``, or ``wait_s`` [s] if longer)."""
        if candidate is None or t_s < self.cooldown_until_s:
            self.candidate_id = self.since_s = None
            return None
        if candidate.vehicle_id != self.candidate_id:
            self.candidate_id, self.since_s = candidate.vehicle_id, t_s
        if t_s - self.since_s + 1e-9 < max(self.trigger_after_s, wait_s):
            return None
        return candidate

    def cool_down(self, until_s: float) -> None:
        self.cooldown_until_s = until_s
        self.candidate_id = self.since_s = None


def stopped_blocking(
    target: VehicleState | None,
    changed_lane: bool,
    *,
    slow_below_mps: float,
) -> str | None:
    """Why the target no longer needs overtaking, or ``None``.

    ``"target_left"``: it is no longer in the simulation; ``"target_changed_lane"``: it moved to
    another lane (``changed_lane``: a lane change of its own, not a renumbering where a lane
    ends); ``"target_sped_up"``: it drives at the cruise again. Also with CAVs past it: the
    cruise then re-forms the platoon, and a CAV the target left stuck behind it (it moved into
    that CAV's lane) passes it on its own, where the plan, made for the old lane, kept it waiting.
    """
    if target is None:
        return "target_left"
    if changed_lane:
        return "target_changed_lane"
    if target.speed_mps >= slow_below_mps:
        return "target_sped_up"
    return None


@dataclass
class Progress:
    """How far a manoeuvre has come: CAVs past the target and rows gained on it."""

    started_s: float
    best_past: int = 0
    best_gain_m: float = -math.inf
    last_progress_s: float = -math.inf
    last_plan_ok_s: float = -math.inf

    def __post_init__(self) -> None:
        self.last_progress_s = self.started_s
        self.last_plan_ok_s = self.started_s

    best_out: int = 0
    failing: bool = False  # the replans since the last usable plan all failed
    stranding_plans: int = 0  # fresh plans in a row that leave CAVs behind the target for good
    waiting_plans: int = 0  # fresh plans in a row that keep every CAV behind it waiting
    stranded: frozenset[str] = frozenset()  # the CAVs the last of them left behind
    gain_step_m: float = GAIN_STEP_M

    def update(
        self, t_s: float, target: VehicleState, platoon: Sequence[VehicleState], min_gap_m: float
    ) -> None:
        """Progress is any of: more CAVs past the target, more CAVs out of its lane (cut
        through), or the CAVs still behind it closer to passing by ``gain_step_m`` in all.

        Only the CAVs still behind count for the gain: CAVs already past drifting away from a
        target at a few m/s looked like progress while the last CAV stayed stuck behind it
        (a stress scene held a stale plan for 27 s that way)."""
        line = target.s_m + min_gap_m
        past = sum(is_past(cav, target, min_gap_m) for cav in platoon)
        out = sum(cav.lane != target.lane and cav.rear_s_m < target.s_m for cav in platoon)
        # Gain [m]: how far the CAVs behind the target still are from passing it (negative),
        # summed, so that any one CAV closing in by gain_step_m counts.
        gain = sum(min(cav.rear_s_m - line, 0.0) for cav in platoon)
        closer = gain > self.best_gain_m + self.gain_step_m
        if past > self.best_past or out > self.best_out or closer:
            self.last_progress_s = t_s
            self.best_gain_m = max(self.best_gain_m, gain)
        self.best_past = max(self.best_past, past)
        self.best_out = max(self.best_out, out)

    def planned(self, t_s: float) -> None:
        self.last_plan_ok_s = t_s
        self.failing = False

    def plan_strands(self, stranded: Iterable[str], n_cavs: int) -> None:
        """A fresh plan leaves the CAVs ``stranded`` (of ``n_cavs``) behind the target for its
        whole horizon while it takes the others on (see :func:`stranded_cavs`). Plans count in
        a row while each strands at least the CAVs the one before did: a plan that finds a way
        for some of them is progress (a stress scene went from three stranded CAVs to one and
        then regrouped)."""
        now = frozenset(stranded)
        if not 0 < len(now) < n_cavs:
            self.stranding_plans, self.stranded = 0, frozenset()
            return
        keeps = self.stranding_plans > 0 and now >= self.stranded
        self.stranding_plans = self.stranding_plans + 1 if keeps else 1
        self.stranded = now

    def plan_waits(self, waiting: bool) -> None:
        """A fresh plan keeps (``waiting``) or does not keep every CAV still behind the
        target in its cell for a while (see :func:`waiting_plan`)."""
        self.waiting_plans = self.waiting_plans + 1 if waiting else 0

    def failed(self) -> None:
        """A replan failed (the last plan may still be driven while it lasts)."""
        self.failing = True

    def give_up_reason(
        self,
        t_s: float,
        no_progress_s: float,
        no_plan_s: float,
        has_plan: bool,
        partial_s: float | None = None,
        n_cavs: int | None = None,
        stranding_plans: int = 0,
        waiting_plans: int = 0,
    ) -> str | None:
        """``"no_progress"``, ``"no_feasible_plan"`` or ``"cavs_stranded"`` when it is time to
        give up: no plan, or only failed replans, for ``no_plan_s`` since the last usable one;
        no progress for ``no_progress_s``, or for ``partial_s`` once some but not all of the
        ``n_cavs`` CAVs have been past the target; ``stranding_plans`` fresh plans in a row
        (0: never) that leave some CAVs behind the target for good; ``"no_way_past"`` after
        ``waiting_plans`` fresh plans in a row (0: never) that keep them all waiting."""
        if (not has_plan or self.failing) and t_s - self.last_plan_ok_s > no_plan_s:
            return "no_feasible_plan"
        if stranding_plans > 0 and self.stranding_plans >= stranding_plans:
            return "cavs_stranded"
        if waiting_plans > 0 and self.waiting_plans >= waiting_plans:
            return "no_way_past"
        limit = no_progress_s
        if partial_s is not None and n_cavs is not None and 0 < self.best_past < n_cavs:
            limit = min(limit, partial_s)
        if t_s - self.last_progress_s > limit:
            return "no_progress"
        return None


def keeps_cell(cells: Sequence[Sequence[int]], steps: int | None = None) -> bool:
    """Does a CAV's planned cell sequence stay in its first cell (row and lane) for its first
    ``steps`` behaving steps (None, or a shorter sequence: to its end)?"""
    if not cells:
        return True
    first = tuple(cells[0])
    stretch = cells if steps is None else cells[: steps + 1]
    return all(tuple(cell) == first for cell in stretch)


def is_past(cav: VehicleState, target: VehicleState, min_gap_m: float) -> bool:
    """Is ``cav``'s rear ahead of ``target``'s front by ``min_gap_m``?"""
    return cav.rear_s_m >= target.s_m + min_gap_m


def cavs_behind(target: VehicleState, cavs: Iterable[VehicleState], min_gap_m: float) -> list[str]:
    """Ids of the CAVs not yet past ``target`` (:func:`is_past`)."""
    return [cav.vehicle_id for cav in cavs if not is_past(cav, target, min_gap_m)]


def stranded_cavs(cells: Mapping[str, Sequence[Sequence[int]]], behind: Iterable[str]) -> set[str]:
    """The CAVs of ``behind`` (still behind the target) that a plan keeps in their cell, row and
    lane, for its whole horizon: the planner found no way past for them."""
    return {vid for vid in behind if vid in cells and keeps_cell(cells[vid])}


def waiting_plan(
    cells: Mapping[str, Sequence[Sequence[int]]], behind: Iterable[str], steps: int
) -> bool:
    """Does a plan keep every CAV of ``behind`` (still behind the target) in its cell, row and
    lane, for its first ``steps`` behaving steps (or its whole horizon, if shorter)? With none
    behind, it does not wait."""
    planned = [cells[vid] for vid in behind if vid in cells]
    return bool(planned) and all(keeps_cell(seq, steps) for seq in planned)


# A platoon again: bumper gaps between consecutive CAVs up to this many desired gaps
# (summary.json's "regrouped", sumo_swarm.sim.summary and .streamed).
REGROUPED_GAP_FACTOR = 2.5


def passing_lane(
    target: VehicleState, cavs: Sequence[VehicleState], road: RoadSection, *, tolerance_m: float
) -> int | None:
    """The lane every CAV of ``cavs`` is settled in (centre within ``tolerance_m`` of that
    lane's), when it is one lane and not the target's; else ``None``."""
    if not cavs:
        return None
    lanes = set()
    for cav in cavs:
        y = road.y_of(cav.lane, cav.lat_m)
        lane = road.lane_of_y(y)
        if not 0 <= lane < road.n_lanes or abs(y - road.lane_centre_y(lane)) > tolerance_m:
            return None
        lanes.add(lane)
    if len(lanes) != 1:
        return None
    lane = lanes.pop()
    return None if lane == road.lane_of(target) else lane


def lane_pass_pace(
    target_mps: float,
    cells_mps: float,
    *,
    cruise_mps: float,
    min_gain_mps: float,
    rule: str,
) -> float:
    """The speed [m/s] a lane beside must beat by ``min_gain_mps`` for a lane pass
    (:func:`lane_for_pass`). ``"cells"``: the cell plan's pace past the target (its speed plus
    ``cells_mps``, one cell per behaving interval). ``"free"``: the lower of that and the cruise
    less the gain (no lower than the target): a lane free at the cruise takes the platoon past
    together."""
    cells = target_mps + cells_mps
    if rule == "cells":
        return cells
    return min(cells, max(target_mps, cruise_mps - min_gain_mps))


def lane_for_pass(
    leader: VehicleState,
    tail: VehicleState,
    target: VehicleState,
    others: Sequence[VehicleState],
    road: RoadSection,
    lanes: Sequence[int],
    *,
    n_cavs: int,
    cell_length_m: float,
    range_m: float,
    cap_mps: float,
    cruise_mps: float,
    pace_mps: float,
    min_gain_mps: float,
    tolerance_m: float,
    desired_of: Callable[[VehicleState], float] | None = None,
    free_pace_mps: float | None = None,
) -> int | None:
    """The lane of ``lanes`` (beside the leader) the platoon moves over to and passes
    ``target`` in, or None (the cells): its speed ahead of the leader (:func:`lane_speeds`, at
    most ``cruise_mps``) beats the cells' pace past the target (``pace_mps``; in a lane with no
    HV beside the platoon or coming up faster within ``range_m`` behind its tail,
    ``free_pace_mps`` where given) by ``min_gain_mps``; it has room for the platoon (within
    ``range_m`` of its ends, ``n_cavs`` cells per vehicle there; denser lanes: the cells make
    room, blocking); it is not the lane the target is moving into (its centre more than
    ``tolerance_m`` off its lane's).
    Ties go to the left, passing side (SUMO numbers lanes from the right). ``others``: the
    HVs. (With the free pace for every lane, a car at 17.5 m/s coming up beside the platoon
    made the CAVs brake to 12 m/s to let it by and follow it: stress scene 184.)"""
    here = road.lane_of(leader)
    candidates = list(lanes)
    if abs(target.lat_m) > tolerance_m:
        heading = road.lane_of(target)
        heading += 1 if target.lat_m > 0.0 else -1
        candidates = [q for q in candidates if q != heading]
    speeds = lane_speeds(leader, others, road, candidates, range_m=range_m, cap_mps=cap_mps,
                         desired_of=desired_of)  # fmt: skip
    lo, hi = tail.rear_s_m - range_m, leader.s_m + range_m
    need = n_cavs * cell_length_m
    for q in list(speeds):
        n = sum(
            1 for o in others
            if lo < o.centre_s_m < hi and road.lane_of(o) == q
        )  # fmt: skip
        if n > 0 and (hi - lo) / n < need:
            del speeds[q]
    if not speeds:
        return None
    if free_pace_mps is None:
        free_pace_mps = pace_mps
    # Free: no HV beside the platoon, nor one coming up behind it within range_m (faster than
    # its tail; the truck just passed, behind and slower, leaves the lane free).
    busy = {
        road.lane_of(o) for o in others
        if lo < o.s_m < leader.s_m and (o.s_m > tail.rear_s_m or o.speed_mps > tail.speed_mps)
    }  # fmt: skip

    def gain(q: int) -> float:
        return min(speeds[q], cruise_mps) - (pace_mps if q in busy else free_pace_mps)

    best = max(speeds, key=lambda q: (gain(q) >= min_gain_mps, speeds[q], q > here))
    return best if gain(best) >= min_gain_mps else None


@dataclass
class LanePass:
    """A pass in a faster lane under way (:func:`lane_for_pass`): the CAVs out of the target's
    lane or past it, counted as progress."""

    target_id: str
    lane: int
    since_s: float
    done: int = 0  # CAVs out of the target's lane or past it, the most so far
    done_s: float = 0.0  # ...since when [s]

    def __post_init__(self) -> None:
        self.done_s = self.since_s

    def update(
        self,
        t_s: float,
        target: VehicleState | None,
        cavs: Sequence[VehicleState],
        road: RoadSection,
        *,
        min_gap_m: float,
        stall_s: float,
    ) -> str | None:
        """``"completed"`` (every CAV past the target), ``"target_left"``, ``"stalled"`` (a CAV
        is still in the target's lane behind it and none got out of that lane or past it for
        ``stall_s``: the cells take over), or None (going on)."""
        if target is None:
            return "target_left"
        behind = set(cavs_behind(target, cavs, min_gap_m))
        if not behind:
            return "completed"
        lane = road.lane_of(target)
        done = sum(
            1 for c in cavs
            if c.vehicle_id not in behind or road.lane_of(c) != lane
        )  # fmt: skip
        if done > self.done or done == len(cavs):  # every CAV out of its lane: passing it
            self.done, self.done_s = done, t_s
        elif t_s - self.done_s > stall_s:
            return "stalled"
        return None


# A cruising leader slows by at most this [m/s] to let a stretched platoon close up, and by up
# to REGROUP_EASE_MPS when no HV follows it in its lane (nobody is held back; a platoon capped
# at the cruise by its vType kept a 25 m hole for the rest of the run without the ease).
MAX_LEADER_EASE_MPS = 2.0
REGROUP_EASE_MPS = 5.0


def leader_ease_cap(
    states: Mapping[str, VehicleState],
    platoon: Sequence[str],
    road: RoadSection,
    *,
    width_m: float,
    reach_m: float,
    ease_mps: float,
    regroup_ease_mps: float,
    everyone: Snapshot | None = None,
) -> float:
    """How much [m/s] the cruising leader (``platoon[0]``) may slow to let a stretched platoon
    close up: ``regroup_ease_mps`` when every CAV is in the leader's lane with nobody else
    between them, and what follows the leader there is a CAV of the platoon or nothing within
    ``reach_m`` (no HV held back; a CAV stuck behind a truck elsewhere does not come closer
    when the leader slows); ``ease_mps`` otherwise. ``everyone``: ``states`` as a
    :class:`Snapshot` (only the vehicles between the tail and the leader are then looked at)."""
    if regroup_ease_mps <= ease_mps or not platoon:
        return ease_mps
    leader, tail = states[platoon[0]], states[platoon[-1]]
    lane = road.lane_of(leader)
    if any(road.lane_of(states[v]) != lane for v in platoon):
        return ease_mps
    members = set(platoon)
    if everyone is None:
        between = [v for v in states.values() if tail.s_m < v.s_m < leader.s_m]
    else:
        between = everyone[bisect_right(everyone.s, tail.s_m) : bisect_left(everyone.s, leader.s_m)]
    for vehicle in between:
        if vehicle.vehicle_id not in members and road.lane_of(vehicle) == lane:
            return ease_mps
    behind = vehicle_behind(leader, states.values() if everyone is None else everyone, road,
                            width_m=width_m)  # fmt: skip
    if behind is None or behind[1] > reach_m or behind[0].vehicle_id in members:
        return regroup_ease_mps
    return ease_mps


def straggler_cruise(
    states: Mapping[str, VehicleState],
    platoon: Sequence[str],
    road: RoadSection,
    *,
    cruise_mps: float,
    cap_mps: float,
    desired_gap_m: float,
    k_close: float,
    slow_below_mps: float,
    reach_m: float,
    width_m: float,
) -> dict[str, float]:
    """Cruising speed [m/s] of each CAV of ``platoon`` that has fallen back from the platoon
    CAV just ahead of it (by position) while that CAV drives in another lane: the cruise plus
    ``k_close`` per metre of bumper gap beyond ``desired_gap_m``, at most ``cap_mps``. The
    CACC closes such a gap only behind a CAV in its own lane: a CAV that got past a truck
    last, in the lane beside the platoon's, drove on 150 m behind it at the very speed of the
    platoon and never caught up (stress scene 40, paper-scene variant 24). Not a CAV with an
    HV slower than ``slow_below_mps`` ahead of it in its lane within ``reach_m``: it would
    only close in on that vehicle, taking the room a CAV merging in front of it needs (stress
    scene 69: a CAV rushed up behind the truck where the CAV beside it was to get in). It
    still follows whatever drives ahead of it in its lane."""
    out: dict[str, float] = {}
    order = sorted(platoon, key=lambda v: states[v].s_m, reverse=True)
    for front, back in itertools.pairwise(order):
        f, b = states[front], states[back]
        if road.lane_of(f) == road.lane_of(b):
            continue
        excess = f.rear_s_m - b.s_m - desired_gap_m
        if excess <= 0.0:
            continue
        ahead = vehicle_ahead(b, states.values(), road, width_m=width_m)
        slow = ahead is not None and not ahead[0].is_cav and ahead[0].speed_mps < slow_below_mps
        if slow and ahead[1] <= reach_m:
            continue  # a slow HV ahead: it would only close in on that
        out[back] = max(cruise_mps, min(cap_mps, cruise_mps + k_close * excess))
    return out


def all_past(target: VehicleState, platoon: Mapping[str, VehicleState], min_gap_m: float) -> bool:
    """Every CAV's rear is ahead of the target's front by ``min_gap_m``."""
    return not cavs_behind(target, platoon.values(), min_gap_m)
