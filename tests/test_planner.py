"""Cell planner: hand-solved grids, brute force, the paper's Figure 7 scene, validator, triggers."""

from __future__ import annotations

import dataclasses
import itertools
import random

import pytest

from sumo_swarm.core.grid import GridSettings, build_grid
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.planner import (
    Blocker,
    CpSatPlanner,
    Plan,
    PlannerSettings,
    PlannerWeights,
    PlanningProblem,
    PlanStatus,
    ReplanTrigger,
    ScipPlanner,
    build_problem,
    evaluate_objective,
    make_planner,
    shift_plan,
    solved_problem,
    validate_plan,
)
from sumo_swarm.core.planner.flow import build_flow_model, extract_paths, uncross_swaps
from sumo_swarm.errors import ConfigError
from sumo_swarm.study.reproduce import PROOF_WORK

W = PlannerWeights(w_tar=10, w_lon=1, w_lat=1)  # integer weights: objectives compare exactly


def small_problem(
    n_rows: int,
    n_cols: int,
    n_steps: int,
    starts: list[tuple[int, int]],
    goal_row: int,
    lane: int = 0,
    blocked: frozenset = frozenset(),
    **kwargs,
) -> PlanningProblem:
    options = {"weights": W, "target_form": "paper", **kwargs}
    return PlanningProblem(
        n_rows=n_rows,
        n_cols=n_cols,
        n_steps=n_steps,
        cav_ids=tuple(f"c{i}" for i in range(len(starts))),
        start_cells=tuple(starts),
        blocked=(frozenset(),) + (frozenset(blocked),) * (n_steps - 1),
        goal_rows=(goal_row,) * n_steps,
        regroup_lane=lane,
        **options,
    )


def plan_of(problem: PlanningProblem, cells, blockers=None) -> Plan:
    return Plan(
        status=PlanStatus.OPTIMAL,
        cells=tuple(tuple(path) for path in cells),
        objective=None,
        solve_ms=0.0,
        backend="hand",
        blockers=blockers if blockers is not None else {},
        cav_ids=problem.cav_ids,
    )


def solve_both(problem: PlanningProblem) -> tuple[Plan, Plan]:
    plans = CpSatPlanner(10.0).plan(problem), ScipPlanner(10.0).plan(problem)
    for plan in plans:
        assert plan.status is PlanStatus.OPTIMAL, plan.message
        assert validate_plan(problem, plan) == []
        assert evaluate_objective(problem, plan.cells) == pytest.approx(plan.objective)
    return plans


# ----------------------------------------------------------------------------- hand-solved


def test_one_cav_2x2_moves_up():
    # Start (0,0), goal region = row 1, 3 steps. Best: up at step 1 (2 * w_lon = 2), stay.
    # Staying costs w_tar = 10 per step below the goal.
    problem = small_problem(2, 2, 3, [(0, 0)], goal_row=1)
    for plan in solve_both(problem):
        assert plan.objective == 2
        assert plan.cells == (((0, 0), (1, 0), (1, 0)),)


def test_one_cav_2x2_lateral_move_is_free_once_past():
    # Regroup lane 1. Up (2), then right at step 1 -> 2: delta_1 = 0 (nobody impeded) so the
    # move is free, but at step 1 it pays the regroup cost w_lat * 1^2 = 1. Total 3. Moving
    # right first costs 2 * w_lat (delta_0 = 1) + 10 (still behind at step 1): worse.
    problem = small_problem(2, 2, 3, [(0, 0)], goal_row=1, lane=1)
    for plan in solve_both(problem):
        assert plan.objective == 3
        assert plan.cells == (((0, 0), (1, 0), (1, 1)),)


def test_two_cavs_3x2_leader_steps_aside():
    # c0 at (1,0), c1 at (0,0), goal = row 2, lane 0, 3 steps. Best: c0 up (2) then right (2,
    # delta_1 = 1 as c1 is still behind); c1 up twice (4); c1 pays 10 at step 1; at step 2 all
    # are past, c0 pays the regroup cost 1. Total 2 + 2 + 4 + 10 + 1 = 19. Leaving c1 behind:
    # 2 + 2 + 10 + 10 = 24.
    problem = small_problem(3, 2, 3, [(1, 0), (0, 0)], goal_row=2)
    for plan in solve_both(problem):
        assert plan.objective == 19
        assert plan.cells == (
            ((1, 0), (2, 0), (2, 1)),
            ((0, 0), (1, 0), (2, 0)),
        )


def test_distance_form_and_per_cav_delta():
    # Distance form: a CAV two rows behind pays 2 * w_tar. 1 CAV at (0,0), goal row 2, 3 steps:
    # up, up: moves 4, target at step 1 = 10 -> 14.
    problem = small_problem(3, 1, 3, [(0, 0)], goal_row=2, target_form="distance")
    for plan in solve_both(problem):
        assert plan.objective == 14
    # Delta: c0 is past (row 2) but off the regroup lane 0, c1 is behind at (0,0); 2 steps.
    # c1 stays (paper form: 10 whether 1 or 2 rows behind; moving up adds 2). Swarm delta: c1
    # is impeded, so c0's lateral move would cost 2 and its regroup cost is waived: c0 stays.
    # Per-CAV delta: c0 is past, its move is free and saves the regroup cost 1: c0 moves.
    # Both total 10.
    swarm = small_problem(3, 2, 2, [(2, 1), (0, 0)], goal_row=2)
    per_cav = dataclasses.replace(swarm, delta_mode="cav")
    for plan in solve_both(swarm):
        assert plan.objective == 10
        assert plan.cells == (((2, 1), (2, 1)), ((0, 0), (0, 0)))
    for plan in solve_both(per_cav):
        assert plan.objective == 10
        assert plan.cells == (((2, 1), (2, 0)), ((0, 0), (0, 0)))


