"""Safety checks applied to every command of the swarm, whatever the plan says (pure).

Both guards look at the lanes a CAV overlaps now and the one it is moving into, through the
shared neighbour look-up (:mod:`sumo_swarm.core.neighbours`), so an HV that is changing lanes
towards a CAV counts early.

* :func:`gap_accel_limit` caps the acceleration so that no CAV closes within its minimum gap
  of whatever is ahead.
* :func:`lateral_refusal` holds a lateral move into another lane while the vehicle ahead there
  is closer than the minimum gap, or the follower there would have to brake harder than
  ``b_safe`` by its own car-following model (:mod:`sumo_swarm.core.hvmodel`): the same model the
  planner uses for its entry margins, so the guard refuses only what the plan did not foresee.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

from sumo_swarm.checks import check_fields
from sumo_swarm.core.hvmodel import DriverModel, accepts_entry
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.neighbours import vehicle_ahead, vehicle_behind, within
from sumo_swarm.core.stepsafe import net_applies


@dataclass(frozen=True)
class GuardSettings:
    """Gains and thresholds of the guards (scenario section ``[guards]``).

    Attributes
    ----------
    gap_gain
        Gap guard gain on the gap error [1/s²].
    speed_gain
        Gap guard gain on the speed difference [1/s].
    gap_extra_m
        The gap guard aims this far beyond the minimum gap [m].
    lane_probe_m
        A lateral move enters the next lane once the CAV's side would be this far across [m].
    match_gain
        Gain of the speed matching before entering a faster lane [1/s].
    follower_range_m
        An HV this close behind makes a CAV brake gently [m].
    side_clearance_m
        A lateral move never brings a CAV's side closer than this to a vehicle alongside (0: off)
        [m].
    follower_lat_gap_m
        A vehicle behind that a lateral move brings within this of the CAV's side is judged as a
        follower (0: off) [m].
    feedforward_from_mps2
        The gap guard feeds forward a leader's braking beyond this [m/s²].
    lane_follower_reach_m
        The lateral guard looks for the entered lane's follower this far behind the CAV [m].
    clearing_mps
        A CAV yields to a swarm CAV still in the lane it enters when that CAV clears it by at least
        this speed [m/s].
    """

    gap_gain: float = 0.8
    speed_gain: float = 1.5
    gap_extra_m: float = 1.0
    lane_probe_m: float = 0.9
    match_gain: float = 1.0
    follower_range_m: float = 60.0
    side_clearance_m: float = 0.3
    follower_lat_gap_m: float = 0.6
    feedforward_from_mps2: float = 0.6
    lane_follower_reach_m: float = 150.0
    clearing_mps: float = 0.5

    def __post_init__(self) -> None:
        check_fields(self, *(f.name for f in dataclasses.fields(self)), ge=0.0)

    def gap_gains(self, step_s: float) -> tuple[float, float]:
        """``(gap gain, speed gain)`` of the gap guard at SUMO steps of ``step_s`` [s].

        The guard's law is a continuous one: the gap error obeys e'' + speed_gain e' +
        gap_gain e = 0. Applied once per SUMO step (a speed held for the step, SUMO's Euler
        update), its loop has the characteristic polynomial z^2 + (k_v dt + k_g dt^2 - 2) z +
        (1 - k_v dt); at 1 s the given gains put a root at -0.87, and a column of CAVs
        amplified every dip 19-fold from one CAV to the next (the 12-CAV variants' tail
        stopped, the drivers behind it braked beyond 4 m/s^2). At steps longer than the CAVs'
        tau (:func:`~sumo_swarm.core.stepsafe.net_applies`) the gains are those whose loop has
        the continuous law's poles s mapped to exp(s dt) (pole matching); at shorter steps the
        given gains, which they approach as dt -> 0 (7 % apart at 0.1 s: the paper's runs as
        they are).
        """
        if not net_applies(step_s):
            return self.gap_gain, self.speed_gain
        half = 0.5 * self.speed_gain
        disc = self.gap_gain - half * half
        root = math.sqrt(abs(disc)) * step_s
        turn = math.cos(root) if disc >= 0.0 else math.cosh(root)
        decay = math.exp(-half * step_s)
        total, product = 2.0 * decay * turn, decay * decay  # of the discrete poles
        return (1.0 - total + product) / step_s**2, (1.0 - product) / step_s


DEFAULT = GuardSettings()


def entering_lane(
    road: RoadSection, y: float, dlat: float, settings: GuardSettings = DEFAULT
) -> int | None:
    """The lane a lateral move ``dlat`` [m] from ``y`` [m] enters (its side within
    ``settings.lane_probe_m`` of the next lane), or ``None`` if it stays in its lane."""
    if abs(dlat) < 1e-6:
        return None
    lane_next = road.lane_of_y(y + dlat + math.copysign(settings.lane_probe_m, dlat))
    return None if lane_next == road.lane_of_y(y) else lane_next


# Fronts within this of ego's front are looked at for the side clearance [m] (a 25 m truck
# alongside a 5 m CAV).
ALONGSIDE_REACH_M = 40.0


def too_close_alongside(
    ego: VehicleState,
    y: float,
    dlat: float,
    others: Sequence[VehicleState],
    road: RoadSection,
    width_m: float,
    clearance_m: float,
) -> bool:
    """Would the lateral move ``dlat`` [m] from ``y`` bring ego's side closer than
    ``clearance_m`` to a vehicle alongside it (bodies overlapping lengthwise, within
    ``clearance_m``), on the side it moves to and closer than before? The lane guards look at
    the next lane only once ego's side nears it; an HV straddling the boundary (SUMO's sublane
    drivers stop half-way through a lane change they cannot finish) was hit by a CAV moving
    within its own lane."""
    if abs(dlat) < 1e-9 or clearance_m <= 0.0:
        return False
    ego_front, ego_rear = ego.s_m, ego.rear_s_m
    for other in within(others, ego.s_m, ALONGSIDE_REACH_M):
        if other.vehicle_id == ego.vehicle_id:
            continue
        if other.rear_s_m > ego_front + clearance_m or other.s_m < ego_rear - clearance_m:
            continue
        if _side_gap_falls_below(other, y, dlat, road, width_m, clearance_m):
            return True
    return False


def _side_gap_falls_below(
    other: VehicleState, y: float, dlat: float, road: RoadSection, width_m: float, limit_m: float
) -> bool:
    """Does the move ``dlat`` [m] from ``y`` bring ego's side (``width_m`` wide) below
    ``limit_m`` from ``other``'s, on the side it moves to, and closer than before?"""
    y_other = road.y_of(other.lane, other.lat_m)
    if (y_other - y) * dlat <= 0.0:
        return False  # on the other side
    half = 0.5 * (width_m + other.width_m)
    after = abs(y_other - (y + dlat)) - half
    return after < limit_m and after < abs(y_other - y) - half


