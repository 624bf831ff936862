"""The route frame on hand-made networks (known answers), and on a network SUMO built itself
(the bridge's route coordinate equals the replay's, read from the .net.xml file)."""

from __future__ import annotations

import math

import pytest
from defusedxml import ElementTree

from sumo_swarm.core.routeframe import RouteFrame, lane_curvature


class TableNetwork:
    """Network data from a table: lane id -> (length, width, shape, links)."""

    def __init__(self, lanes: dict[str, tuple[float, float, list, list[tuple[str, str]]]]):
        self.lanes = lanes

    def lane_count(self, edge: str) -> int:
        return sum(1 for lane in self.lanes if lane.rsplit("_", 1)[0] == edge)

    def lane_length_m(self, lane_id: str) -> float:
        return self.lanes[lane_id][0]

    def lane_width_m(self, lane_id: str) -> float:
        return self.lanes[lane_id][1]

    def lane_shape(self, lane_id: str) -> list:
        return self.lanes[lane_id][2]

    def lane_links(self, lane_id: str) -> list[tuple[str, str]]:
        return self.lanes[lane_id][3]


STRAIGHT = [(0.0, 0.0), (100.0, 0.0)]
LEFT_TURN = [(0.0, 0.0), (100.0, 0.0), (100.0, 100.0)]  # +pi/2 over 200 m


def network(lanes_on_a: int = 2) -> TableNetwork:
    """a (100 m) -> b (200 m, 2 lanes, its left lane ends) -> c (300 m, 1 lane).

    Junction lanes a->b are 10, 12 (and 15) m long, b->c 8 m.
    """
    vias_ab = [":j1_0_0", ":j1_1_0", ":j1_2_0"]
    lanes = {
        f"a_{q}": (100.0, 3.5, STRAIGHT, [(f"b_{min(q, 1)}", vias_ab[q])])
        for q in range(lanes_on_a)
    }
    lanes |= {
        ":j1_0_0": (10.0, 3.5, STRAIGHT, [("b_0", "")]),
        ":j1_1_0": (12.0, 3.5, STRAIGHT, [("b_1", "")]),
        ":j1_2_0": (15.0, 3.5, STRAIGHT, [("b_1", "")]),
        "b_0": (200.0, 3.2, LEFT_TURN, [("c_0", ":j2_0_0"), ("x_0", ":j2_1_0")]),
        "b_1": (200.0, 3.0, LEFT_TURN, [("x_0", ":j2_2_0")]),  # leaves the route only
        ":j2_0_0": (8.0, 3.2, STRAIGHT, [("c_0", "")]),
        "c_0": (300.0, 3.2, STRAIGHT, []),
    }
    return TableNetwork(lanes)


def test_offsets_take_the_shortest_junction_lane():
    frame = RouteFrame(network(), ["a", "b", "c"])
    assert frame.edge_offset_m == {"a": 0.0, "b": 110.0, "c": 318.0}
    # every junction lane into the next route edge ends where that edge starts
    assert frame.via_end == {
        ":j1_0_0": (110.0, 10.0),
        ":j1_1_0": (110.0, 12.0),
        ":j2_0_0": (318.0, 8.0),
    }
    assert frame.lane_ends == [(1, 1, 310.0)]  # b's left lane: no connection into c


def test_route_positions_on_edges_junction_lanes_and_off_the_route():
    frame = RouteFrame(network(), ["a", "b", "c"])
    assert frame.route_s("a", 1, 40.0) == 40.0
    assert frame.route_s("b", 0, 50.0) == 160.0
    assert frame.route_s(":j1_1", 0, 6.0) == 104.0  # 6 m into a 12 m lane ending at 110 m
    assert frame.route_s(":j2_0", 0, 8.0) == 318.0  # the end of a junction lane: c's start
    assert frame.route_s("x", 0, 5.0) is None  # not on the route
    assert frame.route_s(":j2_2", 0, 1.0) is None  # a junction lane off the route


def test_lanes_ending_ahead():
    frame = RouteFrame(network(), ["a", "b", "c"])
    assert frame.lanes_ending("a", 0.0, 1000.0) == [(1, 310.0)]  # a and b: same two lanes
    assert frame.lanes_ending("a", 0.0, 309.0) == []  # the end is beyond the window
    assert frame.lanes_ending("b", 310.0, 400.0) == []  # at the window's start: excluded
    assert frame.lanes_ending("c", 0.0, 1000.0) == []
    assert frame.lanes_ending("x", 0.0, 1000.0) == []
    # a with three lanes: b's lane 1 is not a's lane 1 any more, so nothing is reported on a
    three = RouteFrame(network(lanes_on_a=3), ["a", "b", "c"])
    assert three.lanes_ending("a", 0.0, 1000.0) == []
    assert three.lanes_ending("b", 0.0, 1000.0) == [(1, 310.0)]


