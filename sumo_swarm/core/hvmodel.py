"""How a human-driven vehicle (HV) reacts: its own car-following model, and predictions by it.

Pure module (no SUMO import). The formulas follow SUMO's implementations with SUMO's default
semi-implicit Euler update, so that what the planner expects of an HV is what SUMO makes it do:

- IDM (``MSCFModel_IDM``): the IDM acceleration, integrated over SUMO's internal iterations
  (``max(1, round(step / idmStepping))``, stepping 0.25 s), leader at constant speed within the
  step; then SUMO's speed bounds (``finalizeSpeed``): never above the desired speed, braking at
  most the emergency deceleration.
- Krauss (``MSCFModel_Krauss``): SUMO's safe speed over one step (stop behind the leader even if
  it brakes to a halt, reaction time ``tau``), its emergency-braking correction, the speed bounds,
  and the dawdling ``sigma`` (a random slow-down of up to ``sigma * accel`` per step).
- EIDM is taken as IDM; any other model ("unknown", W99, ACC, ...): a conservative bound, the
  harsher of IDM and Krauss with the vType's values.

Measured against SUMO 1.28 (tests/test_hvmodel_sumo.py): the braking of an IDM or Krauss HV after
a cut-in, first step and strongest, agrees bit for bit at SUMO's step.

Gaps are *bumper* gaps [m] (leader's rear minus this vehicle's front), minGap included; SUMO
subtracts minGap before its car-following call, the formulas here take that into account.
"""

from __future__ import annotations

import bisect
import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from sumo_swarm.core.model import RoadSection, VehicleState

IDM_MODELS = frozenset({"IDM", "EIDM"})
KRAUSS_MODELS = frozenset({"Krauss", "KraussOrig1", "KraussPS"})
# SUMO's NUMERICAL_EPS, and the factor of its emergency deceleration (EMERGENCY_DECEL_AMPLIFIER).
_EPS = 0.001
_EMERGENCY_AMPLIFIER = 1.2
_FREE_GAP_M = 1e6  # SUMO's IDM free-road gap
# Closing speed [m/s] below which a reaction counts as over: safe-speed models (Krauss) approach
# the leader's speed only asymptotically.
_CLOSED_MPS = 0.1
# Time [s] a driver must have stopped closing in for its reaction to count as over.
_SETTLED_S = 2.0


@dataclass(frozen=True, slots=True)
class DriverModel:
    """How one human-driven vehicle drives, read from its vType."""

    model: str = "IDM"  # SUMO carFollowModel: "IDM", "Krauss", "EIDM", ... ("unknown": not read)
    accel_mps2: float = 2.6
    decel_mps2: float = 4.5  # comfortable deceleration b
    emergency_decel_mps2: float = 9.0
    tau_s: float = 1.0  # desired time headway T (IDM) / reaction time (Krauss)
    min_gap_m: float = 2.5  # s0
    delta: float = 4.0  # IDM acceleration exponent
    # v0 [m/s]: the vehicle's own top speed (SUMO's vehicle maxSpeed); see desired_speed_on().
    desired_speed_mps: float = 33.33
    length_m: float = 5.0
    sigma: float = 0.0  # Krauss dawdling, 0..1 (SUMO's default Krauss: 0.5)
    speed_factor: float = 1.0  # the vehicle's chosen speedFactor (applies to lane limits)
    idm_stepping_s: float = 0.25  # IDM's internal integration step

    def desired_speed_on(self, lane_limit_mps: float) -> DriverModel:
        """This driver on a lane with speed limit ``lane_limit_mps``: SUMO's desired speed
        there is ``min(maxSpeed, limit * speedFactor)``."""
        v0 = min(self.desired_speed_mps, lane_limit_mps * self.speed_factor)
        return dataclasses.replace(self, desired_speed_mps=v0)


# ---------------------------------------------------------------------- SUMO's formulas
# SUMO's default passenger vType as a driver (its decel, tau and minGap are what the swarm
# takes where it means "SUMO's own driver"). The class's own fields are slots, not these values.
SUMO_DEFAULTS = DriverModel()


def idm_follow_speed(
    m: DriverModel, v_mps: float, v_lead_mps: float, gap_m: float, step_s: float, v0_mps: float
) -> float:
    """SUMO's IDM ``_v``: speed [m/s] after one step behind a leader at bumper gap ``gap_m``."""
    return _Idm(m, step_s).follow_speed(v_mps, v_lead_mps, gap_m, v0_mps)


