"""The baselines on the paper scene, through real SUMO (libsumo)."""

from __future__ import annotations

import json

import pandas as pd
import pytest

from sumo_swarm.config import load_scenario
from sumo_swarm.sim.runner import run_scenario
from tests.contract import TRAJECTORY_COLUMNS, assert_summary_contract

pytestmark = pytest.mark.sumo


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Each baseline once on the paper scenario (about 2 s of wall time each)."""
    from tests.conftest import PAPER

    sc = load_scenario(PAPER)
    out = {}
    for controller in ("cacc", "sumo-cacc", "sumo-lc"):
        folder = tmp_path_factory.mktemp(controller)
        run_scenario(sc, controller, folder, progress=False)
        out[controller] = folder
    return out


@pytest.mark.parametrize("controller", ["cacc", "sumo-cacc", "sumo-lc"])
def test_runs_to_the_end_with_every_contract_key(runs, controller):
    folder = runs[controller]
    summary = json.loads((folder / "summary.json").read_text())
    assert_summary_contract(summary)
    assert summary["controller"] == controller
    assert summary["sim_end_s"] == pytest.approx(80.0, abs=0.05)
    assert summary["safety"]["collisions"] == 0
    assert summary["safety"]["teleports"] == 0
    assert summary["planner"]["solves"] is None  # a baseline has no planner
    df = pd.read_parquet(folder / "trajectories.parquet")
    assert set(df.columns) >= TRAJECTORY_COLUMNS
    assert df["vehicle"].nunique() == 6 + 3 + 15
    assert (folder / "sumo" / "scenario.sumocfg").is_file()


def test_cacc_stays_in_lane_behind_the_slow_vehicle(runs):
    folder = runs["cacc"]
    summary = json.loads((folder / "summary.json").read_text())
    df = pd.read_parquet(folder / "trajectories.parquet")
    cav = df[df["kind"] == "cav"]
    assert set(cav["lane"]) == {1}
    assert cav["lat_m"].abs().max() < 1e-6
    target = df[df["vehicle"] == "hv_target"].set_index("time_s")["s_m"]
    leader = cav[cav["vehicle"] == "cav0"].set_index("time_s")["s_m"]
    assert (leader < target - 5.0).all()  # never past the slow vehicle
    assert summary["cav"]["mean_speed_mps"] == pytest.approx(17.5, abs=0.5)
    assert summary["cav"]["gap_min_m"] >= 5.0
    assert summary["safety"]["hard_brakes"] == 0
    assert summary["overtake"]["completed"] is False


def test_sumo_cacc_never_changes_lane(runs):
    df = pd.read_parquet(runs["sumo-cacc"] / "trajectories.parquet")
    assert set(df[df["kind"] == "cav"]["lane"]) == {1}


def test_fcd_output_on_request(paper_path, tmp_path):
    from dataclasses import replace

    sc = load_scenario(paper_path)
    sc = replace(sc, simulation=replace(sc.simulation, duration_s=3.0),
                 evaluation=replace(sc.evaluation, end_s=3.0))  # fmt: skip
    run_scenario(sc, "cacc", tmp_path, fcd=True, progress=False)
    text = (tmp_path / "fcd.xml").read_text()
    assert "<fcd-export" in text and 'id="cav0"' in text


def test_the_saved_configuration_is_the_run_with_its_outputs(runs):
    # sumo -c sumo/scenario.sumocfg runs the run's simulation and writes the run's SUMO outputs
    # (tools/bench_plumbing.py's yardstick): sumo-lc sends SUMO no command, so the sumo binary
    # on the saved configuration writes the very trips the run read.
    import subprocess

    from sumo_swarm.safexml import parse_xml
    from sumo_swarm.sim.bridge import sumo_binary

    folder = runs["sumo-lc"]
    tripinfo = folder / "sumo" / "tripinfo.xml"

    def trips() -> list[dict[str, str]]:
        root = parse_xml(tripinfo, what="tripinfo", max_bytes=10**8)
        return [dict(trip.attrib) | {"co2": trip[0].get("CO2_abs")} for trip in root]

    ran = trips()
    tripinfo.unlink()
    cfg = folder / "sumo" / "scenario.sumocfg"
    subprocess.run([sumo_binary(), "-c", str(cfg)], check=True, capture_output=True, timeout=120)
    assert len(ran) == 6 + 3 + 15 and ran[0]["co2"] is not None
    assert trips() == ran
    assert (folder / "sumo" / "edgedata.xml").is_file()
