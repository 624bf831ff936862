"""Stress sweep v2 (issue 12): the generator's v2 mode and the report's pure parts.

Hand-made cases with known answers: trajectories in which the CAVs do or do not get past the
slow vehicle, result tables of a few scenes under swarm, cacc and sumo-lc (a partial batch
included), the sweep's "Done when" figures. The sweep itself runs with `sumo-swarm batch`
(docs/bench/stress2.md).
"""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import pytest

from tests.toolload import load_tool

ROOT = Path(__file__).resolve().parent.parent


ms = load_tool("make_stress")
sr = load_tool("stress_report")

# --------------------------------------------------------------------------- generator


def test_v1_is_still_the_committed_stress_toml():
    text = ms.render(ms.draw(200, 1), 1)
    assert text == (ROOT / "scenarios" / "stress.toml").read_text(encoding="utf-8")


def test_v2_is_the_committed_stress2_toml_with_sumo_lc():
    text = ms.render(ms.draw(200, 2, version=2), 2, version=2)
    assert text == (ROOT / "scenarios" / "stress2.toml").read_text(encoding="utf-8")
    assert 'controllers = ["swarm", "cacc", "sumo-lc"]' in text
    assert 'name = "stress2"' in text


@pytest.mark.parametrize("scenes", [1, 3, 4, 7, 200])
def test_v2_lane_change_share_is_exact_and_at_least_30_pct(scenes):
    cases = ms.draw(scenes, 5, version=2)
    changing = sum(bool(c["hv.lane_changes"]) for c in cases)
    assert changing == math.ceil(0.4 * scenes)
    assert changing / scenes >= 0.3


def test_v2_keeps_v1_randomisation_but_for_the_lane_change_flag():
    v1 = ms.draw(20, 9)
    v2 = ms.draw(20, 9, version=2)
    for a, b in zip(v1, v2, strict=True):
        assert {k: v for k, v in a.items() if k != "hv.lane_changes"} == {
            k: v for k, v in b.items() if k != "hv.lane_changes"
        }


def test_main_writes_v2_and_refuses_zero_scenes(tmp_path, capsys):
    out = tmp_path / "s.toml"
    assert ms.main(["--version", "2", "--scenes", "4", "--out", str(out)]) == 0
    assert "--version 2 --scenes 4 --seed 2" in out.read_text()
    assert ms.main(["--scenes", "0", "--out", str(out)]) == 2
    assert capsys.readouterr().err.count("\n") == 1


# --------------------------------------------------------------------------- passing


def _traj(rows: list[tuple[float, str, str, float, float]]) -> pd.DataFrame:
    return pd.DataFrame(rows, columns=["time_s", "vehicle", "kind", "s_m", "length_m"])


def _two_cavs_and_target(cav1_s_at_2: float) -> pd.DataFrame:
    # time, vehicle, kind, front s [m], length [m]; the target's front is at 100 m at t = 2.
    return _traj(
        [
            (1.0, "cav0", "cav", 90.0, 5.0),
            (1.0, "cav1", "cav", 80.0, 5.0),
            (1.0, "hv_target", "hv", 95.0, 12.0),
            (2.0, "cav0", "cav", 110.0, 5.0),  # rear 105 > 100: past
            (2.0, "cav1", "cav", cav1_s_at_2, 5.0),
            (2.0, "hv_target", "hv", 100.0, 12.0),
            (3.0, "cav0", "cav", 100.0, 5.0),  # falls back: a pass, once made, counts
            (3.0, "cav1", "cav", 90.0, 5.0),
            (3.0, "hv_target", "hv", 105.0, 12.0),
        ]
    )


def test_all_cavs_passed_needs_every_rear_bumper_ahead_of_the_targets_front():
    assert sr.all_cavs_passed(_two_cavs_and_target(105.1))
    assert not sr.all_cavs_passed(_two_cavs_and_target(105.0))  # rear 100 == front 100


def test_a_pass_counts_only_while_the_target_is_on_the_road():
    df = _two_cavs_and_target(105.1)
    gone = df[~((df["vehicle"] == "hv_target") & (df["time_s"] == 2.0))]
    assert not sr.all_cavs_passed(gone)  # at t = 2 no target to be past; at 1 and 3 behind it
    assert not sr.all_cavs_passed(df[df["kind"] != "cav"])  # no CAVs: nothing got past


def test_lc_passes_reads_each_runs_trajectories(tmp_path):
    run = tmp_path / "runs" / "lc1"
    run.mkdir(parents=True)
    _two_cavs_and_target(106.0).to_parquet(run / "trajectories.parquet")
    got = sr.lc_passes(tmp_path, ["lc1", "lc_missing"])
    assert bool(got["lc1"]) is True and pd.isna(got["lc_missing"])


# --------------------------------------------------------------------------- scene table

PARAMS = ["case", "cav.count", "simulation.network", "hv.lane_changes"]


def _run(case: int, controller: str, lane_changes: bool, **fields) -> dict:
    row = {
        "case": case, "cav.count": 3, "simulation.network": "h3", "hv.lane_changes": lane_changes,
        "controller": controller, "run_id": f"{controller}-{case}", "status": "ok",
        "safety.collisions": 0, "safety.hard_brakes_cav": 0, "safety.hard_brakes_hv": 0,
        "overtake.all_past": True, "overtake.all_past_regrouped": True, "cav.gap_min_m": 6.0,
        "cav.gap_min_cav_m": 6.0, "cav.gap_min_hv_m": 9.0, "cav.mean_speed_mps": 20.0,
        "lateral_holds": 0.0, "planner.solve_ms_p95": 10.0, "planner.solve_ms_max": 20.0,
    }  # fmt: skip
    row.update(fields)
    return row


