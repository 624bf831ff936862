"""Who is ahead of whom, without SUMO: hand-made cases, and the sorted snapshot the guards use
answering exactly as a scan over every vehicle does."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.neighbours import (
    Snapshot,
    cav_alongside_behind,
    overlapping_ahead,
    snapshot_of,
    vehicle_ahead,
    vehicle_behind,
    within,
)

ROAD = RoadSection((3.2, 3.2, 3.2))


def car(vid, s, lane, *, length=5.0, lat=0.0, cav=False):
    return VehicleState(vid, s, lane, lat, 20.0, length, 0.0, cav)


def both(vehicles):
    return [list(vehicles), Snapshot(vehicles, ROAD)]


def test_the_nearest_rear_bumper_ahead_even_when_its_front_is_further():
    ego = car("ego", 100.0, 1, cav=True)
    vehicles = [
        ego,
        car("car", 120.0, 1),  # rear at 115: gap 15
        car("truck", 125.0, 1, length=16.0),  # front further, rear at 109: gap 9
        car("beside", 104.0, 0),  # another lane
    ]
    for others in both(vehicles):
        lead, gap = vehicle_ahead(ego, others, ROAD)
        assert (lead.vehicle_id, gap) == ("truck", 9.0)


def test_behind_is_the_nearest_front_bumper_and_the_probe_looks_into_another_lane():
    ego = car("ego", 100.0, 1, cav=True)  # rear at 95
    vehicles = [ego, car("far", 60.0, 1), car("near", 80.0, 1), car("left", 90.0, 2)]
    for others in both(vehicles):
        assert vehicle_behind(ego, others, ROAD) == (vehicles[2], 15.0)
        assert vehicle_behind(ego, others, ROAD, y_m=ROAD.lane_centre_y(2)) == (vehicles[3], 5.0)
        assert vehicle_ahead(ego, others, ROAD) is None


def test_an_hv_drifting_towards_the_lane_counts_before_it_is_in_it():
    ego = car("ego", 100.0, 1, cav=True)
    # A car on the centre of the lane next door (3.2 m off ego's centre) does not overlap;
    # one 0.7 m off its centre towards ego's lane (2.5 m off: cutting in) does.
    centred = car("centred", 130.0, 0)
    drifting = car("drifting", 130.0, 2, lat=-0.7)
    for others in both([ego, centred]):
        assert vehicle_ahead(ego, others, ROAD) is None
    for others in both([ego, drifting]):
        assert vehicle_ahead(ego, others, ROAD)[0].vehicle_id == "drifting"


def test_a_cav_beside_with_its_front_behind_egos_is_neither_ahead_nor_behind():
    ego = car("ego", 302.0, 1, cav=True, lat=-0.6)  # rear at 297
    beside = car("c0", 300.0, 0, cav=True)  # front between ego's rear and front
    y0 = ROAD.lane_centre_y(0)
    for others in both([ego, beside]):
        assert vehicle_ahead(ego, others, ROAD, y_m=y0) is None
        assert vehicle_behind(ego, others, ROAD, y_m=y0)[1] < 0.0  # overlapping, not behind
    assert cav_alongside_behind(ego, [ego, beside], ROAD, y0) is beside
    # Not an HV, not one in another lane, not one whose front is ahead of ego's.
    assert cav_alongside_behind(ego, [car("h", 300.0, 0)], ROAD, y0) is None
    assert cav_alongside_behind(ego, [car("c2", 300.0, 2, cav=True)], ROAD, y0) is None
    assert cav_alongside_behind(ego, [car("c3", 303.0, 0, cav=True)], ROAD, y0) is None


vehicle = st.builds(
    lambda i, s, lane, lat, length, cav: car(f"v{i}", s, lane, length=length, lat=lat, cav=cav),
    st.integers(0, 10**6),
    st.floats(0.0, 400.0),
    st.integers(0, 2),
    st.floats(-1.5, 1.5),
    st.sampled_from([4.5, 5.0, 12.0, 18.75]),
    st.booleans(),
)


@settings(max_examples=300, deadline=None)
@given(st.lists(vehicle, min_size=1, max_size=40, unique_by=lambda v: v.vehicle_id),
       st.floats(-2.0, 8.4), st.booleans())  # fmt: skip
def test_the_snapshot_answers_as_the_scan_over_every_vehicle(vehicles, y_probe, probe):
    snap = Snapshot(vehicles, ROAD)
    for ego in vehicles:
        y = y_probe if probe else None
        for look in (vehicle_ahead, vehicle_behind):
            slow, fast = look(ego, vehicles, ROAD, y_m=y), look(ego, snap, ROAD, y_m=y)
            assert (slow is None) == (fast is None)
            if slow is not None:
                assert fast[1] == slow[1]  # the same gap (on a tie, either vehicle)


def test_within_a_reach_of_a_position_open_at_both_ends():
    vehicles = [car(f"v{s:.0f}", s, 0) for s in (50.0, 80.0, 99.0, 120.0, 140.0, 180.0)]
    for others in both(vehicles):
        # 40 m around 100: 80, 99 and 120; 60 and 140 are exactly 40 away: out.
        assert [v.vehicle_id for v in within(others, 100.0, 40.0)] == ["v80", "v99", "v120"]
        assert within(others, 99.5, 0.6) == [vehicles[2]]
        assert within(others, 1000.0, 40.0) == []
    # 60 m away exactly: not within 60 m.
    assert [v.vehicle_id for v in within(Snapshot(vehicles, ROAD), 120.0, 60.0)] == [
        "v80",
        "v99",
        "v120",
        "v140",
    ]


def test_one_snapshot_per_states_table_and_road_until_the_table_changes():
    states = {v.vehicle_id: v for v in (car("a", 50.0, 0), car("b", 20.0, 1), car("c", 80.0, 2))}
    snap = snapshot_of(states, ROAD)
    assert [v.vehicle_id for v in snap] == ["b", "a", "c"]
    assert snapshot_of(states, ROAD) is snap
    # Another table of the same vehicles, or the same table on another road: a new one.
    assert snapshot_of(dict(states), ROAD) is not snap
    other_road = RoadSection((3.5, 3.5, 3.5))
    assert snapshot_of(states, other_road) is not snap
    # A vehicle dropped from the table (one that vanished from SUMO), or given a new state in
    # place: made again.
    del states["a"]
    assert [v.vehicle_id for v in snapshot_of(states, ROAD)] == ["b", "c"]
    states["b"] = car("b", 120.0, 1)
    assert [v.vehicle_id for v in snapshot_of(states, ROAD)] == ["c", "b"]


def test_one_table_on_two_roads_keeps_each_roads_lateral_positions():
    # Sorted once per table, but the lateral positions are each road's: lane 1's centre is
    # 3.2 m from lane 0's on the first road, 3.5 m on the second; a lane beyond the section
    # (a vehicle still on an edge with more lanes) extends the outermost width.
    states = {v.vehicle_id: v for v in (car("a", 50.0, 1), car("b", 20.0, 0), car("c", 80.0, 4))}
    narrow, wide = snapshot_of(states, ROAD), snapshot_of(states, RoadSection((3.5, 3.5, 3.5)))
    assert [v.vehicle_id for v in narrow] == [v.vehicle_id for v in wide] == ["b", "a", "c"]
    assert narrow.s == wide.s == [20.0, 50.0, 80.0]
    assert narrow.y == pytest.approx([0.0, 3.2, 12.8])
    assert wide.y == pytest.approx([0.0, 3.5, 14.0])


def test_an_hv_standing_off_its_lane_centre_counts_by_its_body_only():
    # A car stuck at the end of an acceleration lane, 0.7 m towards ego's lane, standing: not
    # a leader cutting in (the CAV behind it stood there and the merge deadlocked); the same car
    # rolling at 2 m/s is one.
    ego = car("ego", 100.0, 1, cav=True)
    standing = VehicleState("merging", 110.0, 0, 0.7, 0.0, 5.0, 0.0, False)
    rolling = VehicleState("merging", 110.0, 0, 0.7, 2.0, 5.0, 0.0, False)
    for others in both([ego, standing]):
        assert vehicle_ahead(ego, others, ROAD) is None
    for others in both([ego, rolling]):
        assert vehicle_ahead(ego, others, ROAD)[0].vehicle_id == "merging"
    # Its body in ego's lane counts whatever its speed.
    inside = VehicleState("merging", 110.0, 0, 1.5, 0.0, 5.0, 0.0, False)
    for others in both([ego, inside]):
        assert vehicle_ahead(ego, others, ROAD)[0].vehicle_id == "merging"


def test_every_vehicle_ahead_in_reach_not_only_the_nearest():
    # An HV drifting in (0.8 m off its lane centre, moving) 3 m ahead of ego hides a CAV 5 m
    # ahead in ego's lane from vehicle_ahead; both are there, the far one out of reach is not.
    ego = car("e", 100.0, 1, cav=True)
    drifting = car("h", 108.0, 2, lat=-1.6)
    cav = car("c", 110.0, 1, cav=True)
    far = car("f", 200.0, 1)
    beside = car("b", 104.0, 0)  # another lane, no drift: not overlapping
    snap = Snapshot([ego, drifting, cav, far, beside], ROAD)
    y = ROAD.y_of(1, 0.0)
    found = overlapping_ahead(ego, snap, ROAD, y, 1.8, reach_m=60.0)
    assert found == [(drifting, 3.0), (cav, 5.0)]
    assert vehicle_ahead(ego, snap, ROAD, y_m=y) == (drifting, 3.0)  # the nearest of them