class _Idm:
    """SUMO's IDM of one driver over steps of ``step_s``, with what depends on those alone
    worked out once: a simulated reaction (:func:`_reaction_peak`) evaluates it at each of
    its steps."""

    __slots__ = ("h", "iterations", "m", "min_decel", "step_s", "two_sqrt_ab")

    def __init__(self, m: DriverModel, step_s: float) -> None:
        self.m = m
        self.step_s = step_s
        self.iterations = max(1, int(step_s / m.idm_stepping_s + 0.5))
        self.h = step_s / self.iterations
        self.two_sqrt_ab = 2.0 * math.sqrt(m.accel_mps2 * m.decel_mps2)
        # IDM's minNextSpeed lets it brake at least 1.5 m/s^2 (SUMO: approaching stops)
        self.min_decel = max(m.decel_mps2, min(m.emergency_decel_mps2, 1.5))

    def follow_speed(self, v_mps: float, v_lead_mps: float, gap_m: float, v0_mps: float) -> float:
        """:func:`idm_follow_speed` of this driver and step."""
        m, h, two_sqrt_ab = self.m, self.h, self.two_sqrt_ab
        a, tau, s0, delta = m.accel_mps2, m.tau_s, m.min_gap_m, m.delta
        v0 = max(_EPS, v0_mps)
        speed = v_mps
        gap = gap_m
        # Conditionals rather than max(), the same values (max(lo, x) is x if x > lo, else
        # lo): this runs twice per simulated step of every reaction, the calls were its cost.
        for _ in range(self.iterations):
            s_star = speed * tau + speed * (speed - v_lead_mps) / two_sqrt_ab
            s_star = (s_star if s_star > 0.0 else 0.0) + s0
            gap = gap if gap > _EPS else _EPS
            acc = a * (1.0 - (speed / v0) ** delta - (s_star * s_star) / (gap * gap))
            speed += acc * h
            speed = speed if speed > 0.0 else 0.0
            closing = (speed - v_lead_mps) * h
            gap -= closing if closing > 0.0 else 0.0
        return speed

    def next_speed(self, v: float, v_lead: float | None, gap: float | None) -> float:
        """The driver's speed [m/s] after the step (``v >= 0``; no leader: free road)."""
        v0 = self.m.desired_speed_mps
        v_safe = self.follow_speed(v, v0, _FREE_GAP_M, v0)  # SUMO's freeSpeed
        if v_lead is not None and gap is not None:
            v_safe = min(v_safe, self.follow_speed(v, v_lead, gap, v0))
        return _finalize(self.m, v, v_safe, self.step_s, self.min_decel)[1]

    def accel(self, v_mps: float, v_lead_mps: float, gap_m: float) -> float:
        """Acceleration [m/s^2] over the step behind a leader at bumper gap ``gap_m``:
        ``(next_speed(v, v_lead, gap) - v) / step_s`` with ``v = max(0, v_mps)``, what a
        simulated reaction (:func:`_reaction_peak`) evaluates at each of its steps."""
        v = v_mps if v_mps > 0.0 else 0.0  # max(0.0, v_mps)
        return (self.next_speed(v, v_lead_mps, gap_m) - v) / self.step_s


def brake_gap_euler(v_mps: float, decel_mps2: float, step_s: float) -> float:
    """Distance [m] to stop from ``v_mps`` braking ``decel_mps2`` per Euler step (SUMO)."""
    reduction = decel_mps2 * step_s
    steps = int(v_mps / reduction)
    return step_s * (steps * v_mps - reduction * steps * (steps + 1) / 2.0)


def _safe_stop_speed_euler(gap_m: float, decel_mps2: float, tau_s: float, step_s: float) -> float:
    """SUMO's ``maximumSafeStopSpeedEuler``: the highest speed [m/s] from which the vehicle can
    still stop within ``gap_m`` after its reaction time, braking ``decel_mps2``."""
    g = gap_m - _EPS
    if g < 0.0:
        return 0.0
    b = decel_mps2 * step_s
    t = tau_s
    s = step_s
    n = math.floor(0.5 - (t - math.sqrt(s * s + 4.0 * (s * (2.0 * g / b - t) + t * t)) / 2.0) / s)
    h = 0.5 * n * (n - 1) * b * s + n * b * t
    r = (g - h) / (n * s + t)
    return n * b + r


def krauss_follow_speed(
    m: DriverModel,
    v_mps: float,
    v_lead_mps: float,
    gap_m: float,
    step_s: float,
    lead_decel_mps2: float | None = None,
) -> float:
    """SUMO's Krauss ``followSpeed`` [m/s] behind a leader at bumper gap ``gap_m``."""
    b = m.decel_mps2
    lead_b = b if lead_decel_mps2 is None else lead_decel_mps2
    g = gap_m - m.min_gap_m  # SUMO's gap has minGap removed
    if g >= 0.0:
        x = _safe_stop_speed_euler(
            g + brake_gap_euler(v_lead_mps, max(b, lead_b), step_s), b, m.tau_s, step_s
        )
    else:
        x = max(0.0, v_mps - m.emergency_decel_mps2 * step_s)
    if b != m.emergency_decel_mps2:
        orig_decel = (v_mps - x) / step_s
        if orig_decel > b + _EPS:
            # Braking harder than decel: SUMO's emergency deceleration (calculateEmergencyDecel).
            safe = _EMERGENCY_AMPLIFIER * _emergency_decel(m, g, v_mps, v_lead_mps, lead_b)
            safe = min(max(safe, b), orig_decel)
            x = max(0.0, v_mps - safe * step_s)
    return min(x, v_mps + m.accel_mps2 * step_s)


