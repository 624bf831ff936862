"""Metrics on hand-made trajectory tables, checked against numbers worked out by hand."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from sumo_swarm.core import stats
from sumo_swarm.errors import ConfigError
from sumo_swarm.sim import metrics
from sumo_swarm.sim.metrics import EvaluationWindow
from sumo_swarm.sim.recorder import RECORD_COLUMNS

COLUMNS = list(RECORD_COLUMNS)  # the table sumo-swarm records


def table(rows: list[tuple]) -> pd.DataFrame:
    """Trajectory table from ``(time_s, vehicle, kind, lane, s_m, speed_mps[, accel, length])``.

    Acceleration defaults to 0 and length to 5 m; the columns no metric reads get dummies.
    """
    records = []
    for row in rows:
        t, vid, kind, lane, s, v, *rest = row
        accel = rest[0] if len(rest) > 0 else 0.0
        length = rest[1] if len(rest) > 1 else 5.0
        records.append(
            {
                "time_s": float(t),
                "vehicle": vid,
                "kind": kind,
                "edge": "e0",
                "lane": lane,
                "x_m": float(s),
                "y_m": 3.0 * lane,
                "s_m": float(s),
                "lat_m": 0.0,
                "speed_mps": float(v),
                "accel_mps2": float(accel),
                "length_m": float(length),
            }
        )
    return pd.DataFrame.from_records(records, columns=COLUMNS)


def constant_speed(vid: str, kind: str, lane: int, s0: float, v: float, steps: int) -> list[tuple]:
    """One sample per second for ``steps`` seconds of a vehicle at constant speed."""
    return [(t, vid, kind, lane, s0 + v * t, v) for t in range(steps + 1)]


def row_of(df: pd.DataFrame, t: float, vid: str) -> pd.Series:
    match = df[(df["time_s"] == t) & (df["vehicle"] == vid)]
    assert len(match) == 1
    return match.iloc[0]


# ------------------------------------------------------------------------------------------
# window


def test_window_bounds_are_inclusive_and_tolerate_float_time_stamps():
    df = table([(t, "a", "cav", 0, 0.0, 1.0) for t in (0.0, 1.0, 2.0, 3.0)])
    df.loc[2, "time_s"] = 2.0000000000000004  # what 0.1 * 20 looks like after summing steps
    picked = metrics.window(df, EvaluationWindow(1.0, 2.0))
    assert list(picked.index) == [1, 2]
    assert len(metrics.window(df, EvaluationWindow(start_s=2.5))) == 1
    assert len(metrics.window(df, EvaluationWindow(end_s=0.0))) == 1
    assert metrics.window(df, None) is df
    assert metrics.window(df, EvaluationWindow(0.0, 3.0)) is df  # every row: no copy
    assert metrics.window(df, EvaluationWindow(0.5, 3.0)) is not df


def test_window_ending_before_it_starts_is_rejected():
    with pytest.raises(ConfigError, match="before it starts"):
        EvaluationWindow(5.0, 4.0)
    with pytest.raises(ConfigError):
        EvaluationWindow(float("nan"), 4.0)


# ------------------------------------------------------------------------------------------
# mobility


def test_cav_speed_stats_over_all_cav_samples():
    df = table(
        [
            (0, "a", "cav", 0, 0, 10.0),
            (1, "a", "cav", 0, 10, 12.0),
            (0, "b", "cav", 1, 0, 14.0),
            (1, "b", "cav", 1, 14, 16.0),
            (0, "h", "hv", 0, 50, 30.0),  # HVs do not count
        ]
    )
    stats = metrics.cav_speed_stats(df)
    # samples 10, 12, 14, 16: mean 13, deviations -3 -1 1 3, population variance 20 / 4
    assert stats == {
        "mean_speed_mps": pytest.approx(13.0),
        "min_speed_mps": pytest.approx(10.0),
        "max_speed_mps": pytest.approx(16.0),
        "speed_var_m2ps2": pytest.approx(5.0),
        "count": 2,
        "samples": 4,
    }
    assert all(type(v) in (float, int) for v in stats.values())


def test_cav_speed_stats_window_excludes_samples():
    df = table(
        [
            (0, "a", "cav", 0, 0, 10.0),
            (1, "a", "cav", 0, 10, 12.0),
            (0, "b", "cav", 1, 0, 14.0),
            (1, "b", "cav", 1, 14, 16.0),
        ]
    )
    stats = metrics.cav_speed_stats(df, EvaluationWindow(0.0, 0.5))
    assert stats["mean_speed_mps"] == pytest.approx(12.0)  # samples 10 and 14
    assert stats["speed_var_m2ps2"] == pytest.approx(4.0)
    assert stats["samples"] == 2


def test_cav_speed_stats_without_cav_is_none():
    df = table([(0, "h", "hv", 0, 0, 10.0)])
    stats = metrics.cav_speed_stats(df)
    assert stats["count"] == 0
    assert stats["mean_speed_mps"] is None
    assert stats["speed_var_m2ps2"] is None


@pytest.fixture
def two_cavs() -> pd.DataFrame:
    # a at 10 m/s and b at 20 m/s for 10 s, both from s = 0
    return table(
        constant_speed("a", "cav", 0, 0.0, 10.0, 10)
        + constant_speed("b", "cav", 1, 0.0, 20.0, 10)
        + constant_speed("h", "hv", 2, 0.0, 1.0, 10)
    )


def test_travel_time_is_mean_over_cavs(two_cavs):
    assert metrics.travel_times_s(two_cavs, distance_m=50.0) == {
        "a": pytest.approx(5.0),
        "b": pytest.approx(2.5),
    }
    assert metrics.travel_time_s(two_cavs, distance_m=50.0) == pytest.approx(3.75)


def test_travel_time_interpolates_between_steps(two_cavs):
    # 55 m: a between t = 5 and 6 -> 5.5 s; b between t = 2 and 3 -> 2.75 s
    assert metrics.travel_time_s(two_cavs, distance_m=55.0) == pytest.approx((5.5 + 2.75) / 2)


def test_travel_time_starts_at_each_cavs_first_sample_in_the_window(two_cavs):
    late = EvaluationWindow(2.0, None)
    assert metrics.travel_times_s(two_cavs, late, 50.0)["a"] == pytest.approx(5.0)


def test_travel_time_is_none_when_a_cav_does_not_cover_the_distance(two_cavs):
    # a covers only 100 m in the 10 s of the table
    per_cav = metrics.travel_times_s(two_cavs, distance_m=150.0)
    assert per_cav["a"] is None
    assert per_cav["b"] == pytest.approx(7.5)
    assert metrics.travel_time_s(two_cavs, distance_m=150.0) is None


@pytest.mark.parametrize("distance_m", [50.0, 55.0, 95.0, 150.0])
@pytest.mark.parametrize("cuts", [(), (3,), (1, 2, 6), (5, 6)])
def test_a_travel_clock_fed_in_pieces_gives_the_times_of_the_whole_table(
    two_cavs, distance_m, cuts
):
    # The streamed summary's clock: each CAV's track in pieces (cut at the given samples,
    # a piece may be one sample), a crossing between two pieces interpolated across them.
    clock = metrics.TravelClock(distance_m)
    cav = two_cavs[two_cavs["kind"] == "cav"]
    for lo, hi in zip((0, *cuts), (*cuts, None), strict=True):
        for v, g in cav.groupby("vehicle"):
            piece = g.iloc[lo:hi]
            clock.add(v, piece["time_s"].to_numpy(), piece["s_m"].to_numpy())
    assert clock.times() == metrics.travel_times_s(two_cavs, distance_m=distance_m)
    # by hand: a at 10 m/s, b at 20 m/s, both from s = 0 at t = 0 for 10 s
    expected = {"a": distance_m / 10.0 if distance_m <= 100 else None, "b": distance_m / 20.0}
    assert clock.times() == pytest.approx(expected)


def test_a_travel_clock_needs_a_distance():
    with pytest.raises(ConfigError, match="travel distance_m"):
        metrics.TravelClock(0.0)


def test_speed_and_gap_stats_of_arrays_are_those_of_the_table():
    assert metrics.speed_stats(np.array([10.0, 20.0, 30.0]), 2) == {
        "mean_speed_mps": 20.0, "min_speed_mps": 10.0, "max_speed_mps": 30.0,
        "speed_var_m2ps2": pytest.approx(200.0 / 3), "count": 2, "samples": 3,
    }  # fmt: skip
    assert metrics.speed_stats(np.empty(0), 0)["mean_speed_mps"] is None
    gaps = metrics.gap_stats(np.array([5.0, 2.0, 8.0]), np.array([True, False, True]))
    assert gaps == {"gap_mean_m": 5.0, "gap_min_m": 2.0, "gap_min_cav_m": 5.0,
                    "gap_min_hv_m": 2.0, "samples": 3}  # fmt: skip
    assert metrics.gap_stats(np.empty(0), np.empty(0, bool))["gap_min_m"] is None


def test_travel_time_default_distance_is_the_shortest_covered(two_cavs):
    # a covers 100 m, the shortest: a needs 10 s, b 5 s
    assert metrics.travel_time_s(two_cavs) == pytest.approx(7.5)


def test_travel_time_edge_cases(two_cavs):
    with pytest.raises(ConfigError):
        metrics.travel_time_s(two_cavs, distance_m=0.0)
    assert metrics.travel_time_s(two_cavs[two_cavs["kind"] == "hv"]) is None
    standing = table([(0, "a", "cav", 0, 5.0, 0.0), (1, "a", "cav", 0, 5.0, 0.0)])
    assert metrics.travel_time_s(standing) is None


# ------------------------------------------------------------------------------------------
# gaps


def test_gap_headway_and_ttc_of_a_follower():
    df = table(
        [
            (0, "lead", "hv", 0, 50.0, 10.0),
            (0, "follow", "cav", 0, 20.0, 15.0),
            (0, "side", "hv", 1, 30.0, 10.0),  # other lane: nobody's leader
        ]
    )
    g = metrics.gaps(df)
    follower = g.loc[1]
    assert follower["vehicle"] == "follow"
    assert follower["leader"] == "lead"
    assert follower["leader_kind"] == "hv"
    assert follower["gap_m"] == pytest.approx(25.0)  # 50 - 5 - 20
    assert follower["headway_s"] == pytest.approx(25.0 / 15.0)
    assert follower["closing_speed_mps"] == pytest.approx(5.0)
    assert follower["ttc_s"] == pytest.approx(5.0)
    for alone in (0, 2):
        assert pd.isna(g.loc[alone, "leader"])
        assert math.isnan(g.loc[alone, "gap_m"])
        assert math.isnan(g.loc[alone, "ttc_s"])


def test_gap_leader_is_the_nearest_vehicle_ahead_and_uses_its_length():
    df = table(
        [
            (0, "far", "hv", 0, 100.0, 10.0),
            (0, "truck", "hv", 0, 60.0, 10.0, 0.0, 12.0),
            (0, "me", "cav", 0, 30.0, 10.0),
        ]
    )
    g = metrics.gaps(df)
    assert g.loc[2, "leader"] == "truck"
    assert g.loc[2, "gap_m"] == pytest.approx(18.0)  # 60 - 12 - 30
    assert g.loc[1, "leader"] == "far"
    assert g.loc[1, "gap_m"] == pytest.approx(35.0)  # 100 - 5 - 60
    assert g.loc[2, "ttc_s"] == math.inf  # same speed: not closing


def test_gaps_keep_the_index_and_row_order_of_the_input():
    df = table(
        [
            (1, "b", "hv", 0, 40.0, 10.0),
            (0, "a", "cav", 0, 10.0, 10.0),
            (1, "a", "cav", 0, 20.0, 10.0),
            (0, "b", "hv", 0, 30.0, 10.0),
        ]
    )
    df.index = [30, 10, 20, 40]
    g = metrics.gaps(df)
    assert list(g.index) == [30, 10, 20, 40]
    assert list(g["vehicle"]) == ["b", "a", "a", "b"]
    assert g.loc[10, "gap_m"] == pytest.approx(15.0)  # t=0: 30 - 5 - 10
    assert g.loc[20, "gap_m"] == pytest.approx(15.0)  # t=1: 40 - 5 - 20
    assert pd.isna(g.loc[30, "leader"])


def test_gaps_of_a_long_table_are_paired_in_slices_of_whole_steps(monkeypatch):
    rows = []
    for t in range(12):  # steps in shuffled order, three vehicles, a lane change at t = 6
        for vid, lane, s in (("a", 0, 10.0), ("b", 0 if t < 6 else 1, 25.0), ("c", 1, 45.0)):
            rows.append((float((t * 5) % 12), vid, "hv", lane, s + t, 10.0 + t % 3))
    df = table(rows)
    df.index = np.arange(len(df))[::-1] * 10  # a descending, non-default index
    whole = metrics.gaps(df)
    monkeypatch.setattr(metrics, "GAPS_SLICE_ROWS", 7)  # two steps a slice
    sliced = metrics.gaps(df)
    pd.testing.assert_frame_equal(sliced, whole)
    assert list(sliced.index) == list(df.index)
    assert row_of(sliced, 0, "a")["leader"] == "b" and pd.isna(row_of(sliced, 6, "a")["leader"])


def test_gaps_of_categorical_names_are_those_of_text_names_and_stay_categorical():
    rows = []
    for t in range(4):  # a follower, its leader, a lone vehicle in the next lane, one gone
        rows += [(t, "me", "cav", 0, 10.0 + t, 12.0), (t, "lead", "hv", 0, 30.0 + t, 9.0)]
        rows += [(t, "side", "hv", 1, 20.0, 10.0)] + ([(t, "gone", "cav", 1, 50.0, 10.0)] * (t < 2))
    text = table(rows)
    cats = text.astype({"vehicle": "category", "kind": "category"})
    by_text, by_cats = metrics.gaps(text), metrics.gaps(cats)
    for col in ("vehicle", "kind", "leader", "leader_kind"):
        assert isinstance(by_cats[col].dtype, pd.CategoricalDtype)
        assert by_cats[col].astype(object).where(by_cats[col].notna(), None).tolist() == (
            by_text[col].astype(object).where(by_text[col].notna(), None).tolist()
        )
    numbers = ["gap_m", "headway_s", "closing_speed_mps", "ttc_s"]
    pd.testing.assert_frame_equal(by_cats[numbers], by_text[numbers])
    assert row_of(by_cats, 3, "me")["leader"] == "lead"
    assert row_of(by_cats, 3, "me")["leader_kind"] == "hv"
    assert row_of(by_cats, 0, "side")["leader"] == "gone"
    assert pd.isna(row_of(by_cats, 3, "side")["leader"])  # "gone" left: nobody ahead


def test_a_lane_change_changes_the_leader():
    df = table(
        [
            (0, "me", "cav", 0, 0.0, 10.0),
            (0, "slow", "hv", 0, 30.0, 8.0),
            (0, "left", "hv", 1, 50.0, 12.0),
            (1, "me", "cav", 1, 10.0, 10.0),  # changed to lane 1
            (1, "slow", "hv", 0, 38.0, 8.0),
            (1, "left", "hv", 1, 62.0, 12.0),
        ]
    )
    g = metrics.gaps(df)
    assert row_of(g, 0, "me")["leader"] == "slow"
    assert row_of(g, 0, "me")["gap_m"] == pytest.approx(25.0)
    assert row_of(g, 1, "me")["leader"] == "left"
    assert row_of(g, 1, "me")["gap_m"] == pytest.approx(47.0)  # 62 - 5 - 10
    assert pd.isna(row_of(g, 1, "slow")["leader"])  # me left its lane


def test_stopped_follower_has_infinite_headway():
    df = table([(0, "lead", "hv", 0, 20.0, 0.0), (0, "me", "hv", 0, 5.0, 0.0)])
    assert metrics.gaps(df).loc[1, "headway_s"] == math.inf


def test_gaps_require_the_length_column():
    df = table([(0, "a", "cav", 0, 0.0, 1.0)]).drop(columns="length_m")
    with pytest.raises(ConfigError, match="length_m"):
        metrics.gaps(df)


def test_cav_gap_stats_over_cav_followers_only():
    df = table(
        [
            (0, "h_lead", "hv", 0, 100.0, 10.0),
            (0, "c1", "cav", 0, 75.0, 10.0),  # gap 20 to an HV
            (0, "c2", "cav", 0, 60.0, 10.0),  # gap 10 to a CAV
            (0, "h_tail", "hv", 0, 50.0, 10.0),  # an HV follower: not counted (gap 5)
            (0, "c3", "cav", 1, 0.0, 10.0),  # no leader: not counted
            (1, "h_lead", "hv", 0, 100.0, 10.0),
            (1, "c1", "cav", 0, 80.0, 10.0),  # gap 15
        ]
    )
    stats = metrics.cav_gap_stats(df)
    assert stats == {
        "gap_mean_m": pytest.approx(15.0),
        "gap_min_m": pytest.approx(10.0),
        "gap_min_cav_m": pytest.approx(10.0),  # c2 behind c1
        "gap_min_hv_m": pytest.approx(15.0),  # c1 behind h_lead at t = 1
        "samples": 3,
    }
    assert metrics.cav_gap_stats(df, EvaluationWindow(0.5, None))["gap_mean_m"] == pytest.approx(
        15.0
    )
    assert metrics.cav_gap_stats(df, max_gap_m=16.0)["gap_mean_m"] == pytest.approx(12.5)
    assert metrics.cav_gap_stats(df[df["kind"] == "hv"])["gap_min_m"] is None


# ------------------------------------------------------------------------------------------
# gaps only between vehicles that really share a lane


def lane_row(
    vid: str,
    edge: str,
    lane: int,
    pos: float,
    *,
    lat: float = 0.0,
    width: float = 1.8,
    length: float = 5.0,
    s: float | None = None,
    t: float = 0.0,
) -> dict:
    """One sample as sumo-swarm records it: position on the lane, width, 3.2 m lanes."""
    return {
        "time_s": t,
        "vehicle": vid,
        "kind": "cav" if vid.startswith("c") else "hv",
        "edge": edge,
        "lane": lane,
        "x_m": pos,
        "y_m": 0.0,
        "s_m": pos if s is None else s,
        "lat_m": lat,
        "speed_mps": 10.0,
        "accel_mps2": 0.0,
        "length_m": length,
        "lane_pos_m": pos,
        "width_m": width,
        "lane_width_m": 3.2,
    }


def recorded(rows: list[dict]) -> pd.DataFrame:
    return pd.DataFrame.from_records(rows, columns=COLUMNS)


def test_gaps_use_the_position_on_the_lane_not_the_route_coordinate():
    # a car from a ramp: its route coordinate is off by 40 m, its lane position is SUMO's own
    df = recorded(
        [
            lane_row("merger", "main", 0, 120.0, s=80.0),
            lane_row("cav", "main", 0, 100.0),
        ]
    )
    g = metrics.gaps(df)
    assert g.loc[1, "leader"] == "merger"
    assert g.loc[1, "gap_m"] == pytest.approx(15.0)  # 120 - 5 - 100 (s_m would give -25)


def test_lanes_of_other_edges_and_junction_lanes_are_not_shared():
    df = recorded(
        [
            lane_row("ramp_car", "ramp", 0, 103.0),  # lane 0 of another edge
            lane_row("cross", ":J0_1", 0, 4.0),  # another junction lane
            lane_row("ahead", ":J0_0", 0, 12.0),
            lane_row("cav", ":J0_0", 0, 3.0),
            lane_row("cav_main", "main", 0, 100.0),
        ]
    )
    g = metrics.gaps(df)
    assert g.loc[3, "leader"] == "ahead"
    assert g.loc[3, "gap_m"] == pytest.approx(4.0)  # 12 - 5 - 3
    assert pd.isna(g.loc[4, "leader"])
    assert pd.isna(g.loc[1, "leader"])


def test_side_by_side_in_one_lane_is_no_pair():
    # sublane model: two motorcycles (0.8 m) side by side in a 3.2 m lane, overlapping in length
    df = recorded(
        [
            lane_row("m_left", "e", 0, 52.0, lat=0.8, width=0.8, length=2.2),
            lane_row("m_right", "e", 0, 51.0, lat=-0.8, width=0.8, length=2.2),
            lane_row("car", "e", 0, 60.0, lat=0.0),
            lane_row("m_behind", "e", 0, 40.0, lat=-0.8, width=0.8, length=2.2),
        ]
    )
    g = metrics.gaps(df)
    assert g.loc[1, "leader"] == "car"  # not the motorcycle beside it
    assert g.loc[1, "gap_m"] == pytest.approx(4.0)  # 60 - 5 - 51
    assert g.loc[3, "leader"] == "m_right"  # skips nobody: m_right is right ahead
    assert g.loc[3, "gap_m"] == pytest.approx(8.8)  # 51 - 2.2 - 40
    assert (g["gap_m"].dropna() >= 0).all()


def test_a_vehicle_changing_lanes_is_in_both_lanes():
    # "changer" is on lane 0 but 1.5 m to the left: its left side (1.5 + 0.9 = 2.4 m from lane
    # 0's centre) is 0.8 m past the boundary at 1.6 m; "left_lead", at lane 1's centre, has its
    # right side 0.7 m past that boundary: they overlap sideways by 0.1 m.
    df = recorded(
        [
            lane_row("changer", "e", 0, 100.0, lat=1.5),
            lane_row("left_lead", "e", 1, 110.0),
            lane_row("c_left", "e", 1, 90.0),  # behind the changer in lane 1
            lane_row("right_lead", "e", 0, 130.0),
            lane_row("c_right", "e", 0, 80.0, lat=-0.2),  # behind it in lane 0
        ]
    )
    g = metrics.gaps(df)
    assert g.loc[0, "leader"] == "left_lead"  # the nearer of its two lanes' leaders
    assert g.loc[0, "gap_m"] == pytest.approx(5.0)
    assert g.loc[2, "leader"] == "changer"
    assert g.loc[2, "gap_m"] == pytest.approx(5.0)  # 100 - 5 - 90
    assert g.loc[4, "leader"] == "changer"
    assert g.loc[4, "gap_m"] == pytest.approx(15.0)


def test_reaching_into_the_next_lane_without_touching_its_vehicle_is_no_pair():
    # 1.2 m left: its left side is 0.5 m into lane 1, the other's right side 0.7 m from the
    # boundary: 0.2 m apart sideways
    df = recorded(
        [
            lane_row("changer", "e", 0, 100.0, lat=1.2),
            lane_row("left", "e", 1, 103.0),
        ]
    )
    g = metrics.gaps(df)
    assert pd.isna(g.loc[0, "leader"])


def test_a_negative_gap_means_an_overlap():
    df = recorded(
        [
            lane_row("lead", "e", 1, 100.0, lat=0.3),
            lane_row("c0", "e", 1, 98.0, lat=-0.3),  # 3 m into the leader's rear
        ]
    )
    assert metrics.gaps(df).loc[1, "gap_m"] == pytest.approx(-3.0)
    assert metrics.cav_gap_stats(df)["gap_min_m"] == pytest.approx(-3.0)


# ------------------------------------------------------------------------------------------
# hard braking


def test_one_hard_brake_step_counts_the_vehicle_once():
    rows = [(t, "a", "cav", 0, 0.0, 10.0, -5.0 if t == 2 else 0.0) for t in range(5)]
    df = table(rows)
    assert metrics.hard_brakes(df) == 1
    events = metrics.hard_brake_events(df)
    assert len(events) == 1
    event = events.iloc[0]
    assert event["vehicle"] == "a"
    assert event["start_s"] == event["end_s"] == 2.0
    assert event["min_accel_mps2"] == -5.0
    assert event["samples"] == 1


def test_decelerating_at_exactly_the_threshold_is_not_hard_braking():
    df = table(
        [
            (0, "a", "hv", 0, 0.0, 10.0, -4.0),
            (1, "a", "hv", 0, 0.0, 10.0, -4.0000000001),  # float noise
            (0, "b", "hv", 1, 0.0, 10.0, -4.01),
        ]
    )
    assert metrics.hard_brakes(df) == 1
    assert list(metrics.hard_brake_events(df)["vehicle"]) == ["b"]
    assert metrics.hard_brakes(df, threshold_mps2=4.02) == 0


def test_hard_brake_episodes_of_one_vehicle():
    accel = [0.0, -4.5, -6.0, 0.0, -4.2, 0.0]
    df = table(
        [(t, "a", "cav", 0, 0.0, 10.0, a) for t, a in enumerate(accel)]
        + [(0, "h", "hv", 1, 0.0, 10.0, -7.0)]
    )
    events = metrics.hard_brake_events(df)
    assert list(events["vehicle"]) == ["h", "a", "a"]
    assert list(events["start_s"]) == [0.0, 1.0, 4.0]
    assert list(events["end_s"]) == [0.0, 2.0, 4.0]
    assert list(events["min_accel_mps2"]) == [-7.0, -6.0, -4.2]
    assert list(events["samples"]) == [1, 2, 1]
    assert metrics.hard_brakes(df) == 2
    assert metrics.hard_brakes(df, window=EvaluationWindow(3.0, 5.0)) == 1


def test_no_hard_brakes_in_an_empty_table():
    empty = table([]).astype({"time_s": float, "accel_mps2": float})
    assert metrics.hard_brakes(empty) == 0
    assert list(metrics.hard_brake_events(empty).columns) == [
        "vehicle",
        "kind",
        "start_s",
        "end_s",
        "min_accel_mps2",
        "samples",
    ]


# ------------------------------------------------------------------------------------------
# time to collision


def test_min_ttc_over_closing_pairs():
    df = table(
        [
            (0, "l1", "hv", 0, 45.0, 10.0),
            (0, "f1", "cav", 0, 20.0, 14.0),  # gap 20, closing 4 -> 5 s
            (0, "l2", "hv", 1, 55.0, 10.0),
            (0, "f2", "hv", 1, 20.0, 12.0),  # gap 30, closing 2 -> 15 s
            (1, "l1", "hv", 0, 55.0, 10.0),
            (1, "f1", "cav", 0, 30.0, 9.0),  # opening: no TTC
        ]
    )
    assert metrics.min_ttc_s(df) == pytest.approx(5.0)
    assert metrics.min_ttc_s(df, EvaluationWindow(1.0, 1.0)) is None


def test_min_ttc_is_none_when_never_closing_and_zero_when_overlapping():
    apart = table([(0, "l", "hv", 0, 50.0, 12.0), (0, "f", "hv", 0, 20.0, 12.0)])
    assert metrics.min_ttc_s(apart) is None
    overlap = table([(0, "l", "hv", 0, 22.0, 10.0), (0, "f", "hv", 0, 20.0, 11.0)])
    assert metrics.min_ttc_s(overlap) == 0.0
    assert metrics.min_ttc_s(table([])) is None


# ------------------------------------------------------------------------------------------
# upstream traffic


@pytest.fixture
def upstream_table() -> pd.DataFrame:
    """Two CAVs (rearmost rear at 85 m) and HVs behind them in lanes 0 and 1, t = 0, 1, 2.

    Positions stay put except h1, which closes in on c2 at t = 1; the speeds are what the
    measures read.
    """
    rows = []
    speeds = {
        "h1": (20.0, 18.0, 19.0),
        "h2": (20.0, 20.0, 19.0),
        "h3": (20.0, 20.0, 20.0),
        "k1": (16.0, 12.0, 16.0),
        "k2": (16.0, 16.0, 17.0),
    }
    for t in range(3):
        rows += [
            (t, "c1", "cav", 1, 100.0, 20.0),
            (t, "c2", "cav", 0, 90.0, 20.0),  # rear at 85
            (t, "beside", "hv", 2, 95.0, 20.0),  # alongside the swarm: not upstream
            (t, "touching", "hv", 2, 85.0, 20.0),  # front exactly at the swarm's rear: not behind
            (t, "h1", "hv", 0, 75.0 if t == 1 else 70.0, speeds["h1"][t]),
            (t, "h2", "hv", 0, 40.0, speeds["h2"][t]),
            (t, "h3", "hv", 0, 10.0, speeds["h3"][t]),
            (t, "k1", "hv", 1, 80.0, speeds["k1"][t]),
            (t, "k2", "hv", 1, 50.0, speeds["k2"][t]),
        ]
    return table(rows)


def test_upstream_ranking_and_measures(upstream_table):
    upstream = metrics.upstream_impact(upstream_table, ref_time_s=0.0, n_rank=2)
    assert [(u["lane"], u["rank"], u["vehicle"]) for u in upstream] == [
        (0, 1, "h1"),
        (0, 2, "h2"),
        (1, 1, "k1"),
        (1, 2, "k2"),
    ]
    by_id = {u["vehicle"]: u for u in upstream}
    assert set(by_id["h1"]) == {
        "lane",
        "rank",
        "vehicle",
        "undisturbed_speed_mps",
        "min_speed_mps",
        "speed_reduction_pct",
        "min_gap_m",
        "min_headway_s",
    }
    h1 = by_id["h1"]
    assert h1["undisturbed_speed_mps"] == pytest.approx(20.0)
    assert h1["min_speed_mps"] == pytest.approx(18.0)
    assert h1["speed_reduction_pct"] == pytest.approx(10.0)
    assert h1["min_gap_m"] == pytest.approx(10.0)  # t=1: 90 - 5 - 75
    assert h1["min_headway_s"] == pytest.approx(10.0 / 18.0)
    h2 = by_id["h2"]
    assert h2["speed_reduction_pct"] == pytest.approx(5.0)
    assert h2["min_gap_m"] == pytest.approx(25.0)  # t=0 and 2: 70 - 5 - 40
    assert h2["min_headway_s"] == pytest.approx(25.0 / 20.0)
    k1 = by_id["k1"]
    assert k1["undisturbed_speed_mps"] == pytest.approx(16.0)
    assert k1["speed_reduction_pct"] == pytest.approx(25.0)
    assert k1["min_gap_m"] == pytest.approx(15.0)  # to the CAV c1: 100 - 5 - 80
    assert k1["min_headway_s"] == pytest.approx(15.0 / 16.0)
    k2 = by_id["k2"]
    assert k2["speed_reduction_pct"] == 0.0  # it sped up: no reduction
    assert k2["min_headway_s"] == pytest.approx(25.0 / 17.0)
    json.dumps(upstream, allow_nan=False)


def test_upstream_window_and_undisturbed_speeds(upstream_table):
    upstream = metrics.upstream_impact(
        upstream_table,
        ref_time_s=0.0,
        window=EvaluationWindow(2.0, 2.0),
        undisturbed={"h1": 22.5},
    )
    by_id = {u["vehicle"]: u for u in upstream}
    assert len(upstream) == 5  # n_rank 5: all three of lane 0
    assert by_id["h3"]["rank"] == 3
    assert by_id["h1"]["undisturbed_speed_mps"] == pytest.approx(22.5)
    assert by_id["h1"]["min_speed_mps"] == pytest.approx(19.0)  # t=1 is outside the window
    assert by_id["h1"]["speed_reduction_pct"] == pytest.approx(3.5 / 22.5 * 100.0)
    assert by_id["k1"]["speed_reduction_pct"] == 0.0
    assert by_id["h1"]["min_gap_m"] == pytest.approx(15.0)


def test_upstream_reference_step_is_the_first_at_or_after_ref_time(upstream_table):
    upstream = metrics.upstream_impact(upstream_table, ref_time_s=0.5)
    h1 = next(u for u in upstream if u["vehicle"] == "h1")
    assert h1["undisturbed_speed_mps"] == pytest.approx(18.0)  # speed at t = 1
    assert h1["speed_reduction_pct"] == 0.0  # window t = 1..2: min 18
    assert metrics.upstream_impact(upstream_table, ref_time_s=5.0) == []
    from_start = metrics.upstream_impact(upstream_table, ref_time_s=None)
    assert from_start == metrics.upstream_impact(upstream_table, ref_time_s=0.0)


def test_upstream_without_swarm_is_empty(upstream_table):
    hvs = upstream_table[upstream_table["kind"] == "hv"]
    assert metrics.upstream_impact(hvs, ref_time_s=0.0) == []
    with pytest.raises(ConfigError):
        metrics.upstream_impact(upstream_table, ref_time_s=0.0, n_rank=0)


def test_influenced_count_per_lane(upstream_table):
    upstream = metrics.upstream_impact(upstream_table, ref_time_s=0.0)
    # reductions: lane 0 h1 10 %, h2 5 %, h3 0 %; lane 1 k1 25 %, k2 0 %
    assert metrics.influenced_count(upstream) == {0: 2, 1: 1}
    assert metrics.influenced_count(upstream, threshold_pct=7.0) == {0: 1, 1: 1}
    assert metrics.influenced_count(upstream, threshold_pct=25.0) == {0: 0, 1: 0}
    assert metrics.influenced_count([]) == {}


# ------------------------------------------------------------------------------------------
# small summaries


def test_lateral_rms():
    assert stats.lateral_rms([3.0, -4.0]) == pytest.approx(math.sqrt(12.5))
    assert stats.lateral_rms([3.0, None, float("nan"), -4.0]) == pytest.approx(math.sqrt(12.5))
    assert stats.lateral_rms([]) is None
    assert stats.lateral_rms([None]) is None


def test_summarise_ms():
    summary = stats.summarise_ms([5.0, 1.0, 3.0, 2.0, 4.0])
    # p95 interpolates: position 0.95 * 4 = 3.8 between 4 and 5
    assert summary == {
        "median": pytest.approx(3.0),
        "p95": pytest.approx(4.8),
        "max": pytest.approx(5.0),
    }
    assert stats.summarise_ms([], prefix="solve_ms_") == {
        "solve_ms_median": None,
        "solve_ms_p95": None,
        "solve_ms_max": None,
    }
    assert type(stats.summarise_ms([1.0])["max"]) is float


def test_upstream_behind_the_front_includes_vehicles_beside_the_swarm():
    # One CAV (front at 100 m, 5 m long) and, in the next lane, an HV beside it (front 98 m)
    # and one behind (front 60 m); a slow HV ahead of the CAV in its lane is excluded.
    rows = []
    for t in (0.0, 1.0):
        rows += [
            dict(time_s=t, vehicle="cav", kind="cav", lane=1, s_m=100.0 + 20 * t, speed_mps=20.0),
            dict(time_s=t, vehicle="beside", kind="hv", lane=2, s_m=98.0 + 19 * t,
                 speed_mps=20.0 - t),
            dict(time_s=t, vehicle="behind", kind="hv", lane=2, s_m=60.0 + 20 * t, speed_mps=20.0),
            dict(time_s=t, vehicle="slow", kind="hv", lane=1, s_m=99.0 + 15 * t, speed_mps=15.0),
        ]  # fmt: skip
    df = pd.DataFrame(rows).assign(length_m=5.0)
    rear = metrics.upstream_impact(df, 0.0)
    assert [r["vehicle"] for r in rear] == ["behind"]
    front = metrics.upstream_impact(df, 0.0, behind_of="front", exclude=["slow"])
    assert [(r["lane"], r["rank"], r["vehicle"]) for r in front] == [
        (2, 1, "beside"), (2, 2, "behind")
    ]  # fmt: skip
    assert front[0]["speed_reduction_pct"] == pytest.approx(5.0)  # 20 -> 19 m/s
