"""tools/corridor_checks.py: an OpenStreetMap motorway built by netconvert and run under the
swarm through the tool, and issue 51's seven checks on hand-made summaries with known answers."""

from __future__ import annotations

import copy
import json
from pathlib import Path
from typing import Any

import pandas as pd
import pytest

from sumo_swarm.safexml import parse_xml
from sumo_swarm.sim.userroads import OSM_TRUCK_SHARE, end_edges, write_osm_road
from tests.toolload import load_tool

cc = load_tool("corridor_checks")


def test_osm_motorway_is_netconverted_with_its_ramps_and_lane_drop(tmp_path):
    cfg = write_osm_road("osm-3-lane-drop", cc.OSM_DIR, tmp_path, end_s=30.0)
    net = parse_xml(tmp_path / "road.net.xml")
    lanes = {
        e.get("id"): len(e.findall("lane"))
        for e in net.iter("edge")
        if e.get("function") != "internal"
    }
    leaving, entering = end_edges(tmp_path / "road.net.xml")
    # from the map's upstream end (node 2001) to its downstream end (2009): 3 lanes, then 2
    assert lanes[leaving["2001"]] == 3 and lanes[entering["2009"]] == 2
    # ramps.guess gave the exit a deceleration lane and the on-ramp an acceleration lane
    assert sorted(n for n in lanes.values()) == [1, 1, 2, 3, 3, 3, 4, 4]
    routes = (tmp_path / "routes.rou.xml").read_text(encoding="utf-8")
    assert 'vTypes="car truck cav" probabilities="0.65 0.15 0.2"' in routes
    assert routes.count('departLane="best" departSpeed="max"') == 3
    assert '<step-length value="0.2"/>' in cfg.read_text(encoding="utf-8")


def test_one_road_runs_under_the_swarm_and_is_kept(tmp_path):
    jobs = cc.plan(["osm-3-lane-drop"], [0.4], [7], 30.0, tmp_path)
    assert [j.controller for j in jobs] == ["swarm", "sumo-cacc", "sumo-lc"]
    job = jobs[0]
    row = cc.run_job(job, force=False, timeout_s=300.0)
    assert row["status"] == "ran", row.get("error")
    assert row["collisions"] == 0 and row["cavs"] > 0
    assert row["throughput_vph"] is not None and row["others_delay_s"] is not None
    # 40 % of all vehicles CAVs, the trucks keeping their 15 %: SUMO draws from the run's copy
    copies = list((job.out / "sumo" / "demand").glob("*.xml"))
    derived = [d for c in copies for d in parse_xml(c).iter("vTypeDistribution")]
    drawn = [d for d in derived if d.get("id").startswith("swarm_share_")]
    assert len(drawn) == 1
    names, weights = drawn[0].get("vTypes").split(), drawn[0].get("probabilities").split()
    share = dict(zip(names, map(float, weights), strict=True))
    assert share["cav"] == pytest.approx(0.4) and share["truck"] == pytest.approx(OSM_TRUCK_SHARE)
    again = cc.run_job(job, force=False, timeout_s=300.0)
    assert again["status"] == "kept" and again["cav_speed_mps"] == row["cav_speed_mps"]


def _summary(collisions=0, speed=20.0, throughput=4000.0, delay=20.0, ttc=30, gap=2.5,
             started=20, aborted=2) -> dict[str, Any]:  # fmt: skip
    return {
        "cav": {"count": 10, "mean_speed_mps": speed, "gap_min_cav_m": gap},
        "safety": {"collisions": collisions},
        "swarms": {"overtakes_started": started, "overtakes_aborted": aborted},
        "network": {"throughput_vph": throughput, "delay_s_others": delay,
                    "ttc_below_1_5s_events": ttc},
    }  # fmt: skip


# Every check passes, each on a margin that the wrong baseline would turn: 0.97 x 20.5 = 19.885
# <= 20; 0.98 x 4050 (the better throughput) = 3969 <= 4000; 1.05 x 19.5 (the better, lower
# delay) = 20.475 >= 20; 35 (the worse TTC count) >= 30; 2 of 20 aborted is 10 %.
BASE = {
    "swarm": _summary(),
    "sumo-cacc": _summary(speed=19.0, throughput=3900.0, delay=22.0, ttc=20, started=0, aborted=0),
    "sumo-lc": _summary(speed=20.5, throughput=4050.0, delay=19.5, ttc=35, started=0, aborted=0),
}

