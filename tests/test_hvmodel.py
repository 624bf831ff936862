"""The HV model and the car-following predictor: hand-computed numbers, no SUMO."""

from __future__ import annotations

import itertools
import math
import random

import numpy as np
import pytest

from sumo_swarm.core import hvmodel
from sumo_swarm.core.grid import ConstantSpeedPredictor
from sumo_swarm.core.hvmodel import (
    CarFollowingPredictor,
    DriverArrays,
    DriverModel,
    accepts_entry,
    braking_needed,
    min_entry_gap,
    model_accel,
    model_accel_array,
    peak_braking,
)
from sumo_swarm.core.model import RoadSection, VehicleState

# a = b = 1 (so 2 sqrt(ab) = 2), T = 1 s, s0 = 2 m, delta = 4, v0 = 20 m/s
IDM = DriverModel("IDM", 1.0, 1.0, 9.0, 1.0, 2.0, 4.0, 20.0, 5.0)
# b = 1, tau = 1 s, minGap 2 m, no dawdling; steps of 1 s keep the safe speed hand-computable
KRAUSS = DriverModel("Krauss", 2.0, 1.0, 9.0, 1.0, 2.0, desired_speed_mps=20.0, sigma=0.0)
ROAD = RoadSection((3.2, 3.2))


# ---------------------------------------------------------------------- IDM
def test_idm_in_equilibrium_gap():
    # v = v_lead = 10: s* = 2 + 10 * 1 = 12 = gap -> a (1 - (10/20)^4 - 1) = -0.0625
    assert model_accel(IDM, 10.0, 10.0, 12.0, 0.1) == pytest.approx(-0.0625, abs=1e-9)
    assert braking_needed(IDM, 10.0, 10.0, 12.0, 0.1) == pytest.approx(0.0625, abs=1e-9)


def test_idm_free_road():
    # 1 - (10/20)^4 = 0.9375 (SUMO's free-road gap of 1e6 m adds ~1e-12)
    assert model_accel(IDM, 10.0, None, None, 0.1) == pytest.approx(0.9375, abs=1e-9)
    assert braking_needed(IDM, 10.0, None, None, 0.1) == 0.0
    # above v0: slows down (a (1 - 1.5^4) = -4.0625), not below the free-road bound
    assert model_accel(IDM, 30.0, None, None, 0.1) == pytest.approx(-4.0625, abs=1e-6)


def test_idm_braking_capped_at_emergency_decel():
    # v 10, v_lead 6, gap 10: s* = 2 + 10 + 10 * 4 / 2 = 32, (32 / 10)^2 = 10.24
    # -> a = 1 - 0.0625 - 10.24 = -9.3025; SUMO caps the braking at emergencyDecel 9
    assert model_accel(IDM, 10.0, 6.0, 10.0, 0.1) == pytest.approx(-9.0, abs=1e-9)
    soft = DriverModel("IDM", 1.0, 1.0, 20.0, 1.0, 2.0, 4.0, 20.0)
    assert model_accel(soft, 10.0, 6.0, 10.0, 0.1) == pytest.approx(-9.3025, abs=1e-9)


def test_idm_sumo_iterations_at_long_steps():
    # A 1 s step is integrated in 4 iterations of 0.25 s: the first gives -0.0625, later
    # ones a little less (the driver has slowed), so the mean is between -0.0625 and 0.
    acc = model_accel(IDM, 10.0, 10.0, 12.0, 1.0)
    assert -0.0625 < acc < -0.04


# ---------------------------------------------------------------------- Krauss
def test_krauss_safe_speed():
    # step 1 s, b 1 m/s^2, tau 1 s: from 4 m/s the driver covers 4 (reaction) + 3 + 2 + 1
    # = 10 m to a stop. Leader at 3 m/s brakes to a halt in 2 + 1 = 3 m. SUMO gap 7 m
    # (bumper gap 9 m - minGap 2 m): safe speed 4 m/s, so from 5 m/s: -1 m/s^2.
    assert model_accel(KRAUSS, 5.0, 3.0, 9.0, 1.0) == pytest.approx(-1.0, abs=1e-3)
    # leader stopped, SUMO gap 10 m: the same safe speed
    assert model_accel(KRAUSS, 5.0, 0.0, 12.0, 1.0) == pytest.approx(-1.0, abs=1e-3)


