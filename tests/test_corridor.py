"""Corridor scenarios (``[corridor]``, issue 14 item 2): the section's checks, the network
netconvert builds for it, the flows written for it, and short real SUMO runs in which the CAVs of
the baselines make the lane changes their routes need (merge from an on-ramp, leave by the
off-ramp) without a collision."""

from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import pandas as pd
import pytest
import sumolib

from sumo_swarm.config import CorridorSettings, load_scenario
from sumo_swarm.errors import ConfigError
from sumo_swarm.sim.conflicts import TtcConflictCounter
from sumo_swarm.sim.metrics import gaps
from sumo_swarm.sim.netbuild import CorridorSpec, build_corridor
from sumo_swarm.sim.runner import run_scenario
from sumo_swarm.sim.scene import (
    CAR_TYPE,
    CAV_TYPE,
    TRUCK_TYPE,
    corridor_flows,
    corridor_routes_xml,
    corridor_spec,
    route_edges,
    write_sumo_inputs,
)

ROOT = Path(__file__).resolve().parent.parent
CORRIDOR = ROOT / "scenarios" / "corridor.toml"


# --------------------------------------------------------------------------- the section


def test_the_example_is_the_issues_corridor():
    sc = load_scenario(CORRIDOR)
    c = sc.corridor
    assert c.length_m >= 5000 and c.lanes == 3
    assert len(c.on_ramp_positions_m) == 2 and len(c.off_ramp_positions_m) == 1
    assert c.main_demand_vph_per_lane >= 1500
    assert (c.cav_share, c.truck_share) == (0.2, 0.15)
    assert sc.simulation.duration_s == 3600 and sc.simulation.step_length_s <= 0.3
    # the evaluation window is the whole run when the file does not set it
    assert (sc.evaluation.start_s, sc.evaluation.end_s) == (0.0, 3600.0)
    assert route_edges(sc) == ("m0", "acc0", "m1", "dec0", "m2", "acc1", "m3")


def test_a_scenario_without_the_section_has_no_corridor(paper_path):
    assert load_scenario(paper_path).corridor is None


def _write(tmp_path: Path, corridor: str, extra: str = "") -> Path:
    path = tmp_path / "c.toml"
    path.write_text(f"[simulation]\nstep_length_s = 0.2\n{extra}\n[corridor]\n{corridor}\n")
    return path


@pytest.mark.parametrize(
    ("line", "key"),
    [
        ("lenght_m = 6000.0", "corridor.lenght_m"),
        ("lanes = 1", "lanes"),
        ("lanes = 2.5", "corridor.lanes"),
        ("cav_share = 1.2", "cav_share"),
        ("cav_share = 0.9", "truck_share"),  # 0.9 + 0.15 trucks > 1
        ("truck_share = -0.1", "truck_share"),
        ("main_demand_vph_per_lane = nan", "corridor.main_demand_vph_per_lane"),
        ("speed_limit_mps = 0", "speed_limit_mps"),
        ("truck_max_speed_mps = 20.0", "truck_max_speed_mps"),  # below the desired 23
        ("on_ramp_positions_m = [1000.0]", "on_ramp_demands_vph"),  # no demand for it
        ("off_ramp_positions_m = [3000.0]\noff_ramp_shares = [1.5]", "off_ramp_shares[0]"),
        ("on_ramp_positions_m = [1000.0]\non_ramp_demands_vph = [-5.0]", "on_ramp_demands_vph"),
        # beyond the road's end, and two ramp lanes on top of each other
        ("on_ramp_positions_m = [5900.0]\non_ramp_demands_vph = [100.0]", "on_ramp_positions_m"),
        (
            "on_ramp_positions_m = [1000.0]\non_ramp_demands_vph = [100.0]\n"
            "off_ramp_positions_m = [1300.0]\noff_ramp_shares = [0.1]",
            "off_ramp_positions_m",
        ),
        (
            "on_ramp_positions_m = [3000.0, 1000.0]\non_ramp_demands_vph = [1.0, 1.0]",
            "on_ramp_positions_m",
        ),
        ('arrivals = "bursty"', "corridor.arrivals"),
    ],
)
def test_bad_corridor_values_name_the_key_and_the_file(tmp_path, line, key):
    path = _write(tmp_path, line)
    with pytest.raises(ConfigError) as err:
        load_scenario(path)
    assert key in str(err.value) and str(path) in str(err.value)


