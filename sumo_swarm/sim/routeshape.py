"""Where route coordinates lie on the map: ``(s along the route, lane, lateral offset) -> (x, y)``.

The route coordinate is the SUMO bridge's: each route edge starts where the previous one ended
plus the shortest junction (internal) lane into it; a position on a lane is scaled onto the
lane's drawn shape as SUMO does (``length`` and shape length may differ). The geometry is read
either from a ``.net.xml`` file (defusedxml) or from a running simulation (a traci connection),
so the replay and the live sumo-gui drawing place cells exactly where the controller meant them.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sumo_swarm.core.planner.problem import PlanningProblem
from sumo_swarm.errors import ConfigError
from sumo_swarm.safexml import parse_xml

DEFAULT_LANE_WIDTH_M = 3.2  # SUMO's lane width when the network gives none [m]
# Plan records carry no behaving interval unless the controller adds one: the planner's default
DEFAULT_INTERVAL_S: float = PlanningProblem.__dataclass_fields__["behaving_interval_s"].default


@dataclass(frozen=True, eq=False)
class LaneGeometry:
    """One lane: its centre line ``shape_xy`` (k x 2) [m], width [m] and SUMO length [m]."""

    shape_xy: np.ndarray
    width_m: float
    length_m: float

    def __post_init__(self) -> None:
        shape = np.asarray(self.shape_xy, dtype=float).reshape(-1, 2)
        if len(shape) == 1:  # a degenerate shape: give it a direction so headings exist
            shape = np.vstack([shape, shape + np.array([1e-3, 0.0])])
        object.__setattr__(self, "shape_xy", shape)
        seg = np.hypot(*np.diff(shape, axis=0).T)
        object.__setattr__(self, "_cum_m", np.concatenate([[0.0], np.cumsum(seg)]))

    def along(self, pos_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points at lane positions ``pos_m`` [m] (extrapolated past the ends along the end
        segments): x [m], y [m], heading [rad, counter-clockwise from +x]."""
        cum = self._cum_m  # type: ignore[attr-defined]
        scale = cum[-1] / self.length_m if self.length_m > 0 else 1.0
        u = np.asarray(pos_m, dtype=float) * scale
        i = np.clip(np.searchsorted(cum, u, side="right"), 1, len(cum) - 1)
        a, b = self.shape_xy[i - 1], self.shape_xy[i]
        seg = np.maximum(cum[i] - cum[i - 1], 1e-9)
        f = (u - cum[i - 1]) / seg
        xy = a + f[..., None] * (b - a)
        d = b - a
        return xy[..., 0], xy[..., 1], np.arctan2(d[..., 1], d[..., 0])


@dataclass(frozen=True)
class RouteEdge:
    """A route edge: its id, the route position of its start [m] and its lanes (0 = right)."""

    edge_id: str
    offset_m: float
    lanes: tuple[LaneGeometry, ...]

    @property
    def length_m(self) -> float:
        return self.lanes[0].length_m


