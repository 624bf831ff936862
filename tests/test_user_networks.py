"""The swarm on SUMO configurations that are not the paper's, built here as a user would have
them: a curved three-lane road, a two-lane road, four lanes over two edges, a lane drop ahead.
Through ``sumo-swarm run --sumocfg`` (libsumo) and through the plugin API (libsumo and traci)."""

from __future__ import annotations

import json
import logging
import math
import os

import pytest
import sumo

import sumo_swarm
from sumo_swarm.errors import ConfigError
from sumo_swarm.sim.netbuild import HighwaySpec
from sumo_swarm.sim.runner import run_sumocfg
from tests.usercases import write_user_case

pytestmark = pytest.mark.sumo

CASES = {
    "curved-3-lanes": (HighwaySpec(length_m=2500, lanes=3, radius_m=800), 1),
    "straight-2-lanes": (HighwaySpec(length_m=2500, lanes=2), 0),
    "4-lanes-2-edges": (HighwaySpec(length_m=2500, lanes=4, edges=2), 1),
    "lane-drop-ahead": (HighwaySpec(length_m=2800, lanes=(3, 2, 2, 2), edges=4), 1),
}


@pytest.mark.parametrize("name", sorted(CASES))
def test_user_configuration_overtakes_safely_and_beats_sumo_cacc(tmp_path, name):
    spec, lane = CASES[name]
    cfg = write_user_case(tmp_path / "net", spec, platoon_lane=lane)
    notes: list[str] = []
    swarm = run_sumocfg(
        cfg, "cav", "swarm", tmp_path / "swarm", progress=False, notify=notes.append
    )
    assert len(notes) == 1 and "--lateral-resolution" in notes[0]  # added and reported
    baseline = run_sumocfg(
        cfg, "cav", "sumo-cacc", tmp_path / "cacc", progress=False, notify=notes.append
    )
    assert swarm["cav"]["count"] == 6
    assert swarm["overtake"]["target"] == "truck"  # found on its own, not configured
    # past it and regrouped, at the first try or later (lane-drop-ahead: the truck moves over
    # at the lane drop, the first overtake ends there, the second passes it)
    passed = [m for m in swarm["manoeuvres"] if m["target"] == "truck"]
    assert any(m["outcome"] == "completed" and m["regrouped"] for m in passed), passed
    assert swarm["safety"]["collisions"] == 0
    assert swarm["safety"]["hard_brakes"] == 0
    assert swarm["cav"]["gap_min_m"] >= 5.0
    assert swarm["cav"]["mean_speed_mps"] > baseline["cav"]["mean_speed_mps"]
    assert json.loads((tmp_path / "swarm" / "summary.json").read_text()) == swarm


def test_config_with_lateral_resolution_needs_no_addition(tmp_path):
    cfg = write_user_case(
        tmp_path, HighwaySpec(length_m=1500, lanes=3), end_s=10.0, lateral_resolution=0.8
    )
    notes: list[str] = []
    run_sumocfg(cfg, "cav", "cacc", tmp_path / "o", progress=False, notify=notes.append)
    assert notes == []


def _sumo_cmd(cfg) -> list[str]:
    binary = os.path.join(sumo.SUMO_HOME, "bin", "sumo")
    return [
        binary,
        "-c",
        str(cfg),
        "--lateral-resolution",
        "0.5",
        "--no-step-log",
        "true",
        "--collision.mingap-factor",
        "0",
        "--collision.action",
        "warn",
    ]


def test_attach_through_traci(tmp_path):
    import traci

    cfg = write_user_case(tmp_path, HighwaySpec(length_m=2500, lanes=3), end_s=70.0)
    traci.start(_sumo_cmd(cfg), label="swarm-test")
    conn = traci.getConnection("swarm-test")
    try:
        handle = sumo_swarm.attach(conn, cav_type="cav")
        while conn.simulation.getMinExpectedNumber() > 0 and conn.simulation.getTime() < 70:
            conn.simulationStep()
        summary = handle.summary()
        handle.detach()
    finally:
        conn.close()
    assert summary["cav"]["count"] == 6
    assert summary["overtake"]["completed"] and summary["overtake"]["regrouped"]
    assert summary["safety"]["collisions"] == 0
    assert summary["cav"]["gap_min_m"] >= 5.0


