"""Tests of sumo_swarm.core.trajectory: cells -> smooth reference (eqs. (20)-(22))."""

from __future__ import annotations

import numpy as np
import pytest

from sumo_swarm.core.model import RoadSection
from sumo_swarm.core.trajectory import (
    GridFrame,
    cell_waypoints,
    reference_from_cells,
    waypoint_error_m,
)
from sumo_swarm.errors import ConfigError

ROAD = RoadSection(lane_widths_m=(3.0, 3.5, 3.0))  # lane centres at y = 0, 3.25, 6.5
FRAME = GridFrame(
    origin_s_m=100.0,
    t0_s=10.0,
    speed_mps=17.5,
    cell_length_m=15.0,
    behaving_interval_s=3.0,
    road=ROAD,
)
A_MIN, A_MAX, JERK = -4.0, 3.0, 5.0
# Error in the middle of a one-row-per-interval speed change (5 m/s) with the defaults:
# accel 0.8 * 3 = 2.4, b1 = 2.4 / 5 = 0.48 s, b2 = 5 / 2.4 = 2.0833 s, half width 1.28167 s.
ROW_MOVE_ERROR_M = 5.0 * (1.281667**3 - 0.801667**3) / (6.0 * 0.48 * 5.0 / 2.4)


def dense_times(ref, before_s=2.0, after_s=6.0, dt_s=0.005):
    return np.arange(FRAME.t0_s - before_s, ref.t_end_s + after_s, dt_s)


def assert_within_limits(ref, t, jerk_limit=JERK):
    """Acceleration within the bounds, jerk within ``jerk_limit`` (one transition: ``JERK``;
    overlapping transitions or a blend: ``2 * JERK``)."""
    s, v, a = ref.evaluate_time(t)
    assert a.max() <= A_MAX + 1e-9
    assert a.min() >= A_MIN - 1e-9
    assert np.abs(ref.jerk_at(t)).max() <= jerk_limit + 1e-9
    assert v.min() >= 0.0
    return s, v, a


def test_waypoints_follow_eqs_20_to_22():
    t, s, y = cell_waypoints([(0, 0), (1, 0), (1, 1), (1, 2)], FRAME)
    np.testing.assert_allclose(t, [10.0, 13.0, 16.0, 19.0])
    # origin + v_cell * k * dT + (row + 0.5) * l_cell
    np.testing.assert_allclose(s, [107.5, 175.0, 227.5, 280.0])
    np.testing.assert_allclose(y, [0.0, 0.0, 3.25, 6.5])


def test_waypoint_error_formula_matches_hand_computation():
    assert waypoint_error_m(5.0, 2.4, 5.0) == pytest.approx(ROW_MOVE_ERROR_M, rel=1e-5)
    assert abs(ROW_MOVE_ERROR_M - 1.3251) < 1e-4
    assert waypoint_error_m(0.0, 2.4, 5.0) == 0.0


def test_cav_staying_in_its_cell_drives_at_grid_speed_on_the_cell_centre():
    ref = reference_from_cells([(2, 1)] * 4, FRAME)
    t = dense_times(ref)
    s, v, a = ref.evaluate_time(t)
    np.testing.assert_allclose(s, 100.0 + 17.5 * (t - 10.0) + 2.5 * 15.0, atol=1e-9)
    np.testing.assert_allclose(v, 17.5, atol=1e-12)
    np.testing.assert_allclose(a, 0.0, atol=1e-12)
    y, dy, _ = ref.evaluate_space(s)
    np.testing.assert_allclose(y, 3.25, atol=1e-12)
    np.testing.assert_allclose(dy, 0.0, atol=1e-12)
    assert ref.s_at(11.0) == pytest.approx(100.0 + 17.5 + 37.5, abs=1e-9)
    assert ref.v_at(11.0) == pytest.approx(17.5)


