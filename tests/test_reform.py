"""Re-forming the platoon while cruising, without SUMO: the lane, each CAV's goal, the moves."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import pytest

from sumo_swarm.config import Scenario
from sumo_swarm.controllers import reform
from sumo_swarm.controllers.reform import Reformer
from sumo_swarm.core.hvmodel import DriverModel
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.swarming.guards import run_up

ROAD = RoadSection((3.2, 3.2, 3.2))
SCENARIO = Scenario(name="t", path=Path("t.toml"))  # cruise 20 m/s, min gain 2 m/s


def car(vid, s, lane, v, *, cav=False, lat=0.0):
    return VehicleState(vid, s, lane, lat, v, 5.0, 0.0, cav)


def reformer(events=None):
    def event(kind, **data):
        if events is not None:
            events.append((kind, data))

    return Reformer(SCENARIO, lambda vid: DriverModel(desired_speed_mps=30.0), event)


def states(*vehicles):
    return {v.vehicle_id: v for v in vehicles}


def test_lane_is_the_fastest_one_the_cavs_are_in_and_sticks():
    events = []
    r = reformer(events)
    st = states(
        car("c0", 200.0, 1, 18.0, cav=True), car("c1", 185.0, 0, 18.0, cav=True),
        car("slow", 230.0, 1, 14.0),
    )  # fmt: skip
    assert r.lane(st, ["c0", "c1"], ROAD, ending=(), cap_mps=25.0) == 0  # lane 1 is held at 14
    assert events == [("reform_lane", {"lane": 0, "lane_speeds_mps": {"0": 25.0, "1": 14.0}})]
    # The slow car speeds up to 24: lane 1 is 1 m/s slower than lane 0, not 2: the choice stays.
    st["slow"] = car("slow", 230.0, 1, 24.0)
    assert r.lane(st, ["c0", "c1"], ROAD, ending=(), cap_mps=25.0) == 0
    # A lane that ends ahead is never chosen while another is left.
    r.reset()
    st["slow"] = car("slow", 230.0, 1, 14.0)
    assert r.lane(st, ["c0", "c1"], ROAD, ending={0}, cap_mps=25.0) == 1


def test_a_cav_still_beside_the_road_is_counted_in_the_lane_it_merges_into():
    # An acceleration lane is -1 of the road (beside lane 0): the platoon's lane is one of the
    # road's, whichever CAV is still on the ramp, and so is the lane of a slow car it waits
    # at there.
    r = reformer()
    st = states(car("c0", 200.0, 0, 18.0, cav=True), car("c1", 185.0, -1, 18.0, cav=True))
    assert r.lane(st, ["c0", "c1"], ROAD, ending=(), cap_mps=25.0) == 0
    r.reset()
    st = states(car("c0", 200.0, -1, 18.0, cav=True), car("c1", 185.0, -1, 18.0, cav=True))
    assert r.lane(st, ["c0", "c1"], ROAD, ending=(), cap_mps=25.0) == 0
    r.reset()
    r.waiting = ("slow",)
    st["slow"] = car("slow", 230.0, -1, 5.0)
    assert r.lane(st, ["c0", "c1"], ROAD, ending=(), cap_mps=25.0) == 0


def test_all_in_one_lane_keeps_it_without_looking_around():
    r = reformer()
    st = states(car("c0", 200.0, 2, 18.0, cav=True), car("c1", 185.0, 2, 18.0, cav=True))
    assert r.lane(st, ["c0", "c1"], ROAD, ending=(), cap_mps=25.0) == 2


def test_a_cav_cut_off_by_a_slow_vehicle_passes_it_and_comes_back():
    events = []
    r = reformer(events)
    st = states(
        car("c0", 300.0, 1, 20.0, cav=True),
        car("slow", 240.0, 1, 12.0),
        car("c1", 220.0, 1, 12.0, cav=True),
        car("c2", 205.0, 1, 12.0, cav=True),  # behind c1, which is cut off too
        car("left", 400.0, 2, 13.0),  # lane 2 is barely faster than the slow car
    )  # fmt: skip
    platoon = ["c0", "c1", "c2"]
    goals = r.goals(0.0, st, platoon, ROAD, 1, cap_mps=25.0)
    assert goals == {"c0": 1, "c1": 0, "c2": 1}  # lane 0 is free: c1 passes there
    assert events == [("passing_start", {"vehicle": "c1", "slow": "slow", "lane": 0})]
    # c1 is past the slow car: back to the platoon's lane; c2 is now cut off and passes.
    st["c1"] = car("c1", 255.0, 0, 20.0, cav=True)
    goals = r.goals(5.0, st, platoon, ROAD, 1, cap_mps=25.0)
    assert goals == {"c0": 1, "c1": 1, "c2": 0}
    assert events[1] == ("passing_end", {"vehicle": "c1", "slow": "slow", "past": True})
    # Passing gives up after MAX_PASS_S.
    goals = r.goals(5.0 + reform.MAX_PASS_S + 0.1, st, platoon, ROAD, 1, cap_mps=25.0)
    assert goals["c2"] == 1 and events[-1][1] == {"vehicle": "c2", "slow": "slow", "past": False}


def _decider(wishing):
    """A Decider over a session whose drivers keep right and where those in ``wishing`` want
    to move right now (SUMO's lane-change state)."""
    from sumo_swarm.controllers.decider import Decider
    from sumo_swarm.controllers.lanes import LaneView
    from tests.fakes import FakeSession, run_context

    session = FakeSession(keeps_right=lambda vid: True, wants_right=lambda vid: vid in wishing)
    ctx = run_context(session, SCENARIO, ROAD)
    return Decider(ctx, lanes=LaneView(ctx), reformer=None, planner=SCENARIO.planner,
                   model_of=lambda vid: DriverModel(model="unknown"))  # fmt: skip


def test_no_pass_on_the_right_of_a_slow_vehicle_that_wants_to_move_there():
    # The slow car in the middle lane wants to move right to keep right (SUMO's lane-change
    # state): c1 passes it on its left, although lane 0 is the faster one; a slow car in
    # the leftmost lane (no lane on its left) is still passed on its right.
    events = []
    r = reformer(events)
    r.lane_wanted_right = _decider(wishing={"slow"}).lane_wanted_right
    st = states(
        car("c0", 300.0, 1, 20.0, cav=True),
        car("slow", 240.0, 1, 12.0),
        car("c1", 220.0, 1, 12.0, cav=True),
        car("left", 400.0, 2, 16.0),  # lane 2 is 4 m/s faster than the slow car, lane 0 free
    )  # fmt: skip
    assert r.goals(0.0, st, ["c0", "c1"], ROAD, 1, cap_mps=25.0) == {"c0": 1, "c1": 2}
    assert events == [("passing_start", {"vehicle": "c1", "slow": "slow", "lane": 2})]
    r = reformer()
    r.lane_wanted_right = _decider(wishing={"slow"}).lane_wanted_right
    st = states(car("c0", 300.0, 2, 20.0, cav=True), car("slow", 240.0, 2, 12.0),
                car("c1", 220.0, 2, 12.0, cav=True))  # fmt: skip
    assert r.goals(0.0, st, ["c0", "c1"], ROAD, 2, cap_mps=25.0) == {"c0": 2, "c1": 1}


def test_cavs_cut_off_by_a_slow_vehicle_pass_it_in_a_train():
    # c1 passes the slow car in lane 0; once its centre is in lane 0, c2 follows it there at
    # once (as SUMO's drivers overtake) instead of waiting until c1 is past (5-6 s a CAV).
    events = []
    r = reformer(events)
    st = states(
        car("c0", 300.0, 1, 20.0, cav=True),
        car("slow", 240.0, 1, 12.0),
        car("c1", 220.0, 1, 12.0, cav=True),
        car("c2", 205.0, 1, 12.0, cav=True),
        car("left", 400.0, 2, 13.0),
    )  # fmt: skip
    platoon = ["c0", "c1", "c2"]
    assert r.goals(0.0, st, platoon, ROAD, 1, cap_mps=25.0) == {"c0": 1, "c1": 0, "c2": 1}
    # c1 leans into lane 0, its centre still in lane 1: c2 waits.
    st["c1"] = car("c1", 222.0, 1, 13.0, cav=True, lat=-1.0)
    assert r.goals(0.5, st, platoon, ROAD, 1, cap_mps=25.0)["c2"] == 1
    # c1's centre is in lane 0, beside the slow car's rear: c2 passes behind it, in lane 0.
    st["c1"] = car("c1", 228.0, 0, 14.0, cav=True, lat=0.5)
    goals = r.goals(1.0, st, platoon, ROAD, 1, cap_mps=25.0)
    assert goals == {"c0": 1, "c1": 0, "c2": 0}
    assert events[-1] == ("passing_start", {"vehicle": "c2", "slow": "slow", "lane": 0})


def test_cavs_behind_an_hv_that_splits_the_platoon_pass_it():
    # An HV at 19.2 m/s between c0 (ahead, lane 1) and c1: not slow enough to be passed as a
    # slow vehicle (cruise 20 - gain 2 = 18), but it splits the platoon: c1 passes it in the
    # free lane 0, to re-form the platoon (below the cruise).
    events = []
    r = reformer(events)
    st = states(
        car("c0", 330.0, 1, 19.2, cav=True),
        car("hv", 250.0, 1, 19.2),
        car("c1", 235.0, 1, 19.2, cav=True),
        car("left", 400.0, 2, 19.2),
    )  # fmt: skip
    platoon = ["c0", "c1"]
    assert r.goals(0.0, st, platoon, ROAD, 1, cap_mps=25.0) == {"c0": 1, "c1": 0}
    assert events == [("passing_start", {"vehicle": "c1", "slow": "hv", "lane": 0})]
    # The same HV with no platoon CAV ahead of it in its lane is not passed.
    events.clear()
    r = reformer(events)
    st["c0"] = car("c0", 330.0, 2, 19.2, cav=True)
    assert r.goals(0.0, st, platoon, ROAD, 1, cap_mps=25.0)["c1"] == 1 and events == []
    # Nor one splitting the platoon above the cruise: it is not what holds c1 back.
    st["c0"] = car("c0", 330.0, 1, 20.5, cav=True)
    st["hv"] = car("hv", 250.0, 1, 20.5)
    assert r.goals(0.0, st, platoon, ROAD, 1, cap_mps=25.0)["c1"] == 1 and events == []


def test_past_the_target_the_platoon_reforms_in_its_regroup_lane():
    # Every CAV is past the truck, in lanes 0 and 2; the regroup lane (1, the original) is
    # free: the platoon re-forms there (the paper's Fig. 6 step 4), and stays with it while the
    # CAVs move over, although none is in it yet.
    r = reformer()
    r.prefer = (1, None)
    st = states(
        car("c0", 300.0, 0, 20.0, cav=True),
        car("c1", 285.0, 2, 20.0, cav=True),
        car("truck", 200.0, 1, 15.0),
    )  # fmt: skip
    assert r.lane(st, ["c0", "c1"], ROAD, ending=(), cap_mps=25.0) == 1
    assert r.lane(st, ["c0", "c1"], ROAD, ending=(), cap_mps=25.0) == 1
    # A slow car ahead in lane 1 (lane 0 faster by more than the gain): lane 0 instead, and
    # the preference is gone.
    r2 = reformer()
    r2.prefer = (1, None)
    slow = {**st, "car": car("car", 330.0, 1, 14.0)}
    assert r2.lane(slow, ["c0", "c1"], ROAD, ending=(), cap_mps=25.0) == 0
    assert r2.prefer is None
    # Not into a lane that ends.
    r3 = reformer()
    r3.prefer = (1, None)
    assert r3.lane(st, ["c0", "c1"], ROAD, ending={1}, cap_mps=25.0) != 1
    # Not when it takes more lane changes than where they are: both CAVs in lane 0, the
    # regroup lane 2 (stress scene 131: a CAV stranded at its lane's edge for 18 s crossing).
    r4 = reformer()
    r4.prefer = (2, None)
    both = {**st, "c1": car("c1", 285.0, 0, 20.0, cav=True)}
    assert r4.lane(both, ["c0", "c1"], ROAD, ending=(), cap_mps=25.0) == 0 and r4.prefer is None
    split = {**both, "c0": car("c0", 300.0, 1, 20.0, cav=True)}  # lanes 1 and 0: 1 beats 2
    r5 = reformer()
    r5.prefer = (2, None)
    assert r5.lane(split, ["c0", "c1"], ROAD, ending=(), cap_mps=25.0) != 2


def test_a_passing_lane_is_judged_over_the_length_of_the_pass(monkeypatch):
    # c1 is cut off by a 12 m/s car in lane 1. Lane 0 is free for 60 m (detect_range_m), but
    # a truck drives 11 m/s 120 m ahead there, within the 100 m the pass looks further
    # (PASS_REACH_S, 5 s at the cruise): c1 would end up behind it. It passes in lane 2.
    def goal(truck_ahead_m):
        r = Reformer(SCENARIO, lambda vid: DriverModel(desired_speed_mps=30.0))
        st = states(
            car("c0", 300.0, 1, 20.0, cav=True),
            car("slow", 240.0, 1, 12.0),
            car("c1", 220.0, 1, 12.0, cav=True),
            car("truck", 220.0 + truck_ahead_m, 0, 11.0),
            car("left", 290.0, 2, 16.0),  # lane 2: 16 m/s
        )  # fmt: skip
        return r.goals(0.0, st, ["c0", "c1"], ROAD, 1, cap_mps=25.0)["c1"]

    assert goal(120.0) == 2
    assert goal(200.0) == 0  # beyond the pass's reach: lane 0 is free for it
    monkeypatch.setattr(reform, "PASS_REACH_S", 0.0)
    assert goal(120.0) == 0  # detect_range_m only: the former rule


def passing_on_the_right(events):
    """c1, cut off from c0 by a slow car in lane 1, starts passing it in lane 0."""
    r = reformer(events)
    st = states(
        car("c0", 300.0, 1, 20.0, cav=True),
        car("slow", 240.0, 1, 12.0),
        car("c1", 220.0, 1, 12.0, cav=True),
    )  # fmt: skip
    platoon = ["c0", "c1"]
    assert r.goals(0.0, st, platoon, ROAD, 1, cap_mps=25.0)["c1"] == 0  # passes on the right
    return r, st, platoon


def test_passing_ends_when_the_slow_vehicle_moves_into_the_passing_lane_ahead():
    events = []
    r, st, platoon = passing_on_the_right(events)
    # c1 is in lane 0 now; the slow car keeps right, into lane 0 ahead of it: passing there
    # would only follow it. c1 heads back for the platoon's lane, free now.
    st["c1"] = car("c1", 222.0, 0, 13.0, cav=True)
    st["slow"] = car("slow", 243.0, 0, 12.0)
    goals = r.goals(2.0, st, platoon, ROAD, 1, cap_mps=25.0)
    assert goals["c1"] == 1 and "c1" not in r.passing
    assert events[-1] == ("passing_end", {"vehicle": "c1", "slow": "slow", "past": False})
    # The slow car stays in lane 1: c1 goes on passing it in lane 0.
    r2 = reformer()
    start = {**st, "c1": car("c1", 220.0, 1, 12.0, cav=True), "slow": car("slow", 240.0, 1, 12.0)}
    r2.goals(0.0, start, platoon, ROAD, 1, cap_mps=25.0)
    stays = {**st, "slow": car("slow", 243.0, 1, 12.0)}
    assert r2.goals(2.0, stays, platoon, ROAD, 1, cap_mps=25.0)["c1"] == 0


def test_passing_ends_when_the_slow_vehicle_leaves_to_the_other_side():
    events = []
    r, st, platoon = passing_on_the_right(events)
    # Held in lane 1, c1 sees the slow car move over to lane 2, away from the passing lane:
    # nothing is left to pass; c1 stays with the platoon's lane.
    st["slow"] = car("slow", 243.0, 2, 12.0)
    goals = r.goals(2.0, st, platoon, ROAD, 1, cap_mps=25.0)
    assert goals["c1"] == 1 and "c1" not in r.passing
    assert events[-1] == ("passing_end", {"vehicle": "c1", "slow": "slow", "past": False})


def test_no_pass_of_a_slow_vehicle_already_leaving_the_lane():
    events = []
    r = reformer(events)
    # The slow car's centre is across the line into lane 0 (lat -1.7 in lane 1), its body still
    # ahead of c1: c1 does not start passing it (it would end the pass the next step, as the
    # car left its lane, and start again: a passing_start/passing_end pair every step).
    st = states(
        car("c0", 300.0, 1, 20.0, cav=True),
        car("slow", 240.0, 1, 12.0, lat=-1.7),
        car("c1", 220.0, 1, 12.0, cav=True),
    )  # fmt: skip
    assert r.goals(0.0, st, ["c0", "c1"], ROAD, 1, cap_mps=25.0)["c1"] == 1
    assert "c1" not in r.passing and not events


def test_a_slow_car_merging_from_beside_the_road_is_passed_as_one_in_the_lane():
    # An acceleration lane is -1 of the road: a car standing at its end, leaning into lane 0
    # (its body ahead of c1's), is in none of the road's lanes but merges into lane 0, where
    # c1 is held behind it. c1 passes it in lane 1, and goes on passing it (not "gone": it is
    # not two lanes from the passing lane, it merges beside it). (On the users' 5-lane road,
    # 40 % CAVs, a platoon's CAV followed such a car down to 1.4 m/s, the lane stopping.)
    events = []
    r = reformer(events)
    merging = car("merging", 240.0, -1, 1.0, lat=1.2)
    st = states(
        car("c0", 300.0, 0, 20.0, cav=True), merging, car("c1", 230.0, 0, 12.0, cav=True)
    )  # fmt: skip
    assert r.goals(0.0, st, ["c0", "c1"], ROAD, 0, cap_mps=25.0)["c1"] == 1
    assert events == [("passing_start", {"vehicle": "c1", "slow": "merging", "lane": 1})]
    assert r.goals(0.2, st, ["c0", "c1"], ROAD, 0, cap_mps=25.0)["c1"] == 1
    assert "c1" in r.passing and len(events) == 1
    # One that keeps to its lane beside the road (not reaching into lane 0) holds nobody.
    r2, quiet = reformer([]), {**st, "merging": replace(merging, lat_m=0.0)}
    assert r2.goals(0.0, quiet, ["c0", "c1"], ROAD, 0, cap_mps=25.0)["c1"] == 0


def test_after_a_give_up_the_leader_too_passes_the_target_on_its_own():
    events = []
    r = reformer(events)
    st = states(
        car("truck", 260.0, 1, 12.0),
        car("c0", 240.0, 1, 12.0, cav=True),
        car("c1", 225.0, 1, 12.0, cav=True),
    )  # fmt: skip
    platoon = ["c0", "c1"]
    # The swarm decides for its leader: no passing of its own.
    assert r.goals(0.0, st, platoon, ROAD, 1, cap_mps=25.0) == {"c0": 1, "c1": 1}
    r.singly = ("truck", 60.0)  # the swarm gave up overtaking the truck together
    goals = r.goals(1.0, st, platoon, ROAD, 1, cap_mps=25.0)
    assert goals == {"c0": 0, "c1": 1}  # lane 0 first when both sides are free
    assert events == [("passing_start", {"vehicle": "c0", "slow": "truck", "lane": 0})]
    # Another slow vehicle, or the time is over: the swarm decides again.
    r2 = reformer()
    r2.singly = ("someone_else", 60.0)
    assert r2.goals(1.0, st, platoon, ROAD, 1, cap_mps=25.0) == {"c0": 1, "c1": 1}
    r2.singly = ("truck", 60.0)
    assert r2.goals(61.0, st, platoon, ROAD, 1, cap_mps=25.0) == {"c0": 1, "c1": 1}


def test_no_passing_when_no_lane_beside_is_faster_by_the_gain():
    r = reformer()
    st = states(
        car("c0", 300.0, 1, 20.0, cav=True), car("slow", 240.0, 1, 12.0),
        car("c1", 220.0, 1, 12.0, cav=True), car("l0", 250.0, 0, 13.0), car("l2", 250.0, 2, 13.5),
    )  # fmt: skip
    assert r.goals(0.0, st, ["c0", "c1"], ROAD, 1, cap_mps=25.0) == {"c0": 1, "c1": 1}


def test_a_merging_cav_drops_in_behind_and_the_one_behind_opens_a_gap():
    r = reformer()
    st = states(
        car("c0", 300.0, 1, 20.0, cav=True),
        # next to c0's tail, at the edge of its lane: must drop back before it may cross
        car("c1", 292.0, 0, 20.0, cav=True, lat=0.8),
        car("c2", 280.0, 1, 20.0, cav=True),  # behind c1's position in lane 1
    )  # fmt: skip
    platoon = ["c0", "c1", "c2"]
    moves = r.moves(st, platoon, ROAD, 1, {"c0": 1, "c1": 1, "c2": 1}, 0.1)
    dlat, bound = moves["c1"]
    assert dlat == 0.0  # held: c0's rear is 3 m ahead, under the minimum gap
    gentle = -SCENARIO.hvmodel.planner_share * SCENARIO.hvmodel.b_safe_mps2
    assert bound == pytest.approx(gentle)  # it drops back behind c0, gently
    # c2 follows c1 as if c1 were in its lane already (gap 7 m < desired): it slows too.
    assert moves["c2"][1] < 0.0
    assert moves["c0"] == (0.0, math.inf)  # in its lane, centred: nothing to do
    # With room, the merging CAV moves over at the lateral speed limit.
    st["c1"] = car("c1", 270.0, 0, 20.0, cav=True, lat=0.8)
    st["c2"] = car("c2", 250.0, 1, 20.0, cav=True)
    dlat, _ = r.moves(st, platoon, ROAD, 1, {"c0": 1, "c1": 1, "c2": 1}, 0.1)["c1"]
    assert dlat == pytest.approx(SCENARIO.cav.max_lateral_speed_mps * 0.1)


def test_a_cav_held_out_of_its_passing_lane_tries_the_other_side():
    events = []
    r = reformer(events)
    st = states(
        car("c0", 300.0, 1, 20.0, cav=True),
        car("slow", 240.0, 1, 12.0),
        car("c1", 220.0, 1, 12.0, cav=True, lat=-0.6),  # at its lane's edge, where it is held
        # just behind c1 in lane 0, where nothing is ahead (1 m from c1's rear: the guard holds)
        car("beside", 214.0, 0, 12.0),
        car("l2", 300.0, 2, 16.0),  # lane 2 is faster than the slow car, by less than lane 0
    )  # fmt: skip
    platoon = ["c0", "c1"]
    goals = r.goals(0.0, st, platoon, ROAD, 1, cap_mps=25.0)
    assert goals["c1"] == 0 and events[-1][0] == "passing_start"
    switch_s = reform.PASS_SWITCH_S
    t, dt = 0.0, 0.1
    while t < switch_s - dt / 2:  # the guard holds c1: a car right behind it in lane 0
        assert r.moves(st, platoon, ROAD, 1, goals, dt)["c1"][0] == 0.0
        t += dt
        goals = r.goals(t, st, platoon, ROAD, 1, cap_mps=25.0)
        assert goals["c1"] == (2 if t >= switch_s - dt / 2 else 0)
    assert events[-1] == (
        "passing_switch",
        {"vehicle": "c1", "slow": "slow", "held_lane": 0, "lane": 2},
    )
    assert r.passing["c1"] == ("slow", 2, 0.0)  # MAX_PASS_S still counts from the start
    assert r.moves(st, platoon, ROAD, 1, goals, dt)["c1"][0] > 0.0  # lane 2 is free: it goes
    assert "c1" not in r.held_s


def _held_towards_lane_0(open_side, dt=0.1):
    """c1 behind a slow car in lane 1, passing in lane 0, held there by a car right behind it
    in lane 0; lane 2 is free or (``open_side`` false) a car there is right behind c1 too.
    Returns the time at which c1 switches to lane 2 (None: not within PASS_SWITCH_S)."""
    events = []
    r = reformer(events)
    st = states(
        car("c0", 300.0, 1, 20.0, cav=True),
        car("slow", 240.0, 1, 12.0),
        car("c1", 220.0, 1, 12.0, cav=True, lat=-0.6),
        car("beside", 214.0, 0, 12.0),
        car("l2", 300.0, 2, 16.0),
    )  # fmt: skip
    if not open_side:
        st["behind2"] = car("behind2", 213.0, 2, 16.0)  # closing in on c1's rear in lane 2
    platoon = ["c0", "c1"]
    goals = r.goals(0.0, st, platoon, ROAD, 1, cap_mps=25.0, step_s=dt)
    assert goals["c1"] == 0
    t = 0.0
    while t < reform.PASS_SWITCH_S - 1.5 * dt:
        assert r.moves(st, platoon, ROAD, 1, goals, dt)["c1"][0] == 0.0  # held
        t += dt
        goals = r.goals(t, st, platoon, ROAD, 1, cap_mps=25.0, step_s=dt)
        if goals["c1"] == 2:
            assert events[-1] == (
                "passing_switch",
                {"vehicle": "c1", "slow": "slow", "held_lane": 0, "lane": 2, "open": True},
            )
            assert r.moves(st, platoon, ROAD, 1, goals, dt)["c1"][0] > 0.0  # and it goes
            return t
    return None


def test_a_held_cav_switches_at_once_to_the_other_side_when_that_opens():
    # Lane 2 would let c1 in: it switches once held for PASS_OPEN_SIDE_S, not PASS_SWITCH_S.
    t = _held_towards_lane_0(open_side=True)
    assert t == pytest.approx(reform.PASS_OPEN_SIDE_S, abs=0.11)
    # Lane 2 would refuse it too (a car closing in right behind): it keeps waiting for lane 0.
    assert _held_towards_lane_0(open_side=False) is None


def test_a_cav_held_out_of_the_platoons_lane_behind_a_slow_car_passes_on_the_other_side():
    events = []
    r = reformer(events)
    st = states(
        car("c0", 300.0, 1, 20.0, cav=True),
        car("c1", 220.0, 0, 12.0, cav=True, lat=0.6),  # in lane 0, the platoon in lane 1
        car("slow", 240.0, 0, 12.0),  # ahead of c1 in lane 0
        car("beside", 219.0, 1, 12.0),  # alongside c1 in the platoon's lane
    )  # fmt: skip
    platoon = ["c0", "c1"]
    goals = r.goals(0.0, st, platoon, ROAD, 1, cap_mps=25.0)
    assert goals["c1"] == 1
    for _ in range(round(reform.PASS_SWITCH_S / 0.1)):
        assert r.moves(st, platoon, ROAD, 1, goals, 0.1)["c1"][0] == 0.0  # held
    # Lane 0 is the rightmost: no other side. From lane 1 the other side of lane 0 is lane 2.
    assert r.goals(6.0, st, platoon, ROAD, 1, cap_mps=25.0)["c1"] == 1
    assert not any(kind == "passing_switch" for kind, _ in events)
    st["c1"] = car("c1", 220.0, 1, 12.0, cav=True, lat=-0.6)  # in lane 1, for lane 0
    st["slow"] = car("slow", 240.0, 1, 12.0)
    st["beside"] = car("beside", 219.0, 0, 12.0)
    goals = r.goals(6.0, st, platoon, ROAD, 0, cap_mps=25.0)
    assert goals["c1"] == 0
    for _ in range(round(reform.PASS_SWITCH_S / 0.1)):
        r.moves(st, platoon, ROAD, 0, goals, 0.1)
    assert r.goals(12.0, st, platoon, ROAD, 0, cap_mps=25.0)["c1"] == 2
    assert events[-1][0] == "passing_switch" and events[-1][1]["lane"] == 2


def test_a_cav_beside_a_platoon_cav_a_little_behind_it_drops_back_behind_it():
    # c2 merges into lane 0 right beside c0, its front 2 m ahead of c0's: to vehicle_ahead c0
    # is neither ahead nor behind. Both at 20 m/s, neither gave way (35 s side by side).
    r = reformer()
    st = states(
        car("c1", 315.0, 0, 20.0, cav=True),
        car("c0", 300.0, 0, 20.0, cav=True),
        car("c2", 302.0, 1, 20.0, cav=True, lat=-0.6),
        car("c3", 285.0, 0, 20.0, cav=True),
    )  # fmt: skip
    platoon = ["c1", "c0", "c2", "c3"]
    goals = {"c1": 0, "c0": 0, "c2": 0, "c3": 0}
    gentle = -SCENARIO.hvmodel.planner_share * SCENARIO.hvmodel.b_safe_mps2
    for _ in range(round(reform.DROP_BEHIND_S / 0.1)):
        dlat, bound = r.moves(st, platoon, ROAD, 0, goals, 0.1)["c2"]
        assert dlat == 0.0  # held: c0 is beside it
        assert bound > gentle  # not at once: it may be passing by
    dlat, bound = r.moves(st, platoon, ROAD, 0, goals, 0.1)["c2"]
    assert bound == pytest.approx(gentle)  # held for DROP_BEHIND_S: drops back behind c0
    # Once behind c0 it follows c0 at a real gap, and c3 makes room for it.
    st["c2"] = car("c2", 293.0, 1, 20.0, cav=True, lat=-0.6)
    moves = r.moves(st, platoon, ROAD, 0, goals, 0.1)
    assert moves["c2"][1] < 0.0 and moves["c3"][1] < 0.0


def test_run_up_speed_fits_the_room_behind_the_slow_vehicle():
    asked = []

    def entry_ok(v, tau):
        asked.append((v, tau))
        return True

    kw = dict(desired_gap_m=10.0, accel_mps2=3.0, brake_mps2=1.4, change_s=1.6, min_gain_mps=2.0)
    # 30 m above the desired gap: c * 1.6 + c^2 / 2.8 = 30 at c = 7.195 m/s.
    what, v = run_up(12.0, 12.0, 40.0, 25.0, entry_ok=entry_ok, **kw)
    assert what == "run" and v == pytest.approx(19.195, abs=1e-3)
    assert asked[-1][1] == pytest.approx(7.195 / 3.0, abs=1e-3)  # reached at 3 m/s^2
    # The next lane's speed is the most worth entering at.
    assert run_up(12.0, 12.0, 40.0, 15.0, entry_ok=entry_ok, **kw) == ("run", 15.0)
    assert asked[-1] == (15.0, pytest.approx(1.0))
    # Already faster than that: asked at its own speed, now.
    assert run_up(16.0, 12.0, 40.0, 15.0, entry_ok=entry_ok, **kw) == ("run", 16.0)
    assert asked[-1] == (16.0, 0.0)
    # A gap that takes it at 16.5 m/s at most: the fastest entry speed 1 m/s steps down to.
    what, v = run_up(12.0, 12.0, 40.0, 25.0, entry_ok=lambda v, t: v <= 16.5, **kw)
    assert what == "run" and v == pytest.approx(16.195, abs=1e-3)
    # No gap takes it: hold the run-up distance.
    assert run_up(12.0, 12.0, 40.0, 25.0, entry_ok=lambda v, t: False, **kw) == ("hold", 0.0)
    # Closing 6 m/s with 5 m above the desired gap: brake, at most at 1.4 m/s^2.
    assert run_up(18.0, 12.0, 15.0, 25.0, entry_ok=entry_ok, **kw) == ("brake", -1.4)
    # Closing 1 m/s with 3 m: c * 1.6 + c^2 / 2.8 = 1.96 < 3, room enough, no brake; but the
    # most it could enter at is 13.6 m/s, less than 2 m/s above the slow car: drop back more.
    assert run_up(13.0, 12.0, 13.0, 25.0, entry_ok=entry_ok, **kw) == ("hold", 0.0)
    # A gap only at 13.5 m/s: not worth a run-up either (the guard's own business).
    assert run_up(12.0, 12.0, 40.0, 25.0, entry_ok=lambda v, t: v <= 13.5, **kw)[0] == "hold"


def test_a_stranded_cav_holds_back_from_the_slow_car_then_runs_up_into_a_gap():
    r = reformer()
    platoon = ["c0", "c1"]
    goals = {"c0": 1, "c1": 1}

    def scene(slow_s, c1_speed=12.0, f_s=190.0):
        return states(
            car("c0", 400.0, 1, 20.0, cav=True),
            car("c1", 220.0, 0, c1_speed, cav=True, lat=0.6),  # behind a slow car, for lane 1
            car("slow", slow_s, 0, 12.0),
            car("f", f_s, 1, 20.0),  # lane 1 flows 8 m/s faster: at 12 m/s c1 is refused
        )

    gentle = -SCENARIO.hvmodel.planner_share * SCENARIO.hvmodel.b_safe_mps2
    # Refused, but not yet for run_up_after_s: it waits as before (no bound, no floor).
    dlat, bound = r.moves(scene(240.0), platoon, ROAD, 1, goals, 0.1)["c1"]
    assert dlat == 0.0 and bound > 0.0 and r.floors == {}
    r.held_s["c1"] = (1, reform.RUN_UP_AFTER_S)
    # 15 m behind the slow car, no gap takes it at the speed that room allows: it drops back.
    dlat, bound = r.moves(scene(240.0), platoon, ROAD, 1, goals, 0.1)["c1"]
    assert dlat == 0.0 and bound == pytest.approx(gentle) and r.floors == {}
    # Never more than RUN_UP_DROP_MPS below the slow car's speed.
    assert r.moves(scene(240.0, 9.9), platoon, ROAD, 1, goals, 0.1)["c1"][1] >= 0.0
    # 40 m behind it, f 10 m farther back: running up to 19.2 m/s (2.4 s), it would be taken
    # behind f: it accelerates at its maximum (a floor under the CACC, which would close in on
    # the slow car more slowly). With f where it was, no: it keeps its distance.
    r.held_s["c1"] = (1, reform.RUN_UP_AFTER_S)
    r.moves(scene(265.0), platoon, ROAD, 1, goals, 0.1)
    assert r.floors == {}
    r.held_s["c1"] = (1, reform.RUN_UP_AFTER_S)
    dlat, bound = r.moves(scene(265.0, f_s=180.0), platoon, ROAD, 1, goals, 0.1)["c1"]
    assert dlat == 0.0 and r.floors == {"c1": SCENARIO.cav.accel_max_mps2} and bound >= 3.0
    # An HV alongside in lane 1 as slow as the slow car: lane 1 is no faster, no run-up (it
    # drops in behind that HV as before).
    st = scene(240.0)
    st["beside"] = car("beside", 221.0, 1, 12.5)
    r.held_s["c1"] = (1, reform.RUN_UP_AFTER_S)
    r.moves(st, platoon, ROAD, 1, goals, 0.1)
    assert r.floors == {}
    # A CAV following in lane 1 instead of f: it makes room (no run-up, no drop back).
    cavs = scene(240.0)
    cavs["f"] = car("f", 190.0, 1, 20.0, cav=True)
    r.held_s["c1"] = (1, reform.RUN_UP_AFTER_S)
    assert r.moves(cavs, [*platoon, "f"], ROAD, 1, {**goals, "f": 1}, 0.1)["c1"][1] > gentle


def test_a_cav_enters_a_faster_lane_speeding_up_where_the_guard_then_takes_it():
    # SUMO's default Krauss driver (b = 4.5 m/s^2, Krauss brakes late) in lane 1 at 24 m/s,
    # 120 m behind a CAV at 12 m/s that heads for lane 1, 40 m behind a slow car. Entering at
    # 12 m/s it would close in at 12 m/s and brake harder than b_safe on arrival (refused);
    # entering speeding up at ENTRY_ACCEL_MPS2 to lane 1's 18 m/s (the cruise less the
    # leader's ease) the guard takes it, and the CAV gets that floor so that it does speed up.
    krauss = DriverModel("Krauss", 2.6, 4.5, 9.0, 1.0, 2.5, desired_speed_mps=30.0, sigma=0.0)
    r = Reformer(SCENARIO, lambda vid: krauss)

    def scene(slow_s=265.0):
        return states(
            car("c1", 220.0, 0, 12.0, cav=True, lat=0.6),
            car("slow", slow_s, 0, 12.0),
            car("f", 95.0, 1, 24.0),  # its front 120 m behind c1's rear
        )

    platoon, goals = ["c1"], {"c1": 1}
    dlat, _ = r.moves(scene(), platoon, ROAD, 1, goals, 0.1)["c1"]
    assert dlat > 0.0 and r.floors == {"c1": reform.ENTRY_ACCEL_MPS2}
    # No room to speed up behind the slow car during the lane change (6 m, under min_gap +
    # 1.5 * (3.2 m / max_lateral_speed)^2 / 2 = 5 + 1.92 m): it would enter at its speed, refused.
    r.scenario = SCENARIO
    assert SCENARIO.cav.max_lateral_speed_mps == 2.0
    dlat, _ = r.moves(scene(slow_s=231.0), platoon, ROAD, 1, goals, 0.1)["c1"]
    assert dlat == 0.0 and r.floors == {}


def held_beside_a_follower(hv_wants_mps, held_s):
    """c1 next to the platoon's lane 2, its move there held for ``held_s``, an HV following
    the platoon in lane 2 alongside it, wanting ``hv_wants_mps``; lane 1 ahead holds a car at
    21 m/s (faster than the 20 m/s cruise, slower than the 25 m/s cap)."""
    events = []
    wants = {"hv": hv_wants_mps}

    def event(kind, **data):
        events.append((kind, data))

    r = Reformer(SCENARIO, lambda vid: DriverModel(desired_speed_mps=wants.get(vid, 30.0)), event)
    r.held_s["c1"] = (2, held_s)
    st = states(
        car("c0", 300.0, 2, 20.0, cav=True),
        car("c1", 270.0, 1, 20.0, cav=True, lat=0.6),
        car("hv", 267.0, 2, 20.0),  # its front 3 m behind c1's: alongside
        car("ahead1", 350.0, 1, 21.0),
    )  # fmt: skip
    return r, st, events


def test_an_hv_following_the_platoon_beside_a_held_cav_is_pulled_away_from():
    # The HV wants 21 m/s: the platoon cruises 3 m/s faster (at most the cap) and leaves it
    # behind, so a gap opens behind c1.
    r, st, events = held_beside_a_follower(21.0, 3.5)
    assert r.pull_away(st, ["c0", "c1"], ROAD, 2, cap_mps=25.0) == pytest.approx(3.0)
    assert events == [("pull_away", {"vehicle": "c1", "follower": "hv", "boost_mps": 3.0})]
    assert r.pull_away(st, ["c0", "c1"], ROAD, 2, cap_mps=22.0) == pytest.approx(2.0)  # the cap
    # The condition lapsing for a step and back (noisy states) is not a new event.
    held = r.held_s.pop("c1")
    assert r.pull_away(st, ["c0", "c1"], ROAD, 2, cap_mps=25.0) == 0.0
    r.held_s["c1"] = held
    assert r.pull_away(st, ["c0", "c1"], ROAD, 2, cap_mps=25.0) == pytest.approx(3.0)
    assert len(events) == 1
    r.reset()  # a new manoeuvre: announced again
    r.pull_away(st, ["c0", "c1"], ROAD, 2, cap_mps=25.0)
    assert len(events) == 2
    # Not for an HV that wants as much as the faster cruise (it would follow), not before
    # PULL_AWAY_AFTER_S, not for a CAV still behind a slow car of its own lane.
    r, st, _ = held_beside_a_follower(33.0, 3.5)
    assert r.pull_away(st, ["c0", "c1"], ROAD, 2, cap_mps=25.0) == 0.0
    r, st, _ = held_beside_a_follower(21.0, 2.0)
    assert r.pull_away(st, ["c0", "c1"], ROAD, 2, cap_mps=25.0) == 0.0
    r, st, _ = held_beside_a_follower(21.0, 3.5)
    st["slow"] = car("slow", 290.0, 1, 14.0)
    assert r.pull_away(st, ["c0", "c1"], ROAD, 2, cap_mps=25.0) == 0.0


def test_the_platoon_moves_over_to_a_cav_an_hv_keeps_out_of_its_lane():
    # The HV wants 33 m/s, more than the platoon may drive: after REFORM_SWITCH_S the platoon
    # re-forms in c1's lane 1 (as fast at the cruise: its car ahead drives 21 m/s), and the HV
    # gets lane 2 back. The choice stays although lane 2 is free at the cap, and never goes
    # back to lane 2 on that edge.
    r, st, events = held_beside_a_follower(33.0, 5.0)
    r.lane_id = 2
    assert r.lane(st, ["c0", "c1"], ROAD, ending=(), cap_mps=25.0) == 2  # not yet
    r.held_s["c1"] = (2, 6.5)
    assert r.lane(st, ["c0", "c1"], ROAD, ending=(), cap_mps=25.0) == 1
    assert events[0] == (
        "reform_held", {"lane": 1, "left": 2, "vehicle": "c1", "follower": "hv"}
    )  # fmt: skip
    r.held_s.clear()
    assert r.lane(st, ["c0", "c1"], ROAD, ending=(), cap_mps=25.0) == 1
    # Not for an HV the platoon can pull away from (it wants 21 m/s): pull_away does it.
    r, st, events = held_beside_a_follower(21.0, 6.5)
    r.lane_id = 2
    assert r.lane(st, ["c0", "c1"], ROAD, ending=(), cap_mps=25.0) == 2 and not events
    # Not into a lane where the platoon would drive slower than the cruise by the gain.
    r, st, _ = held_beside_a_follower(33.0, 6.5)
    st["ahead1"] = car("ahead1", 340.0, 1, 15.0)
    r.lane_id = 2
    assert r.lane(st, ["c0", "c1"], ROAD, ending=(), cap_mps=25.0) == 2


def test_a_cav_held_beside_a_platoon_cav_does_not_turn_to_the_other_side():
    # As in the test above (c1 in lane 1 behind a slow car, held out of the platoon's lane 0
    # for PASS_SWITCH_S), but what holds it is a CAV of the platoon alongside in lane 0: the
    # platoon makes room (or c1 drops back behind it), so c1 keeps heading for lane 0.
    events = []
    r = reformer(events)
    st = states(
        car("c0", 300.0, 0, 20.0, cav=True),
        car("c2", 221.0, 0, 12.0, cav=True),  # alongside c1, its front 1 m ahead
        car("c1", 220.0, 1, 12.0, cav=True, lat=-0.6),
        car("slow", 240.0, 1, 12.0),
    )  # fmt: skip
    platoon = ["c0", "c2", "c1"]
    goals = r.goals(0.0, st, platoon, ROAD, 0, cap_mps=25.0)
    assert goals["c1"] == 0
    r.held_s["c1"] = (0, reform.PASS_SWITCH_S + 0.1)
    assert r.goals(6.5, st, platoon, ROAD, 0, cap_mps=25.0)["c1"] == 0
    assert not any(kind == "passing_switch" for kind, _ in events)
    # The same with an HV there instead: it passes on the other side.
    st["c2"] = car("c2", 221.0, 0, 12.0)
    r.held_s["c1"] = (0, reform.PASS_SWITCH_S + 0.1)
    assert r.goals(7.0, st, ["c0", "c1"], ROAD, 0, cap_mps=25.0)["c1"] == 2


def test_a_platoon_cav_slows_the_hv_beside_a_stranded_cav_so_it_can_get_in():
    # c2 is stuck behind a 14 m/s truck in lane 0, held out of the platoon's lane 1 for 3 s by
    # an HV alongside it there, which follows c1 (past the truck) closely and wants 20 m/s. c1
    # slows to 2 m/s below c2 (braking at most the planner's share of b_safe): the HV falls
    # back beside c2 until the guard lets c2 in ahead of it.
    events = []
    r = reformer(events)
    st = states(
        car("c0", 300.0, 1, 14.0, cav=True),
        car("c1", 275.0, 1, 14.0, cav=True),  # past the truck
        car("truck", 260.0, 0, 14.0),
        car("hv", 242.0, 1, 14.0),  # 28 m behind c1's rear: within twice its IDM gap
        car("c2", 243.0, 0, 14.0, cav=True, lat=0.6),  # at its lane's edge, held there
    )  # fmt: skip
    platoon = ["c0", "c1", "c2"]
    goals = {"c0": 1, "c1": 1, "c2": 1}
    r.held_s["c2"] = (1, reform.BLOCK_ASSIST_AFTER_S - 0.05)
    moves = r.moves(st, platoon, ROAD, 1, goals, 0.1)  # held now for BLOCK_ASSIST_AFTER_S
    brake = SCENARIO.hvmodel.planner_share * SCENARIO.hvmodel.b_safe_mps2
    # 2 m/s to lose, at the cruise law's gain (within the gentle brake)
    slower = -SCENARIO.cacc.k_cruise * reform.BLOCK_ASSIST_MPS
    assert moves["c1"][1] == pytest.approx(slower)
    assert moves["c1"][1] >= -brake
    assert moves["c0"][1] > 0.0  # the leader drives on
    assert events == [("block_assist", {"vehicle": "c2", "blocker": "c1", "hv": "hv"})]
    # No room left ahead of c2 (c1's rear within desired_gap_m of its front): no block.
    st["c1"] = car("c1", 255.0, 1, 14.0, cav=True)
    assert r.moves(st, platoon, ROAD, 1, goals, 0.1)["c1"][1] > -brake
    # Nor for an HV that drives its own pace (it wants what it drives).
    r2 = Reformer(SCENARIO, lambda vid: DriverModel(desired_speed_mps=14.0))
    st["c1"] = car("c1", 275.0, 1, 14.0, cav=True)
    r2.held_s["c2"] = (1, reform.BLOCK_ASSIST_AFTER_S + 0.1)
    assert r2.moves(st, platoon, ROAD, 1, goals, 0.1)["c1"][1] > -brake


def split_scene():
    """Two CAVs past a 12 m/s truck in lane 1, one behind it in lane 2 and one behind it in
    its own lane; lane 0 is free ahead."""
    return states(
        car("c0", 320.0, 0, 20.0, cav=True),
        car("c1", 300.0, 0, 20.0, cav=True),
        car("slow", 270.0, 1, 12.0),
        car("c2", 250.0, 2, 14.0, cav=True),
        car("c3", 240.0, 1, 12.0, cav=True),
    )


def test_a_platoon_split_by_the_target_waits_in_its_lane_and_the_cavs_behind_keep_theirs():
    events = []
    r = reformer(events)
    st, platoon = split_scene(), ["c0", "c1", "c2", "c3"]
    # Without a wait the platoon re-forms in lane 0, which holds most of its CAVs: c2 would
    # cross the truck's lane behind it.
    assert r.lane(st, platoon, ROAD, ending=(), cap_mps=25.0) == 0
    assert r.goals(0.0, st, platoon, ROAD, 0, cap_mps=25.0)["c2"] == 0
    r.reset()
    events.clear()
    r.waiting = ("slow", 15.0, 60.0)
    assert r.split_by(10.0, st, platoon, ROAD) is st["slow"]
    assert r.lane(st, platoon, ROAD, ending=(), cap_mps=25.0) == 1  # the truck's lane
    assert events[-1] == ("reform_lane", {"lane": 1, "lane_speeds_mps": {}, "wait": "slow"})
    goals = r.goals(10.0, st, platoon, ROAD, 1, cap_mps=25.0)
    # c0 and c1 move in ahead of the truck; c2 keeps lane 2 and drives past it there; c3
    # keeps the truck's lane (and passes it as the CAV ahead of it is past).
    assert goals == {"c0": 1, "c1": 1, "c2": 2, "c3": 1}
    # A lane that ends ahead is never waited in.
    assert r.split_by(10.0, st, platoon, ROAD, ending={1}) is None
    assert events[-1] == ("wait_end", {"slow": "slow", "reason": "lane_ends"})


@pytest.mark.parametrize(
    ("change", "t_s", "reason"),
    [
        ({"c0": 330.0, "c1": 315.0, "c2": 300.0, "c3": 285.0}, 10.0, "rejoined"),
        ({"c0": 260.0, "c1": 255.0}, 10.0, "none_past"),
        ({}, 61.0, "timeout"),
    ],
)
def test_the_wait_ends_once_the_platoon_is_no_longer_split_or_its_time_is_up(change, t_s, reason):
    events = []
    r = reformer(events)
    st, platoon = split_scene(), ["c0", "c1", "c2", "c3"]
    for vid, s in change.items():
        st[vid] = replace(st[vid], s_m=s, lane=0 if reason == "rejoined" else st[vid].lane)
    r.waiting = ("slow", 15.0, 60.0)
    if reason == "rejoined":  # all past, not yet in one lane: the wait goes on
        assert r.split_by(t_s, {**st, "c3": replace(st["c3"], lane=1)}, platoon, ROAD)
    assert r.split_by(t_s, st, platoon, ROAD) is None
    assert r.waiting is None and r.wait_ends == {reason: 1}
    assert events == [("wait_end", {"slow": "slow", "reason": reason})]
    del st["slow"]  # and once the vehicle is gone
    r.waiting = ("slow", 15.0, 60.0)
    assert r.split_by(10.0, st, platoon, ROAD) is None and r.wait_ends["gone"] == 1


def test_cavs_past_a_slow_car_beside_the_road_wait_at_it_in_the_lane_it_merges_into():
    # The platoon waits at a slow car still on the ramp (lane -1 of the road): the CAVs past
    # it in lane 0, the lane it merges into, wait there at its speed (and the platoon's lane
    # is lane 0); counted in "lane -1" none would be waiting, and they drove away.
    r = reformer()
    st = states(
        car("c0", 300.0, 0, 18.0, cav=True), car("c1", 285.0, 0, 18.0, cav=True),
        car("slow", 240.0, -1, 8.0), car("c2", 200.0, 0, 18.0, cav=True),
    )  # fmt: skip
    r.waiting = ("slow", 0.0, 30.0)
    assert r.lane(st, ["c0", "c1", "c2"], ROAD, ending=(), cap_mps=25.0) == 0
    held = r.wait_cruise(st, ["c0", "c1", "c2"], ROAD, st["slow"], 25.0)
    assert set(held) == {"c0", "c1"} and all(8.0 <= v < 25.0 for v in held.values())


def test_the_cavs_waiting_keep_the_room_the_others_need_ahead_of_the_target_and_no_more(
    monkeypatch,
):
    r = reformer()  # the truck's model: min gap 2.5 m, tau 1 s
    monkeypatch.setattr(reform, "WAIT_LEAD_M", 0.0)
    platoon = ["c0", "c1", "c2", "c3"]
    st = split_scene()
    # Only CAVs past the truck and in its lane are held; none is there yet.
    assert r.wait_cruise(st, platoon, ROAD, st["slow"], 20.0) == {}
    st["c0"] = car("c0", 320.0, 1, 20.0, cav=True)
    st["c1"] = car("c1", 300.0, 1, 20.0, cav=True)
    # Two CAVs behind need 2 * (5 + 10) m plus the truck's secure gap 2.5 + 1.0 * 12 m:
    # 44.5 m. c1's rear is 25 m ahead of the truck: 19.5 m short, 0.15 m/s per metre.
    assert r.wait_cruise(st, platoon, ROAD, st["slow"], 20.0) == {
        "c0": pytest.approx(14.925), "c1": pytest.approx(14.925)
    }  # fmt: skip
    # A CAV past the truck in another lane alongside them or ahead is still to drop in
    # behind them: nobody is held until it is in.
    st["c0"] = car("c0", 320.0, 0, 20.0, cav=True)
    assert r.wait_cruise(st, platoon, ROAD, st["slow"], 20.0) == {}
    # One just past the truck gets in behind them, ahead of the truck: they wait on.
    st["c0"] = car("c0", 280.0, 0, 20.0, cav=True)
    assert r.wait_cruise(st, platoon, ROAD, st["slow"], 20.0) == {"c1": pytest.approx(14.925)}
    # With the room there they keep the truck's speed; never above the cruise they are given.
    st["c1"] = car("c1", 330.0, 1, 20.0, cav=True)
    assert r.wait_cruise(st, platoon, ROAD, st["slow"], 20.0) == {"c1": 12.0}
    st["c0"] = car("c0", 320.0, 1, 20.0, cav=True)
    st["c1"] = car("c1", 285.0, 1, 20.0, cav=True)  # 10 m of room
    assert r.wait_cruise(st, platoon, ROAD, st["slow"], 16.0) == {"c0": 16.0, "c1": 16.0}
    # With a lead of 50 m they keep their cruise until they are 50 m further ahead.
    monkeypatch.undo()
    assert reform.WAIT_LEAD_M == 50.0
    st["c0"] = car("c0", 320.0, 1, 20.0, cav=True)
    st["c1"] = car("c1", 330.0, 1, 20.0, cav=True)  # c0 rearmost: 45 m of room, 49.5 m short
    assert r.wait_cruise(st, platoon, ROAD, st["slow"], 20.0) == {
        "c0": pytest.approx(19.425), "c1": pytest.approx(19.425)
    }  # fmt: skip


def test_a_cav_the_platoon_waits_for_passes_in_any_lane_beside_once_the_wait_has_lasted():
    events = []
    r = reformer(events)
    st = states(
        car("c0", 320.0, 1, 12.0, cav=True),
        car("slow", 270.0, 1, 12.0),
        car("c1", 255.0, 1, 12.0, cav=True),  # right behind the truck
        car("right", 256.0, 0, 12.5),  # an HV beside it on either side, no faster
        car("left", 256.0, 2, 12.5),
    )  # fmt: skip
    platoon = ["c0", "c1"]
    r.waiting = ("slow", 15.0, 60.0)  # from 15 s to 60 s
    # Neither lane beside is faster by the gain: c1 stays behind the truck for now...
    assert r.goals(16.0, st, platoon, ROAD, 1, cap_mps=25.0) == {"c0": 1, "c1": 1}
    assert events == []
    # ... and once the wait has lasted PASS_SWITCH_S (6 s), it passes in the lane beside.
    goals = r.goals(21.0, st, platoon, ROAD, 1, cap_mps=25.0)
    assert goals["c1"] in (0, 2)
    assert events == [("passing_start", {"vehicle": "c1", "slow": "slow", "lane": goals["c1"]})]
    # Without a wait it never does.
    r2 = reformer()
    assert r2.goals(21.0, st, platoon, ROAD, 1, cap_mps=25.0) == {"c0": 1, "c1": 1}


def test_a_pass_out_of_time_goes_on_while_alongside_the_slow_vehicle():
    events = []
    r = reformer(events)
    late = -(reform.MAX_PASS_S + 1.0)  # the pass started longer ago than MAX_PASS_S
    platoon = ["c0", "c1"]
    # c1 in the passing lane, its front past the slow car's rear: the pass goes on
    st = states(
        car("c0", 400.0, 1, 20.0, cav=True),
        car("slow", 240.0, 1, 12.0),
        car("c1", 238.0, 0, 16.0, cav=True),
    )  # fmt: skip
    r.passing["c1"] = ("slow", 0, late)
    assert r.goals(0.0, st, platoon, ROAD, 1, cap_mps=25.0)["c1"] == 0
    assert "c1" in r.passing and not any(kind == "passing_end" for kind, _ in events)
    # still behind it: given up, back to the platoon's lane
    st["c1"] = car("c1", 230.0, 0, 16.0, cav=True)
    assert r.goals(0.1, st, platoon, ROAD, 1, cap_mps=25.0)["c1"] == 1
    assert events[-1] == ("passing_end", {"vehicle": "c1", "slow": "slow", "past": False})


@pytest.mark.parametrize(
    ("hv_s", "centres"),
    [
        (8.0, False),  # the HV's front alongside the CAV's rear half: the CAV stays put
        # The HV 65 m behind (at 25 m, its driver model would brake harder than b_safe for
        # the CAV it could squeeze past): the CAV moves back to its lane centre.
        (-60.0, True),
    ],
)
def test_a_cav_off_centre_in_a_jam_centres_only_once_the_hv_squeezing_past_has_gone(hv_s, centres):
    # Corridor study, 20 % CAVs at 1500 veh/h: a CAV stopped 0.8 m right of its lane's centre
    # after a pass it gave up; an HV of the same lane, 1.2 m left of the centre, crept up beside
    # it, and the CAV's move back to the centre (0.4 m a step) hit its side.
    r = reformer()
    cav = car("c0", 10.0, 1, 0.0, cav=True, lat=-0.8)
    hv = car("h0", hv_s, 1, 4.0, lat=1.2)
    dlat, _ = r.moves(states(cav, hv), ["c0"], ROAD, 1, {"c0": 1}, 0.2)["c0"]
    if centres:
        assert dlat == pytest.approx(SCENARIO.cav.max_lateral_speed_mps * 0.2)
    else:
        assert dlat == 0.0


@pytest.mark.parametrize(("wants", "yields"), [(True, True), (False, False)])
def test_a_cav_lets_in_a_vehicle_that_must_change_into_its_lane_for_its_route(wants, yields):
    # The hour of the corridor: an exiting truck in the middle lane found no gap into the
    # platoons of the right lane for 1.5 km and stood at the end of its lane; the corridor
    # jammed behind it. A CAV behind such a vehicle (SUMO's strategic wish towards its lane)
    # now drops back gently to let it in; a vehicle that only drives there is left alone.
    r = reformer()
    asked = []

    def must_change(vid, direction):
        asked.append((vid, direction))
        return wants

    r.must_change = must_change
    cav = car("c0", 100.0, 0, 20.0, cav=True)
    truck = VehicleState("truck", 118.0, 1, 0.0, 18.0, 12.0, 0.0, False)  # rear 6 m ahead
    _, bound = r.moves(states(cav, truck), ["c0"], ROAD, 0, {"c0": 0}, 0.1)["c0"]
    assert asked == [("truck", -1)]  # asked whether it must move right, into c0's lane
    if yields:
        gentle = -SCENARIO.hvmodel.planner_share * SCENARIO.hvmodel.b_safe_mps2
        assert gentle <= bound < 0.0
    else:
        assert bound == math.inf


def test_a_goal_lane_the_road_does_not_have_steers_to_the_nearest_one():
    r = reformer()
    road = RoadSection(lane_widths_m=(3.5, 3.5, 3.5))
    ego = car("c0", 100.0, 2, 15.0, cav=True, lat=0.3)  # in the leftmost lane, off-centre
    dlat, _ = r._steer(ego, 3, [ego], road, 0.1)  # lane 3: only on an edge with four lanes
    assert dlat < 0.0  # back towards lane 2's centre, not off the road
    dlat, _ = r._steer(car("c0", 100.0, 0, 15.0, cav=True, lat=-0.3), -1, [], road, 0.1)
    assert dlat > 0.0


def test_a_target_driving_on_has_not_changed_lanes_when_the_swarms_lane_numbering_shifts():
    """The swarm's states number lanes as on its lead CAV's edge; past an on-ramp's added
    lane that numbering shifts by one. The target, on one edge in one lane all along, has not
    changed lanes; moved to another lane of its edge, it has (once settled in it)."""
    from sumo_swarm.controllers.decider import Decider
    from sumo_swarm.controllers.lanes import LaneView
    from tests.fakes import FakeSession, run_context

    # lane 1 of its own edge "acc"
    own = {"truck": VehicleState("truck", 300.0, 1, 0.0, 15.0, 12.0)}
    session = FakeSession(own, edges={"truck": "acc"})
    ctx = run_context(session, SCENARIO, ROAD)
    decider = Decider(ctx, lanes=LaneView(ctx), reformer=None, planner=SCENARIO.planner,
                      model_of=lambda vid: DriverModel(model="unknown"))  # fmt: skip
    # As the swarm sees it: lane 0 while its lead CAV is on the edge before the ramp, then 1.
    before_ramp = replace(own["truck"], lane=0)
    assert not decider.target_changed_lane(before_ramp)
    assert not decider.target_changed_lane(before_ramp)
    assert not decider.target_changed_lane(own["truck"])  # the lead CAV is past the ramp now
    # It moves to lane 2 of its edge: changed once its centre is in it.
    session.states = {"truck": VehicleState("truck", 310.0, 2, -1.2, 15.0, 12.0)}
    assert not decider.target_changed_lane(session.states["truck"])  # still moving over
    session.states = {"truck": VehicleState("truck", 320.0, 2, 0.1, 15.0, 12.0)}
    assert decider.target_changed_lane(session.states["truck"])
