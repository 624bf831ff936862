"""Turn a :class:`~sumo_swarm.config.Scenario` into SUMO input: vehicle types, routes, a sumocfg
(and, for a corridor, its network).

File generation (no SUMO import; a corridor's network is built by SUMO's netconvert). The same
traffic is written for every controller; only the CAVs' vehicle type differs, so that the
baselines are judged on the same scene and seed.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from xml.sax.saxutils import quoteattr

from sumo_swarm.config import CorridorSettings, Scenario, load_scenario, read_toml
from sumo_swarm.sim.netbuild import CorridorSpec, build_corridor

ROUTE_ID = "main"
CAV_TYPE = "cav"


@dataclass(frozen=True)
class PlacedVehicle:
    """A vehicle of the scene at t = 0."""

    id: str
    kind: str  # "cav" or "hv"
    type_id: str
    lane: int
    front_m: float
    speed_mps: float
    length_m: float
    role: str = "other"  # "cav", "target", "adjacent", "upstream", "other"


@dataclass(frozen=True)
class Scene:
    vehicles: tuple[PlacedVehicle, ...]
    hv_types: dict[str, float]  # HV vType id -> desired speed [m/s]

    @property
    def cav_ids(self) -> tuple[str, ...]:
        """CAV ids, leader first."""
        return tuple(v.id for v in self.vehicles if v.kind == "cav")

    @property
    def target_id(self) -> str | None:
        return next((v.id for v in self.vehicles if v.role == "target"), None)


def _hv_type(desired_speed: float, types: dict[str, float]) -> str:
    type_id = f"hv_v{desired_speed:g}".replace(".", "_")
    types[type_id] = desired_speed
    return type_id


def build_scene(sc: Scenario) -> Scene:
    """Place every vehicle of the scenario (paper Figure 6)."""
    scene = sc.scene
    cav = sc.cav
    hv = sc.hv
    types: dict[str, float] = {}
    vehicles: list[PlacedVehicle] = []
    for i in range(cav.count):
        front = scene.leader_front_m - i * (cav.length_m + scene.initial_gap_m)
        vehicles.append(
            PlacedVehicle(
                f"cav{i}",
                "cav",
                CAV_TYPE,
                scene.platoon_lane,
                front,
                scene.initial_speed_mps,
                cav.length_m,
                "cav",
            )
        )
    placed = list(scene.hv)
    if not any(p.role == "target" for p in placed):
        # The slow vehicle ahead of the platoon, driving at the initial speed.
        from sumo_swarm.config import HvPlacement

        placed.insert(
            0,
            HvPlacement(
                id="hv_target",
                lane=scene.platoon_lane,
                front_m=scene.leader_front_m + scene.initial_gap_m + hv.length_m,
                speed_mps=scene.initial_speed_mps,
                desired_speed_mps=scene.initial_speed_mps,
                role="target",
            ),
        )
    for p in placed:
        desired = p.desired_speed_mps or hv.desired_speed_mps
        vehicles.append(
            PlacedVehicle(
                p.id,
                "hv",
                _hv_type(desired, types),
                p.lane,
                p.front_m,
                p.speed_mps,
                p.length_m or hv.length_m,
                p.role,
            )
        )
    n_lanes = 1 + max(v.lane for v in vehicles)
    n_lanes = max(n_lanes, 1)
    upstream_type = _hv_type(hv.desired_speed_mps, types)
    for lane in range(n_lanes):
        in_lane = [v for v in vehicles if v.lane == lane]
        if not in_lane:
            continue
        rear = min(v.front_m - v.length_m for v in in_lane)
        for rank in range(1, scene.upstream_per_lane + 1):
            front = rear - scene.upstream_gap_m
            if front - hv.length_m < 0:
                break
            vehicles.append(
                PlacedVehicle(
                    f"up{lane}_{rank}",
                    "hv",
                    upstream_type,
                    lane,
                    front,
                    scene.upstream_speed_mps,
                    hv.length_m,
                    "upstream",
                )
            )
            rear = front - hv.length_m
    return Scene(tuple(vehicles), types)


def cav_vtype_xml(sc: Scenario, controller: str) -> str:
    """The CAVs' vType for one controller (the only thing that differs between runs)."""
    cav = sc.cav
    common = (
        f'id="{CAV_TYPE}" vClass="passenger" length="{cav.length_m}" width="{cav.width_m}" '
        f'accel="{cav.accel_max_mps2}" decel="{-cav.accel_min_mps2}" emergencyDecel="9.0" '
        f'maxSpeedLat="{cav.max_lateral_speed_mps}" latAlignment="center" speedDev="0" '
        'color="0,160,255"'
    )
    # Both SUMO baselines are parametrised so that their equilibrium gap at the initial speed
    # is the paper's desired gap (10 m at 17.5 m/s): minGap + tau * v = desired_gap_m. With
    # SUMO's defaults (tau 1 s) they brake hard at t = 0 in the paper's scene.
    min_gap = 2.5
    v0 = max(sc.scene.initial_speed_mps, 1.0)
    time_gap = max(cav.desired_gap_m - min_gap, 0.5) / v0
    if controller == "sumo-cacc":
        # SUMO's own CACC (Milanes & Shladover); the cruising speed is its maxSpeed.
        return (
            f'<vType {common} maxSpeed="{cav.cruising_speed_mps}" carFollowModel="CACC" '
            f'tau="{time_gap:.3f}" minGap="{min_gap}"/>'
        )
    if controller == "sumo-lc":
        # Ordinary SUMO vehicles: Krauss without dawdling, SUMO's sublane lane changing.
        return (
            f'<vType {common} maxSpeed="{cav.cruising_speed_mps}" carFollowModel="Krauss" '
            f'sigma="0" tau="{0.92 * time_gap:.3f}" minGap="{min_gap}"/>'
        )
    # Our controllers command the speed every step; SUMO's Krauss model with a short tau stays
    # on as a last safety net (speed mode keeps the safe-speed check). With tau 0.2 s and
    # minGap 0.5 m it binds only within about 3 m of a vehicle ahead at 17.5 m/s (measured: with
    # tau 0.5 s and minGap 2 m it already capped a CAV 10 m behind the slow HV at 17.35 m/s).
    # lcAccelLat: the sublane model caps a vehicle's lateral speed at sqrt(2 * lcAccelLat *
    # remaining distance) so it can stop at its target. With the default 1 m/s^2 a per-step
    # command of 0.05 m moved the CAV only 0.009 m per step (0.3 m/s, measured), and a 3 m lane
    # change took 9 s instead of the planned 3 s. At 40 m/s^2 SUMO executes each per-step
    # command exactly (0.05 -> 0.05 m, 0.003 -> 0.003 m); maxSpeedLat still caps the speed.
    # On a corridor the CAVs enter with this vType and SUMO drives them until a platoon takes
    # them (on-ramps, acceleration lanes). Tried instead: sumo-lc's vType (tau 0.39 s, minGap
    # 2.5 m, lcAccelLat 1) for them, set to ours per vehicle when taken (configure_cav): they
    # merged slowly, braked at up to 9 m/s^2 at the ends of the acceleration lanes (4-8 CAV hard
    # brakes in each 600 s run at 20-40 % CAVs, against 0-1) and one stood at a lane's end for
    # minutes; without lcAccelLat 40 alone, 4 hard brakes. Kept as it is.
    return (
        f'<vType {common} maxSpeed="{cav.max_speed_mps}" carFollowModel="Krauss" sigma="0" '
        f'tau="0.2" minGap="0.5" lcAccelLat="40"/>'
    )


