"""Users' roads (sim/userroads.py), written as a new user would, run through
``sumo-swarm run --sumocfg`` with real SUMO: each builds, SUMO's own CAV models drive them without
a collision, and the swarm drives them without a collision or a CAV braking harder than 4 m/s^2.
How fast the swarm is there is reported by tools/user_roads.py, not asserted here."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
import sumolib

from sumo_swarm.errors import ConfigError
from sumo_swarm.sim.metrics import hard_brake_events
from sumo_swarm.sim.netbuild import MotorwaySpec
from sumo_swarm.sim.runner import read_sumocfg_options, run_sumocfg
from sumo_swarm.sim.userroads import CAV_COUNT, MORE_ROADS, ROADS, write_road

pytestmark = pytest.mark.sumo

# Simulated seconds per run: long enough for the swarm to meet the truck and start to pass it.
END_S = 40.0
ALL_ROADS = [*ROADS, *MORE_ROADS]
ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(scope="module")
def road_cfgs(tmp_path_factory) -> dict[str, Path]:
    base = tmp_path_factory.mktemp("roads")
    return {name: write_road(name, base / name, end_s=END_S) for name in ALL_ROADS}


def _net(cfg: Path) -> sumolib.net.Net:
    return sumolib.net.readNet(str(cfg.parent / read_sumocfg_options(cfg)["net-file"]))


def test_motorway_ramps_have_an_acceleration_and_a_deceleration_lane(road_cfgs):
    net = _net(road_cfgs["motorway-ramps"])
    n = MotorwaySpec().through_lanes
    lanes = {e: net.getEdge(e).getLaneNumber() for e in ("up", "acc", "mid", "dec", "down")}
    assert lanes == {"up": n, "acc": n + 1, "mid": n, "dec": n + 1, "down": n}
    acc = net.getEdge("acc")
    # The on-ramp feeds the acceleration lane (lane 0), which ends with its edge.
    assert [c.getToLane().getID() for c in net.getEdge("on").getLanes()[0].getOutgoing()] == [
        "acc_0"
    ]
    assert acc.getLanes()[0].getOutgoing() == []
    assert [c.getToLane().getID() for c in acc.getLanes()[1].getOutgoing()] == ["mid_0"]
    # The deceleration lane (lane 0 of dec) is entered by a lane change along it: no lane of the
    # junction before it turns into it (two vehicles abreast took such a turn together and
    # overlapped); the through lanes keep their order.
    dec = net.getEdge("dec")
    assert dec.getLanes()[0].getIncoming() == []
    assert [
        (c.getFromLane().getIndex(), c.getToLane().getIndex())
        for lane in net.getEdge("mid").getLanes()
        for c in lane.getOutgoing()
    ] == [(i, i + 1) for i in range(n)]
    # It leads to the off-ramp only, and the through lanes do not.
    assert [c.getToLane().getID() for c in dec.getLanes()[0].getOutgoing()] == ["off_0"]
    assert all(
        c.getToLane().getEdge().getID() == "down"
        for lane in dec.getLanes()[1:]
        for c in lane.getOutgoing()
    )


def test_every_road_builds_with_a_truck_ahead_of_the_cavs_in_its_lane(road_cfgs):
    for name, cfg in road_cfgs.items():
        routes = (cfg.parent / "routes.rou.xml").read_text()
        assert routes.count('type="truck"') == 1
        assert 'departLane="best"' in routes or name == "2-lane-passing-flow"
        options = read_sumocfg_options(cfg)
        assert options["step-length"] == "0.1" and "lateral-resolution" not in options
        assert len(_net(cfg).getEdges()) >= 1


def test_default_step_leaves_the_step_to_sumo(tmp_path):
    cfg = write_road("2-lane-passing-flow", tmp_path, end_s=10.0, step_length_s=None)
    assert "step-length" not in read_sumocfg_options(cfg)


def test_unknown_road_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="unknown road 'nowhere'"):
        write_road("nowhere", tmp_path)


def _cav_min_accel_mps2(run_dir: Path) -> tuple[float, pd.DataFrame]:
    df = pd.read_parquet(run_dir / "trajectories.parquet")
    cav = df[df["kind"] == "cav"]
    return float(cav["accel_mps2"].min()), hard_brake_events(cav)


@pytest.mark.parametrize("controller", ["sumo-lc", "sumo-cacc"])
@pytest.mark.parametrize("name", ALL_ROADS)
def test_sumo_models_drive_every_road_without_collision(road_cfgs, tmp_path, name, controller):
    summary = run_sumocfg(
        road_cfgs[name], "cav", controller, tmp_path, progress=False, notify=lambda _: None
    )
    assert summary["cav"]["count"] == CAV_COUNT
    assert summary["safety"]["collisions"] == 0
    # The runner counts physical overlaps: SUMO's collision check without a minimum gap.
    options = read_sumocfg_options(tmp_path / "sumo" / "scenario.sumocfg")
    assert options["collision.mingap-factor"] == "0"


@pytest.mark.parametrize("name", ALL_ROADS)
def test_swarm_drives_every_road_without_collision_or_cav_hard_brake(road_cfgs, tmp_path, name):
    summary = run_sumocfg(
        road_cfgs[name], "cav", "swarm", tmp_path, progress=False, notify=lambda _: None
    )
    assert summary["cav"]["count"] == CAV_COUNT
    assert summary["safety"]["collisions"] == 0
    min_accel, episodes = _cav_min_accel_mps2(tmp_path)
    assert summary["safety"]["hard_brakes_cav"] == 0, episodes.to_string()
    assert min_accel >= -4.0 - 1e-6, episodes.to_string()


def test_cacc_platoon_leaves_a_lane_that_ends(tmp_path):
    """The lane-drop road's right lane ends at 1 km (netconvert drops the rightmost lane): the
    longitudinal-only CACC platoon in it makes the lane change its route needs there (SUMO's
    strategic changes) instead of stopping at the lane's end, where its front CAV stopped
    from 25 m/s and the next one hit it."""
    cfg = write_road("lane-drop", tmp_path / "road", end_s=75.0)
    summary = run_sumocfg(cfg, "cav", "cacc", tmp_path / "cacc", progress=False,
                          notify=lambda _: None)  # fmt: skip
    assert summary["safety"]["collisions"] == 0
    assert summary["safety"]["hard_brakes_cav"] == 0
    df = pd.read_parquet(tmp_path / "cacc" / "trajectories.parquet")
    last = df[df["kind"] == "cav"].groupby("vehicle").last()
    assert len(last) == CAV_COUNT and (last["edge"] == "e1").all(), last.to_string()
    assert summary["cav"]["mean_speed_mps"] > 10.0  # behind the 15 m/s truck, never stopped


def test_swarm_regroups_past_a_lane_drop(tmp_path):
    """The swarm passes the truck and re-forms its platoon past the lane drop: the CAVs still
    before it count their lanes as the leader's edge does (lane 1 there is lane 0 after it);
    counted on their own edges, two CAVs headed for the wrong lane and rode beside the
    platoon for the rest of the run."""
    cfg = write_road("lane-drop", tmp_path / "road", end_s=50.0)
    summary = run_sumocfg(cfg, "cav", "swarm", tmp_path / "swarm", progress=False,
                          notify=lambda _: None)  # fmt: skip
    assert summary["safety"]["collisions"] == 0
    assert summary["safety"]["hard_brakes_cav"] == 0
    assert summary["overtake"]["completed"] and summary["overtake"]["regrouped"]
    df = pd.read_parquet(tmp_path / "swarm" / "trajectories.parquet")
    last = df[(df["kind"] == "cav") & (df["time_s"] >= df["time_s"].max() - 0.05)]
    assert len(last) == CAV_COUNT and last["lane"].nunique() == 1 and set(last["edge"]) == {"e1"}


def test_regrouped_platoon_cruises_at_the_lanes_speed(tmp_path):
    """Past the truck the re-formed platoon drives at the lanes' 33.3 m/s, its CAVs at the
    platoon's gap: SUMO's safe speed under a CAV follower assumed its CAV leader brakes at the
    vType's 4.5 m/s^2 (apparentDecel) while the follower brakes at 4, held it 17 m back at
    28.7 m/s, and the leader eased off to let the stretched platoon close up, for good."""
    cfg = write_road("3-lane-900", tmp_path / "road", end_s=90.0)
    summary = run_sumocfg(cfg, "cav", "swarm", tmp_path / "swarm", progress=False,
                          notify=lambda _: None)  # fmt: skip
    assert summary["overtake"]["completed"] and summary["overtake"]["regrouped"]
    assert summary["safety"]["collisions"] == 0
    df = pd.read_parquet(tmp_path / "swarm" / "trajectories.parquet")
    late = df[(df["kind"] == "cav") & (df["time_s"] >= 80.0)]
    assert late["speed_mps"].min() >= 32.5, late.groupby("vehicle")["speed_mps"].min()
    assert late["lane"].nunique() == 1


def test_swarm_at_sumos_default_step_refuses_or_drives_safely(tmp_path):
    """At SUMO's default 1 s step the swarm either refuses to start (exit 2, one line naming the
    step) or drives without a collision."""
    cfg = write_road("3-lane-900", tmp_path / "road", end_s=END_S, step_length_s=None)
    cmd = [
        sys.executable, "-m", "sumo_swarm", "run", "--sumocfg", str(cfg), "--cav-type", "cav",
        "--controller", "swarm", "--out", str(tmp_path / "swarm"),
    ]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=ROOT)
    if proc.returncode == 2:
        lines = [line for line in proc.stderr.splitlines() if line.strip()]
        assert len(lines) == 1 and "step" in lines[0], proc.stderr
        return
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "swarm" / "summary.json").read_text())
    assert summary["safety"]["collisions"] == 0, proc.stderr


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"through_lanes": 0}, "through_lanes must be >= 1"),
        ({"ramp_m": 0.0}, "must be > 0"),
        ({"accel_lane_m": float("nan")}, "must be > 0"),
    ],
)
def test_motorway_spec_refuses_impossible_geometry(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        MotorwaySpec(**kwargs)
