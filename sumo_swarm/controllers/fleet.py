"""Many swarms in one simulation: CAVs held by a slow vehicle form a platoon, each a swarm.

A :class:`Fleet` stands where one controller stood (the run loop and the plugin API call it
after every SUMO step). It groups the CAVs into platoons (``[platoons]``, see
:class:`~sumo_swarm.config.PlatoonSettings`) and gives every platoon a controller of its own,
made by ``make`` (a :class:`~sumo_swarm.controllers.swarm.SwarmController`, or the CACC
baseline): each decides, overtakes and regroups on its own.

- **A swarm lives while acting together pays.** CAVs that meet in a lane form a platoon only
  where a slow vehicle holds the column of CAVs they drive in (its front CAV, by the decider's
  own test, :func:`~sumo_swarm.core.swarming.decision.held_by`): there is
  something to decide together. The swarm weighs what it can do
  (:mod:`~sumo_swarm.core.swarming.arbiter`), each CAV on its own among it; where nothing the
  CAVs do together pays (it would follow, wait for the slow vehicle to leave its lane, or each
  CAV does better on its own), the platoon
  parts: each CAV drops back to the gap SUMO wants ahead of it and SUMO drives it alone
  (:meth:`Fleet._open_gaps`), in no platoon for the decision's horizon. A platoon that started
  nothing and is held by nothing for ``trigger_after_s`` parts too. A platoon that passed
  and regrouped (the paper's end) cruises on as one. On the corridor checks
  (tools/corridor_checks.py) platoons formed wherever CAVs met gave 78 of 112 checks; formed
  and parted so, 91 (CAVs never in a platoon: 95, but then no swarm ever passes a truck on
  the users' roads).

- **Each swarm sees only its own CAVs as CAVs.** Its session is a :class:`PlatoonSession`: the
  CAVs of other platoons, and CAVs in no platoon, are vehicles like the human-driven ones (the
  planner keeps their cells free, the guards judge a lane change in front of them by their
  driver model, none is ever assumed to cooperate). A CAV of another swarm that follows a plan
  is predicted from that plan (``RunContext.planned_paths``, asked for when a swarm plans), not
  from a car-following model.
- **Two manoeuvres never share the road.** A swarm starts an overtake only where no other
  swarm's manoeuvre is under way within ``[platoons] manoeuvre_clearance_m`` of its last CAV
  and target (``RunContext.may_start``, asked for when it decides, so a swarm that started
  earlier in the same step counts): the cell grids of two swarms never overlap, so they never
  plan into the same cell.
- **CAVs in no platoon** (on a ramp, in an acceleration lane, approaching their exit, or off
  the route frame) drive as SUMO drives them: SUMO's lane changes for their route, and, once
  they have been in a platoon, our CACC for the speed (handed over at the platoon's short gap,
  SUMO's own car-following would brake hard to open its gap; :class:`RouteWatch` does the
  same for a CAV that leaves a platoon for its exit).

Membership is reviewed every ``review_every_s``: platoons that meet merge, a free CAV joins the
platoon it meets, a platoon strung out beyond ``split_gap_m`` or grown beyond ``max_size``
splits. Only platoons that cruise change (a platoon in an overtake keeps its CAVs), except
that a CAV approaching its exit, leaving the route frame or gone leaves at once.

A CAV alone is no swarm: cooperation starts at two. The swarm controller says so
(``alone_to_sumo``): a lone CAV is driven by SUMO (its lane changes for speed, keeping right and
letting merging traffic in, with SUMO's own safety checks at any step length), braking at most
4 m/s^2 and keeping at least SUMO's default gaps (tau 1 s, minGap 2.5 m: the swarm's own vType
has a short headway meant for its commands, with which lone CAVs jammed an on-ramp merge),
until it meets another CAV in its lane. On the corridor checks (tools/corridor_checks.py, 16
runs) a swarm of one gave 49 of 112 checks and 2 collisions, a CAV left to SUMO 72 of 112 and
none. (The ``cacc`` baseline keeps a platoon of one in its lane.)
The summary's ``swarms`` block counts as platoons only groups that
had two CAVs or more.
"""

from __future__ import annotations

import functools
import itertools
import math
from array import array
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Protocol

from sumo_swarm.config import PlatoonSettings
from sumo_swarm.controllers.base import (
    CavSpeeds,
    Controller,
    RouteWatch,
    RunContext,
    close_controller,
)
from sumo_swarm.controllers.cacc import command_cacc
from sumo_swarm.controllers.replanner import PlanStats
from sumo_swarm.controllers.session import ALONE_DECEL_MPS2, STANDING_MPS, SessionView
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.neighbours import (
    PassSnapshots,
    ordered_platoon,
    overlapping_ahead,
    snapshot_of,
    vehicle_ahead,
)
from sumo_swarm.core.stats import lateral_rms, summarise_ms
from sumo_swarm.core.swarming.account import (
    manoeuvres_from_events,
    overtake_counts,
    overtake_outcome,
)
from sumo_swarm.core.swarming.decision import held_by
from sumo_swarm.core.swarming.planlog import PlanLog

if TYPE_CHECKING:
    from sumo_swarm.controllers.replanner import BlockWatch

__all__ = [
    "Fleet",
    "PlatoonSession",
    "SwarmMember",
    "can_follow",
    "in_lane_neighbours",
    "may_join",
    "opening_accel",
    "straddled",
    "strung_out",
]


# --------------------------------------------------------------------------- pure parts


@dataclass(frozen=True)
class Placed:
    """Where a vehicle is, for grouping: its lane in one numbering along the route frame."""

    vehicle_id: str
    s_m: float  # front bumper along the route frame [m]
    length_m: float
    lane: int  # lane index in the frame's common numbering (across lane drops and ramps)


def in_lane_neighbours(vehicles: Iterable[Placed]) -> list[tuple[str, str, float]]:
    """Every pair of vehicles directly behind one another in a lane, as ``(rear, front, gap)``
    with the bumper-to-bumper gap [m]; nothing drives between them in that lane."""
    by_lane: dict[int, list[Placed]] = {}
    for v in vehicles:
        by_lane.setdefault(v.lane, []).append(v)
    pairs = []
    for lane in by_lane.values():
        lane.sort(key=lambda v: v.s_m)
        for rear, front in itertools.pairwise(lane):
            pairs.append((rear.vehicle_id, front.vehicle_id, front.s_m - front.length_m - rear.s_m))
    return pairs