def routes_xml(sc: Scenario, scene: Scene, controller: str) -> str:
    hv = sc.hv
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<routes>"]
    lines.append("    " + cav_vtype_xml(sc, controller))
    # Paper: HVs keep their lanes. SUMO's lane-change eagerness parameters at these values
    # switch off strategic, cooperative, speed-gain, keep-right and sublane manoeuvres.
    lc_off = (
        ' lcStrategic="-1" lcCooperative="-1" lcSpeedGain="0" lcKeepRight="0" lcSublane="0"'
        if not hv.lane_changes
        else ""
    )
    for type_id, desired in sorted(scene.hv_types.items()):
        lines.append(
            f'    <vType id="{type_id}" vClass="passenger" length="{hv.length_m}" '
            f'width="{hv.width_m}" carFollowModel="IDM" accel="{hv.accel_mps2}" '
            f'decel="{hv.decel_mps2}" emergencyDecel="{hv.emergency_decel_mps2}" '
            f'tau="{hv.headway_s}" minGap="{hv.min_gap_m}" delta="{hv.delta}" '
            f'maxSpeed="{desired}" speedDev="0" latAlignment="center" color="200,200,200"'
            f"{lc_off}/>"
        )
    edges = " ".join(sc.simulation.route_edges)
    lines.append(f'    <route id="{ROUTE_ID}" edges="{edges}"/>')
    # All vehicles depart at t = 0 at their exact places; insertion checks are off so the scene
    # is exactly the one configured (the scene itself is checked for overlaps in build_scene).
    for v in sorted(scene.vehicles, key=lambda v: -v.front_m):
        lines.append(
            f"    <vehicle id={quoteattr(v.id)} type={quoteattr(v.type_id)} "
            f'route="{ROUTE_ID}" depart="0" departLane="{v.lane}" '
            f'departPos="{v.front_m:.3f}" departSpeed="{v.speed_mps}" '
            f'insertionChecks="none"/>'
        )
    lines.append("</routes>")
    return "\n".join(lines) + "\n"


