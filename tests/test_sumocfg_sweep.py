"""Studies on a user's own SUMO configuration: the CAV share (derived demand files), SUMO's
--scale and --seed on ``run_sumocfg``, and ``batch``/``impact`` over a sweep file naming a
sumocfg (resumed after kill -9, on Ray). Real SUMO runs of 20-30 s simulated, on a road built
here with netconvert (tests/usercases.py)."""

from __future__ import annotations

import os
import signal
import subprocess
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import pandas as pd
import pytest

from sumo_swarm.cli import main
from sumo_swarm.errors import ConfigError
from sumo_swarm.sim.bridge import sumo_binary
from sumo_swarm.sim.demand import (
    check_share_applies,
    derived_id,
    read_demand,
    shared_members,
    write_shared_demand,
)
from sumo_swarm.sim.runner import SUMO_DEFAULT_SEED, run_sumocfg
from sumo_swarm.study.batch import load_sweep, run_batch
from tests.test_batch import batch_command, finished_runs, unfinished
from tests.usercases import write_mixed_case

ROUTES = """<routes>
    <vType id="car" probability="3"/>
    <vType id="cav" sigma="0"/>
    <vType id="truck" vClass="truck"/>
    <vTypeDistribution id="mix" vTypes="car cav truck" probabilities="0.5 0.3 0.2"/>
    <vTypeDistribution id="plain" vTypes="car cav"/>
    <vTypeDistribution id="nested">
        <vType id="van" probability="2"/>
        <vType id="bus" vClass="bus" probability="2"/>
    </vTypeDistribution>
    <route id="r" edges="e0"/>
    <vehicle id="a" depart="0" route="r"/>
    <flow id="f" type="mix" route="r" begin="0" end="10" number="3"/>
    <flow id="g" type="nested" route="r" begin="0" end="10" number="3"/>
    <trip id="t" type="truck" depart="0" from="e0" to="e0"/>
</routes>
"""


def _demand(tmp_path: Path):
    path = tmp_path / "r.rou.xml"
    path.write_text(ROUTES, encoding="utf-8")
    return path, read_demand([path])


# --------------------------------------------------------------------------- the share (pure)


def test_distribution_share_sets_the_cav_and_rescales_the_others(tmp_path):
    _, demand = _demand(tmp_path)
    new = shared_members(demand, "mix", "cav", 0.6, "distribution")
    # car 0.5 and truck 0.2 share 1 - 0.6 = 0.4 in their old proportion 5:2
    assert new == pytest.approx({"car": 0.4 * 5 / 7, "truck": 0.4 * 2 / 7, "cav": 0.6})
    # without probabilities, each vType's own probability weighs it: car 3, cav 1
    assert demand.members("plain") == pytest.approx({"car": 0.75, "cav": 0.25})
    assert shared_members(demand, "plain", "cav", 0.1, "distribution") == pytest.approx(
        {"car": 0.9, "cav": 0.1}
    )
    assert shared_members(demand, "plain", "cav", 0.0, "distribution") == {"car": 1.0}
    assert shared_members(demand, "plain", "cav", 1.0, "distribution") == {"cav": 1.0}
    # a distribution without the CAV type, and plain types, stay as they are
    assert shared_members(demand, "nested", "cav", 0.6, "distribution") is None
    assert shared_members(demand, "car", "cav", 0.6, "distribution") is None
    # the share that is already there changes nothing
    assert shared_members(demand, "plain", "cav", 0.25, "distribution") is None


def test_passenger_share_turns_passenger_vehicles_into_cavs(tmp_path):
    _, demand = _demand(tmp_path)
    # a vehicle naming no type is SUMO's default passenger car
    assert shared_members(demand, "DEFAULT_VEHTYPE", "cav", 0.3, "passenger") == pytest.approx(
        {"DEFAULT_VEHTYPE": 0.7, "cav": 0.3}
    )
    # the passenger vehicles (car 0.5, cav 0.3) are CAVs with probability 0.5; trucks keep 0.2
    assert shared_members(demand, "mix", "cav", 0.5, "passenger") == pytest.approx(
        {"car": 0.4, "cav": 0.4, "truck": 0.2}
    )
    assert shared_members(demand, "mix", "cav", 0.0, "passenger") == pytest.approx(
        {"car": 0.8, "truck": 0.2}
    )
    assert shared_members(demand, "nested", "cav", 1.0, "passenger") == pytest.approx(
        {"cav": 0.5, "bus": 0.5}
    )
    assert shared_members(demand, "truck", "cav", 1.0, "passenger") is None
    assert shared_members(demand, "cav", "cav", 0.0, "passenger") is None  # placed as a CAV
    assert shared_members(demand, "plain", "cav", 0.25, "passenger") is None  # as it is


