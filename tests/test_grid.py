"""Moving grid: hand-computed rows, origins, HV footprints (sumo_swarm.core.grid)."""

from __future__ import annotations

import pytest

from sumo_swarm.core.grid import (
    ConstantSpeedPredictor,
    GridSettings,
    MovingGrid,
    build_grid,
    cav_cell,
    hv_blocked_cells,
)
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.errors import ConfigError

ROAD3 = RoadSection((3.0, 3.0, 3.0))
SETTINGS = GridSettings()


def veh(vid: str, s_m: float, lane: int, speed: float = 17.5, lat: float = 0.0) -> VehicleState:
    return VehicleState(vid, s_m, lane, lat, speed, 5.0)


def fig7_grid() -> MovingGrid:
    cavs = [veh(f"c{i}", 300.0 - 15.0 * i, 1) for i in range(6)]
    return build_grid(cavs, veh("t", 315.0, 1), ROAD3, 0.0, 17.5, SETTINGS)


def test_settings_validation_names_the_field():
    for kwargs, name in [
        ({"cell_length_m": 0.0}, "cell_length_m"),
        ({"headway_s": -1.0}, "headway_s"),
        ({"gap_behind_m": float("nan")}, "gap_behind_m"),
        ({"cav_length_m": -5.0}, "cav_length_m"),
        ({"lateral_overlap_m": -0.1}, "lateral_overlap_m"),
        ({"rows_ahead": -1}, "rows_ahead"),
        ({"rows_ahead": 2.5}, "rows_ahead"),
    ]:
        with pytest.raises(ConfigError, match=name):
            GridSettings(**kwargs)


def test_fig7_grid_origin_rows_and_size():
    grid = fig7_grid()
    # Tail front bumper 225, centre 222.5 -> origin 222.5 - 7.5 = 215.
    assert grid.origin_s_m == pytest.approx(215.0)
    # Target footprint: centres in (310 - 5 - 2.5, 315 + 21 + 2.5) = (302.5, 338.5) -> rows 6, 7
    # (centres 312.5, 327.5); plus rows_ahead = 6 CAVs -> 8 + 6 rows.
    assert grid.n_rows == 14
    assert grid.n_cols == 3
    assert grid.cell_centre_s(0, 0.0) == pytest.approx(222.5)
    assert grid.cell_centre_s(5, 0.0) == pytest.approx(297.5)
    assert grid.column_y(2) == pytest.approx(6.0)  # from the centre of lane 0
    assert grid.contains(13, 2) and not grid.contains(14, 0) and not grid.contains(0, 3)
    assert not grid.contains(-1, 0)


def test_cav_cells_of_fig7_platoon():
    grid = fig7_grid()
    for i in range(6):
        cav = veh(f"c{i}", 300.0 - 15.0 * i, 1)
        assert cav_cell(grid, cav, ROAD3, 0.0) == (5 - i, 1)


def test_moving_origin_and_rows_over_time():
    grid = MovingGrid(100.0, 10.0, 20.0, 15.0, 5, ROAD3)
    assert grid.origin_at(10.0) == pytest.approx(100.0)
    assert grid.origin_at(13.0) == pytest.approx(160.0)  # 100 + 20 * 3
    # A point fixed on the road falls back one row every 15 m the grid moves.
    assert grid.row_of(140.0, 10.0) == 2  # (140 - 100) / 15 = 2.67
    assert grid.row_of(140.0, 10.75) == 1  # origin 115 -> 1.67
    assert grid.row_of(90.0, 10.0) == -1  # behind the grid
    assert grid.cell_centre_s(2, 13.0) == pytest.approx(160.0 + 37.5)
    # A vehicle at the grid speed keeps its cell.
    cav = veh("c", 150.0, 0, speed=20.0)
    later = ConstantSpeedPredictor().predict(cav, 10.0, 16.0)
    assert later.s_m == pytest.approx(270.0)
    assert cav_cell(grid, cav, ROAD3, 10.0) == cav_cell(grid, later, ROAD3, 16.0) == (3, 0)


def test_lateral_offset_picks_the_column_of_the_centre():
    grid = fig7_grid()
    # 1.6 m left of lane 1's centre is past the lane edge at 1.5 m -> column 2.
    assert cav_cell(grid, veh("c", 270.0, 1, lat=1.6), ROAD3, 0.0) == (3, 2)
    assert cav_cell(grid, veh("c", 270.0, 1, lat=-1.4), ROAD3, 0.0) == (3, 1)


def test_hv_footprint_hand_computed():
    grid = fig7_grid()
    # Left HV, lane 2, front 255: centres in (250 - 7.5, 255 + 21 + 2.5) = (242.5, 278.5):
    # rows 2 (252.5) and 3 (267.5).
    assert hv_blocked_cells(grid, veh("l", 255.0, 2), 0.0, SETTINGS) == {(2, 2), (3, 2)}
    # Right HV, lane 0, front 240: (227.5, 263.5) -> rows 1 (237.5), 2 (252.5).
    assert hv_blocked_cells(grid, veh("r", 240.0, 0), 0.0, SETTINGS) == {(1, 0), (2, 0)}
    # Slower HV: headway shrinks. Front 240 at 5 m/s: (227.5, 240 + 6 + 2.5 = 248.5) -> row 1.
    assert hv_blocked_cells(grid, veh("r", 240.0, 0, speed=5.0), 0.0, SETTINGS) == {(1, 0)}


