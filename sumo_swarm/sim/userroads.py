"""Users' roads: SUMO configurations written as a new user would write them, to try the swarm
(or any controller) on traffic it was not tuned for.

Each road is a network from :mod:`netbuild`, SUMO's default vehicle type for the traffic (Krauss,
``sigma`` 0.5, a speed factor drawn per vehicle, SUMO's lane changing), ``<flow>`` demand with
``departLane="best"`` and ``departSpeed="max"``, a slow truck (vType ``truck``, ``maxSpeed``
15 m/s) and 5 CAVs of vType ``cav`` (SUMO's defaults but ``sigma="0"``: an automated car does not
dawdle) behind it in the same lane. Nothing else is set: no lateral resolution, no
``lanechange.overtake-right``; the step length is 0.1 s or, with ``step_length_s=None``, SUMO's
default 1 s. Run one with::

    sumo-swarm run --sumocfg DIR/user.sumocfg --cav-type cav --controller swarm

Real motorways, from OpenStreetMap (:data:`OSM_ROADS`, the maps in ``networks/osm/``), are
written the same way with the CAVs inside the traffic instead: netconvert's OSM import
(:func:`~sumo_swarm.sim.netbuild.convert_osm`), ``<flow>`` s from each entry to each exit whose
vehicles SUMO draws from a ``vTypeDistribution`` of SUMO's default car, a truck (vClass
``truck``, SUMO's defaults) and the CAV; ``sumo-swarm run --cav-share`` changes the share
(:func:`osm_cav_share_option`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from sumo_swarm.errors import ConfigError
from sumo_swarm.safexml import parse_xml
from sumo_swarm.sim.netbuild import (
    MOTORWAY_FROM_RAMP,
    MOTORWAY_THROUGH,
    MOTORWAY_TO_RAMP,
    HighwaySpec,
    MotorwaySpec,
    build_highway,
    build_motorway,
    convert_osm,
    edge_ids,
)

CAV_TYPE = "cav"
CAV_COUNT = 5
TRUCK_SPEED_MPS = 15.0
# The truck leads at this position of the first edge [m]; the CAVs follow 15 m apart. CAVs
# departing from a flow enter at the start of the road, so the truck starts nearer to it there
# (the CAVs meet it within the first 30 s).
TRUCK_POS_M = 320.0
TRUCK_POS_CAV_FLOW_M = 100.0
CAV_SPACING_M = 15.0

VTYPES = (
    '  <vType id="car"/>',
    f'  <vType id="truck" vClass="truck" maxSpeed="{TRUCK_SPEED_MPS:g}"/>',
    f'  <vType id="{CAV_TYPE}" sigma="0" color="0,160,255"/>',
)


def _truck_and_cavs(route: str, lane: int, *, cav_flow: bool = False) -> list[str]:
    """The slow truck and, behind it in lane ``lane``, 5 CAVs: placed vehicles or, with
    ``cav_flow``, a ``<flow>`` of CAVs entering the road one every 2 s behind the truck."""
    truck_pos_m = TRUCK_POS_CAV_FLOW_M if cav_flow else TRUCK_POS_M
    lines = [
        f'  <vehicle id="truck" type="truck" route="{route}" depart="0" departLane="{lane}" '
        f'departPos="{truck_pos_m:g}" departSpeed="{TRUCK_SPEED_MPS:g}"/>'
    ]
    if cav_flow:
        lines.append(
            f'  <flow id="cav" type="{CAV_TYPE}" route="{route}" begin="0" number="{CAV_COUNT}" '
            f'period="2" departLane="{lane}" departSpeed="max"/>'
        )
        return lines
    lines += [
        f'  <vehicle id="c{i}" type="{CAV_TYPE}" route="{route}" depart="0" departLane="{lane}" '
        f'departPos="{TRUCK_POS_M - 20 - CAV_SPACING_M * i:g}" '
        f'departSpeed="{TRUCK_SPEED_MPS:g}"/>'
        for i in range(CAV_COUNT)
    ]
    return lines


def _flow(flow_id: str, route: str, veh_per_hour: float, end_s: float, lane: str = "best") -> str:
    return (
        f'  <flow id="{flow_id}" type="car" route="{route}" begin="0" end="{end_s:g}" '
        f'vehsPerHour="{veh_per_hour:g}" departLane="{lane}" departSpeed="max"/>'
    )


def _highway_road(
    spec: HighwaySpec,
    *,
    lane: int,
    flows: tuple[tuple[float, str], ...],
    cav_flow: bool = False,
) -> Callable[[Path, float], tuple[Path, list[str]]]:
    """A road over a :class:`HighwaySpec`: ``flows`` as (veh/h, departLane) pairs."""

    def write(folder: Path, end_s: float) -> tuple[Path, list[str]]:
        net = build_highway(spec, folder, name="road")
        lines = [f'  <route id="r" edges="{" ".join(edge_ids(spec))}"/>']
        lines += _truck_and_cavs("r", lane, cav_flow=cav_flow)
        lines += [_flow(f"f{k}", "r", q, end_s, dl) for k, (q, dl) in enumerate(flows)]
        return net, lines

    return write


def _motorway_road(
    spec: MotorwaySpec, *, through_vph: float, exit_vph: float, ramp_vph: float
) -> Callable[[Path, float], tuple[Path, list[str]]]:
    """A motorway with ramps: through traffic, traffic leaving at the off-ramp and traffic
    merging from the on-ramp; the truck and CAVs in the rightmost through lane."""

    def write(folder: Path, end_s: float) -> tuple[Path, list[str]]:
        net = build_motorway(spec, folder, name="road")
        lines = [
            f'  <route id="through" edges="{" ".join(MOTORWAY_THROUGH)}"/>',
            f'  <route id="exit" edges="{" ".join(MOTORWAY_TO_RAMP)}"/>',
            f'  <route id="ramp" edges="{" ".join(MOTORWAY_FROM_RAMP)}"/>',
        ]
        lines += _truck_and_cavs("through", 0)
        lines += [
            _flow("through", "through", through_vph, end_s),
            _flow("exit", "exit", exit_vph, end_s),
            _flow("ramp", "ramp", ramp_vph, end_s),
        ]
        return net, lines

    return write


@dataclass(frozen=True)
class UserRoad:
    """A named road: ``write(folder, end_s)`` builds its network and returns it with its
    route lines; ``about`` says in a line what a user would see."""

    name: str
    about: str
    write: Callable[[Path, float], tuple[Path, list[str]]]


ROADS: dict[str, UserRoad] = {
    road.name: road
    for road in (
        UserRoad(
            "motorway-ramps",
            "5 lanes, on-ramp with a 250 m acceleration lane, off-ramp with a 200 m deceleration "
            "lane; 600 veh/h/lane through, 300 veh/h exiting, 600 veh/h merging",
            _motorway_road(MotorwaySpec(), through_vph=3000, exit_vph=300, ramp_vph=600),
        ),
        UserRoad(
            "3-lane-900",
            "3 lanes, 3 km, 900 veh/h/lane (departLane=best)",
            _highway_road(HighwaySpec(length_m=3000, lanes=3), lane=0, flows=((2700, "best"),)),
        ),
        UserRoad(
            "3-lane-1800",
            "3 lanes, 3 km, 1800 veh/h/lane (departLane=best)",
            _highway_road(HighwaySpec(length_m=3000, lanes=3), lane=0, flows=((5400, "best"),)),
        ),
        UserRoad(
            "2-lane-passing-flow",
            "2 lanes, 3 km, 900 veh/h in the passing lane, none in the truck's lane",
            _highway_road(HighwaySpec(length_m=3000, lanes=2), lane=0, flows=((900, "1"),)),
        ),
        UserRoad(
            "3-lane-cav-flow",
            "3 lanes, 3 km, 900 veh/h/lane; the 5 CAVs depart from a <flow> behind the truck",
            _highway_road(
                HighwaySpec(length_m=3000, lanes=3),
                lane=0,
                flows=((2700, "best"),),
                cav_flow=True,
            ),
        ),
        UserRoad(
            "3-lane-curve",
            "3 lanes, 2.5 km bending left on a 700 m radius, 1200 veh/h/lane (departLane=best)",
            _highway_road(
                HighwaySpec(length_m=2500, lanes=3, radius_m=700), lane=0, flows=((3600, "best"),)
            ),
        ),
        UserRoad(
            "lane-drop",
            "3 lanes for 1 km, then 2 (the right lane, the truck's, ends) for 1 km; 2400 veh/h",
            _highway_road(
                HighwaySpec(length_m=2000, lanes=(3, 2), edges=2), lane=0, flows=((2400, "best"),)
            ),
        ),
    )
}


# A second set, first run once the swarm's design had settled, as roads it was never tuned on:
# more lanes and fewer, the truck in the middle or the passing lane, a tighter curve, denser
# ramps, a lane drop and a CAV flow at higher demand. Kept apart from ROADS so that the tables
# made over that first set stay what their commands give (tools/user_roads.py --roads).
MORE_ROADS: dict[str, UserRoad] = {
    road.name: road
    for road in (
        UserRoad(
            "4-lane-1500",
            "4 lanes, 3 km, 1500 veh/h/lane (departLane=best)",
            _highway_road(HighwaySpec(length_m=3000, lanes=4), lane=0, flows=((6000, "best"),)),
        ),
        UserRoad(
            "2-lane-1500",
            "2 lanes, 3 km, 1500 veh/h/lane (departLane=best)",
            _highway_road(HighwaySpec(length_m=3000, lanes=2), lane=0, flows=((3000, "best"),)),
        ),
        UserRoad(
            "3-lane-truck-middle",
            "3 lanes, 3 km, the truck and the CAVs in the middle lane, 900 veh/h/lane",
            _highway_road(HighwaySpec(length_m=3000, lanes=3), lane=1, flows=((2700, "best"),)),
        ),
        UserRoad(
            "3-lane-truck-left",
            "3 lanes, 3 km, the truck and the CAVs in the passing lane, 900 veh/h/lane",
            _highway_road(HighwaySpec(length_m=3000, lanes=3), lane=2, flows=((2700, "best"),)),
        ),
        UserRoad(
            "3-lane-curve-400",
            "3 lanes, 2.5 km bending left on a 400 m radius, 1200 veh/h/lane (departLane=best)",
            _highway_road(
                HighwaySpec(length_m=2500, lanes=3, radius_m=400), lane=0, flows=((3600, "best"),)
            ),
        ),
        UserRoad(
            "motorway-3-dense",
            "3 lanes, on-ramp and off-ramp; 1500 veh/h/lane through, 500 veh/h exiting, 900 "
            "veh/h merging",
            _motorway_road(
                MotorwaySpec(through_lanes=3), through_vph=4500, exit_vph=500, ramp_vph=900
            ),
        ),
        UserRoad(
            "lane-drop-1800",
            "3 lanes for 1 km, then 2 (the truck's lane ends) for 1 km; 3600 veh/h",
            _highway_road(
                HighwaySpec(length_m=2000, lanes=(3, 2), edges=2), lane=0, flows=((3600, "best"),)
            ),
        ),
        UserRoad(
            "cav-flow-1800",
            "3 lanes, 3 km, 1800 veh/h/lane; the 5 CAVs depart from a <flow> behind the truck",
            _highway_road(
                HighwaySpec(length_m=3000, lanes=3),
                lane=0,
                flows=((5400, "best"),),
                cav_flow=True,
            ),
        ),
    )
}


def user_road(name: str) -> UserRoad:
    """Road ``name`` of either set (ROADS, MORE_ROADS); ConfigError for an unknown name."""
    road = ROADS.get(name) or MORE_ROADS.get(name)
    if road is None:
        known = ", ".join([*ROADS, *MORE_ROADS])
        raise ConfigError(f"unknown road {name!r}; known: {known}")
    return road


def write_road(
    name: str, folder: Path, *, end_s: float = 90.0, step_length_s: float | None = 0.1
) -> Path:
    """Write road ``name`` (network, ``routes.rou.xml``, ``user.sumocfg``) into ``folder``;
    return the sumocfg. ``end_s`` ends the simulation and the flows [s]; ``step_length_s``
    None leaves the step to SUMO's default (1 s). ConfigError for an unknown name."""
    road = user_road(name)
    folder.mkdir(parents=True, exist_ok=True)
    net, lines = road.write(folder, end_s)
    return _write_sumocfg(folder, net, [*VTYPES, *lines], end_s, step_length_s)