def _emergency_decel(
    m: DriverModel, gap_m: float, v_mps: float, v_lead_mps: float, lead_decel_mps2: float
) -> float:
    lead_brake_m = 0.5 * v_lead_mps * v_lead_mps / lead_decel_mps2
    if gap_m + lead_brake_m > 0.0:
        b1 = 0.5 * v_mps * v_mps / (gap_m + lead_brake_m)
        if b1 <= lead_decel_mps2:
            return b1
    if gap_m <= 0.0:
        return m.emergency_decel_mps2
    return 0.5 * (v_mps * v_mps - v_lead_mps * v_lead_mps) / gap_m


def _finalize(
    m: DriverModel, v_mps: float, v_safe: float, step_s: float, min_decel: float
) -> tuple[float, float]:
    """SUMO's ``finalizeSpeed`` bounds: (lowest, highest) next speed [m/s].

    Written out with conditionals, the values of the max() and min() they stand for (``max(a,
    b)`` is b if b > a, else a): this runs at every simulated step of every reaction."""
    v_min_emergency = v_mps - m.emergency_decel_mps2 * step_s
    v_min_emergency = v_min_emergency if v_min_emergency > 0.0 else 0.0  # max(0, .)
    braked = v_mps - min_decel * step_s
    braked = braked if braked > 0.0 else 0.0  # max(0, .)
    lowest = v_min_emergency if v_min_emergency > v_safe else v_safe  # max(v_safe, .)
    v_min = lowest if lowest < braked else braked  # min(braked, lowest)
    v_max = v_mps + m.accel_mps2 * step_s
    desired = 0.0 if m.desired_speed_mps < 0.0 else m.desired_speed_mps  # max(v0, 0)
    v_max = desired if desired < v_max else v_max  # min(v + a step, v0, v_safe) ...
    v_max = v_safe if v_safe < v_max else v_max  # ... in the same order
    return v_min, v_max if v_max > v_min else v_min  # max(v_min, v_max)


def _idm_next_speed(
    m: DriverModel, v: float, v_lead: float | None, gap: float | None, step_s: float
) -> float:
    return _Idm(m, step_s).next_speed(v, v_lead, gap)


def _krauss_next_speed(
    m: DriverModel,
    v: float,
    v_lead: float | None,
    gap: float | None,
    step_s: float,
    dawdle: float,
    lead_decel: float | None,
) -> float:
    v_safe = math.inf
    if v_lead is not None and gap is not None:
        v_safe = krauss_follow_speed(m, v, v_lead, gap, step_s, lead_decel)
    v_min, v_max = _finalize(m, v, v_safe, step_s, m.decel_mps2)
    # Dawdling: SUMO subtracts sigma * min(accel, speed) * step * U[0, 1).
    slow = max(0.0, m.sigma) * dawdle * min(m.accel_mps2, v_max) * step_s
    return max(v_min, max(0.0, v_max - slow))


def model_accel(
    m: DriverModel,
    v_mps: float,
    v_lead_mps: float | None,
    gap_m: float | None,
    step_s: float = 0.1,
    *,
    dawdle: float = 1.0,
    lead_decel_mps2: float | None = None,
) -> float:
    """Acceleration [m/s^2] the driver commands now, following a leader at bumper gap ``gap_m``
    driving ``v_lead_mps`` (either None: free road), over one SUMO step of ``step_s``.

    ``dawdle``: the fraction of Krauss' largest random slow-down assumed (1: the worst case, as
    safety checks want; 0.5: the mean, for predictions). ``lead_decel_mps2``: the leader's
    deceleration as Krauss assumes it (default: the driver's own).
    """
    v = max(0.0, v_mps)
    if m.model in IDM_MODELS:
        v_next = _idm_next_speed(m, v, v_lead_mps, gap_m, step_s)
    elif m.model in KRAUSS_MODELS:
        v_next = _krauss_next_speed(m, v, v_lead_mps, gap_m, step_s, dawdle, lead_decel_mps2)
    else:
        v_next = min(
            _idm_next_speed(m, v, v_lead_mps, gap_m, step_s),
            _krauss_next_speed(m, v, v_lead_mps, gap_m, step_s, dawdle, lead_decel_mps2),
        )
    return (v_next - v) / step_s


