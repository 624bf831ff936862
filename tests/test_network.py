"""Network measures from SUMO's own outputs (sim/network.py): the parsers and the measures on
hand-written SUMO files with known answers, the options on a user's configuration, and real
runs, where the outputs must not change how anyone drives."""

from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import pandas as pd
import pytest

from sumo_swarm.config import OutputSettings, load_scenario
from sumo_swarm.errors import ConfigError
from sumo_swarm.sim.conflicts import TtcConflictCounter
from sumo_swarm.sim.metrics import gaps
from sumo_swarm.sim.network import (
    ADDITIONAL,
    EDGE_COLUMNS,
    NetworkTables,
    mean_speed_field,
    network_block,
    network_options,
    read_conflicts,
    read_edge_data,
    read_network,
    read_trips,
    speed_field,
    vehicle_class,
)
from sumo_swarm.sim.runner import read_sumocfg_options, run_scenario, run_sumocfg
from sumo_swarm.sim.userroads import write_road

TRIPINFO = """<?xml version="1.0" encoding="UTF-8"?>
<tripinfos>
    <tripinfo id="cav0" depart="0.00" arrival="100.00" duration="100.00" routeLength="2000.00"
              waitingTime="0.00" timeLoss="10.00" vType="cav@cav0">
        <emissions CO2_abs="300000.00" fuel_abs="100000.00"/>
    </tripinfo>
    <tripinfo id="car1" depart="10.00" arrival="130.00" duration="120.00" routeLength="2000.00"
              waitingTime="1.00" timeLoss="30.00" vType="car">
        <emissions CO2_abs="280000.00" fuel_abs="90000.00"/>
    </tripinfo>
    <tripinfo id="car2" depart="20.00" arrival="-1.00" duration="160.00" routeLength="1000.00"
              waitingTime="0.00" timeLoss="50.00" vType="car">
        <emissions CO2_abs="120000.00" fuel_abs="40000.00"/>
    </tripinfo>
    <tripinfo id="lorry" depart="0.00" arrival="-1.00" duration="180.00" routeLength="1000.00"
              waitingTime="0.00" timeLoss="5.00" vType="truck" departDelay="2.00">
        <emissions CO2_abs="700000.00" fuel_abs="220000.00"/>
    </tripinfo>
    <tripinfo id="late" depart="-1" departDelay="30.00" arrival="-1.00" duration="0.00"
              routeLength="0.00" waitingTime="0.00" timeLoss="0.00" vType="car" vaporized="end"/>
</tripinfos>
"""

SSM = """<?xml version="1.0" encoding="UTF-8"?>
<SSMLog>
    <conflict begin="3.10" end="5.20" ego="car1" foe="cav0">
        <minTTC time="4.00" position="10.0,0.0" type="2" value="0.90" speed="20.0"/>
    </conflict>
    <conflict begin="8.00" end="9.00" ego="car2" foe="car1">
        <minTTC time="8.50" position="10.0,0.0" type="2" value="1.40" speed="20.0"/>
    </conflict>
    <conflict begin="9.00" end="9.50" ego="lorry" foe="car2">
        <minTTC time="NA" position="NA" type="NA" value="NA" speed="NA"/>
    </conflict>
</SSMLog>
"""

EDGE_DATA = """<?xml version="1.0" encoding="UTF-8"?>
<meandata>
    <interval begin="0.00" end="60.00" id="sumo-swarm">
        <edge id="hwy" sampledSeconds="600.00" density="10.00" laneDensity="3.33" speed="25.00"
              entered="12" left="4" flow="720.00" distance="15000.00"/>
        <edge id="ramp" sampledSeconds="0.50" entered="1" left="0"/>
    </interval>
    <interval begin="60.00" end="120.00" id="sumo-swarm">
        <edge id="hwy" sampledSeconds="300.00" density="5.00" laneDensity="1.67" speed="30.00"
              entered="3" left="9" flow="540.00" distance="9000.00"/>
    </interval>
</meandata>
"""

