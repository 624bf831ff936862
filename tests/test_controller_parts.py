"""The swarm controller's parts without SUMO: lanes ahead, blocked HVs, plan statistics, the
wait, the replanner's fallback when a solve fails, and the plan follower's guards.

Hand-made sessions stand in for the bridge: a route where lane 0 ends at s = 900 m.
"""

import types

import pytest

from sumo_swarm.config import Scenario
from sumo_swarm.controllers import follower, lanes
from sumo_swarm.controllers.cruise import WAIT_AHEAD_S, Cruiser
from sumo_swarm.controllers.follower import PlanFollower
from sumo_swarm.controllers.lanes import (
    LANE_END_LENGTH_M,
    LANE_END_PREFIX,
    LaneView,
)
from sumo_swarm.controllers.reform import Reformer
from sumo_swarm.controllers.replanner import RETRY_AFTER_S, BlockWatch, PlanStats, Replanner
from sumo_swarm.controllers.swarm import SwarmController
from sumo_swarm.core.hvmodel import DriverModel
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.swarming.decision import Progress
from sumo_swarm.core.swarming.manoeuvre import PlanOutcome
from sumo_swarm.core.swarming.planlog import PlanLog
from sumo_swarm.core.swarming.tracker import TrackCommand
from tests.fakes import FakeSession, run_context, said

ROAD = RoadSection((3.2, 3.2, 3.2))
LANE_0_ENDS_M = 900.0


def cav(vid, s, lane, v=20.0, lat=0.0):  # a CAV of 5 m
    return VehicleState(vid, s, lane, lat, v, 5.0, 0.0, True)


def view(*own_states, near_shift=False):
    """A LaneView over a session whose edge "e" loses lane 0 at LANE_0_ENDS_M."""

    def lanes_ending(edge, s_from_m, s_to_m):
        return [(0, LANE_0_ENDS_M)] if edge == "e" and s_from_m <= LANE_0_ENDS_M <= s_to_m else []

    session = FakeSession(
        {st.vehicle_id: st for st in own_states},
        edges={st.vehicle_id: "e" for st in own_states},
        lanes_ending=lanes_ending,
        frame=types.SimpleNamespace(lane_count=lambda edge: 3),
        near_lane_shift=lambda s_m, within_m: near_shift,
    )
    return LaneView(run_context(session, Scenario(name="t", path=None), ROAD))


def test_a_cav_whose_lane_ends_within_8_s_heads_left_and_not_before(monkeypatch):
    # 20 m/s: 8 s is 160 m, less than the 300 m floor, so the lane end is seen 300 m ahead.
    step = 0.1
    near = cav("c", 650.0, 0)  # 250 m to the end
    assert view(near).end_escape(near, 0.0, step) == pytest.approx(step)  # to lane 1
    far = cav("c", 550.0, 0)  # 350 m: beyond the 300 m
    assert view(far).end_escape(far, 0.0, step) == 0.0
    # The thresholds are the module's: looking only 8 s (160 m) ahead, it stays.
    monkeypatch.setattr(lanes, "LANE_END_MIN_M", 100.0)
    assert view(near).end_escape(near, 0.0, step) == 0.0
    monkeypatch.setattr(lanes, "LANE_END_ESCAPE_S", 13.0)
    assert view(near).end_escape(near, 0.0, step) > 0
    other = cav("c", 650.0, 1)  # its own lane goes on
    assert view(other).end_escape(other, -0.05, step) == -0.05


def test_no_lane_change_into_a_lane_that_ends_or_near_a_lane_shift():
    ego = cav("c", 650.0, 1)
    y = ROAD.lane_centre_y(1) - 1.0  # near the line to lane 0
    assert view(ego).shift_hold(ego, y, -0.1)  # into lane 0, which ends 250 m ahead
    assert not view(ego).shift_hold(ego, ROAD.lane_centre_y(1) + 1.0, 0.1)  # into lane 2
    assert not view(ego).shift_hold(ego, ROAD.lane_centre_y(1), 0.0)  # no lane change
    early = cav("c", 550.0, 1)
    assert not view(early).shift_hold(early, y, -0.1)
    assert view(early, near_shift=True).shift_hold(early, y, -0.1)  # lane indices shift here


def test_lanes_ending_ahead_are_renumbered_as_the_leaders_edge_counts_them():
    # The controller's state counts lanes as on the leader's edge (one more lane there): the
    # CAV's own lane 0 is lane 1 in that numbering, and so is the lane that ends.
    own = cav("c", 650.0, 0)
    in_leader_numbering = cav("c", 650.0, 1)
    assert view(own).ends_ahead(in_leader_numbering) == {1}
    assert view(own).ends_ahead(own) == {0}