FAILING = [
    ("collisions", "swarm", "safety.collisions", 1),
    ("cav_speed", "swarm", "cav.mean_speed_mps", 18.9),  # below sumo-cacc's 19
    ("cav_speed", "sumo-lc", "cav.mean_speed_mps", 21.0),  # 20 < 0.97 x 21 = 20.37
    ("throughput", "swarm", "network.throughput_vph", 3960.0),  # < 3969
    ("others_delay", "swarm", "network.delay_s_others", 20.6),  # > 20.475
    ("ttc", "swarm", "network.ttc_below_1_5s_events", 36),  # > 35
    ("cav_gap", "swarm", "cav.gap_min_cav_m", 1.9),
    ("aborted", "swarm", "swarms.overtakes_aborted", 3),  # 15 % of 20
]


def _verdicts(summaries: dict[str, dict[str, Any]]) -> dict[str, str]:
    return {c.key: c.verdict for c in cc.judge({k: cc.measures(s) for k, s in summaries.items()})}


def _with(key: str, controller: str, dotted: str, value: Any) -> dict[str, dict[str, Any]]:
    summaries = copy.deepcopy(BASE)
    block, name = dotted.split(".")
    summaries[controller][block][name] = value
    return summaries


def test_every_check_passes_on_its_margin():
    assert _verdicts(BASE) == {key: cc.PASS for key, _ in cc.CHECKS}


@pytest.mark.parametrize(("key", "controller", "dotted", "value"), FAILING)
def test_each_check_fails_alone(key, controller, dotted, value):
    verdicts = _verdicts(_with(key, controller, dotted, value))
    assert verdicts == {k: (cc.FAIL if k == key else cc.PASS) for k, _ in cc.CHECKS}


def test_no_cav_behind_a_cav_passes_and_a_missing_baseline_is_not_judged():
    assert _verdicts(_with("cav_gap", "swarm", "cav.gap_min_cav_m", None))["cav_gap"] == cc.PASS
    runs = {k: cc.measures(s) for k, s in BASE.items()}
    verdicts = {c.key: c.verdict for c in cc.judge({**runs, "sumo-lc": None})}
    # the checks against a baseline cannot be judged without it; the swarm's own can
    assert verdicts == {
        "collisions": cc.PASS, "cav_speed": cc.NA, "throughput": cc.NA, "others_delay": cc.NA,
        "ttc": cc.NA, "cav_gap": cc.PASS, "aborted": cc.PASS,
    }  # fmt: skip
    # without the swarm's run, nothing is judged
    assert {c.verdict for c in cc.judge({**runs, "swarm": None})} == {cc.NA}


def test_a_failed_run_is_a_row_with_its_error():
    rows = []
    for controller, summary in BASE.items():
        rows.append({"road": "r", "share": 0.2, "seed": 1, "controller": controller,
                     "status": "ran", **cc.measures(summary)})  # fmt: skip
    rows[2] = {"road": "r", "share": 0.2, "seed": 1, "controller": "sumo-lc", "status": "failed",
               "error": "exit 1: boom"}  # fmt: skip
    wide, shown = cc.judged(pd.DataFrame(rows))
    assert wide.loc[0, "passed"] == 3 and wide.loc[0, "errors"] == "sumo-lc: exit 1: boom"
    assert shown.loc[0, "passed"] == "3/7"
    text = cc.report(wide, shown, "cmd", "abc", 30.0)
    assert "Checks passed: 3 / 7" in text and "CAV speed" in text


