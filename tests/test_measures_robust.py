"""The summary's measures on tables as large and as odd as users' roads give them.

Busy networks (thousands of vehicles, hundreds of edges and lanes), names as categories with
more than 127 of them (pandas' codes then outgrow int8), random tables (hypothesis): every
measure returns plain finite numbers or None and never raises; the same table gives the same
measures with its names as categories or as text, in memory or read a slice at a time; and a
measure that fails anyway costs itself, never the summary.
"""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sumo_swarm.config import Scenario
from sumo_swarm.sim import metrics, streamed, summary
from sumo_swarm.sim.measured import MeasureErrors
from sumo_swarm.sim.recorder import RECORD_COLUMNS

NAME_COLUMNS = ("vehicle", "kind", "edge")


def as_recorded(df: pd.DataFrame) -> pd.DataFrame:
    """``df`` with the recorder's dtypes: the names as categories, the lanes int16."""
    df = df.reindex(columns=list(RECORD_COLUMNS)).copy()
    for column in NAME_COLUMNS:
        df[column] = df[column].astype("category")
    df["lane"] = df["lane"].astype("int16")
    return df


def as_text(df: pd.DataFrame) -> pd.DataFrame:
    return df.astype(dict.fromkeys(NAME_COLUMNS, object))


def in_slices(df: pd.DataFrame, steps_per_slice: int):
    """``df`` as the trajectory file gives it back: slices of whole steps, each indexed by its
    rows' place in the table, each with the categories of its own rows."""

    def slices():
        times = np.unique(df["time_s"].to_numpy())
        offset = 0
        for lo in range(0, len(times), steps_per_slice):
            keep = df["time_s"].isin(times[lo : lo + steps_per_slice]).to_numpy()
            part = as_recorded(as_text(df[keep]))
            part.index = pd.RangeIndex(offset, offset + len(part))
            offset += len(part)
            yield part

    return slices


def scenario(start_s: float = 0.0, end_s: float = 60.0, distance_m: float = 50.0) -> Scenario:
    sc = Scenario(name="t", path=None)
    ev = replace(sc.evaluation, start_s=start_s, end_s=end_s, travel_distance_m=distance_m)
    return replace(sc, evaluation=ev)


def assert_plain(value: object, where: str = "measures") -> None:
    """Plain Python values only, numbers finite: what json.dumps(allow_nan=False) takes."""
    if isinstance(value, dict):
        for k, v in value.items():
            assert isinstance(k, str), f"{where}: key {k!r}"
            assert_plain(v, f"{where}.{k}")
    elif isinstance(value, list | tuple):
        for i, v in enumerate(value):
            assert_plain(v, f"{where}[{i}]")
    elif isinstance(value, float):
        assert math.isfinite(value), f"{where} = {value}"
    else:
        assert value is None or type(value) in (int, bool, str), f"{where}: {type(value)}"


def measures_dict(m: summary.TableMeasures) -> dict:
    out = {
        "speed": m.speed,
        "gap": m.gap,
        "travel_time_s": m.travel_time_s,
        "t_end_s": m.t_end_s,
        "t_regrouped_s": m.t_regrouped_s,
        "upstream": m.upstream,
        "min_ttc_s": m.min_ttc_s,
        "errors": m.errors,
    }
    assert_plain(out)
    json.dumps(out, allow_nan=False)
    return out


# ------------------------------------------------------------------------------------------
# the root cause of the busy road: a categorical index of more than 127 names