def test_krauss_emergency_braking():
    # From 8 m/s the safe speed 4 needs 4 m/s^2 > b: SUMO's emergency deceleration,
    # 1.2 * (8^2 - 0) / (2 * 10) = 3.84 m/s^2
    assert model_accel(KRAUSS, 8.0, 0.0, 12.0, 1.0) == pytest.approx(-3.84, abs=1e-3)


def test_krauss_dawdling():
    dawdler = DriverModel("Krauss", 2.0, 1.0, 9.0, 1.0, 2.0, desired_speed_mps=20.0, sigma=0.5)
    # free road from 10 m/s: +2 m/s, less sigma * accel = 1 m/s in the worst case
    assert model_accel(dawdler, 10.0, None, None, 1.0) == pytest.approx(1.0)
    assert model_accel(dawdler, 10.0, None, None, 1.0, dawdle=0.5) == pytest.approx(1.5)
    assert model_accel(KRAUSS, 10.0, None, None, 1.0) == pytest.approx(2.0)


# ---------------------------------------------------------------------- other models
@pytest.mark.parametrize(
    ("v", "v_lead", "gap"),
    [
        (10.0, 10.0, 12.0),
        (10.0, 6.0, 10.0),
        (20.0, 15.0, 30.0),
        (15.0, 18.0, 6.0),
        (12.0, None, None),
    ],
)
def test_unknown_model_is_the_harsher_bound(v, v_lead, gap):
    fields = {f: getattr(IDM, f) for f in IDM.__slots__ if f != "model"}
    unknown = DriverModel("W99", **fields)
    as_idm = model_accel(IDM, v, v_lead, gap, 0.1)
    as_krauss = model_accel(DriverModel("Krauss", **fields), v, v_lead, gap, 0.1)
    acc = model_accel(unknown, v, v_lead, gap, 0.1)
    assert acc == pytest.approx(min(as_idm, as_krauss))
    assert braking_needed(unknown, v, v_lead, gap, 0.1) >= max(
        braking_needed(IDM, v, v_lead, gap, 0.1),
        braking_needed(DriverModel("Krauss", **fields), v, v_lead, gap, 0.1),
    )


def test_desired_speed_on_a_lane():
    m = DriverModel(desired_speed_mps=30.0, speed_factor=1.1)
    assert m.desired_speed_on(20.0).desired_speed_mps == pytest.approx(22.0)
    assert m.desired_speed_on(33.33).desired_speed_mps == pytest.approx(30.0)


# ---------------------------------------------------------------------- entry gaps
def test_min_entry_gap_closed_form_idm():
    # v = v_lead = 10, b_safe 2: (12 / g)^2 = 1 - 0.0625 + 2 -> g = 12 / sqrt(2.9375)
    gap = min_entry_gap(IDM, 10.0, 10.0, 2.0, 0.1)
    assert gap == pytest.approx(12.0 / math.sqrt(2.9375), abs=0.011)
    assert gap >= 12.0 / math.sqrt(2.9375)  # the safe end of the bracket


@pytest.mark.parametrize("m", [IDM, KRAUSS, DriverModel(), DriverModel("Krauss", sigma=0.5)])
@pytest.mark.parametrize(("v", "v_lead"), [(20.0, 17.5), (20.0, 20.0), (17.5, 20.0), (25.0, 20.0)])
def test_min_entry_gap_brakes_exactly_b_safe(m, v, v_lead):
    step = 0.1
    m = m.desired_speed_on(25.0) if m.desired_speed_mps > 25.0 else m
    gap = min_entry_gap(m, v, v_lead, 2.0, step)
    assert math.isfinite(gap)
    assert peak_braking(m, v, v_lead, gap, step) <= 2.0
    assert braking_needed(m, v, v_lead, gap, step) <= 2.0
    assert accepts_entry(m, v, v_lead, gap, 2.0, step)
    assert gap >= m.min_gap_m
    if gap > m.min_gap_m + 0.05:
        assert peak_braking(m, v, v_lead, gap - 0.05, step) > 2.0
        assert not accepts_entry(m, v, v_lead, gap - 0.05, 2.0, step)
        # braking at the gap is b_safe, within what the 1 cm bisection leaves
        assert peak_braking(m, v, v_lead, gap, step) == pytest.approx(2.0, abs=0.05)
    else:
        # never inside minGap; there the braking jumps (Krauss: to emergencyDecel)
        assert gap == pytest.approx(m.min_gap_m, abs=0.011)
        assert not accepts_entry(m, v, v_lead, m.min_gap_m - 0.05, 2.0, step)