def sumo_options(sc: Scenario) -> list[str]:
    """SUMO options every run uses (collisions are physical overlaps, counted, never hidden)."""
    sim = sc.simulation
    # One option and its value a line: the formatter would split each pair over two lines.
    return [
        "--step-length", f"{sim.step_length_s}",
        "--lateral-resolution", f"{sim.lateral_resolution_m}",
        "--seed", str(sim.seed),
        "--end", f"{sim.duration_s}",
        "--collision.mingap-factor", "0",
        "--collision.action", "warn",
        "--collision.check-junctions", "true",
        "--time-to-teleport", "-1",
        "--default.speeddev", "0",
        # SUMO forbids passing on the right by default (a European rule): an HV in the right lane
        # would then brake to stay behind CAVs in the middle lane. The paper's highway has no
        # such rule, and the swarm passes the slow vehicle on both sides.
        "--lanechange.overtake-right", "true",
        "--no-step-log", "true",
        "--no-warnings", "true",
    ]  # fmt: skip


def corridor_spec(corridor: CorridorSettings) -> CorridorSpec:
    """The road of a ``[corridor]`` section, for :func:`~sumo_swarm.sim.netbuild.build_corridor`."""
    c = corridor
    return CorridorSpec(
        length_m=c.length_m, lanes=c.lanes, on_ramp_positions_m=c.on_ramp_positions_m,
        off_ramp_positions_m=c.off_ramp_positions_m, accel_lane_m=c.accel_lane_m,
        decel_lane_m=c.decel_lane_m, ramp_m=c.ramp_length_m, lane_width_m=c.lane_width_m,
        speed_mps=c.speed_limit_mps, ramp_speed_mps=c.ramp_speed_limit_mps,
    )  # fmt: skip


def route_edges(sc: Scenario) -> tuple[str, ...]:
    """The run's route frame (``s_m`` runs along it): a corridor's main road, else
    ``simulation.route_edges``."""
    if sc.corridor is not None:
        return corridor_spec(sc.corridor).through_edges()
    return sc.simulation.route_edges


# The vType ids of a corridor's cars and trucks (its CAVs': CAV_TYPE).
CAR_TYPE = "car"
TRUCK_TYPE = "truck"


