"""Batch sweeps: sweep files, stable run ids, local and Ray runs, resume after kill -9, failures.

The SUMO tests run short scenes (20-40 s of simulated time) with the fast controllers; one
swarm run keeps the paper's method in the loop.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from sumo_swarm.cli import main
from sumo_swarm.errors import ConfigError
from sumo_swarm.sim.network import EDGES_FILE
from sumo_swarm.study.batch import find_case, load_sweep, run_batch
from sumo_swarm.study.impact import flow_density, markdown_table

ROOT = Path(__file__).resolve().parent.parent
PAPER = (ROOT / "scenarios" / "paper.toml").as_posix()


def batch_command(sweep: Path, out: Path, workers: int) -> list[str]:
    args = ["batch", str(sweep), "--out", str(out), "--workers", str(workers)]
    return [sys.executable, "-m", "sumo_swarm", *args]


def short(duration_s: float) -> str:
    return f'[fixed]\n"simulation.duration_s" = {duration_s}\n"evaluation.end_s" = {duration_s}\n'


@pytest.fixture
def sweep_file(tmp_path: Path):
    def write(body: str, name: str = "sweep.toml") -> Path:
        path = tmp_path / name
        path.write_text(f'base = "{PAPER}"\n{body}', encoding="utf-8")
        return path

    return write


def finished_runs(out: Path) -> dict[str, int]:
    """run id -> mtime (ns) of its `done` marker, for the published run folders (a run writes
    `done` in a hidden folder, then renames it: between a listing and a stat the hidden one may
    be gone, which failed this helper once in CI-like load)."""
    found = {}
    for d in (out / "runs").iterdir():
        if d.name.startswith("."):
            continue
        try:
            found[d.name] = (d / "done").stat().st_mtime_ns
        except FileNotFoundError:
            continue
    return found


def unfinished(out: Path) -> list[str]:
    return [d.name for d in (out / "runs").iterdir() if d.name.startswith(".")]


# --------------------------------------------------------------------------- sweep files


@pytest.mark.parametrize(
    ("body", "fragments"),
    [
        ('[grid]\n"scene.initial_sped_mps" = [1.0]\n', ["scene.initial_sped_mps"]),
        ('[grid]\n"scene.initial_speed_mps" = ["fast"]\n', ["scene.initial_speed_mps", "fast"]),
        ('[grid]\n"scene.initial_speed_mps" = 3.0\n', ["scene.initial_speed_mps", "list"]),
        ('[grid]\n"scene.initial_speed_mps" = [-1.0]\n', ["scene.initial_speed_mps", ">= 0"]),
        ("[[cases]]\nscene.hv.hv_nope.speed_mps = 3.0\n", ["scene.hv.hv_nope.speed_mps"]),
        ("colour = 1\n", ["colour"]),
        ('controllers = ["magic"]\n', ["controllers", "magic"]),
        ("seeds = [1.5]\n", ["seeds"]),
        ("seeds = [42, -5]\n", ["seeds[1] must be an integer >= 0"]),
        ('[grid]\n"cav.accel_min_mps2" = [nan]\n', ["cav.accel_min_mps2", "finite"]),
        ('[fixed]\n"simulation.duration_s" = 20.0\n', ["simulation.duration_s", "end_s"]),
        ("[grid]\nsimulation.seed = [1]\n", ["simulation.seed"]),
    ],
)
def test_bad_sweep_file_exits_2_naming_key_and_file(sweep_file, tmp_path, capsys, body, fragments):
    path = sweep_file(body)
    assert main(["batch", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    for fragment in [str(path), *fragments]:
        assert fragment in err[0]
    assert not (tmp_path / "out").exists()


def test_missing_base_and_missing_sweep(tmp_path, capsys):
    sweep = tmp_path / "s.toml"
    sweep.write_text('base = "nope.toml"\n')
    assert main(["batch", str(sweep), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "base" in err and "nope.toml" in err and str(sweep) in err
    assert main(["batch", str(tmp_path / "none.toml"), "--out", str(tmp_path / "o")]) == 2
    assert "none.toml" in capsys.readouterr().err
    assert main(["impact", str(tmp_path)]) == 2


def test_markdown_table_formats_numbers_flags_and_missing_values():
    df = pd.DataFrame(
        {
            "controller": ["swarm", "cacc"],
            "runs": [2, 3],
            "speed": [17.456, math.nan],
            "overtaken": [True, False],
        }
    )
    lines = markdown_table(df, digits=2).splitlines()
    assert [c.strip() for c in lines[0].strip("|").split("|")] == list(df.columns)
    assert [c.strip() for c in lines[2].strip("|").split("|")] == ["swarm", "2", "17.46", "yes"]
    assert [c.strip() for c in lines[3].strip("|").split("|")] == ["cacc", "3", "-", "no"]


def test_a_scenario_file_is_not_a_sweep(paper_path, tmp_path, capsys):
    assert main(["batch", str(paper_path), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(paper_path) in err[0], err
    assert "is a scenario file, not a sweep" in err[0]
    assert not (tmp_path / "o").exists()


def test_runs_are_the_product_with_stable_ids(sweep_file):
    path = sweep_file(
        'controllers = ["cacc", "swarm"]\nseeds = [1, 2]\n'
        '[grid]\n"cav.count" = [4, 6]\n'
        '[[cases]]\n"scene.hv.hv_target.speed_mps" = 16\n'
        '"scene.hv.hv_target.desired_speed_mps" = 16\n'
        "[[cases]]\n"
    )
    sweep = load_sweep(path)
    assert sweep.parameters == (
        "cav.count",
        "scene.hv.hv_target.speed_mps",
        "scene.hv.hv_target.desired_speed_mps",
    )
    assert len(sweep.runs) == 2 * 2 * 2 * 2
    assert len({r.run_id for r in sweep.runs}) == len(sweep.runs)
    # The empty case keeps the base's value, read back from the validated scenario.
    assert {r.params["scene.hv.hv_target.speed_mps"] for r in sweep.runs} == {16.0, 17.5}
    target = sweep.runs[0].overrides["scene"]["hv"][0]
    assert target["id"] == "hv_target" and target["speed_mps"] == 16
    # Ids depend on the values, not on how they are written (16 and 16.0), nor on file order.
    again = load_sweep(
        sweep_file(
            'seeds = [2, 1]\ncontrollers = ["swarm", "cacc"]\n'
            "[grid]\ncav.count = [6, 4]\n"
            '[[cases]]\n"scene.hv.hv_target.desired_speed_mps" = 16.0\n'
            '"scene.hv.hv_target.speed_mps" = 16.0\n'
            "[[cases]]\n",
            name="again.toml",
        )
    )
    assert {r.run_id for r in again.runs} == {r.run_id for r in sweep.runs}
    assert sweep.runs[0].run_id.startswith("cacc-s1-4-16-16-")


def test_flow_density_points_are_per_lane(tmp_path):
    # Two hand-made runs' edge data: a 3-lane edge at 60 veh/km (20 per lane) carrying
    # 3600 veh/h is 1200 veh/h per lane; an interval nobody drove (density 0) is no point.
    edges = pd.DataFrame({
        "begin_s": [0.0, 60.0, 0.0], "end_s": [60.0, 120.0, 60.0], "edge": ["a", "a", "ramp"],
        "sampled_s": [1.0, 0.0, 1.0], "speed_mps": [16.7, np.nan, 20.0],
        "density_veh_per_km": [60.0, 0.0, 10.0], "lane_density_veh_per_km": [20.0, 0.0, 10.0],
        "flow_veh_per_h": [3600.0, np.nan, 720.0], "entered": [1, 0, 1], "left": [1, 0, 1],
        "distance_m": [1.0, 0.0, 1.0],
    })  # fmt: skip
    for run_id in ("r1", "r2"):
        (tmp_path / "runs" / run_id).mkdir(parents=True)
        edges.to_parquet(tmp_path / "runs" / run_id / EDGES_FILE)
    runs = pd.DataFrame(
        {
            "run_id": ["r1", "r2", "r3"],
            "controller": ["swarm", "cacc", "cacc"],
            "p": [0.1, 0.2, 0.2],
        }
    )
    points = flow_density(tmp_path, runs, "p")  # r3 has no edge data: no points
    assert len(points) == 4
    assert points["flow_veh_per_h_lane"].tolist() == pytest.approx([1200.0, 720.0] * 2)
    assert points["density_veh_per_km_lane"].tolist() == pytest.approx([20.0, 10.0] * 2)
    assert points.groupby("controller")["value"].first().to_dict() == {
        "cacc": "0.2", "swarm": "0.1",
    }  # fmt: skip
    assert flow_density(tmp_path, runs.iloc[2:], None).empty


def test_repeated_case_is_refused(sweep_file):
    path = sweep_file('[[cases]]\n"cav.count" = 4\n[[cases]]\n"cav.count" = 4.0\n')
    with pytest.raises(ConfigError, match="repeat"):
        load_sweep(path)


# --------------------------------------------------------------------------- real runs


@pytest.mark.sumo
def test_local_sweep_results_impact_and_rerun(sweep_file, tmp_path, capsys):
    path = sweep_file(
        'controllers = ["cacc", "swarm"]\n[grid]\n"scene.initial_speed_mps" = [16.0, 17.5]\n'
        + short(20.0)
    )
    out = tmp_path / "out"
    report = run_batch(path, out, workers=2, progress=False)
    assert (report.ran, report.skipped, report.failed) == (4, 0, 0)

    df = pd.read_parquet(out / "results.parquet")
    assert len(df) == 4 and df["run_id"].is_unique
    assert list(df.columns[:6]) == [
        "scene.initial_speed_mps",
        "controller",
        "seed",
        "run_id",
        "status",
        "error",
    ]
    assert set(df["status"]) == {"ok"} and df["error"].isna().all()
    assert sorted(df["scene.initial_speed_mps"]) == [16.0, 16.0, 17.5, 17.5]
    for column in (
        "cav.mean_speed_mps",
        "safety.collisions",
        "overtake.completed",
        "overtake.all_past",
        "upstream.first_follower_reduction_pct",
        "upstream.hv_influenced",
        "timing.wall_s",
        "run.peak_rss_mb",
        "network.delay_s.cav",
        "network.co2_g_per_km.hv",
        "swarms.overtakes_started",
    ):
        assert column in df.columns, column
    swarm = df[df["controller"] == "swarm"]
    assert "planner.solves" in df.columns and swarm["planner.solves"].notna().all()
    for run_id in df["run_id"]:
        folder = out / "runs" / run_id
        for name in ("done", "record.json", "summary.json", "trajectories.parquet"):
            assert (folder / name).is_file(), (run_id, name)
        summary = json.loads((folder / "summary.json").read_text())
        row = df[df["run_id"] == run_id].iloc[0]
        assert row["cav.mean_speed_mps"] == pytest.approx(summary["cav"]["mean_speed_mps"])
    assert len(pd.read_parquet(out / "upstream.parquet")) > 0

    impact = out / "impact"
    for name in (
        "impact.md",
        "mobility.csv",
        "upstream.csv",
        "safety.csv",
        "runs.csv",
        "mobility_vs_scene_initial_speed_mps.png",
        "upstream_vs_scene_initial_speed_mps.png",
        "network.csv",
        "network_vs_scene_initial_speed_mps.png",
        "speed_field.csv",
        "speed_field.png",
        "flow_density.csv",
        "flow_density.png",
        "safety.png",
    ):
        assert (impact / name).is_file(), name
    points = pd.read_csv(impact / "flow_density.csv")
    assert set(points["controller"]) == {"cacc", "swarm"} and set(points["value"]) == {16.0, 17.5}
    assert (points["flow_veh_per_h_lane"] > 0).all()
    # the network table: per value and controller, the mean over its runs of each class's delay
    network = pd.read_csv(impact / "network.csv")
    row = network[(network["controller"] == "swarm") & (network["value"] == 16.0)].iloc[0]
    runs_16 = df[(df["controller"] == "swarm") & (df["scene.initial_speed_mps"] == 16.0)]
    assert row["network.delay_s.hv"] == pytest.approx(runs_16["network.delay_s.hv"].mean())
    assert "## Network, from SUMO's outputs" in (impact / "impact.md").read_text()
    fields = pd.read_csv(impact / "speed_field.csv")
    assert set(fields["controller"]) == {"cacc", "swarm"}
    assert set(fields["value"]) == {16.0, 17.5}  # a field per swept value
    assert fields["speed_mps"].between(5.0, 30.0).all()
    mobility = pd.read_csv(impact / "mobility.csv")
    cacc = mobility[mobility["controller"] == "cacc"]
    assert cacc["gain.mean_speed_pct"].tolist() == pytest.approx([0.0, 0.0])
    assert mobility[mobility["controller"] == "swarm"]["gain.mean_speed_pct"].notna().all()

    # The same command again: nothing runs, nothing changes.
    before = finished_runs(out)
    capsys.readouterr()
    assert main(["batch", str(path), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "0 run now, 4 skipped" in printed
    assert re.search(r"^\| swarm +\|", printed, re.MULTILINE), printed
    assert finished_runs(out) == before
    assert len(pd.read_parquet(out / "results.parquet")) == 4


@pytest.mark.sumo
def test_resume_after_kill_9_loses_and_duplicates_nothing(sweep_file, tmp_path):
    path = sweep_file(
        'controllers = ["cacc", "sumo-cacc"]\n[grid]\n'
        '"scene.initial_speed_mps" = [16.0, 17.0, 17.5]\n' + short(40.0)
    )
    out = tmp_path / "out"
    proc = subprocess.Popen(
        batch_command(path, out, workers=2),
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 120
    try:
        while time.monotonic() < deadline:
            if (out / "runs").is_dir() and finished_runs(out) and unfinished(out):
                break
            assert proc.poll() is None, "the batch ended before it could be killed"
            time.sleep(0.02)
        else:
            pytest.fail("no run finished while another was under way")
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the batch and its workers, as in a crash
        proc.wait()
    before = finished_runs(out)
    assert 1 <= len(before) < 6

    report = run_batch(path, out, workers=2, progress=False, impact=False)
    assert report.skipped == len(before) and report.ran == 6 - len(before)
    after = finished_runs(out)
    assert len(after) == 6 and not unfinished(out)
    assert {k: after[k] for k in before} == before  # finished runs were not redone
    df = pd.read_parquet(out / "results.parquet")
    assert len(df) == 6 and df["run_id"].is_unique and set(df["status"]) == {"ok"}
    assert set(df["run_id"]) == set(after)


@pytest.mark.sumo
def test_failed_run_is_recorded_and_the_batch_goes_on(sweep_file, tmp_path, capsys):
    # A network without lane shapes passes the scenario checks (edges and lane counts are
    # there) but SUMO cannot build it: the run fails at run time.
    net = (ROOT / "networks" / "highway3.net.xml").read_text(encoding="utf-8")
    broken = tmp_path / "broken.net.xml"
    broken.write_text(re.sub(r' shape="[^"]*"', "", net), encoding="utf-8")
    path = sweep_file(
        f'controllers = ["cacc"]\n[[cases]]\n"simulation.network" = "{broken.as_posix()}"\n'
        "[[cases]]\n" + short(20.0)
    )
    out = tmp_path / "out"
    assert main(["batch", str(path), "--out", str(out)]) == 1
    df = pd.read_parquet(out / "results.parquet")
    bad = df["simulation.network"] == broken.as_posix()
    assert df.loc[~bad, "status"].tolist() == ["ok"] and df.loc[~bad, "error"].isna().all()
    assert df.loc[bad, "status"].tolist() == ["failed"]
    error = df.loc[bad, "error"].iloc[0]
    # SUMO's own reason, on the file it is about (libsumo says only "Process Error")
    assert f"{broken}: SUMO refuses it: Attribute 'shape' is missing" in error
    assert "\n" not in error
    assert "1 failed" in capsys.readouterr().out
    failed_dir = out / "runs" / df.loc[bad, "run_id"].iloc[0]
    assert "Traceback" in (failed_dir / "worker.log").read_text()
    # Failed runs count as finished; --retry-failed runs them again.
    report = run_batch(path, out, progress=False, impact=False)
    assert (report.ran, report.skipped, report.failed) == (0, 2, 1)
    report = run_batch(path, out, progress=False, impact=False, retry_failed=True)
    assert (report.ran, report.skipped, report.failed) == (1, 1, 1)


@pytest.mark.sumo
def test_bad_records_are_redone_with_a_warning_naming_the_file(sweep_file, tmp_path, caplog):
    path = sweep_file(
        'controllers = ["cacc", "sumo-cacc"]\n[grid]\n"scene.initial_speed_mps" = [16.0, 17.5]\n'
        + short(4.0)
    )
    out = tmp_path / "out"
    run_batch(path, out, workers=2, progress=False, impact=False)
    ids = sorted(finished_runs(out))
    assert len(ids) == 4
    records = {i: out / "runs" / i / "record.json" for i in ids}
    good = records[ids[3]].read_text()
    records[ids[0]].write_text(records[ids[1]].read_text())  # another run's record
    records[ids[1]].write_text("{}")
    records[ids[2]].write_text("[]")
    before = finished_runs(out)

    with caplog.at_level("WARNING", logger="sumo_swarm.study.batch.store"):
        report = run_batch(path, out, workers=2, progress=False, impact=False)
    assert (report.ran, report.skipped, report.failed) == (3, 1, 0)
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    for i in ids[:3]:
        assert any(str(records[i]) in w and "redone" in w for w in warned), (i, warned)
    assert "another run's record" in next(w for w in warned if str(records[ids[0]]) in w)
    df = pd.read_parquet(out / "results.parquet")
    assert sorted(df["run_id"]) == ids  # each run once, none missing
    assert set(df["status"]) == {"ok"} and df["cav.mean_speed_mps"].notna().all()
    for i in ids:
        assert json.loads(records[i].read_text())["run_id"] == i
    assert records[ids[3]].read_text() == good and finished_runs(out)[ids[3]] == before[ids[3]]


def test_record_problems_are_named():
    from sumo_swarm.study.batch.store import RECORD_SCHEMA, record_problem
    from sumo_swarm.study.batch.sweep import RunSpec

    spec = RunSpec("cacc-s1-x", "/base.toml", {}, {}, 1, "cacc")
    summary = {"schema": "sumo-swarm/summary/1", "controller": "cacc"}
    ok = {"schema": RECORD_SCHEMA, "run_id": "cacc-s1-x", "status": "ok", "error": None,
          "controller": "cacc", "seed": 1, "params": {}, "summary": summary, "run": {}}  # fmt: skip
    assert record_problem(ok, "cacc-s1-x", spec) is None
    assert record_problem({**ok, "status": "failed", "summary": None}, "cacc-s1-x", spec) is None
    cases = [
        ([], "a JSON list"),
        ({}, "schema None"),
        ({**ok, "run_id": "swarm-s1-y"}, "another run's record (run_id"),
        ({**ok, "seed": 2}, "another run's record (seed"),
        ({**ok, "controller": "swarm"}, "another run's record (controller"),
        ({**ok, "status": "done"}, "status 'done'"),
        ({**ok, "summary": None}, "without a summary"),
        ({**ok, "summary": []}, "not a sumo-swarm summary"),
        ({**ok, "summary": {**summary, "controller": "swarm"}}, "controller 'swarm'"),
        ({**ok, "error": 3}, "error is not a text"),
        ({**ok, "params": [1]}, "params is not"),
    ]
    for record, fragment in cases:
        problem = record_problem(record, "cacc-s1-x", spec)
        assert problem is not None and fragment in problem, (record, problem)


@pytest.mark.sumo
def test_worker_killed_mid_run_is_a_failed_run(sweep_file, tmp_path):
    path = sweep_file('controllers = ["cacc", "sumo-cacc"]\n' + short(60.0))
    out = tmp_path / "out"
    proc = subprocess.Popen(
        batch_command(path, out, workers=1),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 60
        while not ((out / "runs").is_dir() and unfinished(out)):
            assert time.monotonic() < deadline and proc.poll() is None
            time.sleep(0.02)
        worker_pid = int(unfinished(out)[0].split(".")[-2])  # .<run_id>.<host>.<pid>.<token>
        os.kill(worker_pid, signal.SIGKILL)
        assert proc.wait(timeout=120) == 1
    finally:
        if proc.poll() is None:
            proc.kill()
    df = pd.read_parquet(out / "results.parquet")
    assert sorted(df["status"]) == ["failed", "ok"]
    assert "SIGKILL" in df.loc[df["status"] == "failed", "error"].iloc[0]


@pytest.mark.sumo
def test_ray_backend_on_a_local_instance(sweep_file, tmp_path):
    import ray

    path = sweep_file(
        'controllers = ["cacc", "sumo-cacc"]\n[grid]\n"cav.count" = [4]\n' + short(20.0)
    )
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        report = run_batch(path, tmp_path / "out", ray="auto", progress=False)
        assert ray.is_initialized()  # the caller's Ray is left as it was
    finally:
        ray.shutdown()
    assert (report.ran, report.failed) == (2, 0)
    df = pd.read_parquet(tmp_path / "out" / "results.parquet")
    assert sorted(df["controller"]) == ["cacc", "sumo-cacc"]
    assert set(df["status"]) == {"ok"} and (df["cav.count"] == 4).all()
    assert df["run.pid"].nunique() == 2  # a fresh worker process per run


def test_find_case_picks_the_run_of_a_case_by_its_place_in_the_file():
    path = ROOT / "scenarios" / "variants.toml"
    listed = tomllib.loads(path.read_text())["cases"]
    run = find_case(path, 3, "cacc")
    assert run.controller == "cacc"
    assert run.params == pytest.approx(listed[3])
    assert find_case(path, 3).controller == "swarm" and find_case(path, 3).params == run.params
    with pytest.raises(ConfigError, match="no case 40"):
        find_case(path, len(listed))
    with pytest.raises(ConfigError, match="has no lqr run"):
        find_case(path, 0, "lqr")
