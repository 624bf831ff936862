"""The swarm's one decision principle (core/swarming/arbiter.py) on hand-made scenes."""

from __future__ import annotations

import math

import pytest

from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.swarming.arbiter import (
    PlatoonView,
    choose,
    insertion_loss_m,
    lane_pace_mps,
    mean_speed_mps,
)

ROAD = RoadSection(lane_widths_m=(3.5, 3.5, 3.5))


def car(vid: str, s_m: float, lane: int, v: float, *, cav: bool = False) -> VehicleState:
    return VehicleState(vid, s_m, lane, 0.0, v, 5.0, is_cav=cav)


def platoon(n: int = 3, lane: int = 1, front_m: float = 200.0, v: float = 20.0) -> PlatoonView:
    cavs = [car(f"c{i}", front_m - 15.0 * i, lane, v, cav=True) for i in range(n)]
    return PlatoonView(front=cavs[0], tail=cavs[-1], n_cavs=n, cavs=tuple(cavs), cruise_mps=30.0,
                       lateral_speed_mps=1.0, lane_width_m=3.5)  # fmt: skip


def weigh(view, target, others, desired=None, **kw):
    desired = desired or {}
    args = dict(
        side_lanes=[0, 2], leaves=False, cells_pace_mps=5.0,
        desired_of=lambda v: desired.get(v.vehicle_id, 30.0), horizon_s=20.0, range_m=90.0,
        others_weight=1.0, min_gain_mps=2.0,
    )  # fmt: skip
    args.update(kw)
    return choose(view, target, others, ROAD, **args)


def test_mean_speed_of_a_vehicle_speeding_up_over_the_horizon():
    # 10 -> 20 m/s at 1 m/s^2: 10 s up (mean 15) then 10 s at 20: mean 17.5
    assert mean_speed_mps(10.0, 20.0, 20.0, 1.0) == pytest.approx(17.5)
    assert mean_speed_mps(10.0, 40.0, 10.0, 1.0) == pytest.approx(15.0)  # still rising
    assert mean_speed_mps(20.0, 10.0, 20.0, 1.0) == 10.0  # braking: at once


def test_a_free_lane_runs_at_the_cap_and_a_line_ahead_holds_it_to_its_slowest_wish():
    others = [car("a", 260.0, 0, 25.0), car("b", 280.0, 0, 25.0)]
    pace = dict(cap_mps=30.0, range_m=90.0, horizon_s=20.0)
    assert lane_pace_mps(200.0, others, ROAD, 2, desired_of=lambda v: 40.0, **pace) == 30.0
    slow = {"a": 40.0, "b": 22.0}  # a wants 40 but b, ahead of it, wants 22 (below a's 25)
    got = lane_pace_mps(200.0, others, ROAD, 0, desired_of=lambda v: slow[v.vehicle_id], **pace)
    assert got == pytest.approx(25.0)  # never below the nearest one's speed now


def test_a_slower_vehicle_beyond_the_range_holds_the_lane_from_when_it_is_reached():
    # Front at 200, range 90, cap 30, horizon 20 s. A car at 24 m/s beyond the range, its
    # rear at 355 - 5 = 350: reached when the platoon is its secure gap (2.5 + 24 = 26.5 m)
    # behind it, after (350 - 200 - 26.5) / (30 - 24) = 20.58 s: beyond the horizon, the lane
    # runs at the cap. At 320 (rear 315): after 88.5 / 6 = 14.75 s, then 5.25 s at 24 m/s:
    # a mean of (30 * 14.75 + 24 * 5.25) / 20 = 28.425 m/s.
    pace = dict(cap_mps=30.0, range_m=90.0, horizon_s=20.0, desired_of=lambda v: 30.0)
    assert lane_pace_mps(200.0, [car("far", 355.0, 0, 24.0)], ROAD, 0, **pace) == 30.0
    near = [car("near", 320.0, 0, 24.0)]
    assert lane_pace_mps(200.0, near, ROAD, 0, **pace) == pytest.approx(28.425)
    # one at 30 m/s or faster, or in another lane, never holds it
    assert lane_pace_mps(200.0, [car("fast", 320.0, 0, 31.0)], ROAD, 0, **pace) == 30.0
    assert lane_pace_mps(200.0, near, ROAD, 1, **pace) == 30.0