def test_road_sections_and_an_unknown_route():
    frame = RouteFrame(network())  # the route is not known yet
    assert frame.route_s("a", 0, 5.0) is None and frame.lanes_ending("a", 0.0, 1e3) == []
    b = frame.road_section("b")
    assert b.lane_widths_m == (3.2, 3.0)
    assert b.curvature_1pm == pytest.approx(math.pi / 400)
    assert frame.road_section(":j2_0") is b  # a junction edge: the road last read
    frame.set_route(["a", "b"])
    assert frame.edge_offset_m == {"a": 0.0, "b": 110.0}
    assert frame.lane_ends == []  # the route ends at b: nothing to connect to


# a (3 lanes) -> b: a's right lane ends, a's lanes 1 and 2 go on as b's 0 and 1 (netconvert's
# lane drop, through the junction j1)
A_DROPS_INTO_B = {
    "a_0": (100.0, 3.2, STRAIGHT, []),
    "a_1": (100.0, 3.2, STRAIGHT, [("b_0", ":j1_0_0")]),
    "a_2": (100.0, 3.2, STRAIGHT, [("b_1", ":j1_0_1")]),
    ":j1_0_0": (5.0, 3.2, STRAIGHT, [("b_0", "")]),
    ":j1_0_1": (5.0, 3.2, STRAIGHT, [("b_1", "")]),
}


def test_lane_indices_across_a_dropped_right_lane():
    """a (3 lanes) -> b (2 lanes): a's right lane ends, a's lanes 1 and 2 go on as b's 0 and
    1 (netconvert's lane drop); then b -> c keeps its two lanes."""
    lanes = {
        **A_DROPS_INTO_B,
        "b_0": (100.0, 3.2, STRAIGHT, [("c_0", ":j2_0_0")]),
        "b_1": (100.0, 3.2, STRAIGHT, [("c_1", ":j2_0_1")]),
        ":j2_0_0": (5.0, 3.2, STRAIGHT, [("c_0", "")]),
        ":j2_0_1": (5.0, 3.2, STRAIGHT, [("c_1", "")]),
        "c_0": (100.0, 3.2, STRAIGHT, []),
        "c_1": (100.0, 3.2, STRAIGHT, []),
    }
    frame = RouteFrame(TableNetwork(lanes), ["a", "b", "c"])
    assert frame.lane_offset == {"a": 0, ":j1_0": 1, "b": 1, ":j2_0": 1, "c": 1}
    assert frame.lane_as_on(1, "a", "b") == 0  # the same lane, one index less on b
    assert frame.lane_as_on(2, "a", "c") == 1
    assert frame.lane_as_on(0, "b", "a") == 1
    assert frame.lane_as_on(0, "a", "b") == -1  # the lane that ended: none of b's
    assert frame.lane_as_on(1, ":j1_0", "b") == 1  # on the junction, towards b_1
    assert frame.lane_as_on(0, "x", "b") is None  # off the route
    assert frame.route_edge(":j1_0") == "a" and frame.route_edge("b") == "b"
    assert frame.road_section(":j1_0") is frame.road_section("a")
    assert len(frame.road_section(":j1_0").lane_widths_m) == 3
    # The answers are kept per route: a route given later (b -> c: b's lanes numbered from
    # 0) answers anew, not from the first route's.
    frame.set_route(["b", "c"])
    assert frame.lane_as_on(0, "b", "a") is None  # a is off this route
    assert frame.lane_as_on(1, "b", "c") == 1


@pytest.mark.parametrize(
    ("shape", "curvature"),
    [
        (STRAIGHT, 0.0),
        (LEFT_TURN, math.pi / 400),
        ([(0.0, 0.0), (100.0, 0.0), (100.0, -100.0)], -math.pi / 400),  # right turn
        ([(0.0, 0.0), (50.0, 0.0), (50.0, 0.0), (100.0, 0.0)], 0.0),  # a repeated point
    ],
)
def test_lane_curvature(shape, curvature):
    assert lane_curvature(shape) == pytest.approx(curvature)


@pytest.mark.sumo
def test_the_bridge_coordinate_is_the_replays(tmp_path):
    """SUMO's own network (a lane drop over four edges): the frame read through libsumo gives
    the offsets the replay reads from the .net.xml, and the dropped lane's end."""
    import libsumo

    from sumo_swarm.sim.bridge import SumoNetwork, sumo_binary
    from sumo_swarm.sim.netbuild import HighwaySpec, build_highway, edge_ids
    from sumo_swarm.sim.routeshape import route_from_net

    spec = HighwaySpec(length_m=2000, lanes=(3, 2, 2, 2), edges=4)
    net = build_highway(spec, tmp_path)
    edges = edge_ids(spec)
    libsumo.start([sumo_binary(), "-n", str(net), "--no-step-log", "true"])
    try:
        frame = RouteFrame(SumoNetwork(libsumo), edges)
        widths = frame.road_section("e0").lane_widths_m
        ending_ahead = frame.lanes_ending("e0", 0.0, 1e4)
    finally:
        libsumo.close()
    geometry = route_from_net(net, edges)
    assert [frame.edge_offset_m[e] for e in edges] == pytest.approx(
        [e.offset_m for e in geometry.edges], abs=1e-6
    )
    assert len(widths) == 3
    # the lane of e0 that netconvert did not connect into e1 ends where e0 ends
    root = ElementTree.parse(str(net)).getroot()
    continuing = {
        int(c.get("fromLane"))
        for c in root.iter("connection")
        if c.get("from") == "e0" and c.get("to") == "e1"
    }
    assert len(continuing) == 2
    (ending,) = set(range(3)) - continuing
    assert [(i, lane) for i, lane, _ in frame.lane_ends] == [(0, ending)]
    assert frame.lane_ends[0][2] == pytest.approx(geometry.edges[0].length_m)
    assert ending_ahead == [(ending, frame.lane_ends[0][2])]