def test_attach_through_libsumo_by_ids_with_a_late_cav(tmp_path):
    import libsumo

    cfg = write_user_case(tmp_path, HighwaySpec(length_m=2500, lanes=3), end_s=60.0)
    routes = tmp_path / "routes.rou.xml"
    late = (
        '  <vehicle id="late" type="cav" route="r" depart="4" departLane="1" '
        'departPos="60" departSpeed="16"/>\n</routes>'
    )
    routes.write_text(routes.read_text().replace("</routes>", late))
    libsumo.start(_sumo_cmd(cfg))
    try:
        ids = [f"c{i}" for i in range(6)] + ["late"]
        handle = sumo_swarm.attach(libsumo, cav_ids=ids, cruising_speed_mps=20.0)
        mid = None
        while libsumo.simulation.getTime() < 60:
            libsumo.simulation.step()
            if mid is None and libsumo.simulation.getTime() >= 10:
                mid = handle.summary()  # a summary at any time
        summary = handle.summary()
        handle.detach()
    finally:
        libsumo.close()
    assert mid["cav"]["count"] == 7
    assert "late" in handle.session.cav_ids
    assert summary["safety"]["collisions"] == 0
    assert summary["overtake"]["triggered"]


@pytest.mark.parametrize(
    ("extra", "warned"),
    [
        ([], True),  # SUMO's defaults: jam teleports after 300 s
        (["--time-to-teleport", "-1"], False),
    ],
)
def test_attach_warns_once_when_sumo_teleports(tmp_path, caplog, extra, warned):
    import libsumo

    cfg = write_user_case(tmp_path, HighwaySpec(length_m=500, lanes=3), end_s=5.0)
    libsumo.start([*_sumo_cmd(cfg), *extra])
    try:
        with caplog.at_level(logging.WARNING, logger="sumo_swarm"):
            handle = sumo_swarm.attach(libsumo, cav_type="cav")
            libsumo.simulation.step()
        handle.detach()
    finally:
        libsumo.close()
    lines = [r.getMessage() for r in caplog.records if "teleports" in r.getMessage()]
    assert len(lines) == (1 if warned else 0), lines
    if warned:
        assert "time-to-teleport 300 s" in lines[0] and "--time-to-teleport -1" in lines[0]


def test_attach_needs_exactly_one_cav_selector():
    import libsumo

    with pytest.raises(ValueError, match="exactly one"):
        sumo_swarm.attach(libsumo)


@pytest.mark.parametrize("speed", [math.nan, math.inf, 0.0])
def test_attach_refuses_a_cruising_speed_that_is_no_speed(speed):
    import libsumo

    with pytest.raises(ValueError, match="cruising_speed_mps must be"):
        sumo_swarm.attach(libsumo, cav_type="cav", cruising_speed_mps=speed)


def test_attach_refuses_a_simulation_without_the_sublane_model(tmp_path):
    """Without --lateral-resolution every CAV command fails at every step (SUMO's LC2013 has no
    lcAccelLat): attach() says so at once, in one line, for the controllers that need it."""
    import libsumo

    cfg = write_user_case(tmp_path, HighwaySpec(length_m=500, lanes=3), end_s=5.0)
    command = [c for c in _sumo_cmd(cfg) if c not in ("--lateral-resolution", "0.5")]
    libsumo.start(command)
    try:
        for controller in ("swarm", "cacc"):
            with pytest.raises(ConfigError) as err:
                sumo_swarm.attach(libsumo, cav_type="cav", controller=controller)
            assert "--lateral-resolution" in str(err.value) and "\n" not in str(err.value)
        handle = sumo_swarm.attach(libsumo, cav_type="cav", controller="sumo-lc")
        libsumo.simulation.step()
        handle.detach()
    finally:
        libsumo.close()