def test_upstream_vehicles_that_never_follow_anyone_among_many_names():
    # The swarm (c0) in lane 0; "zz", behind its front in lane 1, never has anyone ahead in its
    # lane; 200 other vehicles far ahead in lane 2. Names as categories: "zz" is the 202nd.
    # pandas 3.1 groups the (empty) gaps of the upstream vehicles on an index of int8 codes
    # and a look-up of "zz" raised OverflowError (the busy road's lost summary).
    rows = []
    for t in range(3):
        rows.append((t, "c0", "cav", 0, 100.0 + 20.0 * t, 20.0))
        rows.append((t, "zz", "hv", 1, 60.0 + 18.0 * t, 18.0 - t))
        rows += [(t, f"a{i:03d}", "hv", 2, 1000.0 + 10.0 * i, 20.0) for i in range(200)]
    df = pd.DataFrame(rows, columns=["time_s", "vehicle", "kind", "lane", "s_m", "speed_mps"])
    df = df.assign(edge="e0", x_m=df["s_m"], y_m=0.0, lat_m=0.0, accel_mps2=0.0, length_m=5.0)
    df = as_recorded(df)
    assert len(df["vehicle"].cat.categories) > 127
    for table in (df, as_text(df)):
        upstream = metrics.upstream_impact(table, 0.0, behind_of="front")
        assert upstream == [
            {
                "lane": 1,
                "rank": 1,
                "vehicle": "zz",
                "undisturbed_speed_mps": 18.0,
                "min_speed_mps": 16.0,
                "speed_reduction_pct": pytest.approx(100.0 * 2.0 / 18.0),
                "min_gap_m": None,  # nobody ahead of it, ever
                "min_headway_s": None,
            }
        ]
        measures = summary.table_measures(table, scenario(), ("c0",), None, None)
        assert measures.upstream == upstream and measures.errors == {}


def test_no_upstream_block_when_the_manoeuvre_began_after_the_evaluation_window():
    # A run evaluated over its first 5 s whose swarm began to overtake at 8 s: the block is
    # empty (it raised a ConfigError, a window ending before it starts, and lost the summary).
    rows = [(t, v, k, 0, s0 + 20.0 * t, 20.0) for t in range(10)
            for v, k, s0 in (("c0", "cav", 100.0), ("h0", "hv", 50.0))]  # fmt: skip
    df = pd.DataFrame(rows, columns=["time_s", "vehicle", "kind", "lane", "s_m", "speed_mps"])
    df = as_recorded(df.assign(edge="e0", x_m=0.0, y_m=0.0, lat_m=0.0, accel_mps2=0.0,
                               length_m=5.0))  # fmt: skip
    sc = scenario(end_s=5.0)
    for measures in (
        summary.table_measures(df, sc, ("c0",), None, 8.0),
        streamed.streamed_measures(in_slices(df, 3), sc, ("c0",), None, 8.0)[0],
    ):
        assert measures.upstream == [] and measures.errors == {}
    # Nothing recorded before 7 s (the CAVs entered late): the first step, the reference, is
    # after the window too. (The streamed summary raised a KeyError; the one in memory
    # measured the vehicles outside the window: speeds None.)
    late = df[df["time_s"] >= 7.0]
    for measures in (
        summary.table_measures(late, sc, ("c0",), None, None),
        streamed.streamed_measures(in_slices(late, 3), sc, ("c0",), None, None)[0],
    ):
        assert measures.upstream == [] and measures.errors == {}
    # inside the window, the HV behind the CAV is measured
    assert [u["vehicle"] for u in summary.table_measures(df, sc, ("c0",), None, 2.0).upstream] == [
        "h0"
    ]


def test_a_step_with_a_position_on_the_lane_unknown_is_paired_on_the_route_alone():
    # Two vehicles in one lane whose route coordinate and position on the lane disagree (5 m
    # apart on the lane, 15 m on the route). At t = 1 one position on the lane is unknown:
    # that step is paired on the route, t = 0 still on the lane, whether the table holds both
    # steps or one (the streamed summary pairs a slice of steps at a time).
    df = pd.DataFrame(
        {
            "time_s": [0.0, 0.0, 1.0, 1.0],
            "vehicle": ["a", "b", "a", "b"],
            "kind": "hv",
            "edge": "e0",
            "lane": 0,
            "s_m": [10.0, 30.0, 10.0, 30.0],
            "lane_pos_m": [50.0, 60.0, np.nan, 60.0],
            "speed_mps": 10.0,
            "length_m": 5.0,
        }
    )
    whole = metrics.gaps(df)
    assert whole["gap_m"].tolist()[::2] == [5.0, 15.0]  # a behind b at t = 0 and t = 1
    assert metrics.gaps(df[df["time_s"] == 0.0])["gap_m"].tolist()[0] == 5.0


def test_travel_times_of_positions_unknown_are_none():
    df = pd.DataFrame({"time_s": [0.0, 1.0], "vehicle": "c0", "kind": "cav", "s_m": [np.nan, 20.0]})
    assert metrics.travel_times_s(df) == {"c0": None}  # no distance covered is known
    assert metrics.travel_time_s(df) is None


# ------------------------------------------------------------------------------------------
# a busy network: thousands of vehicles on hundreds of edges and lanes