class RouteGeometry:
    """Map geometry of one route, in the bridge's route coordinate."""

    def __init__(self, edges: Sequence[RouteEdge]) -> None:
        if not edges:
            raise ConfigError("a route needs at least one edge")
        self.edges = tuple(edges)
        self._offsets = np.array([e.offset_m for e in self.edges])

    @property
    def length_m(self) -> float:
        """Route position of the end of the last edge [m]."""
        return self.edges[-1].offset_m + self.edges[-1].length_m

    def _on_edge(
        self, j: int, pos_m: np.ndarray, lane: np.ndarray, lat_m: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Points on edge ``j``; lanes the edge does not have are placed beside its outer lanes."""
        lanes = self.edges[j].lanes
        x = np.empty(pos_m.shape)
        y = np.empty(pos_m.shape)
        h = np.empty(pos_m.shape)
        clamped = np.clip(lane, 0, len(lanes) - 1)
        for q in np.unique(clamped):
            m = clamped == q
            geom = lanes[int(q)]
            xq, yq, hq = geom.along(pos_m[m])
            off = lat_m[m] + (lane[m] - q) * geom.width_m  # left positive
            x[m] = xq - np.sin(hq) * off
            y[m] = yq + np.cos(hq) * off
            h[m] = hq
        return x, y, h

    def xy(
        self, s_m: Any, lane: Any = 0, lat_m: Any = 0.0
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Map points of route positions ``s_m`` [m] in ``lane`` at ``lat_m`` [m] off its centre
        (left positive): x [m], y [m] and the lane's heading [rad]. Arrays broadcast."""
        s, q, lat = np.broadcast_arrays(
            np.asarray(s_m, dtype=float), np.asarray(lane, dtype=int), np.asarray(lat_m, float)
        )
        s, q, lat = s.ravel(), q.ravel(), lat.ravel()
        x, y, h = np.empty(s.shape), np.empty(s.shape), np.empty(s.shape)
        j_of = np.clip(np.searchsorted(self._offsets, s, side="right") - 1, 0, None)
        for j in np.unique(j_of):
            m = j_of == j
            edge = self.edges[j]
            pos = s[m] - edge.offset_m
            xe, ye, he = self._on_edge(j, pos, q[m], lat[m])
            if j + 1 < len(self.edges):  # in the junction between two route edges: blend
                gap = self.edges[j + 1].offset_m - edge.offset_m - edge.length_m
                inside = pos > edge.length_m
                if gap > 0 and inside.any():
                    f = np.clip((pos[inside] - edge.length_m) / gap, 0.0, 1.0)
                    n = int(inside.sum())
                    x0, y0, _ = self._on_edge(
                        j, np.full(n, edge.length_m), q[m][inside], lat[m][inside]
                    )
                    x1, y1, _ = self._on_edge(j + 1, np.zeros(n), q[m][inside], lat[m][inside])
                    xe[inside] = x0 + f * (x1 - x0)
                    ye[inside] = y0 + f * (y1 - y0)
                    he[inside] = np.arctan2(y1 - y0, x1 - x0)
            x[m], y[m], h[m] = xe, ye, he
        shape = np.broadcast_shapes(np.shape(s_m), np.shape(lane), np.shape(lat_m))
        return x.reshape(shape), y.reshape(shape), h.reshape(shape)

    def lanes_at(self, s_m: float) -> tuple[LaneGeometry, ...]:
        """The lanes of the route edge at route position ``s_m`` [m] (0 = rightmost)."""
        j = max(int(np.searchsorted(self._offsets, s_m, side="right")) - 1, 0)
        return self.edges[j].lanes

    def lane_width_m(self, s_m: float, lane: int) -> float:
        """Width of ``lane`` on the edge at route position ``s_m`` [m] (outer lane if missing)."""
        lanes = self.lanes_at(s_m)
        return lanes[min(max(lane, 0), len(lanes) - 1)].width_m

    def band(self, s_from_m: float, s_to_m: float, lane: int, step_m: float = 5.0) -> np.ndarray:
        """Polygon (k x 2) [m] covering ``lane`` from ``s_from_m`` to ``s_to_m``: the left
        border forward, then the right border back (follows curves every ``step_m``)."""
        n = max(int(np.ceil(abs(s_to_m - s_from_m) / step_m)), 1) + 1
        s = np.linspace(s_from_m, s_to_m, n)
        half = 0.5 * self.lane_width_m(0.5 * (s_from_m + s_to_m), lane)
        xl, yl, _ = self.xy(s, lane, half)
        xr, yr, _ = self.xy(s[::-1], lane, -half)
        return np.column_stack([np.concatenate([xl, xr]), np.concatenate([yl, yr])])

    def cells(self, s_edges_m: np.ndarray, lane: int) -> np.ndarray:
        """Quadrilaterals (n x 4 x 2) [m] of the cells of ``lane`` between consecutive route
        positions ``s_edges_m`` (n + 1 values): rear-left, front-left, front-right, rear-right."""
        s = np.asarray(s_edges_m, dtype=float)
        half = 0.5 * self.lane_width_m(float(s[len(s) // 2]), lane)
        xl, yl, _ = self.xy(s, lane, half)
        xr, yr, _ = self.xy(s, lane, -half)
        left = np.column_stack([xl, yl])
        right = np.column_stack([xr, yr])
        return np.stack([left[:-1], left[1:], right[1:], right[:-1]], axis=1)


def _offsets(
    edge_ids: Sequence[str], lengths: Sequence[float], via_lengths: Sequence[Iterable[float]]
) -> list[float]:
    """Start of each route edge [m]: the previous start, its length and the shortest via."""
    out, offset = [], 0.0
    for i, length in enumerate(lengths):
        out.append(offset)
        offset += length
        if i + 1 < len(edge_ids):
            offset += min(via_lengths[i], default=0.0)
    return out


def _shape(text: str | None) -> np.ndarray:
    pts = [tuple(map(float, p.split(",")[:2])) for p in (text or "").split()]
    return np.array(pts, dtype=float).reshape(-1, 2)


def read_net_lanes(net_path: Path) -> tuple[dict[str, list[LaneGeometry]], Any]:
    """Lanes of every edge of a ``.net.xml`` (internal edges too) and the parsed root element."""
    root = parse_xml(net_path, "SUMO network")
    lanes: dict[str, list[LaneGeometry]] = {}
    try:
        for edge in root.iter("edge"):
            found = sorted(edge.iter("lane"), key=lambda ln: int(ln.get("index", "0")))
            lanes[edge.get("id", "")] = [
                LaneGeometry(
                    _shape(ln.get("shape")),
                    float(ln.get("width", DEFAULT_LANE_WIDTH_M)),
                    float(ln.get("length", "0")),
                )
                for ln in found
                if ln.get("shape")
            ]
    except ValueError as exc:  # a lane's index, width, length or shape is no number
        raise ConfigError(f"{net_path}: malformed SUMO network: {exc}") from None
    return lanes, root


def route_from_net(net_path: Path, edge_ids: Sequence[str]) -> RouteGeometry:
    """The geometry of the route ``edge_ids`` in the network file ``net_path``."""
    lanes, root = read_net_lanes(net_path)
    missing = [e for e in edge_ids if not lanes.get(e)]
    if missing:
        raise ConfigError(f"network {net_path} has no edge '{missing[0]}'")
    via_len: dict[str, float] = {}
    for edge in root.iter("edge"):
        for ln in edge.iter("lane"):
            via_len[ln.get("id", "")] = float(ln.get("length", "0"))
    vias: list[list[float]] = [[] for _ in edge_ids]
    nxt = {e: edge_ids[i + 1] for i, e in enumerate(edge_ids[:-1])}
    index = {e: i for i, e in enumerate(edge_ids[:-1])}
    for con in root.iter("connection"):
        src, via = con.get("from"), con.get("via")
        if src in nxt and con.get("to") == nxt[src] and via:
            vias[index[src]].append(via_len.get(via, 0.0))
    lengths = [lanes[e][0].length_m for e in edge_ids]
    offs = _offsets(edge_ids, lengths, vias)
    return RouteGeometry(
        [RouteEdge(e, o, tuple(lanes[e])) for e, o in zip(edge_ids, offs, strict=True)]
    )


def route_from_connection(conn: Any, edge_ids: Sequence[str]) -> RouteGeometry:
    """The geometry of the route ``edge_ids`` read from a running simulation (traci/libsumo)."""
    edges, lengths, vias = [], [], []
    for i, edge in enumerate(edge_ids):
        n = conn.edge.getLaneNumber(edge)
        lanes = tuple(
            LaneGeometry(
                np.array(conn.lane.getShape(f"{edge}_{q}"), dtype=float),
                float(conn.lane.getWidth(f"{edge}_{q}")),
                float(conn.lane.getLength(f"{edge}_{q}")),
            )
            for q in range(n)
        )
        edges.append(lanes)
        lengths.append(lanes[0].length_m)
        found = []
        if i + 1 < len(edge_ids):
            for q in range(n):
                for link in conn.lane.getLinks(f"{edge}_{q}"):
                    if link[0].rsplit("_", 1)[0] == edge_ids[i + 1] and link[4]:
                        found.append(float(conn.lane.getLength(link[4])))
        vias.append(found)
    offs = _offsets(edge_ids, lengths, vias)
    return RouteGeometry(
        [RouteEdge(e, o, ln) for e, o, ln in zip(edge_ids, offs, edges, strict=True)]
    )


# --------------------------------------------------------------------------------------------
# a plan on the map


@dataclass(frozen=True)
class PlanRecord:
    """A valid record of ``plans.jsonl`` (or of the swarm's plan log) and until when it holds.

    ``grid`` holds ``origin_s_m, t0_s, speed_mps, cell_length_m, n_rows, n_cols``; ``cells``
    maps each CAV to its (row, column) per behaving step, ``interval_s`` apart [s].
    """

    time_s: float
    until_s: float
    grid: dict[str, Any]
    cells: dict[str, list[tuple[int, int]]]
    blockers: dict[str, str]
    interval_s: float

    @staticmethod
    def is_valid(record: dict[str, Any]) -> bool:
        """Whether a record is a plan the swarm followed (solved, with cells, no violation)."""
        return bool(record.get("cells") and record.get("grid") and not record.get("violations"))

    @classmethod
    def from_record(cls, record: dict[str, Any]) -> PlanRecord:
        """The plan of a record (see :meth:`is_valid`), in force until its last step ends."""
        t0 = float(record["time_s"])
        interval = float(record.get("behaving_interval_s", DEFAULT_INTERVAL_S))
        cells = {c: [(int(r), int(q)) for r, q in seq] for c, seq in record["cells"].items()}
        n_steps = len(next(iter(cells.values())))
        return cls(
            t0,
            t0 + n_steps * interval,
            record["grid"],
            cells,
            dict(record.get("blockers") or {}),
            interval,
        )

    @property
    def n_steps(self) -> int:
        return len(next(iter(self.cells.values())))

    def step_at(self, t_s: float) -> int:
        """Index of the behaving step the CAVs are driving into at ``t_s`` (clipped to the plan)."""
        return min(max(int((t_s - self.time_s) // self.interval_s) + 1, 0), self.n_steps - 1)

    def origin_at(self, t_s: float) -> float:
        """Rear edge of the grid's row 0 at ``t_s`` [m along the route]."""
        g = self.grid
        return float(g["origin_s_m"]) + float(g["speed_mps"]) * (t_s - float(g["t0_s"]))

    def polygons(
        self, route: RouteGeometry, t_s: float
    ) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Map polygons at ``t_s``: every grid cell (rows x columns, each 4 x 2) [m], and per CAV
        the cell of the step it is driving into (CAVs whose cell is off the grid left out)."""
        g = self.grid
        n_rows, n_cols = int(g["n_rows"]), int(g["n_cols"])
        rows_s = self.origin_at(t_s) + float(g["cell_length_m"]) * np.arange(n_rows + 1)
        by_lane = [route.cells(rows_s, c) for c in range(n_cols)]
        k = self.step_at(t_s)
        cav_cells = {
            cav: by_lane[seq[k][1]][seq[k][0]]
            for cav, seq in self.cells.items()
            if 0 <= seq[k][0] < n_rows and 0 <= seq[k][1] < n_cols
        }
        return np.concatenate(by_lane), cav_cells