def test_one_row_forward_per_interval_hits_waypoints_within_stated_tolerance():
    cells = [(row, 1) for row in range(6)] + [(5, 1)] * 3
    ref = reference_from_cells(cells, FRAME)
    t_wp, s_wp, _ = cell_waypoints(cells, FRAME)
    errors = np.array([ref.s_at(t) for t in t_wp]) - s_wp
    # speed changes at steps 0 (start moving) and 5 (stop): error of one transition there
    assert errors[0] == pytest.approx(ROW_MOVE_ERROR_M, abs=1e-6)
    assert errors[5] == pytest.approx(-waypoint_error_m(-5.0, 3.2, 5.0), abs=1e-6)
    # constant relative speed elsewhere: exactly on the waypoint
    np.testing.assert_allclose(errors[[1, 2, 3, 4, 6, 7, 8]], 0.0, atol=1e-9)
    _, v, _ = assert_within_limits(ref, dense_times(ref))
    assert v.max() == pytest.approx(17.5 + 5.0)  # one row (15 m) per 3 s on top of the grid
    assert v.min() == pytest.approx(17.5)


def test_after_the_last_cell_the_reference_continues_at_grid_speed_in_the_last_column():
    cells = [(0, 0), (1, 0), (1, 1)]
    ref = reference_from_cells(cells, FRAME)
    t_late = ref.t_end_s + np.array([5.0, 10.0, 30.0])
    s, v, a = ref.evaluate_time(t_late)
    np.testing.assert_allclose(s, FRAME.origin_s_m + 17.5 * (t_late - 10.0) + 1.5 * 15.0)
    np.testing.assert_allclose(v, 17.5)
    np.testing.assert_allclose(a, 0.0, atol=1e-12)
    np.testing.assert_allclose(ref.evaluate_space(s)[0], 3.25)


def test_reversal_moves_keep_acceleration_within_bounds():
    # back, forward, back: relative speed -5, +5, -5, +5 m/s (changes of 10 m/s overlap)
    cells = [(2, 1), (1, 1), (2, 1), (1, 1), (2, 1), (2, 1)]
    ref = reference_from_cells(cells, FRAME)
    assert_within_limits(ref, dense_times(ref), jerk_limit=2.0 * JERK)


def test_lane_changes_end_exactly_on_unequal_lane_centres_with_bounded_lateral_speed():
    cells = [(1, 0), (1, 1), (1, 2), (1, 2), (1, 1)]
    ref = reference_from_cells(cells, FRAME, max_lat_speed_mps=2.5, max_lat_accel_mps2=3.0)
    t_wp, _, y_wp = cell_waypoints(cells, FRAME)
    np.testing.assert_allclose(y_wp, [0.0, 3.25, 6.5, 6.5, 3.25])
    np.testing.assert_allclose([ref.y_at(t) for t in t_wp], y_wp, atol=1e-12)
    t = dense_times(ref)
    s, v, _ = ref.evaluate_time(t)
    _, dy, ddy = ref.evaluate_space(s)
    assert np.abs(dy * v).max() <= 2.5 + 1e-9
    assert np.abs(ddy * v**2).max() <= 3.0 + 1e-9
    assert np.abs(dy * v).max() > 1.5  # it does move: 3.25 m over one 3 s interval


def test_slow_lateral_limit_stretches_the_lane_change_and_still_ends_on_the_lane_centre():
    cells = [(1, 0), (1, 1), (1, 1), (1, 1), (1, 1)]
    ref = reference_from_cells(cells, FRAME, max_lat_speed_mps=1.0)
    t = dense_times(ref)
    s, v, _ = ref.evaluate_time(t)
    y, dy, _ = ref.evaluate_space(s)
    assert np.abs(dy * v).max() == pytest.approx(1.0, abs=1e-3)
    assert np.abs(dy * v).max() <= 1.0 + 1e-9
    # 1.875 * 3.25 m * 17.5 m/s / 1 m/s = 106.6 m: more than one interval (52.5 m)
    assert ref.y_at(FRAME.t0_s + 3.0) < 3.25 - 0.1
    assert y[-1] == pytest.approx(3.25, abs=1e-12)
    assert ref.y_at(FRAME.t0_s + 3.0 + 106.7 / 17.5) == pytest.approx(3.25, abs=1e-12)