def test_derived_file_defines_each_distribution_before_its_first_use(tmp_path):
    path, _ = _demand(tmp_path)
    copies = write_shared_demand([path], tmp_path / "out", "cav", 0.5, "distribution")
    assert list(copies) == [path]
    root = ET.parse(copies[path]).getroot()
    tags = [(e.tag, e.get("id"), e.get("type")) for e in root]
    derived = derived_id("mix")
    at = tags.index(("vTypeDistribution", derived, None))
    assert tags[at + 1] == ("flow", "f", derived)  # just before the flow that draws from it
    dist = root[at]
    assert dist.get("vTypes").split() == ["car", "truck", "cav"]
    assert [float(p) for p in dist.get("probabilities").split()] == pytest.approx(
        [0.5 * 5 / 7, 0.5 * 2 / 7, 0.5]
    )
    # the rest is the user's file as it was
    assert ("vehicle", "a", None) in tags and ("flow", "g", "nested") in tags
    assert ("trip", "t", "truck") in tags
    assert path.read_text(encoding="utf-8") == ROUTES  # the user's file is not touched
    # a share that changes nothing makes no copy
    trucks = tmp_path / "trucks.rou.xml"
    trucks.write_text(
        ROUTES.replace('type="mix"', 'type="truck"').replace('type="nested"', 'type="bus"')
    )
    assert write_shared_demand([trucks], tmp_path / "o2", "cav", 0.3, "distribution") == {}
    assert write_shared_demand([trucks], tmp_path / "o2", "cav", 0.0, "passenger") == {}


def test_a_share_that_cannot_apply_is_refused(tmp_path):
    _, demand = _demand(tmp_path)
    with pytest.raises(ConfigError, match=r"no vType 'robo' in .*vTypes: bus, car, cav"):
        check_share_applies(demand, "robo", "passenger", tmp_path / "x.sumocfg")
    only_trucks = tmp_path / "t.rou.xml"
    only_trucks.write_text(
        '<routes><vType id="cav"/><vType id="lorry" vClass="truck"/>'
        '<route id="r" edges="e0"/><flow id="f" type="lorry" route="r" number="2"/></routes>'
    )
    demand = read_demand([only_trucks])
    with pytest.raises(ConfigError, match=r"no vehicle or flow of .* vClass passenger"):
        check_share_applies(demand, "cav", "passenger", only_trucks)
    with pytest.raises(ConfigError, match="vTypeDistribution holding 'cav'"):
        check_share_applies(demand, "cav", "distribution", only_trucks)


# --------------------------------------------------------------------------- real runs


def _types(run_dir: Path) -> dict[str, str]:
    """vehicle -> vType from a run's tripinfo (departed or not; a controlled CAV's own copy of
    its type, ``cav@<id>``, as ``cav``)."""
    root = ET.parse(run_dir / "sumo" / "tripinfo.xml").getroot()
    return {t.get("id"): t.get("vType").split("@")[0] for t in root.iter("tripinfo")}


def _run(cfg: Path, out: Path, **kwargs) -> dict:
    kwargs.setdefault("require_cavs", False)
    return run_sumocfg(cfg, "cav", "cacc", out, progress=False, notify=lambda _: None, **kwargs)


@pytest.fixture(scope="module")
def road(tmp_path_factory) -> Path:
    return write_mixed_case(tmp_path_factory.mktemp("road"), end_s=30.0, flow_end_s=25.0)