class _Krauss:
    """SUMO's Krauss of one driver over steps of ``step_s``, worst-case dawdling, leader's
    deceleration taken as the driver's own: :func:`model_accel` written out in one function
    (the same operations in the same order, so the same numbers bit for bit). A simulated
    reaction (:func:`_reaction_peak`) evaluates it at each of its steps; through the general
    functions, their calls were most of a dense corridor's planning time."""

    __slots__ = ("m", "step_s")

    def __init__(self, m: DriverModel, step_s: float) -> None:
        self.m = m
        self.step_s = step_s

    def accel(self, v_mps: float, v_lead: float, gap_m: float) -> float:
        m, step = self.m, self.step_s
        v = v_mps if v_mps > 0.0 else 0.0  # max(0.0, v_mps)
        b = m.decel_mps2
        emergency = m.emergency_decel_mps2
        # krauss_follow_speed(m, v, v_lead, gap_m, step), leader braking at b
        g = gap_m - m.min_gap_m
        if g >= 0.0:
            reduction = b * step  # brake_gap_euler(v_lead, b, step)
            steps = int(v_lead / reduction)
            lead_brake = step * (steps * v_lead - reduction * steps * (steps + 1) / 2.0)
            # _safe_stop_speed_euler(g + lead_brake, b, tau, step)
            gs = g + lead_brake - _EPS
            if gs < 0.0:
                x = 0.0
            else:
                bs = b * step
                t = m.tau_s
                root = math.sqrt(step * step + 4.0 * (step * (2.0 * gs / bs - t) + t * t))
                n = math.floor(0.5 - (t - root / 2.0) / step)
                h = 0.5 * n * (n - 1) * bs * step + n * bs * t
                x = n * bs + (gs - h) / (n * step + t)
        else:
            x = max(0.0, v - emergency * step)
        if b != emergency:
            orig_decel = (v - x) / step
            if orig_decel > b + _EPS:
                safe = _EMERGENCY_AMPLIFIER * _emergency_decel(m, g, v, v_lead, b)
                safe = min(max(safe, b), orig_decel)
                x = max(0.0, v - safe * step)
        v_safe = min(x, v + m.accel_mps2 * step)
        # _finalize(m, v, v_safe, step, b)
        lowest = v - emergency * step
        lowest = lowest if lowest > 0.0 else 0.0
        lowest = lowest if lowest > v_safe else v_safe
        braked = v - b * step
        braked = braked if braked > 0.0 else 0.0
        v_min = lowest if lowest < braked else braked
        v_max = v + m.accel_mps2 * step
        desired = 0.0 if m.desired_speed_mps < 0.0 else m.desired_speed_mps
        v_max = desired if desired < v_max else v_max
        v_max = v_safe if v_safe < v_max else v_max
        v_max = v_max if v_max > v_min else v_min
        slow = max(0.0, m.sigma) * 1.0 * min(m.accel_mps2, v_max) * step
        slowed = v_max - slow
        v_next = max(v_min, slowed if slowed > 0.0 else 0.0)
        return (v_next - v) / step


def _accel_of(m: DriverModel, step_s: float) -> Callable[[float, float, float], float]:
    """``model_accel(m, v, v_lead, gap, step_s)`` as a function of ``(v, v_lead, gap)``; an
    IDM or Krauss driver's written out once (the same numbers, bit for bit)."""
    if m.model in IDM_MODELS:
        return _Idm(m, step_s).accel
    if m.model in KRAUSS_MODELS:
        return _Krauss(m, step_s).accel
    return lambda v, v_lead, gap: model_accel(m, v, v_lead, gap, step_s)


def braking_needed(
    m: DriverModel, v_mps: float, v_lead_mps: float | None, gap_m: float | None, step_s: float = 0.1
) -> float:
    """Deceleration [m/s^2, >= 0] the driver applies now: ``max(0, -model_accel(...))``."""
    return max(0.0, -model_accel(m, v_mps, v_lead_mps, gap_m, step_s))


def peak_braking(
    m: DriverModel,
    v_mps: float,
    v_lead_mps: float,
    gap_m: float,
    step_s: float = 0.1,
    horizon_s: float = 60.0,
    limit: float = math.inf,
) -> float:
    """Strongest deceleration [m/s^2, >= 0] over the driver's whole reaction to a leader that
    enters at bumper gap ``gap_m`` and keeps ``v_lead_mps`` (any value above ``limit`` once it
    exceeds it, see :func:`_reaction_peak`).

    The instantaneous :func:`braking_needed` is not enough: closing in on a slower leader, the
    driver may brake harder a few steps later than at first. The reaction is simulated with
    SUMO's update (speed, then position) until the driver is hardly faster than the leader and
    its braking eases, or for ``horizon_s`` (long enough to close in from a few hundred metres:
    a driver far above the leader's speed brakes hard on arrival, whatever the entry gap).
    """
    if not math.isfinite(gap_m):
        return braking_needed(m, v_mps, None, None, step_s)
    v, gap = max(0.0, v_mps), gap_m
    # The entry step is SUMO's; the rest of the reaction is simulated in steps of at least
    # 0.1 s to bound the cost, the model evaluated over the same coarser step (holding a
    # short step's Krauss deceleration for longer would overshoot its safe speed).
    return _reaction_peak(m, v, v_lead_mps, v_lead_mps, 0.0, gap, step_s, horizon_s, limit)


