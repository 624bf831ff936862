"""Re-forming the platoon while cruising, without SUMO: the lane, each CAV's goal, the moves."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from sumo_swarm.config import Scenario
from sumo_swarm.controllers.reform import Reformer
from sumo_swarm.core.hvmodel import DriverModel
from sumo_swarm.core.model import RoadSection, VehicleState

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
    # Passing gives up after max_pass_s.
    goals = r.goals(5.0 + SCENARIO.swarm.max_pass_s + 0.1, st, platoon, ROAD, 1, cap_mps=25.0)
    assert goals["c2"] == 1 and events[-1][1] == {"vehicle": "c2", "slow": "slow", "past": False}


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
        car("beside", 219.0, 0, 12.0),  # alongside c1 in lane 0, where nothing is ahead
        car("l2", 300.0, 2, 16.0),  # lane 2 is faster than the slow car, by less than lane 0
    )  # fmt: skip
    platoon = ["c0", "c1"]
    goals = r.goals(0.0, st, platoon, ROAD, 1, cap_mps=25.0)
    assert goals["c1"] == 0 and events[-1][0] == "passing_start"
    switch_s = SCENARIO.swarm.pass_switch_s
    t, dt = 0.0, 0.1
    while t < switch_s - dt / 2:  # the guard holds c1: a car alongside in lane 0
        assert r.moves(st, platoon, ROAD, 1, goals, dt)["c1"][0] == 0.0
        t += dt
        goals = r.goals(t, st, platoon, ROAD, 1, cap_mps=25.0)
        assert goals["c1"] == (2 if t >= switch_s - dt / 2 else 0)
    assert events[-1] == (
        "passing_switch",
        {"vehicle": "c1", "slow": "slow", "held_lane": 0, "lane": 2},
    )
    assert r.passing["c1"] == ("slow", 2, 0.0)  # max_pass_s still counts from the start
    assert r.moves(st, platoon, ROAD, 1, goals, dt)["c1"][0] > 0.0  # lane 2 is free: it goes
    assert "c1" not in r.held_s


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
    for _ in range(round(SCENARIO.swarm.pass_switch_s / 0.1)):
        assert r.moves(st, platoon, ROAD, 1, goals, 0.1)["c1"][0] == 0.0  # held
    # Lane 0 is the rightmost: no other side. From lane 1 the other side of lane 0 is lane 2.
    assert r.goals(6.0, st, platoon, ROAD, 1, cap_mps=25.0)["c1"] == 1
    assert not any(kind == "passing_switch" for kind, _ in events)
    st["c1"] = car("c1", 220.0, 1, 12.0, cav=True, lat=-0.6)  # in lane 1, for lane 0
    st["slow"] = car("slow", 240.0, 1, 12.0)
    st["beside"] = car("beside", 219.0, 0, 12.0)
    goals = r.goals(6.0, st, platoon, ROAD, 0, cap_mps=25.0)
    assert goals["c1"] == 0
    for _ in range(round(SCENARIO.swarm.pass_switch_s / 0.1)):
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
    for _ in range(round(SCENARIO.swarm.drop_behind_s / 0.1)):
        dlat, bound = r.moves(st, platoon, ROAD, 0, goals, 0.1)["c2"]
        assert dlat == 0.0  # held: c0 is beside it
        assert bound > gentle  # not at once: it may be passing by
    dlat, bound = r.moves(st, platoon, ROAD, 0, goals, 0.1)["c2"]
    assert bound == pytest.approx(gentle)  # held for drop_behind_s: drops back behind c0
    # Once behind c0 it follows c0 at a real gap, and c3 makes room for it.
    st["c2"] = car("c2", 293.0, 1, 20.0, cav=True, lat=-0.6)
    moves = r.moves(st, platoon, ROAD, 0, goals, 0.1)
    assert moves["c2"][1] < 0.0 and moves["c3"][1] < 0.0