@pytest.mark.parametrize(
    ("extra", "key"),
    [
        ('network = "x.net.xml"', "simulation.network"),
        ('route_edges = ["m0"]', "simulation.route_edges"),
        ("[scene]\nplatoon_lane = 1", "scene"),
    ],
)
def test_what_a_corridor_does_not_use_is_refused(tmp_path, extra, key):
    path = _write(tmp_path, "lanes = 3", extra)
    with pytest.raises(ConfigError, match=key):
        load_scenario(path)


def test_a_set_evaluation_window_is_kept(tmp_path):
    path = _write(tmp_path, "lanes = 3", "duration_s = 600.0\n[evaluation]\nend_s = 400.0")
    sc = load_scenario(path)
    assert sc.evaluation.end_s == 400.0 and sc.simulation.duration_s == 600.0


# --------------------------------------------------------------------------- the network


def _targets(lane) -> list[str]:
    return sorted(c.getToLane().getID() for c in lane.getOutgoing())


def test_the_network_has_the_ramps_and_lanes_asked_for(tmp_path):
    sc = load_scenario(CORRIDOR)
    spec = corridor_spec(sc.corridor)
    net = sumolib.net.readNet(str(build_corridor(spec, tmp_path)))
    lanes = {e.getID(): e.getLaneNumber() for e in net.getEdges()}
    assert lanes == {
        "m0": 3, "acc0": 4, "m1": 3, "dec0": 4, "m2": 3, "acc1": 4, "m3": 3,
        "on0": 1, "on1": 1, "off0": 1,
    }  # fmt: skip
    # the main road is as long as asked, the ramp lanes where asked (junctions at the nodes)
    through = [net.getEdge(e) for e in spec.through_edges()]
    starts = {e.getID(): e.getFromNode().getCoord()[0] for e in through}
    assert through[-1].getToNode().getCoord()[0] == pytest.approx(6000.0)
    assert starts == pytest.approx(
        {"m0": 0, "acc0": 1000, "m1": 1250, "dec0": 2550, "m2": 2800, "acc1": 3800, "m3": 4050}
    )
    assert all(e.getSpeed() == pytest.approx(33.33) for e in through)
    assert net.getEdge("on0").getSpeed() == pytest.approx(22.22)
    assert net.getEdge("m0").getLanes()[0].getWidth() == pytest.approx(3.5)
    for i in (0, 1):
        acc = net.getEdge(f"acc{i}")
        # the on-ramp feeds the acceleration lane (lane 0), which ends with its edge
        assert _targets(net.getEdge(f"on{i}").getLanes()[0]) == [f"acc{i}_0"]
        assert acc.getLanes()[0].getOutgoing() == []
        after = acc.getToNode().getOutgoing()[0].getID()
        assert [_targets(acc.getLanes()[k]) for k in (1, 2, 3)] == [
            [f"{after}_{k}"] for k in range(3)
        ]
    dec = net.getEdge("dec0")
    # the deceleration lane leads to the off-ramp only and is entered by a lane change along it:
    # the lanes before it go straight on (none turns into it)
    assert _targets(dec.getLanes()[0]) == ["off0_0"]
    assert [_targets(dec.getLanes()[k]) for k in (1, 2, 3)] == [["m2_0"], ["m2_1"], ["m2_2"]]
    assert [_targets(lane) for lane in net.getEdge("m1").getLanes()] == [
        ["dec0_1"],
        ["dec0_2"],
        ["dec0_3"],
    ]
    assert dec.getLanes()[0].getIncoming() == []


def test_a_corridor_without_ramps_is_one_edge(tmp_path):
    spec = CorridorSpec(length_m=1500.0, lanes=2)
    net = sumolib.net.readNet(str(build_corridor(spec, tmp_path)))
    assert [e.getID() for e in net.getEdges()] == ["m0"] == list(spec.through_edges())


# --------------------------------------------------------------------------- the flows


def test_a_relative_output_folder_names_a_network_sumo_can_open(tmp_path, monkeypatch):
    # SUMO reads a config's paths relative to the config: `run ... --out out` once wrote
    # "out/sumo/corridor.net.xml" into out/sumo/scenario.sumocfg, which SUMO could not open.
    monkeypatch.chdir(tmp_path)
    cfg, _ = write_sumo_inputs(load_scenario(CORRIDOR), "sumo-lc", Path("out") / "sumo")
    net = ET.parse(cfg).find("input/net-file").get("value")
    assert (cfg.parent / net).is_file()


