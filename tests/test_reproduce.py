"""`sumo-swarm reproduce`: every controller on the paper scene, report and figures (real SUMO)."""

from __future__ import annotations

import json
import re
import tomllib
from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest

from sumo_swarm.config import load_scenario
from sumo_swarm.errors import ConfigError
from sumo_swarm.sim.metrics import EvaluationWindow
from sumo_swarm.study.plots import FIGURES
from sumo_swarm.study.reproduce import (
    PROOF_WORK,
    ReproRun,
    default_scenario_path,
    reproduce,
    swarm_changes,
)
from sumo_swarm.study.reproduce_rows import paired_upstream, targets
from sumo_swarm.study.reproduce_text import capped_paragraph
from tests.conftest import PAPER, ROOT
from tests.contract import assert_summary_contract

# The paper scene, cut to 60 s (the manoeuvre is over by about 36 s): keeps the test short.
SHORT = {"simulation": {"duration_s": 60.0}, "evaluation": {"end_s": 60.0}}
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
CONTROLLERS = ("swarm", "cacc", "sumo-cacc", "sumo-lc", "swarm-capped")  # the report's runs
# The swarm's runs decide at the start, as the paper's (IV-E-1), where the scenario keeps the
# swarm's own timing.
AT_ZERO = {"swarm.start_after_s": 0.0, "swarm.trigger_after_s": 0.0}
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
        assert report["runs"][c]["wall_s"] > 0
    assert (out / "runs" / "swarm" / "plans.jsonl").is_file()


@pytest.mark.sumo
def test_report_files_and_every_figure_are_written(reproduction):
    out, report = reproduction
    on_disk = json.loads((out / "report.json").read_text(encoding="utf-8"))
    assert on_disk == json.loads(json.dumps(report))
    md = (out / "report.md").read_text(encoding="utf-8")
    assert report["figure_errors"] == {}
    assert set(report["figures"]) == {*FIGURES, "manoeuvre"}
    clip = out / report["figures"]["manoeuvre"]  # the replay of the swarm run's manoeuvre
    assert clip.read_bytes()[:6] in (b"GIF87a", b"GIF89a") and "](manoeuvre.gif)" in md
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
    assert checked >= len(CONTROLLERS) * 30
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
    assert checked >= len(CONTROLLERS) * 15
    # The baseline against itself: every paired reduction is 0, nobody is influenced.
    cacc = [r["cacc"] for k, r in rows.items() if k.startswith("upstream.") and "lane" in k]
    assert cacc and all(v == 0 for v in cacc if v is not None)
    # Rank 1 in a side lane is the HV the swarm blocks; the targets read the paired rows.
    assert rows["upstream.reduction.lane2.rank1"]["vehicles"]["swarm"] == "hv_left"
    assert rows["upstream.reduction.lane0.rank1"]["vehicles"]["swarm"] == "hv_right"
    goals = {t["target"]: t for t in report["targets"]}
    first = max(rows[f"upstream.reduction.lane{q}.rank1"]["swarm"] for q in range(3))
    assert goals["first following HV's speed reduction (paired) in every lane <= 5 %"][
        "value"
    ] == pytest.approx(first)
    most = max(rows[f"upstream.influenced.lane{q}"]["swarm"] for q in range(3))
    assert goals["upstream HVs influenced (paired, > 0.1 %) in every lane <= 5"]["value"] == most


@pytest.mark.sumo
def test_swarm_is_faster_than_the_cacc_platoon(reproduction):
    _, report = reproduction
    rows = {r["key"]: r for r in report["rows"]}
    assert rows["cav.mobility_gain"]["swarm"] > 0
    assert rows["cav.mobility_gain"]["cacc"] == 0
    assert rows["overtake.completed"]["swarm"] is True
    assert rows["overtake.completed"]["cacc"] is False
    targets = {t["target"]: t for t in report["targets"]}
    assert targets["collisions == 0"]["met"] is True
    assert targets["mobility gain over cacc >= 10 %"]["value"] == rows["cav.mobility_gain"]["swarm"]


@pytest.mark.sumo
def test_every_plan_of_the_paper_scene_is_proven_optimal(reproduction):
    # The reproduction gives the swarm the network search's proof budget (PROOF_WORK): with
    # the default budget the third plan of the paper scene stays 0.26 % above its bound.
    out, report = reproduction
    assert report["runs"]["swarm"]["changes"] == {"planner.network_work": PROOF_WORK, **AT_ZERO}
    statuses = _summary(out, "swarm")["planner"]["statuses"]
    assert statuses and set(statuses) == {"optimal"}


@pytest.mark.sumo
def test_the_swarm_decides_at_the_start_as_the_papers(reproduction):
    # "At time 0s, the platoon makes an overtaking decision" (IV-E-1): the first step the
    # controller acts on (the paper scene's step is 0.03 s), not after its own 1 s + 2 s.
    out, _ = reproduction
    for run in ("swarm", "swarm-capped"):
        assert _summary(out, run)["overtake"]["t_start_s"] == pytest.approx(0.03)