def busy_network(
    vehicles: int = 3000, edges: int = 300, steps: int = 12, seed: int = 1
) -> pd.DataFrame:
    """A recorded table of a large network: each vehicle on one of ``edges`` edges of 1-5
    lanes (some change lane), some stopped, some beside each other in one lane, CAVs among
    them, a few vehicles that appear late or leave early."""
    rng = np.random.default_rng(seed)
    lanes_of = rng.integers(1, 6, size=edges)
    edge = rng.integers(0, edges, size=vehicles)
    lane = rng.integers(0, lanes_of[edge])
    s0 = rng.uniform(0.0, 400.0, size=vehicles)
    speed = np.where(rng.random(vehicles) < 0.1, 0.0, rng.uniform(2.0, 35.0, size=vehicles))
    kind = np.where(rng.random(vehicles) < 0.05, "cav", "hv")
    length = rng.choice([4.5, 5.0, 12.0], size=vehicles)
    first = np.where(rng.random(vehicles) < 0.1, rng.integers(0, steps, size=vehicles), 0)
    last = np.where(rng.random(vehicles) < 0.1, rng.integers(0, steps, size=vehicles), steps)
    last = np.maximum(first, last)
    parts = []
    for t in range(steps):
        on = (first <= t) & (t <= last)
        moved = lane + (rng.random(vehicles) < 0.02)
        parts.append(
            pd.DataFrame(
                {
                    "time_s": float(t),
                    "vehicle": [f"v{i}" for i in np.flatnonzero(on)],
                    "kind": kind[on],
                    "edge": [f"e{e}" for e in edge[on]],
                    "lane": np.minimum(moved, lanes_of[edge] - 1)[on],
                    "x_m": s0[on],
                    "y_m": 0.0,
                    "s_m": s0[on] + speed[on] * t,
                    "lat_m": rng.uniform(-0.5, 0.5, size=on.sum()),
                    "speed_mps": speed[on] + rng.normal(0.0, 0.5, size=on.sum()).clip(0),
                    "accel_mps2": rng.normal(0.0, 2.0, size=on.sum()),
                    "length_m": length[on],
                    "lane_pos_m": s0[on] + speed[on] * t,
                    "width_m": 1.8,
                    "lane_width_m": 3.2,
                }
            )
        )
    return as_recorded(pd.concat(parts, ignore_index=True))


def test_the_measures_of_a_busy_network_are_plain_and_the_same_however_read():
    df = busy_network()
    assert df["vehicle"].nunique() == 3000 and df["edge"].nunique() >= 290
    cavs = tuple(sorted(df.loc[df["kind"] == "cav", "vehicle"].astype(str).unique()))
    target = "v7"
    sc = scenario(end_s=11.0, distance_m=30.0)
    held = measures_dict(summary.table_measures(df, sc, cavs, target, 2.0))
    assert held["errors"] == {}
    assert held["speed"]["count"] == len(cavs) and held["gap"]["samples"] > 100
    assert len(held["upstream"]) == 25  # five per lane index (0-4), whatever the edge
    assert any(u["min_gap_m"] is None for u in held["upstream"])  # leaders of their lanes
    # The same table with its names as text, and read back a few steps at a time.
    text = measures_dict(summary.table_measures(as_text(df), sc, cavs, target, 2.0))
    assert text == held
    read, _ = streamed.streamed_measures(in_slices(df, 5), sc, cavs, target, 2.0)
    assert measures_dict(read) == held
    # Every measure of metrics on its own, of every kind of vehicle.
    for kind in ("cav", "hv"):
        assert_plain(metrics.cav_speed_stats(df, kind=kind))
        assert_plain(metrics.cav_gap_stats(df, kind=kind))
        assert_plain(metrics.travel_times_s(df, kind=kind))
    assert metrics.hard_brakes(df) > 0 and metrics.min_ttc_s(df) is not None


# ------------------------------------------------------------------------------------------
# random tables


