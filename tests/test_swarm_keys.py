"""Every ``[swarm]`` key at a value other than its default, with the answer that value gives.

Issue 51: a key that no test sets to another value is a switch nobody checked. The keys set here
are read where the swarm reads them (its decider, its controller, the function the key feeds);
the others are set by the tests named in :data:`ELSEWHERE`.
:func:`test_every_swarm_key_is_set_to_another_value_by_a_test` fails for a key that neither
covers.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest

from sumo_swarm.config import Scenario, SwarmSettings
from sumo_swarm.controllers.swarm import SwarmController
from sumo_swarm.core.hvmodel import DriverModel
from sumo_swarm.core.model import VehicleState
from sumo_swarm.core.swarming.decision import (
    behaving_interval_s,
    lane_pass_pace,
)
from tests.fakes import FakeSession, run_context
from tests.test_swarming import car

TESTS = Path(__file__).parent
DEFAULT = SwarmSettings()

# Keys set to another value by tests elsewhere: key -> (test file, test function).
# (``None``: set in a helper of that file that its tests use.)
ELSEWHERE = {
    "decide": (
        "test_arbiter.py",
        "test_the_paper_trigger_and_the_weighing_start_the_same_paper_overtake",
    ),
    "hand_over_in_lane": (
        "test_open_traffic.py",
        "test_the_swarm_passes_at_the_lanes_pace_once_in_one_faster_lane",
    ),
    "lane_pass": (
        "test_open_traffic.py",
        "test_the_swarm_passes_at_the_lanes_pace_once_in_one_faster_lane",
    ),
    "keep_right_wait_s": ("test_open_traffic.py", None),
    "keep_right_middle": (
        "test_swarming.py",
        "test_the_wait_for_a_target_keeping_right_holds_in_the_leftmost_lane_only",
    ),
    "keep_right_due": (
        "test_swarming.py",
        "test_the_right_lane_is_judged_for_when_sumo_says_the_truck_will_move",
    ),
    "keep_right_wish": (
        "test_swarming.py",
        "test_the_right_lane_stays_closed_while_a_middle_lane_target_wants_to_move_there",
    ),
}


def swarm_with(states, *, session_answers=None, **swarm) -> SwarmController:
    """A swarm of the CAVs in ``states`` on three 3.2 m lanes, its ``[swarm]`` keys replaced by
    ``swarm`` (the default scenario: cruise 20 m/s, cap 25 m/s, 15 m cells, 3 s intervals)."""
    sc = Scenario(name="t", path=None)
    sc = dataclasses.replace(sc, swarm=dataclasses.replace(sc.swarm, **swarm))
    session = FakeSession(states, **(session_answers or {}))
    cavs = tuple(v for v, st in states.items() if st.is_cav)
    controller = SwarmController()
    controller.attach(run_context(session, sc, cav_ids=cavs))
    return controller


def first_target_s(controller: SwarmController, states, platoon, until_s: float = 12.0):
    """The first time [s] (0.1 s steps) the decider names a target, or None."""
    for i in range(round(until_s / 0.1) + 1):
        t = round(0.1 * i, 1)
        controller.ctx.session.time_s = t
        if controller.decider.decide(t, states, platoon) is not None:
            return t
    return None


def target_at(states=None, **swarm) -> float | None:
    """:func:`first_target_s` of the CAVs a0, a1 of ``states`` (default :func:`held_platoon`)
    with ``swarm`` keys."""
    states = held_platoon() if states is None else states
    return first_target_s(swarm_with(states, **swarm), states, ["a0", "a1"])


def behind_truck():
    """Two CAVs at 12 m/s, 15 m behind a 12 m/s truck in their lane (lane 1 of 3)."""
    return {
        "truck": car("truck", 140.0, 1, 12.0),
        "a0": car("a0", 120.0, 1, 12.0, cav=True),
        "a1": car("a1", 105.0, 1, 12.0, cav=True),
    }


def held_platoon(slow_mps: float = 17.0):
    """Two CAVs at 17 m/s, 25 m behind a car in their lane at ``slow_mps``."""
    return {
        "slow": car("slow", 140.0, 1, slow_mps),
        "a0": car("a0", 110.0, 1, 17.0, cav=True),
        "a1": car("a1", 95.0, 1, 17.0, cav=True),
    }


# ------------------------------------------------------------------ the decision point
def test_trigger_speed_ratio_sets_how_slow_a_vehicle_must_be():
    # Default 0.95 of the 20 m/s cruise: a car at 17 m/s is slow. At 0.8 (16 m/s) it is not.
    assert target_at() == pytest.approx(3.0)
    assert swarm_with(held_platoon(), trigger_speed_ratio=0.8).decider.slow_below() == (
        pytest.approx(16.0)
    )
    assert target_at(trigger_speed_ratio=0.8) is None


def test_start_after_s_holds_every_decision_until_then():
    # No decision before start_after_s (default 1 s); then trigger_after_s (2 s) of the same
    # candidate: 3 s by default, 7 s with start_after_s = 5.
    assert target_at(start_after_s=5.0) == pytest.approx(7.0)


def test_trigger_after_s_sets_how_long_the_same_vehicle_must_hold_the_platoon():
    # From start_after_s (1 s): 2 s of the same candidate by default (3 s), 4 s (5 s).
    assert target_at(trigger_after_s=4.0) == pytest.approx(5.0)


def test_detect_range_m_sets_how_far_ahead_a_slow_vehicle_is_seen():
    # The car is 25 m ahead of the front CAV: seen within the default 60 m, not within 20 m.
    assert target_at(detect_range_m=20.0) is None
    assert target_at(detect_range_m=30.0) == pytest.approx(3.0)


def test_accelerating_mps2_sets_when_a_slow_vehicle_is_only_getting_up_to_speed():
    # The car ahead speeds up at 0.8 m/s^2: beyond the default 0.5 it is getting up to speed,
    # no target; below 1.0 it is slow.
    states = {**held_platoon(), "slow": VehicleState("slow", 140.0, 1, 0.0, 17.0, 5.0, 0.8, False)}
    assert target_at(states) is None
    assert target_at(states, accelerating_mps2=1.0) == pytest.approx(3.0)


def test_horizon_s_sets_how_long_a_manoeuvre_has_to_pay():
    # Two CAVs behind a 12 m/s truck, both lanes beside free: over the default 20 s moving
    # past it pays; within 0.5 s (less than moving over takes) nothing does: the swarm follows.
    states = behind_truck()
    platoon = ["a0", "a1"]
    # (a truck that wants no more than its 12 m/s: it stays to be passed)
    answers = {"driver_model": lambda vid: DriverModel(desired_speed_mps=12.0)}
    default = swarm_with(states, session_answers=answers)
    assert default.decider.choose(states["truck"], states, platoon).kind in ("lane_pass", "cells")
    short = swarm_with(states, session_answers=answers, horizon_s=0.5)
    assert short.decider.choose(states["truck"], states, platoon).kind == "follow"


def test_others_weight_sets_what_a_metre_lost_by_the_others_counts():
    # Two CAVs behind a 12 m/s truck; in both lanes beside, cars at 25 m/s 25 and 55 m behind
    # the tail. The cells gain the CAVs the most (277 vehicle-metres) but block the cars (260
    # lost): counted one for one (the default) the CAVs pass one by one (261, nobody loses);
    # with the others' metres counted at 0.05, the cells.
    states = {
        **behind_truck(),
        **{f"{v}{q}": car(f"{v}{q}", s, q, 25.0) for v, s in (("l", 80.0), ("m", 50.0))
           for q in (0, 2)},
    }  # fmt: skip
    answers = {"driver_model": lambda vid: DriverModel(desired_speed_mps=12.0 if vid == "truck"
                                                       else 25.0)}  # fmt: skip
    platoon = ["a0", "a1"]
    default = swarm_with(states, session_answers=answers)
    assert default.decider.choose(states["truck"], states, platoon).kind == "one_by_one"
    selfish = swarm_with(states, session_answers=answers, others_weight=0.05)
    assert selfish.decider.choose(states["truck"], states, platoon).kind == "cells"


def test_min_speed_gain_mps_sets_how_much_faster_than_the_target_the_cap_must_be():
    # The cap (25 m/s) beats a car at 17 m/s by 8 m/s: a target at the default gain of 2 m/s,
    # none at 10 m/s.
    assert target_at(min_speed_gain_mps=10.0) is None
    assert target_at(min_speed_gain_mps=8.0) == pytest.approx(3.0)


def test_catching_up_ahead_m_sets_how_far_ahead_a_slow_line_holds_the_target():
    # The paper's trigger: a car at 17 m/s that wants 30, 250 m behind a truck that wants 17.
    # Within the default 300 m the truck holds the car's lane back for good: the car is a
    # target. Looking only 200 m ahead, the car is only catching up: no target.
    states = {**held_platoon(), "truck": car("truck", 390.0, 1, 17.0)}
    desired = {"slow": 30.0, "truck": 17.0}
    answers = {"driver_model": lambda vid: DriverModel(desired_speed_mps=desired.get(vid, 30.0))}
    platoon = ["a0", "a1"]
    far = swarm_with(states, session_answers=answers, decide="paper")
    assert first_target_s(far, states, platoon) == pytest.approx(3.0)
    near = swarm_with(states, session_answers=answers, decide="paper", catching_up_ahead_m=200.0)
    assert first_target_s(near, states, platoon) is None


# ------------------------------------------------------------------ passing
def test_in_lane_tolerance_m_sets_when_a_cav_counts_as_settled_in_a_lane():
    # Both CAVs have moved to lane 2 beside a truck; one is still 0.5 m off its centre. Within
    # the default 0.3 m it is not settled: no hand-over to the cruise; within 0.6 m it is.
    states = {
        "truck": car("truck", 140.0, 1, 12.0),
        "a0": car("a0", 120.0, 2, 20.0, cav=True),
        "a1": car("a1", 105.0, 2, 20.0, cav=True, lat=-0.5),
    }
    cavs = {v: states[v] for v in ("a0", "a1")}
    strict = swarm_with(states)
    assert not strict.decider.passing_in_lane(states["truck"], cavs, states, None, None)
    loose = swarm_with(states, in_lane_tolerance_m=0.6)
    assert loose.decider.passing_in_lane(states["truck"], cavs, states, None, None)


def test_lane_pass_stall_s_sets_how_long_a_lane_pass_may_go_without_progress():
    # A lane pass into lane 2 past a 12 m/s truck; neither CAV gets out of the truck's lane:
    # the swarm ends it as stalled (and hands the truck to the cells) once lane_pass_stall_s
    # has gone by, 15 s by default, 5 s here.
    states = behind_truck()

    def stalled_at(swarm: SwarmController) -> float:
        swarm._start_lane_pass(0.0, states["truck"], 2, ["a0", "a1"])
        for i in range(1, 400):
            t = round(0.1 * i, 1)
            if swarm._lane_pass_target(t, states, ["a0", "a1"]) is not None:
                return t
        raise AssertionError("never stalled")

    assert stalled_at(swarm_with(states)) == pytest.approx(15.1)
    assert stalled_at(swarm_with(states, lane_pass_stall_s=5.0)) == pytest.approx(5.1)


def test_lane_pass_beats_sets_the_pace_a_lane_beside_must_beat():
    # A 12 m/s truck, the plan's pace one 15 m cell per 3 s above it (17 m/s), a 20 m/s cruise,
    # a 2 m/s gain: "free" (default) asks of a lane beside the lower of the plan's pace and the
    # cruise less the gain (17 vs 18: 17); "cells" the plan's pace itself.
    args = dict(cruise_mps=20.0, min_gain_mps=2.0)
    assert lane_pass_pace(12.0, 5.0, rule=DEFAULT.lane_pass_beats, **args) == pytest.approx(17.0)
    # With the plan faster than the cruise less the gain, the two differ.
    assert lane_pass_pace(12.0, 8.0, rule="free", **args) == pytest.approx(18.0)
    assert lane_pass_pace(12.0, 8.0, rule="cells", **args) == pytest.approx(20.0)


def test_interval_rule_sets_whether_a_row_move_must_be_drivable():
    # 15 m cells past a 17.5 m/s target under a 20 m/s cap: a row each 3 s needs 22.5 m/s.
    # "drivable" (default) stretches the behaving interval to 6 s; "fixed" keeps the planner's.
    assert behaving_interval_s(3.0, 15.0, 17.5, 20.0, DEFAULT.interval_rule) == pytest.approx(6.0)
    assert behaving_interval_s(3.0, 15.0, 17.5, 20.0, "fixed") == pytest.approx(3.0)
    # With room under the cap both give the planner's interval.
    assert behaving_interval_s(3.0, 15.0, 12.0, 25.0, "drivable") == pytest.approx(3.0)


def test_pass_singly_s_sets_how_long_the_cavs_pass_one_by_one():
    # Started at 4 s: one by one until 64 s by default (60 s), until 24 s at 20 s.
    states = held_platoon()
    for swarm, until_s in ((swarm_with(states), 64.0),
                           (swarm_with(states, pass_singly_s=20.0), 24.0)):  # fmt: skip
        swarm._start_one_by_one(4.0, states["slow"], ["a0", "a1"])
        assert swarm.reformer.singly == ("slow", pytest.approx(until_s))


def test_cooldown_s_sets_how_long_no_target_is_taken_after_a_give_up():
    # The cells on a 12 m/s truck, given up at 4 s (no progress): the swarm names no target
    # until cooldown_s has gone by, then the truck again after trigger_after_s (2 s): at 21 s
    # by default (15 s), at 11 s with 5 s.
    states = behind_truck()

    class NoProgress:
        def update(self, *args, **kwargs) -> None:
            pass

        def give_up_reason(self, *args, **kwargs) -> str:
            return "no_progress"

    def next_target_s(swarm: SwarmController) -> float:
        swarm._start_overtake(3.0, states["truck"], ["a0", "a1"])
        swarm.progress = NoProgress()
        swarm._overtake_step(4.0, states, ["a0", "a1"])
        for i in range(41, 400):
            t = round(0.1 * i, 1)
            if swarm.decider.decide(t, states, ["a0", "a1"]) is not None:
                return t
        raise AssertionError("no target")

    assert next_target_s(swarm_with(states)) == pytest.approx(21.0)
    assert next_target_s(swarm_with(states, cooldown_s=5.0)) == pytest.approx(11.0)


# ------------------------------------------------------------------ keeping right
def right_free_for_truck(other: VehicleState, **swarm) -> bool:
    """Is the right lane free, as the swarm's decider judges it, for a truck in the middle lane
    at 20 m/s (front at 200 m) to keep right, with ``other`` in that lane? Its follower there
    needs the minimum gap (5 m) plus SUMO's secure gap of a default driver (1 s, 4.5 m/s^2)."""
    truck = car("truck", 200.0, 1, 20.0)
    states = {"truck": truck, other.vehicle_id: other, "a0": car("a0", 170.0, 1, 20.0, cav=True)}
    return swarm_with(states, **swarm).decider._right_lane_free(truck, states)


