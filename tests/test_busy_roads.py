"""Busy roads of users' own, run as users run them: every controller writes its summary.

A 4-lane road with 2 CAVs behind a truck in three dense flows of SUMO's default drivers
(``sumo-swarm run --sumocfg``): the road on which the summary of ``sumo-cacc`` and ``sumo-lc``
was lost (pandas 3.1, more than 127 vehicle names: metrics.upstream_impact). And random traffic
drawn up to the road's capacity on 2 to 5 lanes, under all four controllers. Each run writes a
summary.json with the contract's keys, no measure failed, and no collision.
"""

from __future__ import annotations

import json
import random
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest

from sumo_swarm.sim.netbuild import HighwaySpec, build_highway, edge_ids
from sumo_swarm.sim.runner import run_sumocfg
from tests.contract import assert_summary_contract

pytestmark = pytest.mark.sumo

CONTROLLERS = ("swarm", "cacc", "sumo-cacc", "sumo-lc")
ROOT = Path(__file__).resolve().parent.parent
CAPACITY_VPH_PER_LANE = 2000.0  # [veh/h] about what SUMO's default drivers carry per lane


def write_busy_road(
    folder: Path,
    *,
    lanes: int = 4,
    flows_vph: tuple[float, ...] = (3000.0, 3000.0, 3000.0),
    truck_lane: int = 1,
    truck_pos_m: float = 160.0,
    end_s: float = 50.0,
    length_m: float = 1200.0,
) -> Path:
    """A sumocfg as a user writes one: a netconvert-built road of ``lanes`` lanes, a slow truck
    with CAVs ``cav0`` and ``cav1`` (vType ``cav``) behind it, and one flow of SUMO's default
    vType per entry of ``flows_vph`` [veh/h], each entering on the best lane; returns its path."""
    spec = HighwaySpec(length_m=length_m, lanes=lanes)
    net = build_highway(spec, folder, name="road")
    lines = [
        "<routes>",
        '  <vType id="truck" vClass="truck" maxSpeed="15"/>',
        '  <vType id="cav"/>',
        f'  <route id="r" edges="{" ".join(edge_ids(spec))}"/>',
        f'  <vehicle id="truck" type="truck" route="r" depart="0" departLane="{truck_lane}" '
        f'departPos="{truck_pos_m}" departSpeed="15"/>',
    ]
    for i in range(2):
        lines.append(
            f'  <vehicle id="cav{i}" type="cav" route="r" depart="0" departLane="{truck_lane}" '
            f'departPos="{truck_pos_m - 30.0 - 20.0 * i}" departSpeed="15"/>'
        )
    lines += [
        f'  <flow id="f{k}" route="r" begin="0" end="{end_s:g}" vehsPerHour="{vph:.0f}" '
        'departLane="best" departSpeed="max"/>'
        for k, vph in enumerate(flows_vph)
    ]
    lines.append("</routes>")
    (folder / "road.rou.xml").write_text("\n".join(lines) + "\n", encoding="utf-8")
    cfg = folder / "road.sumocfg"
    cfg.write_text(
        "<configuration>\n  <input>\n"
        f'    <net-file value="{net.name}"/>\n    <route-files value="road.rou.xml"/>\n'
        "  </input>\n  <time>\n"
        f'    <step-length value="0.2"/>\n    <end value="{end_s:g}"/>\n'
        "  </time>\n</configuration>\n",
        encoding="utf-8",
    )
    return cfg


def assert_whole(summary: dict) -> None:
    """The contract's keys, every measure taken, no collision."""
    assert_summary_contract(summary)
    assert summary["errors"] == {}, summary["errors"]
    assert isinstance(summary["upstream"], list)
    assert summary["safety"]["collisions"] == 0
    assert summary["network"] is not None and summary.get("network_error") is None


@pytest.fixture(scope="module")
def busy_road(tmp_path_factory) -> Path:
    return write_busy_road(tmp_path_factory.mktemp("busy"))


@pytest.mark.parametrize("controller", CONTROLLERS)
def test_the_busy_road_writes_the_summary_under_every_controller(busy_road, controller, tmp_path):
    out = tmp_path / controller
    cmd = [sys.executable, "-m", "sumo_swarm", "run", "--sumocfg", str(busy_road),
           "--cav-type", "cav", "--controller", controller, "--out", str(out)]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "Traceback" not in proc.stderr and "unexpected error" not in proc.stderr
    summary = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert_whole(summary)
    assert summary["controller"] == controller and summary["cav"]["count"] == 2
    # The case of the lost summary: more than 127 names (pandas' codes outgrow int8) and the
    # upstream vehicles measured.
    names = pd.read_parquet(out / "trajectories.parquet", columns=["vehicle"])["vehicle"]
    assert names.nunique() > 127
    assert summary["upstream"] and summary["network"]["vehicles"] > 127


def random_traffic(seed: int) -> dict:
    """A draw of traffic: 2 to 5 lanes, 1 to 3 flows whose demand together is 20 % to 100 %
    of the road's capacity, the truck (and the CAVs behind it) in any lane."""
    rng = random.Random(seed)
    lanes = 2 + seed % 4  # every lane count in turn
    share = rng.uniform(0.2, 1.0)
    flows = rng.randint(1, 3)
    total_vph = share * CAPACITY_VPH_PER_LANE * lanes
    return {
        "lanes": lanes,
        "flows_vph": tuple(total_vph / flows for _ in range(flows)),
        "truck_lane": rng.randrange(lanes),
        "truck_pos_m": rng.uniform(90.0, 300.0),
    }


@pytest.mark.parametrize("seed", range(4))
def test_random_traffic_up_to_capacity_writes_every_summary(seed, tmp_path):
    draw = random_traffic(seed)
    cfg = write_busy_road(tmp_path / "road", end_s=25.0, length_m=800.0, **draw)
    for controller in CONTROLLERS:
        summary = run_sumocfg(cfg, "cav", controller, tmp_path / controller, notify=lambda _: None)
        assert (tmp_path / controller / "summary.json").is_file()
        assert_whole(summary)


def test_a_measure_failing_on_a_real_run_costs_that_measure_only(monkeypatch, tmp_path):
    # Whatever a measure meets, the run keeps its summary.json: the measure None, the reason
    # in "errors", the other blocks whole (here the upstream block, as on the busy road).
    from sumo_swarm.sim import metrics

    cfg = write_busy_road(tmp_path / "road", end_s=15.0, length_m=600.0)
    plain = run_sumocfg(cfg, "cav", "sumo-lc", tmp_path / "plain", notify=lambda _: None)

    def broken(*args, **kwargs):
        raise OverflowError("Python integer 140 out of bounds for int8")

    monkeypatch.setattr(metrics, "upstream_impact", broken)
    out = tmp_path / "broken"
    run_sumocfg(cfg, "cav", "sumo-lc", out, notify=lambda _: None)
    written = json.loads((out / "summary.json").read_text(encoding="utf-8"))
    assert written["upstream"] is None
    assert written["errors"] == {
        "upstream": "OverflowError: Python integer 140 out of bounds for int8"
    }
    for block in ("cav", "safety", "network"):
        assert written[block].keys() == plain[block].keys()
    assert written["cav"]["mean_speed_mps"] == plain["cav"]["mean_speed_mps"]
    assert written["safety"]["collisions"] == plain["safety"]["collisions"] == 0