def follower_beside(
    ego: VehicleState,
    y: float,
    dlat: float,
    others: Sequence[VehicleState],
    road: RoadSection,
    width_m: float,
    lat_gap_m: float,
) -> tuple[VehicleState, float] | None:
    """The nearest vehicle behind ego (its front behind ego's front, within
    ``ALONGSIDE_REACH_M``: alongside it too), on the side ego moves to, that the move ``dlat``
    [m] from ``y`` brings within ``lat_gap_m`` of ego's side, closer than before, with its
    bumper gap [m] (negative alongside: SUMO's driver would see ego as a leader it overlaps).
    """
    if abs(dlat) < 1e-9 or lat_gap_m <= 0.0:
        return None
    found = None
    for other in within(others, ego.s_m, ALONGSIDE_REACH_M):
        if other.vehicle_id == ego.vehicle_id or other.s_m > ego.s_m:
            continue
        if found is not None and other.s_m <= found.s_m:
            continue
        if _side_gap_falls_below(other, y, dlat, road, width_m, lat_gap_m):
            found = other
    return None if found is None else (found, ego.rear_s_m - found.s_m)


def _hv_behind_straddling_cav(
    ego: VehicleState,
    y: float,
    dlat: float,
    cav: VehicleState,
    others: Sequence[VehicleState],
    road: RoadSection,
    width_m: float,
    settings: GuardSettings,
) -> tuple[VehicleState, float] | None:
    """The HV behind ego in the lane the move ``dlat`` enters, with its bumper gap to ego [m],
    when the follower found there is ``cav``, a CAV whose centre is not in that lane: the HV
    behind it does not see it as its leader (it only leans in), it sees ego, whose side goes
    deeper. (A CAV at its lane's edge, 9 m ahead of an HV at 20 m/s, was taken as the follower;
    the CAV ahead of it moved in at 17 m/s and the HV braked at 4.8 m/s^2: stress scene 17.)
    None when ``cav`` is in that lane (the HV behind it follows it) or no HV is behind."""
    lane_next = entering_lane(road, y, dlat, settings)
    if lane_next is None or road.lane_of(cav) == lane_next:
        return None
    hvs = [o for o in within(others, ego.s_m, settings.follower_range_m) if not o.is_cav]
    return vehicle_behind(ego, hvs, road, y_m=road.lane_centre_y(lane_next), width_m=width_m)