def test_a_scenario_with_its_own_decision_timing_keeps_it():
    sc = load_scenario(PAPER)
    assert swarm_changes(sc) == {**AT_ZERO, "planner.network_work": PROOF_WORK}
    for key in ("start_after_s", "trigger_after_s"):  # either one set: both kept
        own = replace(sc, swarm=replace(sc.swarm, **{key: 5.0}))
        assert swarm_changes(own) == {"planner.network_work": PROOF_WORK}


@pytest.mark.sumo
def test_capped_run_is_a_column_with_what_the_cap_costs(reproduction):
    out, report = reproduction
    cruise = load_scenario(PAPER).cav.cruising_speed_mps
    run = report["runs"]["swarm-capped"]
    assert run["controller"] == "swarm"
    assert run["changes"] == {"cav.max_speed_mps": cruise, "planner.network_work": PROOF_WORK,
                              **AT_ZERO}  # fmt: skip
    record = json.loads((out / "runs" / "swarm-capped" / "record.json").read_text())
    assert record["overrides"]["cav"]["max_speed_mps"] == cruise
    rows = {r["key"]: r for r in report["rows"]}
    # The cap holds in SUMO (the vType's maxSpeed), the default swarm goes beyond it.
    assert rows["cav.max_speed"]["swarm-capped"] <= cruise + 1e-6
    assert rows["cav.max_speed"]["swarm"] > cruise
    md = (out / "report.md").read_text(encoding="utf-8")
    assert "## CAVs capped at the cruising speed" in md
    (text,) = report["capped"]
    assert text in md
    capped, free = rows["cav.mean_speed"]["swarm-capped"], rows["cav.mean_speed"]["swarm"]
    assert f"({capped:.2f} vs {free:.2f} m/s, {(capped / free - 1) * 100:+.1f} %" in text
    a, b = rows["overtake.duration_s"]["swarm-capped"], rows["overtake.duration_s"]["swarm"]
    if a is not None:
        assert f"the regrouped platoon: {a:.1f} s vs {b:.1f} s ({a - b:+.1f} s)" in text
    else:
        assert f"the regrouped platoon: not reached in the run (swarm: {b:.1f} s)" in text


@pytest.mark.sumo
def test_targets_and_sentences_read_the_scenario_and_a_failed_run_is_reported(
    reproduction, tmp_path
):
    """Another scenario (headway, minimum gap, step, cells, upstream spacing changed) changes
    the targets and the sentences that state them; a run SUMO cannot start is reported failed
    and the other finishes."""
    _, paper = reproduction
    bad_net = tmp_path / "bad.net.xml"  # the road's edge, but none of its junctions
    lanes = "".join(
        f'<lane id="hwy_{q}" index="{q}" speed="33.33" length="3000" width="3" '
        f'shape="0,{-7.5 + 3 * q} 3000,{-7.5 + 3 * q}"/>'
        for q in range(3)
    )
    bad_net.write_text(f'<net><edge id="hwy" from="a" to="b">{lanes}</edge></net>')
    changed = {
        "simulation": {"duration_s": 15.0, "step_length_s": 0.05},
        "evaluation": {"end_s": 15.0},
        "hv": {"headway_s": 1.5},
        "cav": {"min_gap_m": 4.0},
        "cell": {"rule": "fixed", "cell_length_m": 7.5},
        "scene": {"upstream_gap_m": 30.0},
    }
    broken = ReproRun("broken", "cacc", lambda sc: {"simulation.network": str(bad_net)})
    out = tmp_path / "rep"
    report = reproduce(out, PAPER, overrides=changed, progress=False, runs=("cacc", broken))
    assert report["runs"]["cacc"]["status"] == "ok"
    assert report["runs"]["broken"]["status"] == "failed"
    # SUMO refuses the network ("Unknown from-node"); libsumo has also been seen to crash on it:
    # the worker's death is then the error. Either way the run is failed and says why.
    assert re.search(r"Unknown from-node|SIGSEGV", report["runs"]["broken"]["error"])
    rows = {r["key"]: r for r in report["rows"]}
    assert rows["cav.mean_speed"]["cacc"] == _summary(out, "cacc")["cav"]["mean_speed_mps"]
    assert rows["cav.mean_speed"]["broken"] is None
    assert "fig7_plan" in report["figure_errors"]  # no swarm run: nothing to draw it from
    md = (out / "report.md").read_text(encoding="utf-8")
    assert "| broken | cacc | `simulation.network = " in md and "| failed |" in md

    def goals(r: dict) -> dict:
        return {t["target"]: t for t in r["targets"]}

    assert "minimum CAV following distance >= 5 m" in goals(paper)
    assert "minimum upstream time headway >= 1.2 s" in goals(paper)
    ours = goals(report)
    assert ours["minimum CAV following distance >= 4 m"]["origin"].startswith("scenario [cav]")
    assert ours["minimum upstream time headway >= 1.5 s"]["threshold"] == 1.5
    assert "not in the scenario" in ours["mobility gain over cacc >= 10 %"]["origin"]

    def sentence(r: dict, start: str) -> str:
        return next(line for line in r["differences"] if line.startswith(start))

    simulator, geometry = "1. **Simulator.**", "4. **The scene's geometry.**"
    assert "step 0.03 s" in sentence(paper, simulator) and "T = 1.2 s" in sentence(paper, simulator)
    assert "step 0.05 s" in sentence(report, simulator) and "T = 1.5 s" in sentence(
        report, simulator
    )
    assert "start 25 m apart" in sentence(paper, geometry)
    assert "start 30 m apart" in sentence(report, geometry)
    assert sentence(paper, "2. ").startswith("2. **Cell length 15 m, not 5 m**")
    assert sentence(report, "2. ").startswith("2. **Cell length 7.5 m, not 5 m**")
    assert "SUMO step of 0.05 s" in report["definitions"]["speed"]
    # The upstream HVs' rise above their start speed is measured, not asserted: each report
    # says what its cacc run showed (and whether that start is an equilibrium).
    for r in (paper, report):
        rise = r["facts"]["upstream_surge_mps"]["cacc"]
        assert f"the fastest of them rises {rise:.2f} m/s above" in sentence(r, geometry)


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
    goals = {t["target"].split(" (")[0]: t for t in targets(rows, load_scenario(PAPER), None)}
    first = goals["first following HV's speed reduction"]
    assert (first["value"], first["where"], first["met"]) == (1.3, "lane 1, up1_1", True)
    influenced = goals["upstream HVs influenced"]
    assert (influenced["value"], influenced["where"], influenced["met"]) == (6, "lane 2; lane 1",
                                                                             False)  # fmt: skip
    assert goals["whole reproduction wall time <= 180 s"]["met"] is None