def _reaction_peak(
    m: DriverModel,
    v: float,
    v_lead: float,
    v_final: float,
    lead_decel: float,
    gap: float,
    step_s: float,
    horizon_s: float,
    limit: float = math.inf,
) -> float:
    """Strongest braking of a driver reacting to a leader that enters at ``gap`` driving
    ``v_lead`` and slows at ``lead_decel`` to ``v_final`` (0: keeps its speed; < 0: speeds up
    to ``v_final``). Once it
    exceeds ``limit`` the reaction is not followed further (the answer is then some braking
    above ``limit``: enough for a yes/no against it, at a fraction of the cost)."""
    sim_dt = max(step_s, 0.1)
    accel, sim_accel = _accel_of(m, step_s), _accel_of(m, sim_dt)
    peak = previous = 0.0
    closed_steps = 0
    dt = step_s  # the entry step is SUMO's, the rest sim_dt
    settled_at = v_final + 1e-9
    speeding_up = lead_decel < 0.0  # a leader speeding up towards v_final
    # The max() and min() of the loop written as conditionals, the same values: this is the
    # guard's and the blocking margin's inner loop, run at every step of every reaction.
    for k in range(max(2, round(horizon_s / sim_dt))):
        acc = accel(v, v_lead, gap)
        braking = -acc if -acc > 0.0 else 0.0  # max(0.0, -acc), as in _Idm.follow_speed
        peak = braking if braking > peak else peak
        if peak > limit:
            break
        closed = k > 0 and v_lead <= settled_at and v <= v_lead + _CLOSED_MPS
        if closed and braking <= previous:
            break  # closing in no more and easing off: the strongest braking is behind
        # Krauss' worst-case dawdling brakes and recovers every other step, so "easing off"
        # may never be seen: no longer closing in for _SETTLED_S ends the reaction too.
        closed_steps = closed_steps + 1 if closed else 0
        if closed_steps * sim_dt >= _SETTLED_S:
            break
        previous = braking
        v += acc * dt
        v = v if v > 0.0 else 0.0
        v_next = v_lead - lead_decel * dt
        if speeding_up:
            v_lead = v_next if v_next < v_final else v_final  # min(v_final, .)
        else:
            v_lead = v_next if v_next > v_final else v_final  # max(v_final, .)
        gap += (v_lead - v) * dt
        if k == 0:
            accel, dt = sim_accel, sim_dt
    return peak


def min_entry_gap(
    m: DriverModel,
    v_mps: float,
    v_lead_mps: float,
    b_safe_mps2: float,
    step_s: float = 0.1,
    *,
    tol_m: float = 0.01,
    max_gap_m: float = 1000.0,
) -> float:
    """Smallest bumper gap [m] at which a vehicle entering ahead at ``v_lead_mps`` makes this
    driver brake no harder than ``b_safe_mps2`` over its whole reaction (:func:`peak_braking`;
    MOBIL's b_safe). ``math.inf`` if no gap up to ``max_gap_m`` does (e.g. the driver is
    above its desired speed and slows harder than that on a free road).

    The braking falls as the gap grows, so the gap is found by bisection to ``tol_m``; the
    returned gap is the safe end of the last bracket, and never below the driver's minGap.
    """
    if b_safe_mps2 < 0.0:
        return math.inf

    def instant_ok(gap: float) -> bool:
        return braking_needed(m, v_mps, v_lead_mps, gap, step_s) <= b_safe_mps2

    def peak_ok(gap: float) -> bool:
        return peak_braking(m, v_mps, v_lead_mps, gap, step_s, limit=b_safe_mps2) <= b_safe_mps2

    # The peak is at least the braking at entry, and most often equal to it: search with the
    # cheap instantaneous braking first, then go on with the peak only where it is larger.
    # Never inside the driver's minGap: there SUMO's models stop being car following (Krauss
    # brakes only at decel behind a faster leader, at emergencyDecel behind a slower one).
    lo = max(0.0, m.min_gap_m)
    gap = _smallest_ok(instant_ok, lo, tol_m, max_gap_m, max(3.0 * lo, 1.0))
    if math.isinf(gap) or peak_ok(gap):
        return gap
    # A safe-speed driver (Krauss) far faster than the entering vehicle brakes late and hard
    # from any gap: one look at the largest gap settles that before a long search.
    if not peak_ok(max_gap_m):
        return math.inf
    return _smallest_ok(peak_ok, gap, tol_m, max_gap_m, 0.02 * gap + 0.1)


def _smallest_ok(ok, lo: float, tol: float, max_x: float, first_step: float) -> float:
    """Smallest x >= lo (to ``tol``, from above) with ``ok(x)``, for ``ok`` false below some
    threshold and true above it; ``math.inf`` if ``ok(max_x)`` is false."""
    if ok(lo):
        return lo
    hi = lo + first_step
    while not ok(hi):
        lo, hi = hi, lo + 2.0 * (hi - lo) + first_step
        if hi >= max_x:
            if not ok(max_x):
                return math.inf
            hi = max_x
            break
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if ok(mid):
            hi = mid
        else:
            lo = mid
    return hi


def accepts_entry(
    m: DriverModel,
    v_mps: float,
    v_lead_mps: float,
    gap_m: float,
    b_safe_mps2: float,
    step_s: float = 0.1,
    *,
    lead_accel_mps2: float = 0.0,
    lead_final_mps: float | None = None,
) -> bool:
    """Whether a vehicle entering ahead at bumper gap ``gap_m`` and speed ``v_lead_mps`` makes
    this driver brake no harder than ``b_safe_mps2`` over its reaction (:func:`peak_braking`),
    outside its minGap (as :func:`min_entry_gap`). With ``lead_accel_mps2`` > 0 the entering
    vehicle speeds up at that rate to ``lead_final_mps`` (one that enters a faster lane
    committed to reaching its speed)."""
    if gap_m < m.min_gap_m:
        return False
    if lead_accel_mps2 <= 0.0 or lead_final_mps is None or lead_final_mps <= v_lead_mps:
        return peak_braking(m, v_mps, v_lead_mps, gap_m, step_s, limit=b_safe_mps2) <= b_safe_mps2
    v = max(0.0, v_mps)
    peak = _reaction_peak(m, v, v_lead_mps, lead_final_mps, -lead_accel_mps2, gap_m, step_s,
                          60.0, b_safe_mps2)  # fmt: skip
    return peak <= b_safe_mps2