def _write_sumocfg(
    folder: Path, net: Path, route_lines: list[str], end_s: float, step_length_s: float | None
) -> Path:
    """``routes.rou.xml`` of ``route_lines`` and ``user.sumocfg`` over ``net`` in ``folder``;
    return the sumocfg."""
    routes = ["<routes>", *route_lines, "</routes>"]
    (folder / "routes.rou.xml").write_text("\n".join(routes) + "\n", encoding="utf-8")
    step = "" if step_length_s is None else f'    <step-length value="{step_length_s:g}"/>\n'
    cfg = folder / "user.sumocfg"
    cfg.write_text(
        "<configuration>\n  <input>\n"
        f'    <net-file value="{net.name}"/>\n    <route-files value="routes.rou.xml"/>\n'
        f'  </input>\n  <time>\n{step}    <end value="{end_s:g}"/>\n  </time>\n'
        "</configuration>\n",
        encoding="utf-8",
    )
    return cfg


# ----------------------------------------------------------------- real motorways, from OSM

# Traffic on the OSM roads: this share of every flow are trucks, whatever the CAVs' share.
OSM_TRUCK_SHARE = 0.15
OSM_CAV_SHARE = 0.2  # the CAVs' share of every flow in the written configuration
OSM_VTYPES = (
    '  <vType id="car"/>',
    '  <vType id="truck" vClass="truck"/>',
    f'  <vType id="{CAV_TYPE}" sigma="0" color="0,160,255"/>',
)
TRAFFIC = "traffic"  # the vTypeDistribution every flow draws its vehicles from


