"""Trajectory tracking: longitudinal and lateral MPC on OSQP, and the paper's DP recursion.

Pure module: no SUMO import (paper Sec. II-D and III-B).

Both trackers are linear MPCs of the same shape: a two-state chain

    x_{k+1} = [[1, h], [0, 1]] x_k + [0, h * b] u_k + c_k,     k = 0..K-1

* longitudinal, time domain (eqs. (29), (31), (32)): ``x = [s, v]``, ``u = a``, ``h = dt``,
  ``b = 1``, ``c = 0``;
* lateral, spatial domain (eqs. (30), (33)-(35)): ``x = [l, phi]``, ``u = delta``,
  ``h = ds`` (the distance travelled per step, ``v * dt``), ``b = 1 / wheelbase``,
  ``c_k = [0, -ds * kappa_k]`` with ``kappa_k`` the road curvature.

The cost (eqs. (36), (41)) is ``1/2 sum_{k=1..K} (x_k - x_des_k)' Q (x_k - x_des_k) +
1/2 r sum_{k=0..K-1} u_k^2`` (Q on every predicted state, the last one included; the cost of
``x_0`` is a constant). Constraints: the dynamics, the input bounds (eqs. (39), (43)) and, for
the longitudinal MPC, the speed bounds (eq. (38)) on ``x_1..x_K``.

The QP is built once (sparse matrices in OSQP's CSC form) and warm-started on every call;
a call only changes the linear cost ``q`` and the bounds ``l``, ``u`` (the initial state,
``c_k`` and the bounds all live there). The lateral step ``ds`` sits in the constraint
matrix: when it changes, only its ``2K`` values are rewritten with OSQP's ``update(Ax=...,
Ax_idx=...)``, which refactorises the KKT matrix (see ``tools/bench_mpc.py`` for the cost).

Defaults: both MPCs use K = 30 steps of 0.1 s (3 s, i.e. 60 m of lateral preview at 20 m/s)
and are meant to be solved every 0.1 s SUMO step. ``tools/bench_mpc.py`` measures about
0.2 ms per call each (median, warm-started), 0.4-0.5 ms for both: within the 1 ms budget per
CAV per step (``docs/bench/mpc.md``).

Lateral reference (X_des)
-------------------------
The paper writes the lateral state in the *reference-path* frame, where the target is
``X_des = [0, 0]`` (eq. (28)). Here ``l`` and ``phi`` are measured in the *road* frame
(``l`` = lateral position from the centre of lane 0, ``phi`` = yaw relative to the road
tangent), which the lane geometry gives directly; a reference path ``l_des(s)`` then has the
target ``X_des = [l_des(s_k), atan(dl_des/ds(s_k))]``. Up to the small-angle approximations
the model already makes, the two are the same problem: the path-frame error is
``l - l_des`` and ``phi - atan(dl_des/ds)``.

Curvature feed-forward
----------------------
On a curve, ``delta = wheelbase * kappa`` is needed to stay on the path; with the paper's
cost ``r * delta^2`` the MPC trades a small lateral offset for a smaller wheel angle. With
``LateralSettings.curvature_feedforward`` (default) the input is split as
``delta = wheelbase * kappa_k + delta'`` and only ``delta'`` is penalised: this cancels
``c_k`` exactly and removes the offset. ``curvature_feedforward=False`` is the paper's cost.
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from sumo_swarm.checks import require_number, require_order
from sumo_swarm.errors import ConfigError

if TYPE_CHECKING:
    import scipy.sparse as sp

# OSQP (and SciPy's sparse matrices) are imported when the first MPC is made, not with this
# module: a run whose controller has no MPC (sumo-cacc, cacc) does not pay for them (~0.15 s).

_USABLE_STATUSES = ("solved", "solved inaccurate")
_NOMINAL_SPEED_MPS = 20.0
# The lateral MPC is not solved for a vehicle on a straight reference on a straight road
# within these of it (lateral offset everywhere on the horizon [m], heading [rad]): it steers
# straight (status "steady") and the tracker zeroes its heading. The QP's answer there is a
# correction of the same order as OSQP's tolerance (about 1e-4 rad); two thirds of the calls in
# a 12-CAV run were such (issue 11's run cost).
STEADY_TOL_M = 1e-3
STEADY_PHI_RAD = 1e-4
STEADY = "steady"  # the status of such a call
# The paper's front-wheel range [-450, 450] deg is the steering-wheel angle. With a steering
# ratio of 15 (typical for passenger cars) that is +-30 deg at the front wheels.
STEERING_RATIO = 15.0
DEFAULT_DELTA_MAX_RAD = math.radians(450.0 / STEERING_RATIO)


@dataclass(frozen=True, slots=True)
class OsqpSettings:
    """OSQP options used by both MPCs (see the OSQP documentation for their meaning).

    ``check_termination`` = 5 (OSQP's default is 25): a warm-started MPC call converges in
    about 10-20 iterations, so checking every 25 would run at least 25.

    Attributes
    ----------
    eps_abs
        OSQP absolute tolerance [1].
    eps_rel
        OSQP relative tolerance [1].
    max_iter
        OSQP iteration limit [iterations].
    polish
        OSQP solution polishing.
    check_termination
        OSQP checks for termination every this many iterations [iterations].
    """

    eps_abs: float = 1e-4
    eps_rel: float = 1e-4
    max_iter: int = 4000
    polish: bool = False
    check_termination: int = 5

    def __post_init__(self) -> None:
        _require_positive("OsqpSettings", "eps_abs", self.eps_abs)
        _require_positive("OsqpSettings", "eps_rel", self.eps_rel)
        _require_positive("OsqpSettings", "max_iter", self.max_iter)
        _require_positive("OsqpSettings", "check_termination", self.check_termination)


@dataclass(frozen=True, slots=True)
class LongitudinalSettings:
    """Longitudinal MPC (time domain): step, horizon, weights of eq. (36), bounds (38)-(39).

    Attributes
    ----------
    dt_s
        Prediction step [s].
    horizon
        Number of steps K [steps].
    q_s, q_v, r_lon
        Weights on the position error [1/m^2], speed error [s^2/m^2] and acceleration
        [s^4/m^2]. The paper gives no values; ours are 1, 2 and 1. These take out a speed
        error of 1.7 m/s braking at a_min (-4 m/s^2): 27 of the 40 paper-scene variants have
        a CAV braking at 3.5 m/s^2 or harder. ``[longitudinal] r_lon = 2`` halves that (13)
        with the same overtakes and mean speed there, but one noise draw of the paper scene
        then gives up (docs/dense-traffic.md, the nineteenth session).
    v_min, v_max
        Speed bounds [m/s]; relaxed per call to what the acceleration bounds can reach from
        the current speed, so the QP stays feasible.
    a_min, a_max
        Acceleration bounds [m/s^2] (paper: [-4, 3]).
    fallback_accel_mps2
        Acceleration returned when OSQP fails [m/s^2] (gentle braking).
    solver
        OSQP options.
    """

    dt_s: float = 0.1
    horizon: int = 30
    q_s: float = 1.0
    q_v: float = 2.0
    r_lon: float = 1.0
    v_min: float = 0.0
    v_max: float = 40.0
    a_min: float = -4.0
    a_max: float = 3.0
    fallback_accel_mps2: float = -1.0
    solver: OsqpSettings = field(default_factory=OsqpSettings)

    def __post_init__(self) -> None:
        name = "LongitudinalSettings"
        _require_positive(name, "dt_s", self.dt_s)
        _require_int(name, "horizon", self.horizon)
        _require_positive(name, "horizon", self.horizon)
        _require_positive(name, "q_s", self.q_s, allow_zero=True)
        _require_positive(name, "q_v", self.q_v, allow_zero=True)
        _require_positive(name, "r_lon", self.r_lon)
        _require_order(name, "v_min", self.v_min, "v_max", self.v_max)
        _require_order(name, "a_min", self.a_min, "a_max", self.a_max)
        fallback = f"{name}.fallback_accel_mps2"
        require_order(f"{name}.a_min", self.a_min, fallback, self.fallback_accel_mps2, strict=False)
        require_order(fallback, self.fallback_accel_mps2, f"{name}.a_max", self.a_max, strict=False)


@dataclass(frozen=True, slots=True)
class LateralSettings:
    """Lateral MPC (spatial domain): step, horizon, weights of eq. (41), bound (43).

    Attributes
    ----------
    dt_s
        Time per prediction step [s]; the caller passes ``ds = v * dt_s`` to ``solve``.
    horizon
        Number of steps K [steps].
    q_l, q_phi, r_lat
        Weights on the lateral error [1/m^2], yaw error [1/rad^2] and front-wheel angle
        [1/rad^2].
    delta_min, delta_max
        Front-wheel angle bounds [rad]. Default +-30 deg: the paper's +-450 deg is the
        steering-wheel angle, divided by a steering ratio of ``STEERING_RATIO`` = 15.
    wheelbase_m
        Wheelbase omega [m].
    curvature_feedforward
        Penalise only the wheel angle on top of ``wheelbase * kappa`` (module docstring);
        ``False`` is the paper's cost ``r * delta^2``.
    solver
        OSQP options.
    """

    dt_s: float = 0.1
    horizon: int = 30
    q_l: float = 1.0
    q_phi: float = 3.0
    r_lat: float = 30.0
    delta_min: float = -DEFAULT_DELTA_MAX_RAD
    delta_max: float = DEFAULT_DELTA_MAX_RAD
    wheelbase_m: float = 2.8
    curvature_feedforward: bool = True
    solver: OsqpSettings = field(default_factory=OsqpSettings)

    def __post_init__(self) -> None:
        name = "LateralSettings"
        _require_positive(name, "dt_s", self.dt_s)
        _require_int(name, "horizon", self.horizon)
        _require_positive(name, "horizon", self.horizon)
        _require_positive(name, "q_l", self.q_l, allow_zero=True)
        _require_positive(name, "q_phi", self.q_phi, allow_zero=True)
        _require_positive(name, "r_lat", self.r_lat)
        _require_order(name, "delta_min", self.delta_min, "delta_max", self.delta_max)
        if not self.delta_min <= 0.0 <= self.delta_max:
            raise ConfigError(f"{name}.delta_min/delta_max must bracket 0 rad")
        if self.delta_max >= math.pi / 2 or self.delta_min <= -math.pi / 2:
            raise ConfigError(f"{name}.delta_min/delta_max must lie in (-pi/2, pi/2) rad")
        _require_positive(name, "wheelbase_m", self.wheelbase_m)


@dataclass(frozen=True, eq=False)
class TrackingResult:
    """Outcome of one MPC call.

    Attributes
    ----------
    status
        OSQP's status (``"solved"``, ``"solved inaccurate"``, ``"maximum iterations
        reached"``, ``"primal infeasible"``, ...) or ``"invalid input"``.
    u0
        Input to apply now: acceleration [m/s^2] or front-wheel angle [rad]. When the status
        is neither ``"solved"`` nor ``"solved inaccurate"``, the safe fallback (gentle
        braking; curvature feed-forward steering, zero on a straight road).
    inputs
        Planned inputs, shape (K,).
    states
        Predicted states ``[s, v]`` or ``[l, phi]``, shape (K+1, 2): the model rolled out
        under ``inputs`` from the initial state (row 0). Speed bounds hold to OSQP's
        tolerance.
    solve_ms
        Wall time of the call [ms], updates included (the prediction excluded).
    objective
        Cost (36) / (41) of the returned plan, without the constant term of ``x_0``.

    ``states`` and ``objective`` are computed on first use, by ``_predict``: the tracker
    applies the inputs only, and rolling out and costing them took as long as the rest of a
    call besides OSQP's own solve (the numbers are the same whenever they are asked for).
    """

    status: str
    u0: float
    inputs: np.ndarray
    solve_ms: float
    _predict: Callable[[], tuple[np.ndarray, float]] = field(repr=False)

    @functools.cached_property
    def _prediction(self) -> tuple[np.ndarray, float]:
        return self._predict()

    @property
    def states(self) -> np.ndarray:
        return self._prediction[0]

    @property
    def objective(self) -> float:
        return self._prediction[1]

    @property
    def solved(self) -> bool:
        """True when the plan comes from OSQP (``solved`` or ``solved inaccurate``)."""
        return self.status in _USABLE_STATUSES


def _known(states: np.ndarray, objective: float) -> Callable[[], tuple[np.ndarray, float]]:
    """A prediction already computed (the rare fallbacks compute theirs at once)."""
    return lambda: (states, objective)


class _ChainQp:
    """The QP of ``x_{k+1} = [[1, h], [0, 1]] x_k + [0, h b] u_k + c_k`` over K steps.

    Variables ``z = [x_0, ..., x_K, u_0, ..., u_{K-1}]``. Constraint rows: ``x_0`` (2),
    dynamics (2K), optional bound on ``x_k[1]`` for k = 1..K (K), inputs (K).
    """

    def __init__(
        self,
        horizon: int,
        q_diag: tuple[float, float],
        r: float,
        input_gain: float,
        step: float,
        bound_second_state: bool,
        solver: OsqpSettings,
    ) -> None:
        import osqp
        import scipy.sparse as sp

        k_steps = horizon
        self.horizon = k_steps
        self.q_diag = np.asarray(q_diag, dtype=float)
        self.r = float(r)
        self.input_gain = float(input_gain)
        self.n_x = 2 * (k_steps + 1)
        n_z = self.n_x + k_steps
        self.n_dyn = 2 + 2 * k_steps
        self.n_bound = k_steps if bound_second_state else 0
        p_diag = np.concatenate([[0.0, 0.0], np.tile(self.q_diag, k_steps), np.full(k_steps, r)])
        p_matrix = sp.diags(p_diag, format="csc")

        rows, cols, vals = [0, 1], [0, 1], [1.0, 1.0]
        k = np.arange(k_steps)
        row_s, row_v = 2 + 2 * k, 3 + 2 * k
        col_s, col_v, col_u = 2 * k, 2 * k + 1, self.n_x + k
        # x_{k+1} - A x_k - B u_k = c_k; the step-dependent entries get placeholders first
        for r_idx, c_idx, value in (
            (row_s, col_s + 2, 1.0),
            (row_s, col_s, -1.0),
            (row_s, col_v, -1.0),  # -h
            (row_v, col_v + 2, 1.0),
            (row_v, col_v, -1.0),
            (row_v, col_u, -1.0),  # -h b
        ):
            rows.extend(r_idx)
            cols.extend(c_idx)
            vals.extend(np.full(k_steps, value))
        next_row = self.n_dyn
        if bound_second_state:
            rows.extend(next_row + k)
            cols.extend(2 * (k + 1) + 1)
            vals.extend(np.ones(k_steps))
            next_row += k_steps
        rows.extend(next_row + k)
        cols.extend(col_u)
        vals.extend(np.ones(k_steps))
        self.n_con = next_row + k_steps
        a_matrix = sp.csc_matrix((vals, (rows, cols)), shape=(self.n_con, n_z))
        a_matrix.sort_indices()
        self._step_idx = _csc_positions(a_matrix, row_s, col_v)
        self._gain_idx = _csc_positions(a_matrix, row_v, col_u)
        self._ax_idx = np.concatenate([self._step_idx, self._gain_idx])
        self.step = float(step)
        a_matrix.data[self._step_idx] = -self.step
        a_matrix.data[self._gain_idx] = -self.step * self.input_gain

        self._q = np.zeros(n_z)
        self._lower = np.zeros(self.n_con)
        self._upper = np.zeros(self.n_con)
        self._solver = osqp.OSQP()
        self._solver.setup(
            p_matrix,
            self._q,
            a_matrix,
            self._lower,
            self._upper,
            verbose=False,
            eps_abs=solver.eps_abs,
            eps_rel=solver.eps_rel,
            max_iter=solver.max_iter,
            polishing=solver.polish,
            check_termination=solver.check_termination,
            warm_starting=True,
        )
        # OSQP's Python wrapper costs more than solving these small warm-started QPs (its
        # update() looks its infinity constant up through importlib twice a call, its solve()
        # copies every info field into a namespace): the calls of every solve go to the
        # solver object it wraps, the bounds clipped to the same infinity as the wrapper
        # does. Another osqp version without that object goes through the wrapper.
        core = getattr(self._solver, "_solver", None)
        usable = all(hasattr(core, name) for name in ("update_data_vec", "solve", "info"))
        self._core = core if usable else None
        self._infinity = float(self._solver.constant("OSQP_INFTY"))

    def set_step(self, step: float) -> None:
        """Change h; rewrites only the 2K matrix values that depend on it."""
        if step == self.step:
            return
        self.step = float(step)
        values = np.concatenate(
            [
                np.full(self.horizon, -self.step),
                np.full(self.horizon, -self.step * self.input_gain),
            ]
        )
        self._solver.update(Ax=values, Ax_idx=self._ax_idx)

    def solve(
        self,
        x0: np.ndarray,
        x_des: np.ndarray,
        affine: np.ndarray,
        u_bounds: tuple[np.ndarray, np.ndarray],
        state_bounds: tuple[np.ndarray, np.ndarray] | None,
    ) -> tuple[str, np.ndarray | None]:
        """Solve for ``x0`` (2,), ``x_des`` (K+1, 2), ``c`` (K, 2) and the bounds (K,).

        Returns (status, inputs (K,)); the inputs are ``None`` unless the status is usable.
        """
        k_steps = self.horizon
        self._q[2 : self.n_x] = -(x_des[1:] * self.q_diag).ravel()
        self._lower[:2] = x0
        self._lower[2 : self.n_dyn] = affine.ravel()
        self._upper[: self.n_dyn] = self._lower[: self.n_dyn]
        row = self.n_dyn
        if state_bounds is not None:
            self._lower[row : row + k_steps], self._upper[row : row + k_steps] = state_bounds
            row += k_steps
        self._lower[row:], self._upper[row:] = u_bounds
        status, x = self._update_and_solve()
        if status not in _USABLE_STATUSES:
            return status, None
        inputs = np.array(x[self.n_x :], dtype=float)  # a copy: OSQP reuses its buffer
        if inputs.shape != (k_steps,) or not np.isfinite(inputs).all():
            return "non-finite solution", None
        return status, inputs

    def _update_and_solve(self) -> tuple[str, np.ndarray]:
        """OSQP's status and solution after setting ``q``, ``l`` and ``u`` (see __init__)."""
        if self._core is None:
            self._solver.update(q=self._q, l=self._lower, u=self._upper)
            result = self._solver.solve(raise_error=False)
            return str(result.info.status), result.x
        self._core.update_data_vec(
            q=self._q,
            l=np.maximum(self._lower, -self._infinity),
            u=np.minimum(self._upper, self._infinity),
        )
        self._core.solve()
        return str(self._core.info.status), self._core.solution.x

    def rollout(
        self, x0: np.ndarray, inputs: np.ndarray, affine: np.ndarray, step: float | None = None
    ) -> np.ndarray:
        """States (K+1, 2) of the model under ``inputs`` (K,), vectorised (``step``: h, by
        default the current one)."""
        step = self.step if step is None else step
        second = np.empty(self.horizon + 1)
        second[0] = x0[1]
        second[1:] = x0[1] + np.cumsum(step * self.input_gain * inputs + affine[:, 1])
        first = np.empty(self.horizon + 1)
        first[0] = x0[0]
        first[1:] = x0[0] + np.cumsum(step * second[:-1] + affine[:, 0])
        return np.column_stack([first, second])

    def predictor(
        self,
        x0: np.ndarray,
        inputs: np.ndarray,
        affine: np.ndarray,
        x_des: np.ndarray,
        offset: np.ndarray | None = None,
    ) -> Callable[[], tuple[np.ndarray, float]]:
        """:meth:`rollout` and :meth:`objective` of ``inputs``, for later (a TrackingResult
        computes them on first use): the step and ``affine`` are taken now, as the next call
        changes them. ``offset`` is added to the states after the cost."""
        step, affine = self.step, affine.copy()

        def predict() -> tuple[np.ndarray, float]:
            states = self.rollout(x0, inputs, affine, step)
            objective = self.objective(states, inputs, x_des)
            return (states if offset is None else states + offset), objective

        return predict

    def objective(self, states: np.ndarray, inputs: np.ndarray, x_des: np.ndarray) -> float:
        error = states[1:] - x_des[1:]
        return float(0.5 * np.sum(error**2 * self.q_diag) + 0.5 * self.r * np.sum(inputs**2))


class LongitudinalMpc:
    """Longitudinal tracker (eqs. (29), (31), (32), (36)-(40)), OSQP set up once.

    Positions are shifted by ``s0`` inside the QP so the numbers stay small on long routes.
    """

    def __init__(self, settings: LongitudinalSettings | None = None) -> None:
        self.settings = settings or LongitudinalSettings()
        cfg = self.settings
        self._qp = _ChainQp(
            cfg.horizon,
            (cfg.q_s, cfg.q_v),
            cfg.r_lon,
            input_gain=1.0,
            step=cfg.dt_s,
            bound_second_state=True,
            solver=cfg.solver,
        )
        k = np.arange(1, cfg.horizon + 1)
        self._no_affine = np.zeros((cfg.horizon, 2))
        self._u_lo = np.full(cfg.horizon, cfg.a_min)
        self._u_hi = np.full(cfg.horizon, cfg.a_max)
        self._reach_down = cfg.a_min * cfg.dt_s * k  # speed change reachable by step k
        self._reach_up = cfg.a_max * cfg.dt_s * k

    def solve(self, s0: float, v0: float, s_ref: np.ndarray, v_ref: np.ndarray) -> TrackingResult:
        """Plan accelerations from ``(s0 [m], v0 [m/s])`` to track ``s_ref``, ``v_ref``.

        ``s_ref`` and ``v_ref`` have shape (K+1,) at ``t_now + k * dt`` (k = 0..K); entry 0 is
        not used by the cost. Raises ``ValueError`` only for wrong shapes.
        """
        started = time.perf_counter()
        cfg = self.settings
        x_des = _stack_reference(cfg.horizon, s_ref=s_ref, v_ref=v_ref)
        x0 = np.array([0.0, v0], dtype=float)
        x_des[:, 0] -= s0
        # ndarray methods rather than np.all / np.clip here: those add a Python dispatch layer
        # that cost more than the operation on these short arrays (every CAV every solve).
        if not (np.isfinite(x_des).all() and math.isfinite(s0) and math.isfinite(v0)):
            return self._fallback("invalid input", s0, x0, x_des, started)
        v_lo = np.minimum(cfg.v_min, v0 + self._reach_up)
        v_hi = np.maximum(cfg.v_max, v0 + self._reach_down)
        status, inputs = self._qp.solve(
            x0, x_des, self._no_affine, (self._u_lo, self._u_hi), (v_lo, v_hi)
        )
        if inputs is None:
            return self._fallback(status, s0, x0, x_des, started)
        inputs = inputs.clip(cfg.a_min, cfg.a_max)
        # The states rolled out under the clipped inputs: consistent with them.
        predict = self._qp.predictor(x0, inputs, self._no_affine, x_des, np.array([s0, 0.0]))
        return TrackingResult(status, float(inputs[0]), inputs, _elapsed_ms(started), predict)

    def _fallback(
        self, status: str, s0: float, x0: np.ndarray, x_des: np.ndarray, started: float
    ) -> TrackingResult:
        inputs = np.full(self.settings.horizon, self.settings.fallback_accel_mps2)
        states = self._qp.rollout(x0, inputs, self._no_affine)
        objective = self._qp.objective(states, inputs, x_des)
        states[:, 0] += s0
        return TrackingResult(
            status, float(inputs[0]), inputs, _elapsed_ms(started), _known(states, objective)
        )


class LateralMpc:
    """Lateral tracker in the spatial domain (eqs. (30), (33)-(35), (41)-(44)), OSQP set up
    once; ``ds`` is set per call (module docstring)."""

    def __init__(self, settings: LateralSettings | None = None) -> None:
        self.settings = settings or LateralSettings()
        cfg = self.settings
        self._qp = _ChainQp(
            cfg.horizon,
            (cfg.q_l, cfg.q_phi),
            cfg.r_lat,
            input_gain=1.0 / cfg.wheelbase_m,
            step=cfg.dt_s * _NOMINAL_SPEED_MPS,  # replaced by the first call's ds
            bound_second_state=False,
            solver=cfg.solver,
        )
        self._affine = np.zeros((cfg.horizon, 2))

    def solve(
        self,
        l0: float,
        phi0: float,
        l_ref: np.ndarray,
        phi_ref: np.ndarray,
        kappa: np.ndarray,
        ds: float,
    ) -> TrackingResult:
        """Plan front-wheel angles from ``(l0 [m], phi0 [rad])`` to track the reference.

        Parameters
        ----------
        l0, phi0
            Lateral position [m] (from the centre of lane 0) and yaw relative to the road
            tangent [rad].
        l_ref, phi_ref
            Targets at ``s_now + k * ds`` (k = 0..K), shape (K+1,): ``l_des(s_k)`` and
            ``atan(dl_des/ds(s_k))`` (``Reference.sample_space``); entry 0 unused.
        kappa
            Road curvature at the K steps [1/m], shape (K,), left turns positive.
        ds
            Distance travelled per step [m], > 0 (``v * dt_s``).

        Raises ``ValueError`` only for wrong shapes.
        """
        started = time.perf_counter()
        cfg = self.settings
        k_steps = cfg.horizon
        x_des = _stack_reference(k_steps, l_ref=l_ref, phi_ref=phi_ref)
        kappa = np.asarray(kappa, dtype=float)
        if kappa.shape != (k_steps,):
            raise ValueError(f"kappa must have shape ({k_steps},), got {kappa.shape}")
        x0 = np.array([l0, phi0], dtype=float)
        feedforward = cfg.wheelbase_m * kappa if cfg.curvature_feedforward else np.zeros(k_steps)
        finite = np.isfinite(x_des).all() and np.isfinite(x0).all()  # methods: see above
        if not (finite and np.isfinite(kappa).all() and math.isfinite(ds) and ds > 0.0):
            return self._fallback("invalid input", x0, x_des, np.zeros(k_steps), 0.0, started)
        straight = abs(phi0) <= STEADY_PHI_RAD and not kappa.any() and not x_des[1:, 1].any()
        if straight and (np.abs(x_des[1:, 0] - l0) <= STEADY_TOL_M).all():
            # Centred on a straight reference on a straight road: straight on, the heading
            # zeroed by the tracker (the optimum up to OSQP's tolerance; most CAVs, most steps).
            inputs = np.zeros(k_steps)
            qp = self._qp

            def predict() -> tuple[np.ndarray, float]:
                states = np.tile(np.array([l0, 0.0]), (k_steps + 1, 1))
                return states, qp.objective(states, inputs, x_des)

            return TrackingResult(STEADY, 0.0, inputs, _elapsed_ms(started), predict)
        self._qp.set_step(float(ds))
        # c_k of eq. (35) plus B * delta_ff (zero when the feed-forward is on)
        self._affine[:, 1] = ds * (feedforward / cfg.wheelbase_m - kappa)
        bounds = (cfg.delta_min - feedforward, cfg.delta_max - feedforward)
        status, extra = self._qp.solve(x0, x_des, self._affine, bounds, None)
        if extra is None:
            return self._fallback(status, x0, x_des, feedforward, ds, started)
        extra = extra.clip(*bounds)
        predict = self._qp.predictor(x0, extra, self._affine, x_des)  # consistent with them
        inputs = feedforward + extra
        return TrackingResult(status, float(inputs[0]), inputs, _elapsed_ms(started), predict)

    def _fallback(
        self,
        status: str,
        x0: np.ndarray,
        x_des: np.ndarray,
        feedforward: np.ndarray,
        ds: float,
        started: float,
    ) -> TrackingResult:
        cfg = self.settings
        inputs = np.clip(feedforward, cfg.delta_min, cfg.delta_max)
        if ds > 0.0 and math.isfinite(ds):  # after a failed solve: affine terms are current
            states = self._qp.rollout(x0, inputs - feedforward, self._affine)
        else:  # invalid input: no prediction
            states = np.tile(x0, (cfg.horizon + 1, 1))
        objective = self._qp.objective(states, inputs - feedforward, x_des)
        return TrackingResult(
            status, float(inputs[0]), inputs, _elapsed_ms(started), _known(states, objective)
        )


def dp_solve(
    a_list: Sequence[np.ndarray],
    b: np.ndarray,
    c_list: Sequence[np.ndarray] | None,
    q: np.ndarray,
    r: np.ndarray | float,
    x0: np.ndarray,
    x_des: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The paper's dynamic-programming solution (eqs. (45)-(57)) of the unconstrained problem

        min 1/2 sum_{k=0..K} (x_k - x_des_k)' Q (x_k - x_des_k) + 1/2 sum_{k=0..K-1} u_k' R u_k
        s.t. x_{k+1} = A_k x_k + B u_k + C_k,

    generalised to the affine term ``C_k`` and a non-zero target ``x_des_k``.

    Derivation: the cost-to-go is ``V_k(x) = 1/2 x' Qt_k x + D_k' x + const``. At the
    terminal step ``Qt_K = Q``, ``D_K = -Q x_des_K`` (the paper's (45)-(47) with
    ``x_des = 0``: ``D = 0``). Minimising ``1/2 u'Ru + V_{k+1}(A_k x + B u + C_k)`` over ``u``
    gives ``u = G_k x + H_k`` with

        P_k = (R + B' Qt_{k+1} B)^-1                                      (51)
        G_k = -P_k B' Qt_{k+1} A_k                                        (52)
        H_k = -P_k B' (Qt_{k+1} C_k + D_{k+1})                 (53) + C_k term
        S_k = A_k + B G_k,   T_k = B H_k + C_k                  (54), (55) + C_k

    and substituting back,

        Qt_k = G_k' R G_k + S_k' Qt_{k+1} S_k + Q                         (48)
        D_k  = G_k' R H_k + S_k' Qt_{k+1} T_k + S_k' D_{k+1} - Q x_des_k  (49) + target term

    The forward pass is (56)-(57): ``u_k = G_k x_k + H_k``, ``x_{k+1} = S_k x_k + T_k``. The
    constant (50) does not change the minimiser and is not computed. The paper's eqs. are the
    case ``C_k = 0``, ``x_des = 0`` (error state).

    Parameters
    ----------
    a_list
        K state matrices (n, n).
    b
        Input matrix (n, m).
    c_list
        K affine vectors (n,), or ``None`` for zero.
    q, r
        State weight (n, n) and input weight (m, m) (a scalar when m = 1).
    x0
        Initial state (n,).
    x_des
        Targets, shape (K+1, n) (row 0 only adds a constant).

    Returns
    -------
    (U, X)
        Inputs (K, m) and states (K+1, n).
    """
    a_mats = [np.atleast_2d(np.asarray(a, dtype=float)) for a in a_list]
    k_steps = len(a_mats)
    b = np.asarray(b, dtype=float)
    b = b.reshape(-1, 1) if b.ndim == 1 else b
    n, m = b.shape
    c_vecs = (
        [np.zeros(n)] * k_steps
        if c_list is None
        else [np.asarray(c, dtype=float).reshape(n) for c in c_list]
    )
    q = np.atleast_2d(np.asarray(q, dtype=float))
    r = np.atleast_2d(np.asarray(r, dtype=float))
    x_des = np.asarray(x_des, dtype=float).reshape(k_steps + 1, n)
    if len(c_vecs) != k_steps:
        raise ValueError(f"c_list has {len(c_vecs)} entries, a_list {k_steps}")

    q_tilde = q.copy()
    d_vec = -q @ x_des[k_steps]
    backward: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    for k in range(k_steps - 1, -1, -1):
        a, c = a_mats[k], c_vecs[k]
        p_inv = r + b.T @ q_tilde @ b
        g = -np.linalg.solve(p_inv, b.T @ q_tilde @ a)
        h = -np.linalg.solve(p_inv, b.T @ (q_tilde @ c + d_vec))
        s_mat = a + b @ g
        t_vec = b @ h + c
        d_vec = g.T @ r @ h + s_mat.T @ q_tilde @ t_vec + s_mat.T @ d_vec - q @ x_des[k]
        q_tilde = g.T @ r @ g + s_mat.T @ q_tilde @ s_mat + q
        backward.append((g, h, s_mat, t_vec))

    inputs = np.empty((k_steps, m))
    states = np.empty((k_steps + 1, n))
    states[0] = np.asarray(x0, dtype=float).reshape(n)
    for k, (g, h, s_mat, t_vec) in enumerate(reversed(backward)):
        inputs[k] = g @ states[k] + h
        states[k + 1] = s_mat @ states[k] + t_vec
    return inputs, states


def lateral_model(ds: float, wheelbase_m: float, kappa: float) -> tuple[np.ndarray, ...]:
    """``(A, B, C)`` of eqs. (33)-(35) for one spatial step ``ds`` [m]."""
    a = np.array([[1.0, ds], [0.0, 1.0]])
    b = np.array([[0.0], [ds / wheelbase_m]])
    c = np.array([0.0, -ds * kappa])
    return a, b, c


def longitudinal_model(dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``(A, B)`` of eqs. (31)-(32) for one time step ``dt`` [s]."""
    return np.array([[1.0, dt], [0.0, 1.0]]), np.array([[0.0], [dt]])


# --------------------------------------------------------------------------- helpers
def _stack_reference(horizon: int, **references: np.ndarray) -> np.ndarray:
    """The two reference arrays as one (K+1, 2) array (a copy); checks their shapes."""
    stacked = np.empty((horizon + 1, len(references)))  # filled column by column: no
    for j, (name, values) in enumerate(references.items()):  # column_stack, twice per call
        array = np.asarray(values, dtype=float)
        if array.shape != (horizon + 1,):
            raise ValueError(f"{name} must have shape ({horizon + 1},), got {array.shape}")
        stacked[:, j] = array
    return stacked


def _csc_positions(matrix: sp.csc_matrix, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Indices into ``matrix.data`` of the entries (rows[i], cols[i])."""
    positions = np.empty(len(rows), dtype=np.int64)
    for i, (row, col) in enumerate(zip(rows, cols, strict=True)):
        start, stop = matrix.indptr[col], matrix.indptr[col + 1]
        positions[i] = start + int(np.flatnonzero(matrix.indices[start:stop] == row)[0])
    return positions


def _elapsed_ms(started: float) -> float:
    return (time.perf_counter() - started) * 1e3


def _require_positive(owner: str, name: str, value: float, *, allow_zero: bool = False) -> None:
    bound = {"ge": 0.0} if allow_zero else {"gt": 0.0}
    require_number(f"{owner}.{name}", value, **bound)


def _require_int(owner: str, name: str, value: object) -> None:
    require_number(f"{owner}.{name}", value, integer=True)


def _require_order(owner: str, low_name: str, low: float, high_name: str, high: float) -> None:
    require_order(f"{owner}.{low_name}", low, f"{owner}.{high_name}", high)
