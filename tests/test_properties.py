"""Property-based tests (hypothesis) of the config loader and the state <-> cell mapping."""

from __future__ import annotations

import math

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sumo_swarm.config import SECTIONS, from_mapping
from sumo_swarm.errors import ConfigError
from sumo_swarm.grid import GridSettings, MovingGrid, cav_cell
from sumo_swarm.model import RoadSection, VehicleState

KNOWN = {
    name: sorted(f for f in tp.__dataclass_fields__ if not f.startswith("_"))
    for name, tp in SECTIONS.items()
}
toml_values = st.one_of(
    st.integers(-10**6, 10**6), st.floats(allow_nan=True, allow_infinity=True), st.booleans(),
    st.text(max_size=8), st.lists(st.integers(-3, 3), max_size=3), st.none(),
)  # fmt: skip


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(section=st.sampled_from(sorted(SECTIONS)), data=st.data(), value=toml_values)
def test_loader_accepts_or_refuses_with_a_config_error(section, data, value):
    key = data.draw(st.sampled_from(KNOWN[section]))
    try:
        obj = from_mapping(SECTIONS[section], {key: value}, prefix=section)
    except ConfigError as exc:
        assert section in str(exc) or key in str(exc)
    else:
        assert getattr(obj, key) is not None or value is None


@given(
    section=st.sampled_from(sorted(SECTIONS)),
    key=st.text(min_size=1, max_size=12).filter(lambda k: k.isidentifier()),
)
def test_unknown_keys_are_always_named(section, key):
    if key in KNOWN[section]:
        return
    try:
        from_mapping(SECTIONS[section], {key: 1}, prefix=section)
    except ConfigError as exc:
        assert f"{section}.{key}" in str(exc)
    else:
        raise AssertionError(f"unknown key {section}.{key} accepted")


widths = st.lists(st.floats(2.5, 4.0), min_size=1, max_size=6)


@given(widths=widths)
def test_lane_centres_map_back_to_their_lane(widths):
    road = RoadSection(tuple(widths))
    for lane in range(road.n_lanes):
        assert road.lane_of_y(road.lane_centre_y(lane)) == lane
        # anywhere strictly inside the lane band maps to the lane
        assert road.lane_of_y(road.lane_centre_y(lane) + 0.49 * widths[lane]) == lane


@given(
    widths=widths,
    cell=st.floats(5.0, 30.0),
    speed=st.floats(0.0, 40.0),
    origin=st.floats(-1e4, 1e4),
    dt=st.floats(0.0, 60.0),
    row=st.integers(0, 30),
    offset=st.floats(-0.49, 0.49),
    data=st.data(),
)
def test_state_to_cell_and_back(widths, cell, speed, origin, dt, row, offset, data):
    road = RoadSection(tuple(widths))
    grid = MovingGrid(origin, 0.0, speed, cell, 31, road)
    lane = data.draw(st.integers(0, road.n_lanes - 1))
    centre = grid.cell_centre_s(row, dt) + offset * cell
    length = 5.0
    cav = VehicleState("c", centre + length / 2, lane, 0.0, speed, length, is_cav=True)
    assert cav_cell(grid, cav, road, dt) == (row, lane)
    assert math.isclose(grid.cell_centre_s(row, dt), grid.origin_at(dt) + (row + 0.5) * cell,
                        rel_tol=0, abs_tol=1e-6)  # fmt: skip
    assert abs(grid.cell_centre_s(grid.row_of(centre, dt), dt) - centre) <= cell / 2 + 1e-6


def test_grid_settings_refuse_bad_values():
    for bad in ({"cell_length_m": 0.0}, {"headway_s": -1.0}, {"rows_ahead": -2}):
        try:
            GridSettings(**bad)
        except ConfigError:
            continue
        raise AssertionError(f"accepted {bad}")
