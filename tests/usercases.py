"""SUMO configurations as a user would have them: networks built here, not the paper's."""

from __future__ import annotations

from pathlib import Path

from sumo_swarm.sim.netbuild import HighwaySpec, build_highway, edge_ids


def write_user_case(
    folder: Path,
    spec: HighwaySpec,
    *,
    platoon_lane: int = 1,
    truck_speed_mps: float = 16.0,
    cav_count: int = 6,
    hv_lanes: tuple[int, ...] | None = None,
    end_s: float = 90.0,
    lateral_resolution: float | None = None,
) -> Path:
    """A sumocfg with a slow truck ahead of ``cav_count`` CAVs of vType ``cav`` and IDM traffic
    in the other lanes; returns its path."""
    net = build_highway(spec, folder)
    edges = " ".join(edge_ids(spec))
    n_lanes = spec.lanes_of(0)
    if hv_lanes is None:
        hv_lanes = tuple(q for q in range(n_lanes) if q != platoon_lane)
    leader = 300.0
    lines = [
        "<routes>",
        '  <vType id="cav" length="5" maxSpeed="20" accel="3" decel="4" sigma="0" '
        'color="0,160,255"/>',
        f'  <vType id="truck" length="12" maxSpeed="{truck_speed_mps:.2f}" vClass="truck" '
        'carFollowModel="IDM" speedDev="0" lcStrategic="-1" lcSpeedGain="0" lcKeepRight="0" '
        'lcCooperative="-1"/>',
        # Cars keep their lanes unless their lane ends (strategic changes stay on).
        '  <vType id="car" length="4.5" carFollowModel="IDM" tau="1.2" accel="0.73" decel="1.67" '
        f'maxSpeed="{truck_speed_mps:.2f}" speedDev="0" lcSpeedGain="0" lcKeepRight="0"/>',
        f'  <route id="r" edges="{edges}"/>',
        f'  <vehicle id="truck" type="truck" route="r" depart="0" departLane="{platoon_lane}" '
        f'departPos="{leader + 10 + 12}" departSpeed="{truck_speed_mps}"/>',
    ]
    for i in range(cav_count):
        lines.append(
            f'  <vehicle id="c{i}" type="cav" route="r" depart="0" departLane="{platoon_lane}" '
            f'departPos="{leader - 15 * i}" departSpeed="{truck_speed_mps}"/>'
        )
    for lane in hv_lanes:
        for k in range(3):
            lines.append(
                f'  <vehicle id="h{lane}_{k}" type="car" route="r" depart="0" '
                f'departLane="{lane}" departPos="{leader - 40 - 35 * k}" '
                f'departSpeed="{truck_speed_mps}"/>'
            )
    lines.append("</routes>")
    (folder / "routes.rou.xml").write_text("\n".join(lines) + "\n", encoding="utf-8")
    lat = (
        f'    <lateral-resolution value="{lateral_resolution}"/>\n'
        if lateral_resolution is not None
        else ""
    )
    cfg = folder / "user.sumocfg"
    cfg.write_text(
        "<configuration>\n  <input>\n"
        f'    <net-file value="{net.name}"/>\n    <route-files value="routes.rou.xml"/>\n'
        "  </input>\n  <time>\n"
        f'    <step-length value="0.1"/>\n    <end value="{end_s}"/>\n'
        f"  </time>\n  <processing>\n{lat}"
        '    <lanechange.overtake-right value="true"/>\n'
        "  </processing>\n</configuration>\n",
        encoding="utf-8",
    )
    return cfg