def test_insertion_loss_is_what_the_followers_must_drop_back():
    # Platoon spans 170..200 in lane 0; a follower at 180 (20 m/s) must be 2.5 + 20 = 22.5 m
    # behind 170 - it drops back 180 + 22.5 - 170 = 32.5 m; the next, at 100 with 75 m of
    # room behind the first's rear (175 - 100) less its 22.5 m gap, has 52.5 m spare: stops it.
    others = [car("f1", 180.0, 0, 20.0), car("f2", 100.0, 0, 20.0)]
    assert insertion_loss_m(others, ROAD, 0, 200.0, 170.0) == pytest.approx(32.5)
    # a second follower close behind the first takes on what exceeds its spare room
    close = [car("f1", 180.0, 0, 20.0), car("f2", 170.0, 0, 20.0)]
    # f2's room: 175 - 170 - 22.5 < 0: drops back the same 32.5
    assert insertion_loss_m(close, ROAD, 0, 200.0, 170.0) == pytest.approx(65.0)
    assert insertion_loss_m(others, ROAD, 2, 200.0, 170.0) == 0.0  # nobody there


def test_a_free_lane_beside_a_truck_is_passed_in():
    view = platoon()
    truck = car("truck", 215.0, 1, 20.0)
    choice = weigh(view, truck, [truck], desired={"truck": 20.0})
    assert choice.best.kind == "lane_pass" and choice.best.loss_m == 0.0
    # 3 CAVs x (30 - 20) m/s x (20 s - 1.75 s moving over)
    assert choice.best.gain_m == pytest.approx(3 * 10.0 * (20.0 - 1.75))


def test_no_lane_pass_is_weighed_where_one_stalled():
    # The same truck, its lane pass stalled once: the lanes beside stay for the other ways
    # past it (one by one, the cells), never for a lane pass again.
    view = platoon()
    truck = car("truck", 215.0, 1, 20.0)
    choice = weigh(view, truck, [truck], desired={"truck": 20.0}, pass_lanes=[])
    kinds = {o.kind for o in choice.weighed}
    assert "lane_pass" not in kinds and {"cells", "one_by_one"} <= kinds
    assert choice.best.kind == "one_by_one"


def test_a_car_that_will_pass_its_own_leader_is_waited_for():
    view = platoon()
    target = car("t", 215.0, 1, 20.0)
    # it wants 30 m/s, a car at 21 m/s holds it, lane 2 beside it is free: SUMO's speed gain
    # will take it there
    ahead, right = car("x", 250.0, 1, 21.0), car("r", 230.0, 0, 20.0)
    desired = {"t": 30.0, "x": 21.0, "r": 20.0}
    choice = weigh(view, target, [target, ahead, right], desired=desired)
    assert choice.best.kind == "wait"
    assert [o.kind for o in choice.weighed] == ["follow", "wait"]  # nothing else weighed
    # the same car wanting only what its lane ahead gives: it stays, and is weighed for
    desired["t"] = 20.0
    stays = weigh(view, target, [target, ahead, right], desired=desired)
    assert "wait" not in {o.kind for o in stays.weighed}
    # SUMO shows a wish: a truck that keeps right, the lane on its right free
    truck = weigh(view, target, [target, ahead, right], desired=desired, leaves=True)
    assert truck.best.kind == "wait"


def test_when_every_lane_is_as_slow_the_platoon_follows():
    view = platoon()
    target = car("t", 215.0, 1, 20.0)
    side = [car("l", 222.0, 2, 20.0), car("r", 222.0, 0, 20.0)]
    desired = {"t": 20.0, "l": 20.0, "r": 20.0}
    choice = weigh(view, target, [target, *side], desired=desired, cells_pace_mps=None)
    assert choice.best.kind == "follow"


def test_blocking_dense_side_lanes_costs_more_than_it_gains():
    view = platoon(n=2)
    target = car("t", 215.0, 1, 20.0)
    # side lanes: a dense stream at 28 m/s beside and behind the platoon
    side = [car(f"{side}{i}", 210.0 - 20.0 * i, lane, 28.0)
            for lane, side in ((0, "r"), (2, "l")) for i in range(8)]  # fmt: skip
    choice = weigh(view, target, [target, *side], desired={"t": 20.0})
    cells = next(o for o in choice.weighed if o.kind == "cells")
    assert cells.loss_m > cells.gain_m
    assert choice.best.kind != "cells"