@dataclass(frozen=True)
class OsmRoad:
    """A motorway mapped in OpenStreetMap (``osm``: a file of ``networks/osm/``) and its demand:
    ``flows`` of (entry node, exit node, veh/h), the nodes being the OSM ids of where a way
    begins (the main road's upstream end, an on-ramp's far end) and where one ends."""

    name: str
    about: str
    osm: str
    flows: tuple[tuple[str, str, float], ...]


OSM_ROADS: dict[str, OsmRoad] = {
    road.name: road
    for road in (
        OsmRoad(
            "osm-5-lane-ramps",
            "5-lane motorway (65 mph), an on-ramp at 0.9 km and an off-ramp at 2.1 km, 3.2 km; "
            "4500 veh/h from upstream (500 of them leaving), 800 veh/h merging",
            "motorway5-ramps.osm",
            (("1001", "1007", 4000), ("1001", "1011", 500), ("1008", "1007", 700),
             ("1008", "1011", 100)),
        ),
        OsmRoad(
            "osm-3-lane-drop",
            "3-lane Autobahn (120 km/h): an exit at 0.8 km, an on-ramp at 1.6 km, the lanes "
            "drop from 3 to 2 at 2.6 km, 3.6 km; 2900 veh/h from upstream (400 leaving), "
            "450 veh/h merging",
            "autobahn3-drop.osm",
            (("2001", "2009", 2500), ("2001", "2011", 400), ("2012", "2009", 450)),
        ),
        OsmRoad(
            "osm-3-lane-junctions",
            "3-lane motorway (70 mph): exits at 0.6, 2.0 and 3.4 km, on-ramps at 1.4 and "
            "2.8 km, 4.0 km; 3400 veh/h from upstream, 400 veh/h at each on-ramp",
            "motorway3-junctions.osm",
            (("3001", "3007", 2600), ("3001", "3009", 300), ("3001", "3013", 250),
             ("3001", "3017", 250), ("3010", "3007", 300), ("3010", "3013", 50),
             ("3010", "3017", 50), ("3014", "3007", 350), ("3014", "3017", 50)),
        ),
    )
}  # fmt: skip


