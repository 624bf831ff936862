"""The step-safety net (core/stepsafe.py): hand-made cases with known answers, and the speed it
gives checked against the very update SUMO makes (Euler: a step moves the new speed times dt)."""

from __future__ import annotations

import dataclasses
import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sumo_swarm.core.model import VehicleState
from sumo_swarm.core.stepsafe import (
    Footprint,
    braking_short_m,
    capped_speeds,
    leader_cap,
    safe_speed,
    sideways_conflicts,
)


def _closest_approach(v: float, gap: float, lead: float, b_lead: float, b: float, dt: float):
    """The smallest gap [m] when the follower drives ``v`` for one step and the leader
    ``lead``, then both brake at their decelerations to a stop, as SUMO moves them."""
    smallest = gap = gap + (lead - v) * dt
    while v > 0.0 or lead > 0.0:
        v, lead = max(v - b * dt, 0.0), max(lead - b_lead * dt, 0.0)
        gap += (lead - v) * dt
        smallest = min(smallest, gap)
    return smallest


def test_without_a_step_it_is_the_stopping_distance_behind_the_leaders():
    # v^2 / (2 b) = gap + lead^2 / (2 b_lead)
    assert safe_speed(10.0, 0.0, 4.0, 4.0, 0.0) == pytest.approx(math.sqrt(80.0))
    assert safe_speed(10.0, 20.0, 4.0, 4.0, 0.0) == pytest.approx(math.sqrt(80.0 + 400.0))


def test_a_standing_leader_ten_metres_ahead_at_one_second_steps():
    # room = 10 - 4 / 8 = 9.5 m; v^2 / 8 + v / 2 = 9.5: v = 4 (sqrt(5) - 0.5) = 6.944 m/s.
    v = safe_speed(10.0, 0.0, 4.0, 4.0, 1.0)
    assert v == pytest.approx(4.0 * (math.sqrt(5.0) - 0.5))
    # SUMO moves it 6.94 m, then 2.94 m, then stands: 0.11 m short of the leader.
    assert _closest_approach(v, 10.0, 0.0, 4.0, 4.0, 1.0) == pytest.approx(10.0 - v - (v - 4.0))


def test_no_room_no_speed():
    assert safe_speed(-1.0, 0.0, 4.0, 4.0, 0.5) == 0.0
    assert safe_speed(0.0, 0.0, 4.0, 4.0, 1.0) == 0.0  # the step's own braking eats 0.5 m


@settings(max_examples=400, deadline=None)
@given(
    st.floats(0.0, 80.0),  # gap
    st.floats(0.0, 35.0),  # leader's speed in the step
    st.floats(1.0, 9.0),  # leader's deceleration
    st.floats(1.0, 9.0),  # follower's deceleration
    st.sampled_from([0.05, 0.1, 0.2, 0.5, 1.0]),
)
def test_the_speed_given_never_runs_into_the_leader_as_sumo_moves_them(gap, lead, b_lead, b, dt):
    v = safe_speed(gap, lead, b_lead, b, dt)
    assert _closest_approach(v, gap, lead, b_lead, b, dt) >= -1e-9
    # ... and, behind a leader braking at least as hard, not far below the fastest that does
    # not: the bounds of the stopping distances are (b + b_lead) dt^2 / 8 apart, and a faster
    # step costs at least dt / 2 per m/s of them.
    if b_lead >= b:
        slack = (b + b_lead) * dt / 4.0
        assert _closest_approach(v + slack + 1e-3, gap, lead, b_lead, b, dt) < 0.0


def _car(vid: str, s: float, speed: float, lane: int = 1) -> VehicleState:
    return VehicleState(vid, s, lane, 0.0, speed, 5.0, 0.0, vid.startswith("c"))


def test_a_platoon_is_capped_front_to_back_on_its_leaders_capped_commands():
    # c1 wants 20 m/s, 15 m (bumper) behind a truck standing; c2 wants 20 m/s 10 m behind c1.
    states = {v.vehicle_id: v for v in (_car("h", 100.0, 0.0), _car("c1", 80.0, 12.0),
                                        _car("c2", 65.0, 12.0))}  # fmt: skip
    ahead = {"c1": [(states["h"], 15.0)], "c2": [(states["c1"], 10.0)]}
    decel = {"h": 4.5, "c1": 4.0, "c2": 4.0}
    out = capped_speeds({"c2": 20.0, "c1": 20.0}, states, lambda v: ahead.get(v, []),
                        decel.__getitem__, 1.0, 0.5)  # fmt: skip
    c1 = safe_speed(14.5, 0.0, 4.5, 4.0, 1.0)  # the standing truck: it brakes no further
    assert out["c1"] == pytest.approx(c1) and c1 < 20.0
    assert out["c2"] == pytest.approx(safe_speed(9.5, c1, 4.0, 4.0, 1.0))  # c1 at its cap