def test_reference_is_continuous_everywhere():
    cells = [(0, 1), (1, 1), (2, 1), (2, 2), (2, 2), (1, 2), (1, 1), (1, 0), (2, 0)]
    ref = reference_from_cells(cells, FRAME, t_now=10.0, s_now=104.0, v_now=18.0, y_now=3.0)
    dt = 0.001
    t = np.arange(9.0, ref.t_end_s + 5.0, dt)
    s, v, a = ref.evaluate_time(t)
    y = ref.evaluate_space(s)[0]
    assert np.abs(np.diff(s)).max() <= 25.0 * dt
    assert np.abs(np.diff(v)).max() <= 4.0 * dt + 1e-9
    assert np.abs(np.diff(a)).max() <= 2.0 * JERK * dt + 1e-9
    assert np.abs(np.diff(y)).max() <= 2.5 * dt + 1e-9


def test_blend_starts_at_the_vehicle_and_joins_the_cell_path():
    cells = [(1, 1)] * 8
    # 6 m behind the cell centre, 1 m/s slower than the grid, braking lightly
    s_now, v_now, a_now = 100.0 + 22.5 - 6.0, 16.5, -0.5
    ref = reference_from_cells(
        cells, FRAME, t_now=10.0, s_now=s_now, v_now=v_now, a_now=a_now, y_now=2.5
    )
    assert ref.start_time_s == 10.0
    assert ref.s_at(10.0) == pytest.approx(s_now, abs=1e-9)
    assert ref.v_at(10.0) == pytest.approx(v_now, abs=1e-9)
    assert ref.a_at(10.0) == pytest.approx(a_now, abs=1e-9)
    assert ref.y_at(10.0) == pytest.approx(2.5, abs=1e-9)
    assert ref.dy_ds_at_s(s_now) == pytest.approx(0.0, abs=1e-12)
    assert_within_limits(ref, np.arange(10.0, 40.0, 0.01), jerk_limit=2.0 * JERK)
    t_wp, s_wp, _ = cell_waypoints(cells, FRAME)
    late = t_wp > 10.0 + 25.0
    np.testing.assert_allclose([ref.s_at(t) for t in t_wp[late]], s_wp[late], atol=1e-9)
    assert ref.y_at(16.0) == pytest.approx(3.25, abs=1e-12)


def test_replan_from_the_current_reference_state_does_not_jump():
    first = reference_from_cells([(0, 1), (1, 1), (2, 1), (2, 2), (3, 2)], FRAME)
    t_now = 17.3  # inside a lane change and a speed transition
    s_now, v_now, a_now = first.s_at(t_now), first.v_at(t_now), first.a_at(t_now)
    y_now = first.y_at(t_now)
    replan_frame = GridFrame(
        origin_s_m=FRAME.origin_s_m + 17.5 * (t_now - 10.0),
        t0_s=t_now,
        speed_mps=17.5,
        cell_length_m=15.0,
        behaving_interval_s=3.0,
        road=ROAD,
    )
    second = reference_from_cells(
        [(2, 2), (3, 2), (3, 2)],
        replan_frame,
        t_now=t_now,
        s_now=s_now,
        v_now=v_now,
        a_now=a_now,
        y_now=y_now,
    )
    assert second.s_at(t_now) == pytest.approx(s_now, abs=1e-9)
    assert second.v_at(t_now) == pytest.approx(v_now, abs=1e-9)
    assert second.a_at(t_now) == pytest.approx(a_now, abs=1e-9)
    assert second.y_at(t_now) == pytest.approx(y_now, abs=1e-9)
    assert_within_limits(second, np.arange(t_now, t_now + 40.0, 0.01), jerk_limit=2.0 * JERK)