def test_hv_blocked_cells_force_a_detour():
    # 1 CAV at (0,0), HV claims (1,0) from step 1 on; goal row 2, 4 steps, lane 0.
    # Path (0,0) -> (0,1) -> (1,1) -> (2,1): lat 2 + lon 2 + lon 2; target 10 + 10 at steps 1, 2;
    # at step 3 past, off lane: regroup 1. Total 27. (Waiting is worse: 10 per step.)
    problem = small_problem(3, 2, 4, [(0, 0)], goal_row=2, blocked=frozenset({(1, 0)}))
    for plan in solve_both(problem):
        assert plan.objective == 27
        assert (1, 0) not in plan.cells[0][1:]


def test_swap_is_forbidden():
    # Costs never reward a swap (both cells stay occupied), but a blocker names its CAV: c0
    # must take c1's cell at step 1. In a 1x2 grid c1 could only leave by swapping: infeasible.
    # In a 2x2 grid c1 steps up instead.
    blocker = Blocker(0, "c0", "h", (0, 1))
    narrow = small_problem(1, 2, 2, [(0, 0), (0, 1)], goal_row=0, blockers=(blocker,))
    for planner in (CpSatPlanner(1.0, retry_without_blockers=False), ScipPlanner(1.0, False)):
        assert planner.plan(narrow).status is PlanStatus.INFEASIBLE
    wide = small_problem(2, 2, 2, [(0, 0), (0, 1)], goal_row=0, blockers=(blocker,))
    for plan in solve_both(wide):
        assert plan.cells == (((0, 0), (0, 1)), ((0, 1), (1, 1)))


def test_infeasible_grids():
    # The only cell is claimed from step 1 on.
    problem = small_problem(1, 1, 3, [(0, 0)], goal_row=1, blocked=frozenset({(0, 0)}))
    for planner in (CpSatPlanner(1.0), ScipPlanner(1.0)):
        plan = planner.plan(problem)
        assert plan.status is PlanStatus.INFEASIBLE
        assert plan.cells is None
    # Two CAVs start in the same cell of a 1x1 grid: they cannot separate at step 1.
    problem = small_problem(1, 1, 2, [(0, 0), (0, 0)], goal_row=0)
    assert CpSatPlanner(1.0).plan(problem).status is PlanStatus.INFEASIBLE


def test_shared_start_cell_splits():
    # Two CAVs whose centres fall in one cell at step 0 must separate at step 1.
    problem = small_problem(3, 1, 3, [(0, 0), (0, 0)], goal_row=1)
    for plan in solve_both(problem):
        assert {plan.cells[0][1], plan.cells[1][1]} == {(0, 0), (1, 0)}


def test_blockers_are_enforced_or_dropped():
    blocker = Blocker(0, "c0", "h", (1, 1), hold_steps=2)
    problem = small_problem(3, 2, 4, [(1, 0), (0, 0)], goal_row=2, blockers=(blocker,))
    for plan in solve_both(problem):
        assert plan.cells[0][1:3] == ((1, 1), (1, 1))
        assert plan.blockers == {"c0": "h"}
    # A blocker whose cell is claimed by an HV: infeasible, then planned without blockers.
    blocked = small_problem(
        3, 2, 4, [(1, 0), (0, 0)], goal_row=2, blocked={(1, 1)}, blockers=(blocker,)
    )
    assert CpSatPlanner(1.0, retry_without_blockers=False).plan(blocked).status is (
        PlanStatus.INFEASIBLE
    )
    plan = CpSatPlanner(1.0).plan(blocked)
    assert plan.ok and plan.blockers == {} and "blockers dropped" in plan.message
    # Such a plan is valid for the problem it solves (no blockers), not for the one asked.
    assert plan.blockers_dropped
    assert validate_plan(blocked, plan)  # the blocker is not in its cell
    assert solved_problem(blocked, plan).blockers == ()
    assert validate_plan(solved_problem(blocked, plan), plan) == []
    kept = CpSatPlanner(1.0).plan(problem)
    assert not kept.blockers_dropped and solved_problem(problem, kept) is problem


