"""Holds that make space for no CAV (``[planner] release_idle_holds``): hand-made cases."""

from __future__ import annotations

import dataclasses
import json

import pytest

from sumo_swarm.core.grid import GridSettings, build_grid
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.planner import (
    PlannerSettings,
    build_problem,
    evaluate_objective,
)
from sumo_swarm.core.planner.problem import hold_useful, idle_hold_cells
from sumo_swarm.errors import ConfigError
from tests.test_planner import small_problem, solve_both


def test_a_hold_is_useful_only_for_a_cav_beside_and_far_enough_ahead():
    # An HV centred in row 2.0 of lane 0; CAVs still to pass given as (row, column).
    assert hold_useful(2.0, 0, [(3.1, 1)], 1.0)  # a lane beside, 1.1 rows ahead
    assert not hold_useful(2.0, 0, [(2.9, 1)], 1.0)  # beside, but less than a row ahead
    assert not hold_useful(2.0, 0, [(1.0, 1)], 1.0)  # behind it
    assert not hold_useful(2.0, 0, [(5.0, 0)], 1.0)  # in its own lane: in front of it already
    assert not hold_useful(2.0, 0, [(5.0, 2)], 1.0)  # two lanes away
    assert hold_useful(2.0, 0, [(1.0, 1), (3.5, 1)], 1.0)  # any one will do
    assert not hold_useful(2.0, 0, [(3.5, 1)], 1.5)  # the distance is a setting


def stuck_problem(impeded_row: int, n_steps: int = 6, **kwargs):
    """3 lanes, regroup lane 1, a truck in rows 3-4 of lane 1, lane 2 taken all along, an HV
    centred in row 1.8 of lane 0 (its cells rows 1-2). c0 is past the truck in row 6 of lane
    0; c1 waits behind the truck in ``impeded_row`` of lane 1 and cannot pass: delta is 1 at
    every step."""
    blocked = {(3, 1), (4, 1), (1, 0), (2, 0)} | {(r, 2) for r in range(8)}
    problem = small_problem(8, 3, n_steps, [(6, 0), (impeded_row, 1)], goal_row=5, lane=1,
                            blocked=frozenset(blocked), **kwargs)  # fmt: skip
    return dataclasses.replace(
        problem,
        target_id="truck",
        target_col=1,
        hv_tracks=((1, (3.5,) * n_steps), (0, (1.8,) * n_steps)),
        start_rows=(6.0, float(impeded_row)),
    )


def test_idle_hold_cells_are_the_side_lane_ahead_of_an_hv_no_cav_can_get_in_front_of():
    # c1 in row 2 is level with the HV (0.2 rows ahead): the hold is idle; the cells of lane 0
    # at and past the goal row (5), ahead of the HV (rows > 1.8), charge for it, and so do the
    # first two rows of the regroup lane from the goal row.
    cells = idle_hold_cells(stuck_problem(2), 1.0, 2)
    assert cells[0] == frozenset()
    assert all(step == {(5, 0), (6, 0), (7, 0), (5, 1), (6, 1)} for step in cells[1:])
    assert idle_hold_cells(stuck_problem(2), 1.0, 0)[1] == {(5, 0), (6, 0), (7, 0)}
    # c1 two rows ahead of the HV (row 4, in front of the truck's rows 3-4): the hold is not
    # idle, nothing charges.
    assert idle_hold_cells(stuck_problem(4), 1.0, 2) == ()
    # Nobody to pass: nothing is idle (delta is 0 and everyone pays anyway).
    past = dataclasses.replace(stuck_problem(2), start_cells=((6, 0), (7, 1)),
                               start_rows=(6.0, 7.0))  # fmt: skip
    assert idle_hold_cells(past, 1.0, 2) == ()


def test_a_cav_past_the_target_leaves_the_lane_of_an_hv_it_holds_for_nothing():
    # Paper weights (w_tar 10, w_lon 1, w_lat 1), 8 steps. c1 cannot pass: 10 per step at
    # steps 1-7 = 70. With the paper's delta c0 may sit in lane 0 for free: 70. With the idle
    # hold it pays w_lat = 1 per step there (7), and as much in rows 5-6 of lane 1: it moves
    # one row up (2), then over to (7, 1) (2), paying one step in an idle cell on the way: 75.
    paper = stuck_problem(2, n_steps=8)
    released = dataclasses.replace(paper, idle_holds=idle_hold_cells(paper, 1.0, 2))
    for plan in solve_both(paper):
        assert plan.objective == 70
        assert all(cell == (6, 0) for cell in plan.cells_of("c0"))
    for plan in solve_both(released):
        assert plan.objective == 75
        assert plan.cells_of("c0")[2:] == ((7, 1),) * 6
        assert evaluate_objective(released, plan.cells) == pytest.approx(75)
    # The same plan judged by the paper's objective costs 4 more than staying: the idle cells
    # are what moves it.
    assert evaluate_objective(paper, solve_both(released)[0].cells) == pytest.approx(74)


def veh(vid: str, s_m: float, lane: int, speed: float = 17.5, cav: bool = False) -> VehicleState:
    return VehicleState(vid, float(s_m), lane, 0.0, speed, 5.0, is_cav=cav)