@st.composite
def random_tables(draw) -> pd.DataFrame:
    """A recorded table of a few steps: any number of vehicles (up to 300 names, so that the
    codes of a categorical table outgrow int8), on any of a few edges and lanes, any positions
    (ties, overlaps), speeds (zero), accelerations, lateral offsets and widths (unknown), some
    of them NaN or infinite."""
    n_names = draw(st.integers(1, 300))
    steps = draw(st.integers(1, 5))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    rows = draw(st.integers(0, 400))
    vehicle = rng.integers(0, n_names, size=rows)
    cav_share = draw(st.sampled_from([0.0, 0.1, 0.5, 1.0]))
    is_cav = rng.random(n_names) < cav_share
    width = draw(st.sampled_from([np.nan, 1.8, 3.5]))

    def coarse(values: np.ndarray) -> np.ndarray:  # ties are common on a real road too
        return np.round(values / draw(st.sampled_from([0.5, 5.0, 50.0]))) * 5.0

    df = pd.DataFrame(
        {
            "time_s": rng.integers(0, steps, size=rows).astype(float),
            "vehicle": [f"{'c' if is_cav[v] else 'h'}{v}" for v in vehicle],
            "kind": np.where(is_cav[vehicle], "cav", "hv"),
            "edge": [f"e{e}" for e in rng.integers(0, draw(st.integers(1, 4)), size=rows)],
            "lane": rng.integers(0, draw(st.integers(1, 5)), size=rows),
            "x_m": 0.0,
            "y_m": 0.0,
            "s_m": coarse(rng.uniform(-50.0, 500.0, size=rows)),
            "lat_m": rng.uniform(-2.0, 2.0, size=rows),
            "speed_mps": rng.choice([0.0, 5.0, 20.0, 33.0], size=rows),
            "accel_mps2": rng.uniform(-9.0, 3.0, size=rows),
            "length_m": rng.choice([0.5, 5.0, 18.0], size=rows),
            "lane_pos_m": rng.uniform(0.0, 500.0, size=rows),
            "width_m": width,
            "lane_width_m": 3.2,
        }
    )
    if draw(st.booleans()):  # values SUMO could not give (a vehicle off its route, ...)
        for column in ("s_m", "speed_mps", "accel_mps2", "lat_m", "lane_pos_m"):
            df.loc[rng.random(rows) < 0.05, column] = draw(st.sampled_from([np.nan, np.inf]))
    # one row per vehicle and step, as SUMO gives them
    df = df.drop_duplicates(["time_s", "vehicle"]).sort_values("time_s", kind="mergesort")
    df = df.reset_index(drop=True)
    return as_recorded(df) if draw(st.booleans()) else df


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    df=random_tables(),
    start_s=st.sampled_from([0.0, 1.0, 3.0]),
    span_s=st.sampled_from([0.5, 2.0, 100.0]),
    t_start_s=st.sampled_from([None, 0.0, 2.0, 9.0]),
    target=st.sampled_from([None, "h1", "c2", "nobody"]),
)
def test_every_measure_of_a_random_table_is_plain_and_never_raises(
    df, start_s, span_s, t_start_s, target
):
    sc = scenario(start_s=start_s, end_s=start_s + span_s, distance_m=20.0)
    names = df["vehicle"].astype(str)
    cavs = tuple(sorted(names[df["kind"].astype(str) == "cav"].unique()))
    held = measures_dict(summary.table_measures(df, sc, cavs, target, t_start_s))
    assert held["errors"] == {}
    assert isinstance(held["upstream"], list)
    read, _ = streamed.streamed_measures(in_slices(df, 2), sc, cavs, target, t_start_s)
    assert measures_dict(read) == held
    w = metrics.EvaluationWindow(start_s, start_s + span_s)
    for kind in ("cav", "hv"):
        assert_plain(metrics.cav_speed_stats(df, w, kind=kind))
        assert_plain(metrics.cav_gap_stats(df, w, kind=kind))
        assert_plain(metrics.travel_time_s(df, w, kind=kind))
    assert_plain(metrics.min_ttc_s(df, w))
    assert_plain(metrics.hard_brakes(df, window=w))
    assert_plain(metrics.upstream_impact(df, t_start_s, window=w, behind_of="rear"))
    assert_plain(summary.pass_times_s(df, cavs, target))


# ------------------------------------------------------------------------------------------
# one failing measure costs itself