@dataclass(frozen=True)
class CorridorFlow:
    """One ``<flow>`` of a corridor: ``rate_vph`` vehicles of vType ``type_id`` per hour on
    ``route`` from ``origin`` to ``destination`` (``main`` / ``end``, or a ramp's edge id)."""

    origin: str
    destination: str
    type_id: str
    route: tuple[str, ...]
    rate_vph: float

    @property
    def id(self) -> str:
        return f"{self.origin}_{self.destination}_{self.type_id}"


def corridor_flows(corridor: CorridorSettings) -> list[CorridorFlow]:
    """Every origin-destination-class flow of a corridor with a positive rate.

    Origins: the upstream end (``main``: ``lanes * main_demand_vph_per_lane``) and each on-ramp;
    destinations: each off-ramp downstream of the origin, which takes its share of what passes
    it, and the downstream end (``end``), which takes the rest. Each flow is split by class:
    ``cav_share``, ``truck_share``, and cars the rest."""
    c = corridor
    spec = corridor_spec(c)
    classes = (
        (CAR_TYPE, 1.0 - c.cav_share - c.truck_share),
        (TRUCK_TYPE, c.truck_share),
        (CAV_TYPE, c.cav_share),
    )
    origins = [(None, "main", c.lanes * c.main_demand_vph_per_lane)]
    origins += [(i, f"on{i}", d) for i, d in enumerate(c.on_ramp_demands_vph)]
    flows = []
    for on_ramp, origin, demand in origins:
        staying = 1.0  # the share of this origin's traffic still on the main road
        splits = []
        for j, share in enumerate(c.off_ramp_shares):
            route = spec.route(on_ramp, j)
            if route is not None:
                splits.append((f"off{j}", route, staying * share))
                staying *= 1.0 - share
        splits.append(("end", spec.route(on_ramp, None), staying))
        for destination, route, split in splits:
            for type_id, share in classes:
                rate = demand * split * share
                if rate > 0.0:
                    flows.append(CorridorFlow(origin, destination, type_id, route, rate))
    return flows


def corridor_routes_xml(sc: Scenario, controller: str) -> str:
    """The corridor's routes file: the three vTypes (the CAVs' per ``controller``, cars, trucks),
    a route per origin and destination, and the flows of :func:`corridor_flows`."""
    c = sc.corridor
    end = sc.simulation.duration_s
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<routes>"]
    lines.append("    " + cav_vtype_xml(sc, controller))
    # Cars: SUMO's default passenger vType, its speed spread written out (the run's
    # --default.speeddev 0 is for the paper's scenes). Trucks: see CorridorSettings.
    lines.append(f'    <vType id="{CAR_TYPE}" vClass="passenger" speedDev="{c.speed_dev}"/>')
    lines.append(
        f'    <vType id="{TRUCK_TYPE}" vClass="trailer" desiredMaxSpeed="'
        f'{c.truck_desired_speed_mps}" maxSpeed="{c.truck_max_speed_mps}" '
        f'speedDev="{c.speed_dev}" color="160,80,0"/>'
    )
    flows = corridor_flows(c)
    routes = {(f.origin, f.destination): f.route for f in flows}
    for (origin, destination), edges in routes.items():
        lines.append(f'    <route id="{origin}_{destination}" edges="{" ".join(edges)}"/>')
    for f in flows:
        rate = (
            f'period="exp({f.rate_vph / 3600.0:.9g})"'
            if c.arrivals == "poisson"
            else f'vehsPerHour="{f.rate_vph:.6g}"'
        )
        lines.append(
            f'    <flow id="{f.id}" type="{f.type_id}" route="{f.origin}_{f.destination}" '
            f'begin="0" end="{end:g}" {rate} departLane="best" departSpeed="max"/>'
        )
    lines.append("</routes>")
    return "\n".join(lines) + "\n"