# ---------------------------------------------------------------------- many drivers at once
class DriverArrays:
    """The parameters of many drivers as arrays, for :func:`model_accel_array` (one row per
    driver, in the order of ``models``)."""

    def __init__(self, models: Sequence[DriverModel]) -> None:
        def col(name: str) -> np.ndarray:
            return np.array([getattr(m, name) for m in models], dtype=float)

        names = [m.model for m in models]
        self.idm = np.array([n not in KRAUSS_MODELS for n in names])  # unknown: both
        self.krauss = np.array([n not in IDM_MODELS for n in names])
        self.a = col("accel_mps2")
        self.b = col("decel_mps2")
        self.emergency = col("emergency_decel_mps2")
        self.tau = col("tau_s")
        self.s0 = col("min_gap_m")
        self.delta = col("delta")
        self.v0 = col("desired_speed_mps")
        self.sigma = np.maximum(col("sigma"), 0.0)
        self.stepping = col("idm_stepping_s")
        self.two_sqrt_ab = 2.0 * np.sqrt(self.a * self.b)
        self.idm_min_decel = np.maximum(self.b, np.minimum(self.emergency, 1.5))
        self.any_idm = bool(self.idm.any())
        self.any_krauss = bool(self.krauss.any())


def _idm_follow_array(d: DriverArrays, v, v_lead, gap, step_s: float):
    iterations = np.maximum(1, (step_s / d.stepping + 0.5).astype(int))
    v0 = np.maximum(_EPS, d.v0)
    if iterations.max() == 1:  # steps up to 0.375 s: one iteration, no masks (speed)
        s_star = np.maximum(0.0, v * d.tau + v * (v - v_lead) / d.two_sqrt_ab) + d.s0
        gap = np.maximum(_EPS, gap)
        acc = d.a * (1.0 - (v / v0) ** d.delta - (s_star * s_star) / (gap * gap))
        return np.maximum(0.0, v + acc * step_s)
    h = step_s / iterations
    speed = v.copy()
    gap = gap.copy()
    for i in range(int(iterations.max())):
        active = i < iterations
        s_star = np.maximum(0.0, speed * d.tau + speed * (speed - v_lead) / d.two_sqrt_ab) + d.s0
        gap = np.maximum(_EPS, gap)
        acc = d.a * (1.0 - (speed / v0) ** d.delta - (s_star * s_star) / (gap * gap))
        new = np.maximum(0.0, speed + acc * h)
        speed = np.where(active, new, speed)
        gap = gap - np.where(active, np.maximum(0.0, (speed - v_lead) * h), 0.0)
    return speed


def _krauss_follow_array(d: DriverArrays, v, v_lead, gap, step_s: float):
    b = d.b
    g = gap - d.s0
    reduction = b * step_s
    steps = np.floor(v_lead / reduction)
    lead_brake = step_s * (steps * v_lead - reduction * steps * (steps + 1) / 2.0)
    g2 = g + lead_brake - _EPS
    bs = b * step_s
    t = d.tau
    g2_pos = np.maximum(g2, 0.0)  # (g2 < 0: stop at once, below)
    root = np.sqrt(step_s * step_s + 4.0 * (step_s * (2.0 * g2_pos / bs - t) + t * t))
    n = np.floor(0.5 - (t - root / 2.0) / step_s)
    h = 0.5 * n * (n - 1) * bs * step_s + n * bs * t
    safe = np.where(g2 < 0.0, 0.0, n * bs + (g2 - h) / (n * step_s + t))
    x = np.where(g >= 0.0, safe, np.maximum(0.0, v - d.emergency * step_s))
    orig_decel = (v - x) / step_s
    emergency = (b != d.emergency) & (orig_decel > b + _EPS)
    if emergency.any():
        lead_brake_m = 0.5 * v_lead * v_lead / b
        with np.errstate(divide="ignore", invalid="ignore"):
            b1 = 0.5 * v * v / (g + lead_brake_m)
            b2 = 0.5 * (v * v - v_lead * v_lead) / g
        need = np.where(
            (g + lead_brake_m > 0.0) & (b1 <= b), b1, np.where(g <= 0.0, d.emergency, b2)
        )
        need = np.minimum(np.maximum(_EMERGENCY_AMPLIFIER * need, b), orig_decel)
        x = np.where(emergency, np.maximum(0.0, v - need * step_s), x)
    return np.minimum(x, v + d.a * step_s)


