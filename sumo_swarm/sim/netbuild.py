"""Build small highway networks with SUMO's netconvert (from the eclipse-sumo package).

Used by the tests, the stress sweep and users who want a quick test bed: straight or curved,
2 to 5 lanes, one or several edges, optionally a lane drop (the rightmost lanes end: netconvert
keeps the lanes on the left going); and a
straight motorway with an on-ramp (acceleration lane) and an off-ramp (deceleration lane).
"""

from __future__ import annotations

import math
import subprocess
from dataclasses import dataclass
from pathlib import Path

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


def _netconvert(
    folder: Path,
    name: str,
    nodes: list[str],
    edges: list[str],
    connections: list[str] | None = None,
) -> Path:
    """Write the plain XML files (nodes, edges, optional connections) into ``folder`` and
    netconvert them to ``name.net.xml``; ConfigError with netconvert's message if it fails."""
    import sumo

    files = {"node-files": (f"{name}.nod.xml", nodes), "edge-files": (f"{name}.edg.xml", edges)}
    if connections is not None:
        files["connection-files"] = (f"{name}.con.xml", connections)
    cmd = [str(Path(sumo.SUMO_HOME) / "bin" / "netconvert")]
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
    folder.mkdir(parents=True, exist_ok=True)
    n = spec.through_lanes
    x1 = spec.upstream_m
    x2 = x1 + spec.accel_lane_m
    x3 = x2 + spec.weave_m
    x4 = x3 + spec.decel_lane_m
    x5 = x4 + spec.downstream_m
    # The ramps leave at a 1:10 slope on the right (negative y when driving along +x).
    ramp_dx = spec.ramp_m * math.cos(math.atan(0.1))
    ramp_dy = -spec.ramp_m * math.sin(math.atan(0.1))
    points = {
        "n0": (0.0, 0.0), "n1": (x1, 0.0), "n2": (x2, 0.0), "n3": (x3, 0.0), "n4": (x4, 0.0),
        "n5": (x5, 0.0), "r0": (x1 - ramp_dx, ramp_dy), "r1": (x4 + ramp_dx, ramp_dy),
    }  # fmt: skip
    nodes = ['<?xml version="1.0" encoding="UTF-8"?>', "<nodes>"]
    nodes += [
        f'    <node id="{node}" x="{x:.3f}" y="{y:.3f}" type="priority"/>'
        for node, (x, y) in points.items()
    ]
    nodes.append("</nodes>")
    # id, from, to, lanes, speed limit, priority (the motorway has right of way over the ramps)
    edge_rows = [
        ("up", "n0", "n1", n, spec.speed_mps, 3),
        ("acc", "n1", "n2", n + 1, spec.speed_mps, 3),
        ("mid", "n2", "n3", n, spec.speed_mps, 3),
        ("dec", "n3", "n4", n + 1, spec.speed_mps, 3),
        ("down", "n4", "n5", n, spec.speed_mps, 3),
        ("on", "r0", "n1", 1, spec.ramp_speed_mps, 1),
        ("off", "n4", "r1", 1, spec.ramp_speed_mps, 1),
    ]
    edges = ['<?xml version="1.0" encoding="UTF-8"?>', "<edges>"]
    edges += [
        f'    <edge id="{edge}" from="{a}" to="{b}" priority="{prio}" numLanes="{lanes}" '
        f'speed="{speed}" width="{spec.lane_width_m}"/>'
        for edge, a, b, lanes, speed, prio in edge_rows
    ]
    edges.append("</edges>")
    # (from edge, from lane, to edge, to lane)
    links = [("on", 0, "acc", 0)]
    links += [("up", i, "acc", i + 1) for i in range(n)]
    links += [("acc", i + 1, "mid", i) for i in range(n)]  # acc lane 0 ends: no link
    links += [("mid", 0, "dec", 0)] + [("mid", i, "dec", i + 1) for i in range(n)]
    links += [("dec", 0, "off", 0)] + [("dec", i + 1, "down", i) for i in range(n)]
    connections = ['<?xml version="1.0" encoding="UTF-8"?>', "<connections>"]
    connections += [
        f'    <connection from="{a}" to="{b}" fromLane="{la}" toLane="{lb}"/>'
        for a, la, b, lb in links
    ]
    connections.append("</connections>")
    return _netconvert(folder, name, nodes, edges, connections)
