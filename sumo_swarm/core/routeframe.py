"""The route coordinate from network data: no SUMO import, so it is unit-tested on hand-made roads.

A route is a list of edges. Its coordinate ``s_m`` accumulates the edges' lengths, junctions
included: each edge starts where the previous one ended plus the shortest junction (internal)
lane into it; a junction lane is placed so that it ends where the next route edge starts. The
frame also knows where lanes end (no connection into the next route edge) and the road section
(lane widths, curvature) of every edge.

The network data come through :class:`NetworkData`: the SUMO session answers it from a running
simulation, a test from a table.
"""

from __future__ import annotations

import itertools
import math
from collections import Counter
from collections.abc import Iterable, Sequence
from typing import Protocol

from sumo_swarm.core.model import RoadSection


class NetworkData(Protocol):
    """What the frame reads about the network; lanes are named ``{edge}_{index}`` as in SUMO."""

    def lane_count(self, edge: str) -> int: ...

    def lane_length_m(self, lane_id: str) -> float: ...

    def lane_width_m(self, lane_id: str) -> float: ...

    def lane_shape(self, lane_id: str) -> Sequence[tuple[float, float]]: ...

    def lane_links(self, lane_id: str) -> Iterable[tuple[str, str]]:
        """(lane reached, junction lane used or "") of each connection leaving ``lane_id``."""
        ...


def lane_curvature(shape: Sequence[tuple[float, float]]) -> float:
    """Mean curvature of a polyline [1/m]: total heading change over length, left positive."""
    if len(shape) < 3:
        return 0.0
    turn = 0.0
    length = 0.0
    prev = None
    for (x0, y0), (x1, y1) in itertools.pairwise(shape):
        seg = math.hypot(x1 - x0, y1 - y0)
        if seg < 1e-9:
            continue
        heading = math.atan2(y1 - y0, x1 - x0)
        if prev is not None:
            turn += (heading - prev + math.pi) % (2 * math.pi) - math.pi
        prev = heading
        length += seg
    return turn / length if length > 0 else 0.0


def carried_route_s(pos_m: float, speed_mps: float, was_m: float | None, step_s: float) -> float:
    """Route position [m] of a vehicle on an edge the route frame does not place (a junction
    edge off the route): its position one step before, ``was_m``, carried on at its speed
    over the step; for a vehicle that was not there one step before, its lane position."""
    return pos_m if was_m is None else was_m + speed_mps * step_s


