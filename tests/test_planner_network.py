"""The exact network search of the cell planner (core/planner/network.py), the problem dump and
the stored problems the swarm built (tests/data/planner_problems.json.gz)."""

from __future__ import annotations

import gzip
import json
import random
from dataclasses import replace
from pathlib import Path

import pytest

from sumo_swarm.core.planner import (
    CpSatPlanner,
    PlannerSettings,
    PlannerWeights,
    PlanStatus,
    evaluate_objective,
    make_planner,
    validate_plan,
)
from sumo_swarm.core.planner.dump import problem_from_dict, problem_to_dict
from sumo_swarm.core.planner.flow import build_flow_model, hint_values
from sumo_swarm.core.planner.network import solve_network
from sumo_swarm.errors import ConfigError
from tests.test_planner import brute_force, fig7_problem, random_small_problem, small_problem

PROBLEMS = Path(__file__).parent / "data" / "planner_problems.json.gz"


def network_planner(work: int = 10**7, only: bool = True) -> CpSatPlanner:
    return CpSatPlanner(30.0, network_work=work, network_only=only)


def check(problem, plan, expected: float) -> None:
    assert plan.status is PlanStatus.OPTIMAL, plan.message
    assert validate_plan(problem, plan) == []
    assert plan.objective == pytest.approx(expected)
    assert evaluate_objective(problem, plan.cells) == pytest.approx(plan.objective)
    assert plan.best_bound == pytest.approx(plan.objective)


# ----------------------------------------------------------------------------- hand-solved


def test_one_cav_moves_up_in_one_flow():
    # 2x2 grid, goal row 1, 3 steps: up at once (2 w_lon = 2), no target cost after. With each
    # CAV's own delta (known from its cell) the model is a plain min-cost flow: one flow.
    problem = small_problem(2, 2, 3, [(0, 0)], goal_row=1, delta_mode="cav")
    model = build_flow_model(problem, rows=False)
    assert not model.delta_var
    result = solve_network(model, 10.0)
    assert result.status == "optimal" and result.branches == 1
    assert result.objective == 2
    check(problem, network_planner().plan(problem), 2.0)


def test_swap_without_stays_is_excluded():
    # Two CAVs side by side in row 0 of a 2x2 grid, nobody impeded (goal row 0), regroup lane 1.
    # An HV in lane 0 falls from row 0.5 to -0.5: the CAV in lane 0 may not stay (it would pass
    # it) nor move up, so it moves to lane 1. Trading cells with the other CAV would cost 1
    # (w_lat for the one left in lane 0) but is a swap, and a swap that cannot be undone into
    # two stays must be excluded: the other CAV moves up instead (2 w_lon = 2).
    problem = small_problem(
        2, 2, 2, [(0, 0), (0, 1)], goal_row=0, lane=1, target_form="distance",
        hv_tracks=((0, (0.5, -0.5)),), start_rows=(0.0, 0.0),
    )  # fmt: skip
    assert brute_force(problem) == 2.0
    model = build_flow_model(problem)
    assert len(model.swap_pairs) == 1
    for planner in (CpSatPlanner(10.0), network_planner()):
        plan = planner.plan(problem)
        check(problem, plan, 2.0)
        assert plan.cells == (((0, 0), (0, 1)), ((0, 1), (1, 1)))


@pytest.mark.parametrize("seed", range(40))
def test_random_small_grids_match_brute_force(seed):
    # The generator of test_planner's brute-force test, with the weights of the delta trap
    # (w_tar small against the regroup cost) drawn often: the search must branch there.
    problem = random_small_problem(
        random.Random(seed), max_w_regroup=8, delta_modes=("swarm", "swarm", "cav")
    )
    expected = brute_force(problem)
    plan = network_planner().plan(problem)
    if expected is None:
        assert plan.status is PlanStatus.INFEASIBLE
    else:
        check(problem, plan, expected)