def test_min_entry_gap_is_monotone():
    m = DriverModel("IDM", 0.73, 1.67, 9.0, 1.2, 2.0, 4.0, 25.0)
    by_v = [min_entry_gap(m, v, 17.5, 2.0, 0.03) for v in (16.0, 18.0, 20.0, 22.0, 24.0)]
    by_lead = [min_entry_gap(m, 20.0, vl, 2.0, 0.03) for vl in (24.0, 21.0, 18.0, 15.0, 12.0)]
    by_b = [min_entry_gap(m, 20.0, 17.5, b, 0.03) for b in (4.0, 3.0, 2.0, 1.5, 1.0)]
    for gaps in (by_v, by_lead, by_b):
        assert all(a < b for a, b in itertools.pairwise(gaps)), gaps


def test_min_entry_gap_impossible():
    # Above its desired speed the IDM driver brakes 4.06 m/s^2 on a free road already.
    assert min_entry_gap(IDM, 30.0, 30.0, 2.0, 0.1) == math.inf
    assert min_entry_gap(IDM, 10.0, 10.0, -1.0, 0.1) == math.inf
    # A Krauss driver closing in at 20 m/s brakes harder than 2 m/s^2 when it arrives,
    # wherever the slow vehicle entered.
    fast = DriverModel("Krauss", 2.6, 4.5, 9.0, 1.0, 2.5, desired_speed_mps=33.0)
    assert min_entry_gap(fast, 30.0, 10.0, 2.0, 0.1) == math.inf


def test_peak_braking_sees_late_braking():
    # Entering far ahead of a much faster IDM driver: no braking at first, more on arrival.
    m = DriverModel("IDM", 1.0, 1.5, 9.0, 1.0, 2.0, 4.0, 30.0)
    assert braking_needed(m, 25.0, 10.0, 300.0, 0.1) == 0.0
    assert peak_braking(m, 25.0, 10.0, 300.0, 0.1) == pytest.approx(0.835, abs=0.01)
    assert not accepts_entry(m, 25.0, 10.0, 300.0, 0.5, 0.1)


@pytest.mark.parametrize("step_s", [0.03, 0.2, 1.0])
def test_array_version_agrees_with_model_accel(step_s):
    # The predictor's vectorised formulas against the scalar ones checked above, on drivers
    # and situations drawn widely (overlaps, emergencies, free roads, dawdlers, long steps).
    rng = random.Random(7)
    models, v, v_lead, gap = [], [], [], []
    for _ in range(2000):
        models.append(
            DriverModel(
                rng.choice(["IDM", "Krauss", "W99", "EIDM"]), rng.uniform(0.5, 3.0),
                rng.uniform(1.0, 5.0), rng.choice([9.0, 5.0, 4.5]), rng.uniform(0.5, 2.0),
                rng.uniform(1.0, 3.0), rng.uniform(2.0, 6.0), rng.uniform(10.0, 35.0),
                sigma=rng.choice([0.0, 0.5]),
            )
        )  # fmt: skip
        v.append(rng.uniform(0.0, 35.0))
        v_lead.append(rng.uniform(0.0, 35.0))
        gap.append(rng.choice([math.inf, rng.uniform(-3.0, 5.0), rng.uniform(0.0, 150.0)]))
    got = model_accel_array(
        DriverArrays(models), np.array(v), np.array(v_lead), np.array(gap), step_s, dawdle=0.5
    )
    for i, m in enumerate(models):
        lead = (v_lead[i], gap[i]) if math.isfinite(gap[i]) else (None, None)
        assert got[i] == pytest.approx(model_accel(m, v[i], *lead, step_s, dawdle=0.5), abs=1e-9)


@pytest.mark.parametrize("step_s", [0.03, 0.1, 0.5, 1.0])
def test_reaction_step_is_model_accel_bit_for_bit(step_s):
    # A simulated reaction evaluates IDM through _Idm.accel (its hot loop): the same numbers
    # as model_accel, to the last bit, overlaps and stops included.
    rng = random.Random(11)
    for _ in range(3000):
        m = DriverModel(
            "IDM", rng.uniform(0.5, 3.0), rng.uniform(1.0, 5.0), rng.choice([9.0, 4.5]),
            rng.uniform(0.5, 2.0), rng.uniform(1.0, 3.0), rng.choice([4.0, 2.0, 3.5]),
            rng.choice([rng.uniform(5.0, 40.0), 0.0]),
            idm_stepping_s=rng.choice([0.25, 0.1]),
        )  # fmt: skip
        v = rng.choice([0.0, rng.uniform(-1.0, 40.0)])
        v_lead = rng.uniform(0.0, 40.0)
        gap = rng.choice([0.0, rng.uniform(-5.0, 200.0), 1e6])
        got = hvmodel._accel_of(m, step_s)(v, v_lead, gap)
        assert got == model_accel(m, v, v_lead, gap, step_s), (m, v, v_lead, gap)


