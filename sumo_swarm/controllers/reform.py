"""Re-forming the platoon while the swarm cruises (no plan in force).

After an overtake, a give-up, a target that left the lane, or CAVs that started spread out, the
CAVs are brought back into one platoon:

* :meth:`Reformer.lane` picks the lane: of the lanes its CAVs are in (a lane ending ahead
  excluded), the one where the swarm can drive fastest (:func:`lane_speeds`), on a tie the one
  holding more CAVs; the choice is kept unless another lane is faster by ``min_speed_gain_mps``.
* :meth:`Reformer.goals` gives each CAV its lane: the platoon's, except for a CAV cut off from
  the CAV ahead of it by a slow vehicle in that lane, which passes it on its own in the faster
  lane beside and then comes back (at most ``MAX_PASS_S``).
* :meth:`Reformer.moves` turns the goals into a lateral move and an acceleration bound per CAV:
  one lane at a time, through the same lateral guard as in a manoeuvre; a CAV that must change
  lanes drops in behind whatever drives ahead in the next lane, and the CAVs in the platoon's
  lane open a gap for a CAV merging next to them. A CAV held behind a slow HV beside a faster
  lane runs up (:func:`~sumo_swarm.core.swarming.guards.run_up`): it keeps
  ``RUN_UP_GAP_M`` behind the slow HV and accelerates when a gap in that lane would
  take it at a speed it can reach, instead of asking the stream to take it at the HV's speed.

Pure apart from the ``event`` callback: tested without SUMO (tests/test_reform.py).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Collection, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from sumo_swarm.config import CavSettings, Scenario
from sumo_swarm.controllers.base import CavSpeeds, lateral_guard
from sumo_swarm.controllers.cacc import cacc_accel
from sumo_swarm.core.hvmodel import DriverModel
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.neighbours import (
    Snapshot,
    cav_alongside_behind,
    snapshot_of,
    vehicle_ahead,
    vehicle_behind,
    within,
)
from sumo_swarm.core.swarming.decision import MAX_LEADER_EASE_MPS, is_past, lane_speeds
from sumo_swarm.core.swarming.guards import gap_accel_limit, run_up

Move = tuple[float, float]  # (lateral move [m], acceleration bound [m/s^2])

# Passing on its own (Reformer.goals), a CAV cut off from the platoon by a slow vehicle:
# at most this long [s] unless alongside it already (a CAV held out of a lane of 25-28 m/s
# traffic kept trying for 30 s, 50 m behind its platoon).
MAX_PASS_S = 30.0
# Held this long [s] from its passing side, it tries the other side (stress scenes where a CAV
# waited for one stream while the other side was free); also how long the platoon waits ahead
# before a CAV behind the target passes in whichever lane beside is fastest.
PASS_SWITCH_S = 6.0
# Held this long [s], it switches at once if the other side would take it now (the last CAV of
# five sat 60 s behind a truck, held towards a stream while the other side's traffic had gone).
PASS_OPEN_SIDE_S = 1.0
# The lanes beside are judged over detect_range_m plus this long [s] at the cruise: a slower
# vehicle just beyond detect_range_m would hold the passing CAV there.
PASS_REACH_S = 5.0
# Held this long [s] beside a platoon CAV a little behind it, a CAV drops back behind that CAV
# (at once, it braked a CAV passing alongside for a moment: stress scene 81, -1.2 m/s).
DROP_BEHIND_S = 3.0
# Run-up (guards.run_up): held this long [s] behind a slow HV beside a faster lane, a CAV keeps
# RUN_UP_GAP_M [m] behind it, dropping at most RUN_UP_DROP_MPS [m/s] below its speed, and runs
# up to a gap it can reach, for RUN_UP_COMMIT_S [s] more once no gap takes it. Entering a
# stream 8 m/s faster at a truck's speed brakes its HVs harder than b_safe at any headway: a CAV
# waited 36 s behind a 12 m/s truck beside a lane at 20 m/s.
RUN_UP_AFTER_S = 2.0
RUN_UP_GAP_M = 30.0
RUN_UP_DROP_MPS = 2.0
RUN_UP_COMMIT_S = 1.0
# A CAV enters a faster lane speeding up at this [m/s^2] (the guard judges that entry, not one
# at its own speed, which the lane's HVs would have to brake for).
ENTRY_ACCEL_MPS2 = 1.5
# Held this long [s] next to the platoon's lane by an HV following the platoon, the platoon
# pulls away up to PULL_AWAY_MPS [m/s] faster; from an HV that wants more, it re-forms in the
# held CAV's lane after REFORM_SWITCH_S [s] (CAVs drove beside such an HV at the cruise for
# 30 s and never regrouped: stress scenes 17, 112, 186).
PULL_AWAY_AFTER_S = 3.0
PULL_AWAY_MPS = 3.0
REFORM_SWITCH_S = 6.0
# A CAV stranded behind a slow vehicle this long [s] is helped by the platoon CAV the HV
# holding it out follows: that CAV slows BLOCK_ASSIST_MPS [m/s] below the stranded CAV (the
# last of nine CAVs sat behind the truck for 20 s without it: stress scene 192).
BLOCK_ASSIST_AFTER_S = 3.0
BLOCK_ASSIST_MPS = 2.0
# An HV is held back by blockers for at most this long [s] per manoeuvre, the cell plan's
# (Replanner) and the cruise's (block_assist): blocking delays the traffic behind it.
MAX_BLOCK_S = 30.0
# Waiting ahead of the target for the CAVs behind it, the CAVs past it keep up to this much
# [m] more room than the others need to get in (room only, they braked the others' entries).
WAIT_LEAD_M = 50.0


def clip(x: float, bound: float) -> float:
    """``x`` within ``[-bound, bound]`` (numpy's clip costs 40 us a call, every step)."""
    return min(max(x, -bound), bound)


@dataclass
class Reformer:
    """The platoon's lane and the CAVs passing on their own, from one step to the next."""

    scenario: Scenario
    model_of: Callable[[str], DriverModel]
    event: Callable[..., Any] = lambda kind, **data: None
    # hold(ego, y, dlat): a lane change to hold besides the guard's refusals (lane shifts)
    hold: Callable[[VehicleState, float, float], bool] = lambda ego, y, dlat: False
    # escape(ego, dlat, step): the lateral move instead of dlat when ego's lane ends ahead
    escape: Callable[[VehicleState, float, float], float] = lambda ego, dlat, step: dlat
    # ends(ego): the lanes that end ahead of ego within a pass, where it never passes (the hold
    # refuses them near their end: a CAV waited 30 s to pass a truck in an on-ramp's
    # acceleration lane)
    ends: Callable[[VehicleState], Collection[int]] = lambda ego: ()
    # The lane on this vehicle's right it is about to move into (Decider.lane_wanted_right)
    lane_wanted_right: Callable[[VehicleState, Mapping[str, VehicleState], float], int | None] = (
        lambda vehicle, states, t_s: None
    )
    # must_change(vid, direction): does this vehicle need to move one lane that way (+1 left)
    # for its route (SUMO's strategic wish)? A CAV lets such a vehicle ahead of it in (let_in).
    must_change: Callable[[str, int], bool] = lambda vid, direction: False
    lane_id: int | None = None
    edge: str | None = None  # the edge whose lane indices lane_id is in
    # CAV -> (the slow vehicle it passes, the lane it passes in, since when [s])
    passing: dict[str, tuple[str, int, float]] = field(default_factory=dict)
    # The vehicle the swarm gave up overtaking together: its leader too passes it on its own
    # (the others follow one by one, each once the CAV ahead is past), until this time [s].
    singly: tuple[str, float] | None = None
    # (lane, edge) the platoon re-forms in next unless a lane its CAVs occupy is faster by the
    # gain: the regroup lane, once every CAV is past the target (the cruise regroups them).
    prefer: tuple[int, str | None] | None = None
    # CAV -> (its goal lane, how long [s] the guard has held its lane change there, in a row)
    held_s: dict[str, tuple[int, float]] = field(default_factory=dict)
    # CAV -> acceleration floor [m/s^2] of this step's moves (a CAV running up, see run_up)
    floors: dict[str, float] = field(default_factory=dict)
    running: dict[str, float] = field(default_factory=dict)  # CAV -> run-up time left [s]
    # (lane, edge): the platoon moves over to this lane as a unit (a lane pass), whatever
    # lanes its CAVs are in now, while the leader is on that edge
    move_to: tuple[int, str | None] | None = None
    # (CAV, HV) pairs the platoon has pulled away from since the last reset (one pull_away
    # event each: with noisy states the condition lapsed and returned every 0.1 s)
    pulled: set[tuple[str, str]] = field(default_factory=set)
    block_s: dict[str, float] = field(default_factory=dict)  # HV -> time held by block_assist
    left_for_held: tuple[int, str | None] | None = None  # (lane, edge) left by _held_switch
    # (slow vehicle, since [s], until [s]): after a give-up with the platoon split by that
    # vehicle, the CAVs past it wait for the others in its lane ahead of it (see split_by)
    waiting: tuple[str, float, float] | None = None
    wait_ends: Counter[str] = field(default_factory=Counter)  # why the waits ended, counted
    last_wait_end: str | None = None  # why the last wait ended
    # The CAVs' speeds in force, shared with the swarm's context (they may follow the world:
    # RunContext.follow_world_speeds); None: the scenario's [cav]
    speeds: CavSpeeds | None = None

    def __post_init__(self) -> None:
        if self.speeds is None:
            self.speeds = CavSpeeds(self.scenario.cav)

    @property
    def cav(self) -> CavSettings:
        """The CAVs' settings in force (their speeds may follow the world)."""
        return self.speeds.cav

    def reset(self) -> None:
        """Choose the lane afresh from where the CAVs are (a manoeuvre just ended)."""
        self.lane_id = None
        self.left_for_held = None
        self.waiting = None
        self.block_s.clear()
        self.pulled.clear()

    def past(self, ego: VehicleState, slow: VehicleState) -> bool:
        """Is ego past ``slow`` (:func:`is_past` by ``cav.min_gap_m``)?"""
        return is_past(ego, slow, self.scenario.cav.min_gap_m)

    def split_by(
        self,
        t_s: float,
        states: Mapping[str, VehicleState],
        platoon: Sequence[str],
        road: RoadSection,
        ending: Collection[int] = (),
    ) -> VehicleState | None:
        """The vehicle the platoon waits at (:attr:`waiting`), until every CAV is past it and in
        one lane (``rejoined``), none is (``none_past``), it is gone, its lane ends ahead
        (``ending``: ``lane_ends``) or the wait is over (``timeout``). While it lasts the CAVs
        past it re-form in its lane ahead of it (:meth:`lane`), where they hold up nobody
        behind them but it, no faster than it beyond the room the others need to get in ahead
        of it (:meth:`wait_cruise`); the CAVs behind it keep their lanes (:meth:`goals`) and
        pass it as they can. Clears the wait once it is over (a ``wait_end`` event with the
        reason)."""
        if self.waiting is None:
            return None
        slow_id, _, until_s = self.waiting
        slow = states.get(slow_id)
        how = None
        if slow is None:
            how = "gone"
        elif t_s > until_s:
            how = "timeout"
        elif road.road_lane_of(slow) in ending:
            how = "lane_ends"
        else:
            past = [self.past(states[v], slow) for v in platoon]
            if all(past):
                # Past, the last CAVs still have to close up: the others wait on at its speed
                # until every CAV is in one lane (driving on, they pulled away at the cruise,
                # and the last two had 52 and 74 m to make up at 5 m/s: stress scene 43).
                if len({road.lane_of(states[v]) for v in platoon}) == 1:
                    how = "rejoined"
            elif not any(past):
                how = "none_past"
        if how is None:
            return slow
        self.waiting = None
        self.lane_id = None  # chosen afresh from where the CAVs are
        self.wait_ends[how] += 1
        self.last_wait_end = how
        self.event("wait_end", slow=slow_id, reason=how)
        return None

    def _held_switch(
        self,
        states: Mapping[str, VehicleState],
        platoon: Sequence[str],
        road: RoadSection,
        current: int,
        speeds: Mapping[int, float],
        candidates: Collection[int],
        cap_mps: float,
    ) -> int:
        """The lane of CAVs an HV has kept out of ``current`` for ``REFORM_SWITCH_S``
        (:meth:`_held_by_hv`; not an HV the platoon can pull away from) when the platoon cruises
        as fast there (``speeds`` capped at the cruise, within ``min_speed_gain_mps``), else
        ``current``. The HV following the platoon then has its lane back (it wanted 33 m/s
        behind a platoon at 20 for 30 s, two CAVs beside it at the lane's edge: stress scenes
        17 and 112). Never back to a lane left so: once per lane and edge."""
        sw = self.scenario.swarm
        if self.left_for_held == (current, self.edge):
            return current
        cruise = self.cav.cruising_speed_mps
        boost = self._boost(cap_mps)
        for ego, hv in self._held_by_hv(states, platoon, road, current, REFORM_SWITCH_S):
            if self._left_behind(hv, boost):
                continue  # the platoon pulls away from it instead (pull_away)
            q = road.lane_of(ego)
            if q not in candidates or self.left_for_held == (q, self.edge):
                continue
            if min(speeds.get(q, -math.inf), cruise) + sw.min_speed_gain_mps < min(
                speeds.get(current, cruise), cruise
            ):
                continue
            self.left_for_held = (current, self.edge)
            self.event("reform_held", lane=q, left=current, vehicle=ego.vehicle_id,
                       follower=hv.vehicle_id)  # fmt: skip
            return q
        return current

    def desired_speed(self, vehicle: VehicleState) -> float:
        """Speed [m/s] a vehicle wants to drive: an HV's by its model, a CAV's unbounded."""
        if vehicle.is_cav:
            return math.inf
        return self.model_of(vehicle.vehicle_id).desired_speed_mps

    def wait_cruise(
        self,
        states: Mapping[str, VehicleState],
        platoon: Sequence[str],
        road: RoadSection,
        slow: VehicleState,
        cruise_mps: float,
    ) -> dict[str, float]:
        """Cruising speed [m/s] of each CAV past ``slow`` and in its lane while the platoon
        waits there for the CAVs behind it (:meth:`split_by`): ``slow``'s speed, plus
        ``cacc.k_close`` per metre the room ahead of it (to the rearmost of those CAVs) falls
        short of what the CAVs behind need to get in (each a CAV length plus
        ``cav.desired_gap_m``, plus ``slow``'s secure gap by its model: ``min_gap_m + tau_s *
        v``, plus ``WAIT_LEAD_M``), at most ``cruise_mps``. Never slower than
        ``slow``: it is held up by nobody.
        None is held while a CAV past ``slow`` in another lane is still to drop in behind them
        (its front within ``cav.desired_gap_m`` of their rear or ahead of it): it would slow
        to their speed beside the target, holding up the lane it leaves (variant 14: the HVs
        there then kept the CAV behind the target out of that lane for 26 s more)."""
        sc = self.scenario
        lane = road.road_lane_of(slow)  # (beside the road: where it merges)
        ahead = [v for v in platoon if self.past(states[v], slow)]
        waiting = [v for v in ahead if road.lane_of(states[v]) == lane]
        if not waiting:
            return {}
        rear = min(states[v].rear_s_m for v in waiting)
        if any(states[v].s_m > rear - sc.cav.desired_gap_m for v in ahead if v not in waiting):
            return {}
        behind = len(platoon) - len(ahead)
        model = self.model_of(slow.vehicle_id)
        need = (
            behind * (sc.cav.length_m + sc.cav.desired_gap_m)
            + (model.min_gap_m + model.tau_s * slow.speed_mps)
            + WAIT_LEAD_M
        )
        room = rear - slow.s_m
        speed = min(slow.speed_mps + sc.cacc.k_close * max(need - room, 0.0), cruise_mps)
        return dict.fromkeys(waiting, speed)

    # ------------------------------------------------------------------ the platoon's lane
    def lane(
        self,
        states: Mapping[str, VehicleState],
        platoon: Sequence[str],
        road: RoadSection,
        *,
        ending: Collection[int],
        cap_mps: float,
        edge: str | None = None,
    ) -> int:
        """The lane the platoon cruises in (``ending``: lanes that end ahead of the leader;
        ``edge``: the leader's edge, whose lane indices the choice is in). While it waits at a
        vehicle (:meth:`split_by`), that vehicle's lane."""
        slow = states.get(self.waiting[0]) if self.waiting is not None else None
        # (one beside the road: the lane it merges into)
        held = None if slow is None else road.road_lane_of(slow)
        if held is not None and held not in ending:
            if self.lane_id != held:
                self.event("reform_lane", lane=held, lane_speeds_mps={}, wait=slow.vehicle_id)
            self.lane_id = held
            return held
        sc = self.scenario
        if edge != self.edge:  # lane indices change between edges (ramps, lane drops)
            self.edge, self.lane_id = edge, None
        leader = states[platoon[0]]
        if self.move_to is not None and self.move_to[1] == edge and self.move_to[0] not in ending:
            if self.lane_id != self.move_to[0]:
                self.event("reform_lane", lane=self.move_to[0], lane_speeds_mps={})
            self.lane_id = self.move_to[0]
            return self.lane_id
        count = Counter(road.road_lane_of(states[v]) for v in platoon)
        if len(count) == 1 and self.lane_id in (None, *count) and not set(count) & set(ending):
            self.lane_id = next(iter(count))
            self.prefer = None  # one lane already: no lane change beats staying
            self.left_for_held = None
            return self.lane_id
        candidates = set(count) - set(ending)
        if not candidates:  # every CAV is in a lane that ends: the nearest one that does not
            free = [q for q in range(road.n_lanes) if q not in ending]
            occupied = min(count)
            candidates = {min(free, key=lambda q: abs(q - occupied))} if free else set(count)
        members = set(platoon)
        speeds = lane_speeds(
            leader, [st for v, st in states.items() if v not in members], road,
            sorted(candidates), range_m=sc.swarm.detect_range_m, cap_mps=cap_mps,
            desired_of=self.desired_speed,
        )  # fmt: skip
        current = self.lane_id
        best = max(speeds, key=lambda lane: (round(speeds[lane] * 2.0) / 2.0, count[lane]))
        if current not in candidates:
            current = None  # it ends ahead, or belongs to another edge
        prefer = self.prefer
        if prefer is not None and (prefer[1] != edge or prefer[0] in ending):
            self.prefer = prefer = None

        def changes(q: int) -> int:  # lane changes for every CAV to re-form in lane q
            return sum(n * abs(lane - q) for lane, n in count.items())

        if prefer is not None and changes(prefer[0]) > changes(best):
            self.prefer = prefer = None  # more lane changes than re-forming where they are
        if prefer is not None and current in (None, prefer[0]):
            # Just past the target: back in the lane it regroups in (the paper's Fig. 6, step
            # 4: the platoon's original lane, when that takes no more lane changes than the
            # lane chosen among those it occupies) unless a lane it occupies is faster by the
            # gain; kept as a choice until a CAV is in it (then it is occupied like any other).
            current = prefer[0]
            speeds.update(lane_speeds(
                leader, [st for v, st in states.items() if v not in members], road, [current],
                range_m=sc.swarm.detect_range_m, cap_mps=cap_mps, desired_of=self.desired_speed,
            ))  # fmt: skip
            if count[current] > 0:
                self.prefer = None
        # Once the platoon has moved over for a held CAV (_held_switch), a lane is faster only
        # by what the platoon would drive there: the lane it left is no better at the cruise.
        top = self.cav.cruising_speed_mps if self.left_for_held is not None else math.inf
        if current in speeds and min(speeds[best], top) - min(speeds[current], top) < (
            sc.swarm.min_speed_gain_mps
        ):
            best = current
        if prefer is not None and best != prefer[0]:
            self.prefer = None  # a lane the CAVs occupy is faster: that one
        if best == current and current is not None:
            best = self._held_switch(states, platoon, road, current, speeds, candidates, cap_mps)
        if best != current:
            shown = {str(k): round(v, 2) for k, v in speeds.items()}
            self.event("reform_lane", lane=best, lane_speeds_mps=shown)
        self.lane_id = best
        return best

    # ------------------------------------------------------------------ each CAV's lane
    def goals(
        self,
        t_s: float,
        states: Mapping[str, VehicleState],
        platoon: Sequence[str],
        road: RoadSection,
        lane: int,
        *,
        cap_mps: float,
        step_s: float = 0.0,
        everyone: Snapshot | None = None,
    ) -> dict[str, int]:
        """The lane each CAV heads for (``passing_start``/``passing_end`` events); a CAV never
        passes in a lane that ends ahead of it (``ends``: an acceleration lane). ``step_s``:
        the simulation step (0: no look at the side opposite a held lane change, see
        :meth:`_switch`); ``everyone``: ``states`` as a :class:`Snapshot`, if the caller has
        one."""
        sc = self.scenario
        sw = sc.swarm
        members = set(platoon)
        others = [st for v, st in states.items() if v not in members]
        if everyone is None:
            everyone = snapshot_of(states, road)  # sorted once: a look-up per CAV below
        waits_at = states.get(self.waiting[0]) if self.waiting is not None else None
        platoon_lane = lane
        goals = {}

        def switch(ego: VehicleState, goal: int, *, passing: bool) -> int:
            # Only a CAV passing a slow vehicle may switch early: either side passes it. One
            # heading for the platoon's lane would leave it (stress scene 133: a CAV held 1 s
            # towards the platoon's lane went on to pass a car on the other side, and the
            # platoon had not regrouped 40 s later).
            return self._switch(t_s, ego, goal, states, others, everyone, road,
                                cap_mps=cap_mps, early=passing, step_s=step_s)  # fmt: skip

        for i, vid in enumerate(platoon):
            ego = states[vid]
            lane = platoon_lane
            if waits_at is not None and not self.past(ego, waits_at):
                # Behind the vehicle the platoon waits at: ego keeps its lane and passes it as
                # it can (merging behind it into its lane only to pass it again cost 10 m/s of
                # speed to the CAVs and the HVs behind them: variant 39).
                lane = road.road_lane_of(ego)
            goals[vid] = lane
            passing = self.passing.get(vid)
            if passing is not None:
                slow_id, side, since = passing
                slow = states.get(slow_id)
                done = slow is None or self.past(ego, slow)
                # (one beside the road is in the lane it merges into, as where the pass began)
                slow_lane = None if done else road.road_lane_of(slow)
                # The slow vehicle moved over into the lane ego passes it in, ahead of it: ego
                # would follow it there (a target keeping right had two CAVs behind it at its
                # speed for 25 s beside the platoon's free lane, stress scene 51).
                moved = not done and slow_lane == side and slow.rear_s_m > ego.s_m
                # Or it left the lane ego passes it from, away from the passing lane (two lanes
                # from it): nothing is left to pass, and a CAV held out of a lane of 25-28 m/s
                # traffic kept trying for 30 s, 50 m behind its platoon (stress scene 39).
                gone = not done and abs(slow_lane - side) >= 2
                # Out of time, but alongside it in the passing lane already: the pass goes on
                # (given up there, a CAV past it 2 s later was recorded as not past).
                alongside = not done and road.lane_of(ego) == side and ego.s_m > slow.rear_s_m
                late = t_s - since > MAX_PASS_S and not alongside
                if done or moved or gone or late:
                    del self.passing[vid]
                    self.event("passing_end", vehicle=vid, slow=slow_id, past=done)
                else:
                    goals[vid] = switch(ego, side, passing=True)
                continue
            if road.lane_of(ego) != lane:
                goals[vid] = switch(ego, lane, passing=False)
                continue
            ahead = vehicle_ahead(ego, everyone, road, width_m=sc.cav.width_m)
            if ahead is None or ahead[0].is_cav or ahead[1] > sw.detect_range_m:
                continue
            slow = ahead[0]
            slow_below = self.cav.cruising_speed_mps - sw.min_speed_gain_mps
            if i > 0 and self._splits(slow, states, platoon[:i], road):
                slow_below = self.cav.cruising_speed_mps  # passed to re-form the platoon
            if slow.speed_mps > slow_below:
                continue
            if road.road_lane_of(slow) != road.lane_of(ego):
                # Leaving ego's lane (its centre is out already): nothing to pass. One beside
                # the road reaching into ego's lane ahead (an acceleration lane's car) merges
                # into it: ego passes it as one in its lane.
                continue
            train = None if i == 0 else self._train_lane(platoon[i - 1], slow.vehicle_id)
            if i == 0:
                singly = self.singly
                if singly is None or singly[0] != slow.vehicle_id or t_s > singly[1]:
                    continue  # the swarm decides for the leader
            elif states[platoon[i - 1]].rear_s_m <= slow.s_m and (
                train is None or road.lane_of(states[platoon[i - 1]]) != train
            ):
                continue  # the CAV ahead is behind it too, not in its passing lane yet
            ending = self.ends(ego)
            side = [q for q in (lane - 1, lane + 1) if 0 <= q < road.n_lanes and q not in ending]
            if train in side:
                side = [train]  # behind the CAV ahead, in the lane it passes in
            wanted = self.lane_wanted_right(slow, states, t_s)
            if wanted is not None:
                # Not on the right of a driver about to move there, with a lane on its left
                # (the swarm's plan keeps out of it too: Decider.keep_right_closure).
                side = [q for q in side if q != wanted]
            reach = sw.detect_range_m + PASS_REACH_S * self.cav.cruising_speed_mps
            speeds = lane_speeds(ego, others, road, side, range_m=reach,
                                 cap_mps=cap_mps, desired_of=self.desired_speed)  # fmt: skip
            best = max(speeds, key=speeds.get, default=None)
            gain = sw.min_speed_gain_mps
            if self._waited_at(slow, t_s) >= PASS_SWITCH_S:
                # The platoon waits for ego ahead of this vehicle: ego passes it to re-join,
                # not to drive faster, in whichever lane beside is fastest (an HV beside the
                # truck at 15.8 m/s kept the only side lane from being 2 m/s faster than the
                # truck's 15.6 for 15 s, and the wait ran out: stress scene 40).
                gain = -math.inf
            if best is not None and speeds[best] - slow.speed_mps >= gain:
                self.passing[vid] = (slow.vehicle_id, best, t_s)
                goals[vid] = best
                self.event("passing_start", vehicle=vid, slow=slow.vehicle_id, lane=best)
        return goals

    def _waited_at(self, slow: VehicleState, t_s: float) -> float:
        """How long [s] the platoon has waited at ``slow`` (:attr:`waiting`; 0: it does not)."""
        if self.waiting is None or self.waiting[0] != slow.vehicle_id:
            return 0.0
        return t_s - self.waiting[1]

    def _splits(
        self,
        hv: VehicleState,
        states: Mapping[str, VehicleState],
        ahead: Sequence[str],
        road: RoadSection,
    ) -> bool:
        """Does ``hv`` split the platoon: is one of the CAVs ``ahead`` (the platoon's CAVs in
        front of the one behind ``hv``) in ``hv``'s lane ahead of it, at any distance? The
        CAVs behind such an HV pass it to re-form the platoon whenever it drives below the
        cruise, not only when it is as slow as a target must be: it follows the platoon's
        front part, which eases off for the stretched platoon. Passed only below 19 m/s at a
        cruise of 20 (1 m/s above a target's line), a car left between the CAVs after a
        one-by-one pass was held at 19.2 m/s behind the front part for 120 s and the platoon
        never re-formed (variant 7); at a target's line, five CAVs drove 85 m behind the other
        four for 15 s, the HV between them, the lane beside free (stress scene 187)."""
        lane = road.lane_of(hv)
        return any(road.lane_of(states[v]) == lane and states[v].rear_s_m > hv.s_m for v in ahead)

    def _train_lane(self, ahead: str, slow_id: str) -> int | None:
        """The lane in which the CAV ``ahead`` passes ``slow_id``, or None. Once that CAV's
        centre is in it, the CAV behind it passes too, behind it there, as SUMO's own drivers
        do: waiting for each CAV to be past before the next one started took 5-6 s a CAV, and
        9-12-CAV platoons that gave up were still in two lanes 50 s later."""
        passing = self.passing.get(ahead)
        if passing is None or passing[0] != slow_id:
            return None
        return passing[1]

    def _next_to_a_cav(
        self, ego: VehicleState, goal: int, states: Mapping[str, VehicleState], road: RoadSection
    ) -> bool:
        """Is the nearest vehicle ahead of ego or behind it in ``goal`` (alongside included) a
        CAV within ``cav.desired_gap_m``? A CAV held there by the platoon's own CAVs gets in
        once they make room or it drops back behind them: it does not turn to the other side
        (a CAV beside a platoon CAV switched to pass a slow line on its other side just as the
        gap opened, and was not back by the end: stress scene 95)."""
        sc = self.scenario
        y = road.lane_centre_y(goal)
        for near in (
            vehicle_ahead(ego, states.values(), road, y_m=y, width_m=sc.cav.width_m),
            vehicle_behind(ego, states.values(), road, y_m=y, width_m=sc.cav.width_m),
        ):
            if near is not None and near[0].is_cav and near[1] < sc.cav.desired_gap_m:
                return True
        return False

    def _switch(
        self,
        t_s: float,
        ego: VehicleState,
        goal: int,
        states: Mapping[str, VehicleState],
        others: Sequence[VehicleState],
        everyone: Snapshot,
        road: RoadSection,
        *,
        cap_mps: float,
        early: bool = False,
        step_s: float = 0.0,
    ) -> int:
        """``goal``, or the lane on ego's other side once the guard has held ego's lane change
        towards ``goal`` for ``PASS_SWITCH_S`` with a slow vehicle ahead of it in its
        own lane, and that other lane is faster than the slow vehicle by the gain: ego then
        passes the slow vehicle there (``passing_switch`` event) and comes back after. With
        ``early``, held for ``PASS_OPEN_SIDE_S`` already, ego switches sooner if the
        guard would let it into the other lane now (``step_s``: the simulation step; a
        ``passing_switch`` event with ``open: true``). ``others``: the vehicles outside the
        platoon, ``everyone``: all of them."""
        sc = self.scenario
        sw = sc.swarm
        vid = ego.vehicle_id
        held_lane, held = self.held_s.get(vid, (goal, 0.0))
        if held_lane != goal:
            return goal
        waited = held + 1e-9 >= PASS_SWITCH_S
        look = early and step_s > 0.0 and held + 1e-9 >= PASS_OPEN_SIDE_S
        if not waited and not look:
            return goal
        here = road.lane_of(ego)
        if goal == here:
            return goal
        other = here - (1 if goal > here else -1)
        if not 0 <= other < road.n_lanes or other in self.ends(ego):
            return goal
        ahead = vehicle_ahead(ego, everyone, road, width_m=sc.cav.width_m)
        if ahead is None or ahead[0].is_cav or ahead[1] > sw.detect_range_m:
            return goal
        slow = ahead[0]
        if slow.speed_mps > self.cav.cruising_speed_mps - sw.min_speed_gain_mps:
            return goal
        if self._next_to_a_cav(ego, goal, states, road):
            return goal
        speed = lane_speeds(ego, others, road, [other], range_m=sw.detect_range_m,
                            cap_mps=cap_mps, desired_of=self.desired_speed)[other]  # fmt: skip
        if speed - slow.speed_mps < sw.min_speed_gain_mps:
            return goal
        opened = not waited
        if opened and not self._open_towards(ego, other, everyone, road, step_s):
            return goal
        since = self.passing[vid][2] if vid in self.passing else t_s
        self.passing[vid] = (slow.vehicle_id, other, since)  # MAX_PASS_S counts from the start
        self.held_s.pop(vid, None)
        extra = {"open": True} if opened else {}
        self.event("passing_switch", vehicle=vid, slow=slow.vehicle_id, held_lane=goal,
                   lane=other, **extra)  # fmt: skip
        return other

    def _open_towards(
        self, ego: VehicleState, lane: int, everyone: Snapshot, road: RoadSection, step_s: float
    ) -> bool:
        """Would the lateral guard let ego into the adjacent ``lane`` now, entering it as
        :meth:`_steer` would (speeding up into it where it may)? Asked where the guard decides:
        with ego's side at the lane line and with ego half across it (the first steps of a
        lane change, still in its own lane, are let through whatever the lane beside holds)."""
        sc = self.scenario
        here = road.lane_of(ego)
        sign = 1.0 if road.lane_centre_y(lane) > road.lane_centre_y(here) else -1.0
        line = 0.5 * (road.lane_centre_y(here) + road.lane_centre_y(lane))
        step = sign * sc.cav.max_lateral_speed_mps * step_s
        commit = self._speed_up_into(ego, lane, self._near(ego, everyone), everyone, road)
        return all(
            self._refusal(ego, y, step, everyone, road, step_s, commit) is None
            for y in (line - sign * 0.5 * sc.cav.width_m, line)
        )

    # ------------------------------------------------------------------ commands
    def moves(
        self,
        states: Mapping[str, VehicleState],
        platoon: Sequence[str],
        road: RoadSection,
        lane: int,
        goals: Mapping[str, int],
        step_s: float,
        everyone: Snapshot | None = None,
    ) -> dict[str, Move]:
        """Lateral move and acceleration bound of every CAV of ``platoon`` (``everyone``:
        ``states`` as a :class:`Snapshot`, if the caller has one)."""
        others = snapshot_of(states, road) if everyone is None else everyone
        self.floors = {}
        moves = {vid: self._steer(states[vid], goals[vid], others, road, step_s) for vid in platoon}
        for vid in platoon:  # how long each CAV's lane change has been held, in a row
            here = road.lane_of(states[vid])
            toward = goals[vid] - here
            if toward != 0 and moves[vid][0] * toward <= 0.0:
                lane_was, held = self.held_s.get(vid, (goals[vid], 0.0))
                self.held_s[vid] = (goals[vid], (held if lane_was == goals[vid] else 0.0) + step_s)
            else:
                self.held_s.pop(vid, None)
        settled = [v for v in platoon if v not in self.passing]  # no CAV passing a slow one
        self._make_room(states, others, settled, road, lane, moves)
        self._let_in(states, others, settled, road, moves)
        self._block_for_stranded(states, others, platoon, road, moves, step_s)
        return moves

    def _block_for_stranded(
        self,
        states: Mapping[str, VehicleState],
        others: Snapshot,
        platoon: Sequence[str],
        road: RoadSection,
        moves: dict[str, Move],
        step_s: float,
    ) -> None:
        """The paper's blocking, while the swarm cruises: a CAV stranded behind a slow vehicle
        in its lane, its move into the lane beside held for ``BLOCK_ASSIST_AFTER_S``
        by an HV alongside or just behind it there (within ``cav.desired_gap_m``), is helped by
        the platoon CAV that HV follows: that CAV slows to ``BLOCK_ASSIST_MPS`` below the
        stranded CAV's speed (braking at most the planner's share of b_safe), so the HV, behind
        it, falls back beside the stranded CAV until the guard lets it in ahead of the HV.
        While the blocker keeps more than ``cav.desired_gap_m`` of room ahead of the stranded
        CAV, and at most ``MAX_BLOCK_S`` per HV (``block_assist`` event). Without it the HV
        drove beside the stranded CAV at the speed of the CAVs ahead of it (stress scene 192:
        the last of nine CAVs behind the truck for 20 s)."""
        sc = self.scenario
        sw = sc.swarm
        members = set(platoon)
        slow_below = self.cav.cruising_speed_mps - sw.min_speed_gain_mps
        width = sc.cav.width_m
        for ego, goal in self._held_next_to(states, platoon, road, BLOCK_ASSIST_AFTER_S):
            vid = ego.vehicle_id
            own = vehicle_ahead(ego, others, road, width_m=width)
            if own is None or own[0].is_cav or own[1] > sw.detect_range_m:
                continue
            if own[0].speed_mps >= slow_below:
                continue  # not stranded: nothing slow ahead of it
            behind = vehicle_behind(ego, others, road, y_m=road.lane_centre_y(goal), width_m=width)
            if behind is None or behind[0].is_cav or behind[1] > sc.cav.desired_gap_m:
                continue
            hv = behind[0]
            lead = vehicle_ahead(hv, others, road, width_m=width)
            if lead is None or lead[0].vehicle_id not in members:
                continue
            blocker = lead[0]
            if blocker.vehicle_id in self.passing or blocker.rear_s_m <= own[0].s_m:
                continue  # a blocker beside the slow vehicle would hold up its own pass
            # Only an HV that follows the blocker (it wants more than it drives, within twice
            # its own desired gap): one driving its own pace further back would not slow down.
            model = self.model_of(hv.vehicle_id)
            follows = 2.0 * (model.min_gap_m + model.tau_s * hv.speed_mps)
            if model.desired_speed_mps < hv.speed_mps + 0.5 or lead[1] > follows:
                continue
            if blocker.rear_s_m - ego.s_m <= sc.cav.desired_gap_m:
                continue  # no room left ahead of the stranded CAV: the blocker drives on
            spent = self.block_s.get(hv.vehicle_id, 0.0)
            if spent > MAX_BLOCK_S:
                continue
            self.block_s[hv.vehicle_id] = spent + step_s
            if spent == 0.0:
                self.event("block_assist", vehicle=vid, blocker=blocker.vehicle_id,
                           hv=hv.vehicle_id)  # fmt: skip
            target = max(ego.speed_mps - BLOCK_ASSIST_MPS, 0.0)
            brake = -sc.hvmodel.planner_share * sc.hvmodel.b_safe_mps2
            accel = max(sc.cacc.k_cruise * (target - blocker.speed_mps), brake)
            dlat, bound = moves[blocker.vehicle_id]
            moves[blocker.vehicle_id] = (dlat, min(bound, accel))

    def _steer(
        self,
        ego: VehicleState,
        lane: int,
        others: Sequence[VehicleState],
        road: RoadSection,
        step_s: float,
    ) -> Move:
        """Towards ``lane``'s centre, one lane at a time, held by the lateral guard; a CAV that
        must change lanes drops in behind whatever drives ahead in the next lane (braking
        gently), so that a gap opens where it will enter."""
        sc = self.scenario
        # A goal lane this road section does not have (a goal chosen on an edge with more
        # lanes): the nearest one it has. Beyond the road, the next lane's width was looked up
        # past the last and the controller failed (users' junctions road, 40 % CAVs).
        lane = road.nearest_lane(lane)
        step = sc.cav.max_lateral_speed_mps * step_s
        y = road.y_of(ego.lane, ego.lat_m)
        # A CAV still beside the road (on a ramp) is steered from the lane it merges into:
        # centred into it, not held by the lane shift at the ramp's end.
        lane_now = road.road_lane_of_y(y)
        if lane_now == lane:
            centre = clip(road.lane_centre_y(lane) - y, step)
            escape = self.escape(ego, centre, step)
            if escape == centre:
                # Back to the centre through the guard too: an HV squeezing past a CAV parked
                # off-centre in a jam, or straddling the boundary beside one that has just
                # entered, was hit by the CAV centring (corridor study, 20 % / 1500 veh/h).
                if centre and self._refusal(ego, y, centre, others, road, step_s) is not None:
                    centre = 0.0
                return centre, math.inf
            lane = lane_now + (1 if escape > 0 else -1)  # its lane ends: out of it first
        next_lane = lane_now + (1 if lane > lane_now else -1)
        y_next = road.lane_centre_y(next_lane)
        dlat = clip(y_next - y, step)
        # The vehicles around ego, for the entry speed and the run-up
        near = self._near(ego, others)
        commit = self._speed_up_into(ego, next_lane, near, others, road)
        refusal = self._refusal(ego, y, dlat, others, road, step_s, commit)
        accel = math.inf
        ahead = vehicle_ahead(ego, others, road, y_m=y_next, width_m=sc.cav.width_m)
        held_lane, held = self.held_s.get(ego.vehicle_id, (None, 0.0))
        stuck = held_lane == lane and held + 1e-9 >= DROP_BEHIND_S
        beside = cav_alongside_behind(ego, others, road, y_next, sc.cav.width_m) if stuck else None
        if beside is not None:
            # Held beside a CAV whose front is a little behind ego's: ego drops back behind it
            # (the CAVs of the platoon's lane make room only for a CAV ahead of them; two CAVs
            # side by side at the same speed stayed so for 35 s, neither giving way).
            ahead = (beside, beside.rear_s_m - ego.s_m)
        if ahead is not None:
            accel = self._follow_gently(ego, *ahead)
        if refusal is None:
            self.running.pop(ego.vehicle_id, None)
        if self.hold(ego, y, dlat):  # back to the lane centre: never straddle two lanes there
            dlat = clip(road.lane_centre_y(lane_now) - y, step)
            if dlat and self._refusal(ego, y, dlat, others, road, step_s) is not None:
                dlat = 0.0  # not into a vehicle alongside
        elif refusal is not None:
            waited = held_lane == lane and held + 1e-9 >= RUN_UP_AFTER_S
            if beside is None and waited:
                bound, floor = self._run_up(ego, y, dlat, next_lane, near, others, road, step_s)
                accel = min(accel, bound)
                if floor > 0.0:
                    self.floors[ego.vehicle_id] = floor
            dlat = 0.0
        if refusal is None and commit is not None and dlat != 0.0:
            self.floors[ego.vehicle_id] = commit[0]  # as the guard was told: it speeds up
        limit = gap_accel_limit(
            ego, y, y + dlat, others, road, sc.cav.min_gap_m, sc.cav.width_m, sc.guards, step_s
        )
        bound = min(accel, limit)
        if ego.vehicle_id in self.floors:
            self.floors[ego.vehicle_id] = min(self.floors[ego.vehicle_id], bound)
        return dlat, bound

    def _near(self, ego: VehicleState, others: Sequence[VehicleState]) -> list[VehicleState]:
        """The vehicles of ``others`` around ego (within twice ``detect_range_m``), ego not:
        what its entry speed and its run-up into the next lane are judged against."""
        reach = 2.0 * self.scenario.swarm.detect_range_m
        return [o for o in within(others, ego.s_m, reach) if o.vehicle_id != ego.vehicle_id]

    def _refusal(
        self,
        ego: VehicleState,
        y: float,
        dlat: float,
        others: Sequence[VehicleState],
        road: RoadSection,
        step_s: float,
        commit: tuple[float, float] | None = None,
    ) -> str | None:
        """The lateral guard (:func:`~sumo_swarm.controllers.base.lateral_guard`) on ego's
        move ``dlat`` from ``y`` (``commit``: ego speeds up at this rate [m/s^2] to this speed
        [m/s] as it moves)."""
        return lateral_guard(self.scenario, self.model_of, ego, y, dlat, others, road, step_s,
                             commit)  # fmt: skip

    def _speed_up_into(
        self,
        ego: VehicleState,
        next_lane: int,
        near: Sequence[VehicleState],
        others: Snapshot,
        road: RoadSection,
    ) -> tuple[float, float] | None:
        """``(a, v)``: ego enters ``next_lane`` speeding up at ``a`` to ``v``, that lane's speed
        ahead of it (at most the cruise), when that is faster than ego by ``min_speed_gain_mps``
        and the vehicle ahead of ego in its own lane leaves room to speed up during the lane
        change (``ENTRY_ACCEL_MPS2``; None: it enters at its speed). ``near``: the vehicles
        around ego, ``others``: all of them."""
        sc = self.scenario
        sw = sc.swarm
        accel = ENTRY_ACCEL_MPS2
        lane_speed = lane_speeds(ego, near, road, [next_lane], range_m=sw.detect_range_m,
                                 cap_mps=self.cav.cruising_speed_mps,
                                 desired_of=self.desired_speed)[next_lane]  # fmt: skip
        # Never more than the cruise a leader easing off to close up would keep.
        final = min(lane_speed, self.cav.cruising_speed_mps - MAX_LEADER_EASE_MPS)
        if final - ego.speed_mps < sw.min_speed_gain_mps:
            return None
        change_s = road.lane_width_m(next_lane) / sc.cav.max_lateral_speed_mps
        own = vehicle_ahead(ego, others, road, width_m=sc.cav.width_m)
        if own is not None:
            closing = max(0.0, ego.speed_mps - own[0].speed_mps)
            need = sc.cav.min_gap_m + closing * change_s + 0.5 * accel * change_s * change_s
            if own[1] < need:
                return None
        return accel, final

    def _run_up(
        self,
        ego: VehicleState,
        y: float,
        dlat: float,
        next_lane: int,
        near: Sequence[VehicleState],
        others: Sequence[VehicleState],
        road: RoadSection,
        step_s: float,
    ) -> tuple[float, float]:
        """Acceleration bound and floor [m/s^2] of a CAV whose lane change into ``next_lane``
        the guard refused, behind a slow HV in its own lane (:func:`run_up`): running up it
        accelerates at its maximum; ``(inf, 0)``: nothing to do. ``near``: the vehicles around
        ego (within twice ``detect_range_m``), ``others``: all of them."""
        sc = self.scenario
        sw = sc.swarm
        nothing = (math.inf, 0.0)
        own = vehicle_ahead(ego, others, road, width_m=sc.cav.width_m)
        if own is None or own[0].is_cav or own[1] > sw.detect_range_m:
            return nothing
        # A CAV of the platoon following in the next lane makes room (_make_room): no need.
        follower = vehicle_behind(ego, others, road, y_m=road.lane_centre_y(next_lane),
                                  width_m=sc.cav.width_m)  # fmt: skip
        if follower is not None and follower[0].is_cav and follower[1] < sw.detect_range_m:
            return nothing
        slow, gap = own
        vid = ego.vehicle_id
        lane_speed = lane_speeds(ego, near, road, [next_lane], range_m=sw.detect_range_m,
                                 cap_mps=self.cav.max_speed_mps,
                                 desired_of=self.desired_speed)[next_lane]  # fmt: skip
        # A vehicle alongside in the next lane sets its speed too (lane_speeds looks ahead
        # only): a leader passing on its own ran up and fell back for 30 s beside an HV as
        # slow as the truck, its CAVs behind it 2 m/s slower than waiting (stress scene 53).
        for other in near:
            if (
                abs(other.centre_s_m - ego.centre_s_m) < 0.5 * (other.length_m + ego.length_m)
                and road.lane_of(other) == next_lane
            ):
                lane_speed = min(lane_speed, other.speed_mps)
        if lane_speed - slow.speed_mps < sw.min_speed_gain_mps:
            return nothing

        def entry_ok(v_enter: float, tau: float) -> bool:
            s_ego = ego.s_m + 0.5 * (ego.speed_mps + v_enter) * tau
            moved = [replace(o, s_m=o.s_m + o.speed_mps * tau) for o in near]
            future = replace(ego, s_m=s_ego, speed_mps=v_enter, accel_mps2=0.0)
            return self._refusal(future, y, dlat, moved, road, step_s) is None

        what, value = run_up(
            ego.speed_mps, slow.speed_mps, gap, lane_speed,
            desired_gap_m=sc.cav.desired_gap_m, accel_mps2=sc.cav.accel_max_mps2,
            brake_mps2=sc.hvmodel.planner_share * sc.hvmodel.b_safe_mps2,
            change_s=road.lane_width_m(next_lane) / sc.cav.max_lateral_speed_mps,
            min_gain_mps=sw.min_speed_gain_mps, entry_ok=entry_ok,
        )  # fmt: skip
        if what == "run":
            self.running[vid] = RUN_UP_COMMIT_S
            return math.inf, sc.cav.accel_max_mps2 if value > ego.speed_mps else 0.0
        if what == "brake":
            self.running.pop(vid, None)
            return value, 0.0
        if self.running.get(vid, 0.0) > 0.0:  # a run-up goes on a moment without a gap ahead
            self.running[vid] -= step_s
            return math.inf, sc.cav.accel_max_mps2
        # No gap takes it: keep the run-up gap behind the slow vehicle, braking gently and
        # dropping at most ``RUN_UP_DROP_MPS`` below its speed (the HVs behind wait too).
        extra = max(RUN_UP_GAP_M - sc.cav.desired_gap_m, 0.0)
        bound = self._follow_gently(ego, slow, gap - extra)
        if ego.speed_mps <= slow.speed_mps - RUN_UP_DROP_MPS:
            bound = max(bound, 0.0)
        return bound, 0.0

    def _make_room(
        self,
        states: Mapping[str, VehicleState],
        others: Sequence[VehicleState],
        platoon: Sequence[str],
        road: RoadSection,
        lane: int,
        moves: dict[str, Move],
    ) -> None:
        """A CAV in the platoon's lane lets a CAV next to that lane merge in front of it: it
        follows the merging CAV as if it were already ahead (braking gently), so a gap opens
        there instead of the platoon streaming past a CAV that cannot get in."""
        lane_of = {v: road.lane_of(states[v]) for v in platoon}
        merging = [states[v] for v in platoon if abs(lane_of[v] - lane) == 1]
        if not merging:
            return
        for vid in platoon:
            if lane_of[vid] != lane:
                continue
            ego = states[vid]
            # Only for a CAV already ahead of it: one alongside drops back instead (braking a
            # whole lane for a CAV stuck beside it slowed the platoon to 12 m/s).
            ahead = [m for m in merging if m.rear_s_m > ego.s_m]
            if not ahead:
                continue
            m = min(ahead, key=lambda x: x.s_m)
            self._let_ahead(ego, m, m.rear_s_m - ego.s_m, others, road, moves)

    def _let_in(
        self,
        states: Mapping[str, VehicleState],
        others: Snapshot,
        platoon: Sequence[str],
        road: RoadSection,
        moves: dict[str, Move],
    ) -> None:
        """A CAV lets in a vehicle that must change into its lane for its route (SUMO's
        strategic wish, :attr:`must_change`): the nearest one ahead of it in a lane beside,
        within ``cav.desired_gap_m`` plus 2 s at its speed, is followed as if it were already
        ahead (braking gently), as SUMO's cooperative drivers open a gap. Without it an exiting
        truck two lanes from the deceleration lane found no gap into the platoons of the right
        lane for 1.5 km, stood at the end of its lane, and the corridor jammed behind it (the
        hour of scenarios/corridor.toml, from 1630 s)."""
        sc = self.scenario
        members = set(platoon)
        for vid in platoon:
            ego = states[vid]
            here = road.lane_of(ego)
            reach = sc.cav.desired_gap_m + 2.0 * ego.speed_mps
            for side in (1, -1):
                q = here + side
                if not 0 <= q < road.n_lanes:
                    continue
                near = vehicle_ahead(ego, others, road, y_m=road.lane_centre_y(q),
                                     width_m=sc.cav.width_m)  # fmt: skip
                if near is None or near[0].vehicle_id in members or near[0].is_cav:
                    continue
                m, gap = near
                if gap > reach or road.lane_of(m) != q:
                    continue
                if self.must_change(m.vehicle_id, -side):
                    self._let_ahead(ego, m, gap, others, road, moves)

    def _let_ahead(
        self,
        ego: VehicleState,
        lead: VehicleState,
        gap_m: float,
        others: Sequence[VehicleState],
        road: RoadSection,
        moves: dict[str, Move],
    ) -> None:
        """Ego follows ``lead``, in a lane beside and ``gap_m`` ahead, as if it were already
        ahead (braking gently, :meth:`_follow_gently`), so that a gap opens for it there;
        unless ego's own leader is nearer (room for ``lead`` is made further ahead)."""
        real = vehicle_ahead(ego, others, road, width_m=self.scenario.cav.width_m)
        if real is not None and real[1] <= gap_m:
            return
        dlat, bound = moves[ego.vehicle_id]
        moves[ego.vehicle_id] = (dlat, min(bound, self._follow_gently(ego, lead, gap_m)))

    def _held_next_to(
        self,
        states: Mapping[str, VehicleState],
        platoon: Sequence[str],
        road: RoadSection,
        after_s: float,
    ) -> Iterator[tuple[VehicleState, int]]:
        """(CAV, goal lane) for each CAV of ``platoon`` whose move into the lane next to it
        the guard has held for ``after_s`` [s] or more (``held_s``)."""
        for vid in platoon:
            goal, held = self.held_s.get(vid, (None, 0.0))
            if goal is None or held + 1e-9 < after_s:
                continue
            ego = states[vid]
            if abs(road.lane_of(ego) - goal) == 1:
                yield ego, goal

    def _held_by_hv(
        self,
        states: Mapping[str, VehicleState],
        platoon: Sequence[str],
        road: RoadSection,
        lane: int,
        after_s: float,
    ) -> list[tuple[VehicleState, VehicleState]]:
        """(CAV, HV) for each CAV of ``platoon`` next to ``lane``, passing nothing, whose move
        into ``lane`` the guard has held for ``after_s`` [s] or more, with an HV the nearest
        vehicle behind it there (alongside included, within ``detect_range_m``): an HV that
        follows the platoon in that lane keeps the CAV out."""
        sc = self.scenario
        y_lane = road.lane_centre_y(lane)
        front = states[platoon[0]]
        found = []
        for ego, goal in self._held_next_to(states, platoon, road, after_s):
            if goal != lane or ego.vehicle_id in self.passing:
                continue
            # Not a CAV with a slow vehicle ahead of it in its own lane, up to the platoon's
            # front (still to be passed): the platoon would pull away from it, or move into
            # the slow vehicle's lane (behind a truck, stress scene 144).
            if self._slow_ahead_in_lane(ego, front, states, road):
                continue
            behind = vehicle_behind(ego, states.values(), road, y_m=y_lane, width_m=sc.cav.width_m)
            if behind is not None and not behind[0].is_cav and behind[1] <= sc.swarm.detect_range_m:
                found.append((ego, behind[0]))
        return found

    def _slow_ahead_in_lane(
        self,
        ego: VehicleState,
        front: VehicleState,
        states: Mapping[str, VehicleState],
        road: RoadSection,
    ) -> bool:
        """Is an HV slower than the cruise by ``min_speed_gain_mps`` in ego's lane, ahead of
        ego and at most ``detect_range_m`` ahead of ``front``?"""
        sc = self.scenario
        lane = road.lane_of(ego)
        slow = self.cav.cruising_speed_mps - sc.swarm.min_speed_gain_mps
        end = max(front.s_m, ego.s_m) + sc.swarm.detect_range_m
        return any(
            not o.is_cav and ego.s_m < o.s_m <= end and o.speed_mps < slow
            and road.lane_of(o) == lane
            for o in states.values()
        )  # fmt: skip

    def _boost(self, cap_mps: float) -> float:
        """How much faster than the cruise [m/s] the platoon may pull away (0: it may not)."""
        cruise = self.cav.cruising_speed_mps
        return max(min(PULL_AWAY_MPS, min(cap_mps, self.cav.max_speed_mps) - cruise), 0.0)

    def _left_behind(self, hv: VehicleState, boost: float) -> bool:
        """Does ``hv`` want less than the cruise plus ``boost`` by a metre per second (a
        platoon pulling away leaves it behind; one wanting as much follows)?"""
        cruise = self.cav.cruising_speed_mps
        return boost > 0.0 and self.desired_speed(hv) <= cruise + boost - 1.0

    def pull_away(
        self,
        states: Mapping[str, VehicleState],
        platoon: Sequence[str],
        road: RoadSection,
        lane: int,
        *,
        cap_mps: float,
    ) -> float:
        """How much faster [m/s] than the cruise the platoon drives to pull away from an HV that
        keeps one of its CAVs out of ``lane`` (:meth:`_held_by_hv` for
        ``PULL_AWAY_AFTER_S``) and wants less than that faster cruise. 0: no such HV. A
        ``pull_away`` event once per CAV and HV until :meth:`reset`."""
        boost = self._boost(cap_mps)
        if boost <= 0.0:
            return 0.0
        for ego, hv in self._held_by_hv(states, platoon, road, lane, PULL_AWAY_AFTER_S):
            if not self._left_behind(hv, boost):
                continue
            if (ego.vehicle_id, hv.vehicle_id) not in self.pulled:
                self.pulled.add((ego.vehicle_id, hv.vehicle_id))
                self.event("pull_away", vehicle=ego.vehicle_id, follower=hv.vehicle_id,
                           boost_mps=round(boost, 2))  # fmt: skip
            return boost
        return 0.0

    def _follow_gently(self, ego: VehicleState, lead: VehicleState, gap_m: float) -> float:
        """CACC acceleration [m/s^2] of ``ego`` behind ``lead`` at ``gap_m`` (a vehicle in the
        lane it moves into, or a CAV merging in front of it), braking no harder than the
        planner's share of b_safe: room is made gently, never by a hard brake."""
        sc = self.scenario
        accel = cacc_accel(ego.speed_mps, gap_m, lead.speed_mps, lead.accel_mps2, self.cav,
                           sc.cacc, ahead_is_cav=lead.is_cav)  # fmt: skip
        return max(accel, -sc.hvmodel.planner_share * sc.hvmodel.b_safe_mps2)
