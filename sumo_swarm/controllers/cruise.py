"""The swarm cruising: a CACC platoon that re-forms, waits, and lets stragglers catch up.

:class:`Cruiser` is the step of the swarm while no plan is in force. The
:class:`~sumo_swarm.controllers.reform.Reformer` picks the platoon's lane and each CAV's moves;
the leader eases off to let a stretched platoon close up (only by what the followers cannot
make up above the cruise); stragglers cut off in another lane may drive above the cruise to
catch up; after a give-up that split the platoon, the CAVs past the slow vehicle wait ahead of
it (``WAIT_AHEAD_S``).
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from typing import Any

from sumo_swarm.controllers.cacc import command_cacc
from sumo_swarm.controllers.decider import Decider
from sumo_swarm.controllers.lanes import LaneView
from sumo_swarm.controllers.reform import Reformer
from sumo_swarm.core.model import VehicleState
from sumo_swarm.core.neighbours import Snapshot, snapshot_of
from sumo_swarm.core.swarming.decision import (
    MAX_LEADER_EASE_MPS,
    REGROUP_EASE_MPS,
    leader_ease_cap,
    straggler_cruise,
)
from sumo_swarm.core.swarming.tracker import Tracker

# After a give-up that leaves the target between CAVs, the CAVs past it wait ahead for the
# others up to this long [s]. Driving on, the last CAV got by 190 m behind them and the
# platoon was still in two lanes at 80 s (variants 24, 39; docs/dense-traffic.md).
WAIT_AHEAD_S = 45.0


class Cruiser:
    """The platoon's commands while it cruises (see the module docstring)."""

    def __init__(
        self, ctx: Any, reformer: Reformer, decider: Decider, lanes: LaneView, tracker: Tracker
    ) -> None:
        self.ctx = ctx
        self.reformer = reformer
        self.decider = decider
        self.lanes = lanes
        self.tracker = tracker
        self.waits_started = 0  # waits ahead of a target splitting the platoon (WAIT_AHEAD_S)

    def step(self, t_s: float, states: Mapping[str, VehicleState], platoon: list[str]) -> None:
        """CACC following in the current lane, drifting back to the lane centre."""
        ctx = self.ctx
        sc = ctx.scenario
        # A stretched platoon regroups from both ends: followers may exceed the cruising speed
        # (cacc_accel), and the leader eases off by k_close per metre of excess gap behind it,
        # which is what closes up a platoon whose CAVs cannot go faster than the cruise speed.
        stretch = 0.0
        for front, back in itertools.pairwise(platoon):
            f, b = states[front], states[back]
            if f.lane == b.lane:
                stretch += max(0.0, f.rear_s_m - b.s_m - sc.cav.desired_gap_m)
        # The leader eases off only by what the followers cannot make up above the cruise
        # (up to the cap): with room above it, easing off slowed the whole re-formed platoon
        # by up to 2 m/s for 20 s after a target left the lane, where cacc drove on.
        reformer, road = self.reformer, ctx.road
        cav = ctx.cav  # the speeds in force (they may follow the world)
        everyone = snapshot_of(states, road)  # sorted once for this step's look-ups
        cap = self.decider.speed_cap(platoon[:1])
        room = max(min(cap, cav.max_speed_mps) - cav.cruising_speed_mps, 0.0)
        ease = self._leader_ease_cap(states, platoon, everyone)
        leader_cruise = cav.cruising_speed_mps - min(
            ease, max(sc.cacc.k_close * stretch - room, 0.0)
        )
        # Never re-form in a lane that ends within 10 s at the cruise (an acceleration lane).
        reach = sc.swarm.detect_range_m + 10.0 * cav.cruising_speed_mps
        ending = self.lanes.ending(states[platoon[0]], platoon[0], reach)
        edge = self.lanes.edge_of(platoon[0])
        waits_at = reformer.split_by(t_s, states, platoon, road, ending)
        lane = reformer.lane(states, platoon, road, ending=ending, cap_mps=cap, edge=edge)
        goals = reformer.goals(t_s, states, platoon, road, lane, cap_mps=cap, step_s=ctx.dt_s,
                               everyone=everyone)  # fmt: skip
        moves = reformer.moves(states, platoon, road, lane, goals, ctx.dt_s, everyone=everyone)
        cruise = None
        boost = reformer.pull_away(states, platoon, road, lane, cap_mps=cap)
        if boost > 0.0:  # an HV following the platoon keeps a CAV out of its lane
            cruise = cav.cruising_speed_mps + boost
            leader_cruise = max(leader_cruise, cruise)
        base = cav.cruising_speed_mps if cruise is None else cruise
        catch_up = straggler_cruise(
            states, platoon, road, cruise_mps=base, cap_mps=min(cap, cav.max_speed_mps),
            desired_gap_m=sc.cav.desired_gap_m, k_close=sc.cacc.k_close,
            slow_below_mps=cav.cruising_speed_mps - sc.swarm.min_speed_gain_mps,
            reach_m=sc.swarm.detect_range_m, width_m=sc.cav.width_m,
        )  # fmt: skip
        if waits_at is not None and boost <= 0.0:
            wait = reformer.wait_cruise(states, platoon, road, waits_at, base)
            catch_up = {**catch_up, **{v: min(catch_up.get(v, base), w) for v, w in wait.items()}}
            if platoon[0] in wait:
                leader_cruise = min(leader_cruise, wait[platoon[0]])
        command_cacc(ctx, platoon, leader_cruise,
                     accel_limits={vid: m[1] for vid, m in moves.items()},
                     accel_floors=reformer.floors, states=states, cruise_mps=cruise,
                     cruise_of=catch_up, everyone=everyone)  # fmt: skip
        for vid, (dlat, _) in moves.items():
            ctx.session.change_sublane(vid, dlat)
        self.tracker.straighten(platoon)

    def wait_if_split(
        self, t_s: float, target: VehicleState | None, cavs: Mapping[str, VehicleState]
    ) -> None:
        """After a give-up: wait for the CAVs behind ``target`` if it splits the platoon
        (``WAIT_AHEAD_S``, :meth:`Reformer.split_by`; a ``wait_start`` event)."""
        wait_s = WAIT_AHEAD_S
        if target is None:
            return
        past = sum(self.reformer.past(c, target) for c in cavs.values())
        if 0 < past < len(cavs):
            self.waits_started += 1
            self.reformer.waiting = (target.vehicle_id, t_s, t_s + wait_s)
            self.ctx.event("wait_start", slow=target.vehicle_id, past=past,
                           behind=len(cavs) - past, until_s=round(t_s + wait_s, 2))  # fmt: skip

    def _leader_ease_cap(
        self, states: Mapping[str, VehicleState], platoon: list[str], everyone: Snapshot
    ) -> float:
        """How much [m/s] the cruising leader may slow to let a stretched platoon close up
        (:func:`leader_ease_cap`; ``everyone``: ``states`` as a Snapshot)."""
        sc = self.ctx.scenario
        return leader_ease_cap(
            states, platoon, self.ctx.road, width_m=sc.cav.width_m,
            reach_m=sc.swarm.detect_range_m, ease_mps=MAX_LEADER_EASE_MPS,
            regroup_ease_mps=REGROUP_EASE_MPS,
            everyone=everyone,
        )  # fmt: skip