@pytest.mark.parametrize("step_s", [0.03, 0.1, 0.2, 0.5, 1.0])
@pytest.mark.parametrize("model", sorted(hvmodel.KRAUSS_MODELS))
def test_krauss_reaction_step_is_model_accel_bit_for_bit(model, step_s):
    # The same for Krauss (_Krauss.accel, written out in one function): worst-case dawdling,
    # emergency braking (a gap inside minGap, a leader far slower), stops and free road.
    rng = random.Random(12)
    for _ in range(3000):
        m = DriverModel(
            model, rng.uniform(0.5, 3.0), rng.uniform(1.0, 5.0), rng.choice([9.0, 4.5, 7.0]),
            rng.choice([1.0, rng.uniform(0.2, 2.0)]), rng.uniform(1.0, 3.0),
            desired_speed_mps=rng.choice([rng.uniform(5.0, 40.0), 0.0]),
            sigma=rng.choice([0.0, 0.5, 1.0]),
        )  # fmt: skip
        v = rng.choice([0.0, rng.uniform(-1.0, 40.0)])
        v_lead = rng.choice([0.0, rng.uniform(0.0, 40.0)])
        gap = rng.choice([0.0, m.min_gap_m, rng.uniform(-5.0, 200.0), 1e6])
        got = hvmodel._accel_of(m, step_s)(v, v_lead, gap)
        assert type(hvmodel._accel_of(m, step_s).__self__) is hvmodel._Krauss
        assert got == model_accel(m, v, v_lead, gap, step_s), (m, v, v_lead, gap)


# ---------------------------------------------------------------------- predictor
def _state(vid, s, v, lane=0, lat=0.0, is_cav=False, length=5.0):
    return VehicleState(vid, s, lane, lat, v, length, 0.0, is_cav)


def test_fast_hv_slows_behind_slow_leader_and_never_overlaps():
    m = DriverModel("IDM", 1.0, 1.5, 9.0, 1.2, 2.0, 4.0, 30.0)
    lead = _state("cav", 100.0, 15.0, is_cav=True)
    hv = _state("hv", 50.0, 25.0)
    p = CarFollowingPredictor([lead, hv], {"hv": m}, ROAD, 0.0, 30.0, 0.2)
    for k in range(151):
        t = 0.2 * k
        s_hv = p.predict(hv, 0.0, t).s_m
        assert s_hv < 100.0 + 15.0 * t - 5.0 - 1.0  # keeps more than a metre
    end = p.predict(hv, 0.0, 30.0)
    assert end.speed_mps == pytest.approx(15.0, abs=0.3)
    # at constant speed it would have driven through the leader
    assert ConstantSpeedPredictor().predict(hv, 0.0, 10.0).s_m > 100.0 + 150.0


def test_free_hv_accelerates_to_its_desired_speed():
    hv = _state("hv", 0.0, 10.0)
    p = CarFollowingPredictor([hv], {"hv": KRAUSS}, ROAD, 5.0, 20.0, 0.2)
    # Krauss without dawdling: +2 m/s^2 for 5 s, then 20 m/s
    assert p.predict(hv, 5.0, 7.0).speed_mps == pytest.approx(14.0)
    assert p.predict(hv, 5.0, 15.0).speed_mps == pytest.approx(20.0)
    assert p.predict(hv, 5.0, 25.0).speed_mps == pytest.approx(20.0)
    idm = CarFollowingPredictor([hv], {"hv": IDM}, ROAD, 5.0, 60.0, 0.2)
    assert 19.0 < idm.predict(hv, 5.0, 65.0).speed_mps <= 20.0


def test_leaders_override_is_respected():
    m = DriverModel("IDM", 1.0, 1.5, 9.0, 1.0, 2.0, 4.0, 30.0)
    cav = _state("cav", 200.0, 20.0, is_cav=True)
    hv = _state("hv", 100.0, 20.0)
    moving = CarFollowingPredictor([cav, hv], {"hv": m}, ROAD, 0.0, 30.0)
    # The plan stops the CAV where it is: the HV stops behind it.
    stopped = CarFollowingPredictor(
        [cav, hv], {"hv": m}, ROAD, 0.0, 30.0, leaders_override={"cav": lambda t: 200.0}
    )
    assert moving.predict(hv, 0.0, 30.0).s_m > 600.0
    end = stopped.predict(hv, 0.0, 30.0)
    assert end.s_m < 195.0
    assert end.speed_mps < 0.5