@pytest.mark.parametrize("release", [True, False])
def test_no_cav_is_told_to_hold_an_hv_level_with_the_cav_behind(release):
    # A truck (front 315 m) in lane 1; cav0 is past it in lane 0 (front 350 m); cav1 and cav2
    # follow the truck in lane 1 (fronts 289 and 260 m) with an HV level with cav1 in lane 0
    # (front 290 m). cav0 holding that HV would make space in front of it that neither cav1 nor
    # cav2 can reach.
    road = RoadSection((3.0, 3.0, 3.0))
    cavs = [veh("cav0", 350, 0, cav=True), veh("cav1", 289, 1, cav=True),
            veh("cav2", 260, 1, cav=True)]  # fmt: skip
    target = dataclasses.replace(veh("truck", 315, 1), length_m=10.0)
    hv = veh("hv", 290, 0)
    gs = GridSettings()
    grid = build_grid(cavs, target, road, 0.0, 17.5, gs)
    settings = PlannerSettings(release_idle_holds=release)
    problem = build_problem(grid, cavs, [target, hv], target, 0.0, settings, gs)
    if release:
        assert problem.blockers == ()
        assert problem.idle_holds and any((r, 0) in problem.idle_holds[1] for r in range(14))
    else:
        assert [(b.cav_id, b.hv_id) for b in problem.blockers] == [("cav0", "hv")]
        assert problem.idle_holds == ()
    # The HV 19 m behind cav1 (1.27 rows, between cav1 and cav2): the hold makes space for cav1.
    ahead = dataclasses.replace(hv, s_m=270.0)
    problem = build_problem(grid, cavs, [target, ahead], target, 0.0, settings, gs)
    assert [(b.cav_id, b.hv_id) for b in problem.blockers] == [("cav0", "hv")]
    assert all(not cells for cells in problem.idle_holds)


def test_idle_hold_settings_are_checked():
    with pytest.raises(ConfigError, match="idle_hold_rows"):
        PlannerSettings(idle_hold_rows=-1.0)
    with pytest.raises(ConfigError, match="idle_clear_rows"):
        PlannerSettings(idle_clear_rows=-1)
    assert PlannerSettings(release_idle_holds="stranded").release_idle_holds == "stranded"
    with pytest.raises(ConfigError, match="release_idle_holds"):
        PlannerSettings(release_idle_holds="yes")


# ----------------------------------------------------------------------------- through SUMO

# A paper-scene variant drawn with `tools/make_variants.py --seed 47` (scene 19): 7 CAVs behind
# a 12.56 m/s truck, side lanes wanting 21.5 and 22.4 m/s, 4 HVs per lane upstream 19.5 m
# apart that change lanes. With the paper's delta the CAVs past the truck sat in both side
# lanes at the truck's speed while two upstream HVs came up beside it, level with the three
# CAVs still behind: nobody could move for 18 s and the swarm gave up (cavs_stranded). That
# was the CAVs held by the lateral guard moving on: SUMO carried their last sublane command
# on past the hold (sim/bridge.py, SumoSession.change_sublane, now stops a move under way).
STRANDED = {
    # The cells' idle holds are what is tested: the paper's trigger starts the cells (weighed,
    # one by one passes this truck without blocking anybody, 7 of 7 past at 29.9 s).
    "swarm": {"decide": "paper"},
    "cav": {"count": 7},
    "hv": {"lane_changes": True},
    "simulation": {"duration_s": 150.0},
    "evaluation": {"end_s": 150.0},
    "scene": {
        "leader_front_m": 300.0,
        "initial_speed_mps": 12.56,
        "upstream_gap_m": 19.5,
        "upstream_per_lane": 4,
        "upstream_speed_mps": 12.56,
        "hv": [
            {
                "id": "hv_target",
                "role": "target",
                "lane": 1,
                "front_m": 321.6,
                "speed_mps": 12.56,
                "desired_speed_mps": 12.56,
                "length_m": 11.6,
            },
            {
                "id": "hv_left",
                "role": "adjacent",
                "lane": 2,
                "front_m": 255.0,
                "speed_mps": 17.5,
                "desired_speed_mps": 21.51,
            },
            {
                "id": "hv_right",
                "role": "adjacent",
                "lane": 0,
                "front_m": 240.0,
                "speed_mps": 17.5,
                "desired_speed_mps": 22.35,
            },
        ],
    },
}


@pytest.mark.parametrize("release", [False, "stranded"])
def test_held_cavs_stop_so_the_paper_holds_strand_the_platoon_no_more(tmp_path, release):
    import copy
    from pathlib import Path

    from sumo_swarm.config import load_scenario
    from sumo_swarm.sim.runner import run_scenario

    paper = Path(__file__).resolve().parent.parent / "scenarios" / "paper.toml"
    overrides = copy.deepcopy(STRANDED)
    overrides["planner"] = {"release_idle_holds": release}
    swarm = run_scenario(load_scenario(paper, overrides=overrides), "swarm", tmp_path / "swarm",
                         seed=42, progress=False)  # fmt: skip
    cacc = run_scenario(load_scenario(paper, overrides=copy.deepcopy(STRANDED)), "cacc",
                        tmp_path / "cacc", seed=42, progress=False)  # fmt: skip
    events = [json.loads(line) for line in (tmp_path / "swarm" / "events.jsonl").open()]
    # Before the fix, with the paper's holds (release False): stranded, CAV speed 16.5 m/s
    # against cacc's 17.4.
    assert not any(e.get("reason") == "cavs_stranded" for e in events)
    assert swarm["cav"]["mean_speed_mps"] > cacc["cav"]["mean_speed_mps"]  # before: below
    assert swarm["safety"]["collisions"] == 0 and swarm["safety"]["hard_brakes"] == 0
    assert swarm["cav"]["gap_min_cav_m"] >= 5.0
