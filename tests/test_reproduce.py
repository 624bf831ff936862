"""`sumo-swarm reproduce`: every controller on the paper scene, report and figures (real SUMO)."""

from __future__ import annotations

import json
import re
import tomllib
from pathlib import Path

import pandas as pd
import pytest

from sumo_swarm.config import load_scenario
from sumo_swarm.errors import ConfigError
from sumo_swarm.metrics import EvaluationWindow
from sumo_swarm.plots import FIGURES
from sumo_swarm.reproduce import default_scenario_path, paired_upstream, reproduce, targets
from tests.conftest import PAPER, ROOT
from tests.contract import assert_summary_contract

# The paper scene, cut to 60 s (the manoeuvre is over by about 36 s): keeps the test short.
SHORT = {"simulation": {"duration_s": 60.0}, "evaluation": {"end_s": 60.0}}
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
CONTROLLERS = ("swarm", "cacc", "sumo-cacc", "sumo-lc")
FORMULA = object()  # a row computed by a formula over summary values: checked on its own


@pytest.fixture(scope="module")
def reproduction(tmp_path_factory):
    out = tmp_path_factory.mktemp("reproduce")
    report = reproduce(out, PAPER, overrides=SHORT, progress=False, workers=2)
    return out, report


def _summary(out: Path, controller: str) -> dict:
    return json.loads((out / "runs" / controller / "summary.json").read_text(encoding="utf-8"))


def _from_source(source: str, s: dict):
    """Read the number a report row names as its source out of a summary."""
    if m := re.fullmatch(r"upstream\[lane=(\d+), rank=(\d+)\]\.(\w+)", source):
        lane, rank, key = int(m[1]), int(m[2]), m[3]
        hits = [e[key] for e in s["upstream"] if e["lane"] == lane and e["rank"] == rank]
        return hits[0] if hits else None
    if m := re.fullmatch(r"min of upstream\[\]\.(\w+)", source):
        values = [e[m[1]] for e in s["upstream"] if e[m[1]] is not None]
        return min(values) if values else None
    if re.fullmatch(r"\w+\.\w+", source):
        block, key = source.split(".")
        return s[block][key]
    return FORMULA


@pytest.mark.sumo
def test_every_run_finishes_with_the_contract(reproduction):
    out, report = reproduction
    assert report["complete"] is True
    assert report["controllers"] == list(CONTROLLERS)
    for c in CONTROLLERS:
        assert report["runs"][c]["status"] == "ok", report["runs"][c]["error"]
        assert report["runs"][c]["dir"] == f"runs/{c}"
        assert_summary_contract(_summary(out, c))
        assert (out / "runs" / c / "trajectories.parquet").is_file()
    assert (out / "runs" / "swarm" / "plans.jsonl").is_file()


@pytest.mark.sumo
def test_report_files_and_every_figure_are_written(reproduction):
    out, report = reproduction
    on_disk = json.loads((out / "report.json").read_text(encoding="utf-8"))
    assert on_disk == json.loads(json.dumps(report))
    md = (out / "report.md").read_text(encoding="utf-8")
    assert report["figure_errors"] == {}
    assert set(report["figures"]) == set(FIGURES)
    for name in FIGURES:
        png = out / f"{name}.png"
        assert png.stat().st_size > 10_000, name
        assert png.read_bytes()[:8] == PNG_MAGIC
        assert f"]({name}.png)" in md  # a relative link
    assert "## Where we differ from the paper and why" in md
    assert not list(out.glob("*.tmp")) and not list(out.glob("*.tmp.png"))