def write_exit_case(
    folder: Path, *, exiting: tuple[int, ...] = (1, 3), end_s: float = 100.0
) -> Path:
    """A 3-lane motorway with an on- and an off-ramp (netbuild), SUMO's default cars at
    600 veh/h/lane, a slow truck and 5 CAVs (``c0``..``c4``) behind it in the right lane; the
    CAVs in ``exiting`` take the off-ramp, the others drive through. Returns the sumocfg."""
    from sumo_swarm.sim.netbuild import (
        MOTORWAY_THROUGH,
        MOTORWAY_TO_RAMP,
        MotorwaySpec,
        build_motorway,
    )

    spec = MotorwaySpec(through_lanes=3, upstream_m=700.0, weave_m=900.0, downstream_m=600.0)
    net = build_motorway(spec, folder, name="road")
    lines = [
        "<routes>",
        '  <vType id="car"/>',
        '  <vType id="truck" vClass="truck" maxSpeed="15"/>',
        '  <vType id="cav" sigma="0" color="0,160,255"/>',
        f'  <route id="through" edges="{" ".join(MOTORWAY_THROUGH)}"/>',
        f'  <route id="exit" edges="{" ".join(MOTORWAY_TO_RAMP)}"/>',
        '  <vehicle id="truck" type="truck" route="through" depart="0" departLane="0" '
        'departPos="320" departSpeed="15"/>',
    ]
    for i in range(5):
        route = "exit" if i in exiting else "through"
        lines.append(
            f'  <vehicle id="c{i}" type="cav" route="{route}" depart="0" departLane="0" '
            f'departPos="{300 - 15 * i}" departSpeed="15"/>'
        )
    lines += [
        f'  <flow id="f{lane}" type="car" route="through" begin="0" end="{end_s:g}" '
        f'vehsPerHour="600" departLane="{lane}" departSpeed="max"/>'
        for lane in range(3)
    ]
    lines.append("</routes>")
    (folder / "routes.rou.xml").write_text("\n".join(lines) + "\n", encoding="utf-8")
    cfg = folder / "user.sumocfg"
    cfg.write_text(
        "<configuration>\n  <input>\n"
        f'    <net-file value="{net.name}"/>\n    <route-files value="routes.rou.xml"/>\n'
        '  </input>\n  <time>\n    <step-length value="0.1"/>\n'
        f'    <end value="{end_s:g}"/>\n  </time>\n</configuration>\n',
        encoding="utf-8",
    )
    return cfg


def write_mixed_case(
    folder: Path,
    *,
    length_m: float = 1500.0,
    lanes: int = 2,
    rate_vph: float = 1800.0,
    flow_end_s: float = 40.0,
    end_s: float = 60.0,
    cav_probability: float = 0.2,
    extra: str = "",
) -> Path:
    """A sumocfg as a corridor study would have it: a slow truck ahead, and a flow that draws
    its vehicles from the vTypeDistribution ``traffic`` (cars of vType ``car``, with SUMO's
    driver imperfection, so that the seed shows; CAVs of vType ``cav`` with probability
    ``cav_probability``), departing at random (``probability``) on the first edge; a flow of
    ``lorry`` trucks (vClass truck) now and then. ``extra`` is added to the routes file.
    Returns the sumocfg (``road.sumocfg``)."""
    spec = HighwaySpec(length_m=length_m, lanes=lanes)
    net = build_highway(spec, folder)
    edges = " ".join(edge_ids(spec))
    per_step = rate_vph / 3600.0
    routes = f"""<routes>
    <vType id="car" length="4.5" maxSpeed="25" sigma="0.5" speedFactor="1" speedDev="0.1"/>
    <vType id="cav" length="5" maxSpeed="25" accel="3" decel="4" sigma="0" color="0,160,255"/>
    <vType id="lorry" vClass="truck" length="12" maxSpeed="14" speedDev="0"/>
    <vTypeDistribution id="traffic" vTypes="car cav"
        probabilities="{1.0 - cav_probability:g} {cav_probability:g}"/>
    <route id="r" edges="{edges}"/>
    <vehicle id="slow" type="lorry" route="r" depart="0" departLane="0" departPos="200"
        departSpeed="14"/>
    <flow id="main" type="traffic" route="r" begin="0" end="{flow_end_s:g}"
        probability="{per_step:.6f}" departLane="random" departSpeed="max"/>
    <flow id="lorries" type="lorry" route="r" begin="0" end="{flow_end_s:g}" number="2"
        departLane="0" departSpeed="max"/>
{extra}</routes>
"""
    (folder / "routes.rou.xml").write_text(routes, encoding="utf-8")
    cfg = folder / "road.sumocfg"
    cfg.write_text(
        "<configuration>\n  <input>\n"
        f'    <net-file value="{net.name}"/>\n    <route-files value="routes.rou.xml"/>\n'
        "  </input>\n  <time>\n"
        f'    <step-length value="0.1"/>\n    <end value="{end_s:g}"/>\n'
        "  </time>\n</configuration>\n",
        encoding="utf-8",
    )
    return cfg
