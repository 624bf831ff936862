"""TTC conflicts counted from the run's steps (sim/conflicts.py): hand-made pairs with known
counts, given at once or a few steps at a time."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from sumo_swarm.sim.conflicts import TtcConflictCounter

INF = math.inf


def pairs(rows: list[tuple[float, str, str | None, float]]) -> pd.DataFrame:
    """metrics.gaps' columns the counter reads: (time_s, vehicle, leader, ttc_s)."""
    return pd.DataFrame(rows, columns=["time_s", "vehicle", "leader", "ttc_s"])


def as_categories(table: pd.DataFrame) -> pd.DataFrame:
    """The names as metrics.gaps gives them: categories, the leaders on the vehicles' ones (a
    batch's categories differ from the next one's)."""
    names = sorted({*table["vehicle"], *table["leader"].dropna()})
    kind = pd.CategoricalDtype(names)
    return table.astype({"vehicle": kind, "leader": kind})


def counted(table: pd.DataFrame, batch_steps: int | None = None, **kw) -> int:
    text = _counted(table, batch_steps, **kw)
    coded = _counted(table, batch_steps, categories=True, **kw)
    assert coded == text  # names as categories or as text: the same count
    return text


def _counted(table, batch_steps, categories=False, **kw) -> int:
    prepare = as_categories if categories else (lambda x: x)
    counter = TtcConflictCounter(**kw)
    if batch_steps is None:
        counter.add(prepare(table))
    else:
        times = np.unique(table["time_s"])
        for lo in range(0, len(times), batch_steps):
            counter.add(prepare(table[table["time_s"].isin(times[lo : lo + batch_steps])]))
    return counter.events


def steps(t0: float, t1: float, dt: float = 0.5) -> list[float]:
    return [float(t) for t in np.arange(t0, t1 + 1e-9, dt)]


# b follows a for 20 s; its TTC dips below 1.5 s twice (at 3 s and at 12 s): one encounter
DIPS = pairs(
    [(t, "b", "a", 1.0 if t in (3.0, 12.0) else 4.0) for t in steps(0.0, 20.0)]
    + [(t, "a", None, math.nan) for t in steps(0.0, 20.0)]
)


@pytest.mark.parametrize("batch", [None, 1, 3, 7])
def test_an_encounter_counts_once_however_often_its_ttc_dips(batch):
    assert counted(DIPS, batch) == 1


@pytest.mark.parametrize("batch", [None, 1, 4])
def test_a_pair_that_meets_again_after_the_extra_time_is_a_new_encounter(batch):
    # b behind a from 0 to 4 s and again from 10.5 s (6.5 s apart > 5 s), below 1.5 s in both;
    # c behind d from 0 to 4 s and again from 8 s (4 s apart): one encounter
    rows = [(t, "b", "a", 1.2) for t in [*steps(0.0, 4.0), *steps(10.5, 14.0)]]
    rows += [(t, "c", "d", 1.2 if t < 1.0 else 3.0) for t in steps(0.0, 4.0)]
    rows += [(t, "c", "d", 0.8) for t in steps(8.0, 14.0)]
    table = pairs(rows).sort_values("time_s", kind="stable")
    assert counted(table, batch) == 3


def test_only_ttc_below_the_threshold_counts():
    table = pairs(
        [(t, "b", "a", 1.5) for t in steps(0.0, 5.0)]  # at the threshold: not below
        + [(t, "c", "b", INF) for t in steps(0.0, 5.0)]  # not closing in
        + [(t, "e", "d", math.nan) for t in steps(0.0, 5.0)]  # no TTC
        + [(t, "g", "f", 1.49 if t == 5.0 else 9.0) for t in steps(0.0, 5.0)]
    ).sort_values("time_s", kind="stable")
    assert counted(table) == 1
    assert counted(table, threshold_s=2.0) == 2  # 1.5 is below 2 s
    assert counted(table, threshold_s=1.0) == 0


def test_direction_matters_and_no_leader_is_no_pair():
    # b behind a, then (after a lane change) a behind b: two pairs, two encounters
    table = pairs([(0.0, "b", "a", 1.0), (0.5, "a", "b", 1.0), (1.0, "x", None, math.nan)])
    assert counted(table) == 2
    assert counted(pairs([(0.0, "x", None, math.nan)])) == 0
    assert counted(pairs([])) == 0


def test_memory_holds_only_the_pairs_that_may_go_on():
    counter = TtcConflictCounter()
    for k in range(200):  # a new pair every second, each seen once, each a conflict
        counter.add(pairs([(float(k), f"f{k}", f"l{k}", 1.0)]))
    assert counter.events == 200
    assert len(counter._open) <= 6  # the pairs seen in the last 5 s (extra time)
