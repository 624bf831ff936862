"""Issue 11's acceptance: paper-scene variants under swarm and cacc, through real SUMO.

A small seeded set drawn by tools/make_variants.py (its stratified draw puts every range's ends
in any set of two or more scenes: side HVs wanting 24 m/s, a 12 m/s truck, 2 and 12 CAVs,
12 m upstream gaps, HV lane changes on) runs as a batch, and tools/variants_report.py judges
every scene against the "Done when" of issue 11, one test per check. The report's and the
generator's pure parts are tested first, on hand-made cases with known answers.
"""

from __future__ import annotations

import json
from pathlib import Path

import pandas as pd
import pytest

from sumo_swarm.study.batch import load_sweep, run_batch
from tests.toolload import load_tool

ROOT = Path(__file__).resolve().parent.parent
SEED = 11
SCENES = 6


mv = load_tool("make_variants")
vr = load_tool("variants_report")
sr = load_tool("stress_report")

# The ranges of issue 11 and the key of each in a case.
RANGES = {
    "scene.hv.hv_left.desired_speed_mps": mv.SIDE_SPEED_MPS,
    "scene.hv.hv_right.desired_speed_mps": mv.SIDE_SPEED_MPS,
    "scene.hv.hv_target.speed_mps": mv.TRUCK_SPEED_MPS,
    "scene.hv.hv_target.length_m": mv.TRUCK_LENGTH_M,
    "scene.upstream_gap_m": mv.UPSTREAM_GAP_M,
    "scene.upstream_per_lane": mv.UPSTREAM_PER_LANE,
    "cav.count": mv.CAV_COUNT,
}


# --------------------------------------------------------------------------- the generator


@pytest.mark.parametrize("count", [2, SCENES, 40])
def test_draw_covers_every_range_ends_included(count):
    cases = pd.DataFrame(mv.draw(SEED, count))
    for key, (lo, hi) in RANGES.items():
        assert cases[key].min() == lo and cases[key].max() == hi, key
    # The fastest left HV's scene has the fastest right HV too: both side lanes at 24 m/s.
    fastest = cases.loc[cases["scene.hv.hv_left.desired_speed_mps"].idxmax()]
    assert fastest["scene.hv.hv_right.desired_speed_mps"] == mv.SIDE_SPEED_MPS[1]
    assert cases["hv.lane_changes"].sum() == count // 2
    assert mv.draw(SEED, count) == mv.draw(SEED, count)


def test_draw_is_stratified_and_scenes_fit_on_the_road():
    cases = pd.DataFrame(mv.draw(SEED, 40))
    # One truck speed in each of 40 strata of 12-17 m/s (0.125 m/s each).
    strata = ((cases["scene.hv.hv_target.speed_mps"] - 12.0) / 0.125).clip(upper=39.99)
    assert sorted(strata.astype(int)) == list(range(40))
    counts = cases["cav.count"].value_counts()
    assert set(counts.index) == set(range(2, 13)) and counts.max() - counts.min() <= 1
    for _, c in cases.iterrows():
        platoon_rear = c["scene.leader_front_m"] - 15.0 * (c["cav.count"] - 1) - 5.0
        upstream = c["scene.upstream_per_lane"] * (c["scene.upstream_gap_m"] + 5.0)
        assert platoon_rear - upstream >= 0.0  # every upstream HV of the platoon's lane fits
        assert c["scene.hv.hv_right.front_m"] - 5.0 - upstream >= 0.0
        assert c["scene.hv.hv_target.front_m"] == pytest.approx(
            c["scene.leader_front_m"] + 10.0 + c["scene.hv.hv_target.length_m"]
        )


def test_rendered_sweep_loads(tmp_path):
    path = tmp_path / "v.toml"
    path.write_text(mv.render(mv.draw(SEED, 3), SEED, base=str(ROOT / "scenarios/paper.toml")))
    sweep = load_sweep(path)
    assert len(sweep.runs) == 9 and set(sweep.controllers) == {"swarm", "cacc", "sumo-lc"}
    scenario = next(r for r in sweep.runs if r.controller == "swarm").scenario()
    assert scenario.simulation.duration_s == mv.DURATION_S