def _next_lane_neighbours(
    ego: VehicleState,
    y: float,
    dlat: float,
    others: Iterable[VehicleState],
    road: RoadSection,
    width_m: float,
    settings: GuardSettings,
) -> tuple[tuple[VehicleState, float] | None, tuple[VehicleState, float] | None] | None:
    """(vehicle ahead, vehicle behind) of ``ego`` in the lane the move ``dlat`` enters, each
    with its bumper gap [m], or ``None`` when the move stays in ``ego``'s lane."""
    lane_next = entering_lane(road, y, dlat, settings)
    if lane_next is None:
        return None
    others = others if isinstance(others, list) else list(others)
    y_probe = road.lane_centre_y(lane_next)
    return (
        vehicle_ahead(ego, others, road, y_m=y_probe, width_m=width_m),
        vehicle_behind(ego, others, road, y_m=y_probe, width_m=width_m),
    )


def gap_accel_limit(
    ego: VehicleState,
    y_now: float,
    y_next: float,
    others: Iterable[VehicleState],
    road: RoadSection,
    min_gap_m: float,
    width_m: float,
    settings: GuardSettings = DEFAULT,
    step_s: float = 0.0,
    speeds_now: Mapping[str, float] | None = None,
) -> float:
    """Largest acceleration [m/s^2] that keeps ``min_gap_m`` to whatever is ahead at ``y_now``
    or ``y_next`` (``math.inf`` with nothing ahead), for a SUMO step of ``step_s`` [s] (0: the
    continuous law; see :meth:`GuardSettings.gap_gains`).

    ``speeds_now`` are speeds [m/s] already commanded for this step (CAVs ahead, commanded
    first): at steps longer than the CAVs' tau a leader among them is taken at the speed it
    drives this step, not the one it drove the last. Reacting a whole step late, a follower
    dips deeper than its leader; with the leader's step speed and the matched gains one CAV
    passes a dip on at most 1.07-fold (1.2-fold at the paper's 0.1 s step)."""
    others = others if isinstance(others, list) else list(others)
    gap_gain, speed_gain = settings.gap_gains(step_s)
    if speeds_now is None or not net_applies(step_s):
        speeds_now = {}
    limit = math.inf
    for y in {y_now, y_next}:
        ahead = vehicle_ahead(ego, others, road, y_m=y, width_m=width_m)
        if ahead is None:
            continue
        lead, gap = ahead
        d = min_gap_m + settings.gap_extra_m
        # Plus the leader's braking beyond feedforward_from_mps2, as it happens: behind a
        # leader braking hard the gap would otherwise shrink for a moment below the minimum
        # (4.99 m seen); milder braking (dawdling, speed keeping) is left to the gains, which a
        # full feedforward made so cautious that the paper scene stalled with noisy states; the
        # part left to them is bounded so that they keep the minimum gap (see the setting).
        lead_mps = speeds_now.get(lead.vehicle_id)
        if lead_mps is None:
            lead_mps, lead_accel = lead.speed_mps, lead.accel_mps2
        else:  # its braking this step (the last step's is in the speed it drives now)
            lead_accel = (lead_mps - lead.speed_mps) / step_s
        feedforward = min(0.0, lead_accel + settings.feedforward_from_mps2)
        limit = min(
            limit, gap_gain * (gap - d) + speed_gain * (lead_mps - ego.speed_mps) + feedforward
        )
    return limit