def test_no_pass_in_a_lane_that_ends_within_the_weighings_horizon():
    # [swarm] horizon_s (20 s) at the cruise (20 m/s): 400 m. A lane ending 350 m ahead
    # carries no pass (a pass there ends at the lane's end), one ending 450 m ahead does; the
    # CAV's own speed counts where it is faster than the cruise (25 m/s: 500 m).
    near = cav("c", 550.0, 1)
    assert view(near).ends_ahead(near) == {0}
    far = cav("c", 450.0, 1)
    assert view(far).ends_ahead(far) == set()
    fast = cav("c", 450.0, 1, v=25.0)
    assert view(fast).ends_ahead(fast) == {0}


def test_a_lane_that_ends_is_a_standing_obstacle_from_its_end_on():
    lanes = view(cav("c", 650.0, 1))
    (wall,) = lanes.end_obstacles("e", 600.0, 1000.0)
    assert wall.vehicle_id == f"{LANE_END_PREFIX}0@900" and wall.lane == 0
    assert wall.rear_s_m == pytest.approx(LANE_0_ENDS_M) and wall.speed_mps == 0.0
    assert wall.length_m == LANE_END_LENGTH_M
    assert lanes.end_obstacles("e", 0.0, 800.0) == [] and lanes.end_obstacles(None, 0, 1e4) == []


def test_a_blocked_hv_is_held_at_most_max_block_s_and_its_braking_is_watched():
    blocks = BlockWatch()
    blocks.blocked("hv", 10.0, 16.0)
    blocks.blocked("hv", 13.0, 15.0)  # a later plan: blocked since 10 s, still until 16 s
    assert blocks.since_s == {"hv": 10.0} and blocks.until_s == {"hv": 16.0}
    # 10 s at most, 4 s used at 14 s: two more 3 s behaving steps; none once past.
    assert blocks.budget(14.0, 10.0, 3.0) == {"hv": 2}
    assert blocks.budget(25.0, 10.0, 3.0) == {"hv": 0}
    braking = {"hv": VehicleState("hv", 0.0, 0, 0.0, 15.0, 5.0, -1.5)}
    blocks.watch(18.0, braking, grace_s=3.0)  # within the interval after its release
    blocks.watch(20.0, {"hv": VehicleState("hv", 0.0, 0, 0.0, 15.0, 5.0, -3.0)}, grace_s=3.0)
    assert blocks.strongest() == -1.5  # the -3 m/s^2 at 20 s came after 16 + 3 s
    blocks.new_manoeuvre()  # a new manoeuvre forgets who is blocked, not how hard they braked
    assert blocks.since_s == {} and blocks.budget(30.0, 10.0, 3.0) == {}
    assert blocks.strongest() == -1.5


def test_the_planner_block_of_a_run_without_solves():
    block = PlanStats().block()
    assert block["solves"] == 0 and block["fallbacks"] == 0
    assert block["grid_retries"] == {"tried": 0, "planned": 0}
    assert block["statuses"] == {} and block["triggers"] == {}


def test_a_give_up_that_leaves_cavs_on_both_sides_of_the_target_starts_the_wait():
    sc = Scenario(name="t", path=None)
    ctx = run_context(FakeSession(), sc, ROAD)
    reformer = Reformer(sc, lambda vid: DriverModel(model="unknown"))
    cruiser = Cruiser(ctx, reformer, decider=None, lanes=None, tracker=None)
    truck = VehicleState("truck", 300.0, 1, 0.0, 15.0, 12.0)
    past, behind = cav("c0", 340.0, 1), cav("c1", 270.0, 1)
    cruiser.wait_if_split(30.0, truck, {"c0": past})  # all past: nothing to wait for
    cruiser.wait_if_split(30.0, truck, {"c1": behind})  # none past: nothing either
    assert cruiser.waits_started == 0 and reformer.waiting is None
    cruiser.wait_if_split(30.0, truck, {"c0": past, "c1": behind})
    assert cruiser.waits_started == 1
    assert reformer.waiting == ("truck", 30.0, 30.0 + WAIT_AHEAD_S)
    assert said(ctx) == [("wait_start", {"slow": "truck", "past": 1, "behind": 1, "until_s": 75.0})]


class _FailingManoeuvre:
    """A manoeuvre planner whose solver never finds a plan (it counts the calls)."""

    def __init__(self):
        self.calls = []
        self.planner = types.SimpleNamespace(plan=lambda problem: None)  # no warm-start hint

    def plan(self, t_s, reason, *args, **kwargs):
        self.calls.append((t_s, reason, kwargs["grid_speed_mps"]))
        record = {"time_s": t_s, "trigger": reason, "status": "error"}
        return PlanOutcome(plan=None, grid=None, problem=None, record=record)


