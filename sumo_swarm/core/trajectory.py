"""Trajectory generation: planned cells -> smooth reference per CAV (paper Sec. II-C).

Pure module: no SUMO import. The planner gives each CAV one cell ``(row, col)`` per behaving
step ``k = 0..N-1``; eqs. (20)-(22) place the cell centre at the step instants:

* ``t_k = t0 + k * dT``                                                              (20)
* ``s_k = origin + v_cell * (t_k - t0) + (row_k + 0.5) * l_cell``  (0-based rows)     (21)
* ``y_k = road.lane_centre_y(col_k)``  (the real lane centre, not the paper's +-3 m)   (22)

``s`` is the vehicle *centre* along the route, ``y`` the lateral position measured from the
centre of lane 0 (left positive), as in :mod:`sumo_swarm.core.model`.

Longitudinal design
-------------------
Work in the grid frame: ``p(t) = s(t) - origin - v_cell * (t - t0)``. The waypoints are
``P_k = (row_k + 0.5) * l_cell``. Joining them by straight lines gives a piecewise-constant
*relative speed* ``u_k = (P_{k+1} - P_k) / dT`` (one row per 3 s interval = 5 m/s with 15 m
cells). A rest-to-rest move of one 15 m row inside one 3 s interval needs at least
``4 * 15 / 9 = 6.7 m/s^2`` (a quintic needs 9.6), so the reference cannot stop at every
waypoint. Instead every speed change ``du_k = u_k - u_{k-1}`` at ``t_k`` is spread over a
window *centred on* ``t_k``: the acceleration is a trapezoid (the convolution of two boxes of
widths ``b1 = a_lim / j_max`` and ``b2 = max(|du| / a_lim, b1)``), so

* speed and acceleration are continuous, ``|a| <= a_lim`` and ``|jerk| <= j_max``;
* the transition is symmetric, so it gives back the distance it borrowed: outside the windows
  the reference lies *exactly* on the straight lines through the waypoints, in particular at
  every step instant where the relative speed does not change;
* at a step instant where it changes, the reference is off the waypoint by
  ``|du| * ((w/2)^3 - (w/2 - b1)^3) / (6 b1 b2)`` with ``w = b1 + b2`` (``waypoint_error_m``):
  about 1.2 m for a 5 m/s change with the default limits, inside a 15 m cell.

``a_lim`` is ``profile_accel_fraction`` (0.8) of ``a_max`` or ``-a_min``: the rest is left for
the blend from the vehicle's current state. For plans in which a CAV moves at most one row per
step (the planner's eq. (8)), two overlapping windows always have opposite signs, so the sum
stays within ``[a_min, a_max]`` (jerk within ``2 * j_max``).

Blend from the current state
----------------------------
With ``s_now`` (and optionally ``v_now``, ``a_now``) at ``t_now``, the offset from the cell
path ``e(t)`` decays to zero along a quintic in time matching position, speed and
acceleration at ``t_now``. Its duration is the shortest on a candidate list (1 s to 60 s) for
which the total speed, acceleration and jerk (``2 * j_max``) stay within bounds (checked on a
0.05 s grid), so a replan never makes the reference jump.

Lateral design (spatial domain)
-------------------------------
The lateral tracker works with the distance travelled, so the lateral path is a function
``y(s)``. A column change between steps ``k`` and ``k+1`` is a quintic smoothstep in ``s``
from ``s(t_k)`` to ``s(t_{k+1})`` (ends exactly on the lane centre at ``t_{k+1}``), lengthened
where needed so the lateral speed ``v * dy/ds`` stays below ``max_lat_speed_mps`` and the
lateral acceleration ``v^2 * d2y/ds2`` below ``max_lat_accel_mps2`` (this also bounds the
front-wheel angle ``~ wheelbase * d2y/ds2``). A current ``y_now`` blends in the same way.
After the last cell the reference continues at the grid speed in the last column.
"""

from __future__ import annotations

import bisect
import dataclasses
import functools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from sumo_swarm.core.model import RoadSection
from sumo_swarm.errors import ConfigError

_BLEND_DURATIONS_S = np.concatenate([np.arange(1.0, 10.0, 0.25), np.arange(10.0, 61.0, 2.0)])
_CHECK_DT_S = 0.05  # grid on which blend candidates are checked against the bounds [s]
_ALL_ORDERS = (0, 1, 2, 3, 4, 5)
# _FALLING[n][m] = m! / (m - n)!: coefficient of the n-th derivative of x^m
_FALLING = [[math.perm(m, n) if m >= n else 0 for m in range(6)] for n in range(6)]
_FALLING_ARRAY = np.array(_FALLING, dtype=float)
_CHECK_MARGIN = 1e-3  # bounds are tightened by this on the check grid: peaks fall between points
_SMOOTHSTEP = np.array([0.0, 0.0, 0.0, 10.0, -15.0, 6.0])  # 10x^3 - 15x^4 + 6x^5
_SMOOTHSTEP_PEAK_SLOPE = 1.875  # max of d/dx (10x^3 - 15x^4 + 6x^5)
_SMOOTHSTEP_PEAK_CURVATURE = 10.0 / math.sqrt(3.0)  # max |d2/dx2| of the same