class RouteFrame:
    """Route positions, lane ends and road sections of one route on a network.

    ``route_edges`` may be empty (the route is not known yet): then only :meth:`road_section`
    answers; :meth:`set_route` gives the route later.
    """

    def __init__(self, net: NetworkData, route_edges: Iterable[str] = ()) -> None:
        self.net = net
        self._roads: dict[str, RoadSection] = {}
        self.set_route(route_edges)

    def set_route(self, edges: Iterable[str]) -> None:
        """Compute each edge's start [m], each junction lane's end [m] and the lane ends."""
        edges = list(edges)
        net = self.net
        self.route_edges = edges
        # Lane counts of the route's edges (static; the swarm asks for them every step).
        self._lane_counts = {edge: net.lane_count(edge) for edge in edges}
        self._edge_index = {edge: i for i, edge in reversed(list(enumerate(edges)))}
        self.edge_offset_m: dict[str, float] = {}
        self.via_end: dict[str, tuple[float, float]] = {}  # junction lane: (end s, length) [m]
        self.lane_ends: list[tuple[int, int, float]] = []  # (route edge index, lane, end s [m])
        # Route positions [m] where lane indices shift (a lane added or dropped on the right:
        # lane i of one edge continues as lane j != i of the next).
        self.lane_shifts_m: list[float] = []
        # Lane index offsets [lanes]: lane i of edge e is the same lane as lane
        # i + off[e] - off[f] of edge f (lane i of one edge goes on as lane j of the next:
        # lane drops and added lanes on the right shift the indices); junction lanes included.
        self.lane_offset: dict[str, int] = {edges[0]: 0} if edges else {}
        self.junction_from: dict[str, str] = {}  # junction edge on the route -> edge it leaves
        # junction lane -> offset of the lane it comes from (a lane that fans out into two
        # junction lanes is the same lane on both)
        self.via_lane_offset: dict[str, int] = {}
        self._lanes_as_on: dict[tuple[int, str, str], int | None] = {}  # lane_as_on's answers
        offset = 0.0
        for i, edge in enumerate(edges):
            self.edge_offset_m[edge] = offset
            offset += net.lane_length_m(f"{edge}_0")
            if i + 1 >= len(edges):
                continue
            # Junction lanes into the next route edge: the shortest sets the next edge's
            # offset; each junction lane is placed so that it ends where that edge starts.
            vias: dict[str, float] = {}
            edge_end = offset
            shifted = False
            shifts: Counter[int] = Counter()  # lane here - lane reached, per connection
            via_shifts: dict[str, Counter[int]] = {}  # the same per junction edge
            base = self.lane_offset.get(edge)
            for lane in range(self._lane_counts[edge]):
                continues = False
                for to_lane, via in net.lane_links(f"{edge}_{lane}"):
                    to_edge, to_index = to_lane.rsplit("_", 1)
                    if to_edge == edges[i + 1] and via:
                        vias[via] = net.lane_length_m(via)
                        continues = True
                        shifted = shifted or int(to_index) != lane
                        shifts[lane - int(to_index)] += 1
                        via_edge, via_index = via.rsplit("_", 1)
                        self.junction_from[via_edge] = edge
                        if base is not None:
                            self.via_lane_offset[via] = base + lane - int(via_index)
                            via_shifts.setdefault(via_edge, Counter())[lane - int(via_index)] += 1
                if not continues:  # no connection into the next route edge: the lane ends
                    self.lane_ends.append((i, lane, edge_end))
            if base is not None and shifts:
                self.lane_offset[edges[i + 1]] = base + shifts.most_common(1)[0][0]
            # A junction edge's lanes are one per connection: where a lane fans out into two
            # (the lane before an added off-ramp lane of an OSM road netconverted with
            # --ramps.guess) the edge has more lanes than the one it leaves, numbered as the
            # edge it enters; its offset is its lanes' usual one, and each lane's own is in
            # via_lane_offset.
            for via_edge, counts in via_shifts.items():
                self.lane_offset.setdefault(via_edge, base + counts.most_common(1)[0][0])
            if shifted or self._lane_counts[edges[i + 1]] != self._lane_counts[edge]:
                self.lane_shifts_m.append(edge_end)
            offset += min(vias.values(), default=0.0)
            for via, length in vias.items():
                self.via_end[via] = (offset, length)

    def lane_as_on(self, lane: int, edge: str, reference: str) -> int | None:
        """Index on ``reference`` of the lane that is lane ``lane`` of ``edge`` (both on the
        route, junction edges included); None where either is off the route. May fall outside
        ``reference``'s lanes: a lane that ended before it, or begins after it. Worked out
        once per route (the controllers ask for every vehicle near a lane shift at each step)."""
        key = (lane, edge, reference)
        try:
            return self._lanes_as_on[key]
        except KeyError:
            pass
        a = self.via_lane_offset.get(f"{edge}_{lane}") if edge in self.junction_from else None
        a = self.lane_offset.get(edge) if a is None else a
        b = self.lane_offset.get(reference)
        found = None if a is None or b is None else lane + a - b
        self._lanes_as_on[key] = found
        return found

    def route_edge(self, edge: str) -> str:
        """``edge`` itself, or for a junction edge on the route the route edge it leaves: the
        edge whose lane indices and road section hold there."""
        return self.junction_from.get(edge, edge)

    def near_lane_shift(self, s_m: float, within_m: float) -> bool:
        """Is route position ``s_m`` within ``within_m`` of a place where lane indices shift?"""
        return any(abs(s_m - b) <= within_m for b in self.lane_shifts_m)

    def route_s(self, edge: str, lane: int, pos_m: float) -> float | None:
        """Route position [m] of lane position ``pos_m`` on ``edge``'s lane ``lane``; None off
        the route (or on a junction edge the route does not use)."""
        offset = self.edge_offset_m.get(edge)
        if offset is not None:
            return offset + pos_m
        via = self.via_end.get(f"{edge}_{lane}")
        if via is not None:  # on a junction lane: measured back from the next edge's start
            return via[0] - (via[1] - pos_m)
        return None

    def lanes_ending(self, edge: str, s_from_m: float, s_to_m: float) -> list[tuple[int, float]]:
        """Lanes that end between ``s_from_m`` and ``s_to_m`` [m] (no connection into the next
        route edge), as (lane index on ``edge``, route position of the end [m]).

        Only ends on ``edge`` itself, or on later edges reached without a change in the number
        of lanes (so the lane indices still mean the same lanes), are reported.
        """
        edges = self.route_edges
        first = self._edge_index.get(edge)
        if first is None or not self.lane_ends:
            return []
        n_lanes = self.lane_count(edge)
        last = first
        while (
            last + 1 < len(edges)
            and self.lane_count(edges[last + 1]) == n_lanes
            and not any(i == last for i, _, _ in self.lane_ends)
        ):
            last += 1
        return [
            (lane, end)
            for i, lane, end in self.lane_ends
            if first <= i <= last and s_from_m < end <= s_to_m
        ]

    def lane_count(self, edge: str) -> int:
        """Number of lanes of ``edge`` (read once for the route's edges)."""
        count = self._lane_counts.get(edge)
        return self.net.lane_count(edge) if count is None else count

    def road_section(self, edge: str) -> RoadSection:
        """Lane widths of ``edge`` [m] (0 = rightmost) and its mean curvature [1/m] (left > 0),
        from the lane geometry. A junction edge (``:...``) gives the section of the route edge
        it leaves (:meth:`route_edge`), or off the route the last road section read."""
        edge = self.route_edge(edge)
        road = self._roads.get(edge)
        if road is not None:
            return road
        if edge.startswith(":") and self._roads:
            return next(reversed(self._roads.values()))
        net = self.net
        widths = tuple(net.lane_width_m(f"{edge}_{i}") for i in range(net.lane_count(edge)))
        road = RoadSection(widths, lane_curvature(net.lane_shape(f"{edge}_0")))
        self._roads[edge] = road
        return road