def test_a_leader_of_no_command_may_brake_within_the_step_and_one_alongside_is_skipped():
    states = {v.vehicle_id: v for v in (_car("h", 100.0, 20.0), _car("c", 80.0, 20.0),
                                        _car("x", 82.0, 20.0, lane=2))}  # fmt: skip
    ahead = [(states["h"], 15.0), (states["x"], -3.0)]  # x alongside: the lateral guards' case
    out = capped_speeds({"c": 25.0}, states, lambda v: ahead, {"h": 4.5, "c": 4.0, "x": 9.0}.get,
                        0.5, 0.5)  # fmt: skip
    assert out["c"] == pytest.approx(safe_speed(14.5, 20.0 - 4.5 * 0.5, 4.5, 4.0, 0.5))
    assert out["c"] == leader_cap(14.5, 20.0, None, 4.5, 4.0, 0.5)  # what a controller asks
    # One commanded for the step is taken at its command (a CAV ahead, commanded first).
    assert leader_cap(14.5, 20.0, 18.0, 4.5, 4.0, 0.5) == safe_speed(14.5, 18.0, 4.5, 4.0, 0.5)
    # A command already below the cap is left as it is.
    assert capped_speeds({"c": 5.0}, states, lambda v: ahead, {"h": 4.5, "c": 4.0}.get, 0.5,
                         0.5) == {"c": 5.0}  # fmt: skip


def _print(s, y, ds=0.0, dy=0.0, length=5.0):
    return Footprint(s, y, s + ds, y + dy, length, 1.8)


def test_two_cavs_moving_into_one_lane_level_with_each_other_are_both_held():
    # Lanes 3.2 m wide: a from the lane to the left, b from the lane to the right, fronts 2 m
    # apart, each 2.2 m across in a step (1 s): they end 1.48 m apart, centre to centre.
    prints = {"a": _print(621.3, 7.58, 16.6, -2.2), "b": _print(619.5, 1.7, 17.6, 2.2),
              "h": _print(660.0, 4.6, 15.0)}  # fmt: skip
    assert sideways_conflicts(["a", "b"], prints, 0.3) == {"a", "b"}
    # 12 m apart lengthwise at the end: both may go.
    prints["b"] = _print(607.5, 1.7, 17.6, 2.2)
    assert sideways_conflicts(["a", "b"], prints, 0.3) == set()


def test_a_move_is_held_only_for_what_it_brings_about():
    # c already 0.2 m beside a truck (SUMO's sublane drivers squeeze past), moving along it,
    # away from it: not held; towards it, closer than at the start: held only if it was clear
    # before (it was not: the guards' business, not the net's).
    truck = _print(400.0, 4.8, 15.0, 0.0, length=12.0)
    away = {"t": truck, "c": _print(395.0, 2.55, 15.0, -0.5)}
    assert sideways_conflicts(["c"], away, 0.3) == set()
    into = {"t": truck, "c": _print(395.0, 1.6, 15.0, 1.5)}  # 3.2 m apart, then 1.7 m
    assert sideways_conflicts(["c"], into, 0.3) == {"c"}


def test_a_cacc_command_held_for_a_step_closes_no_more_than_the_law_would():
    from sumo_swarm.config import CaccSettings
    from sumo_swarm.controllers.cacc import held_share

    law = CaccSettings()  # k_speed 1.1 /s
    assert law.k_speed == pytest.approx(1.1)
    # Below a step of 1 / k_speed (0.91 s) the held command closes less than the whole error.
    for dt in (0.03, 0.1, 0.2, 0.5, 0.9):
        assert held_share(law, dt) == 1.0
    # At 1 s it would close 110 % of it: it closes what the law does over 1 s, 1 - exp(-1.1).
    assert held_share(law, 1.0) * 1.1 == pytest.approx(1.0 - math.exp(-1.1))
    assert held_share(law, 1.0) == pytest.approx(0.6065, abs=1e-4)


def test_a_vehicle_of_no_command_may_end_the_step_anywhere_its_braking_allows():
    # 25 m/s braking at 4.5 m/s^2 over 1 s ends 2.25 m short of 25 m; from 2 m/s it stops
    # within the step, 2 - 4 / 9 = 1.56 m short of 2 m.
    assert braking_short_m(25.0, 4.5, 1.0) == pytest.approx(2.25)
    assert braking_short_m(2.0, 4.5, 1.0) == pytest.approx(2.0 - 4.0 / 9.0)
    assert braking_short_m(25.0, 4.5, 0.1) == pytest.approx(0.0225)
    # The corridor's side collision at 1 s (corridor, 40 %, seed 42): a CAV moving 1.5 m into
    # the middle lane ends at 981.9 m; a car moving into it from the other side, 1.5 m across
    # from it at the end, ends at 988.5 m at its speed: 1.6 m ahead of the CAV's front, clear.
    # Braking within the step (it did: 25.3 -> 22.6 m/s), its rear comes level with the CAV.
    cav = Footprint(961.18, 5.0, 981.90, 3.5, 5.0, 1.8)
    car = Footprint(963.24, 1.0, 988.54, 2.0, 5.0, 1.8)
    assert sideways_conflicts(["cav"], {"cav": cav, "car": car}, 0.3) == set()
    braking = dataclasses.replace(car, short_m=braking_short_m(25.3, 4.5, 1.0))
    assert sideways_conflicts(["cav"], {"cav": cav, "car": braking}, 0.3) == {"cav"}