@dataclass(frozen=True, slots=True)
class GridFrame:
    """Where the moving grid was when the plan started, and how it moves.

    Attributes
    ----------
    origin_s_m
        Route position of the rear edge of row 0 at ``t0_s`` [m].
    t0_s
        Simulation time of behaving step 0 [s].
    speed_mps
        Grid speed ``v_cell`` [m/s].
    cell_length_m
        Cell length ``l_cell`` [m].
    behaving_interval_s
        Time between behaving steps ``dT`` [s].
    road
        Cross-section of the road: gives the lateral position of each column.
    """

    origin_s_m: float
    t0_s: float
    speed_mps: float
    cell_length_m: float
    behaving_interval_s: float
    road: RoadSection

    def __post_init__(self) -> None:
        for name in ("origin_s_m", "t0_s", "speed_mps"):
            if not math.isfinite(getattr(self, name)):
                raise ConfigError(f"GridFrame.{name} must be finite, got {getattr(self, name)!r}")
        if self.speed_mps < 0.0:
            raise ConfigError(f"GridFrame.speed_mps must be >= 0, got {self.speed_mps!r}")
        for name in ("cell_length_m", "behaving_interval_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ConfigError(f"GridFrame.{name} must be > 0, got {value!r}")

    def step_time_s(self, step: int) -> float:
        """Eq. (20): time of behaving step ``step`` [s]."""
        return self.t0_s + step * self.behaving_interval_s

    def cell_centre_s_m(self, row: int, t_s: float) -> float:
        """Eq. (21): route position of the centre of ``row`` at time ``t_s`` [m]."""
        return (
            self.origin_s_m + self.speed_mps * (t_s - self.t0_s) + (row + 0.5) * self.cell_length_m
        )

    def column_y_m(self, col: int) -> float:
        """Eq. (22) with the real lane centre: lateral position of column ``col`` [m]."""
        return self.road.lane_centre_y(col)


def cell_waypoints(
    cells: Sequence[tuple[int, int]], frame: GridFrame
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Eqs. (20)-(22): the cell centres at the behaving-step instants.

    Returns
    -------
    (t, s, y)
        Arrays of shape (N,): times [s], route positions of the vehicle centre [m] and
        lateral positions [m].
    """
    _check_cells(cells, frame.road)
    t = np.array([frame.step_time_s(k) for k in range(len(cells))])
    s = np.array([frame.cell_centre_s_m(row, tk) for (row, _), tk in zip(cells, t, strict=True)])
    y = np.array([frame.column_y_m(col) for _, col in cells])
    return t, s, y


def waypoint_error_m(du_mps: float, accel_limit_mps2: float, jerk_limit_mps3: float) -> float:
    """Distance between the reference and the straight cell path in the middle of a
    relative-speed change ``du_mps`` made with the given limits [m] (see module docstring)."""
    if du_mps == 0.0:
        return 0.0
    b1, b2 = _transition_widths(abs(du_mps), accel_limit_mps2, jerk_limit_mps3)
    half = 0.5 * (b1 + b2)
    return abs(du_mps) * (half**3 - max(half - b1, 0.0) ** 3) / (6.0 * b1 * b2)


@dataclass(frozen=True, eq=False)
class _Piecewise:
    """Piecewise polynomial of degree <= 5, stored as Taylor coefficients about one point per
    piece: evaluation costs a ``searchsorted`` and a Horner loop, whatever the plan length.

    Piece ``i`` covers ``[breaks[i-1], breaks[i])`` (``i = 0``: everything before the first
    break, the last: everything after the last break).
    """

    breaks: np.ndarray  # (n,)
    centres: np.ndarray  # (n+1,)
    coeffs: np.ndarray  # (n+1, 6): f^(m)(centre) / m!

    @classmethod
    def compile(
        cls,
        derivatives: Callable[[np.ndarray, tuple[int, ...]], list[np.ndarray]],
        breaks: np.ndarray,
    ) -> _Piecewise:
        """Sample an exact piecewise function (polynomial between ``breaks``) once per piece."""
        breaks = np.unique(np.asarray(breaks, dtype=float))
        if len(breaks) == 0:
            centres = np.zeros(1)
        else:
            inner = 0.5 * (breaks[:-1] + breaks[1:])
            centres = np.concatenate([[breaks[0] - 1.0], inner, [breaks[-1] + 1.0]])
        values = derivatives(centres, _ALL_ORDERS)
        coeffs = np.column_stack([v / math.factorial(m) for m, v in enumerate(values)])
        return cls(breaks, centres, coeffs)

    @functools.cached_property
    def _scalar(self) -> tuple[list[float], list[float], list[tuple[float, ...]]]:
        """The pieces as Python lists, for :meth:`evaluate_one` (no numpy call per point)."""
        rows = [tuple(float(v) for v in row) for row in self.coeffs]
        return self.breaks.tolist(), self.centres.tolist(), rows

    def evaluate_one(self, x: float, order: int) -> float:
        """Derivative ``order`` (<= 5) at one point: :meth:`evaluate` for a scalar, about ten
        times cheaper (the trackers ask for one point per CAV per step)."""
        breaks, centres, rows = self._scalar
        piece = bisect.bisect_right(breaks, x)
        h = x - centres[piece]
        c = rows[piece]
        falling = _FALLING[order]
        value = c[5] * falling[5]
        for m in range(4, order - 1, -1):
            value = value * h + c[m] * falling[m]
        return value

    @functools.cached_property
    def _scaled(self) -> list[np.ndarray]:
        """Per order n, the coefficients times their falling factorials m!/(m-n)! (the
        Horner terms of the n-th derivative), one contiguous row per power: made once per
        reference, not at every evaluation (the trackers evaluate every few steps)."""
        return [np.ascontiguousarray((self.coeffs * _FALLING_ARRAY[n]).T) for n in range(6)]

    def evaluate(self, x: np.ndarray, orders: tuple[int, ...]) -> list[np.ndarray]:
        """Derivatives ``orders`` (each <= 5) at ``x`` (shape (M,))."""
        piece = np.searchsorted(self.breaks, x, side="right")
        h = x - self.centres[piece]
        values = []
        for order in orders:
            c = self._scaled[order][:, piece]  # (6, M)
            value = c[5]
            for m in range(4, order - 1, -1):
                value = value * h + c[m]
            values.append(value)
        return values


@dataclass(frozen=True, eq=False)
class _SpeedProfile:
    """Exact grid-frame position ``p(t) = p0 + sum_j du_j ramp_j(t) + blend(t)``."""

    p0_m: float
    centres_s: np.ndarray
    du_mps: np.ndarray
    b1_s: np.ndarray
    b2_s: np.ndarray
    blend_start_s: float = 0.0
    blend_coeffs: np.ndarray = field(default_factory=lambda: np.zeros(6))
    blend_duration_s: float = 0.0

    def derivatives(self, t: np.ndarray, orders: tuple[int, ...]) -> list[np.ndarray]:
        ramps = _smoothed_ramp(
            t[:, None] - self.centres_s[None, :], self.b1_s[None, :], self.b2_s[None, :], orders
        )
        blends = _blend(t - self.blend_start_s, self.blend_coeffs, self.blend_duration_s, orders)
        values = []
        for order, ramp, blend in zip(orders, ramps, blends, strict=True):
            value = ramp @ self.du_mps + blend
            values.append(value + self.p0_m if order == 0 else value)
        return values

    def breaks(self) -> np.ndarray:
        opens = self.centres_s - 0.5 * (self.b1_s + self.b2_s)
        knots = [opens, opens + self.b1_s, opens + self.b2_s, opens + self.b1_s + self.b2_s]
        if self.blend_duration_s > 0.0:
            blend = self.blend_start_s + np.array([0.0, self.blend_duration_s])
            knots.append(blend)
        return np.concatenate(knots)


@dataclass(frozen=True, eq=False)
class _LateralProfile:
    """Exact ``y(s) = y0 + sum_j dy_j smoothstep((s - start_j) / length_j)``."""

    y0_m: float
    starts_m: np.ndarray = field(default_factory=lambda: np.zeros(0))
    lengths_m: np.ndarray = field(default_factory=lambda: np.ones(0))
    dys_m: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def derivatives(self, s: np.ndarray, orders: tuple[int, ...]) -> list[np.ndarray]:
        x = (s[:, None] - self.starts_m[None, :]) / self.lengths_m[None, :]
        values = []
        for order, step in zip(orders, _smoothstep(x, orders), strict=True):
            value = step @ (self.dys_m / self.lengths_m**order)
            values.append(value + self.y0_m if order == 0 else value)
        return values

    def breaks(self) -> np.ndarray:
        return np.concatenate([self.starts_m, self.starts_m + self.lengths_m])


@dataclass(frozen=True, eq=False)
class Reference:
    """Smooth reference of one CAV: ``s(t)`` along the route and ``y(s)`` across it.

    Build it with :func:`reference_from_cells`. Every method accepts any time or position:
    after the last cell the reference drives at the grid speed in the last column; before
    ``start_time_s`` it extrapolates the start state at constant relative speed.

    Attributes
    ----------
    frame
        The grid the plan refers to.
    cells
        The planned cells ``(row, col)`` at behaving steps ``0..N-1``.
    start_time_s
        Time from which the reference is meant to be tracked [s] (``t_now`` or ``t0``).
    t_end_s
        Time of the last behaving step ``t0 + (N-1) dT`` [s]: the plan is executed.
    blend_duration_s
        Duration of the blend from the vehicle's state into the cell path [s] (0: none).
    """

    frame: GridFrame
    cells: tuple[tuple[int, int], ...]
    start_time_s: float
    t_end_s: float
    blend_duration_s: float
    _longitudinal: _Piecewise  # grid-frame position p(t)
    _lateral: _Piecewise  # y(s)

    # ----------------------------------------------------------------- longitudinal
    def s_at(self, t_s: float) -> float:
        """Route position of the vehicle centre at time ``t_s`` [m]."""
        frame = self.frame
        p = self._longitudinal.evaluate_one(float(t_s), 0)
        return frame.origin_s_m + frame.speed_mps * (t_s - frame.t0_s) + p

    def v_at(self, t_s: float) -> float:
        """Speed at time ``t_s`` [m/s]."""
        return self.frame.speed_mps + self._longitudinal.evaluate_one(float(t_s), 1)

    def a_at(self, t_s: float) -> float:
        """Acceleration at time ``t_s`` [m/s^2]."""
        return self._longitudinal.evaluate_one(float(t_s), 2)

    def evaluate_time(self, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vectorised ``(s [m], v [m/s], a [m/s^2])`` at the times ``t_s`` (shape (M,))."""
        t = np.asarray(t_s, dtype=float)
        p, dp, ddp = self._longitudinal.evaluate(t, (0, 1, 2))
        s, v = self._in_route_frame(t, p, dp)
        return s, v, ddp

    def _in_route_frame(
        self, t: np.ndarray, p: np.ndarray, dp: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """Route position and speed from the offset ``p`` (and its rate ``dp``) to the grid
        frame moving at its speed from its origin."""
        frame = self.frame
        return frame.origin_s_m + frame.speed_mps * (t - frame.t0_s) + p, frame.speed_mps + dp

    def jerk_at(self, t_s: np.ndarray) -> np.ndarray:
        """Vectorised jerk at the times ``t_s`` [m/s^3] (piecewise smooth)."""
        return self._longitudinal.evaluate(np.asarray(t_s, dtype=float), (3,))[0]

    def sample_time(
        self, t0_s: float, dt_s: float, n_steps: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(t, s, v, a)`` at ``t0_s + k * dt_s`` for ``k = 0..n_steps``: arrays of shape
        (n_steps + 1,), ready as the longitudinal MPC's ``s_ref`` and ``v_ref``."""
        t = t0_s + dt_s * _steps(n_steps)
        s, v, a = self.evaluate_time(t)
        return t, s, v, a

    def targets_time(self, t0_s: float, dt_s: float, n_steps: int) -> tuple[np.ndarray, np.ndarray]:
        """``(s, v)`` of :meth:`sample_time`, the same numbers, without the acceleration: the
        longitudinal MPC's ``s_ref`` and ``v_ref`` (asked per CAV every few SUMO steps)."""
        t = t0_s + dt_s * _steps(n_steps)
        p, dp = self._longitudinal.evaluate(t, (0, 1))
        return self._in_route_frame(t, p, dp)

    # ----------------------------------------------------------------------- lateral
    def y_at_s(self, s_m: float) -> float:
        """Lateral position [m] when the vehicle centre is at route position ``s_m``."""
        return self._lateral.evaluate_one(float(s_m), 0)

    def dy_ds_at_s(self, s_m: float) -> float:
        """Slope of the lateral path ``dy/ds`` at ``s_m`` [-]."""
        return self._lateral.evaluate_one(float(s_m), 1)

    def y_at(self, t_s: float) -> float:
        """Lateral position at time ``t_s`` [m]: ``y_at_s(s_at(t_s))``."""
        return self.y_at_s(self.s_at(t_s))

    def evaluate_space(self, s_m: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Vectorised ``(y [m], dy/ds [-], d2y/ds2 [1/m])`` at the positions ``s_m``."""
        y, dy, ddy = self._lateral.evaluate(np.asarray(s_m, dtype=float), (0, 1, 2))
        return y, dy, ddy

    def sample_space(
        self, s0_m: float, ds_m: float, n_steps: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """``(s, y, dy/ds, d2y/ds2)`` at ``s0_m + k * ds_m`` for ``k = 0..n_steps``: arrays of
        shape (n_steps + 1,). The lateral MPC's targets are ``l_ref = y`` and
        ``phi_ref = arctan(dy/ds)``."""
        s = s0_m + ds_m * _steps(n_steps)
        y, dy, ddy = self.evaluate_space(s)
        return s, y, dy, ddy

    def targets_space(
        self, s0_m: float, ds_m: float, n_steps: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """``(y, dy/ds)`` of :meth:`sample_space`, the same numbers, without the curvature:
        the lateral MPC's targets (asked per CAV every few SUMO steps)."""
        s = s0_m + ds_m * _steps(n_steps)
        y, dy = self._lateral.evaluate(s, (0, 1))
        return y, dy


def reference_from_cells(
    cells: Sequence[tuple[int, int]],
    frame: GridFrame,
    road: RoadSection | None = None,
    *,
    a_min: float = -4.0,
    a_max: float = 3.0,
    v_max: float = 40.0,
    max_lat_speed_mps: float = 2.5,
    max_lat_accel_mps2: float = 3.0,
    max_jerk_mps3: float = 5.0,
    profile_accel_fraction: float = 0.8,
    t_now: float | None = None,
    s_now: float | None = None,
    y_now: float | None = None,
    v_now: float | None = None,
    a_now: float | None = None,
) -> Reference:
    """Turn one CAV's planned cells into a smooth reference (eqs. (20)-(22), module docstring).

    Parameters
    ----------
    cells
        ``(row, col)`` at behaving steps ``k = 0..N-1`` (0-based, row 0 = rear, col 0 =
        rightmost lane); ``N >= 1``.
    frame
        The moving grid of the plan.
    road
        Road cross-section for the column positions; default ``frame.road``.
    a_min, a_max
        Acceleration bounds [m/s^2] of the reference.
    v_max
        Speed bound [m/s] respected by the blend from the current state (the cell path itself
        runs at most ``v_cell + l_cell / dT``).
    max_lat_speed_mps, max_lat_accel_mps2
        Limits on the lateral speed [m/s] and lateral acceleration [m/s^2] of a lane change.
    max_jerk_mps3
        Jerk bound of one speed transition [m/s^3].
    profile_accel_fraction
        Share of the acceleration bounds the cell path may use; the rest is for the blend.
    t_now, s_now, y_now, v_now, a_now
        Current time [s], route position of the vehicle centre [m], lateral position [m],
        speed [m/s] and acceleration [m/s^2]. With them the reference starts at the vehicle
        and blends into the cell path; missing ones are taken from the cell path.

    Raises
    ------
    ValueError
        ``cells`` is empty or names a column outside the road.
    ConfigError
        A limit is not positive (``a_min`` must be negative) or the fraction not in (0, 1].
    """
    _check_limits(
        a_min=a_min,
        a_max=a_max,
        v_max=v_max,
        max_lat_speed_mps=max_lat_speed_mps,
        max_lat_accel_mps2=max_lat_accel_mps2,
        max_jerk_mps3=max_jerk_mps3,
        profile_accel_fraction=profile_accel_fraction,
    )
    road = frame.road if road is None else road
    cells = tuple((int(row), int(col)) for row, col in cells)
    _check_cells(cells, road)
    n_cells = len(cells)
    interval = frame.behaving_interval_s
    step_t = frame.t0_s + interval * np.arange(n_cells)

    # Relative speed per interval; zero before the plan and after its last cell.
    waypoints = (np.array([row for row, _ in cells], dtype=float) + 0.5) * frame.cell_length_m
    rel_speed = np.concatenate([[0.0], np.diff(waypoints) / interval, [0.0]])
    du = np.diff(rel_speed)
    moving = du != 0.0
    accel_limit = np.where(du > 0.0, a_max, -a_min) * profile_accel_fraction
    b1, b2 = _transition_widths(np.abs(du[moving]), accel_limit[moving], max_jerk_mps3)

    speed = _SpeedProfile(
        p0_m=float(waypoints[0]),
        centres_s=step_t[moving],
        du_mps=du[moving],
        b1_s=np.asarray(b1, dtype=float),
        b2_s=np.asarray(b2, dtype=float),
    )
    start_time = frame.t0_s if t_now is None else float(t_now)
    if s_now is not None:
        limits = {"a_min": a_min, "a_max": a_max, "v_max": v_max, "max_jerk_mps3": max_jerk_mps3}
        speed = _with_longitudinal_blend(frame, speed, start_time, s_now, v_now, a_now, limits)
    straight = _LateralProfile(y0_m=road.lane_centre_y(cells[0][1]))
    ref = Reference(
        frame=frame,
        cells=cells,
        start_time_s=start_time,
        t_end_s=float(step_t[-1]),
        blend_duration_s=speed.blend_duration_s,
        _longitudinal=_Piecewise.compile(speed.derivatives, speed.breaks()),
        _lateral=_Piecewise.compile(straight.derivatives, straight.breaks()),
    )
    lateral = _lane_changes(ref, road, max_lat_speed_mps, max_lat_accel_mps2)
    if y_now is not None:
        lateral = _with_lateral_blend(ref, lateral, y_now, max_lat_speed_mps, max_lat_accel_mps2)
    return dataclasses.replace(
        ref, _lateral=_Piecewise.compile(lateral.derivatives, lateral.breaks())
    )


# --------------------------------------------------------------------------- building blocks
@functools.lru_cache(maxsize=8)
def _steps(n_steps: int) -> np.ndarray:
    """``0, 1, ..., n_steps`` as floats, read-only: made once per horizon, not per sample."""
    steps = np.arange(n_steps + 1, dtype=float)
    steps.flags.writeable = False
    return steps


def _check_limits(**limits: float) -> None:
    for name, value in limits.items():
        if not math.isfinite(value):
            raise ConfigError(f"{name} must be finite, got {value!r}")
    if limits["a_min"] >= 0.0:
        raise ConfigError(f"a_min must be < 0, got {limits['a_min']!r}")
    for name in ("a_max", "v_max", "max_lat_speed_mps", "max_lat_accel_mps2", "max_jerk_mps3"):
        if limits[name] <= 0.0:
            raise ConfigError(f"{name} must be > 0, got {limits[name]!r}")
    if not 0.0 < limits["profile_accel_fraction"] <= 1.0:
        raise ConfigError(
            f"profile_accel_fraction must be in (0, 1], got {limits['profile_accel_fraction']!r}"
        )


def _check_cells(cells: Sequence[tuple[int, int]], road: RoadSection) -> None:
    if len(cells) == 0:
        raise ValueError("cells is empty: a plan needs at least the current cell")
    for k, (_, col) in enumerate(cells):
        if not 0 <= col < road.n_lanes:
            raise ValueError(f"cells[{k}] has column {col}, the road has {road.n_lanes} lanes")


def _transition_widths(
    abs_du: np.ndarray | float, accel_limit: np.ndarray | float, jerk_limit: float
) -> tuple[np.ndarray, np.ndarray]:
    """Box widths (b1, b2) [s] of a speed change: plateau accel ``du / b2 <= accel_limit``,
    jerk ``du / (b1 * b2) <= jerk_limit``."""
    b1 = np.asarray(accel_limit, dtype=float) / jerk_limit
    b2 = np.maximum(np.asarray(abs_du, dtype=float) / accel_limit, b1)
    return b1, b2


def _smoothed_ramp(
    tau_from_centre: np.ndarray, b1: np.ndarray, b2: np.ndarray, orders: tuple[int, ...]
) -> list[np.ndarray]:
    """Derivatives ``orders`` of ``max(t, 0)`` smoothed by two boxes of widths b1, b2 centred
    on 0 (broadcast shapes).

    Order 0: position (equals ``max(t, 0)`` outside the window), 1: speed (0 -> 1),
    2: acceleration (trapezoid, plateau ``1/max(b1, b2)``), 3: jerk, 4 and 5: zero (it is
    piecewise cubic).
    """
    width = b1 + b2
    tau = tau_from_centre + 0.5 * width  # time since the window opened
    inside = np.clip(tau, 0.0, width)  # small numbers: the 4-term difference stays accurate
    after = tau >= width
    values = []
    for order in orders:
        power = 3 - order
        if power < 0:
            values.append(np.zeros(np.broadcast(tau, width).shape))
            continue

        def truncated(x: np.ndarray, power: int = power) -> np.ndarray:
            if power == 0:
                return (x > 0.0).astype(float)
            return np.maximum(x, 0.0) ** power / math.factorial(power)

        value = (
            truncated(inside)
            - truncated(inside - b1)
            - truncated(inside - b2)
            + truncated(inside - width)
        ) / (b1 * b2)
        after_value = tau_from_centre if order == 0 else (1.0 if order == 1 else 0.0)
        values.append(np.where(after, after_value, value))
    return values


def _blend(
    tau: np.ndarray, coeffs: np.ndarray, duration: float, orders: tuple[int, ...]
) -> list[np.ndarray]:
    """Derivatives ``orders`` of the quintic blend ``sum_i c_i tau^i`` on ``[0, duration]``,
    zero after, extrapolated at constant rate before ``tau = 0``."""
    if duration <= 0.0:
        return [np.zeros_like(tau) for _ in orders]
    x = np.clip(tau, 0.0, duration)
    after, before = tau >= duration, tau < 0.0
    values = []
    for order in orders:
        value = _polyval(x, _polyder(coeffs, order))
        value = np.where(after, 0.0, value)
        if order == 0:
            value = np.where(before, coeffs[0] + coeffs[1] * tau, value)
        elif order == 1:
            value = np.where(before, coeffs[1], value)
        else:
            value = np.where(before, 0.0, value)
        values.append(value)
    return values


def _polyder(coeffs: np.ndarray, order: int) -> np.ndarray:
    """Coefficients (lowest power first) of the ``order``-th derivative of a quintic."""
    return coeffs[order:] * _FALLING_ARRAY[order, order:]


def _polyval(x: np.ndarray, coeffs: np.ndarray) -> np.ndarray:
    """Horner evaluation of ``sum_i coeffs[i] x^i``."""
    value = np.full(np.shape(x), coeffs[-1], dtype=float)
    for c in coeffs[-2::-1]:
        value = value * x + c
    return value


def _quintic_to_rest(e0: float, de0: float, dde0: float, duration: float) -> np.ndarray:
    """Coefficients of the quintic from (e0, de0, dde0) at 0 to (0, 0, 0) at ``duration``."""
    return np.array(
        [
            e0,
            de0,
            0.5 * dde0,
            -(20.0 * e0 + 12.0 * de0 * duration + 3.0 * dde0 * duration**2) / (2.0 * duration**3),
            (30.0 * e0 + 16.0 * de0 * duration + 3.0 * dde0 * duration**2) / (2.0 * duration**4),
            -(12.0 * e0 + 6.0 * de0 * duration + dde0 * duration**2) / (2.0 * duration**5),
        ]
    )


@functools.cache
def _blend_check_grid() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The grid blend candidates are checked on: times ``tau`` (G,), their powers 0..5
    (6, G) and which candidate is still under way at each (C, G). The same for every CAV and
    plan: made once (read-only)."""
    tau_grid = np.arange(0.0, _BLEND_DURATIONS_S[-1] + _CHECK_DT_S, _CHECK_DT_S)
    powers = tau_grid[None, :] ** np.arange(6)[:, None]  # (6, G)
    active = tau_grid[None, :] <= _BLEND_DURATIONS_S[:, None]  # (C, G)
    for array in (tau_grid, powers, active):
        array.flags.writeable = False
    return tau_grid, powers, active


def _with_longitudinal_blend(
    frame: GridFrame,
    speed: _SpeedProfile,
    t_now: float,
    s_now: float,
    v_now: float | None,
    a_now: float | None,
    limits: dict[str, float],
) -> _SpeedProfile:
    """Add the shortest quintic blend from the current state that keeps the total speed in
    ``[0, v_max]``, acceleration in ``[a_min, a_max]`` and jerk within ``2 * max_jerk``."""
    p_base, dp_base, ddp_base = (x[0] for x in speed.derivatives(np.array([t_now]), (0, 1, 2)))
    s_base = frame.origin_s_m + frame.speed_mps * (t_now - frame.t0_s) + p_base
    e0 = float(s_now) - s_base
    de0 = 0.0 if v_now is None else float(v_now) - (frame.speed_mps + dp_base)
    dde0 = 0.0 if a_now is None else float(a_now) - ddp_base
    if e0 == 0.0 and de0 == 0.0 and dde0 == 0.0:
        return speed
    tau_grid, powers, active = _blend_check_grid()
    dp_grid, a_grid, j_grid = speed.derivatives(t_now + tau_grid, (1, 2, 3))
    v_grid = frame.speed_mps + dp_grid
    lower = np.array([0.0, limits["a_min"], -2.0 * limits["max_jerk_mps3"]]) + _CHECK_MARGIN
    upper = np.array([limits["v_max"], limits["a_max"], 2.0 * limits["max_jerk_mps3"]])
    upper = upper - _CHECK_MARGIN

    # All candidates at once: rows = candidate durations, columns = the check grid. Longer is
    # not always gentler (a speed offset integrates into a larger position swing), so take
    # the shortest feasible candidate, or the least violating one if none is feasible.
    durations = _BLEND_DURATIONS_S
    coeffs = np.stack([_quintic_to_rest(e0, de0, dde0, d) for d in durations])  # (C, 6)
    violation = np.zeros(len(durations))
    for row, (order, base) in enumerate(((1, v_grid), (2, a_grid), (3, j_grid))):
        blend = (coeffs[:, order:] * _FALLING_ARRAY[order, order:]) @ powers[: 6 - order]
        total = base[None, :] + blend
        # The largest excess over the bounds while a candidate is active, from its extremes
        # there: x - upper and lower - x are monotone in x (also as rounded), so this is the
        # largest of the pointwise excesses, exactly, at two passes over the grid less.
        high = np.where(active, total, -np.inf).max(axis=1)
        low = np.where(active, total, np.inf).min(axis=1)
        violation = np.maximum(violation, np.maximum(high - upper[row], lower[row] - low))
    feasible = np.flatnonzero(violation <= 0.0)
    best = int(feasible[0]) if len(feasible) else int(np.argmin(violation))
    best_duration = float(durations[best])
    best_coeffs = coeffs[best]
    return dataclasses.replace(
        speed, blend_start_s=t_now, blend_coeffs=best_coeffs, blend_duration_s=best_duration
    )


def _lane_change_length(
    ref: Reference,
    t_from: float,
    dy: float,
    nominal_m: float,
    max_lat_speed: float,
    max_lat_accel: float,
) -> float:
    """Length [m] of a smoothstep lane change of ``dy`` starting at ``t_from``: at least
    ``nominal_m``, longer if the lateral speed or acceleration would exceed the limits."""
    length = max(nominal_m, 1e-6)
    s_from = ref.s_at(t_from)
    t_grid = np.linspace(t_from, t_from + 4.0 * ref.frame.behaving_interval_s, 400)
    s_grid, v_grid, _ = ref.evaluate_time(t_grid)
    for _ in range(3):  # the speed over a longer window may differ: refine twice
        in_window = s_grid <= s_from + length
        v_hi = float(np.max(v_grid[in_window])) if np.any(in_window) else float(v_grid[0])
        needed = max(
            nominal_m,
            _SMOOTHSTEP_PEAK_SLOPE * abs(dy) * v_hi / max_lat_speed,
            math.sqrt(_SMOOTHSTEP_PEAK_CURVATURE * abs(dy) * v_hi**2 / max_lat_accel),
        )
        if needed <= length:
            break
        length = needed
    return length


def _lane_changes(
    ref: Reference, road: RoadSection, max_lat_speed: float, max_lat_accel: float
) -> _LateralProfile:
    """One smoothstep in ``s`` per column change, from ``s(t_k)`` to ``s(t_{k+1})``."""
    frame = ref.frame
    starts, lengths, dys = [], [], []
    for k in range(len(ref.cells) - 1):
        dy = road.lane_centre_y(ref.cells[k + 1][1]) - road.lane_centre_y(ref.cells[k][1])
        if dy == 0.0:
            continue
        t_from, t_to = frame.step_time_s(k), frame.step_time_s(k + 1)
        s_from = ref.s_at(t_from)
        nominal = ref.s_at(t_to) - s_from
        starts.append(s_from)
        lengths.append(_lane_change_length(ref, t_from, dy, nominal, max_lat_speed, max_lat_accel))
        dys.append(dy)
    return _LateralProfile(
        y0_m=road.lane_centre_y(ref.cells[0][1]),
        starts_m=np.array(starts, dtype=float),
        lengths_m=np.array(lengths, dtype=float),
        dys_m=np.array(dys, dtype=float),
    )


def _with_lateral_blend(
    ref: Reference,
    lateral: _LateralProfile,
    y_now: float,
    max_lat_speed: float,
    max_lat_accel: float,
) -> _LateralProfile:
    """Start the lateral path at ``y_now`` and fade the offset out with a smoothstep."""
    s_now = ref.s_at(ref.start_time_s)
    offset = float(y_now) - lateral.derivatives(np.array([s_now]), (0,))[0][0]
    if offset == 0.0:
        return lateral
    # The blend is a lane change of -offset starting at s_now, on top of y0 + offset.
    nominal = ref.s_at(ref.start_time_s + ref.frame.behaving_interval_s) - s_now
    length = _lane_change_length(
        ref, ref.start_time_s, offset, nominal, max_lat_speed, max_lat_accel
    )
    return _LateralProfile(
        y0_m=lateral.y0_m + offset,
        starts_m=np.append(lateral.starts_m, s_now),
        lengths_m=np.append(lateral.lengths_m, length),
        dys_m=np.append(lateral.dys_m, -offset),
    )


def _smoothstep(x: np.ndarray, orders: tuple[int, ...]) -> list[np.ndarray]:
    """Derivatives ``orders`` of the quintic smoothstep ``10x^3 - 15x^4 + 6x^5``, clamped to
    0 before ``x = 0`` and 1 after ``x = 1``."""
    inside = (x > 0.0) & (x < 1.0)
    xc = np.clip(x, 0.0, 1.0)
    values = []
    for order in orders:
        value = _polyval(xc, _polyder(_SMOOTHSTEP, order))
        values.append(value if order == 0 else np.where(inside, value, 0.0))
    return values