def test_closing_the_lane_a_target_may_keep_right_into_sends_the_plan_left():
    # [swarm] keep_right_middle = "left": a truck in the middle lane that keeps right may move
    # into lane 0; its cells beside and behind the truck are closed, so the CAVs pass on the
    # left. Grid: 8 rows of 15 m from s = 0; the truck's front at 62 m is in row 4, so rows 0-5
    # of column 0 are closed and rows 6-7 (well ahead of it) stay open.
    from sumo_swarm.core.grid import MovingGrid
    from sumo_swarm.core.model import RoadSection, VehicleState
    from sumo_swarm.core.swarming.manoeuvre import close_beside

    grid = MovingGrid(0.0, 0.0, 15.0, 15.0, 8, RoadSection((3.2, 3.2, 3.2)))
    truck = VehicleState("t", 62.0, 1, 0.0, 15.0, 10.0)
    truck_cells = frozenset({(3, 1), (4, 1)})  # its footprint, rear at 52 m
    hv_left = truck_cells | {(r, 2) for r in range(8)}  # and the left lane taken all along
    open_left = small_problem(8, 3, 6, [(2, 1), (1, 1)], goal_row=5, lane=1, blocked=truck_cells)
    closed = close_beside(open_left, grid, truck, 0.0, 0)
    assert closed.blocked[0] == open_left.blocked[0]  # step 0 is not enforced
    assert all(b - open_left.blocked[k + 1] == {(r, 0) for r in range(6)}
               for k, b in enumerate(closed.blocked[1:]))  # fmt: skip
    for plan in solve_both(closed):
        assert all(cell[1] != 0 or cell[0] > 5 for path in plan.cells for cell in path[1:])
        assert any(cell[1] == 2 for path in plan.cells for cell in path)  # passed on the left
    # With the left lane taken too the CAVs wait behind the truck (open, the right lane was
    # used to pass it).
    right_only = small_problem(8, 3, 6, [(2, 1), (1, 1)], goal_row=5, lane=1, blocked=hv_left)
    assert any(cell[1] == 0 for path in solve_both(right_only)[0].cells for cell in path)
    for plan in solve_both(close_beside(right_only, grid, truck, 0.0, 0)):
        assert all(cell[1] == 1 for path in plan.cells for cell in path)
    # A CAV already in that lane keeps it open; a column off the grid closes nothing.
    in_right = small_problem(8, 3, 6, [(2, 0), (1, 1)], goal_row=5, lane=1, blocked=truck_cells)
    assert close_beside(in_right, grid, truck, 0.0, 0) is in_right
    assert close_beside(open_left, grid, truck, 0.0, 3) is open_left


def test_a_car_following_the_target_inside_its_margin_may_follow_on():
    # One lane; a 10 m truck (front 300 m) at 15 m/s and three CAVs 12 m apart behind it, the
    # first 6 m behind its rear. Row 0 is centred on the tail CAV (origin 250 m), so the first
    # CAV's cell, row 2 (centre 287.5 m), lies inside the truck's 5 m margin (from 285 m) while
    # the CAV itself (centre 281.5 m) is 6 m behind the truck. Keeping the grid's speed it
    # stays 6 m behind, so it may keep its cell for the whole horizon (stay_on). Without that
    # it would have to fall back at step 2 into the row of the CAV behind it, which has no
    # row to fall back into: no plan.
    from sumo_swarm.core.planner.problem import stay_exempt

    road = RoadSection((3.2,))
    truck = VehicleState("truck", 300.0, 0, 0.0, 15.0, 10.0)

    def problem_at(speed):
        cavs = [VehicleState(f"c{i}", 284.0 - 12 * i, 0, 0.0, speed, 5.0, is_cav=True)
                for i in range(3)]  # fmt: skip
        grid = build_grid(cavs, truck, road, 0.0, speed, GridSettings())
        assert grid.origin_s_m == 250.0
        return build_problem(grid, cavs, [], truck, 0.0, PlannerSettings(n_steps=5),
                             GridSettings())  # fmt: skip

    problem = problem_at(15.0)
    assert problem.start_cells == ((2, 0), (1, 0), (0, 0))
    assert all((2, 0) in cells for cells in problem.blocked)  # claimed at every step
    assert [set(cells) for cells in problem.stay_on] == [set(), {(2, 0)}, {(2, 0)}, {(2, 0)}]
    for plan in solve_both(problem):
        assert plan.cells == tuple(((r, 0),) * 5 for r in (2, 1, 0))  # all follow on
    # Only where the cell stays claimed since the start: free at a step, the usual rules.
    assert stay_exempt(problem, 2, (2, 0))
    assert not stay_exempt(dataclasses.replace(problem, blocked=problem.blocked[:2]
                                               + (frozenset(),) * 3), 2, (2, 0))  # fmt: skip
    without = dataclasses.replace(problem, stay_on=())
    assert validate_plan(without, solve_both(problem)[0]) == [
        f"CAV c0 step {k}: (2, 0) is claimed by an HV" for k in (2, 3, 4)
    ]
    for planner in (CpSatPlanner(10.0), ScipPlanner(10.0)):
        assert planner.plan(without).status is PlanStatus.INFEASIBLE
    # On a grid 0.3 m/s faster than the truck the CAV keeping the grid's speed comes within
    # 5 m of it after 6 s (4.2 m): it may keep its cell for step 1 only, and no plan exists
    # (the swarm then plans again at the target's speed, Replanner.replan).
    faster = problem_at(15.3)
    assert (2, 0) in faster.stay_ok and faster.stay_on == ()
    assert CpSatPlanner(10.0).plan(faster).status is PlanStatus.INFEASIBLE