def test_a_measure_that_raises_is_none_with_its_reason_and_the_others_stay(monkeypatch):
    df = busy_network(vehicles=400, edges=20, steps=6)
    cavs = tuple(sorted(df.loc[df["kind"] == "cav", "vehicle"].astype(str).unique()))
    sc = scenario(end_s=5.0, distance_m=30.0)
    whole = measures_dict(summary.table_measures(df, sc, cavs, None, None))

    def broken(*args, **kwargs):
        raise RuntimeError("a corner nobody foresaw")

    monkeypatch.setattr(metrics, "upstream_impact", broken)
    for measures in (
        summary.table_measures(df, sc, cavs, None, None),
        streamed.streamed_measures(in_slices(df, 2), sc, cavs, None, None)[0],
    ):
        got = measures_dict(measures)
        assert got["upstream"] is None
        assert got["errors"] == {"upstream": "RuntimeError: a corner nobody foresaw"}
        assert {k: v for k, v in got.items() if k not in ("upstream", "errors")} == {
            k: v for k, v in whole.items() if k not in ("upstream", "errors")
        }
    # The pairing fails: the three measures made of the pairs, each with its reason.
    monkeypatch.setattr(metrics, "gaps", broken)
    got = measures_dict(summary.table_measures(df, sc, cavs, None, None))
    assert set(got["errors"]) == {"cav.gap", "safety.min_ttc_s", "upstream"}
    assert got["gap"] == {} and got["min_ttc_s"] is None
    assert got["speed"] == whole["speed"] and got["travel_time_s"] == whole["travel_time_s"]


def test_a_measure_taken_slice_by_slice_stops_at_its_first_failure():
    errors = MeasureErrors()
    calls = []

    def measure(x: int) -> int:
        calls.append(x)
        if x == 2:
            raise ValueError("bad slice")
        return x

    assert [errors.take("m", measure, x, default=-1) for x in (1, 2, 3)] == [1, -1, -1]
    assert calls == [1, 2]  # the third slice was not measured: the measure is already lost
    assert errors.reasons == {"m": "ValueError: bad slice"}
    assert errors.take("other", measure, 3) == 3 and errors.failed("m")


# ------------------------------------------------------------------------------------------
# the network block, from SUMO's own outputs


@settings(max_examples=40, deadline=None)
@given(
    trips=st.integers(0, 3000),
    seed=st.integers(0, 2**32 - 1),
    duration_s=st.sampled_from([0.0, 1.0, 3600.0]),
    conflicts=st.booleans(),
)
def test_the_network_block_of_any_trips_is_plain(trips, seed, duration_s, conflicts):
    # Thousands of trips of any class, departed or not, finished or not, with SUMO's values
    # unknown (NaN) here and there; the speed field of a table of thousands of vehicles.
    from sumo_swarm.sim import network

    rng = np.random.default_rng(seed)
    departed = rng.random(trips) < 0.9
    finished = departed & (rng.random(trips) < 0.7)

    def values(scale: float) -> np.ndarray:
        v = rng.uniform(0.0, scale, size=trips)
        v[rng.random(trips) < 0.05] = np.nan
        return v

    table = pd.DataFrame(
        {
            "vehicle": [f"v{i}" for i in range(trips)],
            "vtype": "DEFAULT_VEHTYPE",
            "vehicle_class": rng.choice(["cav", "hv", "truck", "bus"], size=trips),
            "departed": departed,
            "depart_s": np.where(departed, values(3600.0), np.nan),
            "depart_delay_s": values(60.0),
            "arrival_s": np.where(finished, values(3600.0), np.nan),
            "finished": finished,
            "duration_s": values(600.0),
            "route_length_m": np.where(rng.random(trips) < 0.1, 0.0, values(5000.0)),
            "time_loss_s": values(300.0),
            "waiting_time_s": values(100.0),
            "co2_mg": values(1e6),
            "fuel_mg": values(1e5),
        },
        columns=list(network.TRIP_COLUMNS),
    )
    ssm = None
    if conflicts:
        ssm = pd.DataFrame({c: [] for c in network.CONFLICT_COLUMNS})
    tables = network.NetworkTables(table, ssm, None)
    block = network.network_block(
        tables, hard_brake_events=int(rng.integers(0, 50)), duration_s=duration_s,
        ttc_threshold_s=1.5,
    )  # fmt: skip
    assert_plain(block)
    json.dumps(block, allow_nan=False)
    assert block["vehicles"] == int(departed.sum())
    df = busy_network(vehicles=max(1, trips), edges=30, steps=3, seed=seed % 1000)
    field = network.mean_speed_field([network.speed_field(df), network.speed_field(df.iloc[:0])])
    assert np.isfinite(field["speed_mps"].to_numpy(dtype=float)).all()