def test_margins_are_open_bounds():
    grid = MovingGrid(0.0, 0.0, 0.0, 15.0, 10, ROAD3)
    settings = GridSettings(headway_s=0.0, gap_behind_m=0.0)
    # HV 5 m, front 30: centres in (25 - 2.5, 30 + 2.5) = (22.5, 32.5): row 1's centre 22.5 is
    # on the bound (a CAV there would touch bumpers) -> free; nothing else is in.
    assert hv_blocked_cells(grid, veh("h", 30.0, 0, speed=0.0), 0.0, settings) == frozenset()
    assert hv_blocked_cells(grid, veh("h", 29.9, 0, speed=0.0), 0.0, settings) == {(1, 0)}


def test_partial_hv_only_in_grid_rows_count():
    grid = fig7_grid()
    # Upstream HV lane 2 front 225: (212.5, 248.5) -> rows -1? centre 207.5 no; rows 0, 1.
    assert hv_blocked_cells(grid, veh("u", 225.0, 2), 0.0, SETTINGS) == {(0, 2), (1, 2)}
    # Front 210 in lane 0: (197.5, 233.5) -> row -1 (centre 207.5) is outside, row 0 counts.
    assert hv_blocked_cells(grid, veh("u", 210.0, 0), 0.0, SETTINGS) == {(0, 0)}
    # Wholly behind the grid.
    assert hv_blocked_cells(grid, veh("u", 195.0, 1), 0.0, SETTINGS) == frozenset()
    # Straddling the front edge (grid ends at 215 + 14 * 15 = 425): centre rows 13 (417.5) only.
    assert hv_blocked_cells(grid, veh("f", 425.0, 1), 0.0, SETTINGS) == {(13, 1)}


def test_lateral_overlap_blocks_the_neighbour_column():
    grid = fig7_grid()
    rows = {(2, 2), (3, 2)}
    left_hv = veh("l", 255.0, 2, lat=-0.7)  # leaning right by 0.7 m > 0.6 m
    assert hv_blocked_cells(grid, left_hv, 0.0, SETTINGS) == rows | {(2, 1), (3, 1)}
    assert hv_blocked_cells(grid, veh("l", 255.0, 2, lat=-0.5), 0.0, SETTINGS) == rows
    # Leaning off the road edge: no neighbour column there.
    assert hv_blocked_cells(grid, veh("l", 255.0, 2, lat=0.9), 0.0, SETTINGS) == rows
    right_hv = veh("r", 240.0, 0, lat=0.61)
    assert hv_blocked_cells(grid, right_hv, 0.0, SETTINGS) == {(1, 0), (2, 0), (1, 1), (2, 1)}


def test_moving_grid_and_predicted_hv():
    grid = fig7_grid()
    predictor = ConstantSpeedPredictor()
    hv = veh("l", 255.0, 2)
    later = predictor.predict(hv, 0.0, 9.0)
    assert later.s_m == pytest.approx(255.0 + 17.5 * 9.0)
    # Same speed as the grid: same cells.
    assert hv_blocked_cells(grid, later, 9.0, SETTINGS) == {(2, 2), (3, 2)}
    # 2.5 m/s faster: 7.5 m per 3 s; after 6 s it is 15 m (one row) ahead in the grid.
    fast = veh("f", 255.0, 2, speed=20.0)
    moved = predictor.predict(fast, 0.0, 6.0)
    # At 6 s: front 375, origin 215 + 105 = 320, row centres 327.5 + 15 r. Footprint centres in
    # (370 - 7.5, 375 + 1.2 * 20 + 2.5) = (362.5, 401.5) -> rows 3 (372.5) and 4 (387.5).
    cells = hv_blocked_cells(grid, moved, 6.0, SETTINGS)
    assert cells == {(3, 2), (4, 2)}


def test_build_grid_rows_ahead_and_leader_ahead_of_target():
    cavs = [veh("a", 100.0, 0), veh("b", 85.0, 0)]
    target = veh("t", 60.0, 1, speed=10.0)  # behind the platoon already
    grid = build_grid(cavs, target, ROAD3, 0.0, 10.0, GridSettings(rows_ahead=3))
    # Origin = 82.5 - 7.5 = 75; leader centre 97.5 -> row 1; target top row < 1 -> 1 + 1 + 3.
    assert grid.origin_s_m == pytest.approx(75.0)
    assert grid.n_rows == 5
    with pytest.raises(ConfigError):
        build_grid([], target, ROAD3, 0.0, 10.0, SETTINGS)


def test_a_vehicle_beside_the_road_is_placed_at_the_edge_lane_of_the_grid():
    # A CAV or HV still in an acceleration lane (SUMO's lane counted as -1 on the road's edge)
    # is in no lane of the road; the grid places it in lane 0 beside which it drives: the CAV
    # starts from a cell of the grid (not column -1, which no plan could start from), the HV
    # claims lane 0's cells as it merges (not column -1, which the plan would ignore).
    grid = fig7_grid()
    assert ROAD3.lane_of(veh("c", 270.0, -1)) == -1
    assert cav_cell(grid, veh("c", 270.0, -1), ROAD3, 0.0) == (3, 0)
    assert cav_cell(grid, veh("c", 270.0, -1, lat=1.6), ROAD3, 0.0) == (3, 0)  # half in lane 0
    merging = veh("m", 255.0, -1)
    assert hv_blocked_cells(grid, merging, 0.0, SETTINGS) == {(2, 0), (3, 0)}
    # A lane beyond the left edge (an edge with more lanes): the last column.
    assert cav_cell(grid, veh("c", 270.0, 3), ROAD3, 0.0) == (3, 2)