@pytest.mark.sumo
def test_sumo_default_seed_is_sumos():
    template = subprocess.run(
        [sumo_binary(), "--save-template", "-"], capture_output=True, text=True, check=True
    ).stdout
    seed = next(e for e in ET.fromstring(template).iter("seed"))
    assert int(seed.get("value")) == SUMO_DEFAULT_SEED


@pytest.mark.sumo
def test_the_seed_reaches_sumo_and_the_summary_says_it(road, tmp_path):
    one = _run(road, tmp_path / "s1", seed=1)
    again = _run(road, tmp_path / "s1b", seed=1)
    two = _run(road, tmp_path / "s2", seed=2)
    assert (one["seed"], two["seed"]) == (1, 2)
    assert _types(tmp_path / "s1") == _types(tmp_path / "s1b")
    assert _types(tmp_path / "s1") != _types(tmp_path / "s2")
    traj = pd.read_parquet(tmp_path / "s1" / "trajectories.parquet")
    assert traj.equals(pd.read_parquet(tmp_path / "s1b" / "trajectories.parquet"))
    assert one["cav"] == again["cav"]

    # No seed given: SUMO's own default, as plain SUMO runs the file, and the summary says so.
    plain = tmp_path / "plain.xml"
    subprocess.run(
        [sumo_binary(), "-c", str(road), "--tripinfo-output", str(plain),
         "--tripinfo-output.write-undeparted", "true", "--no-step-log", "true"],
        capture_output=True, check=True,
    )  # fmt: skip
    plain_types = {t.get("id"): t.get("vType") for t in ET.parse(plain).getroot()}
    assert main(["run", "--sumocfg", str(road), "--cav-type", "cav", "--controller", "cacc",
                 "--out", str(tmp_path / "default")]) == 0  # fmt: skip
    summary = pd.read_json(tmp_path / "default" / "summary.json", typ="series")
    assert summary["seed"] == SUMO_DEFAULT_SEED
    assert _types(tmp_path / "default") == plain_types

    # The configuration's own seed.
    seeded = road.with_name("seeded.sumocfg")
    seeded.write_text(
        road.read_text().replace(
            "</configuration>",
            '  <random_number>\n    <seed value="2"/>\n  </random_number>\n</configuration>',
        )
    )
    own = _run(seeded, tmp_path / "own")
    assert own["seed"] == 2 and _types(tmp_path / "own") == _types(tmp_path / "s2")

    # A configuration that asks for a seed from the clock gets one drawn here, given to SUMO
    # and reported, so that the run can be repeated.
    clock = road.with_name("clock.sumocfg")
    clock.write_text(
        road.read_text().replace(
            "</configuration>",
            '  <random_number>\n    <random value="true"/>\n  </random_number>\n</configuration>',
        )
    )
    drawn = _run(clock, tmp_path / "clock")["seed"]
    saved = ET.parse(tmp_path / "clock" / "sumo" / "scenario.sumocfg").getroot()
    assert int(next(saved.iter("seed")).get("value")) == drawn
    assert next(saved.iter("random")).get("value") == "false"
    _run(road, tmp_path / "repeat", seed=drawn)
    assert _types(tmp_path / "repeat") == _types(tmp_path / "clock")


@pytest.mark.sumo
def test_the_share_sets_the_number_of_cavs(road, tmp_path):
    base = _types_after(road, tmp_path / "base", seed=5)
    main_flow = [v for v in base if v.startswith("main.")]
    assert len(main_flow) >= 10 and set(base.values()) >= {"car", "cav", "lorry"}
    counts = {}
    for share in (0.0, 0.5, 1.0):
        types = _types_after(road, tmp_path / f"d{share}", seed=5, cav_share=share)
        assert set(types) == set(base)  # the same vehicles, only their types differ
        counts[share] = sum(t == "cav" for t in types.values())
        assert all(types[v] == "lorry" for v in types if not v.startswith("main."))
    assert counts[0.0] == 0 and counts[1.0] == len(main_flow)
    assert 0 < counts[0.5] < len(main_flow)

    # Of all passenger vehicles: every car becomes a CAV at 1, none at 0; lorries stay lorries.
    none = _types_after(road, tmp_path / "p0", seed=5, cav_share=0.0, cav_share_of="passenger")
    assert set(none) == set(base) and "cav" not in none.values()
    assert {v for v, t in none.items() if t == "lorry"} == {
        v for v, t in base.items() if t == "lorry"
    }
    every = _types_after(road, tmp_path / "p1", seed=5, cav_share=1.0, cav_share_of="passenger")
    assert {v for v, t in every.items() if t == "cav"} == set(main_flow)
    summary = pd.read_json(tmp_path / "p1" / "summary.json", typ="series")
    assert summary["cav"]["count"] == sum(1 for t in every.values() if t == "cav")