def model_accel_array(
    d: DriverArrays,
    v_mps: np.ndarray,
    v_lead_mps: np.ndarray,
    gap_m: np.ndarray,
    step_s: float,
    dawdle: float = 1.0,
) -> np.ndarray:
    """:func:`model_accel` of many drivers at once [m/s^2], to ~1e-9 m/s^2. A driver without
    leader has ``gap_m = inf`` (its ``v_lead_mps`` is then ignored)."""
    v = np.maximum(0.0, v_mps)
    free = ~np.isfinite(gap_m)
    v_min_emergency = np.maximum(0.0, v - d.emergency * step_s)
    v_top = np.minimum(v + d.a * step_s, np.maximum(d.v0, 0.0))
    v_next = np.full_like(v, np.inf)
    if d.any_idm:
        # SUMO takes the lower of the free-road and the following speed; with a leader closer
        # than its free-road gap (1e6 m) the following speed is the lower (to ~1e-12 m/s).
        idm_safe = _idm_follow_array(
            d, v, np.where(free, d.v0, v_lead_mps), np.where(free, _FREE_GAP_M, gap_m), step_s
        )
        # SUMO's finalizeSpeed, with IDM's minNextSpeed (at least 1.5 m/s^2)
        idm_vmin = np.minimum(
            np.maximum(0.0, v - d.idm_min_decel * step_s), np.maximum(idm_safe, v_min_emergency)
        )
        idm_next = np.maximum(idm_vmin, np.minimum(v_top, idm_safe))
        v_next = np.where(d.idm, idm_next, v_next)
    if d.any_krauss:
        krauss_safe = np.where(
            free, np.inf, _krauss_follow_array(d, v, v_lead_mps, np.where(free, 0.0, gap_m), step_s)
        )
        kr_vmin = np.minimum(
            np.maximum(0.0, v - d.b * step_s), np.maximum(krauss_safe, v_min_emergency)
        )
        kr_vmax = np.maximum(kr_vmin, np.minimum(v_top, krauss_safe))
        slow = d.sigma * dawdle * np.minimum(d.a, kr_vmax) * step_s
        kr_next = np.maximum(kr_vmin, np.maximum(0.0, kr_vmax - slow))
        v_next = np.where(d.krauss, np.minimum(v_next, kr_next), v_next)
    return (v_next - v) / step_s


