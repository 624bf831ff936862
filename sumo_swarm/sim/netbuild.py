"""Build small highway networks with SUMO's netconvert (from the eclipse-sumo package).

Used by the tests, the stress sweep and users who want a quick test bed: straight or curved,
2 to 5 lanes, one or several edges, optionally a lane drop (the rightmost lanes end: netconvert
keeps the lanes on the left going); and a
straight motorway with an on-ramp (acceleration lane) and an off-ramp (deceleration lane); and
a motorway corridor of any length with any number of on- and off-ramps (the corridor scenarios,
``[corridor]`` in a scenario file); and, from an OpenStreetMap file, whatever road it maps
(:func:`convert_osm`, netconvert's OSM import as SUMO's documentation recommends it).
"""

from __future__ import annotations

import itertools
import math
import os
import subprocess
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

from sumo_swarm.config import corridor_ramp_lanes
from sumo_swarm.errors import ConfigError


@dataclass(frozen=True)
class HighwaySpec:
    """A highway: ``edges`` pieces of ``length_m / edges`` metres each.

    ``lanes`` per edge (an int for all, or one per edge: fewer lanes on a later edge is a lane
    drop; netconvert ends the rightmost lanes, as where a merging lane ends). ``radius_m``
    bends the whole road into an arc turning left (None: straight). Lanes are
    ``lane_width_m`` wide; ``speed_mps`` is the speed limit.
    """

    length_m: float = 2000.0
    lanes: int | tuple[int, ...] = 3
    edges: int = 1
    lane_width_m: float = 3.0
    radius_m: float | None = None
    speed_mps: float = 33.33

    def lanes_of(self, i: int) -> int:
        return self.lanes if isinstance(self.lanes, int) else self.lanes[i]

    def __post_init__(self) -> None:
        if self.edges < 1:
            raise ConfigError(f"edges must be >= 1, got {self.edges}")
        counts = [self.lanes_of(i) for i in range(self.edges)]
        if any(n < 1 for n in counts):
            raise ConfigError(f"lanes must be >= 1, got {self.lanes}")
        if self.length_m <= 0 or self.lane_width_m <= 0 or self.speed_mps <= 0:
            raise ConfigError("length_m, lane_width_m and speed_mps must be > 0")
        if self.radius_m is not None and self.radius_m <= 0:
            raise ConfigError(f"radius_m must be > 0, got {self.radius_m}")


def _point(spec: HighwaySpec, s: float) -> tuple[float, float]:
    if spec.radius_m is None:
        return (s, 0.0)
    r = spec.radius_m
    angle = s / r
    return (r * math.sin(angle), r * (1.0 - math.cos(angle)))


def edge_ids(spec: HighwaySpec) -> list[str]:
    return [f"e{i}" for i in range(spec.edges)]


def build_highway(spec: HighwaySpec, folder: Path, name: str = "highway") -> Path:
    """Write ``name.nod.xml``/``name.edg.xml`` into ``folder`` and netconvert them to
    ``name.net.xml``; return the network path."""

    folder.mkdir(parents=True, exist_ok=True)
    piece = spec.length_m / spec.edges
    nodes = ['<?xml version="1.0" encoding="UTF-8"?>', "<nodes>"]
    for i in range(spec.edges + 1):
        x, y = _point(spec, i * piece)
        nodes.append(f'    <node id="n{i}" x="{x:.3f}" y="{y:.3f}" type="priority"/>')
    nodes.append("</nodes>")
    edges = ['<?xml version="1.0" encoding="UTF-8"?>', "<edges>"]
    for i, edge in enumerate(edge_ids(spec)):
        shape = ""
        if spec.radius_m is not None:
            n_pts = max(2, int(piece / 5.0) + 1)
            pts = [_point(spec, i * piece + piece * k / (n_pts - 1)) for k in range(n_pts)]
            shape = ' shape="' + " ".join(f"{x:.3f},{y:.3f}" for x, y in pts) + '"'
        edges.append(
            f'    <edge id="{edge}" from="n{i}" to="n{i + 1}" priority="3" '
            f'numLanes="{spec.lanes_of(i)}" speed="{spec.speed_mps}" '
            f'width="{spec.lane_width_m}"{shape}/>'
        )
    edges.append("</edges>")
    return _netconvert(folder, name, nodes, edges)


