"""Tests of sumo_swarm.core.tracking: OSQP MPCs against hand-computed answers and the DP
recursion."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sumo_swarm.core.model import RoadSection
from sumo_swarm.core.tracking import (
    DEFAULT_DELTA_MAX_RAD,
    STEADY_PHI_RAD,
    STEADY_TOL_M,
    LateralMpc,
    LateralSettings,
    LongitudinalMpc,
    LongitudinalSettings,
    OsqpSettings,
    dp_solve,
    lateral_model,
    longitudinal_model,
)
from sumo_swarm.core.trajectory import GridFrame, reference_from_cells
from sumo_swarm.errors import ConfigError

TIGHT = OsqpSettings(eps_abs=1e-10, eps_rel=1e-10, max_iter=200_000, polish=True)


# ----------------------------------------------------------------------------- settings
@pytest.mark.parametrize(
    ("cls", "field", "value"),
    [
        (LongitudinalSettings, "horizon", 0),
        (LongitudinalSettings, "horizon", 2.5),
        (LongitudinalSettings, "dt_s", -0.1),
        (LongitudinalSettings, "r_lon", 0.0),
        (LongitudinalSettings, "a_min", 5.0),
        (LongitudinalSettings, "fallback_accel_mps2", -9.0),
        (LateralSettings, "wheelbase_m", 0.0),
        (LateralSettings, "delta_min", 0.1),
        (LateralSettings, "q_l", -1.0),
    ],
)
def test_settings_reject_bad_values_naming_the_field(cls, field, value):
    with pytest.raises(ConfigError, match=field):
        cls(**{field: value})


def test_default_wheel_angle_is_the_papers_steering_range_over_a_ratio_of_15():
    assert abs(DEFAULT_DELTA_MAX_RAD - math.radians(30.0)) < 1e-12
    assert LateralSettings().delta_min == -LateralSettings().delta_max


# ------------------------------------------------------------------ hand-computed 1-step QPs
def test_longitudinal_one_step_qp_matches_hand_computation():
    # x1 = [s0 + dt v0, v0 + dt a]: a* = q_v dt (v_ref - v0) / (q_v dt^2 + r)
    #    = 1 * 0.1 * 1 / (0.01 + 0.04) = 2.0 m/s^2
    settings = LongitudinalSettings(dt_s=0.1, horizon=1, q_s=1.0, q_v=1.0, r_lon=0.04, solver=TIGHT)
    result = LongitudinalMpc(settings).solve(0.0, 20.0, np.array([0.0, 2.0]), np.array([20, 21]))
    assert result.status == "solved"
    assert result.u0 == pytest.approx(2.0, abs=1e-8)
    np.testing.assert_allclose(result.states, [[0.0, 20.0], [2.0, 20.2]], atol=1e-8)
    # 1/2 (20.2 - 21)^2 + 1/2 * 0.04 * 2^2 = 0.32 + 0.08
    assert result.objective == pytest.approx(0.40, abs=1e-8)


def test_longitudinal_one_step_qp_with_active_bound_clips_to_a_max():
    # unconstrained a* = 0.1 / (0.01 + 0.01) = 5 > a_max = 3: a scalar QP's answer is the clip
    settings = LongitudinalSettings(dt_s=0.1, horizon=1, q_s=1.0, q_v=1.0, r_lon=0.01, solver=TIGHT)
    result = LongitudinalMpc(settings).solve(0.0, 20.0, np.array([0.0, 2.0]), np.array([20, 21]))
    assert result.u0 == pytest.approx(3.0, abs=1e-8)


@pytest.mark.parametrize(("feedforward", "expected"), [(False, 0.05 / 1.510204), (True, None)])
def test_lateral_one_step_qp_matches_hand_computation(feedforward, expected):
    # phi1 = phi0 + ds (delta / w - kappa), b = ds / w = 2 / 2.8 = 0.714286
    # paper cost: delta* = b (phi_ref - phi0 + ds kappa) / (b^2 + r) = 0.714286 * 0.07 / 1.510204
    # feed-forward: delta* = w kappa + b (phi_ref - phi0) / (b^2 + r) = 0.028 + 0.035714 / 1.510204
    if expected is None:
        expected = 0.028 + 0.714286 * 0.05 / 1.510204
    settings = LateralSettings(
        horizon=1, q_l=1.0, q_phi=1.0, r_lat=1.0, curvature_feedforward=feedforward, solver=TIGHT
    )
    result = LateralMpc(settings).solve(
        0.0, 0.0, np.array([0.0, 0.0]), np.array([0.0, 0.05]), np.array([0.01]), 2.0
    )
    assert result.status == "solved"
    assert result.u0 == pytest.approx(expected, abs=1e-6)
    assert result.states[1, 1] == pytest.approx(2.0 * (result.u0 / 2.8 - 0.01), abs=1e-8)


# -------------------------------------------------------------------- DP recursion vs OSQP
def test_dp_solve_matches_longitudinal_mpc_when_no_bound_is_active():
    settings = LongitudinalSettings(solver=TIGHT)
    k_steps, dt = settings.horizon, settings.dt_s
    t = dt * np.arange(k_steps + 1)
    s_ref, v_ref = 1000.0 + 18.0 * t + 0.3 * t**2, 18.0 + 0.6 * t
    result = LongitudinalMpc(settings).solve(1000.0, 17.8, s_ref, v_ref)
    a_mat, b_mat = longitudinal_model(dt)
    u_dp, x_dp = dp_solve(
        [a_mat] * k_steps,
        b_mat,
        None,
        np.diag([settings.q_s, settings.q_v]),
        settings.r_lon,
        np.array([1000.0, 17.8]),
        np.column_stack([s_ref, v_ref]),
    )
    assert np.abs(u_dp).max() < settings.a_max  # no bound active
    np.testing.assert_allclose(result.inputs, u_dp[:, 0], atol=1e-6)
    np.testing.assert_allclose(result.states, x_dp, atol=1e-6)


@pytest.mark.parametrize("feedforward", [False, True])
def test_dp_solve_matches_lateral_mpc_with_curvature_and_a_lane_change(feedforward):
    settings = LateralSettings(curvature_feedforward=feedforward, solver=TIGHT)
    k_steps, ds, wheelbase = settings.horizon, 2.0, settings.wheelbase_m
    x = np.clip(np.arange(k_steps + 1) / k_steps, 0.0, 1.0)
    l_ref = 3.0 * x**3 * (10 - 15 * x + 6 * x**2)
    phi_ref = np.arctan(np.gradient(l_ref, ds))
    kappa = np.linspace(0.0, 1.0 / 400.0, k_steps)
    result = LateralMpc(settings).solve(0.2, 0.01, l_ref, phi_ref, kappa, ds)
    a_mat, b_mat, _ = lateral_model(ds, wheelbase, 0.0)
    if feedforward:  # delta = w kappa + delta': C_k + B w kappa_k = 0
        c_list = [np.zeros(2)] * k_steps
        offset = wheelbase * kappa
    else:
        c_list = [lateral_model(ds, wheelbase, kappa_k)[2] for kappa_k in kappa]
        offset = np.zeros(k_steps)
    u_dp, x_dp = dp_solve(
        [a_mat] * k_steps,
        b_mat,
        c_list,
        np.diag([settings.q_l, settings.q_phi]),
        np.array([[settings.r_lat]]),
        np.array([0.2, 0.01]),
        np.column_stack([l_ref, phi_ref]),
    )
    np.testing.assert_allclose(result.inputs, u_dp[:, 0] + offset, atol=1e-6)
    np.testing.assert_allclose(result.states, x_dp, atol=1e-6)


def test_dp_solve_reduces_to_the_papers_recursion_for_the_error_state():
    # x_des = 0, C = 0: the textbook finite-horizon LQR; compare with a brute-force least squares
    a_mat, b_mat = longitudinal_model(0.2)
    q, r, x0, k_steps = np.diag([2.0, 0.5]), np.array([[0.3]]), np.array([1.5, -0.4]), 6
    u_dp, x_dp = dp_solve([a_mat] * k_steps, b_mat, None, q, r, x0, np.zeros((k_steps + 1, 2)))
    # states as a linear map of the inputs: x = F x0 + G u
    f_rows, g_rows = [np.eye(2)], [np.zeros((2, k_steps))]
    for k in range(k_steps):
        g_next = a_mat @ g_rows[-1]
        g_next[:, k] += b_mat[:, 0]
        f_rows.append(a_mat @ f_rows[-1])
        g_rows.append(g_next)
    big_f, big_g = np.vstack(f_rows), np.vstack(g_rows)
    big_q = np.kron(np.eye(k_steps + 1), q)
    hessian = big_g.T @ big_q @ big_g + r[0, 0] * np.eye(k_steps)
    u_ls = np.linalg.solve(hessian, -big_g.T @ big_q @ big_f @ x0)
    np.testing.assert_allclose(u_dp[:, 0], u_ls, atol=1e-10)
    np.testing.assert_allclose(x_dp.ravel(), big_f @ x0 + big_g @ u_ls, atol=1e-10)


# ------------------------------------------------------------------------ closed loops
def simulate_longitudinal(mpc, s0, v0, v_target, seconds):
    cfg = mpc.settings
    s, v, accels, speeds, errors = s0, v0, [], [], []
    for step in range(round(seconds / cfg.dt_s)):
        t = (step + np.arange(cfg.horizon + 1)) * cfg.dt_s
        result = mpc.solve(s, v, s0 + v_target * t, np.full(cfg.horizon + 1, v_target))
        assert result.status == "solved"
        a = result.u0
        s, v = s + v * cfg.dt_s + 0.5 * a * cfg.dt_s**2, v + a * cfg.dt_s
        accels.append(a)
        speeds.append(v)
        errors.append(s - (s0 + v_target * (step + 1) * cfg.dt_s))
    return np.array(accels), np.array(speeds), np.array(errors)


def test_speed_step_saturates_at_a_max_then_converges():
    mpc = LongitudinalMpc(LongitudinalSettings())
    accels, speeds, errors = simulate_longitudinal(mpc, 500.0, 17.5, 20.0, 20.0)
    assert accels[0] == pytest.approx(3.0, abs=1e-3)  # far from the target: saturated
    assert accels.max() <= 3.0 + 1e-3
    assert accels.min() >= -4.0 - 1e-3
    assert abs(speeds[99] - 20.0) < 0.01  # after 10 s
    assert abs(errors[99]) < 0.01
    assert abs(speeds[-1] - 20.0) < 1e-3


def test_a_cav_ahead_of_its_reference_and_faster_brakes_less_with_a_larger_r_lon():
    # A CAV let go by the lane-speed match: 1.35 m ahead of its reference, 1.7 m/s faster.
    # The default weights (r_lon = 1) take that out braking at a_min; r_lon = 2 brakes at
    # 3.2 m/s^2 (docs/dense-traffic.md, the nineteenth session: not made the default).
    def first_input(settings):
        t = settings.dt_s * np.arange(settings.horizon + 1)
        ref_s, ref_v = 1000.0 + 14.6 * t, np.full(settings.horizon + 1, 14.6)
        return LongitudinalMpc(settings).solve(1001.35, 16.3, ref_s, ref_v).u0

    assert first_input(LongitudinalSettings()) == pytest.approx(-4.0, abs=1e-3)
    assert first_input(LongitudinalSettings(r_lon=2.0)) == pytest.approx(-3.22, abs=0.01)


def test_speed_bound_holds_and_a_start_above_it_stays_feasible():
    settings = LongitudinalSettings(v_max=25.0)
    mpc = LongitudinalMpc(settings)
    k1 = settings.horizon + 1
    t = settings.dt_s * np.arange(k1)
    result = mpc.solve(0.0, 24.0, 30.0 * t, np.full(k1, 30.0))
    assert result.status == "solved"
    assert result.states[:, 1].max() <= 25.0 + 1e-2  # OSQP's tolerance (eps 1e-4)
    above = mpc.solve(0.0, 27.0, 20.0 * t, np.full(k1, 20.0))  # 2 m/s over v_max
    assert above.status == "solved"
    assert above.u0 == pytest.approx(-4.0, abs=1e-3)


def lane_change_reference(lane_width_m, speed_mps):
    road = RoadSection(lane_widths_m=(lane_width_m,) * 3)
    frame = GridFrame(0.0, 0.0, speed_mps, 15.0, 3.0, road)
    return reference_from_cells([(0, 0), (0, 0), (0, 1), (0, 1), (0, 1), (0, 1)], frame)


def simulate_lateral(mpc, ref, kappa_road, speed_mps, metres):
    """Kinematic bicycle in the road frame (exact tan terms, 20 sub-steps per MPC step)."""
    cfg = mpc.settings
    ds = speed_mps * cfg.dt_s
    s, lat, phi = ref.s_at(0.0), 0.0, 0.0
    deltas, errors = [], []
    for _ in range(round(metres / ds)):
        _, y, dy, _ = ref.sample_space(s, ds, cfg.horizon)
        kappa = np.full(cfg.horizon, kappa_road)
        result = mpc.solve(lat, phi, y, np.arctan(dy), kappa, ds)
        assert result.status in ("solved", "steady")
        if result.status == "steady":
            phi = 0.0  # as the tracker does
        delta = result.u0
        for _ in range(20):
            lat += ds / 20 * math.tan(phi)
            phi += ds / 20 * (math.tan(delta) / cfg.wheelbase_m - kappa_road)
        s += ds
        deltas.append(delta)
        errors.append(lat - ref.y_at_s(s))
    return np.array(deltas), np.array(errors), lat


def test_lane_change_on_a_straight_road_reaches_the_next_lane():
    mpc = LateralMpc(LateralSettings())
    ref = lane_change_reference(3.0, 20.0)
    deltas, errors, lat = simulate_lateral(mpc, ref, 0.0, 20.0, 400.0)
    assert abs(lat - 3.0) < 0.05
    assert abs(errors[-1]) < 0.05
    assert np.abs(errors).max() < 0.1
    assert np.abs(deltas).max() <= DEFAULT_DELTA_MAX_RAD
    assert np.abs(deltas).max() > 0.005  # it steers


@pytest.mark.parametrize("feedforward", [True, False])
def test_lane_change_on_a_curve_settles_on_the_kinematic_wheel_angle(feedforward):
    mpc = LateralMpc(LateralSettings(curvature_feedforward=feedforward))
    ref = lane_change_reference(3.0, 20.0)
    kappa = 1.0 / 500.0
    deltas, errors, lat = simulate_lateral(mpc, ref, kappa, 20.0, 600.0)
    assert deltas[-1] == pytest.approx(math.atan(2.8 * kappa), abs=1e-5)
    assert abs(errors[-1]) < 0.05
    assert abs(lat - 3.0) < 0.05


def test_a_centred_vehicle_on_a_straight_road_steers_zero_without_a_solve():
    settings = LateralSettings(solver=TIGHT)
    k1, k = settings.horizon + 1, settings.horizon
    lane, straight, flat = np.full(k1, 3.2), np.zeros(k1), np.zeros(k)
    near = 3.2 + 0.9 * STEADY_TOL_M
    steady = LateralMpc(settings).solve(near, 0.9 * STEADY_PHI_RAD, lane, straight, flat, 2.0)
    assert steady.status == "steady"
    assert not steady.inputs.any() and steady.objective < 1e-4
    # Just outside the tolerances the QP is solved, and its answer is a tiny correction: the
    # skipped solves inside them would have steered less than that.
    for l0, phi0 in ((3.2 + 2 * STEADY_TOL_M, 0.0), (3.2, 2 * STEADY_PHI_RAD)):
        res = LateralMpc(settings).solve(l0, phi0, lane, straight, flat, 2.0)
        assert res.status == "solved" and 0.0 < np.abs(res.inputs).max() < 2e-3
    # A curve, or a lane change ahead, is always solved.
    curve = LateralMpc(settings).solve(3.2, 0.0, lane, straight, np.full(k, 0.002), 2.0)
    change = LateralMpc(settings).solve(3.2, 0.0, np.linspace(3.2, 4.0, k1), straight, flat, 2.0)
    for res in (curve, change):
        assert res.status == "solved" and np.abs(res.inputs).max() > 1e-3


# ---------------------------------------------------------------- warm start and failures
def test_changing_ds_gives_the_same_answer_as_a_fresh_solver():
    settings = LateralSettings(solver=TIGHT)
    k1 = settings.horizon + 1
    l_ref, phi_ref = np.linspace(0.0, 1.0, k1), np.full(k1, 0.02)
    kappa = np.full(settings.horizon, 0.001)
    reused = LateralMpc(settings)
    reused.solve(0.0, 0.0, l_ref, phi_ref, kappa, 2.0)
    second = reused.solve(0.1, 0.0, l_ref, phi_ref, kappa, 1.5)
    fresh = LateralMpc(settings).solve(0.1, 0.0, l_ref, phi_ref, kappa, 1.5)
    np.testing.assert_allclose(second.inputs, fresh.inputs, atol=1e-8)


def test_unsolved_call_returns_a_safe_result_instead_of_raising():
    lon = LongitudinalMpc(LongitudinalSettings(solver=OsqpSettings(max_iter=1)))
    k1 = lon.settings.horizon + 1
    t = 0.1 * np.arange(k1)
    result = lon.solve(0.0, 20.0, 25.0 * t, np.full(k1, 25.0))
    assert result.status != "solved"
    assert not result.solved
    assert result.u0 == -1.0  # gentle braking
    assert result.states.shape == (k1, 2)
    assert result.states[1, 1] == pytest.approx(20.0 - 0.1)

    lat = LateralMpc(LateralSettings(solver=OsqpSettings(max_iter=1)))
    kappa = np.full(lat.settings.horizon, 0.002)
    result = lat.solve(0.5, 0.0, np.zeros(k1), np.zeros(k1), kappa, 2.0)
    assert result.status != "solved"
    assert result.u0 == pytest.approx(2.8 * 0.002)  # follow the road's curvature


def test_non_finite_input_is_reported_not_raised():
    lon = LongitudinalMpc()
    k1 = lon.settings.horizon + 1
    result = lon.solve(0.0, float("nan"), np.zeros(k1), np.zeros(k1))
    assert result.status == "invalid input"
    assert result.u0 == -1.0
    lat = LateralMpc()
    result = lat.solve(0.0, 0.0, np.zeros(k1), np.zeros(k1), np.zeros(k1 - 1), float("nan"))
    assert result.status == "invalid input"
    assert result.u0 == 0.0


def test_wrong_shapes_raise_value_error():
    lon = LongitudinalMpc()
    with pytest.raises(ValueError, match="shape"):
        lon.solve(0.0, 20.0, np.zeros(5), np.zeros(5))
    lat = LateralMpc()
    k1 = lat.settings.horizon + 1
    with pytest.raises(ValueError, match="kappa"):
        lat.solve(0.0, 0.0, np.zeros(k1), np.zeros(k1), np.zeros(k1), 2.0)


def test_the_direct_osqp_path_gives_the_wrappers_answer():
    # The QPs call OSQP's wrapped solver object directly (its Python wrapper cost more than
    # these small solves); an osqp without that object goes through the wrapper: the same
    # inputs either way, over a run of warm-started solves with bounds at +-inf.
    fast, slow = LongitudinalMpc(LongitudinalSettings()), LongitudinalMpc(LongitudinalSettings())
    assert fast._qp._core is not None  # the osqp this project installs has it
    slow._qp._core = None
    k1 = fast.settings.horizon + 1
    t = fast.settings.dt_s * np.arange(k1)
    for v0, v_ref in [(17.5, 20.0), (19.0, 20.0), (24.0, 30.0), (27.0, 20.0), (20.0, 12.0)]:
        a = fast.solve(0.0, v0, v_ref * t, np.full(k1, v_ref))
        b = slow.solve(0.0, v0, v_ref * t, np.full(k1, v_ref))
        assert a.status == b.status
        np.testing.assert_array_equal(a.inputs, b.inputs)
        assert a.objective == b.objective
    lat_fast, lat_slow = LateralMpc(LateralSettings()), LateralMpc(LateralSettings())
    lat_slow._qp._core = None
    ref = lane_change_reference(3.2, 20.0)
    ds = 20.0 * lat_fast.settings.dt_s
    _, y, dy, _ = ref.sample_space(ref.s_at(0.0) + 40.0, ds, lat_fast.settings.horizon)
    kappa = np.zeros(lat_fast.settings.horizon)
    a = lat_fast.solve(0.1, 0.0, y, np.arctan(dy), kappa, ds)
    b = lat_slow.solve(0.1, 0.0, y, np.arctan(dy), kappa, ds)
    assert a.status == b.status == "solved"
    np.testing.assert_array_equal(a.inputs, b.inputs)


def _tracker_holding(deltas, accels, dt_s):
    """A Tracker whose CAV "c" has ``deltas`` [rad] and ``accels`` [m/s^2] solved at t = 0 for
    the MPC's steps (0.1 s), heading straight; a reference is not asked for (no solve)."""
    from sumo_swarm.core.swarming.tracker import Tracker

    tracker = Tracker(LongitudinalSettings(), LateralSettings(), interval_steps=10)
    tracker.add("c")
    tracker._inputs["c"] = (0.0, np.asarray(accels, float), np.asarray(deltas, float))
    return tracker