def _types_after(cfg: Path, out: Path, **kwargs) -> dict[str, str]:
    _run(cfg, out, **kwargs)
    return _types(out)


@pytest.mark.sumo
def test_scale_changes_the_demand(road, tmp_path):
    counts = {}
    for scale in (1.0, 2.0, 0.5):
        summary = _run(road, tmp_path / f"x{scale}", seed=3, scale=scale)
        counts[scale] = summary["network"]["vehicles"]
        assert counts[scale] == len(_types(tmp_path / f"x{scale}"))
    assert counts[2.0] == 2 * counts[1.0]  # every vehicle twice
    assert counts[0.5] < counts[1.0]


# --------------------------------------------------------------------------- sweep files


def _sweep(folder: Path, body: str, cfg: str = "road/road.sumocfg") -> Path:
    path = folder / "study.toml"
    path.write_text(f'sumocfg = "{cfg}"\n{body}', encoding="utf-8")
    return path


@pytest.fixture
def study(tmp_path):
    write_mixed_case(tmp_path / "road", end_s=20.0, flow_end_s=15.0)
    return tmp_path


@pytest.mark.parametrize(
    ("body", "fragments"),
    [
        ('cav_type = "cav"\ncolour = 1\n', ["unknown key 'colour'"]),
        (
            'cav_type = "cav"\ncav_share_of = "distribution"\n[grid]\ncav_share = [0.1, 1.5]\n',
            ['grid."cav_share" = 1.5', "<= 1"],
        ),
        (
            'cav_type = "cav"\ncav_share_of = "distribution"\n[fixed]\ncav_share = -0.1\n',
            ['fixed."cav_share" = -0.1', ">= 0"],
        ),
        ('cav_type = "cab"\n', ["cav_type: no vType 'cab'", "road.sumocfg", "car, cav, lorry"]),
        ("", ["cav_type: missing"]),
        ('cav_type = "cav"\n[grid]\ncav_share = [0.1]\n', ["cav_share_of: missing"]),
        (
            'cav_type = "cav"\ncav_share_of = "trucks"\n[grid]\ncav_share = [0.1]\n',
            ["cav_share_of", "trucks"],
        ),
        ('cav_type = "cav"\n[grid]\n"cav.count" = [4]\n', ["unknown parameter 'cav.count'"]),
        ('cav_type = "cav"\n[grid]\nscale = [1.0, 0.0]\n', ['grid."scale" = 0.0', "> 0"]),
        ('cav_type = "cav"\nbase = "paper.toml"\n', ["base and sumocfg"]),
        (
            'cav_type = "cav"\n[grid]\nscale = [1.0]\n[[cases]]\nscale = 2.0\n',
            ['grid."scale": also set in [[cases]]'],
        ),
        ('cav_type = "cav"\n[fixed]\nscale = 1.0\n[grid]\nscale = [2.0]\n', ["also swept"]),
        (
            'cav_type = "lorry"\ncav_share_of = "distribution"\n[grid]\ncav_share = [0.1]\n',
            ["vTypeDistribution holding 'lorry'"],
        ),
    ],
)
def test_bad_sumocfg_sweep_exits_2_naming_problem_and_file(study, capsys, body, fragments):
    path = _sweep(study, body)
    assert main(["batch", str(path), "--out", str(study / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    for fragment in [str(path), *fragments]:
        assert fragment in err[0], (fragment, err[0])
    assert not (study / "out").exists()


def test_missing_sumocfg_exits_2(study, capsys):
    path = _sweep(study, 'cav_type = "cav"\n', cfg="nowhere/road.sumocfg")
    assert main(["batch", str(path), "--out", str(study / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0]
    assert "sumocfg: file not found" in err[0] and "nowhere/road.sumocfg" in err[0]


def test_sumocfg_sweep_runs_are_the_product_with_stable_ids(study):
    body = (
        'cav_type = "cav"\ncav_share_of = "distribution"\ncontrollers = ["swarm", "cacc"]\n'
        "seeds = [1, 2]\n[grid]\ncav_share = [0.1, 0.3, 0.6]\n[fixed]\nscale = 1\n"
    )
    sweep = load_sweep(_sweep(study, body))
    assert len(sweep.runs) == 12 and len({r.run_id for r in sweep.runs}) == 12
    assert sweep.parameters == ("cav_share",) and sweep.fixed == {"scale": 1.0}
    assert {(r.params["cav_share"], r.seed, r.controller) for r in sweep.runs} == {
        (s, seed, c) for s in (0.1, 0.3, 0.6) for seed in (1, 2) for c in ("swarm", "cacc")
    }
    assert all(r.sumocfg.scale == 1.0 and r.sumocfg.cav_type == "cav" for r in sweep.runs)
    again = load_sweep(_sweep(study, body.replace("scale = 1", "scale = 1.0")))
    assert [r.run_id for r in again.runs] == [r.run_id for r in sweep.runs]
    passenger = load_sweep(_sweep(study, body.replace('"distribution"', '"passenger"')))
    assert not {r.run_id for r in passenger.runs} & {r.run_id for r in sweep.runs}
    # the configuration's own seed (none here: SUMO's default) when the sweep lists none
    assert load_sweep(_sweep(study, 'cav_type = "cav"\n')).seeds == (SUMO_DEFAULT_SEED,)


def test_the_example_sweep_loads():
    sweep = load_sweep(Path(__file__).resolve().parent.parent / "scenarios" / "my-road-sweep.toml")
    assert len(sweep.runs) == 12 and sweep.parameters == ("cav_share",)
    assert sweep.base.kind == "sumocfg" and sweep.to_json()["base_kind"] == "sumocfg"


@pytest.mark.sumo
def test_sumocfg_sweep_resumes_after_kill_9_and_impact_draws_it(study, tmp_path):
    path = _sweep(
        study,
        'cav_type = "cav"\ncav_share_of = "distribution"\ncontrollers = ["swarm", "cacc"]\n'
        "seeds = [1, 2]\n[grid]\ncav_share = [0.1, 0.4, 0.8]\n",
    )
    out = tmp_path / "out"
    proc = subprocess.Popen(
        batch_command(path, out, workers=2),
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.monotonic() + 180
    try:
        while time.monotonic() < deadline:
            if (out / "runs").is_dir() and len(finished_runs(out)) >= 2 and unfinished(out):
                break
            assert proc.poll() is None, "the batch ended before it could be killed"
            time.sleep(0.02)
        else:
            pytest.fail("no run finished while another was under way")
    finally:
        os.killpg(proc.pid, signal.SIGKILL)  # the batch and its workers, as in a crash
        proc.wait()
    before = finished_runs(out)
    assert 2 <= len(before) < 12

    report = run_batch(path, out, workers=2, progress=False, impact=False)
    assert report.skipped == len(before) and report.ran == 12 - len(before)
    after = finished_runs(out)
    assert len(after) == 12 and not unfinished(out)
    assert {k: after[k] for k in before} == before  # finished runs were not redone
    df = pd.read_parquet(out / "results.parquet")
    assert len(df) == 12 and df["run_id"].is_unique and set(df["status"]) == {"ok"}
    assert set(df["run_id"]) == set(after)
    assert list(df.columns[:3]) == ["cav_share", "controller", "seed"]
    assert (df["safety.collisions"] == 0).all()
    # Both controllers meet the same CAVs: SUMO draws them with the seed, before any control.
    counts = df.pivot_table(index=["cav_share", "seed"], columns="controller", values="cav.count")
    assert (counts["swarm"] == counts["cacc"]).all()
    by_share = counts["cacc"].groupby(level="cav_share").sum()
    assert by_share.is_monotonic_increasing and by_share.iloc[0] < by_share.iloc[-1]
    for run_id in df["run_id"]:
        summary = pd.read_json(out / "runs" / run_id / "summary.json", typ="series")
        row = df[df["run_id"] == run_id].iloc[0]
        assert summary["seed"] == row["seed"]
        assert summary["cav"]["count"] == row["cav.count"]

    assert main(["impact", str(out)]) == 0
    impact = out / "impact"
    for name in ("impact.md", "mobility.csv", "mobility_vs_cav_share.png", "safety.png",
                 "upstream_vs_cav_share.png", "network_vs_cav_share.png"):  # fmt: skip
        assert (impact / name).is_file(), name
    mobility = pd.read_csv(impact / "mobility.csv")
    assert set(mobility["value"]) == {0.1, 0.4, 0.8}
    assert mobility[mobility["controller"] == "cacc"]["gain.mean_speed_pct"].tolist() == (
        pytest.approx([0.0, 0.0, 0.0])
    )
    assert mobility[mobility["controller"] == "swarm"]["gain.mean_speed_pct"].notna().all()


@pytest.mark.sumo
def test_sumocfg_sweep_on_ray(study, tmp_path):
    import ray

    path = _sweep(
        study,
        'cav_type = "cav"\ncav_share_of = "passenger"\ncontrollers = ["cacc", "sumo-cacc"]\n'
        "seeds = [4]\n[fixed]\ncav_share = 1.0\nscale = 2\n",
    )
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        report = run_batch(path, tmp_path / "out", ray="auto", progress=False, impact=False)
    finally:
        ray.shutdown()
    assert (report.ran, report.failed) == (2, 0)
    df = pd.read_parquet(tmp_path / "out" / "results.parquet")
    assert sorted(df["controller"]) == ["cacc", "sumo-cacc"] and (df["seed"] == 4).all()
    assert df["cav.count"].nunique() == 1 and df["cav.count"].iloc[0] > 0
    assert df["run.pid"].nunique() == 2


# --------------------------------------------------------------------------- run --sumocfg


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--cav-share", "1.5"], "--cav-share: must be >= 0 and <= 1, got 1.5"),
        (["--cav-share", "nan"], "--cav-share: must be >= 0 and <= 1"),
        (["--scale", "0"], "--scale: must be > 0, got 0"),
        (["--cav-share-of", "trucks"], "--cav-share-of"),
    ],
)
def test_run_share_and_scale_options_refuse_bad_values(road, tmp_path, capsys, args, fragment):
    cmd = ["run", "--sumocfg", str(road), "--cav-type", "cav", "--out", str(tmp_path / "o")]
    assert main([*cmd, *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and fragment in err[0], err
    assert not (tmp_path / "o").exists()


def test_run_share_that_cannot_apply_exits_2_before_any_folder(road, tmp_path, capsys):
    out = tmp_path / "o"
    cmd = ["run", "--sumocfg", str(road), "--cav-type", "lorry", "--cav-share", "0.5"]
    assert main([*cmd, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "vTypeDistribution holding 'lorry'" in err[0] and str(road) in err[0]
    assert not out.exists() and not list(tmp_path.iterdir())


def test_run_share_options_go_with_sumocfg(capsys, tmp_path):
    assert main(["run", "paper.toml", "--cav-share", "0.5", "--out", str(tmp_path)]) == 2
    assert "--cav-share go with --sumocfg" in capsys.readouterr().err


@pytest.mark.sumo
def test_run_sumocfg_with_share_and_scale(road, tmp_path):
    base = _run(road, tmp_path / "base", seed=6)
    cmd = ["run", "--sumocfg", str(road), "--cav-type", "cav", "--controller", "cacc", "--seed"]
    out = tmp_path / "o"
    assert main([*cmd, "6", "--cav-share", "0", "--scale", "2", "--out", str(out)]) == 0
    summary = pd.read_json(out / "summary.json", typ="series")
    assert summary["cav"]["count"] == 0  # no CAV is a result here, not an error
    assert summary["network"]["vehicles"] == 2 * base["network"]["vehicles"]
    assert (out / "sumo" / "demand" / "0_routes.rou.xml").is_file()