def test_flows_split_every_demand_by_destination_and_class():
    c = load_scenario(CORRIDOR).corridor
    flows = corridor_flows(c)
    total = sum(f.rate_vph for f in flows)
    assert total == pytest.approx(3 * 1500.0 + 600.0 + 500.0)
    by_type = {t: sum(f.rate_vph for f in flows if f.type_id == t) for t in (CAV_TYPE, TRUCK_TYPE)}
    assert by_type[CAV_TYPE] == pytest.approx(0.2 * total)
    assert by_type[TRUCK_TYPE] == pytest.approx(0.15 * total)
    # a fifth of what passes the off-ramp leaves there: the main demand and on-ramp 0's
    exits = sum(f.rate_vph for f in flows if f.destination == "off0")
    assert exits == pytest.approx(0.2 * (4500.0 + 600.0))
    # on-ramp 1 joins downstream of the off-ramp: its traffic cannot take it
    assert {f.destination for f in flows if f.origin == "on1"} == {"end"}
    routes = {f.id: f.route for f in flows}
    assert routes["on0_off0_cav"] == ("on0", "acc0", "m1", "dec0", "off0")
    assert routes["main_end_car"] == ("m0", "acc0", "m1", "dec0", "m2", "acc1", "m3")


def test_routes_differ_between_controllers_only_in_the_cav_type():
    sc = load_scenario(CORRIDOR)
    files = {name: corridor_routes_xml(sc, name) for name in ("cacc", "sumo-lc")}
    lines = {name: text.splitlines() for name, text in files.items()}
    differ = [a for a, b in zip(lines["cacc"], lines["sumo-lc"], strict=True) if a != b]
    assert len(differ) == 1 and f'id="{CAV_TYPE}"' in differ[0]
    text = files["cacc"]
    assert text.count("<flow ") == len(corridor_flows(sc.corridor))
    assert 'departLane="best"' in text and 'departSpeed="max"' in text and "exp(" in text
    assert f'<vType id="{CAR_TYPE}" vClass="passenger" speedDev="0.1"/>' in text
    assert 'desiredMaxSpeed="23.0" maxSpeed="25.0"' in text


def test_uniform_arrivals_are_flows_per_hour():
    c = CorridorSettings(arrivals="uniform", cav_share=0.0)
    sc = load_scenario(CORRIDOR)
    from dataclasses import replace

    text = corridor_routes_xml(replace(sc, corridor=c), "cacc")
    assert "exp(" not in text and 'vehsPerHour="3825"' in text  # 4500 * 0.85 cars
    assert f'type="{CAV_TYPE}"' not in text


# --------------------------------------------------------------------------- SUMO runs

# A short corridor the tests run: one on-ramp, one off-ramp 900 m later, a high CAV share.
SHORT = {
    "length_m": 1900.0,
    "on_ramp_positions_m": [300.0],
    "on_ramp_demands_vph": [800.0],
    "off_ramp_positions_m": [1300.0],
    "off_ramp_shares": [0.3],
    "main_demand_vph_per_lane": 1200.0,
    "cav_share": 0.4,
}
END_S = 240.0


def _tripinfo(run: Path) -> pd.DataFrame:
    rows = sumolib.xml.parse_fast(
        str(run / "sumo" / "tripinfo.xml"),
        "tripinfo",
        ["id", "depart", "departDelay", "arrival", "arrivalLane", "vType"],
    )
    df = pd.DataFrame(
        [
            (r.id, float(r.depart), float(r.departDelay), float(r.arrival), r.arrivalLane, r.vType)
            for r in rows
        ],
        columns=["vehicle", "depart_s", "depart_delay_s", "arrival_s", "arrival_lane", "vtype"],
    )
    df["flow"] = df["vehicle"].str.rsplit(".", n=1).str[0]
    return df


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[str, tuple[dict, Path]]:
    sc = load_scenario(CORRIDOR, overrides={"simulation": {"duration_s": END_S}, "corridor": SHORT})
    out = {}
    for controller in ("cacc", "sumo-lc", "swarm"):
        folder = tmp_path_factory.mktemp(controller)
        out[controller] = (run_scenario(sc, controller, folder, progress=False), folder)
    return out