@pytest.mark.sumo
def test_the_network_reads_each_lane_count_and_length_from_sumo_once(tmp_path):
    """They do not change while SUMO runs; the fleet measures the road ahead of every CAV
    with them at each membership review."""
    from collections import Counter
    from types import SimpleNamespace

    import libsumo

    from sumo_swarm.sim.bridge import SumoNetwork, sumo_binary
    from sumo_swarm.sim.netbuild import HighwaySpec, build_highway

    calls: Counter[str] = Counter()

    class Counted:  # libsumo's domain, each call counted
        def __init__(self, domain) -> None:
            self.domain = domain

        def __getattr__(self, name):
            def call(*args):
                calls[name] += 1
                return getattr(self.domain, name)(*args)

            return call

    net_file = build_highway(HighwaySpec(length_m=1000, lanes=(3, 2), edges=2), tmp_path)
    libsumo.start([sumo_binary(), "-n", str(net_file), "--no-step-log", "true"])
    try:
        net = SumoNetwork(SimpleNamespace(lane=Counted(libsumo.lane), edge=Counted(libsumo.edge)))
        for _ in range(3):
            assert net.lane_count("e0") == 3 and net.lane_count("e1") == 2
            assert net.lane_length_m("e0_0") == libsumo.lane.getLength("e0_0")
    finally:
        libsumo.close()
    assert calls == {"getLaneNumber": 2, "getLength": 1}


def test_lane_shifts_where_lanes_are_added_or_dropped_on_the_right():
    # a -> b: lanes map 0 -> 0, 1 -> 1 (no shift); b -> c: 2 lanes become 1 (a lane drop).
    frame = RouteFrame(network(), ["a", "b", "c"])
    assert frame.lane_shifts_m == [310.0]
    assert frame.near_lane_shift(290.0, 25.0) and frame.near_lane_shift(330.0, 25.0)
    assert not frame.near_lane_shift(250.0, 25.0)
    # An acceleration lane added on the right: a's lane 0 continues as d's lane 1.
    lanes = {
        "a_0": (100.0, 3.5, STRAIGHT, [("d_1", ":j_0_0")]),
        ":j_0_0": (10.0, 3.5, STRAIGHT, [("d_1", "")]),
        "d_0": (200.0, 3.5, STRAIGHT, []),
        "d_1": (200.0, 3.5, STRAIGHT, []),
    }
    assert RouteFrame(TableNetwork(lanes), ["a", "d"]).lane_shifts_m == [100.0]


def test_a_lane_that_fans_out_at_a_deceleration_lane_keeps_its_index_on_the_junction():
    """a (3 lanes) -> d (4 lanes, an off-ramp's deceleration lane added on the right), as
    netconvert builds it from OpenStreetMap with --ramps.guess (and as scenarios/corridor.toml's
    m1 -> dec0 was built before its deceleration lane was entered by a lane change): a's lane 0
    fans out into junction lanes 0 and 1 (to d_0 and d_1), a_1 -> :j_0_2 -> d_2, a_2 -> :j_0_3
    -> d_3. A CAV in a's left lane is on junction lane 3: still a's lane 2 (the first junction
    lane's offset for all made it lane 3, the swarm steered it 1.2 m right, into a car, in the
    study)."""
    lanes = {
        "a_0": (100.0, 3.5, STRAIGHT, [("d_0", ":j_0_0"), ("d_1", ":j_0_1")]),
        "a_1": (100.0, 3.5, STRAIGHT, [("d_2", ":j_0_2")]),
        "a_2": (100.0, 3.5, STRAIGHT, [("d_3", ":j_0_3")]),
        **{f":j_0_{q}": (8.0, 3.5, STRAIGHT, [(f"d_{q}", "")]) for q in range(4)},
        **{f"d_{q}": (250.0, 3.5, STRAIGHT, []) for q in range(4)},
    }
    frame = RouteFrame(TableNetwork(lanes), ["a", "d"])
    assert frame.lane_offset["d"] == -1 and frame.lane_offset[":j_0"] == -1
    assert [frame.lane_as_on(q, ":j_0", "a") for q in range(4)] == [0, 0, 1, 2]
    assert [frame.lane_as_on(q, "d", "a") for q in range(4)] == [-1, 0, 1, 2]
    assert frame.lane_as_on(3, ":j_0", "d") == 3  # the lane it enters, numbered on d