# --------------------------------------------------------------------------- the judge


def _record(summary: dict | None, status: str = "ok") -> dict:
    return {"status": status, "summary": summary}


def _summary(**changes: object) -> dict:
    """A summary that passes every check; ``changes`` replace dotted fields (None deletes)."""
    s = {
        "cav": {"gap_min_m": 6.0, "max_speed_mps": 24.0, "mean_speed_mps": 19.0},
        "overtake": {
            "triggered": True, "completed": True, "regrouped": True, "aborted": 0,
            "all_past": True, "all_past_regrouped": True,
            "lateral_holds": 0, "blocked_hv_min_accel_mps2": -1.5,
        },
        "safety": {"collisions": 0, "hard_brakes_cav": 0, "hard_brakes_hv": 1},
        "planner": {"solves": 4, "solve_ms_p95": 40.0, "solve_ms_max": 90.0},
        "timing": {"wall_s": 5.0},
    }  # fmt: skip
    for dotted, value in changes.items():
        section, key = dotted.split("__")
        if value is None:
            del s[section][key]
        else:
            s[section][key] = value
    return s


CACC = _record(
    {"cav": {"mean_speed_mps": 17.0}, "safety": {"hard_brakes_hv": 1}, "timing": {"wall_s": 2.0}}
)


def _judge(summary: dict, platoon=None, cacc=CACC, status="ok") -> dict:
    return vr.judge_scene(_record(summary, status), cacc, 25.0, 2.0, platoon)


def test_a_good_scene_passes_every_check():
    verdicts = _judge(_summary())
    assert {k: verdicts[k] for k in vr.CHECKS} == dict.fromkeys(vr.CHECKS, vr.PASS)
    assert verdicts["all"] == vr.PASS and verdicts["cost_ratio"] == 2.5


@pytest.mark.parametrize(
    ("change", "check"),
    [
        ({"cav__gap_min_m": 4.97}, "min_gap"),
        ({"safety__hard_brakes_hv": 2}, "hard_brakes"),  # one more HV than under cacc
        ({"safety__hard_brakes_cav": 1}, "hard_brakes"),
        ({"cav__max_speed_mps": 25.11}, "max_speed"),
        ({"overtake__blocked_hv_min_accel_mps2": -2.11}, "blocked_hv_brake"),
        ({"cav__mean_speed_mps": 17.0}, "mean_speed"),  # equal is not above
        ({"timing__wall_s": 6.01}, "run_cost"),
        ({"planner__solve_ms_p95": 50.5}, "planner_p95"),
        ({"planner__solve_ms_max": 251.0}, "planner_max"),
        ({"safety__collisions": 1}, "no_collision"),
        ({"overtake__all_past_regrouped": False}, "overtake"),
    ],
)
def test_each_check_fails_on_its_own(change, check):
    verdicts = _judge(_summary(**change))
    assert verdicts[check] == vr.FAIL
    assert [k for k in vr.CHECKS if verdicts[k] != vr.PASS] == [check]


def test_bounds_themselves_pass():
    at_bounds = {
        "cav__gap_min_m": 5.0, "cav__max_speed_mps": 25.1, "timing__wall_s": 6.0,
        "overtake__blocked_hv_min_accel_mps2": -2.1, "planner__solve_ms_p95": 50.0,
        "planner__solve_ms_max": 250.0,
    }  # fmt: skip
    verdicts = _judge(_summary(**at_bounds))
    assert verdicts["all"] == vr.PASS


@pytest.mark.parametrize(
    ("change", "check"),
    [
        ({"overtake__blocked_hv_min_accel_mps2": None}, "blocked_hv_brake"),
        ({"timing__wall_s": None}, "run_cost"),
        ({"safety__hard_brakes_hv": None}, "hard_brakes"),
        ({"planner__solve_ms_p95": None}, "planner_p95"),
        ({"overtake__all_past": None, "overtake__aborted": None}, "overtake"),
    ],
)
def test_a_missing_field_is_not_a_pass(change, check):
    verdicts = _judge(_summary(**change))
    assert verdicts[check] == vr.NA and verdicts["all"] == vr.FAIL