@pytest.mark.sumo
def test_table_has_the_contract_columns_and_every_measure(reproduction):
    _, report = reproduction
    assert report["columns"] == ["measure", "paper", *CONTROLLERS]
    keys = {r["key"] for r in report["rows"]}
    for key in ("cav.mean_speed", "cav.mobility_gain", "cav.min_speed", "cav.max_speed",
                "cav.speed_var", "cav.travel_time", "cav.gap_mean", "cav.gap_min",
                "cav.gap_excess", "upstream.reduction.lane2.rank1", "upstream.influenced.lane2",
                "upstream.min_gap", "upstream.min_headway", "overtake.behaving_steps",
                "overtake.duration_s", "safety.collisions", "safety.hard_brakes"):  # fmt: skip
        assert key in keys
    for row in report["rows"]:
        assert set(row) >= set(report["columns"])
        assert row["definition"] in report["definitions"]
    paper = {r["key"]: r["paper"] for r in report["rows"]}
    assert paper["cav.mean_speed"] == 19.43
    assert paper["cav.mobility_gain"] == 12.04
    assert paper["upstream.reduction.lane2.rank1"] == 2.19
    assert paper["overtake.behaving_steps"] == 14
    # The report's upstream rows are the paired ones; summary.json's own are the secondary table.
    basis = {r["key"]: r["basis"] for r in report["rows"]}
    assert basis["upstream.reduction.lane2.rank1"] == "paired"
    assert basis["upstream.influenced.lane2"] == "paired"
    assert basis["cav.mean_speed"] == "summary"
    secondary = {r["key"]: r for r in report["upstream_summary_rows"]}
    assert {"upstream.summary.reduction.lane2.rank1", "upstream.summary.influenced.lane2"} <= set(
        secondary
    )
    assert all(r["basis"] == "summary" and r["paper"] is None for r in secondary.values())


@pytest.mark.sumo
def test_numbers_equal_those_in_the_summaries(reproduction):
    out, report = reproduction
    summaries = {c: _summary(out, c) for c in CONTROLLERS}
    checked = 0
    for row in report["rows"] + report["upstream_summary_rows"]:
        if row["basis"] == "paired":  # from the trajectories: see the next test
            continue
        for c in CONTROLLERS:
            expected = _from_source(row["source"], summaries[c])
            if expected is FORMULA:
                continue
            assert row[c] == expected, (row["key"], c)
            checked += 1
    assert checked >= 4 * 30
    rows = {r["key"]: r for r in report["rows"]}
    base = summaries["cacc"]["cav"]["mean_speed_mps"]
    for c in CONTROLLERS:
        s = summaries[c]
        gain = (s["cav"]["mean_speed_mps"] / base - 1) * 100
        assert rows["cav.mobility_gain"][c] == pytest.approx(gain, rel=1e-12)
        excess = (s["cav"]["gap_mean_m"] / 10.0 - 1) * 100
        assert rows["cav.gap_excess"][c] == pytest.approx(excess, rel=1e-12)
        ot = s["overtake"]
        if ot["t_regrouped_s"] is not None:
            assert rows["overtake.duration_s"][c] == pytest.approx(
                ot["t_regrouped_s"] - ot["t_start_s"]
            )
        else:
            assert rows["overtake.duration_s"][c] is None
        influenced = sum(e["speed_reduction_pct"] > 0.1 for e in s["upstream"] if e["lane"] == 2)
        secondary = {r["key"]: r for r in report["upstream_summary_rows"]}
        assert secondary["upstream.summary.influenced.lane2"][c] == influenced