VCLASSES = {"cav": "passenger", "car": "passenger", "truck": "truck"}


def classify(vid: str, vtype: str) -> str:
    """As a run classifies: the CAV type (or SUMO's copy of it for one vehicle), then vClass."""
    kind = "cav" if vtype.split("@")[0] == "cav" else "hv"
    return vehicle_class(kind, VCLASSES.get(vtype.split("@")[0]))


@pytest.fixture
def sumo_files(tmp_path) -> dict[str, Path]:
    files = {"tripinfo": TRIPINFO, "ssm": SSM, "edgedata": EDGE_DATA}
    out = {}
    for name, text in files.items():
        out[name] = tmp_path / f"{name}.xml"
        out[name].write_text(text, encoding="utf-8")
    return out


def test_vehicle_classes():
    assert vehicle_class("cav", "truck") == "cav"
    assert vehicle_class("hv", "truck") == vehicle_class("hv", "trailer") == "truck"
    assert vehicle_class("hv", "coach") == "bus"
    assert vehicle_class("hv", "passenger") == vehicle_class("hv", None) == "hv"


def test_trips_are_read_with_their_class_and_emissions(sumo_files):
    trips = read_trips(sumo_files["tripinfo"], classify).set_index("vehicle")
    assert list(trips["vehicle_class"]) == ["cav", "hv", "hv", "truck", "hv"]
    assert list(trips["finished"]) == [True, True, False, False, False]
    assert list(trips["departed"]) == [True, True, True, True, False]  # "late" never entered
    assert math.isnan(trips.loc["late", "depart_s"]) and trips.loc["late", "depart_delay_s"] == 30
    assert math.isnan(trips.loc["late", "co2_mg"])  # no emissions of a car that never drove
    assert trips.loc["car1", "arrival_s"] == 130.0 and math.isnan(trips.loc["car2", "arrival_s"])
    assert trips.loc["lorry", "co2_mg"] == 700000.0 and trips.loc["cav0", "fuel_mg"] == 100000.0
    assert trips.loc["car1", "time_loss_s"] == 30.0


def test_conflicts_and_edge_data_are_read(sumo_files):
    conflicts = read_conflicts(sumo_files["ssm"])
    assert list(conflicts["ego"]) == ["car1", "car2", "lorry"]
    assert conflicts["min_ttc_s"].iloc[:2].tolist() == [0.9, 1.4]
    assert math.isnan(conflicts["min_ttc_s"].iloc[2])  # SUMO's NA
    edges = read_edge_data(sumo_files["edgedata"])
    assert list(edges.columns) == list(EDGE_COLUMNS)
    assert len(edges) == 3
    first = edges.iloc[0]
    assert (first["edge"], first["speed_mps"], first["flow_veh_per_h"]) == ("hwy", 25.0, 720.0)
    ramp = edges[edges["edge"] == "ramp"].iloc[0]
    assert math.isnan(ramp["speed_mps"]) and ramp["entered"] == 1  # SUMO left the speed out