def test_bad_arguments_are_refused_before_any_run(tmp_path):
    with pytest.raises(ConfigError, match="unknown run 'nope'"):
        reproduce(tmp_path, PAPER, runs=("swarm", "nope"), progress=False)
    with pytest.raises(ConfigError, match=r"run 'capped': .*max_speed_mps"):
        slow = ReproRun("capped", "swarm", lambda sc: {"cav.max_speed_mps": 1.0})
        reproduce(tmp_path, PAPER, runs=("cacc", slow), progress=False)
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


def test_capped_paragraph_by_hand():
    def row(key, capped, swarm):
        return {"key": key, "swarm-capped": capped, "swarm": swarm}

    ok = {"status": "ok"}
    report = {
        "runs": {"swarm": ok, "swarm-capped": ok},
        "rows": [row("cav.max_speed", 20.0, 24.5), row("cav.mean_speed", 19.0, 20.0),
                 row("cav.mobility_gain", 8.5, 14.25), row("overtake.pass_s", 30.0, 20.5),
                 row("overtake.duration_s", None, 31.0), row("cav.gap_min", 6.0, 5.5),
                 row("safety.collisions", 0, 0)],
    }  # fmt: skip
    (text,) = capped_paragraph(report, load_scenario(PAPER))
    assert (
        "`[cav] max_speed_mps` set to the cruising speed, 20 m/s (the `swarm` run: 25 m/s)" in text
    )
    assert "Its fastest CAV sample is 20.00 m/s (swarm: 24.50 m/s)." in text
    assert "The cap costs 1.00 m/s of platoon average speed (19.00 vs 20.00 m/s, -5.0 %;" in text
    assert "gain over cacc 8.50 vs 14.25 %" in text
    assert "Decision to all CAVs past the slow HV: 30.0 s vs 20.5 s (+9.5 s)." in text
    assert "Decision to the regrouped platoon: not reached in the run (swarm: 31.0 s)." in text
    report["runs"]["swarm-capped"] = {"status": "failed"}
    assert "did not finish" in capped_paragraph(report, load_scenario(PAPER))[0]
    del report["runs"]["swarm-capped"]
    assert capped_paragraph(report, load_scenario(PAPER)) == []


def test_reproduce_has_no_process_pool_of_its_own():
    """Its runs go through the batch backend: no multiprocessing or executor of its own."""
    import ast

    for name in ("reproduce.py", "reproduce_rows.py", "reproduce_text.py"):
        tree = ast.parse((ROOT / "sumo_swarm" / "study" / name).read_text(encoding="utf-8"))
        imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        imported |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        assert not {"multiprocessing", "concurrent.futures", "ray"} & imported, name