def test_sampling_helpers_return_horizon_arrays():
    ref = reference_from_cells([(0, 0), (1, 0), (1, 1)], FRAME)
    t, s, v, a = ref.sample_time(10.0, 0.1, 30)
    assert t.shape == s.shape == v.shape == a.shape == (31,)
    assert t[-1] == pytest.approx(13.0)
    assert s[5] == pytest.approx(ref.s_at(10.5))
    s_grid, y, dy, ddy = ref.sample_space(200.0, 2.0, 30)
    assert s_grid.shape == y.shape == dy.shape == ddy.shape == (31,)
    assert y[3] == pytest.approx(ref.y_at_s(206.0))
    assert dy[3] == pytest.approx(ref.dy_ds_at_s(206.0))


def test_bad_input_is_rejected_with_the_field_named():
    with pytest.raises(ConfigError, match="cell_length_m"):
        GridFrame(0.0, 0.0, 17.5, 0.0, 3.0, ROAD)
    with pytest.raises(ConfigError, match="speed_mps"):
        GridFrame(0.0, 0.0, -1.0, 15.0, 3.0, ROAD)
    with pytest.raises(ConfigError, match="a_min"):
        reference_from_cells([(0, 0)], FRAME, a_min=1.0)
    with pytest.raises(ConfigError, match="max_lat_speed_mps"):
        reference_from_cells([(0, 0)], FRAME, max_lat_speed_mps=0.0)
    with pytest.raises(ValueError, match="empty"):
        reference_from_cells([], FRAME)
    with pytest.raises(ValueError, match="column 3"):
        reference_from_cells([(0, 0), (0, 3)], FRAME)


def test_derivatives_are_consistent_with_finite_differences():
    cells = [(0, 1), (1, 1), (2, 1), (2, 2), (2, 2), (1, 2), (1, 1), (1, 0), (2, 0)]
    ref = reference_from_cells(
        cells, FRAME, t_now=10.0, s_now=104.0, v_now=18.0, a_now=0.3, y_now=3.0
    )
    t = np.random.default_rng(7).uniform(8.0, 50.0, 2000)
    h = 1e-5
    s, v, a = ref.evaluate_time(t)
    s_plus, v_plus, _ = ref.evaluate_time(t + h)
    s_minus, v_minus, _ = ref.evaluate_time(t - h)
    np.testing.assert_allclose((s_plus - s_minus) / (2 * h), v, atol=1e-6)
    np.testing.assert_allclose((v_plus - v_minus) / (2 * h), a, atol=1e-6)
    _, dy, ddy = ref.evaluate_space(s)
    y_plus, dy_plus, _ = ref.evaluate_space(s + h)
    y_minus, dy_minus, _ = ref.evaluate_space(s - h)
    np.testing.assert_allclose((y_plus - y_minus) / (2 * h), dy, atol=1e-7)
    np.testing.assert_allclose((dy_plus - dy_minus) / (2 * h), ddy, atol=1e-7)


def test_point_evaluation_equals_the_vectorised_one():
    cells = [(2, 1), (3, 1), (3, 2), (4, 2), (4, 1)]
    ref = reference_from_cells(cells, FRAME, t_now=10.0, s_now=104.0, v_now=18.0, y_now=3.0)
    t = dense_times(ref, dt_s=0.37)
    s, v, a = ref.evaluate_time(t)
    for k in range(len(t)):  # every piece, before the first break and after the last
        assert ref.s_at(t[k]) == pytest.approx(s[k], abs=1e-9)
        assert ref.v_at(t[k]) == pytest.approx(v[k], abs=1e-9)
        assert ref.a_at(t[k]) == pytest.approx(a[k], abs=1e-9)
    positions = np.linspace(s.min() - 50.0, s.max() + 50.0, 97)
    y, dy, _ = ref.evaluate_space(positions)
    for k, s_k in enumerate(positions):
        assert ref.y_at_s(s_k) == pytest.approx(y[k], abs=1e-9)
        assert ref.dy_ds_at_s(s_k) == pytest.approx(dy[k], abs=1e-12)