# A CAV decelerating harder than this [m/s^2] as it moves over is braking for something (its
# lane's leader), not easing off: the lateral guard takes it to brake on to a stop.
BRAKING_MPS2 = 1.0


def _travelled(v0: float, brake: float, v_floor: float, t: float) -> float:
    """Distance [m] driven in ``t`` [s] from ``v0`` [m/s], braking at ``brake`` [m/s^2] down to
    ``v_floor`` [m/s] and holding it."""
    if brake <= 0.0 or v0 <= v_floor:
        return v0 * t
    t_floor = (v0 - v_floor) / brake
    if t <= t_floor:
        return v0 * t - 0.5 * brake * t * t
    return (v0 * v0 - v_floor * v_floor) / (2.0 * brake) + v_floor * (t - t_floor)


def gap_lost(
    follower_mps: float, follower_brake: float, ego_mps: float, ego_brake: float, ego_end_mps: float
) -> float:
    """The most [m] a follower's gap to ego shrinks while ego slows from ``ego_mps`` to
    ``ego_end_mps`` at ``ego_brake`` [m/s^2] (0: it keeps its speed) and the follower brakes at
    ``follower_brake`` [m/s^2] from ``follower_mps`` to no slower than ego ends. The gap shrinks
    while the follower is faster: the most is where their speeds meet (exact, piecewise)."""
    floor = min(follower_mps, ego_end_mps)
    t_ego = (ego_mps - ego_end_mps) / ego_brake if ego_brake > 0.0 else 0.0
    times = [(follower_mps - floor) / follower_brake]  # the follower down to ego's end speed
    if follower_brake != ego_brake:
        t = (follower_mps - ego_mps) / (follower_brake - ego_brake)  # equal while ego slows
        if 0.0 < t < t_ego:
            times.append(t)
    lost = (
        _travelled(follower_mps, follower_brake, floor, t)
        - _travelled(ego_mps, ego_brake, ego_end_mps, t)
        for t in times
    )
    return max(0.0, *lost)