# A CAV joins the CAV ahead of it only where it can follow it braking at most this much
# [m/s^2], keeping JOIN_MIN_GAP_M [m]: a lone CAV (SUMO's) closing at 18 m/s on a CAV standing
# at an acceleration lane's end was taken into its platoon 40 m behind it, and the platoon's
# braking (at most 4 m/s^2) could not stop it in time.
JOIN_DECEL_MPS2 = 3.0
JOIN_MIN_GAP_M = 2.0
# ...and only where both drive centred in their lane, within this [m]: SUMO may have a CAV it
# drives alone off-centre, squeezing past a truck half across the lane line; taken into a
# platoon 0.4 m off-centre, the swarm's tracker centred it into the truck's side at 31.7 m/s.
JOIN_LATERAL_M = 0.2
# A CAV whose platoon parted drops back to SUMO's gap this much slower than the vehicle
# ahead [m/s], braking at most this much for it [m/s^2] (:meth:`Fleet._open_gaps`).
OPEN_RATE_MPS = 1.5
OPEN_DECEL_MPS2 = 2.0
# ...and is handed over once at most this much above the speed SUMO drives it at [m/s] (SUMO
# brakes the rest at once: 1 m/s^2 at a 0.1 s step).
HANDOVER_MPS = 0.1


def can_follow(rear_mps: float, front_mps: float, gap_m: float) -> bool:
    """Can a vehicle at ``rear_mps`` follow one at ``front_mps`` ``gap_m`` [m] ahead, braking
    at most JOIN_DECEL_MPS2 and keeping JOIN_MIN_GAP_M (the front one holding its speed)?"""
    closing = max(0.0, rear_mps * rear_mps - front_mps * front_mps) / (2.0 * JOIN_DECEL_MPS2)
    return gap_m - closing >= JOIN_MIN_GAP_M


def may_join(rear: VehicleState, front: VehicleState, gap_m: float) -> bool:
    """May CAV ``rear`` join CAV ``front``, ``gap_m`` [m] ahead of it in its lane: can it follow
    it (:func:`can_follow`), both centred in their lane (JOIN_LATERAL_M)?"""
    centred = abs(rear.lat_m) <= JOIN_LATERAL_M and abs(front.lat_m) <= JOIN_LATERAL_M
    return centred and can_follow(rear.speed_mps, front.speed_mps, gap_m)


def straddled(ego: VehicleState, others: Iterable[VehicleState], road: RoadSection) -> bool:
    """Does a vehicle of another lane reach into CAV ``ego``'s lane ahead of it (ego centred,
    as a platoon drives it) closer than ego can follow it (:func:`can_follow`)? A platoon does
    not take such a CAV over: SUMO drove one past a CAV straddling the lane line, 10 m/s faster
    and 3 m behind it; taken into a platoon and centred, it could no longer brake for it when
    that one completed its lane change (corridor, 20 % CAVs). The vehicle ahead in ego's own
    lane is the platoon's to follow (:func:`may_join`)."""
    ahead = vehicle_ahead(ego, others, road, y_m=road.y_of(ego.lane, 0.0), width_m=ego.width_m)
    if ahead is None or road.lane_of(ahead[0]) == road.lane_of(ego):
        return False
    return not can_follow(ego.speed_mps, ahead[0].speed_mps, ahead[1])


def strung_out(
    members: list[str], states: Mapping[str, VehicleState], split_gap_m: float, max_size: int
) -> list[list[str]]:
    """``members`` (any order) cut into platoons, front first: a cut where two CAVs next to each
    other along the road (any lane) are more than ``split_gap_m`` apart, and after every
    ``max_size`` CAVs."""
    ordered = ordered_platoon(states, members)
    parts: list[list[str]] = []
    for vid in ordered:
        if parts:
            last = states[parts[-1][-1]]
            gap = last.rear_s_m - states[vid].s_m
            if gap <= split_gap_m and len(parts[-1]) < max_size:
                parts[-1].append(vid)
                continue
        parts.append([vid])
    return parts


def opening_accel(
    speed_mps: float, desired_mps: float, lead: tuple[float, float] | None, min_gap_m: float
) -> float:
    """Acceleration [m/s^2] of a CAV handed from a platoon to SUMO, before SUMO drives it:
    down to ``desired_mps`` (SUMO's speed for it) and to OPEN_RATE_MPS below the vehicle
    ahead (``lead``: its speed [m/s] and the gap to it [m]; None: none), braking at most
    OPEN_DECEL_MPS2 for either (one second's worth of the difference), and as much more as
    not closing in below ``min_gap_m`` needs (safety first); never speeding up (SUMO does)."""
    accel = max(min(desired_mps - speed_mps, 0.0), -OPEN_DECEL_MPS2)
    if lead is None:
        return accel
    lead_mps, gap_m = lead
    closing = speed_mps - lead_mps
    need = closing * closing / (2.0 * max(gap_m - min_gap_m, 0.1)) if closing > 0.0 else 0.0
    drop = max(min(lead_mps - OPEN_RATE_MPS - speed_mps, 0.0), -OPEN_DECEL_MPS2)
    return min(accel, drop, -need)


# --------------------------------------------------------------------------- the swarms


class SwarmMember(Controller, Protocol):
    """What the fleet asks of each platoon's controller (the swarm controller offers it)."""

    alone_to_sumo: bool  # a CAV alone is driven by SUMO, not as a swarm of one
    may_part: bool  # set by the fleet: it may find that nothing together pays (below)
    nothing_pays: bool  # ...and has: the fleet hands its CAVs back to SUMO
    target_id: str | None  # the target of its manoeuvre (None: none yet)
    t_start_s: float | None  # when its first manoeuvre started [s] (None: none yet)
    routes: RouteWatch  # its CAVs whose routes part leave it
    blocks: BlockWatch  # the HVs its plans blocked, with their strongest braking
    stats: PlanStats  # its planning calls (the summary's planner block sums every swarm's)
    planlog: Any  # where it writes its plans (plans.jsonl), or None
    drawer: Any  # a sumo-gui plan drawer, or None

    def idle(self) -> bool:
        """Cruising with no manoeuvre of its own under way: its CAVs may change."""
        ...

    def forget(self, vid: str) -> None:
        """CAV ``vid`` left it."""
        ...

    def dissolve(self, t_s: float) -> None:
        """It has no CAV left: what it had under way ends."""
        ...

    def tracking_samples(self) -> tuple[list[float], list[float]]:
        """(lateral tracking errors [m], MPC solve times [ms]) of its CAVs so far."""
        ...

    def planned_paths(self) -> Mapping[str, Callable[[float], float]]:
        """Its CAVs' planned front positions s(t) [m] while a plan is in force."""
        ...

    def manoeuvre_region(self, t_s: float) -> tuple[float, float] | None:
        """The stretch of road [m] its manoeuvre takes now (None: it cruises)."""
        ...

    def use_planlog(self, planlog: Any) -> None:
        """Write its plans to ``planlog`` (shared by every swarm); before ``attach``."""
        ...

    def fallback(self, t_s: float) -> None:
        """Its step after the swarms stood down (CACC in its lanes)."""
        ...

    def manoeuvres(self) -> list[dict[str, Any]]:
        """Its manoeuvres (the summary's list)."""
        ...


