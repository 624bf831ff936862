"""Who is ahead of whom: pure look-ups over a snapshot of vehicle states (no SUMO import)."""

from __future__ import annotations

import operator
from bisect import bisect_left, bisect_right
from collections.abc import Iterable, Mapping

from sumo_swarm.core.model import RoadSection, VehicleState

VEHICLE_WIDTH_M = 1.8  # lateral extent used for overlap tests [m]
# A human-driven vehicle this far off its lane centre is changing lanes [m]; it counts as
# overlapping over a band CUT_IN_EXTRA_WIDTH_M wider [m], so that a CAV reacts to it before it
# is in its lane (in the stress sweep HVs cutting in ahead of CAVs made gaps of 2.2 m).
CUT_IN_LAT_M = 0.3
CUT_IN_EXTRA_WIDTH_M = 1.2
# ...while it moves faster than this [m/s]. One standing still off its lane centre is not
# cutting in (it cannot come in ahead without moving): it counts by its body only. SUMO held a
# car at the end of an acceleration lane 0.4-0.8 m off its centre for minutes; the CAV behind
# it in the lane beside took it for a leader cutting in, stood 4.7 m behind it, and the
# merge never happened: the whole on-ramp jammed (corridor, 20 % CAVs at 1800 veh/h/lane).
CUT_IN_MIN_SPEED_MPS = 0.5
# Half of SUMO's lateral resolution as the swarm runs it (0.5 m sublanes) [m]
SUBLANE_MARGIN_M = 0.25


def lateral_overlap(a_y: float, b_y: float, width_m: float = VEHICLE_WIDTH_M) -> bool:
    """True when two vehicles whose centres are at ``a_y`` and ``b_y`` overlap laterally."""
    return abs(a_y - b_y) < width_m


class Snapshot(list[VehicleState]):
    """The vehicles of one step sorted by position, with their lateral positions on ``road``:
    the look-ups below scan outward from ego's position and stop once nothing further can be
    nearer, instead of testing every vehicle (the guards ask several times per CAV and step).
    A plain list of the same vehicles gives the same answers, only slower. ``ordered``: the
    same vehicles already sorted (one table seen on several roads is sorted once)."""

    def __init__(
        self,
        vehicles: Iterable[VehicleState],
        road: RoadSection,
        ordered: _Ordered | None = None,
    ) -> None:
        if ordered is None:
            ordered = _Ordered(vehicles)
        super().__init__(ordered.vehicles)
        self.road = road
        self.s = ordered.s
        self.y = road.ys_of(ordered.lanes, ordered.lats)
        self.max_length_m = ordered.max_length_m


class _Ordered:
    """Vehicles sorted by position, their positions, lanes and lateral offsets: what a
    :class:`Snapshot` needs that does not depend on the road."""

    __slots__ = ("lanes", "lats", "max_length_m", "s", "vehicles")

    def __init__(self, vehicles: Iterable[VehicleState]) -> None:
        self.vehicles = sorted(vehicles, key=_S_OF)
        self.s = [v.s_m for v in self.vehicles]
        self.lanes = [v.lane for v in self.vehicles]
        self.lats = [v.lat_m for v in self.vehicles]
        self.max_length_m = max((v.length_m for v in self.vehicles), default=0.0)


_S_OF = operator.attrgetter("s_m")

# Snapshots made by snapshot_of, by the identity of the states table and the road they were
# made of; each entry holds both (so that no later table can take their ids while it is kept)
# and the table's vehicles as they were. _ORDERED: the same per table, whatever the road.
_SNAPSHOTS: dict[tuple[int, int], tuple[Mapping, RoadSection, tuple, Snapshot]] = {}
_ORDERED: dict[int, tuple[Mapping, tuple, _Ordered]] = {}
_SNAPSHOTS_KEPT = 64  # a step's tables (one per platoon and lane numbering), then emptied


def _same(seen: tuple, states: Mapping[str, VehicleState]) -> bool:
    return len(seen) == len(states) and all(map(operator.is_, seen, states.values()))