def test_null_means_none_happened():
    # No plan made (null times, 0 solves) and no HV blocked (a null, not a missing key):
    # nothing to exceed.
    s = _summary(planner__solves=0)
    s["planner"]["solve_ms_p95"] = s["planner"]["solve_ms_max"] = None
    verdicts = _judge(s)
    assert verdicts["planner_p95"] == verdicts["planner_max"] == vr.PASS
    s["overtake"]["blocked_hv_min_accel_mps2"] = None
    assert _judge(s)["blocked_hv_brake"] == vr.PASS


@pytest.mark.parametrize(
    ("platoon", "verdict"),
    [
        ((1, 7.0, 0), vr.PASS),
        ((1, None, 0), vr.PASS),
        ((2, 7.0, 0), vr.FAIL),
        ((1, 4.9, 0), vr.FAIL),
        ((1, 7.0, 1), vr.FAIL),  # one lane, the truck between its CAVs: split, not intact
    ],
)
def test_give_up_is_clean_only_with_the_platoon_intact(platoon, verdict):
    gave_up = _summary(
        overtake__all_past=False, overtake__all_past_regrouped=False, overtake__aborted=1
    )
    assert _judge(gave_up, platoon)["overtake"] == verdict
    # Not completed and no give-up: a failure, whatever the platoon looks like.
    stuck = _summary(overtake__all_past=False, overtake__all_past_regrouped=False)
    assert _judge(stuck, (1, 7.0, 0))["overtake"] == vr.FAIL
    assert _judge(stuck, (1, 7.0, 0), status="failed")["ran"] == vr.FAIL
    assert _judge(_summary(), cacc=None)["ran"] == vr.NA  # its cacc run has not finished


def test_platoon_at_end_reads_the_last_step():
    rows = [
        # time, kind, lane, front s, length
        (1.0, "cav", 2, 50.0, 5.0),  # an earlier step is ignored
        (2.0, "cav", 1, 100.0, 5.0),
        (2.0, "cav", 1, 88.0, 5.0),  # 7 m behind the first
        (2.0, "hv", 1, 120.0, 12.0),
        (2.0, "cav", 1, 76.5, 5.0),  # 6.5 m behind the second
    ]
    df = pd.DataFrame(rows, columns=["time_s", "kind", "lane", "s_m", "length_m"])
    assert vr.platoon_at_end(df) == (1, 6.5, 0)  # the HV drives ahead of them
    df.loc[4, "lane"] = 0
    assert vr.platoon_at_end(df) == (2, 7.0, 0)
    df.loc[4, "lane"] = 1
    df.loc[3, "s_m"] = 82.0  # now between the second CAV and the third
    assert vr.platoon_at_end(df) == (1, 6.5, 1)


def test_lateral_holds_from_summary_else_events(tmp_path):
    assert vr.lateral_holds({"overtake": {"lateral_holds": 3}}, tmp_path) == 3
    assert vr.lateral_holds({}, tmp_path) is None
    lines = [{"event": "lateral_hold"}, {"event": "overtake_start"}, {"event": "lateral_hold"}]
    (tmp_path / "events.jsonl").write_text("\n".join(json.dumps(e) for e in lines) + "\n")
    assert vr.lateral_holds({}, tmp_path) == 2


def test_stress_report_counts_lateral_holds_and_spreads(tmp_path):
    run = tmp_path / "runs" / "r1"
    run.mkdir(parents=True)
    (run / "events.jsonl").write_text('{"event": "lateral_hold"}\n{"event": "lateral_hold"}\n')
    from_events = pd.Series({"run_id": "r1", "overtake.lateral_holds": float("nan")})
    assert sr.lateral_holds(tmp_path, from_events) == 2.0
    from_summary = pd.Series({"run_id": "r1", "overtake.lateral_holds": 5})
    assert sr.lateral_holds(tmp_path, from_summary) == 5.0
    assert pd.isna(sr.lateral_holds(tmp_path, pd.Series({"run_id": "none"})))
    values = pd.Series([0.0] * 19 + [100.0, float("nan")])
    assert sr.spread(values) == "0 / 5 / 100"  # median, p95 (interpolated), max
    assert sr.spread(pd.Series([float("nan")])) == "n/a"