def test_keep_right_ahead_s_sets_how_far_ahead_the_right_lane_must_be_clear():
    # A car 65 m ahead of the truck in the right lane at 10 m/s. Moving over gains the truck
    # nothing if something slower is within ahead_s at its speed: the default 4 s (80 m, plus
    # the 5 m minimum gap) sees the car; 1 s (25 m) does not.
    slow_right = car("c", 270.0, 0, 10.0)
    assert not right_free_for_truck(slow_right)
    assert right_free_for_truck(slow_right, keep_right_ahead_s=1.0)


def test_keep_right_move_s_sets_how_long_a_follower_there_closes_in_before_the_move():
    # A car 44 m behind the truck's rear in the right lane at 22 m/s needs 5 + 31.3 m (22 s x 1
    # + (22^2 - 20^2) / 9). Judged for the default 5 s it closes 10 m: 34 m, not enough; for
    # 3 s it closes 6 m: 38 m, the lane is free.
    behind = car("c", 151.0, 0, 22.0)
    assert not right_free_for_truck(behind)
    assert right_free_for_truck(behind, keep_right_move_s=3.0)


def test_keep_right_soon_s_sets_how_soon_the_right_lane_must_open():
    # A truck keeping right in the middle lane at 20 m/s, a car beside it on the right at 15:
    # the lane opens for the truck once the car is 5 m behind its rear (a follower that slow
    # needs no secure gap), at 2 s. Within the default 10 s the lane opens soon enough (the
    # plan keeps it closed); asked to open within 1 s, it does not.
    states = {
        "truck": car("truck", 200.0, 1, 20.0),
        "c": car("c", 200.0, 0, 15.0),
        "a0": car("a0", 170.0, 1, 20.0, cav=True),
    }
    soon = swarm_with(states)
    assert soon.decider._right_lane_opens(states["truck"], states)
    at_once = swarm_with(states, keep_right_soon_s=1.0)
    assert not at_once.decider._right_lane_opens(states["truck"], states)
    assert swarm_with(states, keep_right_soon_s=2.0).decider._right_lane_opens(
        states["truck"], states
    )