def lateral_refusal(
    ego: VehicleState,
    y: float,
    dlat: float,
    others: Iterable[VehicleState],
    road: RoadSection,
    *,
    min_gap_m: float,
    width_m: float,
    model_of: Callable[[str], DriverModel],
    b_safe_mps2: float,
    step_s: float,
    settings: GuardSettings = DEFAULT,
    brake_mps2: float = 4.0,
    ego_accel_mps2: float = 0.0,
    ego_final_mps: float | None = None,
) -> str | None:
    """Why the lateral move ``dlat`` [m] from ``y`` [m] must be held, or ``None`` if it is safe.

    ``ego_accel_mps2`` > 0: ego is committed to speed up at that rate to ``ego_final_mps`` once
    it moves (a CAV entering a faster lane; the caller makes it do so): the HV follower reacts
    to that, and closing in on the leader is judged at ``ego_final_mps``.

        Reasons: ``"leader"`` (the vehicle ahead in the new lane is closer than ``min_gap_m``
        plus what closing in on it at ``b_safe_mps2``, or stopping behind it at
        ``brake_mps2``, takes),
        ``"follower_gap"`` (the follower there, a CAV or an HV, is closer than ``min_gap_m``;
        a CAV closing in, closer than ``min_gap_m`` plus what it needs to stop closing at
        ``b_safe_mps2``),
        ``"follower_brake"`` (the HV following there would brake harder than ``b_safe_mps2`` at
    some point of its reaction, :func:`sumo_swarm.core.hvmodel.accepts_entry`),
        ``"alongside"`` (a vehicle alongside, whatever lane it is in, would be closer to ego's
        side than ``settings.side_clearance_m`` after the move: an HV straddling the lane
        boundary; checked for moves within ego's own lane too). A vehicle behind that the
        move brings within ``settings.follower_lat_gap_m`` of ego's side
        (:func:`follower_beside`) is judged as a follower, in whatever lane it is.
    """
    if not isinstance(others, list):  # a Snapshot is a list: its look-ups stay fast
        others = list(others)
    if too_close_alongside(ego, y, dlat, others, road, width_m, settings.side_clearance_m):
        return "alongside"
    near = _next_lane_neighbours(ego, y, dlat, others, road, width_m, settings)
    ahead, behind = (None, None) if near is None else near
    if behind is None:  # within its lane, or nobody behind there: one leaning in from beside
        behind = follower_beside(ego, y, dlat, others, road, width_m, settings.follower_lat_gap_m)
    if ahead is not None:
        # Closing in on it, the CAV must be able to stop closing within the minimum gap braking
        # no harder than b_safe (the gap it enters with is what it keeps), and to stop behind it
        # braking at most ``brake_mps2`` should it stop (SUMO's safe speed, which brakes at the
        # vType's decel the moment the CAV's body enters the lane).
        v, v_lead = ego.speed_mps, ahead[0].speed_mps
        if ego_accel_mps2 > 0.0 and ego_final_mps is not None:
            v = max(v, ego_final_mps)
        closing = max(0.0, v - v_lead)
        need = max(
            closing * closing / (2.0 * max(b_safe_mps2, 0.1)),
            (v * v - v_lead * v_lead) / (2.0 * max(brake_mps2, 0.1)),
        )
        if ahead[1] < min_gap_m + need:
            return "leader"
    if behind is None:
        return None
    follower, gap = behind
    if follower.is_cav:
        # A CAV follower cooperates, but only within its own braking: closing in faster than
        # b_safe can absorb above the minimum gap, it would brake hard (a CAV slowing to drop
        # in behind another cut in 10 m ahead of a CAV 4.7 m/s faster: -4 m/s^2, gap 4.5 m).
        # Judged against what ego will do once in the lane, not its speed now: close in on the
        # leader there, and, braking as it moves over, maybe brake on to a stop for what it
        # leaves behind (a CAV braking at 4 m/s^2 for a truck standing in its lane moved over
        # 20 m ahead of a CAV 5.6 m/s faster, stayed across both lanes and braked on; the CAV
        # behind ran into it).
        v_end, ego_brake = ego.speed_mps, 0.0
        if ego_accel_mps2 <= 0.0:
            if ahead is not None and ahead[0].speed_mps < ego.speed_mps:
                v_end = ahead[0].speed_mps
                room = max(ahead[1] - min_gap_m, 0.1)
                ego_brake = min(brake_mps2, (ego.speed_mps - v_end) ** 2 / (2.0 * room))
            if ego.accel_mps2 < -BRAKING_MPS2:
                v_end, ego_brake = 0.0, max(ego_brake, -ego.accel_mps2)
        lost = gap_lost(follower.speed_mps, max(b_safe_mps2, 0.1), ego.speed_mps, ego_brake, v_end)
        if gap < min_gap_m + lost:
            return "follower_gap"
        behind = _hv_behind_straddling_cav(ego, y, dlat, follower, others, road, width_m, settings)
        if behind is None:
            return None
        follower, gap = behind
    entry = (ego, model_of, min_gap_m, b_safe_mps2, step_s, ego_accel_mps2, ego_final_mps)
    why = _follower_refusal(follower, gap, *entry)
    if why is not None:
        return why
    # The nearest vehicle behind is not always the lane's follower: an HV of ego's own lane
    # leaning towards the next one counts as overlapping it, nearer, and hid the HV of that
    # lane behind it, which braked at 9 m/s^2 (paper-scene variant 24: a CAV cut in 24 m
    # ahead of it, 8.5 m/s slower). That HV must accept the entry too.
    lane_next = entering_lane(road, y, dlat, settings)
    reach = settings.lane_follower_reach_m
    own = None if lane_next is None else _behind_in_lane(ego, others, road, lane_next, reach)
    if own is None or own[0] is follower or own[0].is_cav:
        return None
    return _follower_refusal(*own, *entry)