def test_network_block_from_hand_made_trips(sumo_files):
    tables = read_network(sumo_files, classify)
    block = network_block(tables, hard_brake_events=3, duration_s=180.0, ttc_threshold_s=1.5)
    assert block["vehicles"] == 4 and block["trips_finished"] == 2
    assert block["vehicles_not_departed"] == 1
    assert block["exits_missed"] == 0
    assert network_block(tables, hard_brake_events=3, duration_s=180.0, ttc_threshold_s=1.5,
                         exits_missed=2)["exits_missed"] == 2  # fmt: skip
    # travel time over finished trips only: none of the truck's
    assert block["travel_time_s"] == {"cav": 100.0, "hv": 120.0, "truck": None}
    # delay: timeLoss plus insertion delay, every vehicle due to depart, so far for unfinished
    # ones: HVs (30 + 50 + 30 waiting at the entry) / 3, the truck 5 + 2
    assert block["delay_s"] == {"cav": 10.0, "hv": pytest.approx(110 / 3), "truck": 7.0}
    # every vehicle but the CAV, classes together: (110 + 7) / 4, not the mean of class means
    assert block["delay_s_others"] == pytest.approx(117 / 4)
    assert block["depart_delay_s"] == {"cav": 0.0, "hv": 10.0, "truck": 2.0}
    assert block["throughput_vph"] == pytest.approx(2 / (180.0 / 3600.0))  # 40 veh/h
    assert block["vehicle_km"] == pytest.approx(6.0)
    assert block["hard_brakes_per_1000_vkm"] == pytest.approx(3 / 6.0 * 1000.0)
    assert block["ttc_below_1_5s_events"] == 2  # 0.9 and 1.4; NA is no TTC
    # mg per m is g per km: 300 g over 2 km; HVs 400 g over 3 km; the truck 700 g over 1 km
    assert block["co2_g_per_km"] == pytest.approx({"cav": 150.0, "hv": 400 / 3, "truck": 700.0})
    assert block["fuel_g_per_km"]["truck"] == pytest.approx(220.0)
    assert block["vehicles_per_class"] == {"cav": 1, "hv": 2, "truck": 1}
    stricter = network_block(tables, hard_brake_events=0, duration_s=180.0, ttc_threshold_s=1.0)
    assert stricter["ttc_below_1_5s_events"] == 1
    # the run's own count, when given, is the field; SSM's stays beside it
    counted = network_block(tables, hard_brake_events=0, duration_s=180.0, ttc_threshold_s=1.5,
                            ttc_events=7)  # fmt: skip
    assert counted["ttc_below_1_5s_events"] == 7 and counted["ttc_below_1_5s_events_ssm"] == 2
    assert "ttc_below_1_5s_events_ssm" not in block