def test_a_failed_solve_is_a_fallback_recorded_and_retried_after_retry_after_s():
    sc = Scenario(name="t", path=None)
    truck = VehicleState("truck", 300.0, 1, 0.0, 15.0, 12.0)
    cavs = [cav("c0", 280.0, 1, 15.0), cav("c1", 265.0, 1, 15.0)]
    states = {v.vehicle_id: v for v in [truck, *cavs]}
    ctx = run_context(FakeSession(states), sc, ROAD, cav_ids=["c0", "c1"])
    manoeuvre, stats, resets = _FailingManoeuvre(), PlanStats(), []
    decider = types.SimpleNamespace(speed_cap=lambda platoon: 25.0,
                                    keep_right_closure=lambda *args: None)  # fmt: skip
    replanner = Replanner(
        ctx, manoeuvre, sc.planner, decider=decider, lanes=LaneView(ctx),
        model_of=lambda vid: DriverModel(model="unknown"), planlog=PlanLog(None),
        tracker_reset=lambda: resets.append(1), stats=stats, blocks=BlockWatch(),
    )  # fmt: skip
    progress = Progress(0.0)
    replanner.start()
    replanner.maybe_replan(1.0, states, ["c0", "c1"], "truck", progress)
    assert manoeuvre.calls == [(1.0, "initial", 15.0)]  # the grid at the target's speed
    assert replanner.plan is None and progress.failing and not resets
    assert stats.fallbacks == 1 and stats.statuses == {"error": 1}
    assert stats.triggers == {"initial": 1}
    assert said(ctx) == [("planner_fallback", {"trigger": "initial", "kept_last_plan": False})]
    # Nothing is asked again before RETRY_AFTER_S (1 s) has passed; then it is.
    replanner.maybe_replan(1.5, states, ["c0", "c1"], "truck", progress)
    assert len(manoeuvre.calls) == 1
    replanner.maybe_replan(1.0 + RETRY_AFTER_S + 0.1, states, ["c0", "c1"], "truck",
                           progress)  # fmt: skip
    assert len(manoeuvre.calls) == 2 and stats.fallbacks == 2
    assert stats.block()["solves"] == 0  # no solver ran to a result


def test_a_lane_the_target_comes_to_want_is_closed_by_a_replan_once():
    # The plan in force was made with the target's right lane open; then its driver shows
    # it wants to move there (Decider.keep_right_closure): the replanner asks for a plan
    # without that lane ("keep_right"), once: not again while that plan's lane is closed.
    sc = Scenario(name="t", path=None)
    truck = VehicleState("truck", 300.0, 1, 0.0, 15.0, 12.0)
    states = {"truck": truck, "c0": cav("c0", 280.0, 1, 15.0)}
    ctx = run_context(FakeSession(), sc, ROAD, cav_ids=["c0"])
    closure = {"lane": None}
    decider = types.SimpleNamespace(speed_cap=lambda platoon: 25.0,
                                    keep_right_closure=lambda *args: closure["lane"])  # fmt: skip
    replanner = Replanner(
        ctx, _FailingManoeuvre(), sc.planner, decider=decider, lanes=LaneView(ctx),
        model_of=lambda vid: DriverModel(model="unknown"), planlog=PlanLog(None),
        tracker_reset=lambda: None, stats=PlanStats(), blocks=BlockWatch(),
    )  # fmt: skip
    progress = Progress(0.0)
    replanner.start()
    assert not replanner._lane_to_close(1.0, states, "truck", progress)  # nothing wanted
    closure["lane"] = 0
    assert replanner._lane_to_close(1.0, states, "truck", progress)
    assert not replanner._lane_to_close(1.0, states, "gone", progress)  # no target: no replan
    replanner.closed_lane = 0  # the plan made then kept out of it
    assert not replanner._lane_to_close(2.0, states, "truck", progress)
    replanner.start()  # a new manoeuvre: its first plan decides afresh
    assert replanner.closed_lane is None


class _FixedTracker:
    """A tracker that asks every CAV for the same command (injected as the controller's is)."""

    def __init__(self, accel_mps2=0.0, dlat_m=0.0):
        self.cmd = TrackCommand(accel_mps2, dlat_m, 0.0, 0.0)
        self.held = []

    def tick(self):
        return True

    def command(self, t_s, ego, ref, road, dt_s, solve):
        return self.cmd

    def commit(self, ego, cmd, held, road, dt_s):
        self.held.append(held)