def snapshot_of(states: Mapping[str, VehicleState], road: RoadSection) -> Snapshot:
    """``Snapshot(states.values(), road)``, made once per states table and road while the
    table holds the same vehicle states: a platoon's cruise, decision, plan following and
    CACC all ask for one of the same table in a step, and each sorted every vehicle of the
    road again (a corridor's 600, for each of 20 platoons). A table changed in place since (a
    vehicle dropped, added or given a new state) gets a new one. A table asked for on several
    roads (one per CAV's edge in a membership review) is sorted once."""
    key = (id(states), id(road))
    entry = _SNAPSHOTS.get(key)
    if entry is not None and entry[0] is states and entry[1] is road and _same(entry[2], states):
        return entry[3]
    if len(_SNAPSHOTS) >= _SNAPSHOTS_KEPT:
        _SNAPSHOTS.clear()
        _ORDERED.clear()
    seen = tuple(states.values())
    known = _ORDERED.get(id(states))
    if known is not None and known[0] is states and _same(known[1], states):
        ordered = known[2]
    else:
        ordered = _Ordered(seen)
        _ORDERED[id(states)] = (states, seen, ordered)
    snap = Snapshot(seen, road, ordered)
    _SNAPSHOTS[key] = (states, road, seen, snap)
    return snap


class PassSnapshots:
    """:func:`snapshot_of` for one pass over tables that do not change during it (a step's
    safety net, a membership review): each table and road checked once, then found by
    identity (checking that a corridor's table of 600 vehicles still held the same states, at
    each of a step's thousands of asks, was most of what the snapshots cost)."""

    def __init__(self) -> None:
        self._made: dict[tuple[int, int], tuple[Mapping, RoadSection, Snapshot]] = {}

    def __call__(self, states: Mapping[str, VehicleState], road: RoadSection) -> Snapshot:
        key = (id(states), id(road))
        entry = self._made.get(key)
        if entry is None:  # the entry holds the table and road: their ids stay theirs
            entry = self._made[key] = (states, road, snapshot_of(states, road))
        return entry[2]


def _band(width_m: float, other: VehicleState) -> float:
    """Lateral distance [m] of centres under which ``other`` counts as overlapping: both
    half-widths (a truck is wider than a car) and SUMO's sublane granularity (with the sublane
    model a vehicle occupies every sublane it touches, so SUMO sees a leader, and brakes for
    it, a little before the two bodies overlap); wider for a moving HV drifting off its lane
    centre (cutting in)."""
    band = 0.5 * (width_m + other.width_m) + SUBLANE_MARGIN_M
    if (
        not other.is_cav
        and abs(other.lat_m) > CUT_IN_LAT_M
        and other.speed_mps > CUT_IN_MIN_SPEED_MPS
    ):
        band += CUT_IN_EXTRA_WIDTH_M
    return band


def _nearest_sorted(
    ego: VehicleState, snap: Snapshot, ego_y: float, width_m: float, ahead: bool
) -> tuple[VehicleState, float] | None:
    ego_s, ego_id = ego.s_m, ego.vehicle_id
    s, y = snap.s, snap.y
    best: tuple[VehicleState, float] | None = None
    if ahead:
        reach = snap.max_length_m  # a rear bumper is at most this far behind its front
        for j in range(bisect_right(s, ego_s), len(s)):
            if best is not None and s[j] - reach - ego_s >= best[1]:
                break  # every vehicle from here on has its rear further ahead than best's
            other = snap[j]
            if other.vehicle_id == ego_id or not abs(ego_y - y[j]) < _band(width_m, other):
                continue
            gap = other.rear_s_m - ego_s
            if best is None or gap < best[1]:
                best = (other, gap)
        return best
    ego_rear = ego.rear_s_m
    for j in range(bisect_left(s, ego_s) - 1, -1, -1):  # fronts nearest first
        other = snap[j]
        if other.vehicle_id == ego_id or not abs(ego_y - y[j]) < _band(width_m, other):
            continue
        return other, ego_rear - s[j]
    return None