# cacc and swarm hand an exiting CAV to SUMO's lane changing under CACC speed commands
# (controllers.base.RouteWatch, controllers.fleet): in this dense traffic one found no gap into
# the deceleration lane at the CACC speed, ran into the end of dec0's lane 1 and was stopped
# dead there (hit by the CAV behind under cacc). The CACC now slows such a CAV for its lane's
# end (controllers.cacc.lane_end_accel), as SUMO's drivers do, and it merges.
@pytest.mark.sumo
@pytest.mark.parametrize("controller", ["cacc", "sumo-lc", "swarm"])
def test_cavs_merge_and_exit_without_a_collision(runs, controller):
    summary, folder = runs[controller]
    assert summary["safety"]["collisions"] == 0 and summary["safety"]["teleports"] == 0
    assert summary["cav"]["count"] > 20
    trips = _tripinfo(folder)
    arrived = trips[trips["arrival_s"] > 0]
    traj = pd.read_parquet(folder / "trajectories.parquet", columns=["vehicle", "edge"])
    last_edge = traj.astype({"vehicle": str, "edge": str}).groupby("vehicle")["edge"].last()
    # every vehicle bound for the off-ramp that arrived did so on it, and those that left early
    # enough (two minutes for at most 2.2 km) all got there: arrived, or on it at the end (a
    # jam at the merge may hold them longer)
    for flow, lane in (
        ("main_off0_cav", "off0_0"),
        ("on0_off0_cav", "off0_0"),
        ("on0_end_cav", "m2_"),
    ):
        mine = trips[trips["flow"] == flow]
        assert (arrived[arrived["flow"] == flow]["arrival_lane"].str.startswith(lane)).all()
        early = mine[mine["depart_s"] < END_S - 120.0]
        assert len(early) >= 1, flow
        edge = lane.rstrip("_").removesuffix("_0")  # off0_0 -> off0, m2_ -> m2
        on_it = early["vehicle"].map(last_edge).astype(str) == edge
        there = early["arrival_lane"].str.startswith(lane) | on_it
        assert there.all(), (flow, early[~there])
    # on-ramp CAVs merged: they drove on the main road after the acceleration lane
    merged = traj[
        traj["vehicle"].astype(str).str.startswith("on0_end_cav") & (traj["edge"] == "m1")
    ]
    assert merged["vehicle"].nunique() >= 3
    # the network block counts the classes, and the exits given up (events.jsonl)
    assert set(summary["network"]["vehicles_per_class"]) >= {"cav", "hv", "truck"}
    events = [json.loads(line) for line in (folder / "events.jsonl").open()]
    missed = sum(e["event"] == "exit_missed" for e in events)
    assert summary["network"]["exits_missed"] == missed


# A CAV SUMO drives alone keeps SUMO's default gaps: set on each CAV after its insertion, the
# CAVs inserted at departSpeed="max" at the scenario type's short tau braked beyond 4 m/s^2 to
# open that gap (here 37 CAV hard brakes, sumo-lc's CAVs 5); set on the vType, SUMO inserts them
# within it (bridge.SumoSession.drive_alone): 2. What remains is SUMO's own driving (a CAV cut
# in on by another changing lanes for its exit), as under sumo-lc.
@pytest.mark.sumo
def test_cavs_brake_hard_no_more_often_than_sumos(runs):
    swarm, sumo = runs["swarm"][0]["safety"], runs["sumo-lc"][0]["safety"]
    assert swarm["hard_brakes_cav"] <= sumo["hard_brakes_cav"]


@pytest.mark.sumo
def test_every_controller_gets_the_same_traffic(runs):
    planned = {}
    for controller, (_, folder) in runs.items():
        trips = _tripinfo(folder)
        trips = trips[trips["depart_s"] >= 0]
        planned[controller] = {
            (v, round(d - w, 1))
            for v, d, w in trips[["vehicle", "depart_s", "depart_delay_s"]].itertuples(index=False)
        }
    assert planned["cacc"] == planned["sumo-lc"]