def netconvert_binary() -> Path:
    """SUMO's netconvert, from the eclipse-sumo package."""
    import sumo

    return Path(sumo.SUMO_HOME) / "bin" / "netconvert"


# What SUMO's documentation recommends for importing OpenStreetMap ("Recommended netconvert
# Options"), less the traffic-light options a motorway does not need: geometry-only nodes
# removed, on- and off-ramps given their acceleration and deceleration lanes, the nodes of one
# intersection joined.
OSM_OPTIONS = ("--geometry.remove", "--ramps.guess", "--junctions.join")


def convert_osm(osm: Path, folder: Path, name: str = "road") -> Path:
    """netconvert an OpenStreetMap file as a user does (:data:`OSM_OPTIONS`, SUMO's built-in
    type map) into ``folder/name.net.xml``; return the network path. ConfigError naming the
    file with netconvert's message if it fails."""
    import sumo

    if not osm.is_file():
        raise ConfigError(f"OpenStreetMap file not found: {osm}")
    folder.mkdir(parents=True, exist_ok=True)
    net = folder / f"{name}.net.xml"
    home = Path(sumo.SUMO_HOME)
    # SUMO_HOME: netconvert finds its type maps; PROJ_LIB: PROJ finds its database for the
    # projection to UTM (the pip package's own copy).
    env = {**os.environ, "SUMO_HOME": str(home), "PROJ_LIB": str(home / "data" / "proj")}
    cmd = [
        str(netconvert_binary()), "--osm-files", str(osm.resolve()), "--output-file", net.name,
        *OSM_OPTIONS, "--no-warnings", "true",
    ]  # fmt: skip
    proc = subprocess.run(cmd, cwd=folder, capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        message = proc.stderr.strip().splitlines()
        raise ConfigError(f"netconvert failed for {osm}: {message[-1] if message else ''}")
    return net


def _netconvert(
    folder: Path,
    name: str,
    nodes: list[str],
    edges: list[str],
    connections: list[str] | None = None,
) -> Path:
    """Write the plain XML files (nodes, edges, optional connections) into ``folder`` and
    netconvert them to ``name.net.xml``; ConfigError with netconvert's message if it fails."""
    files = {"node-files": (f"{name}.nod.xml", nodes), "edge-files": (f"{name}.edg.xml", edges)}
    if connections is not None:
        files["connection-files"] = (f"{name}.con.xml", connections)
    cmd = [str(netconvert_binary())]
    for option, (file_name, lines) in files.items():
        (folder / file_name).write_text("\n".join(lines) + "\n", encoding="utf-8")
        cmd += [f"--{option}", file_name]
    net = folder / f"{name}.net.xml"
    cmd += [
        "--output-file", net.name, "--no-turnarounds", "true", "--no-warnings", "true",
        "--geometry.avoid-overlap", "false",
    ]  # fmt: skip
    proc = subprocess.run(cmd, cwd=folder, capture_output=True, text=True)
    if proc.returncode != 0:
        raise ConfigError(f"netconvert failed for {folder / name}: {proc.stderr.strip()}")
    return net


@dataclass(frozen=True)
class MotorwaySpec:
    """A straight motorway of ``through_lanes`` lanes with an on-ramp and, later, an off-ramp.

    Edges in driving order: ``up`` (``upstream_m``), ``acc`` (``accel_lane_m``: the on-ramp ``on``
    joins as an extra rightmost lane, the acceleration lane, which ends with the edge), ``mid``
    (``weave_m``), ``dec`` (``decel_lane_m``: an extra rightmost lane, the deceleration lane, that
    leads to the off-ramp ``off``), ``down`` (``downstream_m``). Ramps are one lane,
    ``ramp_m`` long with the limit ``ramp_speed_mps``; lanes are ``lane_width_m`` wide (SUMO's
    default 3.2 m); the motorway's limit is ``speed_mps``.
    """

    through_lanes: int = 5
    upstream_m: float = 800.0
    accel_lane_m: float = 250.0
    weave_m: float = 700.0
    decel_lane_m: float = 200.0
    downstream_m: float = 500.0
    ramp_m: float = 250.0
    lane_width_m: float = 3.2
    speed_mps: float = 33.33
    ramp_speed_mps: float = 22.22

    def __post_init__(self) -> None:
        if self.through_lanes < 1:
            raise ConfigError(f"through_lanes must be >= 1, got {self.through_lanes}")
        sizes = (
            self.upstream_m, self.accel_lane_m, self.weave_m, self.decel_lane_m,
            self.downstream_m, self.ramp_m, self.lane_width_m, self.speed_mps,
            self.ramp_speed_mps,
        )  # fmt: skip
        if any(not v > 0 for v in sizes):
            raise ConfigError("the lengths, lane width and speed limits of a motorway must be > 0")


# Routes over a MotorwaySpec network: through traffic, traffic from the on-ramp, exiting traffic.
MOTORWAY_THROUGH = ("up", "acc", "mid", "dec", "down")
MOTORWAY_FROM_RAMP = ("on", "acc", "mid", "dec", "down")
MOTORWAY_TO_RAMP = ("up", "acc", "mid", "dec", "off")


def build_motorway(spec: MotorwaySpec, folder: Path, name: str = "motorway") -> Path:
    """Write the plain XML of ``spec`` into ``folder`` and netconvert it to ``name.net.xml``;
    return the network path. Lanes are given explicitly (connection file) so that the
    acceleration lane ends and the deceleration lane leads only to the off-ramp."""
    x1 = spec.upstream_m
    x2 = x1 + spec.accel_lane_m
    x3 = x2 + spec.weave_m
    x4 = x3 + spec.decel_lane_m
    pieces = (
        Piece("up", 0.0, x1), Piece("acc", x1, x2, "acc", ramp="on"), Piece("mid", x2, x3),
        Piece("dec", x3, x4, "dec", ramp="off"), Piece("down", x4, x4 + spec.downstream_m),
    )  # fmt: skip
    road = RampedRoad(
        pieces, spec.through_lanes, spec.lane_width_m, spec.speed_mps, spec.ramp_m,
        spec.ramp_speed_mps,
    )  # fmt: skip
    return build_ramped_road(road, folder, name)


@dataclass(frozen=True)
class Piece:
    """One edge of a straight main road, from ``start_m`` to ``end_m`` along it [m].

    ``aux``: None (the through lanes only), ``"acc"`` (an acceleration lane: the on-ramp
    ``ramp`` joins at ``start_m`` as an extra rightmost lane that ends with the piece) or
    ``"dec"`` (a deceleration lane: an extra rightmost lane that begins with the piece and leads
    only to the off-ramp ``ramp``, which leaves at ``end_m``).
    """

    id: str
    start_m: float
    end_m: float
    aux: Literal["acc", "dec"] | None = None
    ramp: str | None = None


@dataclass(frozen=True)
class RampedRoad:
    """A straight main road of ``pieces`` (in driving order, each starting where the one before
    ends) with ``lanes``
    through lanes ``lane_width_m`` wide at the limit ``speed_mps``; every ramp is one lane,
    ``ramp_m`` long, at the limit ``ramp_speed_mps``."""

    pieces: tuple[Piece, ...]
    lanes: int
    lane_width_m: float
    speed_mps: float
    ramp_m: float
    ramp_speed_mps: float


def build_ramped_road(road: RampedRoad, folder: Path, name: str) -> Path:
    """Write the plain XML of ``road`` into ``folder`` and netconvert it to ``name.net.xml``;
    return the network path. Nodes: ``n0``... along the main road, ``r0``... at the ramps' far
    ends in driving order. Lanes are connected explicitly (a connection file): acceleration
    lanes end, deceleration lanes lead only to their off-ramp, through lanes keep their order."""
    folder.mkdir(parents=True, exist_ok=True)
    n = road.lanes
    pieces = road.pieces
    # The ramps leave at a 1:10 slope on the right (negative y when driving along +x).
    ramp_dx = road.ramp_m * math.cos(math.atan(0.1))
    ramp_dy = -road.ramp_m * math.sin(math.atan(0.1))
    points = {f"n{k}": (p.start_m, 0.0) for k, p in enumerate(pieces)}
    points[f"n{len(pieces)}"] = (pieces[-1].end_m, 0.0)
    # id, from, to, lanes, speed limit, priority (the main road has right of way over the ramps)
    edge_rows = [
        (p.id, f"n{k}", f"n{k + 1}", n + (p.aux is not None), road.speed_mps, 3)
        for k, p in enumerate(pieces)
    ]
    links = []  # (from edge, from lane, to edge, to lane)
    ramped = [(k, p) for k, p in enumerate(pieces) if p.aux is not None]
    for r, (k, p) in enumerate(ramped):
        far = f"r{r}"
        if p.aux == "acc":
            points[far] = (p.start_m - ramp_dx, ramp_dy)
            edge_rows.append((p.ramp, far, f"n{k}", 1, road.ramp_speed_mps, 1))
            links.append((p.ramp, 0, p.id, 0))
        else:
            points[far] = (p.end_m + ramp_dx, ramp_dy)
            edge_rows.append((p.ramp, f"n{k + 1}", far, 1, road.ramp_speed_mps, 1))
            links.append((p.id, 0, p.ramp, 0))
    for a, b in itertools.pairwise(pieces):
        first_from = int(a.aux is not None)  # an auxiliary lane is lane 0: through lanes from 1
        first_to = int(b.aux is not None)
        # A deceleration lane begins beside the rightmost through lane and is entered by a lane
        # change along it, as on a motorway: no lane of the junction before it turns into it.
        # With such a turn (the rightmost through lane feeding both), the sublane model let two
        # vehicles abreast in that lane take the turn together, and their bodies, turned by
        # 3.5 m within the junction, overlapped: the corridor's four collisions (a CAV and a
        # car, a car and a car under sumo-lc, two with trucks; 20-40 % CAVs, 1500 veh/h/lane).
        links += [(a.id, first_from + i, b.id, first_to + i) for i in range(n)]
    nodes = ['<?xml version="1.0" encoding="UTF-8"?>', "<nodes>"]
    nodes += [
        f'    <node id="{node}" x="{x:.3f}" y="{y:.3f}" type="priority"/>'
        for node, (x, y) in points.items()
    ]
    nodes.append("</nodes>")
    edges = ['<?xml version="1.0" encoding="UTF-8"?>', "<edges>"]
    edges += [
        f'    <edge id="{edge}" from="{a}" to="{b}" priority="{prio}" numLanes="{lanes}" '
        f'speed="{speed}" width="{road.lane_width_m}"/>'
        for edge, a, b, lanes, speed, prio in edge_rows
    ]
    edges.append("</edges>")
    connections = ['<?xml version="1.0" encoding="UTF-8"?>', "<connections>"]
    connections += [
        f'    <connection from="{a}" to="{b}" fromLane="{la}" toLane="{lb}"/>'
        for a, la, b, lb in links
    ]
    connections.append("</connections>")
    return _netconvert(folder, name, nodes, edges, connections)


@dataclass(frozen=True)
class CorridorSpec:
    """A straight motorway corridor ``length_m`` long with ``lanes`` through lanes and ramps.

    ``on_ramp_positions_m``: where each on-ramp joins the main road, i.e. where its acceleration
    lane (``accel_lane_m``) begins; ``off_ramp_positions_m``: where each off-ramp leaves, i.e.
    where its deceleration lane (``decel_lane_m``) ends; both in metres from the upstream end,
    increasing. Every ramp lane lies on the road with at least
    :data:`~sumo_swarm.config.CORRIDOR_MIN_PIECE_M` of plain road before, between and after
    them (:func:`~sumo_swarm.config.corridor_ramp_lanes`, the check of ``[corridor]``).

    Edge ids: the main road's pieces in driving order (:meth:`through_edges`, the main through
    route) are ``acc{i}`` (the acceleration lane of on-ramp ``i``, an extra rightmost lane that
    ends with the edge), ``dec{j}`` (the deceleration lane of off-ramp ``j``, an extra
    rightmost lane that leads only to the ramp) and ``m0``, ``m1``, ... (the plain road before,
    between and after them); the ramps are ``on{i}`` and ``off{j}``, ``ramp_m`` long at
    ``ramp_speed_mps``. Ramps are numbered from upstream. Lanes are ``lane_width_m`` wide; the
    limit is ``speed_mps``.
    """

    length_m: float = 6000.0
    lanes: int = 3
    on_ramp_positions_m: tuple[float, ...] = ()
    off_ramp_positions_m: tuple[float, ...] = ()
    accel_lane_m: float = 250.0
    decel_lane_m: float = 250.0
    ramp_m: float = 300.0
    lane_width_m: float = 3.5
    speed_mps: float = 33.33
    ramp_speed_mps: float = 22.22

    def __post_init__(self) -> None:
        if self.lanes < 1:
            raise ConfigError(f"lanes must be >= 1, got {self.lanes}")
        sizes = (
            self.length_m, self.accel_lane_m, self.decel_lane_m, self.ramp_m,
            self.lane_width_m, self.speed_mps, self.ramp_speed_mps,
        )  # fmt: skip
        if any(not v > 0 for v in sizes):
            raise ConfigError("the lengths, lane width and speed limits of a corridor must be > 0")
        self.pieces()  # the ramp lanes fit on the road

    def pieces(self) -> tuple[Piece, ...]:
        """The main road's edges in driving order; ConfigError if the ramp lanes do not fit."""
        ramp_lanes = corridor_ramp_lanes(
            self.length_m, self.on_ramp_positions_m, self.off_ramp_positions_m,
            self.accel_lane_m, self.decel_lane_m,
        )  # fmt: skip
        pieces: list[Piece] = []
        at = 0.0
        for k, (start, end, kind, number) in enumerate(ramp_lanes):
            ramp = f"on{number}" if kind == "acc" else f"off{number}"
            pieces.append(Piece(f"m{k}", at, start))
            pieces.append(Piece(f"{kind}{number}", start, end, kind, ramp=ramp))
            at = end
        pieces.append(Piece(f"m{len(ramp_lanes)}", at, self.length_m))
        return tuple(pieces)

    def through_edges(self) -> tuple[str, ...]:
        """The main through route: every piece of the main road, upstream end to downstream."""
        return tuple(p.id for p in self.pieces())

    def route(self, on_ramp: int | None, off_ramp: int | None) -> tuple[str, ...] | None:
        """The edges from on-ramp ``on_ramp`` (None: the upstream end) to off-ramp ``off_ramp``
        (None: the downstream end); None if that off-ramp lies upstream of that on-ramp."""
        through = list(self.through_edges())
        first = 0 if on_ramp is None else through.index(f"acc{on_ramp}")
        last = len(through) - 1 if off_ramp is None else through.index(f"dec{off_ramp}")
        if last < first:
            return None
        head = [] if on_ramp is None else [f"on{on_ramp}"]
        tail = [] if off_ramp is None else [f"off{off_ramp}"]
        return (*head, *through[first : last + 1], *tail)


def build_corridor(spec: CorridorSpec, folder: Path, name: str = "corridor") -> Path:
    """Write the plain XML of ``spec`` into ``folder`` and netconvert it to ``name.net.xml``;
    return the network path (edge ids: :class:`CorridorSpec`)."""
    road = RampedRoad(
        spec.pieces(), spec.lanes, spec.lane_width_m, spec.speed_mps, spec.ramp_m,
        spec.ramp_speed_mps,
    )  # fmt: skip
    return build_ramped_road(road, folder, name)