def test_following_on_never_drives_through_an_hv_or_beside_one_leaning_in():
    # What stay_on must not allow (review of c830095). (a) A CAV 25 m/s fast on a 25 m/s grid,
    # 40 m behind a 14 m/s truck in its lane: at 3 s it is 7 m behind the truck's rear, at 6 s
    # 11 m ahead of its front, clear at both but driven through it; it may keep its cell for
    # step 1 only. (b) An HV beside the first CAV of a queue, leaning 1 m into its lane, claims
    # the CAV's cell: the CAV may not keep it beside that HV.
    road = RoadSection((3.2, 3.2))
    truck = VehicleState("truck", 300.0, 0, 0.0, 14.0, 10.0)
    cavs = [VehicleState("c0", 250.0, 0, 0.0, 25.0, 5.0, is_cav=True),
            VehicleState("c1", 238.0, 1, 0.0, 25.0, 5.0, is_cav=True)]  # fmt: skip
    grid = build_grid(cavs, truck, road, 0.0, 25.0, GridSettings())
    fast = build_problem(grid, cavs, [], truck, 0.0, PlannerSettings(n_steps=5), GridSettings())
    assert (1, 0) in fast.stay_ok and fast.stay_on == ()
    for plan in solve_both(fast):
        assert plan.cells[0][2] != (1, 0)  # gone from the truck's lane by step 2
    far = VehicleState("truck", 400.0, 1, 0.0, 15.0, 10.0)
    queue = [VehicleState(f"c{i}", 284.0 - 12 * i, 0, 0.0, 15.0, 5.0, is_cav=True)
             for i in range(3)]  # fmt: skip
    leaning = VehicleState("hv", 286.0, 1, -1.0, 15.0, 5.0)
    grid = build_grid(queue, far, road, 0.0, 15.0, GridSettings())
    beside = build_problem(grid, queue, [leaning], far, 0.0, PlannerSettings(n_steps=5),
                           GridSettings())  # fmt: skip
    assert all((2, 0) in cells for cells in beside.blocked)
    assert (2, 0) not in beside.stay_ok and beside.stay_on == ()


# ----------------------------------------------------------------------------- brute force


def brute_force(problem: PlanningProblem) -> float | None:
    moves = ((0, 0), (1, 0), (-1, 0), (0, 1), (0, -1))
    paths_per_cav = []
    for start in problem.start_cells:
        paths = []
        for seq in itertools.product(moves, repeat=problem.n_steps - 1):
            path = [start]
            for dr, dc in seq:
                r, c = path[-1]
                path.append((r + dr, c + dc))
            inside = all(0 <= r < problem.n_rows and 0 <= c < problem.n_cols for r, c in path)
            if inside and not any(cell in problem.blocked[k] for k, cell in enumerate(path) if k):
                paths.append(tuple(path))
        paths_per_cav.append(paths)
    best = None
    for combo in itertools.product(*paths_per_cav):
        plan = plan_of(problem, combo, {b.cav_id: b.hv_id for b in problem.blockers})
        if validate_plan(problem, plan):
            continue
        value = evaluate_objective(problem, combo)
        best = value if best is None or value < best else best
    return best


def random_small_problem(
    rng: random.Random, *, max_w_regroup: int = 4, delta_modes: tuple[str, ...] = ("swarm", "cav")
) -> PlanningProblem:
    """A random grid of 2-4 rows x 1-3 lanes, 3-4 steps, 1-2 CAVs and up to 2 blocked cells,
    small enough for :func:`brute_force`."""
    n_rows, n_cols = rng.randint(2, 4), rng.randint(1, 3)
    n_steps = rng.randint(3, 4)
    n_cavs = rng.randint(1, 2)
    cells = [(r, c) for r in range(n_rows) for c in range(n_cols)]
    starts = rng.sample(cells, n_cavs)
    free = [cell for cell in cells if cell not in starts]
    blocked = frozenset(rng.sample(free, rng.randint(0, min(2, len(free)))))
    return small_problem(
        n_rows, n_cols, n_steps, starts,
        goal_row=rng.randint(1, n_rows - 1) if n_rows > 1 else 0,
        lane=rng.randrange(n_cols), blocked=blocked,
        weights=PlannerWeights(
            rng.randint(1, 12), rng.randint(0, 3), rng.randint(0, max_w_regroup)
        ),
        target_form=rng.choice(["paper", "distance"]),
        delta_mode=rng.choice(delta_modes),
    )  # fmt: skip


@pytest.mark.parametrize("seed", range(12))
def test_random_small_grids_match_brute_force_and_backends_agree(seed):
    problem = random_small_problem(random.Random(seed))
    expected = brute_force(problem)
    plans = [CpSatPlanner(10.0).plan(problem), ScipPlanner(10.0).plan(problem)]
    for plan in plans:
        if expected is None:
            assert plan.status is PlanStatus.INFEASIBLE
        else:
            assert plan.status is PlanStatus.OPTIMAL, plan.message
            assert validate_plan(problem, plan) == []
            assert plan.objective == pytest.approx(expected)


# ----------------------------------------------------------------------------- Figure 7


def veh(vid: str, s_m: float, lane: int) -> VehicleState:
    return VehicleState(vid, float(s_m), lane, 0.0, 17.5, 5.0)


def fig7_problem(settings: PlannerSettings | None = None) -> PlanningProblem:
    road = RoadSection((3.0, 3.0, 3.0))
    cavs = [dataclasses.replace(veh(f"cav{i}", 300 - 15 * i, 1), is_cav=True) for i in range(6)]
    target = veh("target", 315, 1)
    hvs = [target, veh("left", 255, 2), veh("right", 240, 0)]
    hvs += [veh(f"up1_{s}", s, 1) for s in (195, 165, 135)]
    hvs += [veh(f"up2_{s}", s, 2) for s in (225, 195)]
    hvs += [veh(f"up0_{s}", s, 0) for s in (210, 180)]
    grid_settings = GridSettings()
    grid = build_grid(cavs, target, road, 0.0, 17.5, grid_settings)
    settings = settings or PlannerSettings(block_steps=1)  # the paper's blockers hold one step
    return build_problem(grid, cavs, hvs, target, 0.0, settings, grid_settings)


