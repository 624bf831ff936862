"""Property-based tests (hypothesis) of the config loader and the state <-> cell mapping."""

from __future__ import annotations

import json
import math
import typing

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sumo_swarm.config import (
    SECTIONS,
    from_mapping,
    load_scenario,
    nested_dataclass,
    union_members,
)
from sumo_swarm.core.grid import GridSettings, MovingGrid, cav_cell
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.errors import ConfigError

KNOWN = {
    name: sorted(f for f in tp.__dataclass_fields__ if not f.startswith("_"))
    for name, tp in SECTIONS.items()
}
toml_values = st.one_of(
    st.integers(-(10**6), 10**6),
    st.floats(allow_nan=True, allow_infinity=True),
    st.booleans(),
    st.text(max_size=8),
    st.lists(st.integers(-3, 3), max_size=3),
    st.none(),
)
NON_FINITE = (math.nan, math.inf, -math.inf)


def numeric_keys(cls: type, prefix: str) -> list[str]:
    """Every dotted key below ``cls`` whose type hint admits an int or a float (nested tables
    followed; a list of tables as its first item, ``[0]``)."""
    keys = []
    for name, tp in typing.get_type_hints(cls).items():
        if not cls.__dataclass_fields__[name].init:
            continue
        dotted = f"{prefix}.{name}"
        nested = nested_dataclass(tp)
        if nested is not None:
            below = dotted if nested[0] == "table" else f"{dotted}[0]"
            keys += numeric_keys(nested[1], below)
        elif any(arg in (int, float) for arg in union_members(tp)):
            keys.append(dotted)
    return keys


NUMERIC_KEYS = [key for name, tp in sorted(SECTIONS.items()) for key in numeric_keys(tp, name)]


def _table(dotted: str, value: object) -> tuple[str, dict]:
    """``("cav", {"length_m": value})`` for ``"cav.length_m"``; a list item gets the required
    keys of an HV placement around it."""
    section, *path = dotted.split(".")
    table: dict = {}
    node = table
    for part in path[:-1]:
        if part.endswith("[0]"):
            item = {"id": "x", "lane": 0, "front_m": 10.0}
            node[part[:-3]] = [item]
            node = item
        else:
            node = node.setdefault(part, {})
    node[path[-1]] = value
    return section, table


def _toml(value: object) -> str:
    """``value`` in TOML syntax (tables and lists inline; TOML spells NaN ``nan``)."""
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + " }"
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    if isinstance(value, float) and not math.isfinite(value):
        return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
    return json.dumps(value)


def test_numeric_keys_are_found():
    # the walk above must see the keys this file's NaN checks are about
    for key in ("cav.accel_min_mps2", "planner.weights.w_tar", "scene.hv[0].speed_mps"):
        assert key in NUMERIC_KEYS
    assert len(NUMERIC_KEYS) > 60


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(section=st.sampled_from(sorted(SECTIONS)), data=st.data(), value=toml_values)
def test_loader_accepts_or_refuses_with_a_config_error(section, data, value):
    key = data.draw(st.sampled_from(KNOWN[section]))
    try:
        obj = from_mapping(SECTIONS[section], {key: value}, prefix=section)
    except ConfigError as exc:
        assert key in str(exc), str(exc)
    else:
        # accepted: read back as given (ints may become floats), so never NaN or inf
        got = getattr(obj, key)
        assert got == (tuple(value) if isinstance(value, list) else value), (key, value, got)
        assert not (isinstance(got, float) and not math.isfinite(got)), (key, got)


@settings(max_examples=300, deadline=None)
@given(key=st.sampled_from(NUMERIC_KEYS), value=st.sampled_from(NON_FINITE))
def test_non_finite_numbers_are_refused_naming_the_key(key, value):
    section, table = _table(key, value)
    try:
        from_mapping(SECTIONS[section], table, prefix=section)
    except ConfigError as exc:
        assert key in str(exc), str(exc)
    else:
        raise AssertionError(f"{key} = {value} accepted")


@pytest.mark.parametrize("key", NUMERIC_KEYS)
def test_nan_in_a_scenario_file_names_key_and_file(tmp_path, key):
    section, table = _table(key, math.nan)
    path = tmp_path / "s.toml"
    lines = [f"[{section}]", *(f"{k} = {_toml(v)}" for k, v in table.items())]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    with pytest.raises(ConfigError) as err:
        load_scenario(path, require_network=False)
    assert key in str(err.value) and str(path) in str(err.value)


@given(
    section=st.sampled_from(sorted(SECTIONS)),
    # identifiers drawn as such: filtering random text for them failed Hypothesis's health
    # check now and then (50 of 57 draws thrown away)
    key=st.from_regex(r"[A-Za-z_][A-Za-z0-9_]{0,11}", fullmatch=True),
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


@given(widths=widths, lane=st.integers(-3, 8), within=st.floats(-0.49, 0.49))
def test_a_lane_beside_the_road_maps_back_to_itself_and_its_nearest_is_the_edge_lane(
    widths, lane, within
):
    # A lane counted beside the section (an acceleration lane is -1) has a band of the
    # outermost lane's width there: a point in it maps back to that lane, not into the road
    # (a car in an acceleration lane is not in lane 0); its nearest lane of the section is the
    # outermost one on that side, and a lane of the section is itself.
    road = RoadSection(tuple(widths))
    outer = widths[0] if lane < 0 else widths[-1] if lane >= road.n_lanes else widths[lane]
    assert road.lane_of_y(road.lane_centre_y(lane) + within * outer) == lane
    edge_lane = 0 if lane < 0 else road.n_lanes - 1 if lane >= road.n_lanes else lane
    assert road.nearest_lane(lane) == edge_lane


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
    assert math.isclose(
        grid.cell_centre_s(row, dt),
        grid.origin_at(dt) + (row + 0.5) * cell,
        rel_tol=0,
        abs_tol=1e-6,
    )
    assert abs(grid.cell_centre_s(grid.row_of(centre, dt), dt) - centre) <= cell / 2 + 1e-6


def test_grid_settings_refuse_bad_values():
    for bad in ({"cell_length_m": 0.0}, {"headway_s": -1.0}, {"rows_ahead": -2}):
        try:
            GridSettings(**bad)
        except ConfigError:
            continue
        raise AssertionError(f"accepted {bad}")