def test_constant_speed_fallback_and_lanes():
    m = DriverModel("IDM", 1.0, 1.5, 9.0, 1.0, 2.0, 4.0, 30.0)
    # the slow vehicle is numbered lane 0 but 2 m left of its centre: it is in lane 1
    slow = _state("slow", 80.0, 10.0, lane=0, lat=2.0)
    hv1 = _state("hv1", 50.0, 20.0, lane=1)
    hv0 = _state("hv0", 50.0, 20.0, lane=0)
    p = CarFollowingPredictor([slow, hv1, hv0], {"hv1": m, "hv0": m}, ROAD, 0.0, 10.0)
    assert sorted(p.simulated_ids) == ["hv0", "hv1"]
    assert p.predict(hv1, 0.0, 10.0).speed_mps < 12.0  # follows the slow vehicle
    assert p.predict(hv0, 0.0, 10.0).speed_mps > 20.0  # free lane
    # not simulated: constant speed
    other = _state("other", 0.0, 13.0)
    assert p.predict(other, 0.0, 4.0).s_m == pytest.approx(52.0)
    assert p.predict(slow, 0.0, 4.0).s_m == pytest.approx(120.0)


def test_predict_from_a_later_now_and_error_against():
    hv = _state("hv", 0.0, 10.0)
    p = CarFollowingPredictor([hv], {"hv": KRAUSS}, ROAD, 0.0, 10.0, 0.2)
    # Euler: after k steps the speed is 10 + 0.4 k and the position sum of those speeds * 0.2
    s_1 = sum(10.0 + 0.4 * k for k in range(1, 6)) * 0.2
    at_1 = p.predict(hv, 0.0, 1.0)
    assert at_1.s_m == pytest.approx(s_1)
    assert at_1.speed_mps == pytest.approx(12.0)
    # asked from t = 1 with the state at t = 1: the displacement from 1 to 2
    s_2 = sum(10.0 + 0.4 * k for k in range(1, 11)) * 0.2
    assert p.predict(at_1, 1.0, 2.0).s_m == pytest.approx(s_2)
    actual = {"hv": _state("hv", s_2 - 0.7, 14.0), "nobody": _state("nobody", 5.0, 1.0)}
    assert p.error_against(actual, 2.0) == {"hv": pytest.approx(0.7)}


def test_a_queue_forms_behind_a_slow_vehicle():
    # IDM behind Krauss behind a slow CAV: each follows its own leader, none overlaps.
    idm = DriverModel("IDM", 1.0, 1.5, 9.0, 1.2, 2.0, 4.0, 30.0)
    krauss = DriverModel("Krauss", 2.6, 4.5, 9.0, 1.0, 2.5, desired_speed_mps=30.0, sigma=0.5)
    cav = _state("cav", 200.0, 10.0, is_cav=True)
    hv1 = _state("hv1", 160.0, 20.0)
    hv2 = _state("hv2", 125.0, 20.0)
    p = CarFollowingPredictor([hv2, cav, hv1], {"hv1": krauss, "hv2": idm}, ROAD, 0.0, 40.0)
    for k in range(201):
        t = 0.2 * k
        s_cav = 200.0 + 10.0 * t
        s1 = p.predict(hv1, 0.0, t).s_m
        s2 = p.predict(hv2, 0.0, t).s_m
        assert s1 <= s_cav - 5.0 - 2.5 + 1e-6  # Krauss keeps its minGap
        assert s2 < s1 - 5.0
    assert p.predict(hv1, 0.0, 40.0).speed_mps == pytest.approx(10.0, abs=0.3)
    assert p.predict(hv2, 0.0, 40.0).speed_mps == pytest.approx(10.0, abs=0.3)


def _peak_by_brute_force(m, v, v_lead, gap, step_s, horizon_s=60.0):
    """The whole reaction simulated to the horizon, no early end: the strongest braking."""
    peak = 0.0
    for k in range(round(horizon_s / 0.1)):
        dt = step_s if k == 0 else 0.1
        acc = model_accel(m, v, v_lead, gap, dt)
        peak = max(peak, -acc)
        v = max(0.0, v + acc * dt)
        gap += (v_lead - v) * dt
    return peak