# --------------------------------------------------------------------------- the views


class _Same:
    """A name of :class:`SessionView` a platoon's view passes on to the session unchanged."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, view: PlatoonSession | None, owner: type | None = None) -> Any:
        if view is None:
            return self
        return getattr(view._session, self.name)


class PlatoonSession:
    """A platoon's view of the SUMO session (:class:`SessionView`): the session itself, except
    that in :attr:`states` (and :meth:`states_in_lanes_of`) only the platoon's own CAVs are
    CAVs (``is_cav``); every other CAV is a vehicle like the human-driven ones. Every other
    name is the session's own, each passed on by name."""

    time_s = _Same()
    step_length_s = _Same()
    cav_ids = _Same()
    departed = _Same()
    arrived = _Same()
    kinds = _Same()
    released = _Same()
    frame = _Same()
    edges = _Same()
    lane_positions = _Same()
    exists = _Same()
    road_at = _Same()
    lanes_ending = _Same()
    near_lane_shift = _Same()
    driver_model = _Same()
    speed_limits = _Same()
    route_of = _Same()
    distance_to_parting_m = _Same()
    lane_change_need = _Same()
    standing_s = _Same()
    keeps_right = _Same()
    wants_right = _Same()
    lane_wish = _Same()
    must_change = _Same()
    keep_right_due_s = _Same()
    set_speed = _Same()
    flush_commands = _Same()
    release_speed = _Same()
    change_sublane = _Same()
    set_modes = _Same()
    configure_cav = _Same()
    restore_gaps = _Same()
    release = _Same()
    drive_alone = _Same()
    alone_gap_m = _Same()
    reclaim = _Same()
    miss_exit = _Same()

    def __init__(self, session: SessionView, fleet: Fleet, members: frozenset[str]) -> None:
        self._session = session
        self._fleet = fleet
        self.members = members

    @property
    def states(self) -> dict[str, VehicleState]:
        return self._fleet.view(self.members)

    def states_in_lanes_of(self, vid: str) -> dict[str, VehicleState]:
        return self._fleet.view(self.members, self._session.states_in_lanes_of(vid))


@dataclass
class Platoon:
    """One platoon and the controller that drives it."""

    id: int
    controller: SwarmMember
    ctx: RunContext
    session: PlatoonSession
    members: list[str]
    counted: bool = False  # has had two CAVs or more (a platoon in the summary's count)

    def set_members(self, members: list[str], states: Mapping[str, VehicleState]) -> None:
        self.members = ordered_platoon(states, members) + [v for v in members if v not in states]
        self.ctx.cav_ids = tuple(self.members)
        self.session.members = frozenset(self.members)

    @property
    def idle(self) -> bool:
        """Cruising, no manoeuvre of its own under way: its CAVs may change."""
        return bool(self.controller.idle())


@dataclass
class FleetCounts:
    """What the platoons came to over the run (the summary's ``swarms`` block)."""

    formed: int = 0
    max_concurrent: int = 0
    swarms: int = 0  # every swarm, lone CAVs included
    joins: int = 0
    merges: int = 0
    splits: int = 0
    parted: int = 0  # platoons handed back to SUMO: nothing they did together paid
    # (swarm, target) of overtakes held back by another swarm's manoeuvre nearby
    deferred_for: set[tuple[int | None, str]] = field(default_factory=set)
    blocked_min: dict[str, float] = field(default_factory=dict)


# --------------------------------------------------------------------------- the fleet


