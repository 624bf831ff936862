"""Build small highway networks with SUMO's netconvert (from the eclipse-sumo package).

Used by the tests, the stress sweep and users who want a quick test bed: straight or curved,
2 to 5 lanes, one or several edges, optionally a lane drop (the leftmost lanes end).
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
    drop on the left). ``radius_m`` bends the whole road into an arc turning left (None:
    straight). Lanes are ``lane_width_m`` wide; ``speed_mps`` is the speed limit.
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
    import sumo

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
    (folder / f"{name}.nod.xml").write_text("\n".join(nodes) + "\n", encoding="utf-8")
    (folder / f"{name}.edg.xml").write_text("\n".join(edges) + "\n", encoding="utf-8")
    net = folder / f"{name}.net.xml"
    cmd = [
        str(Path(sumo.SUMO_HOME) / "bin" / "netconvert"),
        "--node-files", f"{name}.nod.xml", "--edge-files", f"{name}.edg.xml",
        "--output-file", net.name, "--no-turnarounds", "true", "--no-warnings", "true",
        "--geometry.avoid-overlap", "false",
    ]  # fmt: skip
    proc = subprocess.run(cmd, cwd=folder, capture_output=True, text=True)
    if proc.returncode != 0:
        raise ConfigError(f"netconvert failed for {folder / name}: {proc.stderr.strip()}")
    return net
