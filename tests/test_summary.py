"""Overtake outcome flags of summary.json on hand-made trajectory tables (known answers)."""

from __future__ import annotations

import pandas as pd
import pytest

from sumo_swarm.sim.recorder import RECORD_COLUMNS
from sumo_swarm.sim.summary import overtake_progress, overtake_times_s, pass_times_s

CAVS = ("c0", "c1", "c2")
MAX_GAP_M = 25.0


def row(t: float, vid: str, s: float, lane: int = 1, edge: str = "hwy", lat: float = 0.0):
    """One sample: a 5 m vehicle; CAVs are the ids starting with "c"."""
    return {
        "time_s": float(t),
        "vehicle": vid,
        "kind": "cav" if vid.startswith("c") else "hv",
        "edge": edge,
        "lane": lane,
        "x_m": s,
        "y_m": 0.0,
        "s_m": s,
        "lat_m": lat,
        "speed_mps": 20.0,
        "accel_mps2": 0.0,
        "length_m": 5.0,
    }


def frame(rows: list[dict]) -> pd.DataFrame:
    df = pd.DataFrame.from_records(rows)
    df = df.reindex(columns=[c for c in RECORD_COLUMNS if c in df.columns])
    for col in ("kind", "vehicle", "edge"):
        df[col] = df[col].astype("category")
    return df


def platoon(t: float, head_s: float, lane: int = 1, ids=CAVS, gap_m: float = 10.0) -> list[dict]:
    """The CAVs in one lane, ``gap_m`` apart bumper to bumper, the head's front at ``head_s``."""
    return [row(t, vid, head_s - i * (5.0 + gap_m), lane) for i, vid in enumerate(ids)]


# ------------------------------------------------------------------------------------------
# completed: every CAV has been past the target once, whatever happens after


def test_completed_although_the_cavs_leave_the_road_before_the_end():
    rows = []
    for t in range(6):
        rows.append(row(t, "truck", 100.0 + 10.0 * t))
    for t in range(4):  # the platoon passes the truck, then leaves the road after t = 3
        rows += platoon(t, head_s=60.0 + 40.0 * t, lane=2)
    df = frame(rows)
    # rears 55 + 40 t, 40 + 40 t, 25 + 40 t against the truck's front 100 + 10 t (strictly ahead)
    assert pass_times_s(df, CAVS, "truck") == {"c0": 2.0, "c1": 3.0, "c2": 3.0}
    t_end, _ = overtake_times_s(df, CAVS, "truck", MAX_GAP_M)
    assert t_end == 3.0


def test_completed_although_the_target_leaves_the_road():
    rows = []
    for t in range(3):  # the truck exits at t = 3
        rows.append(row(t, "truck", 100.0 + 10.0 * t))
    for t in range(6):
        rows += platoon(t, head_s=120.0 + 20.0 * t, lane=1)
    df = frame(rows)
    # rears 115 + 20 t, 100 + 20 t, 85 + 20 t against the truck's front at 100 + 10 t
    assert overtake_times_s(df, CAVS, "truck", MAX_GAP_M)[0] == 2.0


def test_each_cav_passes_in_its_own_time_and_the_first_may_be_gone():
    rows = [row(t, "truck", 100.0 + 10.0 * t) for t in range(8)]
    rows += [row(t, "c0", 110.0 + 30.0 * t, lane=2) for t in range(3)]  # past at t = 0, exits
    rows += [row(t, "c1", 80.0 + 20.0 * t, lane=2) for t in range(8)]  # rear > truck from t = 3
    df = frame(rows)
    assert pass_times_s(df, ("c0", "c1"), "truck") == {"c0": 0.0, "c1": 3.0}
    assert overtake_times_s(df, ("c0", "c1"), "truck", MAX_GAP_M)[0] == 3.0


def test_not_completed_while_one_cav_never_passes():
    rows = [row(t, "truck", 100.0 + 10.0 * t) for t in range(5)]
    rows += [row(t, "c0", 200.0 + 20.0 * t, lane=2) for t in range(5)]
    rows += [row(t, "c1", 50.0 + 10.0 * t, lane=1) for t in range(5)]  # stays behind
    df = frame(rows)
    assert overtake_times_s(df, ("c0", "c1"), "truck", MAX_GAP_M) == (None, None)
    assert overtake_times_s(df, ("c0",), None, MAX_GAP_M) == (None, None)


def test_falling_back_after_the_pass_still_completed():
    rows = [row(t, "truck", 100.0 + 10.0 * t) for t in range(6)]
    speeds = [130.0, 150.0, 150.0, 150.0, 150.0, 150.0]  # past at t = 0 and 1, then behind
    rows += [row(t, "c0", s, lane=2) for t, s in enumerate(speeds)]
    df = frame(rows)
    t_end, t_regroup = overtake_times_s(df, ("c0",), "truck", MAX_GAP_M)
    assert t_end == 0.0
    assert t_regroup is None  # behind the truck at the end: not regrouped ahead of it


# ------------------------------------------------------------------------------------------
# regrouped: all CAVs in the head CAV's lane, consecutive, gaps within tolerance