def follower_run(ego, others=(), tracker=None, steps=1):
    """Drive ``ego`` with a PlanFollower for ``steps`` steps of 0.1 s: the commands and events."""
    scenario = Scenario(name="t", path=None)
    commands = []
    states = {v.vehicle_id: v for v in (ego, *others)}
    session = FakeSession(
        states,
        set_speed=lambda vid, v: commands.append(("speed", vid, v)),
        change_sublane=lambda vid, d: commands.append(("lat", vid, d)),
    )
    ctx = run_context(session, scenario, ROAD)
    tracker = tracker or _FixedTracker()
    idm = DriverModel(model="IDM", accel_mps2=2.6, decel_mps2=4.5, tau_s=1.0, min_gap_m=2.5,
                      desired_speed_mps=30.0)  # fmt: skip
    follower = PlanFollower(ctx, tracker, LaneView(ctx), lambda vid: idm)
    follower.new_manoeuvre()
    centre = types.SimpleNamespace(y_at_s=lambda s: ROAD.lane_centre_y(ego.lane))
    for k in range(steps):
        follower.drive(0.1 * k, states, [ego.vehicle_id], {ego.vehicle_id: centre}, cap_mps=25.0)
    return follower, tracker, commands, said(ctx)


def test_a_cav_above_the_cap_comes_down_to_it_at_cap_decel_mps2(monkeypatch):
    fast = cav("c", 300.0, 1, 30.0)
    _, _, commands, _ = follower_run(fast)
    assert commands[0] == ("speed", "c", pytest.approx(30.0 - 2.0 * 0.1))
    monkeypatch.setattr(follower, "CAP_DECEL_MPS2", 4.0)
    _, _, commands, _ = follower_run(fast)
    assert commands[0] == ("speed", "c", pytest.approx(30.0 - 4.0 * 0.1))
    # At the cap it drives on at the tracker's acceleration.
    monkeypatch.undo()
    _, _, commands, _ = follower_run(cav("c", 300.0, 1, 24.0), tracker=_FixedTracker(1.0))
    assert commands[0] == ("speed", "c", pytest.approx(24.1))


def test_a_lane_change_the_guard_refuses_is_held_and_counted_once_per_episode():
    # The CAV's side is at the line to lane 2; an HV there 5 m behind closes in at 8 m/s.
    ego = cav("c", 300.0, 1, 20.0, lat=1.0)
    hv = VehicleState("hv", 290.0, 2, 0.0, 28.0, 5.0)
    follower, tracker, commands, events = follower_run(
        ego, [hv], _FixedTracker(dlat_m=0.1), steps=3
    )
    assert [c for c in commands if c[0] == "lat"] == [("lat", "c", 0.0)] * 3
    assert tracker.held == [True] * 3
    assert [e[0] for e in events] == ["lateral_hold"]  # three steps, one episode
    assert follower.holds == 1 and follower.holds_per_manoeuvre == [1]
    # With the lane beside free the move goes ahead.
    _, tracker, commands, events = follower_run(ego, [], _FixedTracker(dlat_m=0.1))
    assert ("lat", "c", 0.1) in commands and tracker.held == [False] and events == []


@pytest.mark.parametrize("may_part", [True, False])
def test_a_swarm_waiting_for_its_target_to_leave_parts_where_it_may(may_part):
    # The car holding the platoon back wants to move right and is free to (SUMO's wish): the
    # weighing chooses to wait for it. What waiting gains, each CAV gains on its own, so a
    # swarm that may part (many swarms) hands its CAVs back to SUMO once it has weighed; the
    # paper's one swarm (may_part false) waits as a platoon.
    states = {
        "slow": VehicleState("slow", 140.0, 1, 0.0, 12.0, 5.0, 0.0, False),
        "a0": cav("a0", 110.0, 1, v=12.0),
        "a1": cav("a1", 95.0, 1, v=12.0),
    }
    session = FakeSession(
        states, lane_wish=lambda vid: (-1, False) if vid == "slow" else (0, False)
    )
    ctx = run_context(session, cav_ids=("a0", "a1"))
    swarm = SwarmController()
    swarm.may_part = may_part
    swarm.attach(ctx)
    try:
        for i in range(100):  # 10 s
            session.time_s = 0.1 * i
            swarm.control(session.time_s)
            if swarm.nothing_pays:
                break
        chosen = [d["chosen"] for kind, d in said(ctx) if kind == "overtake_weighed"]
        assert chosen == ["wait"]
        assert swarm.nothing_pays is may_part and swarm.book.started == 0
    finally:
        swarm.close()