def test_hvs_out_of_the_grids_reach_are_left_out_of_the_margins_not_of_the_problem():
    # The Fig. 7 scene on a long road: HVs 2 km ahead and behind claim no cell with any
    # margin up to the bound, so theirs are never asked for; one 300 m behind at 35 m/s
    # reaches the grid within the horizon and still claims cells. The problem is the same.
    road = RoadSection((3.0, 3.0, 3.0))
    cavs = [dataclasses.replace(veh(f"cav{i}", 2300 - 15 * i, 1), is_cav=True) for i in range(6)]
    target = veh("target", 2315, 1)
    closing = dataclasses.replace(veh("closing", 1900, 2), speed_mps=35.0)
    hvs = [target, veh("left", 2255, 2), veh("right", 2240, 0), veh("far_ahead", 4300, 0),
           veh("far_behind", 300, 2), closing]  # fmt: skip
    asked: list[str] = []

    def margin(hv: VehicleState) -> tuple[float, float]:
        asked.append(hv.vehicle_id)
        return 2.5, 2.5 + 2.0 * hv.speed_mps  # at most 72.5 m here

    gs = GridSettings()
    grid = build_grid(cavs, target, road, 0.0, 17.5, gs)
    settings = PlannerSettings(block_steps=1)
    every = build_problem(grid, cavs, hvs, target, 0.0, settings, gs, front_margin=margin)
    assert {"far_ahead", "far_behind"} <= set(asked)
    asked.clear()
    near = build_problem(grid, cavs, hvs, target, 0.0, settings, gs, front_margin=margin,
                         margin_bound_m=72.5)  # fmt: skip
    assert "far_ahead" not in asked and "far_behind" not in asked and "closing" in asked
    for name in ("blocked", "entry_blocked", "goal_rows", "hv_tracks", "hv_ids", "stay_ok",
                 "stay_on", "blockers", "exempt_moves"):  # fmt: skip
        assert getattr(near, name) == getattr(every, name), name
    # ...and the closing HV's cells are in it (without it, fewer are claimed).
    without = build_problem(grid, cavs, [h for h in hvs if h is not closing], target, 0.0,
                            settings, gs, front_margin=margin, margin_bound_m=72.5)  # fmt: skip
    assert without.blocked != near.blocked


def test_fig7_problem_data():
    problem = fig7_problem()
    assert problem.n_rows == 14 and problem.n_cols == 3 and problem.n_steps == 14
    assert problem.start_cells == ((5, 1), (4, 1), (3, 1), (2, 1), (1, 1), (0, 1))
    assert problem.goal_rows == (8,) * 14
    assert problem.regroup_lane == 1
    # Hand-computed footprints (see test_grid): target rows 6-7 lane 1; left HV rows 2-3 and
    # upstream HV (front 225) rows 0-1 in lane 2; right HV rows 1-2 and upstream HV (front 210)
    # row 0 in lane 0. The lane 1 upstream HVs are behind the grid.
    expected = {(6, 1), (7, 1), (0, 2), (1, 2), (2, 2), (3, 2), (0, 0), (1, 0), (2, 0)}
    assert all(step == expected for step in problem.blocked)
    # hv_ids: the HVs whose centre is in a grid row now (up0_210's centre is behind row 0; its
    # margin still claims row 0 above), the target always.
    assert problem.hv_ids == ("left", "right", "target", "up2_225")
    # Leader blocks the left HV (the frontmost), the second CAV the right HV.
    assert [(b.cav_id, b.hv_id, b.cell) for b in problem.blockers] == [
        ("cav0", "left", (5, 2)),
        ("cav1", "right", (4, 0)),
    ]


@pytest.mark.parametrize("backend", ["cp-sat", "scip"])
def test_fig7_swarm_overtakes_blocks_and_regroups(backend):
    problem = fig7_problem()
    # The proof budget of `sumo-swarm reproduce` (28000 would do): the default (20000) finds
    # the same plan in the same time but leaves it 4 units above its bound (checked below).
    settings = PlannerSettings(backend=backend, time_limit_s=30.0, network_work=PROOF_WORK)
    plan = make_planner(settings).plan(problem)
    assert plan.status is PlanStatus.OPTIMAL, plan.message
    assert validate_plan(problem, plan) == []
    assert plan.blockers == {"cav0": "left", "cav1": "right"}
    assert plan.cells_of("cav0")[1] == (5, 2) and plan.cells_of("cav1")[1] == (4, 0)
    columns_used = {col for path in plan.cells for _, col in path}
    assert columns_used == {0, 1, 2}
    # Every CAV passes the target (rows 6-7) within the horizon and ends regrouped in lane 1.
    final = sorted(path[-1] for path in plan.cells)
    assert final == [(row, 1) for row in range(8, 14)]
    assert evaluate_objective(problem, plan.cells) == pytest.approx(plan.objective)
    default = make_planner(PlannerSettings(backend=backend, time_limit_s=30.0)).plan(problem)
    assert default.status in (PlanStatus.OPTIMAL, PlanStatus.FEASIBLE)
    assert default.objective == plan.objective and default.best_bound <= plan.objective