def passing_scene(regroup_lane: int, steps: int = 8) -> list[dict]:
    """A truck in lane 1; the platoon ends up ahead of it in ``regroup_lane`` from t = 4."""
    rows = [row(t, "truck", 100.0 + 10.0 * t) for t in range(steps)]
    for t in range(steps):
        if t < 4:  # side by side beside the truck, spread over two lanes
            rows += [
                row(t, "c0", 110.0 + 20.0 * t, lane=2),
                row(t, "c1", 95.0 + 20.0 * t, lane=0),
                row(t, "c2", 70.0 + 20.0 * t, lane=2),  # its rear passes the truck at t = 4
            ]
        else:
            rows += platoon(t, head_s=210.0 + 20.0 * (t - 4), lane=regroup_lane)
    return rows


@pytest.mark.parametrize("lane", [0, 1, 2])
def test_regrouped_in_whatever_lane_the_platoon_forms(lane):
    df = frame(passing_scene(lane))
    t_end, t_regroup = overtake_times_s(df, CAVS, "truck", MAX_GAP_M)
    assert t_end == 4.0
    assert t_regroup == 4.0
    progress = overtake_progress(df, CAVS, "truck", MAX_GAP_M)
    assert list(progress["platoon"]) == [False] * 4 + [True] * 4


def test_a_vehicle_between_the_cavs_in_their_lane_breaks_the_platoon():
    rows = passing_scene(2)
    rows += [row(t, "car", 195.0 + 20.0 * (t - 4), lane=2) for t in range(4, 6)]  # 4..5
    df = frame(rows)
    progress = overtake_progress(df, CAVS, "truck", MAX_GAP_M)
    assert list(progress["platoon"]) == [False] * 6 + [True] * 2
    assert overtake_times_s(df, CAVS, "truck", MAX_GAP_M) == (4.0, 6.0)


def test_a_vehicle_on_a_ramp_beside_the_platoon_is_not_between_them():
    rows = passing_scene(0)
    # lane 0 of an on-ramp edge, its route coordinate between the platoon's tail and head
    rows += [row(t, "merger", 195.0 + 20.0 * (t - 4), lane=0, edge="ramp") for t in range(4, 8)]
    df = frame(rows)
    assert overtake_times_s(df, CAVS, "truck", MAX_GAP_M) == (4.0, 4.0)


def test_a_gap_too_wide_or_a_cav_off_the_lane_centre_is_no_platoon():
    rows = [row(t, "truck", 100.0 + 10.0 * t) for t in range(4)]
    rows += platoon(0, 200.0, lane=1, gap_m=MAX_GAP_M + 1.0)  # too far apart
    rows += platoon(1, 220.0, lane=1)
    rows += platoon(2, 240.0, lane=1)
    rows[-1]["lat_m"] = 0.8  # the tail drifts off the lane centre at t = 2
    rows += platoon(3, 260.0, lane=1)
    df = frame(rows)
    assert list(overtake_progress(df, CAVS, "truck", MAX_GAP_M)["platoon"]) == [
        False,
        True,
        False,
        True,
    ]


def test_regrouped_holds_until_the_cavs_leave_the_road():
    rows = passing_scene(1, steps=6)
    rows += [row(t, "truck", 100.0 + 10.0 * t) for t in range(6, 10)]  # the truck drives on
    df = frame(rows)
    assert overtake_times_s(df, CAVS, "truck", MAX_GAP_M) == (4.0, 4.0)


def test_the_platoon_splitting_again_before_the_end_is_not_regrouped():
    rows = passing_scene(1)
    rows = [r for r in rows if not (r["time_s"] == 7.0 and r["vehicle"] == "c1")]
    rows.append(row(7, "c1", 300.0, lane=2))  # changes lane at the end
    df = frame(rows)
    assert overtake_times_s(df, CAVS, "truck", MAX_GAP_M) == (4.0, None)


def test_the_overtake_block_describes_the_first_manoeuvre_and_lists_all_targets():
    # A second overtake, of a car met past the truck: the run is judged on the truck (the
    # first target, with the first decision time); every manoeuvre is listed.
    from sumo_swarm.core.swarming.account import (
        ManoeuvreBook,
        manoeuvres_from_events,
        overtake_outcome,
    )

    events, clock = [], [0.0]

    def event(name: str, /, **data) -> None:  # as RunContext.event: stamped with the time
        events.append({"time_s": clock[0], "event": name, **data})

    book = ManoeuvreBook(event, 1.0)
    for t_s, target in ((3.0, "truck"), (38.0, "car")):
        clock[0] = t_s
        book.start(t_s, "cells", target, ["c0", "c1"])
    listed = manoeuvres_from_events(events)
    overtake = overtake_outcome(listed, 3.0)
    assert overtake["target"] == "truck" and overtake["t_start_s"] == 3.0
    assert [m["target"] for m in listed] == ["truck", "car"]
    # the first was superseded by the second: not completed, and said why
    assert listed[0]["outcome"] == "aborted:superseded" and listed[0]["t_end_s"] == 38.0
    assert not overtake["completed"] and overtake["abort_reasons"] == {"superseded": 1}