def _follower_refusal(
    hv: VehicleState,
    gap: float,
    ego: VehicleState,
    model_of: Callable[[str], DriverModel],
    min_gap_m: float,
    b_safe_mps2: float,
    step_s: float,
    ego_accel_mps2: float,
    ego_final_mps: float | None,
) -> str | None:
    """``"follower_gap"`` or ``"follower_brake"`` if the HV ``hv``, ``gap`` [m] behind ego,
    refuses ego's entry (:func:`lateral_refusal`), else None."""
    if gap < min_gap_m:
        return "follower_gap"
    model = model_of(hv.vehicle_id)
    if accepts_entry(model, hv.speed_mps, ego.speed_mps, gap, b_safe_mps2, step_s,
                     lead_accel_mps2=ego_accel_mps2, lead_final_mps=ego_final_mps):  # fmt: skip
        return None
    return "follower_brake"


def _behind_in_lane(
    ego: VehicleState, others: list[VehicleState], road: RoadSection, lane: int, reach_m: float
) -> tuple[VehicleState, float] | None:
    """The nearest vehicle behind ``ego`` (within ``reach_m`` of its front) whose centre is in
    ``lane``, with the bumper gap."""
    best: tuple[VehicleState, float] | None = None
    for other in within(others, ego.s_m, reach_m):
        if other.vehicle_id == ego.vehicle_id or other.s_m >= ego.s_m:
            continue
        if road.lane_of(other) != lane:
            continue
        gap = ego.rear_s_m - other.s_m
        if best is None or gap < best[1]:
            best = (other, gap)
    return best


def yields_to_cav(
    ego: VehicleState,
    y: float,
    dlat: float,
    others: Iterable[VehicleState],
    road: RoadSection,
    *,
    min_gap_m: float,
    width_m: float,
    settings: GuardSettings = DEFAULT,
) -> str | None:
    """The swarm CAV ``ego`` waits for before entering the next lane, or ``None``.

    Within a behaving interval two CAVs' cells may swap in time: one moves into a lane that
    another CAV still occupies alongside and is leaving, faster ahead or slower behind (the plan
    has them one row apart at the interval's end). Entering waits until that CAV is clear by
    ``min_gap_m``; that is the tracker's timing, below the planner's resolution, not a move the
    guard refuses (the guard still checks the move once the CAV is clear)."""
    near = _next_lane_neighbours(ego, y, dlat, others, road, width_m, settings)
    ahead, behind = (None, None) if near is None else near
    if behind is None:  # within its lane, or nobody behind there: one leaning in from beside
        behind = follower_beside(ego, y, dlat, others, road, width_m, settings.follower_lat_gap_m)
    clearing = settings.clearing_mps
    if ahead is not None:
        lead, gap = ahead
        if lead.is_cav and gap < min_gap_m and lead.speed_mps >= ego.speed_mps + clearing:
            return lead.vehicle_id
    if behind is not None:
        back, gap = behind
        if back.is_cav and gap < min_gap_m and back.speed_mps <= ego.speed_mps - clearing:
            return back.vehicle_id
    return None


def lane_speed_match(
    ego: VehicleState,
    lane: int,
    others: Iterable[VehicleState],
    road: RoadSection,
    width_m: float,
    cap_mps: float,
    settings: GuardSettings = DEFAULT,
) -> float:
    """Acceleration [m/s^2] towards the speed of the HV that will follow ``ego`` in ``lane``
    (up to ``cap_mps``), when ``ego`` is about to move into that lane in front of a faster HV;
    ``-inf`` (no demand) otherwise. A CAV that enters at the lane's speed needs a much smaller
    gap than one that enters slower (:func:`sumo_swarm.core.hvmodel.min_block_gap`)."""
    if lane == road.lane_of(ego):
        return -math.inf
    behind = vehicle_behind(ego, others, road, y_m=road.lane_centre_y(lane), width_m=width_m)
    if behind is None or behind[0].is_cav or behind[0].speed_mps <= ego.speed_mps:
        return -math.inf
    return settings.match_gain * (min(behind[0].speed_mps, cap_mps) - ego.speed_mps)


