"""The swarm controller's parts, without SUMO: decision, guards, progress, plan log."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from sumo_swarm.core.hvmodel import DriverModel, braking_needed
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.swarming.decision import (
    LanePass,
    Progress,
    TargetWatch,
    behaving_interval_s,
    keep_right_due_s,
    lane_for_pass,
    lane_pass_pace,
    lane_speeds,
    leader_ease_cap,
    only_catching_up,
    passing_lane,
    right_lane_free,
    right_lane_opens_within,
    secure_gap_m,
    slow_vehicle_ahead,
    speed_cap_mps,
    stopped_blocking,
    straggler_cruise,
    stranded_cavs,
    waiting_plan,
)
from sumo_swarm.core.swarming.guards import (
    GuardSettings,
    follower_beside,
    gap_accel_limit,
    lateral_refusal,
    too_close_alongside,
)
from sumo_swarm.core.swarming.planlog import PlanLog
from sumo_swarm.errors import ConfigError
from tests.fakes import FakeSession, run_context

ROAD = RoadSection((3.2, 3.2, 3.2))
IDM = DriverModel(model="IDM", accel_mps2=1.0, decel_mps2=2.0, tau_s=1.0, min_gap_m=2.0,
                  desired_speed_mps=30.0)  # fmt: skip


def car(vid, s, lane, v, *, cav=False, lat=0.0, length=5.0):
    return VehicleState(vid, s, lane, lat, v, length, 0.0, cav)


def find(leader, others, **kw):
    args = dict(slow_below_mps=19.0, detect_range_m=60.0, cap_mps=25.0, min_gain_mps=2.0,
                width_m=1.8)  # fmt: skip
    args.update(kw)
    return slow_vehicle_ahead(leader, others, ROAD, **args)


def test_target_is_the_slow_hv_ahead_in_the_leaders_own_lane():
    leader = car("c0", 100.0, 1, 15.0, cav=True)
    truck = car("truck", 130.0, 1, 15.0)
    beside = car("side", 110.0, 2, 12.0)  # slower, but in the neighbouring lane
    assert find(leader, [leader, truck, beside]).vehicle_id == "truck"
    assert find(leader, [leader, beside]) is None


def test_no_target_when_it_does_not_pay_or_is_far_or_a_cav():
    leader = car("c0", 100.0, 1, 15.0, cav=True)
    truck = car("truck", 130.0, 1, 15.0)
    assert find(leader, [leader, truck], cap_mps=16.5) is None  # 1.5 m/s to gain < 2
    assert find(leader, [leader, truck], detect_range_m=20.0) is None  # gap 25 m
    assert find(leader, [leader, car("c9", 130.0, 1, 15.0, cav=True)]) is None
    fast_leader = car("c0", 100.0, 1, 19.5, cav=True)  # not held back
    assert find(fast_leader, [fast_leader, truck]) is None
    # Speeding up at 0.8 m/s^2 (after a merge): not slow, unless [swarm] accelerating_mps2
    # allows that much.
    merging = dataclasses.replace(truck, accel_mps2=0.8)
    assert find(leader, [leader, merging]) is None
    assert find(leader, [leader, merging], accelerating_mps2=1.0).vehicle_id == "truck"


def test_target_watch_needs_persistence_and_respects_cool_down():
    watch = TargetWatch(trigger_after_s=2.0)
    truck = car("truck", 130.0, 1, 15.0)
    assert watch.update(0.0, truck) is None
    assert watch.update(1.9, truck) is None
    assert watch.update(2.0, truck) is truck
    other = car("van", 130.0, 1, 15.0)
    assert watch.update(2.1, other) is None  # a new candidate starts its own clock
    watch.cool_down(until_s=10.0)
    assert watch.update(9.0, truck) is None
    assert watch.update(10.0, truck) is None  # the clock starts after the cool-down
    assert watch.update(12.0, truck) is truck


def test_target_watch_waits_longer_for_a_target_about_to_keep_right():
    watch = TargetWatch(trigger_after_s=2.0)
    truck = car("truck", 130.0, 1, 15.0)
    assert watch.update(0.0, truck, wait_s=10.0) is None
    assert watch.update(9.9, truck, wait_s=10.0) is None
    assert watch.update(10.0, truck, wait_s=10.0) is truck
    # The lane on its right fills up at 5 s: no more reason to wait, the decision is due at once
    watch = TargetWatch(trigger_after_s=2.0)
    assert watch.update(0.0, truck, wait_s=10.0) is None
    assert watch.update(5.0, truck) is truck


def free(truck, *others):
    # Followers with SUMO's secure gap at headway 1 s and deceleration 2 m/s^2
    return right_lane_free(
        truck, [truck, *others], ROAD, move_s=8.0, ahead_s=4.0, min_gap_m=2.0,
        secure_gap=lambda f, v: secure_gap_m(1.0, 2.0, f.speed_mps, v),
    )  # fmt: skip


def test_secure_gap_hand_computed():
    assert secure_gap_m(1.0, 2.0, 20.0, 15.0) == pytest.approx(20.0 + (400 - 225) / 4.0)
    assert secure_gap_m(1.2, 4.5, 20.0, 10.0) == pytest.approx(24.0 + (400 - 100) / 9.0)
    assert secure_gap_m(1.2, 4.5, 10.0, 20.0) == 0.0  # the leader pulls away faster
    assert secure_gap_m(0.0, 4.5, 10.0, 10.0) == 0.0
    # A follower braking at 4 behind a leader SUMO takes to brake at 4.5, both at 30 m/s:
    # 30 + 900/8 - 900/9 = 42.5 m (SUMO's vehicle.getSecureGap: 42.49), not the 30 m of a
    # leader braking as the follower does
    assert secure_gap_m(1.0, 4.0, 30.0, 30.0, 4.5) == pytest.approx(42.5)
    assert secure_gap_m(1.0, 4.0, 30.0, 30.0) == pytest.approx(30.0)


def test_right_lane_free_hand_computed():
    truck = car("truck", 200.0, 1, 15.0, length=12.0)  # rear at 188 m
    assert free(truck)
    assert not free(car("truck", 200.0, 0, 15.0))  # no lane on its right
    # Behind in lane 0 at its speed: secure gap 1 s * 15 = 15 m, plus 2: free from 171 m back
    assert free(truck, car("a", 170.9, 0, 15.0))
    assert not free(truck, car("a", 171.1, 0, 15.0))
    # 5 m/s faster: 40 m closer in 8 s, secure gap 20 + 43.75 m: free from 188 - 105.75 m
    assert free(truck, car("a", 82.2, 0, 20.0))
    assert not free(truck, car("a", 82.3, 0, 20.0))
    assert not free(truck, car("a", 195.0, 0, 15.0))  # alongside
    # Ahead: a slower one within 2 + 4 s * 15 = 62 m of its front holds it (rear < 262 m)
    assert not free(truck, car("b", 266.0, 0, 14.0))  # rear at 261 m
    assert free(truck, car("b", 268.0, 0, 14.0))
    assert free(truck, car("b", 230.0, 0, 15.0))  # no slower: moving over loses nothing
    assert free(truck, car("c", 150.0, 2, 30.0))  # the lane on its left does not count


def test_keep_right_due_hand_computed():
    # SUMO's defaults (lcKeepRight 1, lcSpeedGain 1): the wish shows once the build-up passes
    # 2, at most 2 / 5 s = 0.4 per second.
    due = dict(keep_right=1.0, speed_gain=1.0)
    assert keep_right_due_s(1.2, None, 3.0, **due) == pytest.approx(2.0)  # at the fastest rate
    assert keep_right_due_s(-1.2, None, 3.0, **due) == pytest.approx(2.0)  # LC2013's sign
    assert keep_right_due_s(1.0, (2.0, 0.8), 3.0, **due) == pytest.approx(5.0)  # 0.2 per s seen
    assert keep_right_due_s(1.0, (2.9, 0.8), 3.0, **due) == pytest.approx(2.5)  # 0.1 s: too short
    assert keep_right_due_s(1.0, (2.0, 1.0), 3.0, **due) == math.inf  # not building up
    assert keep_right_due_s(2.0, None, 3.0, **due) == 0.0  # shown
    assert keep_right_due_s(2.5, (2.0, 1.0), 3.0, **due) == 0.0
    assert keep_right_due_s(1.0, None, 3.0, keep_right=0.0, speed_gain=1.0) == math.inf
    # lcSpeedGain 2 halves the threshold (1) and the rate (0.2 per s); lcKeepRight 2 doubles
    # the rate: the wish comes in 5 / lcKeepRight s from nothing.
    assert keep_right_due_s(0.5, None, 3.0, keep_right=1.0, speed_gain=2.0) == pytest.approx(2.5)
    assert keep_right_due_s(0.0, None, 3.0, keep_right=2.0, speed_gain=1.0) == pytest.approx(2.5)


def test_right_lane_opens_when_the_last_car_of_a_stream_has_passed():
    # The truck (15 m/s, front 200 m, 12 m long) and cars at 20 m/s on its right; secure gap
    # at 20 behind 15: 1 s * 20 + (400 - 225) / 4 = 63.75 m, plus 2. Constant speeds.
    truck = car("truck", 200.0, 1, 15.0, length=12.0)

    def opens(within_s, *others):
        return right_lane_opens_within(
            truck, [truck, *others], ROAD, within_s=within_s, move_s=0.0, ahead_s=4.0,
            min_gap_m=2.0, secure_gap=lambda f, v: secure_gap_m(1.0, 2.0, f.speed_mps, v),
        )  # fmt: skip

    assert opens(10.0) == 0.0  # nothing there
    assert opens(10.0, car("x", 150.0, 0, 30.0), car("y", 100.0, 2, 30.0)) is not None
    # "a" 8 m behind its rear: clear once its rear (175 + 20 t) is 2 m past the truck's front
    # (200 + 15 t): t > 5.4 s, the sample at 5.5 s.
    a = car("a", 180.0, 0, 20.0)
    assert opens(10.0, a) == pytest.approx(5.5)
    assert opens(5.0, a) is None
    # "b" 80 m behind "a": short of its secure gap once "a" has passed (88 - 5 t < 65.75 m),
    # clear itself at t > 21.4 s.
    b = car("b", 100.0, 0, 20.0)
    assert opens(10.0, a, b) is None
    assert opens(30.0, a, b) == pytest.approx(21.5)
    assert opens(30.0, a, car("b", 40.0, 0, 20.0)) == pytest.approx(5.5)  # far enough back
    assert opens(30.0, car("t", 200.0, 0, 15.0)) is None  # alongside at its speed for good
    rightmost = car("truck", 200.0, 0, 15.0)  # no lane on its right
    assert right_lane_opens_within(rightmost, [], ROAD, within_s=10.0, move_s=0.0, ahead_s=4.0,
                                   min_gap_m=2.0, secure_gap=lambda f, v: 0.0) is None  # fmt: skip


def test_speed_cap_and_drivable_interval():
    assert speed_cap_mps([25.0, 44.4, 22.2, math.inf]) == 22.2
    # 15 m cells, target at 17.5, cap 20: 2.5 m/s of room -> 6 s per row.
    assert behaving_interval_s(3.0, 15.0, 17.5, 20.0, "drivable") == pytest.approx(6.0)
    assert behaving_interval_s(3.0, 15.0, 17.5, 25.0, "drivable") == pytest.approx(3.0)
    assert behaving_interval_s(3.0, 15.0, 17.5, 20.0, "fixed") == 3.0
    assert behaving_interval_s(3.0, 15.0, 19.8, 20.0, "drivable") == pytest.approx(75.0)
    assert behaving_interval_s(3.0, 15.0, 20.0, 20.0, "drivable") == math.inf


def test_target_stops_blocking():
    kw = dict(slow_below_mps=19.0)
    truck = car("truck", 130.0, 1, 15.0)
    assert stopped_blocking(None, False, **kw) == "target_left"
    assert stopped_blocking(truck, True, **kw) == "target_changed_lane"
    fast = car("truck", 130.0, 1, 20.0)
    assert stopped_blocking(fast, False, **kw) == "target_sped_up"
    assert stopped_blocking(truck, False, **kw) is None
    # With CAVs past it too (the cruise re-forms the platoon, passes a CAV left behind).
    assert stopped_blocking(truck, True, slow_below_mps=19.0) == "target_changed_lane"


def test_progress_and_giving_up():
    p = Progress(started_s=0.0)
    truck = car("truck", 200.0, 1, 15.0)
    behind = [car("c0", 180.0, 1, 15.0, cav=True), car("c1", 165.0, 1, 15.0, cav=True)]
    p.update(1.0, truck, behind, 5.0)
    assert p.give_up_reason(10.0, no_progress_s=18.0, no_plan_s=20.0, has_plan=True) is None
    assert p.give_up_reason(19.5, 18.0, 20.0, True) == "no_progress"
    ahead = [car("c0", 215.0, 1, 20.0, cav=True), car("c1", 165.0, 1, 15.0, cav=True)]
    p.update(19.0, truck, ahead, 5.0)  # one CAV past: progress
    assert p.give_up_reason(19.5, 18.0, 20.0, True) is None
    assert p.give_up_reason(25.0, 18.0, 5.0, has_plan=False) == "no_feasible_plan"


def test_progress_counts_only_the_cavs_still_behind():
    # Two CAVs past the truck drive away from it at 5 m/s; the third stays stuck behind it.
    truck = car("truck", 200.0, 0, 12.0)
    p = Progress(started_s=0.0)
    for t in range(0, 20):
        cavs = [
            car("c0", 240.0 + 5.0 * t, 1, 17.0, cav=True),
            car("c1", 225.0 + 5.0 * t, 1, 17.0, cav=True),
            car("c2", 185.0, 0, 12.0, cav=True),
        ]
        p.update(float(t), truck, cavs, 5.0)
    assert (
        p.give_up_reason(19.0, no_progress_s=18.0, no_plan_s=30.0, has_plan=True) == "no_progress"
    )
    # The stuck CAV closing in on the truck by 4 m (> GAIN_STEP_M, 3 m) is progress; with
    # a step of 5 m it is not.
    import copy

    coarse = copy.copy(p)
    coarse.gain_step_m = 5.0
    closer = [*cavs[:2], car("c2", 189.0, 0, 12.0, cav=True)]
    p.update(19.5, truck, closer, 5.0)
    assert p.give_up_reason(20.0, 18.0, 30.0, True) is None
    coarse.update(19.5, truck, closer, 5.0)
    assert coarse.give_up_reason(20.0, 18.0, 30.0, True) == "no_progress"


def test_partly_past_gives_up_sooner():
    truck = car("truck", 200.0, 0, 12.0)
    p = Progress(started_s=0.0)
    cavs = [car("c0", 240.0, 1, 12.0, cav=True), car("c1", 185.0, 0, 12.0, cav=True)]
    p.update(0.0, truck, cavs, 5.0)  # one of two past
    kw = dict(no_progress_s=18.0, no_plan_s=99.0, has_plan=True, n_cavs=2)
    assert p.give_up_reason(8.0, partial_s=9.0, **kw) is None
    assert p.give_up_reason(9.5, partial_s=9.0, **kw) == "no_progress"
    assert p.give_up_reason(9.5, **kw) is None  # without the partial limit: 18 s
    behind = Progress(started_s=0.0)
    behind.update(0.0, truck, [car("c0", 185.0, 0, 12.0, cav=True)] * 2, 5.0)  # none past
    assert behind.give_up_reason(9.5, partial_s=9.0, **kw) is None


def test_a_plan_that_keeps_cavs_in_their_cells_strands_them():
    cells = {
        "c0": [(7, 1), (7, 1), (7, 1)],  # past, waiting in its cell: not behind
        "c2": [(2, 0), (2, 0), (2, 0)],  # behind, never moves: stranded
        "c3": [(1, 0), (1, 0), (1, 1)],  # behind, cuts out at the end: not stranded
        "c4": [(0, 0), (1, 0), (1, 0)],  # behind, moves up a row: not stranded
    }
    assert stranded_cavs(cells, ["c2", "c3", "c4"]) == {"c2"}
    assert stranded_cavs(cells, ["c0", "c2"]) == {"c0", "c2"}  # whoever the caller says is behind
    assert stranded_cavs(cells, ["gone"]) == set()


def test_a_plan_that_keeps_every_cav_behind_in_its_cell_for_a_while_waits():
    cells = {
        "c0": [(7, 1), (7, 1), (8, 1), (8, 1), (8, 1)],  # past: not behind, does not count
        "c1": [(2, 0), (2, 0), (2, 0), (2, 0), (3, 1)],  # moves at step 4
        "c2": [(1, 0), (1, 0), (1, 0), (2, 0), (2, 0)],  # moves at step 3
    }
    assert waiting_plan(cells, ["c1", "c2"], steps=2)  # steps 0-2 all in place
    assert not waiting_plan(cells, ["c1", "c2"], steps=3)  # c2 moves up a row at step 3
    assert waiting_plan(cells, ["c1"], steps=3)
    assert not waiting_plan(cells, ["c1"], steps=4)  # it cuts out at step 4
    # A horizon shorter than the wait: in place to its end (an idle plan) is waiting
    assert waiting_plan({"c3": [(0, 0)] * 3}, ["c3"], steps=9)
    assert not waiting_plan(cells, [], steps=2)  # none behind: nothing waits
    assert not waiting_plan(cells, ["gone"], steps=2)


def test_waiting_plans_give_up_after_the_configured_number():
    p = Progress(started_s=0.0)
    kw = dict(no_progress_s=99.0, no_plan_s=99.0, has_plan=True, waiting_plans=2)
    p.plan_waits(True)
    assert p.give_up_reason(3.0, **kw) is None  # one plan in a row
    p.plan_waits(True)
    assert p.give_up_reason(6.0, **kw) == "no_way_past"
    assert p.give_up_reason(6.0, **{**kw, "waiting_plans": 0}) is None  # switched off
    p.plan_waits(False)  # a plan that moves someone now starts the count again
    p.plan_waits(True)
    assert p.give_up_reason(9.0, **kw) is None


def test_plans_stranding_some_cavs_give_up_after_the_configured_number():
    p = Progress(started_s=0.0)
    kw = dict(no_progress_s=99.0, no_plan_s=99.0, has_plan=True, stranding_plans=2)
    p.plan_strands({"c3", "c4"}, 5)
    assert p.give_up_reason(3.0, **kw) is None  # one plan in a row
    p.plan_strands({"c3", "c4"}, 5)
    assert p.give_up_reason(6.0, **kw) == "cavs_stranded"
    assert p.give_up_reason(6.0, **{**kw, "stranding_plans": 0}) is None  # switched off
    p.plan_strands(set(), 5)  # a plan with a way past for everyone starts the count again
    assert p.give_up_reason(9.0, **kw) is None
    every = {f"c{i}" for i in range(5)}
    p.plan_strands(every, 5)  # every CAV kept in place: not "some", the progress rule decides
    p.plan_strands(every, 5)
    assert p.give_up_reason(12.0, **kw) is None
    # A plan that finds a way for some of the stranded CAVs is progress: the count restarts.
    q = Progress(started_s=0.0)
    q.plan_strands({"c1", "c2", "c3"}, 5)
    q.plan_strands({"c1"}, 5)
    assert q.give_up_reason(6.0, **kw) is None
    q.plan_strands({"c1", "c2"}, 5)  # more stranded than the plan before: counts
    assert q.give_up_reason(9.0, **kw) == "cavs_stranded"


def test_failed_replans_give_up_although_an_old_plan_is_kept():
    p = Progress(started_s=0.0)
    p.planned(2.0)
    p.failed()  # the replan failed; the swarm drives the old plan on
    assert p.give_up_reason(11.0, no_progress_s=99.0, no_plan_s=10.0, has_plan=True) is None
    assert p.give_up_reason(12.5, 99.0, 10.0, True) == "no_feasible_plan"
    p.planned(12.0)  # a usable plan again
    assert p.give_up_reason(12.5, 99.0, 10.0, True) is None


def test_gap_guard_hand_computed():
    ego = car("c0", 100.0, 1, 20.0, cav=True)
    lead = car("h", 120.0, 1, 18.0)  # bumper gap 15 m
    y1 = ROAD.lane_centre_y(1)
    limit = gap_accel_limit(ego, y1, y1, [ego, lead], ROAD, min_gap_m=5.0, width_m=1.8)
    g = GuardSettings()
    assert limit == pytest.approx(g.gap_gain * (15.0 - 6.0) + g.speed_gain * (18.0 - 20.0))
    assert gap_accel_limit(ego, y1, y1, [ego], ROAD, 5.0, 1.8) == math.inf


def test_gap_guard_keeps_the_minimum_gap_behind_a_leader_braking_steadily():
    # A CAV 6 m behind a CAV braking at a steady 1 m/s^2 from 20 m/s, commanded by the gap
    # guard alone: its gains settle inside the 1 m it aims beyond the minimum gap, but with the
    # leader's braking beyond 0.6 m/s^2 fed forward not below the 5 m minimum (4.75 m when
    # only the braking beyond 1 m/s^2 was: 4.998 m seen between two CAVs).
    y = ROAD.lane_centre_y(1)
    s_lead, v_lead, s_ego, v_ego, dt = 111.0, 20.0, 100.0, 20.0, 0.05
    gaps = []
    for _ in range(round(12.0 / dt)):
        lead = VehicleState("lead", s_lead, 1, 0.0, v_lead, 5.0, -1.0, True)
        ego = VehicleState("ego", s_ego, 1, 0.0, v_ego, 5.0, 0.0, True)
        accel = gap_accel_limit(ego, y, y, [ego, lead], ROAD, min_gap_m=5.0, width_m=1.8)
        v_ego = max(v_ego + min(accel, 0.0) * dt, 0.0)
        v_lead = max(v_lead - 1.0 * dt, 0.0)
        s_ego += v_ego * dt
        s_lead += v_lead * dt
        gaps.append(s_lead - 5.0 - s_ego)
    assert min(gaps) >= 5.0
    assert min(gaps) < 6.0  # it did close in: the guard, not a wide start, kept the gap


@pytest.mark.parametrize(
    ("gap_gain", "speed_gain", "step_s"),
    [(0.8, 1.5, 0.5), (0.8, 1.5, 1.0), (1.0, 3.0, 0.3), (1.0, 3.0, 1.0)],  # complex, real poles
)
def test_gap_gains_at_a_long_step_have_the_continuous_laws_poles(gap_gain, speed_gain, step_s):
    # Applied once per step (a speed held for the step, SUMO's Euler update), the guard's loop
    # is z^2 + (kv dt + kg dt^2 - 2) z + (1 - kv dt); its roots must be the continuous law's
    # (s^2 + kv s + kg) mapped to exp(s dt).
    kg, kv = GuardSettings(gap_gain=gap_gain, speed_gain=speed_gain).gap_gains(step_s)
    got = np.sort_complex(np.roots([1.0, kv * step_s + kg * step_s**2 - 2.0, 1.0 - kv * step_s]))
    want = np.sort_complex(np.exp(np.roots([1.0, speed_gain, gap_gain]) * step_s))
    assert np.allclose(got, want, atol=1e-9)


def test_gap_gains_known_values():
    g = GuardSettings()
    assert g.gap_gains(0.1) == (0.8, 1.5)  # up to the CAVs' tau: the gains as given
    assert g.gap_gains(0.2) == (0.8, 1.5)
    # By hand at 1 s: exp(-1.5) = 0.22313 (pole product), 2 exp(-0.75) cos(0.48734) = 0.83475
    # (pole sum): kv = 1 - 0.22313, kg = 1 - 0.83475 + 0.22313.
    assert g.gap_gains(1.0) == pytest.approx((0.38838, 0.77687), abs=1e-5)


def _column_under_the_gap_guard(step_s: float, discrete: bool, n: int = 12) -> tuple[float, float]:
    """(tail's lowest speed, smallest gap) of ``n`` CAVs 6 m apart at 18 m/s, each driven by
    the gap guard alone (it wants +3 m/s^2, brakes at most 4), commanded front to back and
    moved by SUMO's Euler update, behind a leader braking at 3 m/s^2 to 12 m/s, holding it 1 s
    and speeding up again; ``discrete``: the guard at the step with the speeds already
    commanded, else the continuous law on the last step's speeds."""
    y = ROAD.lane_centre_y(1)
    s, v, a = [300.0 - 11.0 * i for i in range(n)], [18.0] * n, [0.0] * n
    tail_mps, gap_m = 18.0, 6.0
    for k in range(round(20.0 / step_s)):
        t = (k + 1) * step_s
        now = {"c0": min(18.0, max(12.0, 18.0 - 3.0 * t), max(12.0, 3.0 + 3.0 * t))}
        states = [VehicleState(f"c{i}", s[i], 1, 0.0, v[i], 5.0, a[i], True) for i in range(n)]
        for i in range(1, n):
            limit = gap_accel_limit(
                states[i], y, y, states, ROAD, 5.0, 1.8,
                step_s=step_s if discrete else 0.0, speeds_now=now if discrete else None,
            )  # fmt: skip
            now[f"c{i}"] = max(0.0, v[i] + max(-4.0, min(3.0, limit)) * step_s)
        for i in range(n):
            a[i], v[i] = (now[f"c{i}"] - v[i]) / step_s, now[f"c{i}"]
            s[i] += v[i] * step_s
        tail_mps = min(tail_mps, v[-1])
        gap_m = min(gap_m, *(s[i - 1] - 5.0 - s[i] for i in range(1, n)))
    return tail_mps, gap_m


@pytest.mark.parametrize("step_s", [0.5, 1.0])
def test_gap_guard_at_long_steps_passes_a_dip_down_a_column_no_deeper_than_at_01s(step_s):
    # At the paper's 0.1 s the twelfth CAV dips to 7.8 m/s and the column closes to 1.2 m.
    # At 1 s the law as given, on the last step's speeds, drove the column through itself
    # (12-CAV paper-scene variants at 1 s: the tail stopped, the drivers behind braked beyond
    # 4 m/s^2); the discrete guard keeps the tail at the leader's 12 m/s less the 2 a step can
    # not follow.
    paper_tail, paper_gap = _column_under_the_gap_guard(0.1, discrete=False)
    assert (paper_tail, paper_gap) == pytest.approx((7.82, 1.2), abs=0.01)
    tail, gap = _column_under_the_gap_guard(step_s, discrete=True)
    assert tail >= 10.0 - 1e-9
    assert gap > paper_gap + 1.0
    assert _column_under_the_gap_guard(1.0, discrete=False)[1] < 0.0  # why: a collision


def refusal(ego, others, dlat=0.3):
    y = ROAD.y_of(ego.lane, ego.lat_m)
    return lateral_refusal(
        ego, y, dlat, [ego, *others], ROAD, min_gap_m=5.0, width_m=1.8,
        model_of=lambda vid: IDM, b_safe_mps2=2.0, step_s=0.1,
    )  # fmt: skip


def test_lateral_guard_uses_the_followers_own_model():
    ego = car("c0", 100.0, 1, 17.5, cav=True, lat=1.0)  # moving left, about to cross
    # A follower at the same speed 40 m back: IDM brakes gently, the move goes ahead.
    assert braking_needed(IDM, 17.5, 17.5, 40.0) < 2.0
    assert refusal(ego, [car("h", 55.0, 2, 17.5)]) is None
    # A follower 24 m back closing at 6.5 m/s: IDM would brake hard; the move is held.
    assert braking_needed(IDM, 24.0, 17.5, 24.0) > 2.0
    assert refusal(ego, [car("h", 71.0, 2, 24.0)]) == "follower_brake"
    assert refusal(ego, [car("h", 93.0, 2, 17.5)]) == "follower_gap"  # 2 m gap
    assert refusal(ego, [car("h", 108.0, 2, 17.5)]) == "leader"  # 3 m ahead
    assert refusal(ego, [car("h", 71.0, 2, 24.0)], dlat=0.0) is None
    # Moving within its own lane is never held.
    centred = car("c0", 100.0, 1, 17.5, cav=True)
    assert refusal(centred, [car("h", 71.0, 2, 24.0)], dlat=0.05) is None


def test_lateral_guard_sees_the_lanes_follower_behind_an_hv_leaning_towards_it():
    ego = car("c0", 100.0, 1, 17.5, cav=True, lat=1.0)  # moving left, about to cross
    # An HV of ego's own lane 15 m back, slower, leaning 0.5 m towards lane 2: it counts as
    # overlapping the lane ego enters, and the entry suits it.
    lean = car("lean", 90.0, 1, 15.0, lat=0.5)
    assert refusal(ego, [lean]) is None
    # Behind it, lane 2's own HV closes in at 6.5 m/s and would brake hard: held, although
    # the leaning HV is the nearer one (variant 24: an HV braked at 9 m/s^2).
    assert refusal(ego, [lean, car("h", 71.0, 2, 24.0)]) == "follower_brake"
    assert refusal(ego, [lean, car("h", 55.0, 2, 17.5)]) is None  # 40 m back, no faster


def test_plan_log_writes_lines_and_drops_a_failing_listener(tmp_path):
    log = PlanLog(tmp_path)
    seen = []
    log.listeners.append(seen.append)

    def broken(record):
        raise RuntimeError("boom")

    log.listeners.append(broken)
    log.write({"time_s": 1.0, "cells": (1, 2)})
    log.write({"time_s": 2.0})
    log.close()
    lines = [json.loads(x) for x in (tmp_path / "plans.jsonl").read_text().splitlines()]
    assert [r["time_s"] for r in lines] == [1.0, 2.0] and lines[0]["cells"] == [1, 2]
    assert len(seen) == 2 and broken not in log.listeners


def test_a_slow_car_is_only_catching_up_when_nothing_ahead_wants_less():
    desired = {"car": 33.0, "mid": 33.0, "lead": 19.7, "truck": 14.0}
    kw = dict(desired_of=lambda v: desired[v.vehicle_id], slow_below_mps=19.0, width_m=1.8)
    car18 = car("car", 200.0, 1, 18.9)
    # A line of cars closing in on a leader that wants 19.7 m/s: all want the trigger speed.
    line = [car18, car("mid", 240.0, 1, 18.9), car("lead", 280.0, 1, 18.95)]
    assert only_catching_up(car18, line, ROAD, **kw)
    # Alone on a free lane, wanting 33 m/s: catching up.
    assert only_catching_up(car18, [car18], ROAD, **kw)
    # A truck wanting 14 m/s heads the line: slow for good, a target.
    assert not only_catching_up(car18, [*line, car("truck", 320.0, 1, 14.0)], ROAD, **kw)
    # The candidate itself wants less than the trigger: slow for good.
    assert not only_catching_up(car("truck", 200.0, 1, 14.0), [], ROAD, **kw)
    # The truck beyond the 300 m reach, or in another lane, does not count.
    far = car("truck", 200.0 + 301.0, 1, 14.0)
    assert only_catching_up(car18, [car18, far], ROAD, **kw)
    assert only_catching_up(car18, [car18, car("truck", 230.0, 2, 14.0)], ROAD, **kw)
    # ...within a reach of 400 m ([swarm] catching_up_ahead_m) it does.
    assert not only_catching_up(car18, [car18, far], ROAD, ahead_m=400.0, **kw)


# --------------------------------------------------------------------------- lane speeds
def test_lane_speeds_from_the_nearest_vehicle_ahead_in_each_lane():
    leader = car("c0", 100.0, 1, 15.0, cav=True)
    others = [
        car("slow", 140.0, 0, 12.0),  # nearest ahead in lane 0
        car("far", 300.0, 0, 5.0),  # beyond the range
        car("behind", 90.0, 2, 30.0),  # behind the leader: does not slow the lane
        car("leaving", 130.0, 2, 11.0, lat=-1.7),  # its centre is in lane 1 already
        car("fast", 150.0, 1, 26.0),
    ]
    speeds = lane_speeds(leader, others, ROAD, [0, 1, 2], range_m=100.0, cap_mps=25.0)
    # lane 1: "leaving" counts there (its centre is across the line), nearer than "fast"
    assert speeds == {0: 12.0, 1: 11.0, 2: 25.0}
    # A truck alongside the leader (its front 2 m ahead, its rear behind the leader's front)
    # holds its lane to its speed; one whose front is behind the leader's rear does not.
    beside = [car("truck", 102.0, 2, 12.8, length=10.0), car("gone", 94.0, 0, 5.0)]
    assert lane_speeds(leader, beside, ROAD, [0, 2], range_m=100.0, cap_mps=25.0) == {
        0: 25.0,
        2: 12.8,
    }
    desired = lane_speeds(
        leader,
        others,
        ROAD,
        [0, 1],
        range_m=100.0,
        cap_mps=25.0,
        desired_of=lambda v: 10.0 if v.vehicle_id == "slow" else 99.0,
    )
    assert desired == {0: 10.0, 1: 11.0}  # "slow" drives 12 m/s but wants 10
    assert lane_speeds(leader, [], ROAD, [2], range_m=100.0, cap_mps=22.0) == {2: 22.0}


def test_margins_cached_per_desired_speed_class_on_the_safe_side():
    from sumo_swarm.core.hvmodel import min_entry_gap
    from sumo_swarm.core.swarming.manoeuvre import canonical_model, entry_gap

    a = DriverModel(model="IDM", desired_speed_mps=27.93, speed_factor=1.07)
    b = DriverModel(model="IDM", desired_speed_mps=27.51, speed_factor=0.99)
    assert canonical_model(a) == canonical_model(b)
    assert canonical_model(a).desired_speed_mps == 27.5 and canonical_model(a).speed_factor == 1
    assert entry_gap(a, 24.0, 18.0, 2.0, 0.1) == entry_gap(b, 24.0, 18.0, 2.0, 0.1)
    # A slower desired speed makes IDM brake harder: the cached margin is never the smaller.
    assert entry_gap(a, 24.0, 18.0, 2.0, 0.1) >= min_entry_gap(a, 24.0, 18.0, 2.0, 0.1) - 0.1


def test_lateral_guard_leaves_room_to_stop_closing_in_on_the_leader():
    ego = car("c0", 100.0, 1, 20.0, cav=True, lat=1.0)  # moving left, about to cross
    # 6 m/s faster than the vehicle ahead there: closing at b_safe needs 6^2 / (2 * 2) = 9 m,
    # stopping behind it at 4 m/s^2 (20^2 - 14^2) / 8 = 25.5 m: 5 + 25.5 m are needed.
    assert refusal(ego, [car("h", 100.0 + 5.0 + 30.0, 2, 14.0)]) == "leader"
    assert refusal(ego, [car("h", 100.0 + 5.0 + 31.0, 2, 14.0)]) is None
    slow = car("c0", 100.0, 1, 8.0, cav=True, lat=1.0)  # 6 m/s faster but slow: 9 m rule
    assert refusal(slow, [car("h", 100.0 + 5.0 + 13.5, 2, 2.0)]) == "leader"
    assert refusal(slow, [car("h", 100.0 + 5.0 + 14.5, 2, 2.0)]) is None
    # Not closing in: the minimum gap is enough.
    assert refusal(ego, [car("h", 100.0 + 5.0 + 5.5, 2, 20.0)]) is None
    assert refusal(ego, [car("h", 100.0 + 5.0 + 4.5, 2, 20.0)]) == "leader"


def test_an_idle_plan_is_one_that_keeps_every_cav_in_its_cell():
    from sumo_swarm.controllers.replanner import plan_is_idle
    from sumo_swarm.core.planner import Plan, PlanStatus

    def plan(*paths):
        cells = tuple(tuple(p) for p in paths)
        return Plan(PlanStatus.OPTIMAL, cells, 0.0, 1.0, "test", cav_ids=("c0", "c1"))

    waiting = plan([(2, 0)] * 4, [(1, 0)] * 4)
    assert plan_is_idle(waiting, 0) and plan_is_idle(waiting, 3)
    moving_later = plan([(2, 0), (2, 0), (2, 0), (2, 1)], [(1, 0)] * 4)
    assert not plan_is_idle(moving_later, 0)
    assert plan_is_idle(moving_later, 3)  # the move is behind it: it only holds from now on
    assert not plan_is_idle(Plan(PlanStatus.INFEASIBLE, None, None, 1.0, "test"), 0)


def test_lateral_guard_keeps_a_cav_follower_from_braking_hard():
    ego = car("c4", 100.0, 1, 10.0, cav=True, lat=-1.0)  # moving right, into lane 0
    # A CAV in lane 0 with a 10 m bumper gap, closing at 5 m/s: it needs 5^2 / (2 * 2) =
    # 6.25 m beyond the 5 m minimum gap to stop closing at b_safe; 10 < 11.25, held.
    fast = car("c5", 85.0, 0, 15.0, cav=True)
    assert refusal(ego, [fast], dlat=-0.3) == "follower_gap"
    # The same CAV at the ego's speed may follow at the minimum gap: the move goes ahead.
    assert refusal(ego, [car("c5", 85.0, 0, 10.0, cav=True)], dlat=-0.3) is None


def test_gap_lost_to_a_cav_follower_counts_what_ego_does_in_the_lane():
    from sumo_swarm.core.swarming.guards import gap_lost

    # ego keeps its speed: the follower's closing, 5^2 / (2 * 2)
    assert gap_lost(15.0, 2.0, 10.0, 0.0, 10.0) == pytest.approx(6.25)
    # ego brakes to a stop at 4 from 14.9, the follower at 2 from 20.5: 20.5^2/4 - 14.9^2/8
    assert gap_lost(20.5, 2.0, 14.9, 4.0, 0.0) == pytest.approx(105.0625 - 27.75125)
    # ego slows at 1 from 25 to 20, the follower at 2 from 30: equal speeds after 5 s, when
    # the follower drove 125 m and ego 112.5 m
    assert gap_lost(30.0, 2.0, 25.0, 1.0, 20.0) == pytest.approx(12.5)
    # a slower follower loses nothing, even as ego brakes harder than it
    assert gap_lost(10.0, 2.0, 15.0, 4.0, 0.0) == 0.0


def test_a_cav_braking_as_it_moves_over_is_not_cut_in_ahead_of_a_faster_cav():
    # ego brakes at 4 m/s^2 (for something in its own lane) as it moves right; a CAV 20 m
    # behind in lane 0 at 20.5 m/s: 5.6 m/s faster, 5 + 5.6^2 / 4 = 12.8 m would do if ego
    # kept its speed, but it may brake on to a stop: held.
    braking = VehicleState("c4", 100.0, 1, -1.0, 14.9, 5.0, -4.0, True)
    follower = car("c5", 75.0, 0, 20.5, cav=True)
    assert refusal(braking, [follower], dlat=-0.3) == "follower_gap"
    cruising = VehicleState("c4", 100.0, 1, -1.0, 14.9, 5.0, 0.0, True)
    assert refusal(cruising, [follower], dlat=-0.3) is None
    # A CAV 17 m behind: 12.8 m do for an ego keeping its speed. Closing in on a leader at
    # 10 m/s 21 m ahead there, ego slows 14.9 -> 10 m/s at 4.9^2 / (2 * 16) = 0.75 m/s^2; the
    # speeds meet after 5.6 / 1.25 = 4.48 s, 12.5 m closer: 17.5 m needed.
    near = car("c5", 78.0, 0, 20.5, cav=True)
    assert refusal(cruising, [near], dlat=-0.3) is None
    leader = car("h", 126.0, 0, 10.0)
    assert refusal(cruising, [near, leader], dlat=-0.3) == "follower_gap"
    assert refusal(cruising, [follower, leader], dlat=-0.3) is None  # 20 m: enough


def test_lateral_guard_sees_the_hv_behind_a_cav_that_only_leans_into_the_lane():
    ego = car("c5", 100.0, 1, 17.0, cav=True, lat=1.0)  # moving left, into lane 2
    # c6 leans 1.3 m into lane 2 from lane 1, 8 m behind ego at its speed: for the guard it is
    # the follower (a CAV, far enough), but its centre is in lane 1. The HV 24 m behind ego in
    # lane 2 does not follow c6, it sees ego moving in: 20 m/s against 17, IDM brakes hard.
    leaning = car("c6", 87.0, 1, 17.0, cav=True, lat=1.3)
    hv = car("h", 71.0, 2, 20.0)
    assert ROAD.lane_of(leaning) == 1
    assert refusal(ego, [leaning]) is None
    assert braking_needed(IDM, 20.0, 17.0, 24.0) > 2.0
    assert refusal(ego, [leaning, hv]) == "follower_brake"
    # With c6 in lane 2 (its centre there) the HV follows c6, not ego: the move goes ahead.
    assert refusal(ego, [car("c6", 87.0, 2, 17.0, cav=True), hv]) is None


def test_a_cav_waits_for_a_swarm_cav_clearing_the_lane_it_enters():
    from sumo_swarm.core.swarming.guards import yields_to_cav

    ego = car("c1", 100.0, 1, 16.0, cav=True, lat=1.0)  # moving left, into lane 2
    y = ROAD.y_of(ego.lane, ego.lat_m)
    kw = dict(min_gap_m=5.0, width_m=1.8)
    passing = car("c0", 103.0, 2, 21.0, cav=True)  # alongside, pulling away at 5 m/s
    assert yields_to_cav(ego, y, 0.3, [ego, passing], ROAD, **kw) == "c0"
    dropping = car("c2", 99.0, 2, 12.0, cav=True)  # alongside, dropping back
    assert yields_to_cav(ego, y, 0.3, [ego, dropping], ROAD, **kw) == "c2"
    # Not for a CAV at the same speed (a real conflict: the guard holds it), nor an HV.
    same = car("c0", 103.0, 2, 16.0, cav=True)
    assert yields_to_cav(ego, y, 0.3, [ego, same], ROAD, **kw) is None
    assert yields_to_cav(ego, y, 0.3, [ego, car("h", 103.0, 2, 21.0)], ROAD, **kw) is None
    # Clear by the minimum gap, or moving within its own lane: nothing to wait for.
    assert (
        yields_to_cav(ego, y, 0.3, [ego, car("c0", 112.0, 2, 21.0, cav=True)], ROAD, **kw) is None
    )
    assert yields_to_cav(car("c1", 100.0, 1, 16.0, cav=True), ROAD.y_of(1, 0.0), 0.05,
                         [ego, passing], ROAD, **kw) is None  # fmt: skip


def test_a_vehicle_beside_the_road_is_in_none_of_its_lanes():
    # An acceleration lane counts as lane -1 of the road beside it (SumoSession numbers every
    # vehicle's lane on the platoon leader's edge): a car merging from it is not in lane 0. It
    # does not set lane 0's speed, it is no target's right-hand lane, and CAVs settled in it
    # are in no lane to pass in.
    leader = car("c0", 100.0, 0, 25.0, cav=True)
    merging = car("merging", 130.0, -1, 12.0)
    assert ROAD.lane_of(merging) == -1
    assert ROAD.lane_of(dataclasses.replace(merging, lat_m=1.7)) == 0  # across the line: in
    assert lane_speeds(leader, [merging], ROAD, [0, 1], range_m=100.0, cap_mps=25.0) == {
        0: 25.0,
        1: 25.0,
    }
    assert not free(car("truck", 200.0, -1, 15.0))  # nothing on its right, as in lane 0
    truck = car("truck", 300.0, 0, 15.0)
    beside = [car(f"c{i}", 290.0 - 15.0 * i, -1, 20.0, cav=True) for i in range(2)]
    assert passing_lane(truck, beside, ROAD, tolerance_m=0.3) is None


def test_passing_lane_is_one_settled_lane_that_is_not_the_targets():
    truck = car("truck", 300.0, 0, 15.0)
    kw = dict(tolerance_m=0.3)
    cavs = [car(f"c{i}", 290.0 - 15.0 * i, 1, 20.0, cav=True) for i in range(3)]
    assert passing_lane(truck, cavs, ROAD, **kw) == 1
    ahead_in_2 = [car(f"c{i}", 320.0 - 15.0 * i, 2, 25.0, cav=True) for i in range(3)]
    assert passing_lane(truck, ahead_in_2, ROAD, **kw) == 2  # past it or not: one lane
    one_left_behind = [*cavs[:2], car("c2", 260.0, 0, 15.0, cav=True)]
    assert passing_lane(truck, one_left_behind, ROAD, **kw) is None
    two_lanes = [*cavs[:2], car("c2", 260.0, 2, 20.0, cav=True)]
    assert passing_lane(truck, two_lanes, ROAD, **kw) is None
    changing = [*cavs[:2], dataclasses.replace(cavs[2], lat_m=-1.0)]  # still moving over
    assert passing_lane(truck, changing, ROAD, **kw) is None
    in_its_lane = [car(f"c{i}", 290.0 - 15.0 * i, 0, 15.0, cav=True) for i in range(3)]
    assert passing_lane(truck, in_its_lane, ROAD, **kw) is None
    assert passing_lane(truck, [], ROAD, **kw) is None
    moved_over = dataclasses.replace(truck, lane=1)  # the target in the CAVs' lane
    assert passing_lane(moved_over, cavs, ROAD, **kw) is None


def test_lateral_guard_judges_an_entry_speeding_up_by_the_speeds_it_reaches():
    krauss = DriverModel("Krauss", 2.6, 4.5, 9.0, 1.0, 2.5, desired_speed_mps=33.0, sigma=0.0)

    def held(ego, others, **kw):
        y = ROAD.y_of(ego.lane, ego.lat_m)
        return lateral_refusal(
            ego, y, 0.3, [ego, *others], ROAD, min_gap_m=5.0, width_m=1.8,
            model_of=lambda vid: krauss, b_safe_mps2=2.0, step_s=0.1, **kw,
        )  # fmt: skip

    ego = car("c0", 300.0, 0, 15.0, cav=True, lat=1.0)  # moving left into lane 1
    # The driver 150 m behind at 33 m/s (see test_hvmodel): held at 15 m/s, not speeding up.
    fast = car("h", 145.0, 1, 33.0)  # its front 150 m behind ego's rear (295 m)
    assert held(ego, [fast]) == "follower_brake"
    assert held(ego, [fast], ego_accel_mps2=1.5, ego_final_mps=33.0) is None
    # Speeding up to 33 m/s behind a leader at 20 m/s 30 m ahead: closing in, held.
    slow = car("l", 340.0, 1, 20.0)
    assert held(ego, [slow]) is None
    assert held(ego, [slow], ego_accel_mps2=1.5, ego_final_mps=33.0) == "leader"


def test_the_leader_eases_off_more_only_for_a_platoon_strung_out_in_its_lane():
    from sumo_swarm.core.neighbours import Snapshot

    kw = dict(width_m=1.8, reach_m=60.0, ease_mps=2.0, regroup_ease_mps=5.0)

    def ease(states, platoon, **kw):  # the same answer over a plain table and a Snapshot
        plain = leader_ease_cap(states, platoon, ROAD, **kw)
        assert leader_ease_cap(states, platoon, ROAD, everyone=Snapshot(states.values(), ROAD),
                               **kw) == plain  # fmt: skip
        return plain

    platoon = ["c0", "c1", "c2"]
    strung = states_of(
        car("c0", 500.0, 1, 20.0, cav=True), car("c1", 380.0, 1, 22.0, cav=True),
        car("c2", 360.0, 1, 22.0, cav=True),
    )  # fmt: skip
    assert ease(strung, platoon, **kw) == 5.0
    # An HV between the leader and the others: easing off would hold it back, not close up.
    assert ease({**strung, **states_of(car("h", 450.0, 1, 20.0))}, platoon, **kw) == 2.0
    # A CAV stuck in another lane (behind a truck): the leader slowing does not bring it closer.
    stuck = {**strung, **states_of(car("c2", 360.0, 0, 12.0, cav=True))}
    assert ease(stuck, platoon, **kw) == 2.0
    # A single CAV leading, an HV 30 m behind it: that HV would be held back.
    alone = states_of(car("c0", 500.0, 1, 20.0, cav=True), car("h", 465.0, 1, 22.0))
    assert ease(alone, ["c0"], **kw) == 2.0
    far = states_of(car("c0", 500.0, 1, 20.0, cav=True), car("h", 400.0, 1, 22.0))
    assert ease(far, ["c0"], **kw) == 5.0
    # Vehicles in other lanes do not matter; no larger ease configured: the base one.
    beside = {**strung, **states_of(car("h", 450.0, 2, 20.0))}
    assert ease(beside, platoon, **kw) == 5.0
    assert ease(strung, platoon, **{**kw, "regroup_ease_mps": 2.0}) == 2.0


def test_a_cav_fallen_back_behind_a_platoon_cav_in_another_lane_closes_up():
    kw = dict(cruise_mps=20.0, cap_mps=25.0, desired_gap_m=10.0, k_close=0.15,
              slow_below_mps=18.0, reach_m=60.0, width_m=1.8)  # fmt: skip
    # c2 in lane 0, 60 m behind c1's rear (lane 1): 20 + 0.15 * 50 = 27.5, capped at 25.
    # c1 follows c0 in its own lane: the CACC's own k_close handles it, nothing here.
    st = states_of(
        car("c0", 500.0, 1, 20.0, cav=True), car("c1", 470.0, 1, 20.0, cav=True),
        car("c2", 405.0, 0, 20.0, cav=True),
    )  # fmt: skip
    assert straggler_cruise(st, ["c0", "c1", "c2"], ROAD, **kw) == {"c2": 25.0}
    # Its front 20 m behind c1's rear: 20 + 0.15 * (20 - 10) = 21.5.
    st["c2"] = car("c2", 445.0, 0, 20.0, cav=True)
    assert straggler_cruise(st, ["c0", "c1", "c2"], ROAD, **kw) == {"c2": pytest.approx(21.5)}
    # Within the desired gap, or in the same lane: the platoon's cruise.
    st["c2"] = car("c2", 460.0, 0, 20.0, cav=True)
    assert straggler_cruise(st, ["c0", "c1", "c2"], ROAD, **kw) == {}
    st["c2"] = car("c2", 405.0, 1, 20.0, cav=True)
    assert straggler_cruise(st, ["c0", "c1", "c2"], ROAD, **kw) == {}
    # A truck at 14 m/s 40 m ahead of it in its lane: it would only close in on the truck.
    st["c2"] = car("c2", 405.0, 0, 20.0, cav=True)
    st["truck"] = car("truck", 450.0, 0, 14.0)
    assert straggler_cruise(st, ["c0", "c1", "c2"], ROAD, **kw) == {}
    # ...but a car at the cruise ahead of it does not hold it back (it follows that car).
    st["truck"] = car("truck", 450.0, 0, 20.0)
    assert straggler_cruise(st, ["c0", "c1", "c2"], ROAD, **kw) == {"c2": 25.0}


def states_of(*vehicles):
    return {v.vehicle_id: v for v in vehicles}


def test_lane_for_pass_is_a_faster_lane_with_room_not_the_one_the_target_moves_into():
    truck = car("truck", 300.0, 0, 15.0)
    leader, tail = car("c0", 280.0, 0, 15.0, cav=True), car("c2", 250.0, 0, 15.0, cav=True)
    kw = dict(n_cavs=3, cell_length_m=15.0, range_m=60.0, cap_mps=33.0, cruise_mps=33.0,
              pace_mps=20.0, min_gain_mps=2.0, tolerance_m=0.3)  # fmt: skip
    assert lane_for_pass(leader, tail, truck, [truck], ROAD, [1], **kw) == 1  # free: 33 > 22
    # The cruise only 1 m/s above the cells' pace: the cells.
    assert (
        lane_for_pass(leader, tail, truck, [truck], ROAD, [1], **{**kw, "cruise_mps": 21.0}) is None
    )
    # A car 40 m ahead in lane 1 at 21 m/s: the lane is no faster than the pace by the gain.
    slow = car("s", 320.0, 1, 21.0)
    assert lane_for_pass(leader, tail, truck, [truck, slow], ROAD, [1], **kw) is None
    # Room: the window is 245 - 60 .. 280 + 60 m (155 m) and 3 CAVs need 45 m (3 cells) per
    # vehicle there: three cars in lane 1 leave 51.7 m each, four 38.75 m.
    three = [car(f"h{i}", 200.0 + 40.0 * i, 1, 33.0) for i in range(3)]  # fronts 200-280 m
    assert lane_for_pass(leader, tail, truck, [truck, *three], ROAD, [1], **kw) == 1
    four = [*three, car("h3", 330.0, 1, 33.0)]
    assert lane_for_pass(leader, tail, truck, [truck, *four], ROAD, [1], **kw) is None
    # Two free lanes: the left one (SUMO numbers lanes from the right)...
    middle = car("c0", 280.0, 1, 15.0, cav=True)
    in_1 = dataclasses.replace(truck, lane=1)
    assert lane_for_pass(middle, tail, in_1, [in_1], ROAD, [0, 2], **kw) == 2
    # ...but never the lane the target is moving into (0.8 m to the left of its centre).
    moving_left = dataclasses.replace(in_1, lat_m=0.8)
    assert lane_for_pass(middle, tail, moving_left, [moving_left], ROAD, [0, 2], **kw) == 0
    # A cruise of 21 m/s: 1 m/s above the cells' pace, but 3 above a free pace of 18, which
    # counts in a lane with no HV beside the platoon or within 60 m behind its tail.
    free = {**kw, "cruise_mps": 21.0, "free_pace_mps": 18.0}
    assert lane_for_pass(leader, tail, truck, [truck], ROAD, [1], **free) == 1
    beside = car("b", 265.0, 1, 33.0)
    assert lane_for_pass(leader, tail, truck, [truck, beside], ROAD, [1], **free) is None
    coming = car("b", 200.0, 1, 33.0)  # 45 m behind the tail's rear
    assert lane_for_pass(leader, tail, truck, [truck, coming], ROAD, [1], **free) is None
    far = car("b", 180.0, 1, 33.0)  # 65 m behind it
    assert lane_for_pass(leader, tail, truck, [truck, far], ROAD, [1], **free) == 1
    slower = car("b", 200.0, 1, 14.0)  # 45 m behind, slower than the tail: it never comes up
    assert lane_for_pass(leader, tail, truck, [truck, slower], ROAD, [1], **free) == 1


def test_a_lane_pass_must_beat_the_cells_or_only_the_cruise_less_the_gain():
    kw = dict(cruise_mps=20.0, min_gain_mps=2.0)
    # A 14.4 m/s truck, cells 5 m/s above it: 19.4 with "cells", 18 with "free" (so a lane
    # free at the 20 m/s cruise beats it by the gain).
    assert lane_pass_pace(14.4, 5.0, rule="cells", **kw) == pytest.approx(19.4)
    assert lane_pass_pace(14.4, 5.0, rule="free", **kw) == pytest.approx(18.0)
    # A 12 m/s truck with 4 m/s cells: 16 either way (the cells' pace is lower).
    assert lane_pass_pace(12.0, 4.0, rule="free", **kw) == pytest.approx(16.0)
    # A target at 19 m/s: never below the target itself.
    assert lane_pass_pace(19.0, 5.0, rule="free", **kw) == pytest.approx(19.0)


def test_a_lane_pass_completes_stalls_or_goes_on():
    truck = car("truck", 300.0, 0, 15.0)
    lp = LanePass("truck", 1, since_s=10.0)
    kw = dict(min_gap_m=5.0, stall_s=15.0)
    behind = [car("c0", 280.0, 0, 15.0, cav=True), car("c1", 265.0, 0, 15.0, cav=True)]
    assert lp.update(20.0, truck, behind, ROAD, **kw) is None
    assert lp.update(25.1, truck, behind, ROAD, **kw) == "stalled"  # 15.1 s, none out
    lp = LanePass("truck", 1, since_s=10.0)
    one_out = [dataclasses.replace(behind[0], lane=1), behind[1]]
    assert lp.update(20.0, truck, one_out, ROAD, **kw) is None  # progress at 20 s
    assert lp.update(34.0, truck, one_out, ROAD, **kw) is None
    assert lp.update(35.1, truck, one_out, ROAD, **kw) == "stalled"
    # Every CAV out of its lane: passing it, never stalled however long it takes.
    lp = LanePass("truck", 1, since_s=10.0)
    all_out = [dataclasses.replace(c, lane=1) for c in behind]
    assert lp.update(60.0, truck, all_out, ROAD, **kw) is None
    assert lp.update(90.0, truck, all_out, ROAD, **kw) is None
    past = [car("c0", 330.0, 1, 25.0, cav=True), car("c1", 312.0, 1, 25.0, cav=True)]
    assert lp.update(91.0, truck, past, ROAD, **kw) == "completed"  # rears 325, 307 > 305
    assert lp.update(92.0, None, past, ROAD, **kw) == "target_left"


def test_a_move_within_the_lane_towards_an_hv_leaning_in_from_behind_is_judged_as_entering():
    # Lanes 3.2 m wide: lane 1's left boundary at y = 4.8. An HV of lane 2 leaning 0.07 m into
    # lane 1 (centre 0.77 m right of lane 2's: its right side at 6.4 - 0.77 - 0.9 = 4.73) and
    # a CAV centred in lane 1 (left side at 4.1): 0.63 m apart. Moving 0.2 m left (still in
    # lane 1) leaves 0.43 m, within SUMO's 0.6 m minGapLat: the HV would take the CAV for its
    # leader, 4 m ahead and 3.6 m/s slower (stress scene 113: it braked at 9 m/s^2).
    ego = car("c6", 100.0, 1, 14.9, cav=True)
    hv = car("h", 91.0, 2, 18.5, lat=-0.77)  # its front 4 m behind ego's rear
    y = ROAD.y_of(1, 0.0)
    guard = dict(min_gap_m=5.0, width_m=1.8, model_of=lambda vid: IDM, b_safe_mps2=2.0,
                 step_s=0.1)  # fmt: skip
    found = follower_beside(ego, y, 0.2, [ego, hv], ROAD, 1.8, 0.6)
    assert found is not None and found[0] is hv and found[1] == pytest.approx(4.0)
    assert lateral_refusal(ego, y, 0.2, [ego, hv], ROAD, **guard) == "follower_gap"
    assert follower_beside(ego, y, -0.2, [ego, hv], ROAD, 1.8, 0.6) is None  # moving away
    assert lateral_refusal(ego, y, -0.2, [ego, hv], ROAD, **guard) is None
    # Alongside and a little behind (its front 0.3 m behind ego's): a negative gap, held.
    beside = dataclasses.replace(hv, s_m=99.7)
    assert follower_beside(ego, y, 0.2, [ego, beside], ROAD, 1.8, 0.6)[1] == pytest.approx(-4.7)
    # Centred in lane 2 (1.4 m apart after the move), or far behind, or off: nothing to judge.
    centred = dataclasses.replace(hv, lat_m=0.0)
    assert follower_beside(ego, y, 0.2, [ego, centred], ROAD, 1.8, 0.6) is None
    far = dataclasses.replace(hv, s_m=40.0)
    assert follower_beside(ego, y, 0.2, [ego, far], ROAD, 1.8, 0.6) is None
    off = GuardSettings(follower_lat_gap_m=0.0)
    assert lateral_refusal(ego, y, 0.2, [ego, hv], ROAD, settings=off, **guard) is None
    with pytest.raises(ConfigError, match="follower_lat_gap_m"):
        GuardSettings(follower_lat_gap_m=-1.0)


def test_no_lateral_move_brings_a_cav_beside_an_hv_straddling_the_lane_boundary():
    settings = GuardSettings()
    # An HV of lane 1 stopped half-way through a lane change to the right: its centre 0.95 m
    # right of lane 1's, its right side 0.25 m into lane 0. The CAV alongside in lane 0 at
    # 0.2 m left of its lane centre keeps 1.6 - 0.2 - 0.9 - 0.25 = 0.25 m to it; moving 0.1 m
    # further left leaves 0.15 m, under the 0.3 m clearance: held, though it stays in lane 0.
    hv = car("h", 101.0, 1, 25.0, lat=-0.95)
    ego = car("c4", 100.0, 0, 15.0, cav=True, lat=0.2)
    y = ROAD.y_of(0, 0.2)
    kw = dict(width_m=1.8, clearance_m=settings.side_clearance_m)
    assert too_close_alongside(ego, y, 0.1, [ego, hv], ROAD, **kw)
    assert not too_close_alongside(ego, y, -0.1, [ego, hv], ROAD, **kw)  # moving away
    assert not too_close_alongside(ego, y, 0.0, [ego, hv], ROAD, **kw)
    # Far enough ahead lengthwise (its rear 0.3 m past ego's front and more): no matter.
    ahead = dataclasses.replace(hv, s_m=100.0 + 5.0 + 0.31)
    assert not too_close_alongside(ego, y, 0.1, [ego, ahead], ROAD, **kw)
    # A vehicle centred in lane 1 leaves 1.4 - 0.3 = 1.1 m after the move: fine.
    centred = dataclasses.replace(hv, lat_m=0.0)
    assert not too_close_alongside(ego, y, 0.1, [ego, centred], ROAD, **kw)
    # The lateral guard holds the move, in lane or not, naming why; 0 turns the check off.
    guard = dict(min_gap_m=5.0, width_m=1.8, model_of=lambda vid: IDM, b_safe_mps2=2.0,
                 step_s=0.1)  # fmt: skip
    assert lateral_refusal(ego, y, 0.1, [ego, hv], ROAD, **guard) == "alongside"
    off = GuardSettings(side_clearance_m=0.0)
    assert lateral_refusal(ego, y, 0.1, [ego, hv], ROAD, settings=off, **guard) is None


def test_the_wait_for_a_target_keeping_right_holds_in_the_leftmost_lane_only():
    # A keep-right truck with the lane to its right free: the swarm waits. A car then passes
    # beside it there for a moment: in the leftmost lane (every pass takes the lane it is to
    # move into) the wait holds; with a lane on its left and [swarm] keep_right_middle =
    # "wait", the swarm may start (and passed faster so in a paper-scene variant).
    import dataclasses

    from sumo_swarm.config import Scenario
    from sumo_swarm.controllers.decider import Decider
    from sumo_swarm.controllers.lanes import LaneView
    from sumo_swarm.core.hvmodel import DriverModel

    events = []
    session = FakeSession(keeps_right=lambda vid: True)
    default = Scenario(name="t", path=None)
    waits = dataclasses.replace(
        default, swarm=dataclasses.replace(default.swarm, keep_right_middle="wait")
    )

    def controller(scenario):
        ctx = run_context(session, scenario, ROAD)
        ctx.events = events
        return Decider(ctx, lanes=LaneView(ctx), reformer=None, planner=scenario.planner,
                       model_of=lambda vid: DriverModel(model="unknown"))  # fmt: skip

    for lane, holds in ((2, True), (1, False)):
        decider = controller(waits)
        truck = car("truck", 300.0, lane, 14.0)
        assert decider.may_keep_right(truck, states_of(truck))  # the lane to its right is free
        beside = car("c", 300.0, lane - 1, 14.0)
        assert decider.may_keep_right(truck, states_of(truck, beside)) is holds
    assert [e["event"] for e in events] == ["target_may_keep_right"] * 2
    # The default, "left": a target with a lane on its left is not waited for; its right lane
    # is closed to the plan while free, for keep_right_wait_s (10 s) from the start.
    decider = controller(default)
    truck = car("truck", 300.0, 1, 14.0)
    assert not decider.may_keep_right(truck, states_of(truck))
    assert decider.keep_right_closure(5.0, 0.0, truck, states_of(truck)) == 0
    beside = car("c", 300.0, 0, 14.0)
    assert decider.keep_right_closure(5.0, 0.0, truck, states_of(truck, beside)) is None  # taken
    assert decider.keep_right_closure(10.5, 0.0, truck, states_of(truck)) is None  # waited enough
    leftmost = car("truck", 300.0, 2, 14.0)
    assert decider.keep_right_closure(5.0, 0.0, leftmost, states_of(leftmost)) is None  # waited for
    assert decider.may_keep_right(leftmost, states_of(leftmost))
    assert controller(waits).keep_right_closure(5.0, 0.0, truck, states_of(truck)) is None


def test_the_right_lane_is_judged_for_when_sumo_says_the_truck_will_move():
    # A fresh variant of seed 23: a keep-right truck at 14.97 m/s in the middle lane, 3 s into
    # the run (its wish 2 s away by SUMO's build-up), a car at 17.87 m/s on its right 62 m
    # behind its rear. SUMO lets the truck in front of it at its minGap (2 m) plus its secure
    # gap at IDM's 1.2 s and 1.67 m/s^2 (21.44 + 28.51 = 49.95 m): 51.95 m. Judged the old way,
    # 5 s ahead with the CAVs' 5 m, it has closed 14.5 m (47.5 m left, 54.95 needed): not
    # free, and the plan sent a blocker there, which kept the truck in the platoon's way
    # until 17 s (it moved at 7 s under cacc). Judged 2 s ahead (56.2 m left): free, so
    # closed to the plan.

    from sumo_swarm.config import Scenario
    from sumo_swarm.controllers.decider import Decider
    from sumo_swarm.controllers.lanes import LaneView
    from sumo_swarm.core.hvmodel import DriverModel

    due = {"truck": 2.0}
    session = FakeSession(keeps_right=lambda vid: True, wants_right=lambda vid: False,
                          keep_right_due_s=lambda vid: due["truck"])  # fmt: skip
    idm = DriverModel(model="IDM", accel_mps2=0.73, decel_mps2=1.67, tau_s=1.2, min_gap_m=2.0,
                      desired_speed_mps=18.5)  # fmt: skip
    default = Scenario(name="t", path=None)
    off = dataclasses.replace(
        default, swarm=dataclasses.replace(default.swarm, keep_right_due=False)
    )

    def closure(scenario, *vehicles):
        ctx = run_context(session, scenario, ROAD)
        decider = Decider(ctx, lanes=LaneView(ctx), reformer=None, planner=scenario.planner,
                          model_of=lambda vid: idm)  # fmt: skip
        return decider.keep_right_closure(3.0, 3.0, vehicles[0], states_of(*vehicles))

    truck = car("truck", 360.36, 1, 14.97)
    follower = car("hv_right", 360.36 - 5.0 - 62.0, 0, 17.87)
    assert secure_gap_m(1.2, 1.67, 17.87, 14.97) == pytest.approx(49.95, abs=0.01)
    assert closure(default, truck, follower) == 0
    assert closure(off, truck, follower) is None  # keep_right_move_s (5 s) ahead, 5 m
    # Speeding up at 0.3 m/s^2 (towards a desired speed well above): 18.47 m/s in 2 s, 0.6 m
    # closer, secure gap 22.16 + 35.04: 59.8 m needed, 56.2 left. Not free: the truck will
    # not get in in front of it (blocking that car is what lets it in).
    speeding = dataclasses.replace(follower, accel_mps2=0.3)
    assert closure(default, truck, speeding) is None
    due["truck"] = None  # SUMO cannot tell: the old way
    assert closure(default, truck, follower) is None
    due["truck"] = 9.0  # further off than keep_right_move_s: 5 s ahead, 47.5 m left
    assert closure(default, truck, follower) is None
    due["truck"] = 0.0  # the wish shows: free if it is free now (62 m)
    assert closure(default, truck, follower) == 0
    nearer = car("hv_right", 360.36 - 5.0 - 51.0, 0, 17.87)  # 51 m: not even now
    assert closure(default, truck, nearer) is None


def test_the_right_lane_stays_closed_while_a_middle_lane_target_wants_to_move_there():
    # A keep-right truck in the middle lane whose driver wants to move right (SUMO's
    # lane-change state) while a stream passes on its right: that lane is not free, and the
    # wait for it is over, yet it stays closed to the plan for as long as the wish lasts (the
    # truck moves over once the stream has passed; CAVs passing there kept it from doing so:
    # held-out variants, 0.3-0.4 m/s slower than cacc). [swarm] keep_right_wish = false: the
    # former rule, closed only while free.
    import dataclasses

    from sumo_swarm.config import Scenario
    from sumo_swarm.controllers.decider import Decider
    from sumo_swarm.controllers.lanes import LaneView
    from sumo_swarm.core.hvmodel import DriverModel

    wish = {"truck": True}
    session = FakeSession(keeps_right=lambda vid: True, wants_right=lambda vid: wish[vid])
    default = Scenario(name="t", path=None)
    off = dataclasses.replace(
        default, swarm=dataclasses.replace(default.swarm, keep_right_wish=False)
    )

    def decider(scenario):
        ctx = run_context(session, scenario, ROAD)
        return Decider(ctx, lanes=LaneView(ctx), reformer=None, planner=scenario.planner,
                       model_of=lambda vid: DriverModel(model="unknown"))  # fmt: skip

    truck = car("truck", 300.0, 1, 14.0)
    stream = car("c", 290.0, 0, 23.0)  # passing on its right: the lane is not free
    states = states_of(truck, stream)
    assert decider(default).keep_right_closure(40.0, 0.0, truck, states) == 0
    # A stream that passes it for longer than keep_right_soon_s (10 s): not closed for it.
    long = [car(f"s{k}", 290.0 - 25.0 * k, 0, 23.0) for k in range(12)]
    assert decider(default).keep_right_closure(40.0, 0.0, truck, states_of(truck, *long)) is None
    cavs = [car(f"s{k}", 290.0 - 25.0 * k, 0, 23.0, cav=True) for k in range(12)]
    assert decider(default).keep_right_closure(40.0, 0.0, truck, states_of(truck, *cavs)) == 0
    assert decider(off).keep_right_closure(40.0, 0.0, truck, states) is None
    assert decider(off).keep_right_closure(5.0, 0.0, truck, states) is None  # taken
    wish["truck"] = False  # no wish: the former rule
    assert decider(default).keep_right_closure(40.0, 0.0, truck, states) is None
    assert decider(default).keep_right_closure(5.0, 0.0, truck, states_of(truck)) == 0
    leftmost = car("truck", 300.0, 2, 14.0)  # waited for instead (keep_right_wait_s)
    wish["truck"] = True
    assert decider(default).keep_right_closure(40.0, 0.0, leftmost, states_of(leftmost)) is None