@pytest.mark.sumo
def test_paired_upstream_rows_equal_a_recomputation_from_the_trajectories(reproduction):
    """Each upstream HV's minimum speed against its own in the cacc run, read straight from the
    parquet files, over the swarm's decision to the window end, for every controller."""
    out, report = reproduction
    rows = {r["key"]: r for r in report["rows"]}
    summaries = {c: _summary(out, c) for c in CONTROLLERS}
    t0, t1 = summaries["swarm"]["overtake"]["t_start_s"], SHORT["evaluation"]["end_s"]
    assert report["upstream_window_s"] == [t0, t1]

    def slowest(c: str) -> pd.Series:
        df = pd.read_parquet(out / "runs" / c / "trajectories.parquet")
        df = df[(df["time_s"] >= t0 - 1e-6) & (df["time_s"] <= t1 + 1e-6)]
        return df.groupby(df["vehicle"].astype(str))["speed_mps"].min()

    base = slowest("cacc")
    checked = 0
    for c in CONTROLLERS:
        own = slowest(c)
        per_lane: dict[int, int] = {}
        for e in summaries[c]["upstream"]:
            lane, rank, vid = e["lane"], e["rank"], e["vehicle"]
            expected = max(0.0, (base[vid] - own[vid]) / base[vid] * 100)
            row = rows[f"upstream.reduction.lane{lane}.rank{rank}"]
            assert row[c] == pytest.approx(expected, abs=1e-9), (c, vid)
            assert row["vehicles"][c] == vid
            per_lane[lane] = per_lane.get(lane, 0) + (expected > 0.1)
            checked += 1
        for lane, count in per_lane.items():
            assert rows[f"upstream.influenced.lane{lane}"][c] == count
    assert checked >= 4 * 15
    # The baseline against itself: every paired reduction is 0, nobody is influenced.
    cacc = [r["cacc"] for k, r in rows.items() if k.startswith("upstream.") and "lane" in k]
    assert cacc and all(v == 0 for v in cacc if v is not None)
    # Rank 1 in a side lane is the HV the swarm blocks; the targets read the paired rows.
    assert rows["upstream.reduction.lane2.rank1"]["vehicles"]["swarm"] == "hv_left"
    assert rows["upstream.reduction.lane0.rank1"]["vehicles"]["swarm"] == "hv_right"
    goals = {t["target"]: t for t in report["targets"]}
    first = max(rows[f"upstream.reduction.lane{q}.rank1"]["swarm"] for q in range(3))
    assert goals["first following HV's speed reduction (paired) <= 5 % in every lane"][
        "value"
    ] == pytest.approx(first)
    most = max(rows[f"upstream.influenced.lane{q}"]["swarm"] for q in range(3))
    assert goals["upstream HVs influenced (paired, > 0.1 %) <= 5 in every lane"]["value"] == most


@pytest.mark.sumo
def test_swarm_is_faster_than_the_cacc_platoon(reproduction):
    _, report = reproduction
    rows = {r["key"]: r for r in report["rows"]}
    assert rows["cav.mobility_gain"]["swarm"] > 0
    assert rows["cav.mobility_gain"]["cacc"] == 0
    assert rows["overtake.completed"]["swarm"] is True
    assert rows["overtake.completed"]["cacc"] is False
    targets = {t["target"]: t for t in report["targets"]}
    assert targets["zero collisions"]["met"] is True
    assert targets["mobility gain over cacc >= 10 %"]["value"] == rows["cav.mobility_gain"]["swarm"]


@pytest.mark.sumo
def test_a_failed_run_is_reported_and_the_others_finish(tmp_path):
    # A file where the run's output folder should be: that run cannot start; the other can.
    (tmp_path / "runs").mkdir()
    (tmp_path / "runs" / "sumo-lc").write_text("in the way", encoding="utf-8")
    short = {"simulation": {"duration_s": 15.0}, "evaluation": {"end_s": 15.0}}
    report = reproduce(
        tmp_path, PAPER, overrides=short, progress=False, controllers=("cacc", "sumo-lc")
    )
    assert report["runs"]["cacc"]["status"] == "ok"
    assert report["runs"]["sumo-lc"]["status"] == "failed"
    assert "cannot be written" in report["runs"]["sumo-lc"]["error"]
    rows = {r["key"]: r for r in report["rows"]}
    assert rows["cav.mean_speed"]["cacc"] == _summary(tmp_path, "cacc")["cav"]["mean_speed_mps"]
    assert rows["cav.mean_speed"]["sumo-lc"] is None
    # No swarm run: its figures are reported missing, the baseline's numbers are still there.
    assert "fig7_plan" in report["figure_errors"]
    md = (tmp_path / "report.md").read_text(encoding="utf-8")
    assert "| sumo-lc | failed |" in md
    assert json.loads((tmp_path / "report.json").read_text())["runs"]["sumo-lc"]["error"]


def _frame(samples: list[tuple[float, str, float]]) -> pd.DataFrame:
    return pd.DataFrame(samples, columns=["time_s", "vehicle", "speed_mps"])