def _nearest(
    ego: VehicleState,
    others: Iterable[VehicleState],
    road: RoadSection,
    y_m: float | None,
    width_m: float,
    ahead: bool,
) -> tuple[VehicleState, float] | None:
    # Called several times per CAV and step over every vehicle around: locals, and the cheap
    # longitudinal test first.
    ego_y = road.y_of(ego.lane, ego.lat_m) if y_m is None else y_m
    if isinstance(others, Snapshot) and others.road is road:
        return _nearest_sorted(ego, others, ego_y, width_m, ahead)
    ego_s, ego_id = ego.s_m, ego.vehicle_id
    y_of = road.y_of
    best: tuple[VehicleState, float] | None = None
    for other in others:
        s = other.s_m
        if s == ego_s or (s > ego_s) != ahead or other.vehicle_id == ego_id:
            continue
        if not abs(ego_y - y_of(other.lane, other.lat_m)) < _band(width_m, other):
            continue
        gap = other.rear_s_m - ego_s if ahead else ego.rear_s_m - s
        if best is None or gap < best[1]:
            best = (other, gap)
    return best


def vehicle_ahead(
    ego: VehicleState,
    others: Iterable[VehicleState],
    road: RoadSection,
    y_m: float | None = None,
    width_m: float = VEHICLE_WIDTH_M,
) -> tuple[VehicleState, float] | None:
    """Nearest vehicle ahead of ``ego`` that overlaps it laterally, with the bumper gap [m].

    ``y_m`` overrides ego's lateral position (e.g. the position it is moving to), so the
    swarm can check the lane it is entering too.
    """
    return _nearest(ego, others, road, y_m, width_m, ahead=True)


def overlapping_ahead(
    ego: VehicleState,
    others: Snapshot,
    road: RoadSection,
    y_m: float,
    width_m: float,
    reach_m: float,
) -> list[tuple[VehicleState, float]]:
    """Every vehicle whose front is ahead of ``ego``'s, less than ``reach_m`` [m] ahead, that
    overlaps ego placed at ``y_m`` laterally as :func:`vehicle_ahead` counts it, with its bumper
    gap [m]: not only the nearest (an HV cutting in ahead of a CAV hid the CAV braking hard
    behind it). The nearest of them is :func:`vehicle_ahead`'s."""
    lo, hi = bisect_right(others.s, ego.s_m), bisect_left(others.s, ego.s_m + reach_m)
    found = []
    for j in range(lo, hi):
        other = others[j]
        if other.vehicle_id != ego.vehicle_id and abs(y_m - others.y[j]) < _band(width_m, other):
            found.append((other, other.rear_s_m - ego.s_m))
    return found


def within(others: Iterable[VehicleState], s_m: float, reach_m: float) -> list[VehicleState]:
    """The vehicles of ``others`` whose front is less than ``reach_m`` from ``s_m``, in the
    order of ``others`` (of a :class:`Snapshot`: a slice found by bisection)."""
    if isinstance(others, Snapshot):
        lo, hi = bisect_right(others.s, s_m - reach_m), bisect_left(others.s, s_m + reach_m)
        return others[lo:hi]
    return [o for o in others if abs(o.s_m - s_m) < reach_m]


def cav_alongside_behind(
    ego: VehicleState,
    others: Iterable[VehicleState],
    road: RoadSection,
    y_m: float,
    width_m: float = VEHICLE_WIDTH_M,
) -> VehicleState | None:
    """The CAV whose front is beside ``ego`` (between ego's rear bumper and its front) and
    that overlaps ``ego`` moved to ``y_m``, the front-most if several: to :func:`vehicle_ahead`
    it is neither ahead nor behind."""
    found = None
    for other in others:
        if not other.is_cav or other.vehicle_id == ego.vehicle_id:
            continue
        if not ego.rear_s_m < other.s_m <= ego.s_m:
            continue
        y = road.y_of(other.lane, other.lat_m)
        beside = lateral_overlap(y, y_m, 0.5 * (width_m + other.width_m))
        if beside and (found is None or other.s_m > found.s_m):
            found = other
    return found


def vehicle_behind(
    ego: VehicleState,
    others: Iterable[VehicleState],
    road: RoadSection,
    y_m: float | None = None,
    width_m: float = VEHICLE_WIDTH_M,
) -> tuple[VehicleState, float] | None:
    """Nearest vehicle behind ``ego`` overlapping it laterally (at ``y_m``), with the gap [m]."""
    return _nearest(ego, others, road, y_m, width_m, ahead=False)


def ordered_platoon(states: Mapping[str, VehicleState], cav_ids: Iterable[str]) -> list[str]:
    """CAV ids present in ``states``, front-most first."""
    present = [v for v in cav_ids if v in states]
    return sorted(present, key=lambda v: -states[v].s_m)