def test_fig7_both_backends_same_objective_and_paper_form_reachable():
    for settings in (PlannerSettings(), PlannerSettings(target_form="paper", delta_mode="cav")):
        problem = fig7_problem(settings)
        cp, scip = solve_both(problem)
        assert cp.objective == scip.objective


# ----------------------------------------------------------------------------- robustness


def test_too_short_time_limit_never_raises():
    problem = fig7_problem()
    for planner in (CpSatPlanner(1e-4), ScipPlanner(1e-4), CpSatPlanner(0.02)):
        plan = planner.plan(problem)
        assert plan.status in (PlanStatus.TIMEOUT, PlanStatus.FEASIBLE, PlanStatus.OPTIMAL)
        if plan.cells is not None:
            assert validate_plan(problem, plan) == []
        else:
            assert plan.status is PlanStatus.TIMEOUT


def test_solver_exception_becomes_error_plan(monkeypatch):
    import sumo_swarm.core.planner.solvers as solvers

    def boom(problem):
        raise RuntimeError("boom")

    monkeypatch.setattr(solvers, "build_flow_model", boom)
    plan = CpSatPlanner(1.0).plan(small_problem(2, 1, 2, [(0, 0)], goal_row=1))
    assert plan.status is PlanStatus.ERROR and plan.cells is None and "boom" in plan.message


def test_hint_from_shifted_plan_is_accepted():
    problem = fig7_problem()
    first = CpSatPlanner(30.0).plan(problem)
    hint = shift_plan(first, 0)
    again = CpSatPlanner(30.0).plan(problem, hint=hint)
    assert again.status is PlanStatus.OPTIMAL and again.objective == first.objective


def hand_problems() -> list[PlanningProblem]:
    """Hand-made problems with known optima (see the hand-solved tests above)."""
    blocker = Blocker(0, "c0", "h", (1, 1), hold_steps=2)
    return [
        small_problem(2, 2, 3, [(0, 0)], goal_row=1, lane=1),  # optimum 3
        small_problem(3, 2, 3, [(1, 0), (0, 0)], goal_row=2),  # optimum 19
        small_problem(3, 2, 4, [(0, 0)], goal_row=2, blocked=frozenset({(1, 0)})),  # 27
        small_problem(3, 2, 4, [(1, 0), (0, 0)], goal_row=2, blockers=(blocker,)),
        small_problem(3, 2, 2, [(2, 1), (0, 0)], goal_row=2),  # optimum 10
    ]


@pytest.mark.parametrize("planner_type", [CpSatPlanner, ScipPlanner])
def test_hinted_solves_return_the_same_optimum(planner_type):
    # Hints: the optimal plan itself, a worse feasible plan (everyone stays), a plan through
    # an HV-claimed cell (infeasible) and one with a CAV too few. None may change the optimum.
    for problem in hand_problems():
        plain = planner_type(10.0).plan(problem)
        assert plain.status is PlanStatus.OPTIMAL
        stay = tuple((cell,) * problem.n_steps for cell in problem.start_cells)
        bad_cell = next(iter(problem.blocked[1]), problem.start_cells[0])
        through_hv = tuple(
            (cell, bad_cell, *(cell,) * (problem.n_steps - 2)) for cell in problem.start_cells
        )
        hints = [plain, plan_of(problem, stay), plan_of(problem, through_hv)]
        hints.append(dataclasses.replace(plain, cells=plain.cells[:1]))
        for hint in hints:
            hinted = planner_type(10.0).plan(problem, hint=hint)
            assert hinted.status is PlanStatus.OPTIMAL, hinted.message
            assert hinted.objective == pytest.approx(plain.objective)
            assert validate_plan(problem, hinted) == []


def test_hint_shifted_into_a_new_grid_matches_a_fresh_solve():
    # Replanning one step later in a grid whose origin moved one row: the old plan, shifted by
    # a step and a row, is a valid warm start and the optimum does not change.
    problem = small_problem(4, 2, 4, [(1, 0), (0, 0)], goal_row=3)
    first = CpSatPlanner(10.0).plan(problem)
    moved = [path[1] for path in first.cells]
    later = small_problem(4, 2, 4, [(r - 1, c) for r, c in moved], goal_row=2)
    hint = shift_plan(first, 1, row_offset=1)
    assert [path[0] for path in hint.cells] == list(later.start_cells)
    fresh = CpSatPlanner(10.0).plan(later)
    hinted = CpSatPlanner(10.0).plan(later, hint=hint)
    assert hinted.status is fresh.status is PlanStatus.OPTIMAL
    assert hinted.objective == fresh.objective


def test_reused_planner_gives_the_plan_of_a_fresh_one():
    # One planner keeps its CP-SAT model object and replaces its content every call: solving
    # other problems in between must not leave anything behind.
    reused = CpSatPlanner(10.0)
    problems = hand_problems()
    first = [reused.plan(problem) for problem in problems]
    again = [reused.plan(problem) for problem in reversed(problems)][::-1]
    for problem, a, b in zip(problems, first, again, strict=True):
        fresh = CpSatPlanner(10.0).plan(problem)
        assert a.cells == b.cells == fresh.cells
        assert a.objective == b.objective == fresh.objective