def write_sumo_inputs(
    sc: Scenario, controller: str, folder: Path, outputs: Sequence[str] = ()
) -> tuple[Path, Scene | None]:
    """Write ``routes.rou.xml`` and ``scenario.sumocfg`` into ``folder``; return the sumocfg
    and the placed scene. A corridor (``[corridor]``) also gets its network built there
    (``corridor.net.xml``); it has no placed scene (None): its CAVs are those SUMO inserts.
    ``outputs``: the run's output options (``--name value`` pairs,
    :func:`~sumo_swarm.sim.network.network_options`), written into the configuration too, so
    that ``sumo -c scenario.sumocfg`` is the run's simulation with the run's SUMO outputs."""
    folder.mkdir(parents=True, exist_ok=True)
    routes = folder / "routes.rou.xml"
    if sc.corridor is not None:
        scene = None
        net = build_corridor(corridor_spec(sc.corridor), folder)
        routes.write_text(corridor_routes_xml(sc, controller), encoding="utf-8")
    else:
        scene = build_scene(sc)
        net = sc.network_path
        routes.write_text(routes_xml(sc, scene, controller), encoding="utf-8")
    cfg = folder / "scenario.sumocfg"
    # SUMO reads the config's paths relative to the config: a network built into the folder is
    # named by its file name (a relative --out gave "out/sumo/out/sumo/corridor.net.xml").
    net_value = net.name if net.parent.resolve() == folder.resolve() else str(Path(net).resolve())
    sections = [("processing", sumo_options(sc))]
    if outputs:
        sections.append(("output", list(outputs)))
    body = "".join(
        f"    <{section}>\n{_option_lines(opts)}    </{section}>\n" for section, opts in sections
    )
    cfg.write_text(
        '<?xml version="1.0" encoding="UTF-8"?>\n<configuration>\n    <input>\n'
        f"        <net-file value={quoteattr(net_value)}/>\n"
        f'        <route-files value="{routes.name}"/>\n    </input>\n'
        f"{body}</configuration>\n",
        encoding="utf-8",
    )
    return cfg, scene


def _option_lines(opts: Sequence[str]) -> str:
    """SUMO command-line options (``--name value`` pairs) as lines of a configuration file
    (SUMO reads an option by its name in any section)."""
    pairs = [(opts[i].removeprefix("--"), opts[i + 1]) for i in range(0, len(opts), 2)]
    return "".join(f"        <{k} value={quoteattr(v)}/>\n" for k, v in pairs)


def default_settings(config: str | Path | Scenario | None) -> Scenario:
    """The swarm's settings on a simulation no scenario describes (a user's sumocfg, or
    ``attach()``): a Scenario object, a scenario/settings TOML, or the defaults."""
    if isinstance(config, Scenario):
        return config
    if config is None:
        return _world_speeds(Scenario(name="attached", path=Path.cwd() / "attached.toml"))
    settings = load_scenario(config, require_network=False)
    cav = read_toml(Path(config), "scenario file").get("cav", {})
    if not isinstance(cav, dict) or not WORLD_SPEED_KEYS & set(cav):
        settings = _world_speeds(settings)
    return settings


# A user's config setting any of these keys takes the CAVs' speeds from the config, not from the
# CAVs' vType and the lanes (``[cav] speeds``).
WORLD_SPEED_KEYS = frozenset({"cruising_speed_mps", "max_speed_mps", "speeds"})


def _world_speeds(settings: Scenario) -> Scenario:
    """``settings`` with ``[cav] speeds = "world"``: on a user's network the CAVs drive at SUMO's
    desired speed for them, never at the paper's 20 m/s."""
    return replace(settings, cav=replace(settings.cav, speeds="world"))


class LiveScene:
    """The scene as SUMO placed it (a user's configuration, or the plugin API): the CAVs that
    have departed so far and the target the controller chose."""

    def __init__(self, session, controller) -> None:
        self._session = session
        self._controller = controller

    @property
    def cav_ids(self) -> tuple[str, ...]:
        return tuple(self._session.cav_ids)

    @property
    def target_id(self) -> str | None:
        return getattr(self._controller, "target_id", None)