@pytest.mark.parametrize(
    ("v", "v_lead", "gap"), [(25.0, 14.0, 80.0), (22.0, 18.0, 30.0), (18.0, 18.0, 20.0)]
)
def test_reaction_with_worst_case_dawdling_ends_early_and_misses_nothing(v, v_lead, gap):
    # Krauss with sigma 0.5, dawdling at its worst every step, never "eases off" steadily: the
    # reaction ends once it has stopped closing in for 2 s, with the same peak as 60 s of it.
    m = DriverModel("Krauss", 2.6, 4.5, 9.0, 1.0, 2.5, desired_speed_mps=27.0, sigma=0.5)
    assert peak_braking(m, v, v_lead, gap, 0.1) == pytest.approx(
        _peak_by_brute_force(m, v, v_lead, gap, 0.1), abs=1e-9
    )


@pytest.mark.parametrize("m", [IDM, KRAUSS], ids=["IDM", "Krauss"])
def test_a_reaction_followed_until_its_bound_gives_the_same_verdict(m):
    # peak_braking(..., limit=b) stops once the braking exceeds b: the yes/no against b (what
    # accepts_entry, min_entry_gap and min_block_gap ask) is the full reaction's, and a peak
    # that stays within b is the full peak itself.
    for v, v_lead, gap, b in itertools.product(
        (8.0, 15.0, 20.0), (5.0, 12.0, 18.0), (3.0, 10.0, 25.0, 60.0), (0.5, 1.0, 2.0)
    ):
        full = peak_braking(m, v, v_lead, gap)
        cut = peak_braking(m, v, v_lead, gap, limit=b)
        assert (cut <= b) == (full <= b)
        if full <= b:
            assert cut == full
        else:
            assert b < cut <= full


def test_an_entry_speeding_up_is_judged_by_the_speeds_it_reaches():
    # SUMO's default Krauss driver at 33 m/s (b = 4.5 m/s^2, tau = 1 s, minGap 2.5 m); a CAV
    # enters 150 m ahead at 15 m/s. Keeping 15 m/s, the driver closes in at 18 m/s and brakes
    # harder than 2 m/s^2 on arrival (Krauss brakes late). Speeding up at 1.5 m/s^2 to 33 m/s,
    # the CAV lets it close in by 18 * 12 / 2 = 108 m, to 42 m at equal speeds, where Krauss'
    # safe speed -4.5 + sqrt(4.5^2 + 33^2 + 2 * 4.5 * (42 - 2.5)) = 33.8 m/s is above its speed;
    # at entry it is -4.5 + sqrt(4.5^2 + 15^2 + 2 * 4.5 * 147.5) = 35.2 m/s: it never brakes.
    krauss = DriverModel("Krauss", 2.6, 4.5, 9.0, 1.0, 2.5, desired_speed_mps=33.0, sigma=0.0)
    assert not accepts_entry(krauss, 33.0, 15.0, 150.0, 2.0, 0.1)
    assert accepts_entry(krauss, 33.0, 15.0, 150.0, 2.0, 0.1, lead_accel_mps2=1.5,
                         lead_final_mps=33.0)  # fmt: skip
    # 100 m is too close even so: 108 m of closing would end inside the minimum gap.
    assert not accepts_entry(krauss, 33.0, 15.0, 100.0, 2.0, 0.1, lead_accel_mps2=1.5,
                             lead_final_mps=33.0)  # fmt: skip
    # A "final" speed at or below the entry speed is an entry at constant speed.
    for gap in (60.0, 150.0, 400.0):
        assert accepts_entry(krauss, 33.0, 15.0, gap, 2.0, 0.1) == accepts_entry(
            krauss, 33.0, 15.0, gap, 2.0, 0.1, lead_accel_mps2=1.5, lead_final_mps=15.0
        )


@pytest.mark.parametrize("m", [IDM, KRAUSS, DriverModel("Krauss", 2.6, 4.5, 9.0, 1.0, 2.5,
                                                        desired_speed_mps=33.0)])  # fmt: skip
def test_speeding_up_never_makes_an_entry_worse(m):
    rng = random.Random(7)
    for _ in range(200):
        v, v_lead, gap = rng.uniform(5, 33), rng.uniform(0, 30), rng.uniform(3, 300)
        if accepts_entry(m, v, v_lead, gap, 2.0, 0.1):
            assert accepts_entry(m, v, v_lead, gap, 2.0, 0.1, lead_accel_mps2=1.0,
                                 lead_final_mps=v_lead + rng.uniform(0, 10))  # fmt: skip