def _rows(seed: int, summaries: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    return [
        {"road": "r", "share": 0.2, "seed": seed, "controller": c, "status": "ran",
         **cc.measures(s)}
        for c, s in summaries.items()
    ]  # fmt: skip


def test_a_road_and_share_is_judged_on_its_seeds_together():
    # Seed 1 is BASE (every check passes on its margin). Seed 2: the swarm's others' delay
    # 21.0 (> 1.05 x 19.5: its own check fails), 1 of 20 aborted, a CAV-CAV gap of 2.1 m; the
    # TTC counts 30 / 20 / 35 again. Together: the mean delay 20.5 is above 1.05 x 19.5 =
    # 20.475 (fail, one seed of two passing); 3 of 40 aborted (pass); the smallest gap 2.1 m;
    # TTC 60 against the worse baseline's sum, 70.
    second = copy.deepcopy(BASE)
    second["swarm"]["network"]["delay_s_others"] = 21.0
    second["swarm"]["swarms"]["overtakes_aborted"] = 1
    second["swarm"]["cav"]["gap_min_cav_m"] = 2.1
    runs = pd.DataFrame(_rows(1, BASE) + _rows(2, second))
    wide, _ = cc.judged(runs)
    roads = cc.judged_by_road(runs, wide)
    row = roads.iloc[0]
    assert row["seeds"] == 2 and row["passed"] == 6
    assert row["check.others_delay"] == cc.FAIL and row["seeds_passing.others_delay"] == 0.5
    assert row["check.others_delay.detail"] == "20.50 <= 1.05 x 19.50"
    assert row["check.aborted.detail"] == "3 of 40" and row["check.aborted"] == cc.PASS
    assert row["check.cav_gap.detail"] == "2.10 m" and row["check.ttc.detail"] == "60 <= 70"
    # A seed a baseline failed in is left out of the comparisons, not out of the swarm's own
    # checks: its 3 collisions and 0.5 m gap fail the road.
    failed = _rows(3, BASE)
    failed[2] = {"road": "r", "share": 0.2, "seed": 3, "controller": "sumo-lc",
                 "status": "failed", "error": "boom"}  # fmt: skip
    runs = pd.DataFrame(_rows(1, BASE) + failed)
    wide, shown = cc.judged(runs)
    roads = cc.judged_by_road(runs, wide)
    assert roads.iloc[0]["seeds"] == 1 and roads.iloc[0]["passed"] == 7
    assert roads.iloc[0]["failed_runs"] == 1
    text = cc.report(wide, shown, "cmd", "abc", 30.0, roads=roads)
    assert "Checks passed, per road and share: 7 / 7" in text
    failed[0] = {**failed[0], "collisions": 3, "cav_cav_gap_min_m": 0.5}
    runs = pd.DataFrame(_rows(1, BASE) + failed)
    wide, _ = cc.judged(runs)
    row = cc.judged_by_road(runs, wide).iloc[0]
    assert (row["check.collisions"], row["check.collisions.detail"]) == (cc.FAIL, "swarm 3")
    assert (row["check.cav_gap"], row["check.cav_gap.detail"]) == (cc.FAIL, "0.50 m")
    assert row["check.throughput"] == cc.PASS and row["passed"] == 5
    failed[0] = _rows(3, BASE)[0]
    # A swarm run that failed leaves the road unjudged, however well the other seeds did.
    failed[0] = {**failed[0], "status": "failed", "error": "boom"}
    failed[2] = _rows(3, BASE)[2]
    runs = pd.DataFrame(_rows(1, BASE) + failed)
    wide, _ = cc.judged(runs)
    roads = cc.judged_by_road(runs, wide)
    assert roads.iloc[0]["passed"] == 0 and roads.iloc[0]["check.ttc"] == cc.NA


def test_others_delay_of_an_older_summary_comes_from_its_trips(tmp_path: Path):
    trips = pd.DataFrame(
        {"vehicle_class": ["cav", "hv", "truck"], "time_loss_s": [50.0, 10.0, 20.0],
         "depart_delay_s": [0.0, 2.0, 4.0]}
    )  # fmt: skip
    trips.to_parquet(tmp_path / "network_trips.parquet")
    older = copy.deepcopy(BASE["swarm"])
    del older["network"]["delay_s_others"]
    assert cc.measures(older, tmp_path)["others_delay_s"] == pytest.approx(18.0)
    assert cc.measures(older)["others_delay_s"] is None


def test_a_kept_run_whose_controller_stood_down_is_a_failed_row(tmp_path: Path):
    job = cc.Job("r", 0.2, 1, "swarm", ("x.toml",), tmp_path / "swarm")
    job.out.mkdir()
    stood_down = {"t_s": 264.0, "reason": "IndexError: boom", "then": "fallback"}
    summary = {**BASE["swarm"], "complete": True, "stood_down": stood_down}
    (job.out / "summary.json").write_text(json.dumps(summary), encoding="utf-8")
    row = cc.run_job(job, force=False, timeout_s=1.0)  # kept: not run again
    assert row["status"] == "failed" and "264.00 s" in row["error"] and "IndexError" in row["error"]
    assert row["cav_speed_mps"] == 20.0  # its measures stay for the runs' table, not judged
    rows = [row] + [{"road": "r", "share": 0.2, "seed": 1, "controller": c, "status": "ran",
                     **cc.measures(BASE[c])} for c in cc.BASELINES]  # fmt: skip
    wide, _ = cc.judged(pd.DataFrame(rows))
    assert wide.loc[0, "passed"] == 0 and "stood down" in wide.loc[0, "errors"]
