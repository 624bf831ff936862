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
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from sumo_swarm.errors import ConfigError
from sumo_swarm.sim.netbuild import (
    MOTORWAY_FROM_RAMP,
    MOTORWAY_THROUGH,
    MOTORWAY_TO_RAMP,
    HighwaySpec,
    MotorwaySpec,
    build_highway,
    build_motorway,
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


def write_road(
    name: str, folder: Path, *, end_s: float = 90.0, step_length_s: float | None = 0.1
) -> Path:
    """Write road ``name`` (network, ``routes.rou.xml``, ``user.sumocfg``) into ``folder``;
    return the sumocfg. ``end_s`` ends the simulation and the flows [s]; ``step_length_s``
    None leaves the step to SUMO's default (1 s). ConfigError for an unknown name."""
    road = ROADS.get(name)
    if road is None:
        raise ConfigError(f"unknown road {name!r}; known: {', '.join(ROADS)}")
    folder.mkdir(parents=True, exist_ok=True)
    net, lines = road.write(folder, end_s)
    routes = ["<routes>", *VTYPES, *lines, "</routes>"]
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