def test_no_manoeuvre_below_the_incentive_threshold():
    view = platoon(n=2)
    # 1 m/s below the cruise, held there by a car ahead: gain 2 x 1 x 18.25 = 36.5 m
    target, ahead = car("t", 215.0, 1, 29.0), car("x", 260.0, 1, 29.0)
    choice = weigh(view, target, [target, ahead], desired={"t": 29.0, "x": 29.0})
    lane = max((o for o in choice.weighed if o.kind == "lane_pass"), key=lambda o: o.score_m)
    assert 0.0 < lane.score_m < 2 * 2.0 * 0.5 * 20.0
    assert choice.best.kind == "follow"
    assert math.isclose(choice.weighed[0].score_m, 0.0)


def test_others_weight_trades_their_loss_against_the_cavs_gain():
    # Side lanes of 24 m/s traffic beside and behind the platoon: the cells block them to the
    # grid's 20 m/s while the pass lasts (8 vehicles x 4 m/s x 8 s = 256 m lost), a lane pass
    # waits for them to go by first.
    view = platoon(n=3)
    target = car("t", 215.0, 1, 20.0)
    side = [car(f"{name}{i}", 205.0 - 30.0 * i, lane, 24.0)
            for lane, name in ((0, "r"), (2, "l")) for i in range(4)]  # fmt: skip
    counted = weigh(view, target, [target, *side], desired={"t": 20.0})
    cells = next(o for o in counted.weighed if o.kind == "cells")
    assert cells.loss_m == pytest.approx(8 * 4.0 * 8.0)
    assert counted.best.kind == "cells"  # 480 m gained against 256 m lost
    careful = weigh(view, target, [target, *side], desired={"t": 20.0}, others_weight=2.0)
    assert careful.best.kind == "one_by_one"  # 480 - 2 x 256 < 0


def test_a_short_horizon_sees_no_pass_paying():
    view = platoon()
    truck = car("truck", 215.0, 1, 20.0)
    # moving over takes 1.75 s: within 1.5 s no lane pass gains anything
    short = weigh(view, truck, [truck], desired={"truck": 20.0}, horizon_s=1.5,
                  cells_pace_mps=None)  # fmt: skip
    assert short.best.kind == "follow"
    assert [o.kind for o in short.weighed] == ["follow", "one_by_one"]
    long = weigh(view, truck, [truck], desired={"truck": 20.0}, horizon_s=20.0,
                 cells_pace_mps=None)  # fmt: skip
    assert long.best.kind == "lane_pass"


@pytest.mark.sumo
def test_the_paper_trigger_and_the_weighing_start_the_same_paper_overtake(tmp_path):
    """[swarm] decide = "paper" (the paper's trigger) and the default weighing both start the
    cells on the paper scene at 3.03 s; only the weighing says why (overtake_weighed)."""
    import json

    from sumo_swarm.config import load_scenario
    from sumo_swarm.sim.runner import run_scenario
    from tests.conftest import PAPER

    events = {}
    for decide in ("weigh", "paper"):
        sc = load_scenario(PAPER, overrides={"swarm": {"decide": decide},
                                             "simulation": {"duration_s": 12.0},
                                             "evaluation": {"end_s": 12.0}})  # fmt: skip
        run_scenario(sc, "swarm", tmp_path / decide, progress=False)
        lines = (tmp_path / decide / "events.jsonl").read_text().splitlines()
        events[decide] = [json.loads(line) for line in lines]
    for decide, evs in events.items():
        start = next(e for e in evs if e["event"] == "overtake_start")
        assert (start["kind"], start["time_s"]) == ("cells", pytest.approx(3.03)), decide
    weighed = [e for e in events["weigh"] if e["event"] == "overtake_weighed"]
    assert [e["chosen"] for e in weighed] == ["cells"]
    assert not any(e["event"] == "overtake_weighed" for e in events["paper"])


def test_the_cells_pass_no_faster_than_the_lanes_beside_let_them():
    view = platoon(n=2, v=20.0)  # fronts at 200 and 185: the footprint 180..200
    target = car("t", 215.0, 1, 20.0)
    # Lanes beside with cars ahead at the target's speed: the CAVs cannot get ahead there, the
    # cells are not weighed (timed at the plan's 5 m/s they were a pass of 5 s).
    level = [car("l", 230.0, 2, 20.0), car("r", 230.0, 0, 20.0)]
    desired = {"t": 20.0, "l": 20.0, "r": 20.0}
    choice = weigh(view, target, [target, *level], desired=desired)
    assert "cells" not in [o.kind for o in choice.weighed]
    # At 22 m/s beside (the plan's 25 m/s is more): 2 m/s past the grid over the footprint
    # and the target (25 m) takes 12.5 s after the first move over (1.75 s); then the lane
    # ahead of the target, free (the 30 m/s cap), for the 5.75 s left:
    # gain 2 x (2 x 12.5 + 10 x 5.75) = 165 m; the two cars beside give up 2 m/s each while
    # the pass lasts: 50 m.
    faster = [car("l", 230.0, 2, 22.0), car("r", 230.0, 0, 22.0)]
    desired = {"t": 20.0, "l": 22.0, "r": 22.0}
    choice = weigh(view, target, [target, *faster], desired=desired)
    cells = next(o for o in choice.weighed if o.kind == "cells")
    assert cells.gain_m == pytest.approx(165.0)
    assert cells.loss_m == pytest.approx(50.0)