def test_swaps_are_uncrossed_at_no_cost():
    # Two CAVs past the target side by side, per-CAV delta: lateral moves are free and the
    # regroup costs of (0,0)+(0,1) are the same either way, so a swap is as cheap as staying.
    problem = small_problem(1, 2, 2, [(0, 0), (0, 1)], goal_row=0, delta_mode="cav")
    model = build_flow_model(problem)
    swap = [0] * model.n_edges
    for src, dst in (((0, 0), (0, 1)), ((0, 1), (0, 0))):
        swap[model.edge_between(0, src, dst)] = 1
    values, swaps = uncross_swaps(model, swap)
    assert swaps == 1
    stays = {model.edge_between(0, c, c) for c in problem.start_cells}
    assert {e for e, v in enumerate(values) if v} == stays
    cells = extract_paths(model, values)
    assert cells == (((0, 0), (0, 0)), ((0, 1), (0, 1)))
    assert evaluate_objective(problem, cells) <= evaluate_objective(
        problem, (((0, 0), (0, 1)), ((0, 1), (0, 0)))
    )
    # Whatever optimum a backend returns, the plan never swaps.
    for plan in solve_both(problem):
        assert validate_plan(problem, plan) == []


# ----------------------------------------------------------------------------- settings


def test_settings_validation():
    for kwargs, name in [
        ({"n_steps": 1}, "n_steps"),
        ({"behaving_interval_s": 0.0}, "behaving_interval_s"),
        ({"backend": "gurobi"}, "backend"),
        ({"time_limit_s": -1.0}, "time_limit_s"),
        ({"weights": {"w_tar": 1, "w_up": 2}}, "weights"),
        ({"weights": {"w_tar": -1}}, "w_tar"),
        ({"regroup_lane": -1}, "regroup_lane"),
        ({"target_form": "sum"}, "target_form"),
        ({"delta_mode": "any"}, "delta_mode"),
        ({"block_steps": 14}, "block_steps"),
    ]:
        with pytest.raises(ConfigError, match=name):
            PlannerSettings(**kwargs)
    assert PlannerSettings(weights={"w_tar": 5}).weights == PlannerWeights(5, 1, 3)


# ----------------------------------------------------------------------------- validator


def test_validator_rejects_each_broken_constraint():
    blocker = Blocker(0, "c0", "h", (1, 1))
    problem = small_problem(
        4, 3, 3, [(1, 0), (0, 0)], goal_row=2, blocked={(3, 2)}, blockers=(blocker,)
    )
    good = [[(1, 0), (1, 1), (2, 1)], [(0, 0), (1, 0), (2, 0)]]
    blockers = {"c0": "h"}
    assert validate_plan(problem, plan_of(problem, good, blockers)) == []

    def broken(change, expect, plan_blockers=blockers):
        cells = [list(path) for path in good]
        change(cells)
        errors = validate_plan(problem, plan_of(problem, cells, plan_blockers))
        assert errors and any(expect in e for e in errors), errors

    broken(lambda c: c[1].__setitem__(0, (0, 1)), "starts in")
    broken(lambda c: c[1].__setitem__(2, (1, -1)), "outside the grid")
    broken(lambda c: c[1].__setitem__(2, (2, 1)) or c[0].__setitem__(2, (1, 1)), "jump")
    broken(lambda c: c[0].__setitem__(2, (3, 1)), "jump")
    broken(lambda c: c[1].__setitem__(2, (2, 1)), "share")
    broken(lambda c: c[0].__setitem__(1, (1, 0)) or c[1].__setitem__(1, (0, 0)), "blocker")
    broken(lambda c: None, "blockers", plan_blockers={})
    broken(lambda c: c[0].pop(), "steps")
    assert validate_plan(problem, dataclasses.replace(plan_of(problem, good), cells=None))
    # HV-claimed cell.
    hv_problem = dataclasses.replace(problem, blocked=(frozenset(), frozenset(), {(2, 1)}))
    errors = validate_plan(hv_problem, plan_of(hv_problem, good, blockers))
    assert any("claimed by an HV" in e for e in errors)
    # Swap: c0 and c1 trade (1,0) <-> (0,0)... build one on a problem without blockers.
    plain = dataclasses.replace(problem, blockers=())
    swap = [[(1, 0), (0, 0), (0, 0)], [(0, 0), (1, 0), (1, 0)]]
    assert any("swap" in e for e in validate_plan(plain, plan_of(plain, swap)))


def test_validator_is_cheap():
    import time

    problem = fig7_problem()
    plan = CpSatPlanner(30.0).plan(problem)
    started = time.perf_counter()
    for _ in range(100):
        assert validate_plan(problem, plan) == []
    assert (time.perf_counter() - started) / 100 < 1e-3


# ----------------------------------------------------------------------------- plan helpers


def test_shift_plan_and_cells_of():
    problem = small_problem(3, 1, 3, [(0, 0)], goal_row=2)
    plan = dataclasses.replace(
        plan_of(problem, [[(0, 0), (1, 0), (2, 0)]]), t0_s=10.0, behaving_interval_s=3.0
    )
    assert plan.cells_of("c0") == ((0, 0), (1, 0), (2, 0))
    assert plan.cell_at("c0", 7) == (2, 0)
    with pytest.raises(KeyError):
        plan.cells_of("nobody")
    shifted = shift_plan(plan, 1)
    assert shifted.cells == (((1, 0), (2, 0), (2, 0)),)
    assert shifted.t0_s == pytest.approx(13.0)
    assert shift_plan(plan, 0) is plan