class _Flat:
    def y_at_s(self, s_m):
        return 0.0


@pytest.mark.parametrize("dt_s", [0.1, 0.3])
def test_a_long_sumo_step_is_driven_on_the_mpcs_clock(dt_s):
    from sumo_swarm.core.model import VehicleState

    road = RoadSection(lane_widths_m=(3.5, 3.5))
    wheelbase = LateralSettings().wheelbase_m
    # A wheel angle turning the CAV at 0.01 rad per metre, 10 m/s: 0.01 rad per MPC step.
    delta = math.atan(0.01 * wheelbase)
    tracker = _tracker_holding([delta] * 5, [0.0] * 5, dt_s)
    ego = VehicleState("c", 100.0, 0, 0.0, 10.0, 5.0, is_cav=True)
    cmd = tracker.command(0.0, ego, _Flat(), road, dt_s, solve=False)
    if dt_s == 0.1:  # the paper's step: one MPC step, straight ahead until it turns
        assert cmd.dlat_m == 0.0 and cmd.phi_end_rad == pytest.approx(0.01)
    else:  # three MPC steps: 1 m at headings 0, 0.01 and 0.02 rad (held: 0 m, then a jump)
        assert cmd.dlat_m == pytest.approx(math.sin(0.01) + math.sin(0.02))
        assert cmd.phi_end_rad == pytest.approx(0.03)
    tracker.commit(ego, cmd, False, road, dt_s)
    assert tracker.phi["c"] == pytest.approx(cmd.phi_end_rad)
    tracker.commit(ego, cmd, True, road, dt_s)  # a held move stops turning
    assert tracker.phi["c"] == 0.0


def test_a_long_step_commands_the_mean_of_the_mpcs_accelerations():
    from sumo_swarm.core.model import VehicleState

    road = RoadSection(lane_widths_m=(3.5,))
    tracker = _tracker_holding([0.0] * 5, [1.0, 2.0, 3.0, 4.0, 5.0], 0.3)
    ego = VehicleState("c", 100.0, 0, 0.0, 10.0, 5.0, is_cav=True)
    cmd = tracker.command(0.0, ego, _Flat(), road, 0.3, solve=False)
    assert cmd.accel_mps2 == pytest.approx(2.0)  # (1 + 2 + 3) x 0.1 s over 0.3 s
    later = tracker.command(0.2, ego, _Flat(), road, 0.1, solve=False)
    assert later.accel_mps2 == pytest.approx(3.0)  # one step: the input of its MPC step