def test_search_branches_on_delta_and_proves_the_mip_optimum():
    # Figure 7 has open deltas at steps 9-13: the search branches, and its optimum is the one
    # CP-SAT proves on the full MIP (3210, docs/planner.md), with the paper's blockers.
    problem = fig7_problem()
    model = build_flow_model(problem, rows=False)
    assert sorted(model.delta_var) == [9, 10, 11, 12, 13]
    result = solve_network(model, 30.0)
    assert result.status == "optimal" and result.branches > 1
    assert result.objective == result.bound == 3210
    plan = make_planner(PlannerSettings(network_work=28_000)).plan(problem)  # proves it
    check(problem, plan, 3210.0)
    assert plan.message.startswith("network: proved")
    assert plan.cells_of("cav0")[1] == (5, 2) and plan.cells_of("cav1")[1] == (4, 0)
    cp_sat = CpSatPlanner(30.0).plan(problem)
    assert cp_sat.objective == plan.objective


def test_paper_form_and_per_cav_delta_agree_with_cp_sat():
    for settings in (
        PlannerSettings(target_form="paper", delta_mode="cav"),
        PlannerSettings(weights=PlannerWeights(10, 1, 10)),  # the delta trap (docs/planner.md)
    ):
        problem = fig7_problem(settings)
        cp_sat = CpSatPlanner(60.0).plan(problem)
        assert cp_sat.status is PlanStatus.OPTIMAL
        check(problem, network_planner().plan(problem), cp_sat.objective)


def test_budget_returns_the_best_plan_with_a_valid_bound():
    problem = fig7_problem()
    model = build_flow_model(problem, rows=False)
    result = solve_network(model, 30.0, max_branches=2)
    assert result.status == "feasible" and result.branches == 2
    assert result.bound <= 3210 <= result.objective
    plan = CpSatPlanner(30.0, network_work=1).plan(problem)  # at least 2 flows, then CP-SAT
    check(problem, plan, 3210.0)
    only = network_planner(work=1).plan(problem)
    assert only.status is PlanStatus.FEASIBLE and validate_plan(problem, only) == []
    assert only.best_bound <= 3210 <= only.objective
    assert evaluate_objective(problem, only.cells) == pytest.approx(only.objective)


def test_plan_work_ends_a_search_that_has_a_plan_never_one_without():
    problem = fig7_problem()  # 6 CAVs
    model = build_flow_model(problem, rows=False)
    full = solve_network(model, 30.0)
    cut = solve_network(model, 30.0, plan_work=1)  # stops at its first plan (>= 2 flows)
    assert full.status == "optimal" and cut.status == "feasible"
    assert 2 <= cut.branches < full.branches
    assert cut.bound <= 3210 <= cut.objective
    # Above network_ref_cavs CAVs the stopping work shrinks in proportion: 3 of 6 halves it.
    halved = CpSatPlanner(30.0, network_work=28_000, network_only=True, network_ref_cavs=3)
    assert halved._plan_work(problem) == 14_000
    plan = halved.plan(problem)
    assert plan.status is PlanStatus.FEASIBLE and validate_plan(problem, plan) == []
    assert plan.best_bound <= 3210 <= plan.objective
    same = CpSatPlanner(30.0, network_work=28_000, network_only=True, network_ref_cavs=6)
    assert same._plan_work(problem) is None
    check(problem, same.plan(problem), 3210.0)  # 6 CAVs: the budget as it was, proved
    with pytest.raises(ConfigError, match="network_ref_cavs"):
        PlannerSettings(network_ref_cavs=-1)
    with pytest.raises(ConfigError, match="network_ref_cavs"):
        CpSatPlanner(1.0, network_ref_cavs=2.5)


def test_hint_is_a_first_plan_and_a_bad_one_is_ignored():
    problem = fig7_problem()
    best = network_planner().plan(problem)
    model = build_flow_model(problem, rows=False)
    hint = hint_values(model, best.cells)[: model.n_edges]
    result = solve_network(model, 30.0, max_branches=1, hint=hint)
    assert result.objective == 3210  # the hint, the best plan known after one flow
    # Without it (or with a hint that is not a flow) one flow gives the root's plan only.
    alone = solve_network(model, 30.0, max_branches=1)
    assert alone.status == "feasible" and alone.objective == 3234
    broken = [1] * model.n_edges  # every edge used: not a flow
    assert solve_network(model, 30.0, max_branches=1, hint=broken).objective == 3234
    assert network_planner().plan(problem, hint=replace(best, cells=best.cells[:1])).ok