# ---------------------------------------------------------------------- prediction
class CarFollowingPredictor:
    """Predicts HVs with their own car-following model over a horizon, lane by lane, with their
    leaders.

    ``states``: every vehicle seen (HVs and CAVs); a vehicle's lane is the band its centre is
    in (``road.lane_of_y``). An HV (id in ``models``) follows the vehicle ahead in its lane by
    :func:`model_accel` (mean dawdling); CAVs and vehicles without a model keep their speed,
    unless ``leaders_override`` gives their front position ``s(t)`` [m] as a function of
    absolute time [s] (e.g. a CAV's planned positions). No lane changes are predicted. All
    vehicles advance together in steps of ``dt_s`` (SUMO's update: new speed, then position);
    the car-following formulas use the same step.
    """

    def __init__(
        self,
        states: Sequence[VehicleState],
        models: Mapping[str, DriverModel],
        road: RoadSection,
        now_s: float,
        horizon_s: float,
        dt_s: float = 0.2,
        leaders_override: Mapping[str, Callable[[float], float]] | None = None,
    ) -> None:
        if dt_s <= 0.0:
            raise ValueError(f"dt_s must be > 0, got {dt_s}")
        self.now_s = now_s
        self.dt_s = dt_s
        n_steps = max(1, math.ceil(horizon_s / dt_s - 1e-9))
        self.times_s = [now_s + k * dt_s for k in range(n_steps + 1)]
        self._states = {st.vehicle_id: st for st in states}
        ids = list(self._states)
        self._column = {vid: j for j, vid in enumerate(ids)}
        lane = np.array([road.lane_of(st) for st in states], int)
        length = np.array([st.length_m for st in states], dtype=float)
        s = np.array([st.s_m for st in states], dtype=float)
        v = np.array([max(0.0, st.speed_mps) for st in states], dtype=float)
        overrides = [(self._column[vid], f) for vid, f in (leaders_override or {}).items()
                     if vid in self._column]  # fmt: skip
        driven = np.array(
            [vid in models and vid not in (leaders_override or {}) for vid in ids], dtype=bool
        )
        drivers = DriverArrays([models[vid] for vid, on in zip(ids, driven, strict=True) if on])
        self._s = np.empty((n_steps + 1, len(ids)))
        self._v = np.empty((n_steps + 1, len(ids)))
        self._s[0], self._v[0] = s, v
        for k in range(1, n_steps + 1):
            s, v = self._step(s, v, lane, length, driven, drivers, overrides, self.times_s[k])
            self._s[k], self._v[k] = s, v
        self._simulated = [vid for vid, on in zip(ids, driven, strict=True) if on]
        self._simulated_set = frozenset(self._simulated)

    def _step(self, s, v, lane, length, driven, drivers, overrides, t_s: float):
        """Positions and speeds one step later (time ``t_s``)."""
        dt = self.dt_s
        v_next = v.copy()
        if driven.any():
            # Leader: the next vehicle ahead in the same lane, at the start of the step.
            order = np.lexsort((s, lane))
            leader = np.full(len(s), -1)
            same_lane = lane[order[1:]] == lane[order[:-1]]
            leader[order[:-1][same_lane]] = order[1:][same_lane]
            lead = leader[driven]
            has_lead = lead >= 0
            safe_lead = np.where(has_lead, lead, 0)
            gap = np.where(has_lead, s[safe_lead] - length[safe_lead] - s[driven], np.inf)
            acc = model_accel_array(drivers, v[driven], v[safe_lead], gap, dt, dawdle=0.5)
            v_next[driven] = np.maximum(0.0, v[driven] + acc * dt)
        s_next = s + v_next * dt
        for j, position in overrides:
            s_next[j] = position(t_s)
            v_next[j] = max(0.0, (s_next[j] - s[j]) / dt)
        return s_next, v_next

    @property
    def simulated_ids(self) -> list[str]:
        """Ids of the HVs predicted by their car-following model."""
        return list(self._simulated)

    def _s_at(self, j: int, t_s: float) -> float:
        times = self.times_s
        if t_s <= times[0]:
            return float(self._s[0, j] + self._v[0, j] * (t_s - times[0]))
        if t_s >= times[-1]:
            return float(self._s[-1, j] + self._v[-1, j] * (t_s - times[-1]))
        k = bisect.bisect_right(times, t_s) - 1
        w = (t_s - times[k]) / (times[k + 1] - times[k])
        return float(self._s[k, j] + w * (self._s[k + 1, j] - self._s[k, j]))

    def _v_at(self, j: int, t_s: float) -> float:
        times = self.times_s
        if t_s <= times[0]:
            return float(self._v[0, j])
        if t_s >= times[-1]:
            return float(self._v[-1, j])
        # The speed of step k + 1 is the one driven between times k and k + 1 (Euler).
        k = bisect.bisect_left(times, t_s) - 1
        return float(self._v[k + 1, j])

    def predict(self, hv: VehicleState, now_s: float, t_s: float) -> VehicleState:
        """State of ``hv`` at ``t_s``: the simulated displacement from ``now_s`` to ``t_s``
        added to ``hv``'s position (lane kept). An id not simulated: constant speed."""
        j = self._column.get(hv.vehicle_id)
        if j is None or hv.vehicle_id not in self._simulated_set:
            s, v, acc = hv.s_m + hv.speed_mps * (t_s - now_s), hv.speed_mps, hv.accel_mps2
        else:
            s = hv.s_m + (self._s_at(j, t_s) - self._s_at(j, now_s))
            v = self._v_at(j, t_s)
            acc = (v - self._v_at(j, t_s - self.dt_s)) / self.dt_s
        # built directly (dataclasses.replace costs more than the prediction: a plan asks for
        # every HV at every step of its horizon)
        return VehicleState(
            hv.vehicle_id, s, hv.lane, hv.lat_m, v, hv.length_m, acc, hv.is_cav, hv.width_m
        )

    def error_against(self, actual: Mapping[str, VehicleState], t_s: float) -> dict[str, float]:
        """Position error [m] of each simulated HV at ``t_s``: predicted minus ``actual``."""
        return {
            vid: self._s_at(self._column[vid], t_s) - actual[vid].s_m
            for vid in self._simulated
            if vid in actual
        }


# ---------------------------------------------------------------------- blocking
def peak_braking_behind_slowing(
    m: DriverModel,
    v_mps: float,
    v_lead_mps: float,
    v_final_mps: float,
    lead_decel_mps2: float,
    gap_m: float,
    step_s: float = 0.1,
    horizon_s: float = 20.0,
    limit: float = math.inf,
) -> float:
    """Strongest deceleration [m/s^2, >= 0] of this driver behind a leader that enters at
    bumper gap ``gap_m`` driving ``v_lead_mps`` and then slows at ``lead_decel_mps2`` to
    ``v_final_mps`` (a blocker: it matches the lane's speed, then brings the lane down to the
    swarm's speed gently); any value above ``limit`` once it exceeds it."""
    v_lead = max(0.0, v_lead_mps)
    final = min(v_final_mps, v_lead)
    return _reaction_peak(
        m, max(0.0, v_mps), v_lead, final, lead_decel_mps2, gap_m, step_s, horizon_s, limit
    )


def min_block_gap(
    m: DriverModel,
    v_mps: float,
    v_lead_mps: float,
    v_final_mps: float,
    lead_decel_mps2: float,
    b_safe_mps2: float,
    step_s: float = 0.1,
    *,
    tol_m: float = 0.05,
    max_gap_m: float = 500.0,
) -> float:
    """Smallest bumper gap [m] at which a blocker entering ahead (see
    :func:`peak_braking_behind_slowing`) makes this driver brake no harder than
    ``b_safe_mps2``; ``math.inf`` if none up to ``max_gap_m``."""

    def ok(gap: float) -> bool:
        peak = peak_braking_behind_slowing(
            m, v_mps, v_lead_mps, v_final_mps, lead_decel_mps2, gap, step_s, limit=b_safe_mps2
        )
        return peak <= b_safe_mps2

    return _smallest_ok(ok, 0.0, tol_m, max_gap_m, max(4.0 * m.min_gap_m, 1.0))