# ------------------------------------------------------------------ the MPC's clock
def test_control_interval_s_sets_how_often_the_mpcs_solve():
    # At SUMO's 0.1 s step: every 2 steps by default (0.18 s), every 5 at 0.5 s.
    states = held_platoon()
    assert swarm_with(states).tracker.interval_steps == 2
    assert swarm_with(states, control_interval_s=0.5).tracker.interval_steps == 5


# ------------------------------------------------------------------ all of them
def _block(text: str, test: str) -> str:
    """The text of test function ``test`` with its decorators ("" if there is none)."""
    found = re.search(rf"^def {re.escape(test)}\(", text, re.M)
    if found is None:
        return ""
    start = text.rfind("\n\n\n", 0, found.start())
    end = text.find("\n\n\n", found.end())
    return text[start : None if end < 0 else end]


def _sets(text: str, key: str) -> bool:
    """Does ``text`` give ``[swarm] key`` a value: a keyword argument, a mapping key, a line
    of a settings text (after a newline escape too), or the default read to pass on?"""
    pattern = rf"(?:\\n|\b){key}\s*=|\"{key}\"\s*:|\bDEFAULT\.{key}\b"
    return re.search(pattern, text) is not None


def test_every_swarm_key_is_set_to_another_value_by_a_test():
    # Each key is given a value inside its test here (test_<key>_...), or inside the test
    # named in ELSEWHERE (its helper's file, for None).
    here = (TESTS / "test_swarm_keys.py").read_text(encoding="utf-8")
    untested = []
    for key in (f.name for f in dataclasses.fields(SwarmSettings)):
        if key in ELSEWHERE:
            file, test = ELSEWHERE[key]
            text = (TESTS / file).read_text(encoding="utf-8")
            block = text if test is None else _block(text, test)
        else:
            named = re.findall(rf"^def (test_{key}_\w+)\(", here, re.M)
            block = "".join(_block(here, name) for name in named)
        if not _sets(block, key):
            untested.append(key)
    assert untested == [], f"[swarm] keys no test sets to another value: {untested}"