class Fleet:
    """Many platoons, each driven by its own controller from ``make``; see the module."""

    def __init__(self, make: Callable[[], SwarmMember], name: str | None = None) -> None:
        self._make = make
        self._kind = make()  # never attached: what the platoons' controllers offer
        self.name = name or self._kind.name
        self.ctx: RunContext | None = None
        self.settings: PlatoonSettings | None = None
        self.platoons: list[Platoon] = []
        self.counts = FleetCounts()
        self.planlog = None  # one plans.jsonl for every swarm (the swarm controller's)
        self.drawer = None  # a sumo-gui plan drawer (sim.gui), given to the first swarm
        self._next_id = 0
        self._reviewed_s = -math.inf
        self._first: Platoon | None = None  # whose overtake block the summary shows
        self._first_summary: dict[str, Any] | None = None  # ... kept when it ended
        self._view_source: dict[str, VehicleState] | None = None  # the table _views are of
        self._relabelled: dict[str, tuple[VehicleState, VehicleState]] = {}
        # (table, view) by (the table's id, members): each entry holds its table, so no later
        # table can take its id while the entry is kept (one step)
        self._views: dict[tuple[int, frozenset[str]], tuple[dict, dict[str, VehicleState]]] = {}
        self._handed: set[str] = set()  # CAVs once in a platoon, now free: CACC for the speed
        self._plan_stats = PlanStats()  # the planning calls of the swarms retired
        self._lat_errors = array("d")  # ... their CAVs' lateral tracking errors [m]
        self._mpc_ms = array("d")  # ... and their MPC solve times [ms]
        self._off_frame: set[str] = set()  # ... that left the route frame: SUMO drives them
        self._single: SwarmMember | None = None  # grouping = "one"
        self._parted: set[str] = set()  # CAVs whose exit came near: no platoon again
        self._alone: set[str] = set()  # CAVs left to SUMO alone, their braking limited
        self._apart_until: dict[str, float] = {}  # CAVs parted: no platoon until then [s]
        self._free_since: dict[int, float] = {}  # platoons held by nothing since [s]
        self._opening: set[str] = set()  # CAVs parted, opening their gap to SUMO's
        self._to_sumo: set[str] = set()  # CAVs the fleet gave SUMO to drive (drive_alone)

    # ------------------------------------------------------------------ set-up
    def attach(self, ctx: RunContext) -> None:
        self.ctx = ctx
        self.settings = ctx.scenario.platoons
        if self.settings.grouping == "one":
            self._single = self._make()
            self._single.attach(ctx)
            self.planlog = self._single.planlog
            return
        self._open_planlog()

    def _open_planlog(self) -> None:
        """One plans.jsonl for every swarm."""
        self.planlog = PlanLog(self.ctx.out_dir)

    @property
    def lead(self) -> SwarmMember | None:
        """The controller a single swarm's readers ask (its ``mode``, ``plan``,
        ``target_id``, ...): with ``grouping = "one"`` the run's swarm; else the first swarm
        that started a manoeuvre (whose overtake block the summary shows), or the first swarm
        now; None while there is none."""
        if self._single is not None:
            return self._single
        self._note_first()
        lead = self._first or (self.platoons[0] if self.platoons else None)
        return None if lead is None else lead.controller

    @property
    def target_id(self) -> str | None:
        """The target of the lead swarm's manoeuvre (None: none yet), for the scene's
        outputs."""
        lead = self.lead
        return None if lead is None else lead.target_id

    # ------------------------------------------------------------------ the step
    def control(self, t_s: float) -> None:
        if self._single is not None:
            self._single.control(t_s)
            return
        session = self.ctx.session
        states = session.states
        if self._kind.alone_to_sumo:
            for vid in session.departed:
                if vid in states and states[vid].is_cav and vid not in self._alone:
                    self._alone.add(vid)
                    session.drive_alone(vid)  # until a platoon takes it (configure_cav)
                    self._to_sumo.add(vid)
        new = any(vid in states and self._platoon_of(vid) is None for vid in session.departed)
        if new or t_s - self._reviewed_s >= self.settings.review_every_s - 1e-9:
            self._reviewed_s = t_s
            # An error goes on to the run loop's StandDown (one warning, the CAVs back to SUMO)
            self._review(t_s, states)
        for platoon in list(self.platoons):
            platoon.controller.control(t_s)
            if platoon.controller.nothing_pays and platoon.idle:
                self._part(t_s, platoon, states)
        self._drive_free(states)

    def fallback(self, t_s: float) -> None:
        """The step after the swarms stood down: each platoon's fallback (CACC in its lane),
        and the CAVs of no platoon as before."""
        if self._single is not None:
            self._single.fallback(t_s)
            return
        for platoon in list(self.platoons):
            platoon.controller.fallback(t_s)
        self._drive_free(self.ctx.session.states)

    # ------------------------------------------------------------------ views
    def view(
        self, members: frozenset[str], table: dict[str, VehicleState] | None = None
    ) -> dict[str, VehicleState]:
        """The session's states (or ``table``, the step's states in one lane numbering: see
        ``states_in_lanes_of``) as the platoon of ``members`` sees them (:meth:`relabel`),
        built once per step, table and platoon."""
        states = self.ctx.session.states
        if states is not self._view_source:  # a new step (held: no later table reuses its id)
            self._view_source = states
            self._views = {}
        table = states if table is None else table
        key = (id(table), members)
        entry = self._views.get(key)
        if entry is None or entry[0] is not table:
            entry = self._views[key] = (table, self.relabel(_near(table, members), members))
        return entry[1]

    def relabel(
        self, states: dict[str, VehicleState], members: frozenset[str]
    ) -> dict[str, VehicleState]:
        """``states`` with every CAV not in ``members`` as a vehicle like the human-driven
        ones; ``states`` itself when there is no such CAV."""
        foreign = [st for st in states.values() if st.is_cav and st.vehicle_id not in members]
        if not foreign:
            return states
        view = dict(states)
        for st in foreign:
            view[st.vehicle_id] = self._as_vehicle(st)
        return view

    def _as_vehicle(self, st: VehicleState) -> VehicleState:
        """``st`` as a vehicle like the human-driven ones, made once per state read."""
        cached = self._relabelled.get(st.vehicle_id)
        if cached is not None and cached[0] is st:
            return cached[1]
        other = VehicleState(
            st.vehicle_id, st.s_m, st.lane, st.lat_m, st.speed_mps, st.length_m,
            st.accel_mps2, False, st.width_m,
        )  # fmt: skip
        self._relabelled[st.vehicle_id] = (st, other)
        return other

    # ------------------------------------------------------------------ other swarms
    def _paths_for(self, platoon: Platoon) -> dict[str, Callable[[float], float]]:
        """The planned front positions ``s(t)`` of the other swarms' CAVs that follow a plan
        (``RunContext.planned_paths`` of ``platoon``)."""
        paths: dict[str, Callable[[float], float]] = {}
        for other in self.platoons:
            if other is not platoon:
                paths.update(other.controller.planned_paths())
        return paths

    def _may_start(
        self, platoon: Platoon, t_s: float, s_from_m: float, s_to_m: float, target_id: str
    ) -> bool:
        """Whether ``platoon`` may start a manoeuvre on ``[s_from_m, s_to_m]``: no other swarm's
        manoeuvre within ``manoeuvre_clearance_m`` (``RunContext.may_start``). A start held
        back is counted, and an ``overtake_deferred`` event written, once per swarm and
        target."""
        clearance = self.settings.manoeuvre_clearance_m
        for other in self.platoons:
            extent = None if other is platoon else other.controller.manoeuvre_region(t_s)
            if extent is None:
                continue
            lo, hi = extent
            if s_from_m <= hi + clearance and lo - clearance <= s_to_m:
                key = (platoon.id, target_id)
                if key not in self.counts.deferred_for:
                    self.counts.deferred_for.add(key)
                    platoon.ctx.event("overtake_deferred", target=target_id, reason="other_swarm")
                return False
        return True

    # ------------------------------------------------------------------ membership
    def _platoon_of(self, vid: str) -> Platoon | None:
        for platoon in self.platoons:
            if vid in platoon.session.members:
                return platoon
        return None

    def _review(self, t_s: float, states: Mapping[str, VehicleState]) -> None:
        session = self.ctx.session
        st = self.settings
        cavs = [vid for vid in session.cav_ids if vid in states]
        self._parted &= set(cavs)
        self._relabelled = {v: pair for v, pair in self._relabelled.items() if v in states}
        self._apart_until = {v: t for v, t in self._apart_until.items() if t > t_s}
        frame_edges = frozenset(session.frame.route_edges)
        where = {vid: self._where(vid, states, frame_edges) for vid in cavs}
        # may stay in a platoon: on the frame, its exit not near (a lane that ends ahead is
        # the swarm's to leave); may join one: also in a lane that goes on
        stays = {vid for vid, w in where.items() if w is not None and w[1] is None}
        eligible = {vid for vid in stays if where[vid][2] and vid not in self._apart_until}
        # Leaving at once, whatever the platoon does: gone, off the frame, or near the exit.
        for platoon in list(self.platoons):
            left = platoon.controller.routes.left
            keep = [
                v for v in platoon.members
                if v in states and v not in left and (v in stays or _on_junction(session, v))
            ]  # fmt: skip
            for vid in platoon.members:
                if vid not in keep:
                    self._free(platoon, vid)
                    reason = (where.get(vid) or (None, None))[1]
                    if vid in states and reason is not None and vid not in left:
                        platoon.ctx.event("cav_leaves", vehicle=vid, reason=reason)
            if len(keep) != len(platoon.members):
                self._set(platoon, keep, states)
        # Idle platoons strung out, or too long, split.
        for platoon in list(self.platoons):
            if platoon.idle and len(platoon.members) > 1:
                parts = strung_out(platoon.members, states, st.split_gap_m, st.max_size)
                if len(parts) > 1:
                    self._set(platoon, parts[0], states)
                    for part in parts[1:]:
                        self._new(t_s, part, states)
                        self.counts.splits += 1
                    self.ctx.event("platoon_split", platoon=platoon.id, parts=parts)
        # Meeting in a lane: joins and merges, nearest first, where a slow vehicle holds the
        # column of CAVs they drive in (its front CAV): there is something to decide together.
        placed = self._placed_all(states)
        meetings = [
            (rear, front, gap) for rear, front, gap in in_lane_neighbours(placed)
            if gap <= st.join_gap_m and rear in eligible and front in eligible
            and may_join(states[rear], states[front], gap)
        ]  # fmt: skip
        ahead = {rear: front for rear, front, _ in meetings}
        held: dict[str, bool] = {}
        snapshots = PassSnapshots()  # states hold still during the review
        for rear, front, _ in sorted(meetings, key=lambda p: p[2]):
            road = session.road_at(rear) or self.ctx.road
            # Lanes counted as on rear's edge, as its road section counts them: near an
            # on-ramp a car in the acceleration lane was taken to be in the lane beside it.
            table = session.states_in_lanes_of(rear)
            everyone = snapshots(table, road)  # sorted once per table and road
            if any(straddled(table[v], everyone, road) for v in (rear, front)):
                continue
            lead = front
            while lead in ahead:
                lead = ahead[lead]
            if lead not in held:
                held[lead] = self._held(lead, table, everyone, road)
            if held[lead]:
                self._meet(t_s, rear, front, states)
        # Every other eligible CAV drives as a swarm of one; or, where the swarms leave a CAV
        # alone to SUMO (``alone_to_sumo``), as SUMO drives it (one that left a platoon: SUMO's
        # lane changes, our CACC for the speed, as every CAV leaving a platoon).
        alone_to_sumo = self._kind.alone_to_sumo
        for vid in cavs:
            if not alone_to_sumo and vid in eligible and self._platoon_of(vid) is None:
                self._new(t_s, [vid], states)
        # A platoon with nothing to do together (cruising, no slow vehicle holding it) is handed
        # back to SUMO.
        for platoon in list(self.platoons):
            if len(platoon.members) > 1 and platoon.idle and platoon.controller.t_start_s is None:
                lead = platoon.members[0]
                road = session.road_at(lead) or self.ctx.road
                table = session.states_in_lanes_of(lead)
                if self._held(lead, table, snapshots(table, road), road):
                    self._free_since.pop(platoon.id, None)
                    continue
                since = self._free_since.setdefault(platoon.id, t_s)
                if t_s - since >= self.ctx.scenario.swarm.trigger_after_s - 1e-9:
                    self._part(t_s, platoon, states, embargo_s=0.0)
        self._alone &= set(cavs)
        if alone_to_sumo:
            for platoon in [p for p in self.platoons if len(p.members) == 1 and p.idle]:
                vid = platoon.members[0]
                self._set(platoon, [], states)
                self._free(platoon, vid)
        self._retire_empty()
        live = sum(1 for p in self.platoons if len(p.members) > 1)
        self.counts.max_concurrent = max(self.counts.max_concurrent, live)

    def _held(self, lead: str, states, everyone, road: RoadSection) -> bool:
        """Is CAV ``lead`` held by a slow vehicle (:func:`held_by`, at the cruise and
        cap its swarm's decider takes: ``Decider.slow_below``, ``speed_cap``)? Only there
        have CAVs something to decide together; elsewhere SUMO drives them."""
        st = states.get(lead)
        if st is None:
            return False
        limits = self.ctx.session.speed_limits(lead)
        if limits is None:  # vanished this step
            return False
        world = min(limits)
        sc = self.ctx.scenario
        cav = sc.cav
        cruise = world if cav.speeds == "world" else cav.cruising_speed_mps
        cap = min(world, cruise if cav.speeds == "world" else cav.max_speed_mps)
        held = held_by(st, everyone, road, sc.swarm, cruise_mps=cruise, cap_mps=cap,
                       width_m=st.width_m)  # fmt: skip
        return held is not None

    def _meet(self, t_s: float, rear: str, front: str, states) -> None:
        """CAV ``rear`` drives right behind CAV ``front`` in a lane: one platoon, if both
        platoons cruise and the sum fits."""
        a, b = self._platoon_of(front), self._platoon_of(rear)
        if a is not None and a is b:
            return
        size = (len(a.members) if a else 1) + (len(b.members) if b else 1)
        if size > self.settings.max_size:
            return
        if (a is not None and not a.idle) or (b is not None and not b.idle):
            return
        if a is None and b is None:
            self._new(t_s, [front, rear], states)
        elif b is None:
            self._set(a, [*a.members, rear], states)
            self.counts.joins += 1
        elif a is None:
            self._set(b, [front, *b.members], states)
            self.counts.joins += 1
        else:  # the platoon ahead takes the one behind
            members = [*a.members, *b.members]
            self._set(b, [], states)
            self._set(a, members, states)
            self.counts.merges += 1
            self.ctx.event("platoon_merge", platoon=a.id, merged=b.id, cavs=a.members)

    def _where(
        self, vid: str, states, frame_edges: frozenset[str]
    ) -> tuple[str, str | None, bool] | None:
        """``(its route's last edge, why it may not be in a platoon, may join one)`` of CAV ``vid``
        (None: it may be; ``route_parts``: its exit is near; ``off_route``: off the route
        frame); None if unknown."""
        session = self.ctx.session
        route = session.route_of(vid)
        if route is None:
            return None
        edges, index = route
        st = self.settings
        edge = session.edges.get(vid)
        frame = session.frame
        if edge is not None and edge.startswith(":"):
            return None  # on a junction, its position is not on its route's edge: ask later
        if edge is None or edge not in frame.edge_offset_m:
            return edges[-1], "off_route", False
        speed = states[vid].speed_mps
        reach = max(st.exit_reach_min_m, st.exit_reach_s * speed)
        parting = session.distance_to_parting_m(vid, edges, index, frame_edges)
        if vid in self._parted or (parting is not None and parting <= reach):
            self._parted.add(vid)  # for good: it heads for its exit
            return edges[-1], "route_parts", False
        s = states[vid].s_m
        ending = session.lanes_ending(edge, s, s + reach)
        # Where every lane ends, the road (the frame's route) ends: no lane to leave for.
        ends_at: dict[float, int] = {}
        for _, end in ending:
            ends_at[end] = ends_at.get(end, 0) + 1
        n_lanes = frame.lane_count(edge)
        lane = states[vid].lane
        return edges[-1], None, all(i != lane or ends_at[end] >= n_lanes for i, end in ending)

    def _placed_all(self, states) -> list[Placed]:
        """Every vehicle of ``states`` on an edge of the route frame, placed in the frame's
        lane numbering (one pass over the step's states: a corridor's 600 vehicles at each
        membership review)."""
        session = self.ctx.session
        edges = session.edges
        offsets = session.frame.lane_offset
        return [
            Placed(vid, st.s_m, st.length_m, st.lane + offset)
            for vid, st in states.items()
            if (offset := offsets.get(edges.get(vid))) is not None
        ]

    # ------------------------------------------------------------------ platoons
    def _new(self, t_s: float, members: list[str], states) -> Platoon:
        session = PlatoonSession(self.ctx.session, self, frozenset())
        # Its CAVs start at the speeds the fleet's CAVs drive at now (they may follow the world).
        ctx = RunContext(
            session, self.ctx.scenario, (), self.ctx.road, out_dir=None, events=self.ctx.events,
            speeds=CavSpeeds(self.ctx.cav), platoon_id=self._next_id,
        )  # fmt: skip
        controller = self._make()
        controller.may_part = True
        if self.planlog is not None:
            controller.use_planlog(_Tagged(self.planlog, self._next_id))
        platoon = Platoon(self._next_id, controller, ctx, session, [])
        ctx.planned_paths = functools.partial(self._paths_for, platoon)
        ctx.may_start = functools.partial(self._may_start, platoon)
        self._next_id += 1
        self.counts.swarms += 1
        for vid in members:
            self._claim(vid)
        platoon.set_members(members, states)
        controller.attach(ctx)
        if self.drawer is not None and not any(p.controller is not None for p in self.platoons):
            controller.drawer = self.drawer
        self.platoons.append(platoon)
        self._count(platoon)
        return platoon

    def _set(self, platoon: Platoon, members: list[str], states) -> None:
        for vid in members:
            if vid not in platoon.session.members:
                self._claim(vid)
        platoon.set_members(members, states)
        self._count(platoon)

    def _count(self, platoon: Platoon) -> None:
        if len(platoon.members) > 1 and not platoon.counted:
            platoon.counted = True
            self.counts.formed += 1
            self.ctx.event("platoon_formed", platoon=platoon.id, cavs=list(platoon.members))

    def _claim(self, vid: str) -> None:
        """``vid`` joins a platoon: the controllers' modes are set again (by the platoon)."""
        self._handed.discard(vid)
        self._off_frame.discard(vid)
        self._to_sumo.discard(vid)
        self.ctx.session.reclaim(vid)
        for platoon in self.platoons:
            if vid in platoon.session.members:  # moving from another platoon
                _forget(platoon.controller, vid)

    def _free(self, platoon: Platoon, vid: str) -> None:
        """``vid`` leaves ``platoon``: SUMO changes its lanes, our CACC keeps its speed."""
        _forget(platoon.controller, vid)
        session = self.ctx.session
        if vid in session.states:
            session.release(vid)  # (a vehicle that vanished: no error)
            self._handed.add(vid)

    def _part(self, t_s: float, platoon: Platoon, states, embargo_s: float | None = None) -> None:
        """Nothing pays the CAVs of ``platoon`` doing together: SUMO drives each alone again,
        once it has opened its gap to SUMO's (:meth:`_drive_free`); none joins a platoon for
        ``embargo_s`` (default: the decision's horizon)."""
        members = list(platoon.members)
        self._set(platoon, [], states)
        session = self.ctx.session
        until = t_s + (self.ctx.scenario.swarm.horizon_s if embargo_s is None else embargo_s)
        for vid in members:
            _forget(platoon.controller, vid)
            self._apart_until[vid] = until
            if vid not in session.states:
                continue
            session.release(vid)  # SUMO's lane changes at once (vanished: no error)
            self._opening.add(vid)
        self.counts.parted += 1
        self.ctx.event("platoon_apart", platoon=platoon.id, cavs=members)
        self._retire(platoon)

    def _retire_empty(self) -> None:
        for platoon in [p for p in self.platoons if not p.members]:
            self._retire(platoon)

    def _retire(self, platoon: Platoon) -> None:
        counts = self.counts
        self._note_first()  # before it goes: the summary's overtake block may be its
        platoon.controller.dissolve(self.ctx.session.time_s)  # what it had under way ends
        _merge_min(counts.blocked_min, _blocked_of(platoon.controller))
        self._plan_stats.add(platoon.controller.stats)
        lat_errors, mpc_ms = platoon.controller.tracking_samples()
        self._lat_errors.extend(e for e in lat_errors if e is not None)
        self._mpc_ms.extend(mpc_ms)
        self._free_since.pop(platoon.id, None)
        if platoon is self._first:
            self._first_summary = platoon.controller.summary()
        close_controller(platoon.controller)
        self.platoons.remove(platoon)

    def _drive_free(self, states: Mapping[str, VehicleState]) -> None:
        """CAVs once in a platoon and now in none follow by CACC while on the route frame;
        those parted open their gap to SUMO's first (:meth:`_open_gaps`)."""
        session = self.ctx.session
        self._watch_alone(states)
        self._open_gaps(states)
        follow = []
        for vid in list(self._handed):
            if vid not in states:
                self._handed.discard(vid)
            elif session.edges.get(vid) in session.frame.edge_offset_m:
                follow.append(vid)
            elif vid not in self._off_frame and not _on_junction(session, vid):
                self._off_frame.add(vid)  # off the frame: SUMO's car-following drives it
                session.release_speed(vid)
                session.restore_gaps(vid)
        if follow:
            # At SUMO's desired speed for them where they drive ([cav] speeds = "world"), as the
            # swarms: the fleet's own settings kept the config's 20 m/s, and a CAV leaving for
            # its exit drove at 20 m/s on a 33 m/s motorway.
            self.ctx.follow_world_speeds(follow)
            road = session.road_at(follow[0]) or self.ctx.road
            command_cacc(replace(self.ctx, road=road), follow)

    def _watch_alone(self, states: Mapping[str, VehicleState]) -> None:
        """A CAV SUMO drives alone is the fleet's again where SUMO brakes it at the hard-brake
        line (its decel, :data:`ALONE_DECEL_MPS2`) while a vehicle ahead that overlaps it, or
        is off its lane's centre and moving (:func:`overlapping_ahead`, the guards' wider band
        for a vehicle that may be cutting in), is so close that SUMO, following it, would
        brake beyond the line within a step (closer than SUMO's gap,
        :meth:`SessionView.alone_gap_m`, at the speed one more step at the line leaves): it
        opens SUMO's gap, then SUMO drives it again (:meth:`_open_gaps`, as when it left its
        platoon; a ``cav_taken_back`` event). SUMO's sublane model follows a vehicle only once
        it overlaps: at 0.5 s steps a CAV SUMO drove 7.6 m behind a car moving into its lane
        at 31 m/s let it in by braking at its decel every other step, and braked at 4.47
        m/s^2 when it came in (users' roads, 2 runs of 72). Taken back wherever it was closer
        than SUMO's gap at its own speed, the CAVs gave way to every merging car at 0.5 s
        steps, and the others' delay rose. On the route frame only (off a junction), and for
        a CAV whose decel is the line: one whose user's type brakes less is not watched."""
        if not self._to_sumo:
            return
        session = self.ctx.session
        for vid in list(self._to_sumo):
            st = states.get(vid)
            if st is None:  # gone (a platoon that takes it claims it: _claim)
                self._to_sumo.discard(vid)
                continue
            if st.accel_mps2 > -ALONE_DECEL_MPS2 + 1e-6:
                continue
            # Only on the route frame, off a junction: its lanes are the road's there (as
            # _drive_free does).
            if session.edges.get(vid) not in session.frame.edge_offset_m:
                continue
            road = session.road_at(vid) or self.ctx.road
            table = session.states_in_lanes_of(vid)
            me = table.get(vid, st)
            # SUMO's gap at the speed one more step at the line leaves: closer than that, SUMO
            # following the vehicle brakes beyond the line within a step.
            after = max(0.0, me.speed_mps - ALONE_DECEL_MPS2 * self.ctx.dt_s)
            for lead, gap in self._leaders(vid, me, table, road):
                if gap < session.alone_gap_m(vid, after, lead.speed_mps, lead.vehicle_id):
                    self._to_sumo.discard(vid)
                    self._opening.add(vid)
                    self.ctx.event(
                        "cav_taken_back", vehicle=vid, leader=lead.vehicle_id,
                        gap_m=round(gap, 2), speed_mps=round(me.speed_mps, 2),
                    )  # fmt: skip
                    break

    def _open_gaps(self, states: Mapping[str, VehicleState]) -> None:
        """The CAVs of a platoon that parted first drop back from its short gaps to the gap
        SUMO wants ahead of a CAV it drives alone (:meth:`SessionView.alone_gap_m`), and down
        to the speed SUMO drives it at (its vType's and lane's, with its speedFactor), by
        :func:`opening_accel`; there SUMO drives each alone. Handed to SUMO at once, SUMO's
        car-following braked them at 4.1-4.7 m/s^2: closing in on a truck faster than SUMO's
        headway allows, or cruising above that speed with the platoon."""
        session = self.ctx.session
        cav = self.ctx.cav
        for vid in list(self._opening):
            st = states.get(vid)
            if st is None or self._platoon_of(vid) is not None:
                self._opening.discard(vid)
                continue
            limits = session.speed_limits(vid)
            if limits is None:  # vanished this step
                continue
            desired = min(limits)
            road = session.road_at(vid) or self.ctx.road
            # Its leaders with every lane counted as on its own edge: past an on-ramp the lane
            # it drives on is numbered one higher, and a CAV just beyond, 6.7 m ahead, was
            # taken for one in the next lane; handed to SUMO, it braked at 9 m/s^2.
            table = session.states_in_lanes_of(vid)
            leaders = self._leaders(vid, table.get(vid, st), table, road)
            # Not while it drives across a junction, whose lanes off the route frame are not
            # the road's: a leader beyond it on the next edge (its lanes numbered afresh) is
            # not seen as one there. A CAV standing there is handed over (it would never move).
            if (
                (not _on_junction(session, vid) or st.speed_mps < STANDING_MPS)
                and st.speed_mps <= desired + HANDOVER_MPS
                and all(
                    gap >= session.alone_gap_m(vid, st.speed_mps, lead.speed_mps, lead.vehicle_id)
                    for lead, gap in leaders
                )
            ):  # down to SUMO's speed and at SUMO's gap behind every leader: SUMO takes it
                self._opening.discard(vid)
                session.release_speed(vid)  # (a vehicle that vanished: no error)
                session.drive_alone(vid)
                self._to_sumo.add(vid)
                continue
            accel = min(
                (opening_accel(st.speed_mps, desired, (lead.speed_mps, gap), cav.min_gap_m)
                 for lead, gap in leaders),
                default=opening_accel(st.speed_mps, desired, None, cav.min_gap_m),
            )  # fmt: skip
            accel = min(max(accel, cav.accel_min_mps2), cav.accel_max_mps2)
            session.set_speed(vid, max(0.0, st.speed_mps + accel * self.ctx.dt_s))

    def _leaders(
        self, vid: str, st: VehicleState, states: Mapping[str, VehicleState], road: RoadSection
    ) -> list[tuple[VehicleState, float]]:
        """Every vehicle ahead of CAV ``vid`` (state ``st``) on its road section that overlaps
        it sideways, with the bumper gap: the leaders SUMO's sublane model has it follow there
        once SUMO drives it, within the gap SUMO wants behind a vehicle standing (the leader
        SUMO sees across a junction is not asked for: results-history, "A parted CAV's
        leader"). Not only the nearest: a parted CAV that SUMO was moving over to the next
        lane had a faster car there 11 m ahead as its nearest, was handed to SUMO, and SUMO
        braked it at 4.4 m/s^2 for the truck it still followed in its own lane (users' road
        3-lane-cav-flow at 0.5 s steps, seed 3)."""
        snap = snapshot_of(states, road)
        reach = self.ctx.session.alone_gap_m(vid, st.speed_mps, 0.0) + snap.max_length_m
        y = road.y_of(st.lane, st.lat_m)
        return overlapping_ahead(st, snap, road, y, st.width_m, reach)

    # ------------------------------------------------------------------ outputs
    def _note_first(self) -> None:
        if self._first is None:
            for platoon in self.platoons:
                if platoon.controller.t_start_s is not None:
                    self._first = platoon
                    break

    def manoeuvres(self) -> list[dict[str, Any]]:
        """Every swarm's manoeuvres, in order of start (the summary's list, of the events)."""
        if self._single is not None:
            return self._single.manoeuvres()
        return manoeuvres_from_events(self.ctx.events) if self.ctx is not None else []

    def swarms_block(self) -> dict[str, int]:
        counts = self.counts
        return {
            "platoons_formed": counts.formed,
            "max_concurrent": counts.max_concurrent,
            **overtake_counts(self.manoeuvres()),
            "swarms": counts.swarms,
            "joins": counts.joins,
            "merges": counts.merges,
            "splits": counts.splits,
            "overtakes_deferred": len(counts.deferred_for),
            "platoons_now": sum(1 for p in self.platoons if len(p.members) > 1),
        }

    def summary(self) -> dict[str, Any]:
        if self._single is not None:
            return self._single.summary()
        self._note_first()
        if self._first is not None and self._first in self.platoons:
            out = dict(self._first.controller.summary())
        elif self._first_summary is not None:
            out = dict(self._first_summary)
        elif self.platoons:
            out = dict(self.platoons[0].controller.summary())
        else:
            out = dict(self._kind.summary())
        out["swarms"] = self.swarms_block()
        # Every swarm's planning calls, not the first's alone (a corridor's summary showed 0
        # solves of a run that planned 106 times).
        stats = PlanStats()
        stats.add(self._plan_stats)
        for platoon in self.platoons:
            stats.add(platoon.controller.stats)
        out["planner"] = stats.block()
        lat_errors, mpc_ms = list(self._lat_errors), list(self._mpc_ms)
        for platoon in self.platoons:
            lat, ms = platoon.controller.tracking_samples()
            lat_errors += lat
            mpc_ms += ms
        out["lat_error_rms_m"] = lateral_rms(lat_errors)
        out["mpc"] = summarise_ms(mpc_ms, prefix="solve_ms_per_cav_")
        manoeuvres = self.manoeuvres()
        out["manoeuvres"] = manoeuvres
        overtake = out.get("overtake")
        if isinstance(overtake, dict):
            interval = overtake.get("behaving_interval_s") or (
                self.ctx.scenario.planner.behaving_interval_s if self.ctx is not None else 3.0
            )
            overtake = {**overtake, **overtake_outcome(manoeuvres, interval)}
            overtake["targets"] = [m["target"] for m in manoeuvres]
            overtake["manoeuvres"] = len(manoeuvres)
            strongest = dict(self.counts.blocked_min)
            for platoon in self.platoons:
                _merge_min(strongest, _blocked_of(platoon.controller))
            overtake = dict(overtake)
            overtake["blocked_hv_min_accel_mps2"] = min(strongest.values(), default=None)
            overtake["blocked_hvs"] = sorted(strongest)
            out["overtake"] = overtake
        if self.ctx is not None and "speeds" not in out:
            out["speeds"] = self.ctx.speeds_block()
        return out

    def close(self) -> None:
        if self._single is not None:
            close_controller(self._single)
            return
        for platoon in self.platoons:
            close_controller(platoon.controller)
        if self.planlog is not None:
            self.planlog.close()