def test_outputs_sumo_did_not_write_are_errors_not_zeros(sumo_files, tmp_path):
    with pytest.raises(FileNotFoundError, match="tripinfo"):
        read_network({}, classify)
    missing = {**sumo_files, "ssm": tmp_path / "nowhere.xml"}
    with pytest.raises(FileNotFoundError, match="ssm"):
        read_network(missing, classify)
    cut = tmp_path / "cut.xml"  # a run that died while SUMO wrote
    cut.write_text(TRIPINFO[: len(TRIPINFO) // 2], encoding="utf-8")
    with pytest.raises(Exception):  # noqa: B017 - the XML parser's own error
        read_network({**sumo_files, "tripinfo": cut}, classify)
    without = read_network({"tripinfo": sumo_files["tripinfo"]}, classify)
    assert without.conflicts is None and without.edges is None  # not asked for: no table


def test_network_block_of_nothing(tmp_path):
    (tmp_path / "none.xml").write_text("<tripinfos/>\n", encoding="utf-8")
    empty = NetworkTables(read_trips(tmp_path / "none.xml", classify), conflicts=None, edges=None)
    block = network_block(empty, hard_brake_events=0, duration_s=0.0, ttc_threshold_s=1.5)
    assert block["vehicles"] == 0 and block["travel_time_s"] == {}
    assert block["delay_s_others"] is None
    assert block["throughput_vph"] is None and block["hard_brakes_per_1000_vkm"] is None
    assert block["ttc_below_1_5s_events"] is None  # no SSM output read
    no_ssm = NetworkTables(empty.trips, conflicts=None, edges=None)
    assert (
        network_block(no_ssm, hard_brake_events=0, duration_s=60.0, ttc_threshold_s=1.5)[
            "throughput_vph"
        ]
        == 0.0
    )


def test_options_ask_for_every_output(tmp_path):
    settings = OutputSettings(edge_data_period_s=30.0, ttc_threshold_s=2.0, ssm=True)
    opts, files = network_options(tmp_path / "sumo", settings)
    pairs = dict(zip(opts[::2], opts[1::2], strict=True))
    assert pairs["--tripinfo-output"] == str(files["tripinfo"])
    assert pairs["--tripinfo-output.write-unfinished"] == "true"
    assert pairs["--tripinfo-output.write-undeparted"] == "true"
    assert pairs["--device.emissions.probability"] == "1"
    assert pairs["--device.ssm.thresholds"] == "2.0" and pairs["--device.ssm.measures"] == "TTC"
    assert pairs["--device.ssm.file"] == str(files["ssm"])
    additional = tmp_path / "sumo" / ADDITIONAL
    assert pairs["--additional-files"] == str(additional.resolve())
    text = additional.read_text()
    assert 'period="30.0"' in text and str(files["edgedata"]) in text
    assert files["edgedata"].is_absolute()  # SUMO reads it from the additional file's folder


def test_the_ssm_device_is_left_out_by_default(tmp_path):
    # SUMO's SSM device keeps every open encounter in memory (a jam's, for the jam's length):
    # left out unless [outputs] ssm = true, the other outputs kept.
    opts, files = network_options(tmp_path / "sumo", OutputSettings())
    assert not any(o.startswith("--device.ssm") for o in opts[::2])
    assert "ssm" not in files and {"tripinfo", "edgedata"} <= set(files)
    assert "--device.emissions.probability" in opts


def test_options_keep_what_the_user_asked_for(tmp_path):
    given = {
        "tripinfo-output": "out/trips.xml",
        "tripinfo-output.write-unfinished": "false",
        "tripinfo-output.write-undeparted": "false",
        "device.ssm.measures": "DRAC TTC",
        "device.ssm.probability": "0.5",
        "device.ssm.file": "conflicts.xml",
        "device.emissions.probability": "0.2",
        "additional-files": "detectors.add.xml, more.add.xml",
    }
    opts, files = network_options(tmp_path / "sumo", OutputSettings(), given, tmp_path / "cfg")
    assert files["tripinfo"] == tmp_path / "cfg" / "out" / "trips.xml"
    assert files["ssm"] == tmp_path / "cfg" / "conflicts.xml"
    assert not any(o.startswith(("--tripinfo", "--device.")) for o in opts)
    pairs = dict(zip(opts[::2], opts[1::2], strict=True))
    theirs = [str((tmp_path / "cfg" / n).resolve()) for n in ("detectors.add.xml", "more.add.xml")]
    assert pairs["--additional-files"].split(",") == [
        *theirs,
        str((tmp_path / "sumo" / ADDITIONAL).resolve()),
    ]
    # SSM set up by the user without a file of theirs to read, or without TTC (SUMO's default
    # measures have none): no conflicts to count
    _, files = network_options(tmp_path / "s2", OutputSettings(), {"device.ssm.probability": "1"})
    assert "ssm" not in files
    no_ttc = {"device.ssm.probability": "1", "device.ssm.file": "c.xml"}
    assert "ssm" not in network_options(tmp_path / "s3", OutputSettings(), no_ttc)[1]


def test_options_follow_the_users_output_prefix(tmp_path):
    given = {"output-prefix": "run1_", "tripinfo-output": "trips.xml"}
    _, files = network_options(tmp_path / "sumo", OutputSettings(ssm=True), given, tmp_path)
    assert files["tripinfo"] == tmp_path / "run1_trips.xml"
    assert files["ssm"].name == "run1_ssm.xml" and files["edgedata"].name == "run1_edgedata.xml"


def test_a_folder_with_a_comma_is_refused(tmp_path):
    with pytest.raises(ConfigError, match="comma"):
        network_options(tmp_path / "a,b", OutputSettings())


@pytest.mark.parametrize(
    "key, value", [("edge_data_period_s", 0.0), ("ttc_threshold_s", -1.0), ("ssm_range_m", 0.0)]
)
def test_impossible_output_settings_are_config_errors(key, value):
    with pytest.raises(ConfigError, match=key):
        OutputSettings(**{key: value})


# --------------------------------------------------------------------------- with SUMO


def _without_network(scenario):
    return replace(scenario, outputs=replace(scenario.outputs, network=False))


@pytest.mark.sumo
def test_a_scenario_run_measures_the_network_without_changing_it(tmp_path, paper_path):
    sc = load_scenario(paper_path)
    sc = replace(sc, simulation=replace(sc.simulation, duration_s=25.0))
    on = run_scenario(sc, "swarm", tmp_path / "on", progress=False)
    off = run_scenario(_without_network(sc), "swarm", tmp_path / "off", progress=False)
    assert off["network"] is None and not (tmp_path / "off" / "network_trips.parquet").exists()
    pd.testing.assert_frame_equal(
        pd.read_parquet(tmp_path / "on" / "trajectories.parquet"),
        pd.read_parquet(tmp_path / "off" / "trajectories.parquet"),
    )
    net = on["network"]
    df = pd.read_parquet(tmp_path / "on" / "trajectories.parquet")
    assert net["vehicles"] == df["vehicle"].nunique()
    assert net["vehicles_per_class"]["cav"] == on["cav"]["count"] == 6
    trips = pd.read_parquet(tmp_path / "on" / "network_trips.parquet").set_index("vehicle")
    # SUMO's distance driven is the distance our trajectories saw, every vehicle
    s = df.groupby("vehicle", observed=True)["s_m"]
    driven = (s.last() - s.first()).reindex(trips.index)
    first_step_m = df.groupby("vehicle", observed=True)["speed_mps"].first() * 0.03
    assert (trips["route_length_m"] - driven).abs().max() < first_step_m.max() + 0.5
    assert net["co2_g_per_km"]["cav"] > 0 and net["delay_s"]["hv"] >= 0.0
    assert net["hard_brakes_per_1000_vkm"] == 0.0  # no hard brake in the paper's scene
    assert not (tmp_path / "on" / "network_conflicts.parquet").exists()  # no SSM by default
    # the conflicts counted during the run: the same as counted afterwards from every row
    counted = TtcConflictCounter(1.5)
    counted.add(gaps(df))
    assert net["ttc_below_1_5s_events"] == counted.events
    edges = pd.read_parquet(tmp_path / "on" / "network_edges.parquet")
    assert set(edges["edge"]) == {"hwy"} and edges["speed_mps"].between(10, 30).all()
    assert on["swarms"]["platoons_formed"] == 1 and on["swarms"]["overtakes_started"] >= 1
    assert json.loads((tmp_path / "on" / "summary.json").read_text())["network"] == net


@pytest.mark.sumo
def test_a_users_road_keeps_the_users_outputs_and_drives_the_same(tmp_path):
    """A road of SUMO's defaults (random dawdling, speed deviation: the random numbers matter)
    with the user's own tripinfo output and detector file: theirs are written where they asked
    and read, ours are added, and nobody drives differently for it."""
    cfg = write_road("motorway-ramps", tmp_path / "road", end_s=40.0)
    (tmp_path / "road" / "loops.add.xml").write_text(
        '<additional>\n    <inductionLoop id="loop0" lane="mid_1" pos="100" period="10" '
        'file="loops.xml"/>\n</additional>\n',
        encoding="utf-8",
    )
    text = cfg.read_text().replace(
        "  </input>",
        '    <additional-files value="loops.add.xml"/>\n  </input>\n'
        '  <output>\n    <tripinfo-output value="mytrips.xml"/>\n  </output>',
    )
    cfg.write_text(text, encoding="utf-8")
    assert read_sumocfg_options(cfg)["tripinfo-output"] == "mytrips.xml"
    quiet = {"progress": False, "notify": lambda m: None}
    on = run_sumocfg(cfg, "cav", "swarm", tmp_path / "on", **quiet)
    assert (tmp_path / "road" / "mytrips.xml").is_file()  # theirs, where they asked
    assert (tmp_path / "road" / "loops.xml").is_file()  # their detectors still run
    assert not (tmp_path / "on" / "sumo" / "tripinfo.xml").exists()
    assert 'arrival="-1.00"' in (tmp_path / "road" / "mytrips.xml").read_text()  # unfinished
    assert not (tmp_path / "on" / "sumo" / "ssm.xml").exists()  # no SSM device by default
    net = on["network"]
    assert set(net["vehicles_per_class"]) == {"cav", "hv", "truck"}
    assert net["vehicles_per_class"]["truck"] == 1
    trips = pd.read_parquet(tmp_path / "on" / "network_trips.parquet")
    assert len(trips) == net["vehicles"] > 20

    settings = tmp_path / "quiet.toml"
    settings.write_text("[outputs]\nnetwork = false\n", encoding="utf-8")
    off = run_sumocfg(cfg, "cav", "swarm", tmp_path / "off", config=settings, **quiet)
    assert off["network"] is None
    pd.testing.assert_frame_equal(
        pd.read_parquet(tmp_path / "on" / "trajectories.parquet"),
        pd.read_parquet(tmp_path / "off" / "trajectories.parquet"),
    )


def test_speed_field_is_distance_over_time_per_cell():
    # two vehicles sampled every 1 s: one at 10 m/s from s = 0, one at 30 m/s from s = 150
    rows = []
    for t in range(20):
        rows.append({"time_s": float(t), "vehicle": "a", "edge": "hwy", "s_m": 10.0 * t,
                     "speed_mps": 10.0})  # fmt: skip
        rows.append({"time_s": float(t), "vehicle": "b", "edge": "hwy", "s_m": 150.0 + 30.0 * t,
                     "speed_mps": 30.0})  # fmt: skip
    rows.append({"time_s": 3.0, "vehicle": "r", "edge": "ramp", "s_m": 5.0, "speed_mps": 0.0})
    df = pd.DataFrame(rows)
    field = speed_field(df, ["hwy"], cell_m=100.0, period_s=10.0).set_index(["t_s", "s_m"])
    # 0-10 s: a covers 0-90 m (cell 0), b 150-420 m (cells 100 to 400); the ramp car is off it
    assert field.loc[(0.0, 0.0), "speed_mps"] == 10.0 and field.loc[(0.0, 0.0), "samples"] == 10
    assert field.loc[(0.0, 100.0), "speed_mps"] == 30.0
    # 10-20 s: a and b share no cell until b is gone; a is in cell 100 alone
    assert field.loc[(10.0, 100.0), "speed_mps"] == 10.0
    # every edge counted, the stopped ramp car joins a's cell: 100 m over 11 samples
    everyone = speed_field(df, [], 100.0, 10.0).set_index(["t_s", "s_m"])
    assert everyone.loc[(0.0, 0.0), "speed_mps"] == pytest.approx(100.0 / 11)
    both = mean_speed_field([field.reset_index(), field.reset_index()])
    assert both["speed_mps"].tolist() == field["speed_mps"].tolist()
    assert both["samples"].tolist() == (2 * field["samples"]).tolist()


def test_mean_speed_field_weights_by_samples():
    one = pd.DataFrame({"t_s": [0.0], "s_m": [0.0], "speed_mps": [10.0], "samples": [30]})
    two = pd.DataFrame({"t_s": [0.0], "s_m": [0.0], "speed_mps": [30.0], "samples": [10]})
    merged = mean_speed_field([one, two])
    # 300 + 300 m over 40 samples of time: 15 m/s, not the plain mean of 20
    assert merged["speed_mps"].tolist() == [15.0] and merged["samples"].tolist() == [40]
    assert mean_speed_field([]).empty


# --------------------------------------------------------------------------- what is recorded


def test_hard_brakes_counted_step_by_step_as_on_the_whole_table():
    from sumo_swarm.sim.metrics import HardBrakeCounter, hard_brake_events

    # a brakes hard at 1-2 and again at 4; b at 2, is gone at 3 and still brakes at 4 (one
    # episode, as in the table); c never; d (a CAV) at 0
    steps = {
        0: {"a": -1.0, "b": -1.0, "c": -1.0, "d": -4.5},
        1: {"a": -4.2, "b": -1.0, "c": -3.0, "d": -1.0},
        2: {"a": -5.0, "b": -4.5, "c": -4.0},
        3: {"a": -1.0, "c": -4.0 - 1e-7},
        4: {"a": -4.1, "b": -6.0, "c": 0.0},
    }
    kinds = {"d": "cav"}
    counter = HardBrakeCounter()
    rows = []
    for t, accels in steps.items():
        counter.update(list(accels), list(accels.values()), kinds)
        rows += [(float(t), v, kinds.get(v, "hv"), a) for v, a in accels.items()]
    df = pd.DataFrame(rows, columns=["time_s", "vehicle", "kind", "accel_mps2"])
    events = hard_brake_events(df)
    assert counter.episodes == len(events) == 4  # a twice, b once, d once; c's -4.0 is not
    assert sorted(counter.vehicles) == sorted(events["vehicle"].unique()) == ["a", "b", "d"]
    assert (counter.count(), counter.count("cav"), counter.count("hv")) == (3, 1, 2)


def test_near_cavs_keeps_the_cavs_and_their_neighbours():
    from sumo_swarm.sim.recorder import _near_cavs

    pos = {"cav0": (0.0, 0.0), "near": (150.0, 100.0), "far": (500.0, 0.0),
           "cav1": (1000.0, 0.0), "ramp": (1000.0, 199.0)}  # fmt: skip
    ids, xy = list(pos), list(pos.values())
    kinds = {"cav0": "cav", "cav1": "cav"}
    assert _near_cavs(ids, xy, kinds, 200.0) == [0, 1, 3, 4]  # rows, in order
    assert _near_cavs(ids, xy, kinds, 100.0) == [0, 3]
    assert _near_cavs(ids, xy, {}, 200.0) == []
    assert _near_cavs([], [], kinds, 200.0) == []


@pytest.mark.sumo
def test_recording_only_the_cavs_surroundings_keeps_every_cav_measure(tmp_path):
    cfg = write_road("3-lane-1800", tmp_path / "road", end_s=40.0)
    quiet = {"progress": False, "notify": lambda m: None}
    runs = {}
    for name, extra in (("all", ""), ("cavs", 'trajectories = "cavs"\nneighbour_range_m = 150.0'),
                        ("late", "record_from_s = 20.0\nrecord_to_s = 30.0")):  # fmt: skip
        settings = tmp_path / f"{name}.toml"
        settings.write_text(f"[outputs]\nnetwork = false\n{extra}\n", encoding="utf-8")
        summary = run_sumocfg(cfg, "cav", "swarm", tmp_path / name, config=settings, **quiet)
        runs[name] = (summary, pd.read_parquet(tmp_path / name / "trajectories.parquet"))
    (s_all, all_rows), (s_cavs, cav_rows), (s_late, late_rows) = runs.values()
    assert len(cav_rows) < 0.6 * len(all_rows)
    cav = all_rows[all_rows["kind"] == "cav"].reset_index(drop=True)
    pd.testing.assert_frame_equal(
        cav_rows[cav_rows["kind"] == "cav"].reset_index(drop=True), cav, check_categorical=False
    )
    for block in ("cav", "overtake"):
        assert s_cavs[block] == s_all[block], block
    # hard brakes, collisions, teleports of everyone; the smallest TTC of those recorded only
    safety = {k: v for k, v in s_all["safety"].items() if k != "min_ttc_s"}
    assert {k: s_cavs["safety"][k] for k in safety} == safety
    assert s_all["safety"]["hard_brakes_hv"] > 0  # SUMO's own drivers brake hard on this road
    assert late_rows["time_s"].between(20.0 - 1e-6, 30.0 + 1e-6).all()
    assert late_rows["time_s"].min() == pytest.approx(20.0)
    # hard brakes of the whole run, recorded or not
    assert {k: s_late["safety"][k] for k in safety} == safety


@pytest.mark.sumo
def test_a_users_short_option_names_prefix_and_queue_at_the_entry(tmp_path):
    """SUMO's synonyms (<additional>, <tripinfo>), an output prefix, and an on-ramp whose
    demand cannot all enter: the user's detectors still run, their prefixed tripinfo is read,
    and the vehicles still waiting at the end count in the delay."""
    cfg = write_road("motorway-ramps", tmp_path / "road", end_s=20.0)
    routes = tmp_path / "road" / "routes.rou.xml"
    text = routes.read_text()
    assert 'id="ramp"' in text
    routes.write_text(text.replace('vehsPerHour="600"', 'vehsPerHour="20000"', 1), encoding="utf-8")
    (tmp_path / "road" / "loops.add.xml").write_text(
        '<additional>\n    <inductionLoop id="loop0" lane="mid_1" pos="50" period="10" '
        'file="loops.xml"/>\n</additional>\n',
        encoding="utf-8",
    )
    cfg.write_text(
        cfg.read_text().replace(
            "  </input>",
            '    <additional value="loops.add.xml"/>\n  </input>\n  <output>\n'
            '    <tripinfo value="mytrips.xml"/>\n    <output-prefix value="u_"/>\n  </output>',
        ),
        encoding="utf-8",
    )
    summary = run_sumocfg(
        cfg, "cav", "sumo-lc", tmp_path / "run", progress=False, notify=lambda m: None
    )
    assert (tmp_path / "road" / "u_loops.xml").is_file()  # their detectors, their prefix
    assert (tmp_path / "road" / "u_mytrips.xml").is_file()
    assert "network_error" not in summary
    net = summary["network"]
    assert net["vehicles_per_class"]["cav"] == 5 and net["vehicles"] > 20
    assert net["vehicles_not_departed"] > 5  # the ramp's queue
    trips = pd.read_parquet(tmp_path / "run" / "network_trips.parquet")
    waiting = trips[~trips["departed"]]
    assert len(waiting) == net["vehicles_not_departed"]
    assert (waiting["depart_delay_s"] > 0).all() and waiting["vehicle"].str.startswith("ramp").all()
    hv = trips[trips["vehicle_class"] == "hv"]
    assert net["delay_s"]["hv"] == pytest.approx((hv["time_loss_s"] + hv["depart_delay_s"]).mean())


@pytest.mark.sumo
def test_network_outputs_that_cannot_be_read_cost_the_block_not_the_run(
    tmp_path, paper_path, monkeypatch
):
    import sumo_swarm.sim.network as network

    sc = load_scenario(paper_path)
    sc = replace(sc, simulation=replace(sc.simulation, duration_s=5.0))
    run_scenario(sc, "cacc", tmp_path / "run", progress=False)
    assert (tmp_path / "run" / "network_trips.parquet").is_file()

    def broken(path, classify):
        raise ValueError("damaged")

    monkeypatch.setattr(network, "read_trips", broken)
    # the same folder, the earlier run replaced (refused without force)
    summary = run_scenario(sc, "cacc", tmp_path / "run", progress=False, force=True)
    assert summary["network"] is None and summary["network_error"] == "ValueError: damaged"
    written = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert written["network_error"] == "ValueError: damaged" and written["cav"]["count"] == 6
    assert len(pd.read_parquet(tmp_path / "run" / "trajectories.parquet")) > 0
    # nothing of the earlier run's network tables is left beside a block that says none
    assert not list((tmp_path / "run").glob("network_*.parquet"))