def test_replan_trigger_reasons():
    problem = small_problem(4, 2, 4, [(0, 0)], goal_row=3)
    plan = dataclasses.replace(
        plan_of(problem, [[(0, 0), (1, 0), (2, 0), (3, 0)]]), t0_s=0.0, behaving_interval_s=3.0
    )
    trigger = ReplanTrigger(drift_cells=1)
    assert trigger.check(0.0, {"c0": (0, 0)}, []) == "initial"
    trigger.planned(plan, 0.0, ["h1"])
    assert trigger.check(1.0, {"c0": (0, 0)}, ["h1"]) is None
    assert trigger.check(1.0, {"c0": (0, 0)}, ["h1", "h2"]) == "new_hv"
    assert trigger.check(1.0, {"c0": (2, 1)}, ["h1"]) == "drift"  # 2 cells from (1,0)
    assert trigger.check(4.0, {"c0": (2, 1)}, ["h1"]) is None  # step 1: next cell (2,0)
    assert trigger.check(4.0, {"x": (0, 0)}, []) == "drift"
    assert trigger.check(9.0, {"c0": (3, 0)}, ["h1"]) == "plan_done"
    failed = dataclasses.replace(plan, status=PlanStatus.INFEASIBLE, cells=None)
    trigger.planned(failed, 10.0, [])
    assert trigger.check(11.0, {}, []) is None
    assert trigger.check(13.0, {}, []) == "initial"


def test_move_masks_agree_with_move_allowed_cell_by_cell():
    """The vectorised move rules (flow model) and the scalar ones (validator) are the same rules."""
    import random

    from sumo_swarm.core.planner.problem import MOVES, move_allowed, move_masks

    rng = random.Random(7)
    for _ in range(20):
        n_rows, n_cols, n_steps = rng.randint(3, 8), rng.randint(2, 4), rng.randint(2, 5)
        cells = [(r, c) for r in range(n_rows) for c in range(n_cols)]

        def some(p):
            return frozenset(cell for cell in cells if rng.random() < p)  # noqa: B023

        starts = tuple(rng.sample(cells, 2))
        problem = PlanningProblem(
            n_rows=n_rows, n_cols=n_cols, n_steps=n_steps, cav_ids=("a", "b"),
            start_cells=starts, blocked=tuple(some(0.15) for _ in range(n_steps)),
            goal_rows=(n_rows,) * n_steps, regroup_lane=0,
            entry_blocked=tuple(some(0.2) for _ in range(n_steps)),
            hv_tracks=tuple(
                (rng.randrange(n_cols), tuple(rng.uniform(-1, n_rows) for _ in range(n_steps)))
                for _ in range(2)
            ),
            start_rows=tuple(r + rng.uniform(-0.5, 0.5) for r, _ in starts),
            stay_ok=frozenset({starts[0]}),
            stay_on=tuple(some(0.3) | {starts[1]} for _ in range(n_steps - 1)),
            exempt_moves=frozenset(
                {(0, starts[1], (starts[1][0], starts[1][1] + 1))} if starts[1][1] + 1 < n_cols
                else set()
            ),
        )  # fmt: skip
        masks = move_masks(problem)
        for k in range(n_steps - 1):
            for row, col in cells:
                for m, (dr, dc) in enumerate(MOVES):
                    dst = (row + dr, col + dc)
                    inside = 0 <= dst[0] < n_rows and 0 <= dst[1] < n_cols
                    expected = inside and move_allowed(problem, k, (row, col), dst)
                    assert masks[m, k, row, col] == expected, (k, (row, col), dst)


def test_malformed_hint_is_ignored():
    problem = hand_problems()[1]
    junk = dataclasses.replace(plan_of(problem, [[(0, 0)] * 3] * 2), cells=((1, 2, 3), (4,)))
    plan = CpSatPlanner(10.0).plan(problem, hint=junk)
    assert plan.status is PlanStatus.OPTIMAL and plan.objective == 19


def test_an_hv_claims_the_cells_it_drives_through_between_steps():
    # A 35 m/s HV in lane 1 behind a grid moving at 15 m/s (3 s steps): its centre is at
    # (-62.5 + 20 t) m from the grid's origin, i.e. rows -4.2, -0.2, 3.8 and 7.8 at steps 0-3
    # (15 m cells). Between steps 2 and 3 it drives through rows 4-6, beyond which the 7-row grid
    # ends: checked at the steps alone (the paper), a CAV planned there at step 3 is "behind" it.
    road = RoadSection((3.2, 3.2, 3.2))
    cavs = [VehicleState(f"c{i}", 300.0 - 15 * i, 0, 0.0, 15.0, 5.0, is_cav=True) for i in (0, 1)]
    target = VehicleState("truck", 330.0, 0, 0.0, 15.0, 12.0)
    fast = VehicleState("fast", 215.0, 1, 0.0, 35.0, 5.0)
    lane1 = {}
    for sweep in (False, True):
        gs = GridSettings(hv_sweep=sweep)
        grid = build_grid(cavs, target, road, 0.0, 15.0, gs)
        assert (grid.origin_s_m, grid.n_rows) == (275.0, 7)
        problem = build_problem(grid, cavs, [fast], target, 0.0, PlannerSettings(n_steps=4), gs)
        lane1[sweep] = [{r for r, c in step if c == 1} for step in problem.blocked]
    assert lane1[False][3] == set()
    assert lane1[True][3] == {4, 5, 6}  # passed through during the last interval
    assert lane1[True][0] == {0, 1}  # passed through during the first interval
    for step in range(4):  # the sweep only adds
        assert lane1[False][step] <= lane1[True][step]