def test_cavs_past_counts_each_cav_whose_rear_was_ever_ahead_of_the_truck():
    # A truck with its front at 100 + 10 t m; c0 (5 m long) at 80 + 25 t has its rear 5 m
    # ahead of the truck's front at t = 2 (125 > 120 m), not at t = 1 (100 < 110 m); c1 stays
    # behind the truck.
    rows = []
    for t in (0.0, 1.0, 2.0):
        rows.append({"time_s": t, "vehicle": "hv_target", "kind": "hv", "s_m": 100 + 10 * t,
                     "length_m": 10.0})  # fmt: skip
        rows.append({"time_s": t, "vehicle": "c0", "kind": "cav", "s_m": 80 + 25 * t,
                     "length_m": 5.0})  # fmt: skip
        rows.append({"time_s": t, "vehicle": "c1", "kind": "cav", "s_m": 70 + 10 * t,
                     "length_m": 5.0})  # fmt: skip
    df = pd.DataFrame(rows)
    assert vr.cavs_past(df) == (1, 2)
    assert vr.cavs_past(df[df["vehicle"] != "c0"]) == (0, 1)


def test_sumo_lc_figures_split_the_failing_scenes_by_what_sumo_lc_did():
    table = pd.DataFrame({
        "overtake": [vr.PASS, vr.FAIL, vr.FAIL, vr.FAIL],
        "sumo_lc_all_past": [True, True, False, None],
        "cavs_past": [3, 5, 6, 2],
        "sumo_lc_cavs_past": [3, 5, 1, None],
        "mean_speed_mps": [18.0, 16.0, 15.0, 14.0],
        "mean_speed_sumo_lc_mps": [17.0, 15.0, 13.0, None],
    })  # fmt: skip
    got = dict(vr._sumo_lc_figures(table))  # the last scene, sumo-lc not known, left out
    assert got["scenes where sumo-lc got every CAV past the truck"] == "2 of 3"
    assert got["failing the overtake check: sumo-lc got every CAV past / did not"] == "1 / 1"
    assert got["CAVs past the truck, swarm / sumo-lc (sum over those scenes)"] == "14 / 9"
    assert got["mean CAV speed, swarm / sumo-lc [m/s]"] == "16.33 / 15.00"
    assert vr._sumo_lc_figures(table.assign(sumo_lc_all_past=None)) == []


def test_hardest_cav_brake_is_the_cavs_most_negative_sample():
    df = pd.DataFrame({
        "kind": ["cav", "cav", "hv", "cav"],
        "accel_mps2": [-1.2, 0.8, -6.0, -3.7],  # the HV's -6 is not a CAV's
    })  # fmt: skip
    assert vr.hardest_cav_brake(df) == -3.7
    assert vr.hardest_cav_brake(df[df["kind"] == "hv"]) is None


def test_brake_figures_name_the_scenes_near_the_hard_brake_line():
    table = pd.DataFrame({"scene": [0, 1, 2, 3], "cav_min_accel_mps2": [-1.0, -3.5, -3.49, None]})
    near = "scenes with a CAV braking at 3.5 m/s^2 or harder"
    got = dict(vr._brake_figures(table))
    assert got["hardest CAV braking over all scenes [m/s^2]"] == -3.5
    assert got[near] == "1"
    assert dict(vr._brake_figures(table.iloc[[0]]))[near] == "none"
    assert vr._brake_figures(table.iloc[[3]]) == []


