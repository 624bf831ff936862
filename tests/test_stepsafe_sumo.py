"""The bridge's step-safety net (core/stepsafe.py, SumoSession.flush_commands) on real SUMO."""

from __future__ import annotations

from pathlib import Path

import pytest

from sumo_swarm.sim.bridge import SumoSession
from sumo_swarm.sim.netbuild import HighwaySpec, build_highway

ROUTES = """<routes>
    <vType id="cav" tau="0.2" minGap="0.5" decel="4" sigma="0" length="5"/>
    <vType id="car" sigma="0" length="5"/>
    <route id="both" edges="e0 e1"/>
    <route id="last" edges="e1"/>
    <vehicle id="stand" type="car" route="last" depart="0" departPos="8" departSpeed="0"/>
    <vehicle id="c" type="cav" route="both" depart="0" departPos="60" departSpeed="25"/>
</routes>
"""


@pytest.mark.parametrize("step", ["0.5", "1"])
def test_a_cav_stops_for_a_vehicle_standing_beyond_the_road_it_knows(tmp_path: Path, step):
    # The session's road is e0 alone (a CAV whose route leaves it, for an off-ramp); a car
    # stands 8 m into e1. The net looked for leaders on the session's road only: the CAV,
    # commanded at 25 m/s with its short tau (SUMO's own safe speed does not hold within a
    # long step), drove on through the car at 25 m/s. SUMO's leader along the route counts.
    net = build_highway(HighwaySpec(length_m=400.0, lanes=1, edges=2), tmp_path)
    routes = tmp_path / "r.rou.xml"
    routes.write_text(ROUTES, encoding="utf-8")
    args = ["-n", str(net), "-r", str(routes), "--step-length", step, "--no-step-log", "true",
            "--collision.mingap-factor", "0", "--collision.action", "warn",
            "--lateral-resolution", "0.5"]  # fmt: skip
    collisions, fronts = 0, []
    with SumoSession(args, route_edges=["e0"], is_cav=lambda v, t: t.startswith("cav")) as s:
        veh = s.api.vehicle
        s.step()
        veh.setSpeed("stand", 0.0)
        while s.time_s < 20.0:
            if "c" in s.states:
                s.set_speed("c", 25.0)  # a controller that wants to go on
            s.step()
            collisions += s.api.simulation.getCollidingVehiclesNumber()
            if veh.getRoadID("c") == "e1":
                fronts.append(veh.getLanePosition("c"))
        assert veh.getSpeed("c") == 0.0
    assert collisions == 0
    assert fronts and max(fronts) < 8.0 - 5.0  # behind the standing car's rear


BRAKING = """<routes>
    <vType id="cav" tau="1" minGap="2.5" decel="4.5" sigma="0" length="5"/>
    <vType id="car" tau="1" minGap="2.5" decel="4.5" sigma="0" length="5"/>
    <route id="r" edges="e0"/>
    <vehicle id="car" type="car" route="r" depart="0" departPos="100" departSpeed="20"/>
    <vehicle id="c" type="cav" route="r" depart="0" departPos="89" departSpeed="20"
             insertionChecks="none"/>
</routes>
"""


def test_a_released_cav_still_commanded_brakes_at_the_controllers_floor(tmp_path: Path):
    # A CAV that left its platoon: SUMO changes its lanes, a controller still commands its
    # speed (opening the short gap the platoon left: 6 m at 20 m/s). The car ahead brakes at
    # 4.5 m/s^2 to a stop, the controller at its floor of -4 m/s^2. SUMO holds a commanded
    # speed's braking to the vehicle's decel (speed mode 31), which the release lowered to
    # 3.5 m/s^2: the CAV ran 6.6 m into the car. Released at the hard-brake line, 4 m/s^2,
    # it stops behind it.
    net = build_highway(HighwaySpec(length_m=600.0, lanes=1), tmp_path)
    routes = tmp_path / "r.rou.xml"
    routes.write_text(BRAKING, encoding="utf-8")
    args = ["-n", str(net), "-r", str(routes), "--step-length", "0.1", "--no-step-log", "true",
            "--collision.mingap-factor", "0", "--collision.action", "warn",
            "--lateral-resolution", "0.5"]  # fmt: skip
    collisions, gaps, accels = 0, [], []
    with SumoSession(args, route_edges=["e0"], is_cav=lambda v, t: t == "cav") as s:
        veh = s.api.vehicle
        s.step()
        s.configure_cav("c", lane_change_mode=0)
        s.release("c")
        veh.setSpeedMode("car", 0)
        while s.time_s < 8.0:
            veh.setSpeed("car", max(0.0, veh.getSpeed("car") - 0.45))
            s.set_speed("c", max(0.0, s.states["c"].speed_mps - 0.4))
            s.step()
            collisions += s.api.simulation.getCollidingVehiclesNumber()
            gaps.append(veh.getLanePosition("car") - 5.0 - veh.getLanePosition("c"))
            accels.append(veh.getAcceleration("c"))
        assert veh.getSpeed("car") == 0.0 and veh.getSpeed("c") == 0.0
    assert collisions == 0
    assert min(gaps) > 0.0
    assert min(accels) == pytest.approx(-4.0)
