"""The summary's measures of a table on disk, read back a slice of steps at a time
(sim/streamed.py): the numbers of the whole table in memory, in memory that does not hold the
slices read."""

from __future__ import annotations

import tracemalloc

import numpy as np
import pandas as pd
import pytest

from sumo_swarm.sim import streamed, summary
from tests.test_measures_robust import as_recorded, in_slices, measures_dict, scenario


def convoy(steps: int, cavs: int = 2) -> pd.DataFrame:
    """An HV ``h0`` at 10 m/s, then ``cavs`` CAVs behind it in one lane, 1 s steps: the CAV
    next behind the HV 17 m behind its tail, each other CAV 13 m behind the CAV ahead's tail
    (5 m long vehicles). The first CAV drives 10 m/s, every other one 8 and 12 m/s in turn
    (its recorded speed; the positions keep the gaps constant)."""
    rows = []
    for t in range(steps):
        rows.append((float(t), "h0", "hv", 100.0 + 10.0 * t, 10.0))
        s = 100.0 - 5.0 - 17.0
        for i in range(cavs):
            speed = 10.0 if i == 0 else (8.0 if t % 2 == 0 else 12.0)
            rows.append((float(t), f"c{i}", "cav", s + 10.0 * t, speed))
            s -= 5.0 + 13.0
    df = pd.DataFrame(rows, columns=["time_s", "vehicle", "kind", "s_m", "speed_mps"])
    return as_recorded(
        df.assign(edge="e0", lane=0, x_m=df["s_m"], y_m=0.0, lat_m=0.0, accel_mps2=0.0,
                  length_m=5.0, lane_pos_m=df["s_m"], width_m=1.8, lane_width_m=3.5)
    )  # fmt: skip


def test_a_table_read_in_slices_has_the_known_measures_of_the_whole_table():
    # 40 steps read 3 at a time (14 slices, the last one short): the same numbers as the table
    # in memory, exactly (the same sums in the same order), and the ones known by hand.
    df = convoy(40)
    sc = scenario(end_s=39.0, distance_m=100.0)
    cavs = ("c0", "c1")
    held = measures_dict(summary.table_measures(df, sc, cavs, None, None))
    read, _ = streamed.streamed_measures(in_slices(df, 3), sc, cavs, None, None)
    assert measures_dict(read) == held
    # c0 at 10 m/s, c1 8 and 12 in turn: mean 10, variance (20 * 0 + 20 * 4) / 40 = 2
    assert held["speed"] == {"mean_speed_mps": 10.0, "min_speed_mps": 8.0, "max_speed_mps": 12.0,
                             "speed_var_m2ps2": 2.0, "count": 2, "samples": 80}  # fmt: skip
    # c0 17 m behind h0, c1 13 m behind c0: every step
    assert held["gap"] == {"gap_mean_m": 15.0, "gap_min_m": 13.0, "gap_min_cav_m": 13.0,
                           "gap_min_hv_m": 17.0, "samples": 80}  # fmt: skip
    # 100 m at 10 m/s (the positions move 10 m/s whatever speed is recorded)
    assert held["travel_time_s"] == pytest.approx(10.0)
    # c1 at 12 m/s closes on c0 (10 m/s) at 2 m/s, 13 m behind: 6.5 s
    assert held["min_ttc_s"] == pytest.approx(6.5)
    assert held["errors"] == {}


def test_the_cav_samples_wait_on_disk_not_in_memory():
    # The speeds and gaps kept from each slice for the end's statistics go to a scratch file:
    # what the read holds from the second slice to the last does not grow with them. Held in
    # memory they took 17 bytes a sample (8 a speed, 8 a gap, 1 whom the gap is to), and as
    # views of each slice's block of every float column (the code before) several times that:
    # 170 MB of the end of the corridor's hour (docs/bench/memory.md).
    cavs = 240
    df = convoy(300, cavs=cavs)
    samples = int((df["kind"] == "cav").sum())
    sc = scenario(end_s=299.0, distance_m=100.0)
    traced: list[int] = []

    def slices():
        for part in in_slices(df, 10)():
            traced.append(tracemalloc.get_traced_memory()[0])
            yield part

    tracemalloc.start()
    try:
        read, _ = streamed.streamed_measures(
            slices, sc, tuple(f"c{i}" for i in range(cavs)), None, None
        )
    finally:
        tracemalloc.stop()
    assert read.speed["samples"] == read.gap["samples"] == samples == 72_000
    assert read.speed["mean_speed_mps"] == 10.0 and read.gap["gap_min_hv_m"] == 17.0
    # a few kB a slice (pandas' own), not the samples' 17 bytes each
    held_bytes = traced[-1] - traced[1]
    assert held_bytes < 4 * samples, held_bytes


def test_samples_come_back_from_disk_in_order_once(tmp_path):
    floats = streamed._Samples(float, tmp_path)
    flags = streamed._Samples(bool, tmp_path)
    assert floats.read().tolist() == [] and floats.read().dtype == float
    for values in ([0.5, -1.0, np.nan], [], [np.inf, 2.0]):
        floats.add(pd.Series(values, dtype=float))
        flags.add(pd.Series([v == 2.0 for v in values], dtype=bool))
    assert floats.count == 5 and list(tmp_path.iterdir()) == []  # an unnamed file
    back = floats.read()
    assert np.array_equal(back, [0.5, -1.0, np.nan, np.inf, 2.0], equal_nan=True)
    assert flags.read().tolist() == [False, False, False, False, True]
    assert floats.count == 0 and floats.read().tolist() == []  # given back once