def test_infeasible_and_settings():
    crowded = small_problem(1, 1, 3, [(0, 0), (0, 0)], goal_row=0)  # two CAVs, one cell
    assert network_planner().plan(crowded).status is PlanStatus.INFEASIBLE
    walled = small_problem(2, 1, 3, [(0, 0)], goal_row=1, blocked={(0, 0), (1, 0)})
    assert network_planner().plan(walled).status is PlanStatus.INFEASIBLE
    with pytest.raises(ConfigError, match="network_work"):
        PlannerSettings(network_work=-1)
    with pytest.raises(ConfigError, match="network_only"):
        PlannerSettings(network_only="yes")
    with pytest.raises(ConfigError, match="network_work"):
        CpSatPlanner(1.0, network_work=-5)
    assert PlannerSettings().network_work > 0 and PlannerSettings().network_only


# ----------------------------------------------------------------------------- dump


def test_dump_round_trip_and_bad_input():
    problem = fig7_problem()
    problem = replace(problem, stay_on=(frozenset(), frozenset({problem.start_cells[0]})))
    data = json.loads(json.dumps(problem_to_dict(problem)))
    again = problem_from_dict(data)
    assert again == problem and again.stay_on == problem.stay_on
    older = dict(data)
    del older["stay_on"]  # dumps written before stay_on existed
    assert problem_from_dict(older).stay_on == ()
    assert again.blockers == problem.blockers and again.blocked == problem.blocked
    del data["goal_rows"]
    with pytest.raises(ConfigError, match="goal_rows"):
        problem_from_dict(data)


# ----------------------------------------------------------------------------- stored problems


def stored_problems() -> list[dict]:
    with gzip.open(PROBLEMS, "rt") as handle:
        return json.load(handle)["calls"]


def test_stored_problems_solved_within_budget_and_never_below_the_proven_optimum():
    # The 50 problems the swarm built in the paper scene and three 12-CAV variants: the
    # default planner (the network search alone) returns a valid plan or the same
    # infeasibility, proves the optimum where the recorded CP-SAT run proved one and the
    # search finished, and never reports a bound above a proven optimum.
    calls = stored_problems()
    assert len(calls) == 50 and PROBLEMS.stat().st_size < 1_000_000
    planner = make_planner(PlannerSettings())
    proved = 0
    for call in calls:
        problem = problem_from_dict(call["problem"])
        plan = planner.plan(problem)
        if call["run_status"] == "infeasible":
            assert plan.status is PlanStatus.INFEASIBLE
            continue
        assert plan.ok, plan.message
        assert validate_plan(problem, plan) == []
        assert plan.best_bound <= plan.objective + 1e-9
        if call["run_status"] == "optimal":
            assert plan.best_bound <= call["run_objective"] + 1e-9
            assert plan.objective >= call["run_objective"] - 1e-9
            if plan.status is PlanStatus.OPTIMAL:
                proved += 1
                assert plan.objective == pytest.approx(call["run_objective"])
    assert proved >= 10


def test_scenario_keys_and_collector_bad_input(tmp_path):
    import os
    import subprocess
    import sys

    from sumo_swarm.config import load_scenario
    from tests.conftest import PAPER

    sc = load_scenario(PAPER, overrides={"planner": {"network_work": 5000, "network_only": False}})
    assert (sc.planner.network_work, sc.planner.network_only) == (5000, False)
    with pytest.raises(ConfigError, match="network_work"):
        load_scenario(PAPER, overrides={"planner": {"network_work": -3}})
    root = Path(__file__).parents[1]
    sweep = root / "scenarios" / "variants.toml"
    env = dict(os.environ, PYTHONPATH=str(root))
    run = subprocess.run(
        [sys.executable, str(root / "tools" / "collect_problems.py"), str(sweep),
         str(tmp_path / "out.json"), "--case", "400"],
        capture_output=True, text=True, env=env, check=False,
    )  # fmt: skip
    err = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(err) == 1
    assert "no case 400" in err[0] and "variants.toml" in err[0]