# --------------------------------------------------------------------------- helpers


# A swarm sees the vehicles within this distance [m] of its CAVs, along the road: more than
# anything it looks at (a cell grid of ~300 m, a line ahead of a slow vehicle of 300 m, a target
# it watches for a horizon of 20 s at up to 30 m/s apart). On a corridor of 600 vehicles each
# swarm sorted all of them several times a step: the larger part of the controller's time.
VIEW_M = 1000.0


def _near(
    states: Mapping[str, VehicleState], members: frozenset[str]
) -> Mapping[str, VehicleState]:
    """The vehicles of ``states`` within :data:`VIEW_M` of the CAVs of ``members`` there
    (``states`` itself when none of them is in it, or every vehicle is near)."""
    ours = [states[v].s_m for v in members if v in states]
    if not ours:
        return states
    lo, hi = min(ours) - VIEW_M, max(ours) + VIEW_M
    near = {v: st for v, st in states.items() if lo <= st.s_m <= hi}
    return states if len(near) == len(states) else near


def _on_junction(session: Any, vid: str) -> bool:
    edge = session.edges.get(vid)
    return edge is not None and edge.startswith(":")


def _forget(controller: SwarmMember, vid: str) -> None:
    controller.forget(vid)


def _blocked_of(controller: SwarmMember) -> dict[str, float]:
    return dict(controller.blocks.min_accel)


def _merge_min(into: dict[str, float], other: Mapping[str, float]) -> None:
    for key, value in other.items():
        into[key] = min(value, into.get(key, value))


class _Tagged:
    """A plan log shared by every swarm; each record says whose plan it is (``platoon``)."""

    def __init__(self, log_: Any, platoon: int) -> None:
        self._log = log_
        self._platoon = platoon
        self.listeners = log_.listeners

    def write(self, record: dict[str, Any]) -> None:
        record["platoon"] = self._platoon
        self._log.write(record)

    def close(self) -> None:  # the fleet closes the shared log
        pass