def _beside_two_cavs_held(other: VehicleState):
    """The weighing, ``apart`` among it, of two CAVs at 15 m/s (fronts at 200 and 185 m, lane
    1) behind a 15 m/s truck (front at 215 m), with ``other`` in lane 2 at its own speed."""
    truck = car("truck", 215.0, 1, 15.0)
    desired = {"truck": 15.0, other.vehicle_id: other.speed_mps}
    return weigh(platoon(n=2, v=15.0), truck, [truck, other], desired=desired, side_lanes=[2],
                 cells_pace_mps=None, apart=True)  # fmt: skip


def test_apart_each_cav_moves_over_where_sumo_lets_it_on_its_own():
    # Two CAVs at 15 m/s behind a 15 m/s truck; a car at 30 m/s in lane 2, 60 m behind the
    # tail: outside the secure room a platoon's guards keep (2.5 + 30 = 32.5 m), inside the
    # secure gap SUMO's lane-change model wants in front of it for a CAV at 15 m/s
    # (2.5 + 30 + (30^2 - 15^2) / 9 = 107.5 m).
    choice = _beside_two_cavs_held(car("f", 120.0, 2, 30.0))
    kinds = {o.kind: o for o in choice.weighed}
    # As a platoon at once, 15 m/s up for 18.25 s each: 547.5 m.
    assert kinds["lane_pass"].gain_m == pytest.approx(547.5)
    # Apart, each waits for the car to pass: c0 (front 200) 87.5 m / 15 m/s, c1 (front 185)
    # 72.5 m / 15 m/s, then 15 m/s up for what is left of the 20 s less 1.75 s of moving
    # over: 186.25 + 201.25 m; less the 7.5 m c1 drops back to a driver's own gap
    # (2.5 + 15 = 17.5 m against the platoon's 10 m).
    assert kinds["apart"].gain_m == pytest.approx(186.25 + 201.25 - 7.5)
    assert "one_by_one" not in kinds  # apart, a CAV passing on its own does not re-form
    assert choice.best.kind == "lane_pass"


def test_apart_is_taken_where_only_some_cavs_can_move_over():
    # A car as slow as the platoon in lane 2, 15 m behind the tail's front: it never passes,
    # so the platoon as a whole cannot move over; the front CAV, 30 m ahead of it, can.
    choice = _beside_two_cavs_held(car("s", 165.0, 2, 15.0))
    kinds = {o.kind: o for o in choice.weighed}
    assert "lane_pass" not in kinds
    # c0 alone: 15 m/s up for 18.25 s, the car behind it keeps its room (no loss); c1 stays
    # behind the truck; c1 drops back 7.5 m.
    assert kinds["apart"].gain_m == pytest.approx(15.0 * 18.25 - 7.5)
    assert kinds["apart"].loss_m == 0.0
    assert choice.best.kind == "apart"


def test_a_held_back_target_merging_from_beside_the_road_does_not_leave_into_the_platoons_lane():
    # A truck still on the ramp (lane -1 of the road), leaning into lane 0 ahead of a platoon
    # there, held back below its desired speed: lane 0 is the lane it merges into, not a
    # faster lane beside it that it will leave for; only lane 1 (no faster) is beside it.
    # Nothing to wait for: the platoon follows (or passes), it does not wait for it to leave.
    from dataclasses import replace

    view = platoon(n=3, lane=0, front_m=200.0, v=20.0)
    truck = replace(car("truck", 240.0, -1, 10.0), lat_m=1.2)
    others = [car("l1", 250.0, 1, 10.5), car("l1b", 215.0, 1, 10.5)]
    choice = weigh(view, truck, others, desired={"truck": 25.0, "l1": 10.5, "l1b": 10.5},
                   side_lanes=[1])  # fmt: skip
    assert "wait" not in {o.kind for o in choice.weighed}
    assert choice.best.kind == "follow"