def gentle_for_follower(
    ego: VehicleState,
    others: Iterable[VehicleState],
    road: RoadSection,
    width_m: float,
    decel_mps2: float,
    settings: GuardSettings = DEFAULT,
) -> float:
    """Lowest acceleration [m/s^2] allowed with an HV close behind in ``ego``'s lane:
    ``-decel_mps2`` (so it brakes gently too), ``-inf`` with no such HV. The gap guard, for
    what is ahead, still overrides it."""
    behind = vehicle_behind(ego, others, road, width_m=width_m)
    if behind is None or behind[0].is_cav or behind[1] > settings.follower_range_m:
        return -math.inf
    return -decel_mps2


RUN_UP_STEP_MPS = 1.0  # entry speeds a run-up tries, this far apart [m/s]


def run_up(
    v_mps: float,
    slow_speed_mps: float,
    gap_m: float,
    lane_speed_mps: float,
    *,
    desired_gap_m: float,
    accel_mps2: float,
    brake_mps2: float,
    change_s: float,
    min_gain_mps: float,
    entry_ok: Callable[[float, float], bool],
) -> tuple[str, float]:
    """What a CAV refused a lane change out of a slow vehicle's lane does next: ``("run",
    v_enter)`` (accelerate towards ``v_enter``: a gap in the next lane will take it at that
    speed), ``("brake", a)`` (closing in on the slow vehicle too fast for the room left: brake
    at ``a`` < 0) or ``("hold", 0)`` (no gap takes it: keep the run-up distance).

    ``gap_m``: bumper gap to the slow vehicle ahead at ``slow_speed_mps``; ``lane_speed_mps``:
    the next lane's speed, the most worth entering at. The room above ``desired_gap_m`` must
    hold, at the closing speed c, the lane change (c * ``change_s``: the CAV still shares the
    slow vehicle's lane meanwhile) and a stop of the closing braking at ``brake_mps2``: entry
    speeds from the highest that fits down to ``min_gain_mps`` above the slow vehicle, each
    reached at ``accel_mps2`` (less room than that: drop back further).
    ``entry_ok(v_enter, tau)``: would the guard take the CAV at ``v_enter`` in ``tau`` [s]?"""
    room = gap_m - desired_gap_m
    closing = v_mps - slow_speed_mps
    if closing > 0.0 and room < closing * change_s + closing * closing / (2.0 * brake_mps2):
        return "brake", -min(brake_mps2, closing * closing / (2.0 * max(room, 0.5)))
    # Largest closing speed c with c * change_s + c^2 / (2 b) <= room.
    b = brake_mps2
    c_max = b * (math.sqrt(change_s * change_s + 2.0 * max(room, 0.0) / b) - change_s)
    v_enter = min(lane_speed_mps, slow_speed_mps + c_max)
    lowest = slow_speed_mps + min_gain_mps  # slower entries are the guard's own business
    if v_enter < lowest - 1e-9:
        return "hold", 0.0
    if v_enter <= v_mps:
        return ("run", v_mps) if entry_ok(v_mps, 0.0) else ("hold", 0.0)
    # The fastest entry first, then slower ones (a gap may come by before the CAV is at its
    # fastest), RUN_UP_STEP_MPS apart, down to ``min_gain_mps`` above the slow vehicle.
    v = v_enter
    while v > max(v_mps, lowest - 1e-9):
        if entry_ok(v, (v - v_mps) / accel_mps2):
            return "run", v
        v -= RUN_UP_STEP_MPS
    return "hold", 0.0