@pytest.mark.sumo
def test_class_shares_of_the_vehicles_that_came(runs):
    trips = _tripinfo(runs["sumo-lc"][1])
    counts = trips["vtype"].str.split("@").str[0].value_counts()
    n = len(trips)
    expected = (3 * 1200.0 + 800.0) * END_S / 3600.0  # 293 vehicles
    assert abs(n - expected) < 4 * math.sqrt(expected)  # Poisson arrivals
    assert counts[CAV_TYPE] / n == pytest.approx(0.4, abs=0.1)
    assert counts[TRUCK_TYPE] / n == pytest.approx(0.15, abs=0.07)
    assert counts[CAR_TYPE] / n == pytest.approx(0.45, abs=0.1)


@pytest.mark.sumo
def test_a_cav_stuck_beside_the_deceleration_lane_misses_its_exit_and_drives_on(tmp_path):
    # A CAV released to take the off-ramp, standing near the end of dec0's leftmost lane (it
    # found no gap): after a wait it gives up its exit and drives on (an ``exit_missed``
    # event) instead of holding up its lane (the corridor jammed for five minutes behind one,
    # the road ahead empty). In the deceleration lane itself it keeps its exit.
    from types import SimpleNamespace

    from sumo_swarm.controllers.cacc import MISS_EXIT_AFTER_S, lane_end_accel
    from sumo_swarm.sim.bridge import SumoSession

    spec = CorridorSpec(length_m=1500.0, lanes=3, off_ramp_positions_m=(800.0,))
    net = build_corridor(spec, tmp_path)
    main = spec.route(None, None)
    routes = tmp_path / "r.rou.xml"
    dec_length = sumolib.net.readNet(str(net)).getEdge("dec0").getLength()
    place = dec_length - 12.0
    routes.write_text(
        f"""<routes>
  <vType id="cav" maxSpeedLat="2"/>
  <route id="out" edges="{" ".join(spec.route(None, 0))}"/>
  <vehicle id="stuck" type="cav" route="out" depart="0" departSpeed="0"/>
  <vehicle id="exiting" type="cav" route="out" depart="0" departSpeed="0"/>
</routes>""",
        encoding="utf-8",
    )
    args = ["-n", str(net), "-r", str(routes), "--lateral-resolution", "0.5",
            "--no-step-log", "true", "--step-length", "0.2"]  # fmt: skip
    with SumoSession(args, route_edges=main, is_cav=lambda vid, type_id: True) as sumo:
        sumo.step()
        vehicle = sumo.api.vehicle
        vehicle.moveTo("stuck", "dec0_3", place)
        vehicle.moveTo("exiting", "dec0_0", place)
        for vid in ("stuck", "exiting"):
            sumo.release(vid)
            vehicle.setLaneChangeMode(vid, 0)  # it finds no gap
        sumo.step()
        events = []
        ctx = SimpleNamespace(session=sumo, dt_s=0.2,
                              event=lambda kind, **data: events.append((kind, data)))  # fmt: skip
        for _ in range(round(MISS_EXIT_AFTER_S / 0.2)):  # it waits for a gap, standing
            vehicle.setSpeed("stuck", 0.0)
            sumo.step()
            assert lane_end_accel(ctx, "stuck", 0.0) is not None
        assert events == []
        sumo.step()
        assert lane_end_accel(ctx, "stuck", 0.0) is None  # it drives on: no lane end to slow for
        assert lane_end_accel(ctx, "exiting", 0.0) is None  # in the lane its route goes on in
        assert events == [("exit_missed", {"vehicle": "stuck", "exit": "off0"})]
        assert vehicle.getRoute("stuck")[-1] == main[-1]
        assert vehicle.getRoute("exiting")[-1] == "off0"
        vehicle.setSpeed("stuck", -1.0)  # (our CACC drives it in a run)
        for _ in range(100):
            sumo.step()
        assert vehicle.getRoadID("stuck") in main[main.index("dec0") + 1 :]


@pytest.mark.sumo
def test_ttc_conflicts_are_counted_during_the_run_as_from_the_whole_table(runs):
    # The network block's conflicts are counted step by step while the run goes (every
    # vehicle, whatever is recorded: sim/conflicts.py); here every vehicle is recorded, so the
    # count from the whole trajectory table afterwards is the same.
    seen = 0
    for controller, (summary, folder) in runs.items():
        counter = TtcConflictCounter(1.5)
        counter.add(gaps(pd.read_parquet(folder / "trajectories.parquet")))
        assert summary["network"]["ttc_below_1_5s_events"] == counter.events, controller
        seen += counter.events
    assert seen > 0  # some conflict to count in this dense traffic