def end_edges(net: Path) -> tuple[dict[str, str], dict[str, str]]:
    """The network's edges by node: ``(leaving, entering)``, node id -> the edge leaving it
    and node id -> the edge entering it (the last one read where several do; the ends of a
    road have one). Internal edges are left out."""
    leaving: dict[str, str] = {}
    entering: dict[str, str] = {}
    for edge in parse_xml(net, "SUMO network").iter("edge"):
        if edge.get("function") == "internal":
            continue
        leaving[edge.get("from", "")] = edge.get("id", "")
        entering[edge.get("to", "")] = edge.get("id", "")
    return leaving, entering


def osm_cav_share_option(cav_share: float) -> float:
    """``sumo-swarm run --cav-share`` (of passenger vehicles, ``--cav-share-of passenger``)
    that makes ``cav_share`` of all vehicles of an OSM road CAVs: the trucks keep their
    :data:`OSM_TRUCK_SHARE`."""
    return cav_share / (1.0 - OSM_TRUCK_SHARE)


def write_osm_road(
    name: str,
    osm_dir: Path,
    folder: Path,
    *,
    end_s: float = 300.0,
    step_length_s: float | None = 0.2,
) -> Path:
    """Write OSM road ``name`` (its network, netconverted from ``osm_dir``'s map,
    ``routes.rou.xml`` and ``user.sumocfg``) into ``folder``; return the sumocfg. Every flow
    runs from 0 to ``end_s`` with ``departLane="best"`` and ``departSpeed="max"``, its vehicles
    drawn as :data:`OSM_TRUCK_SHARE` trucks, :data:`OSM_CAV_SHARE` CAVs and cars the rest.
    ConfigError for an unknown name or a node of the demand the network lacks."""
    road = OSM_ROADS.get(name)
    if road is None:
        raise ConfigError(f"unknown OSM road {name!r}; known: {', '.join(OSM_ROADS)}")
    folder.mkdir(parents=True, exist_ok=True)
    net = convert_osm(osm_dir / road.osm, folder)
    leaving, entering = end_edges(net)
    car = 1.0 - OSM_TRUCK_SHARE - OSM_CAV_SHARE
    lines = [
        *OSM_VTYPES,
        f'  <vTypeDistribution id="{TRAFFIC}" vTypes="car truck {CAV_TYPE}" '
        f'probabilities="{car:g} {OSM_TRUCK_SHARE:g} {OSM_CAV_SHARE:g}"/>',
    ]
    for k, (entry, exit_, veh_per_hour) in enumerate(road.flows):
        if entry not in leaving or exit_ not in entering:
            raise ConfigError(f"{osm_dir / road.osm}: no road leaves {entry} or enters {exit_}")
        lines.append(
            f'  <flow id="f{k}_{entry}_{exit_}" type="{TRAFFIC}" from="{leaving[entry]}" '
            f'to="{entering[exit_]}" begin="0" end="{end_s:g}" vehsPerHour="{veh_per_hour:g}" '
            'departLane="best" departSpeed="max"/>'
        )
    return _write_sumocfg(folder, net, lines, end_s, step_length_s)