def _scene(case: int, lane_changes: bool, swarm: dict, cacc_mps: float = 20.0) -> list[dict]:
    return [
        _run(case, "swarm", lane_changes, **swarm),
        _run(case, "cacc", lane_changes, **{"cav.mean_speed_mps": cacc_mps}),
        _run(case, "sumo-lc", lane_changes),
    ]


def _results() -> pd.DataFrame:
    rows = (
        # 0: a good scene, 10 % faster than cacc
        _scene(0, False, {"cav.mean_speed_mps": 22.0})
        # 1: 0.9 % slower than cacc (allowed); sumo-lc did not pass, nor did the swarm (fine);
        # its CAV-to-CAV gap unknown, the gap of any CAV (4.9 m) stands in
        + _scene(1, True, {"cav.mean_speed_mps": 19.82, "overtake.all_past": False,
                           "overtake.all_past_regrouped": False, "cav.gap_min_cav_m": None,
                           "cav.gap_min_m": 4.9, "cav.gap_min_hv_m": 3.0})
        # 2: 1.1 % slower; sumo-lc passed but the swarm did not regroup; a collision
        + _scene(2, True, {"cav.mean_speed_mps": 19.78, "overtake.all_past_regrouped": False,
                           "safety.collisions": 2})
        # 3: sumo-lc's trajectories unknown; a CAV gap of 4.0 m behind an HV only
        + _scene(3, False, {"cav.mean_speed_mps": 24.0, "cav.gap_min_m": 4.0,
                            "cav.gap_min_hv_m": 4.0})
        # 4: a scene still under way: its sumo-lc run has not finished
        + _scene(4, True, {})[:2]
    )  # fmt: skip
    return pd.DataFrame(rows)


LC_PASSED = pd.Series({"sumo-lc-0": True, "sumo-lc-1": False, "sumo-lc-2": True}, dtype="boolean")


@pytest.fixture
def table() -> pd.DataFrame:
    return sr.scene_table(_results(), PARAMS, LC_PASSED)


def test_v2_judges_only_the_scenes_with_all_three_runs(table):
    assert len(table) == 4  # scene 4 (no sumo-lc run yet) left out
    assert list(table["mean_speed_mps"]) == [22.0, 19.82, 19.78, 24.0]


def test_v2_per_scene_checks(table):
    assert list(table["gain_over_cacc_pct"].round(6)) == [10.0, -0.9, -1.1, 20.0]
    assert list(table["not_slower_than_cacc"]) == [True, True, False, True]
    assert list(table["sumo_lc_passed"].astype(object)) == [True, False, True, pd.NA]
    # passed and regrouped; not passed (nothing asked); passed, not regrouped; unknown
    assert list(table["passes_where_sumo_lc_passes"]) == [True, True, False, False]
    assert list(table["gap_min_cav_m"]) == [6.0, 4.9, 6.0, 6.0]  # falls back to gap_min_m
    assert list(table["cav_gap_ok"]) == [True, False, True, True]  # HV gaps are apart
    assert list(table["no_collision"]) == [True, True, False, True]
    assert sr.checks_of(table) == list(sr.CHECKS) + list(sr.V2_CHECKS)


def test_done_when_figures(table):
    got = sr.done_when(table, total_scenes=200).set_index("measure")
    assert got.loc["scenes judged (all three runs finished)", "value"] == "4 of 200"
    assert got.loc["scenes with HV lane changes (%)", "value"] == 50.0
    assert got.loc["collisions in all (swarm)", ["value", "met"]].tolist() == [2, "NO"]
    assert got.loc["scenes where swarm is > 1 % slower than cacc", "value"] == 1
    assert got.loc["scenes where all sumo-lc CAVs got past the slow vehicle", "value"] == (
        "2 (50.0 %)"
    )
    assert got.loc["  of these, swarm completed and regrouped (%)", "value"] == 50.0
    assert got.loc["mean gain over cacc, all scenes (%)", "value"] == 7.0  # (10-.9-1.1+20)/4
    assert got.loc["mean gain over cacc, lane-change scenes (%) [2]", "value"] == -1.0
    assert got.loc["min CAV-to-CAV gap (m)", ["value", "met"]].tolist() == [4.9, "NO"]
    assert got.loc["min gap of a CAV behind an HV (m), reported apart", "value"] == 3.0


def test_failing_view_names_the_failed_checks(table):
    failing = table[~table[sr.checks_of(table)].all(axis=1)]
    view = sr.failing_view(failing)
    assert list(view["failed"]) == [
        "cav_gap_ok",
        "no_collision, not_slower_than_cacc, passes_where_sumo_lc_passes",
        "passes_where_sumo_lc_passes",
    ]


def test_failures_by_check_counts_lane_change_scenes_apart(table):
    got = sr.failures_by_check(table).set_index("check")
    assert got.loc["passes_where_sumo_lc_passes"].tolist() == [2, 1]  # scenes 2 (lc) and 3
    assert got.loc["cav_gap_ok"].tolist() == [1, 1]
    assert got.loc["ran"].tolist() == [0, 0]


def test_without_sumo_lc_the_table_is_v1s():
    v1 = _results()
    v1 = v1[v1["controller"] != "sumo-lc"]
    table = sr.scene_table(v1, PARAMS)
    assert len(table) == 5  # every swarm run, as before
    assert "sumo_lc_passed" not in table and sr.checks_of(table) == list(sr.CHECKS)
    assert sr.failing_view(table).equals(table)


def test_report_exits_2_with_one_line_on_a_folder_that_is_not_a_batch(tmp_path, capsys):
    assert sr.main([str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "sweep.json" in err