def test_report_exits_2_on_a_folder_that_is_not_a_batch(tmp_path, capsys):
    assert vr.main([str(tmp_path), "--to", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "sweep.json" in err


# --------------------------------------------------------------------------- real runs


@pytest.fixture(scope="module")
def variant_table(tmp_path_factory) -> pd.DataFrame:
    """The seeded scenes, each under swarm and cacc, judged by tools/variants_report.py."""
    folder = tmp_path_factory.mktemp("variants")
    sweep = folder / "variants.toml"
    cases = mv.draw(SEED, SCENES)
    # Issue 11's per-scene acceptance is of the paper's trigger (decide = "paper"); the weighing
    # is judged by the family's distribution (variants_report.family_verdict, issue 51).
    text = mv.render(cases, SEED, base=str(ROOT / "scenarios" / "paper.toml"))
    sweep.write_text(text.replace("[fixed]\n", '[fixed]\n"swarm.decide" = "paper"\n', 1))
    report = run_batch(sweep, folder / "out", workers=2, progress=False, impact=False)
    assert report.failed == 0
    table = vr.scene_table(folder / "out")
    assert len(table) == SCENES
    print("\n" + vr.render(table, folder / "out"))  # shown with -s: the whole verdict
    # The report's own tables go into the batch folder unless --to says otherwise.
    assert vr.main([str(folder / "out")]) in (0, 1)
    assert (folder / "out" / "variants.md").is_file()
    assert (folder / "out" / "variants.csv").is_file()
    return table


# What every variant must do in CI: run, stay safe, keep within its limits, never be slower than
# the plain platoon. Whether it also completes the overtake within the run, at <= 3x the cost of
# cacc and within the planner's time budget, is issue 11's acceptance measure: judged by
# tools/variants_report.py over the 40-scene sweep (docs/bench/variants.md), not asserted here.
ASSERTED = ("ran", "no_collision", "min_gap", "max_speed", "blocked_hv_brake", "mean_speed")


@pytest.mark.sumo
@pytest.mark.parametrize("check", ASSERTED)
def test_every_variant_passes(variant_table, check):
    table = variant_table
    failing = table[table[check] != vr.PASS]
    shown = ["scene", *vr.SCENE_COLUMNS.values(), check, *_NUMBERS.get(check, ())]
    assert failing.empty, f"{check}: {len(failing)}/{len(table)} scenes do not pass\n" + failing[
        shown
    ].to_string(index=False)


_NUMBERS = {
    "overtake": ("overtake_how",),
    "no_collision": ("collisions",),
    "min_gap": ("gap_min_m",),
    "max_speed": ("cav_max_speed_mps", "max_speed_limit_mps"),
    "blocked_hv_brake": ("blocked_hv_min_accel_mps2", "b_safe_mps2"),
    "mean_speed": ("mean_speed_mps", "mean_speed_cacc_mps"),
    "run_cost": ("wall_s", "wall_cacc_s", "cost_ratio"),
    "planner_p95": ("solve_ms_p95", "replans", "lateral_holds"),
    "planner_max": ("solve_ms_max", "replans"),
}


def _family(gains_pct):
    cacc = 20.0
    return pd.DataFrame({
        "mean_speed_cacc_mps": [cacc] * len(gains_pct),
        "mean_speed_mps": [cacc * (1 + g / 100) for g in gains_pct],
    })  # fmt: skip


def test_a_family_is_judged_by_its_distribution():
    # mean 13.25 %, one scene 0.5 % below cacc (within 1 %), none 5 % below: passes
    good = vr.family_verdict(_family([20, 20, 20, 20, 10, 10, 10, 10, 13, -0.5] * 2))
    assert set(good["verdict"]) - {""} == {vr.PASS}
    got = dict(zip(good["measure"], good["value"], strict=True))
    assert got["mean gain over cacc [%]"] == pytest.approx(13.25)
    assert got["worst gain over cacc [%]"] == pytest.approx(-0.5)


@pytest.mark.parametrize(
    ("gains", "failing"),
    [
        ([11.0] * 20, "mean gain over cacc [%]"),  # every scene wins, the mean too little
        ([14.0] * 18 + [-2.0, -2.0], "share within 1 % of cacc or better"),  # 90 % within
        ([15.0] * 39 + [-6.0], "worst gain over cacc [%]"),  # one scene 6 % below
    ],
)
def test_each_family_bound_fails_on_its_own(gains, failing):
    verdict = vr.family_verdict(_family(gains))
    failed = verdict.loc[verdict["verdict"] == vr.FAIL, "measure"].tolist()
    assert failed == [failing]


def test_a_family_without_speeds_fails():
    verdict = vr.family_verdict(pd.DataFrame({"mean_speed_mps": [float("nan")]}))
    assert (verdict["verdict"] == vr.FAIL).any()