def test_paired_upstream_by_hand():
    summary = {"upstream": [
        {"lane": 2, "rank": 1, "vehicle": "a", "speed_reduction_pct": 9.0},
        {"lane": 2, "rank": 2, "vehicle": "b", "speed_reduction_pct": 1.0},
        {"lane": 0, "rank": 1, "vehicle": "gone", "speed_reduction_pct": 0.0},
    ]}  # fmt: skip
    # Baseline: a at 20 m/s, b at 10 m/s (b's 5 m/s sample lies before the window).
    base = _frame([(0.0, "a", 20.0), (1.0, "a", 20.0), (0.0, "b", 5.0), (1.0, "b", 10.0),
                   (1.0, "gone", 10.0)])  # fmt: skip
    # This run: a slows to 19 m/s (5 %), b never below 11 m/s (faster: 0, not negative).
    run = _frame([(0.0, "a", 1.0), (1.0, "a", 19.0), (2.0, "a", 20.0), (1.0, "b", 11.0)])
    rows = paired_upstream(summary, run, base, EvaluationWindow(1.0, 2.0), blocked=["a"])
    assert [(r["lane"], r["rank"], r["vehicle"], r["role"]) for r in rows] == [
        (2, 1, "a", "blocked"), (2, 2, "b", "upstream"), (0, 1, "gone", "upstream")]  # fmt: skip
    assert rows[0]["speed_reduction_pct"] == pytest.approx(5.0)
    assert rows[0]["undisturbed_speed_mps"] == 20.0 and rows[0]["min_speed_mps"] == 19.0
    assert rows[0]["summary_reduction_pct"] == 9.0
    assert rows[1]["speed_reduction_pct"] == 0.0
    assert rows[2]["speed_reduction_pct"] is None  # not in this run's window
    assert paired_upstream({"upstream": None}, run, base, EvaluationWindow(1.0, 2.0)) is None


def test_upstream_targets_take_the_worst_lane():
    def row(key, value, vehicle=None):
        r = {"key": key, "swarm": value}
        return r | {"vehicles": {"swarm": vehicle}} if vehicle else r

    rows = [row("upstream.reduction.lane2.rank1", 0.5, "hv_left"),
            row("upstream.reduction.lane1.rank1", 1.3, "up1_1"),
            row("upstream.reduction.lane1.rank10", 9.0, "up1_10"),  # not a first follower
            row("upstream.influenced.lane2", 6), row("upstream.influenced.lane1", 6),
            row("upstream.influenced.lane0", 1)]  # fmt: skip
    goals = {t["target"].split(" (")[0]: t for t in targets(rows, wall_s=None)}
    first = goals["first following HV's speed reduction"]
    assert (first["value"], first["where"], first["met"]) == (1.3, "lane 1, up1_1", True)
    influenced = goals["upstream HVs influenced"]
    assert (influenced["value"], influenced["where"], influenced["met"]) == (6, "lane 2; lane 1",
                                                                             False)  # fmt: skip
    assert goals["whole reproduction within 180 s"]["met"] is None


def test_bad_arguments_are_refused_before_any_run(tmp_path):
    with pytest.raises(ConfigError, match="unknown controller 'nope'"):
        reproduce(tmp_path, PAPER, controllers=("swarm", "nope"), progress=False)
    with pytest.raises(ConfigError, match="workers"):
        reproduce(tmp_path, PAPER, workers=0, progress=False)
    with pytest.raises(ConfigError, match="not found"):
        reproduce(tmp_path, tmp_path / "missing.toml", progress=False)
    assert not (tmp_path / "report.json").exists()


def test_default_scenario_is_the_paper_scenario():
    assert default_scenario_path() == PAPER.resolve()


def test_shipped_copy_of_the_paper_scenario_matches_the_repository():
    """sumo_swarm/data/ serves installs without the source tree: it must not drift."""
    data = ROOT / "sumo_swarm" / "data"
    repo = tomllib.loads(PAPER.read_text(encoding="utf-8"))
    shipped = tomllib.loads((data / "paper.toml").read_text(encoding="utf-8"))
    assert shipped["simulation"].pop("network") == "highway3.net.xml"
    repo["simulation"].pop("network")
    assert shipped == repo
    net = (data / "highway3.net.xml").read_bytes()
    assert net == (ROOT / "networks" / "highway3.net.xml").read_bytes()
    sc = load_scenario(data / "paper.toml")
    assert sc.network_path == (data / "highway3.net.xml").resolve()
