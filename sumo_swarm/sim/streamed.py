"""A run's trajectory table on disk, written chunk by chunk, and the summary's measures taken
from it a slice of steps at a time: what keeps the memory of a long run from growing with it.

:class:`TrajectoryFile` appends the recorder's packed chunks (whole steps each) to a Parquet file,
one row group per chunk, the name columns as dictionaries. :func:`streamed_measures` reads the
row groups back one after another and takes the same measures as
:func:`sumo_swarm.sim.summary.table_measures` takes on the whole table in memory, with the same
functions on the few rows each needs:

- the CAVs' speeds and travel times: the CAV rows of the evaluation window, kept as their
  speeds and each CAV's travel clock (:class:`~sumo_swarm.sim.metrics.TravelClock`);
- the CAVs' gaps and the smallest time to collision: the pairs of each slice (pairing is step by
  step, so a slice's pairs are the whole table's), kept as the CAVs' gaps;
- the upstream block: every vehicle at the reference step, then the rows and pairs of the
  vehicles it selected;
- the overtake's times: each CAV's first pass of the target, slice by slice; and, only if
  every CAV got past the target, a second reading for the vehicles between the CAVs (a
  platoon's intruders);
- the network's space-time speed field, cell sums merged over slices.

Each measure is taken on its own (:mod:`~sumo_swarm.sim.measured`): one that fails on a slice
stops there and is None in the summary, with its reason; the others go on.

Held in memory: a slice at a time, the upstream vehicles' rows and the speed field's cells;
the CAVs' speeds and gaps wait on disk for their statistics (``_Samples``). The hour of the
corridor under sumo-cacc (7.8 million rows, 2.9 million CAV samples) is read with 115 MB more
than the process held: ~65 MB the first slices' working set, whatever the length, and for a
moment at the end the speeds read back with numpy's variance of them, 16 bytes a CAV sample
(docs/bench/memory.md).
"""

from __future__ import annotations

import functools
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq

from sumo_swarm.core.swarming.decision import REGROUPED_GAP_FACTOR
from sumo_swarm.files import dictionary_columns
from sumo_swarm.sim import metrics
from sumo_swarm.sim.measured import MeasureErrors
from sumo_swarm.sim.metrics import EvaluationWindow
from sumo_swarm.sim.summary import TableMeasures, overtake_times_s, pass_times_s

if TYPE_CHECKING:
    from sumo_swarm.config import Scenario

# What the CAVs' own measures and the overtake's pass times read of the CAV (and target) rows.
CAV_COLUMNS = ["time_s", "vehicle", "s_m", "speed_mps"]
TRACK_COLUMNS = ["time_s", "vehicle", "s_m", "length_m"]


def _arrow_type(column: pd.Series) -> pa.DataType:
    if isinstance(column.dtype, pd.CategoricalDtype):
        return pa.dictionary(pa.int32(), pa.string())  # the same type whatever the chunk holds
    return pa.from_numpy_dtype(column.dtype)


class TrajectoryFile:
    """``path`` written one chunk (whole steps) at a time: :meth:`append`, then :meth:`close`.

    Each chunk is a file of its own in a hidden folder beside ``path`` until :meth:`close`
    copies them, a row group each, into ``path`` (a chunk in memory at a time): the rows
    written so far can be read back at any time (:meth:`slices`, a summary asked for in the
    middle of a run), and a half-written file never stands where a finished one is expected."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.parts_dir = self.path.with_name(f".{self.path.name}.{os.getpid()}.parts")
        self.parts: list[Path] = []
        self._schema: pa.Schema | None = None
        self._coded: list[str] = []  # the columns written as dictionaries (files.py)
        self.rows = 0
        self.closed = False

    @property
    def open(self) -> bool:
        """True while chunks were written and the file is not finished."""
        return bool(self.parts) and not self.closed

    def append(self, chunk: pd.DataFrame) -> None:
        if chunk.empty:
            return
        if self._schema is None:
            self.parts_dir.mkdir(parents=True, exist_ok=True)
            fields = [pa.field(c, _arrow_type(chunk[c])) for c in chunk.columns]
            # with the pandas metadata of the first chunk: the names read back as categories
            self._schema = pa.Table.from_pandas(
                chunk, schema=pa.schema(fields), preserve_index=False
            ).schema
            self._coded = dictionary_columns(chunk)
        part = self.parts_dir / f"{len(self.parts):06d}.parquet"
        table = pa.Table.from_pandas(chunk, schema=self._schema, preserve_index=False)
        pq.write_table(table, part, use_dictionary=self._coded)
        self.parts.append(part)
        self.rows += len(chunk)

    def slices(self, tail: Iterable[pd.DataFrame] = ()) -> Iterator[pd.DataFrame]:
        """The rows written so far, a chunk at a time, then ``tail`` (chunks not written):
        each slice indexed by its rows' place in the whole table."""
        if self.closed:
            return read_slices(self.path, tail)
        return _indexed([*(lambda p=p: pq.read_table(p).to_pandas() for p in self.parts),
                         *(lambda c=c: c for c in tail)])  # fmt: skip

    def close(self) -> None:
        """Copy the chunks into ``path`` (under a temporary name, then renamed into place) and
        remove them; nothing when nothing was appended."""
        if not self.open:
            return
        partial = self.path.with_name(f".{self.path.name}.{os.getpid()}.partial")
        with pq.ParquetWriter(partial, self._schema, use_dictionary=self._coded) as writer:
            for part in self.parts:
                table = pq.read_table(part, schema=self._schema)
                writer.write_table(table, row_group_size=max(1, table.num_rows))
        os.replace(partial, self.path)
        shutil.rmtree(self.parts_dir, ignore_errors=True)
        self.closed = True


def read_slices(path: Path, tail: Iterable[pd.DataFrame] = ()) -> Iterator[pd.DataFrame]:
    """The row groups of the Parquet file ``path`` (whole steps each, as
    :class:`TrajectoryFile` writes them) in order, then the ``tail`` chunks; each slice indexed
    by its rows' place in the whole table."""
    pf = pq.ParquetFile(path)
    reads = [lambda i=i: pf.read_row_group(i).to_pandas() for i in range(pf.num_row_groups)]
    return _indexed([*reads, *(lambda c=c: c for c in tail)])


def _indexed(reads: list[Callable[[], pd.DataFrame]]) -> Iterator[pd.DataFrame]:
    offset = 0
    for read in reads:
        part = read()
        part.index = pd.RangeIndex(offset, offset + len(part))
        offset += len(part)
        yield part


def _in(df: pd.DataFrame, w: EvaluationWindow) -> pd.DataFrame:
    return metrics.window(df, w)


def streamed_measures(
    slices: Callable[[], Iterator[pd.DataFrame]],
    scenario: Scenario,
    cav_ids: tuple[str, ...],
    target: str | None,
    t_start_s: float | None,
    speed_field: Callable[[pd.DataFrame], pd.DataFrame] | None = None,
    scratch_dir: Path | None = None,
) -> tuple[TableMeasures, list[pd.DataFrame]]:
    """:func:`~sumo_swarm.sim.summary.table_measures` of the table that ``slices()`` yields a
    slice of whole steps at a time (called once, or twice when the overtake's regrouping must
    be checked); also the speed field of each slice (``speed_field``, when given).
    ``scratch_dir``: where the CAVs' samples wait for their statistics (default: the system's
    temporary folder)."""
    ev = scenario.evaluation
    w = EvaluationWindow(ev.start_s, ev.end_s)
    ref_time = t_start_s if t_start_s is not None else ev.start_s
    ref_w = metrics.upstream_window(ref_time, ev.end_s)  # None: no upstream block
    paired_w = EvaluationWindow(min(ev.start_s, ref_time), ev.end_s)
    followed = set(cav_ids) | ({target} if target else set())
    excluded = {target} if target else set()

    cav = _CavSamples(ev.travel_distance_m, scratch_dir)
    passed: dict[str, float | None] = dict.fromkeys(cav_ids)
    fields: list[pd.DataFrame] = []
    ttc = _SmallestTtc()
    up = _UpstreamRows(ref_time, ref_w, ev.upstream_ranks, excluded)
    m = MeasureErrors()  # each measure on its own: one that fails stops there, the rest go on
    for part in slices():
        if speed_field is not None:
            fields.append(m.take("network.speed_field", speed_field, part))
        names = part["vehicle"].astype(str)
        m.take("overtake.times", _first_passes, passed,
               part.loc[names.isin(followed).to_numpy(), TRACK_COLUMNS], target)  # fmt: skip
        windowed = _in(part, w)
        cav_rows = windowed.loc[windowed["kind"] == metrics.CAV, CAV_COLUMNS]
        m.take("cav.speed", cav.add_speeds, cav_rows)
        m.take("cav.travel_time_s", cav.add_travel, cav_rows)

        @functools.cache
        def pairs(part: pd.DataFrame = part) -> pd.DataFrame:
            """The slice's pairs, made by the first measure that needs them (again by the next
            if that failed: each measure of the pairs fails with its own reason)."""
            return metrics.gaps(_in(part, paired_w))

        @functools.cache
        def in_window(windowed: pd.DataFrame = windowed) -> pd.DataFrame:
            return pairs().loc[pairs().index.isin(windowed.index)]

        m.take("cav.gap", lambda: cav.add_pairs(_of_kind(in_window(), metrics.CAV)))
        m.take("safety.min_ttc_s", lambda: ttc.add(in_window()))
        m.take("upstream", up.add, part, pairs)

    upstream = m.take("upstream", up.measure, target)
    t_end = t_regroup = None
    if (
        not m.failed("overtake.times")
        and target is not None
        and passed
        and all(t is not None for t in passed.values())
    ):
        # Every CAV got past the target: the regrouping needs the vehicles between the CAVs.
        t_end, t_regroup = m.take(
            "overtake.times",
            lambda: overtake_times_s(
                _between_cavs(slices(), cav_ids, followed),
                cav_ids,
                target,
                REGROUPED_GAP_FACTOR * scenario.cav.desired_gap_m,
            ),
            default=(None, None),
        )
    measures = TableMeasures(
        speed=m.take("cav.speed", cav.speed, default={}),
        gap=m.take("cav.gap", cav.gap, default={}),
        travel_time_s=m.take(
            "cav.travel_time_s", lambda: metrics.mean_travel_time_s(cav.clock.times())
        ),
        t_end_s=t_end,
        t_regrouped_s=t_regroup,
        upstream=upstream,
        min_ttc_s=None if m.failed("safety.min_ttc_s") else ttc.value(),
        errors=m.reasons,
    )
    fields = [f for f in fields if f is not None] if not m.failed("network.speed_field") else []
    return measures, fields


def _of_kind(rows: pd.DataFrame, kind: str) -> pd.DataFrame:
    return rows.loc[rows["kind"] == kind]


class _SmallestTtc:
    """The smallest finite time to collision [s] of the pairs of every slice (None: none)."""

    def __init__(self) -> None:
        self.smallest = np.inf

    def add(self, pairs: pd.DataFrame) -> None:
        ttc = pairs["ttc_s"].to_numpy(dtype=float)
        ttc = ttc[np.isfinite(ttc)]
        if ttc.size:
            self.smallest = min(self.smallest, float(ttc.min()))

    def value(self) -> float | None:
        return float(self.smallest) if np.isfinite(self.smallest) else None


class _UpstreamRows:
    """The rows and pairs the upstream block reads, gathered slice by slice: every vehicle at
    the reference step (the first at or after ``ref_time``), then the rows of the vehicles
    :func:`~sumo_swarm.sim.metrics.upstream_impact` selects there, over ``ref_w``."""

    def __init__(
        self, ref_time: float, ref_w: EvaluationWindow | None, n_rank: int, excluded: set[str]
    ) -> None:
        self.ref_time, self.ref_w, self.n_rank, self.excluded = ref_time, ref_w, n_rank, excluded
        self.rows: list[pd.DataFrame] = []
        self.pairs: list[pd.DataFrame] = []
        self.ids: set[str] | None = None  # the upstream vehicles, once the reference step is read

    def add(self, part: pd.DataFrame, pairs: Callable[[], pd.DataFrame]) -> None:
        if self.ref_w is None:
            return
        if self.ids is None:
            times = part["time_s"].to_numpy(dtype=float)
            tol = metrics.TIME_TOLERANCE_S
            later = times[times >= self.ref_time - tol]
            if later.size and self.ref_w.end_s is not None and later.min() > self.ref_w.end_s + tol:
                self.ids = set()  # the reference step comes after the window: no block
            elif later.size:
                at_ref = part[times == later.min()]
                self.rows.append(at_ref)
                self.pairs.append(pairs().loc[pairs().index.isin(at_ref.index)])
                self.ids = _upstream_ids(at_ref, self.n_rank, self.excluded)
        if self.ids:
            in_ref = _in(part, self.ref_w)
            mine = in_ref[in_ref["vehicle"].astype(str).isin(self.ids)]
            self.rows.append(mine)
            self.pairs.append(pairs().loc[pairs().index.isin(mine.index)])

    def measure(self, target: str | None) -> list:
        if not self.ids:
            return []
        return metrics.upstream_impact(
            _first_of_each_row(_concat(self.rows)),  # the reference step's rows: once
            self.ref_time,
            n_rank=self.n_rank,
            window=self.ref_w,
            behind_of="front",
            exclude=[target] if target else [],
            gap_table=_first_of_each_row(_concat(self.pairs)),
        )


class _CavSamples:
    """The CAV rows and pairs of the evaluation window, as little as their measures read: the
    speeds and gaps as samples on disk (in the table's order, read back whole for their
    statistics: the same sums as the whole table's), the CAVs seen, and each CAV's travel
    clock."""

    def __init__(self, travel_distance_m: float, scratch_dir: Path | None = None) -> None:
        self.speeds = _Samples(float, scratch_dir)
        self.vehicles: set[str] = set()
        self.clock = metrics.TravelClock(travel_distance_m)
        self.gaps = _Samples(float, scratch_dir)
        self.behind_cav = _Samples(bool, scratch_dir)

    def add_speeds(self, rows: pd.DataFrame) -> None:
        """CAV rows of a slice (whole steps, in time order): their speeds."""
        if rows.empty:
            return
        self.speeds.add(rows["speed_mps"])
        self.vehicles.update(rows["vehicle"].astype(str).unique())

    def add_travel(self, rows: pd.DataFrame) -> None:
        """CAV rows of a slice (whole steps, in time order): each CAV's travel clock."""
        if rows.empty:
            return
        rows = _as_text(rows)
        t, s = rows["time_s"].to_numpy(dtype=float), rows["s_m"].to_numpy(dtype=float)
        for vehicle, at in rows.groupby("vehicle", sort=False).indices.items():
            self.clock.add(str(vehicle), t[at], s[at])

    def add_pairs(self, pairs: pd.DataFrame) -> None:
        """CAV followers' pairs of a slice (:func:`metrics.gaps`)."""
        known = pairs[pairs["gap_m"].notna()]
        self.gaps.add(known["gap_m"])
        self.behind_cav.add(known["leader_kind"] == metrics.CAV)

    def speed(self) -> dict:
        return metrics.speed_stats(self.speeds.read(), len(self.vehicles))

    def gap(self) -> dict:
        return metrics.gap_stats(self.gaps.read(), self.behind_cav.read())


class _Samples:
    """Values of one dtype gathered a slice at a time, kept in an unnamed scratch file (in
    ``scratch_dir``, else the system's; gone when closed) until :meth:`read` gives them back
    in one array, once.

    Why not running sums: the statistics must be numpy's own over the whole array (the table
    in memory takes them so), and numpy sums in an order that changes between releases (1.26
    in blocks of 8192 values one after another, 2.4 pairwise over the whole array), so no
    running total gives the same last digits on each. Held in memory instead, the samples
    grew with the run (17 bytes a CAV sample: 50 MB of the corridor's hour under sumo-cacc,
    docs/bench/memory.md); on disk they take memory only while their statistics are taken."""

    def __init__(self, dtype: type, scratch_dir: Path | None) -> None:
        self.dtype, self.scratch_dir = np.dtype(dtype), scratch_dir
        self.count = 0
        self._file = None

    def add(self, column: pd.Series) -> None:
        values = np.ascontiguousarray(column.to_numpy(dtype=self.dtype))
        if not values.size:
            return
        if self._file is None:  # open across calls, closed by read(); never named on POSIX
            self._file = tempfile.TemporaryFile(dir=self.scratch_dir, prefix=".samples-")  # noqa: SIM115
        self._file.write(values.tobytes())
        self.count += values.size

    def read(self) -> np.ndarray:
        """Every value added, in order; the file is closed (and gone)."""
        if self._file is None:
            return np.empty(0, dtype=self.dtype)
        with self._file as f:
            self._file, count, self.count = None, self.count, 0
            f.flush()
            f.seek(0)
            return np.fromfile(f, dtype=self.dtype, count=count)


def _first_passes(passed: dict[str, float | None], track: pd.DataFrame, target: str | None) -> None:
    """Each CAV's first pass of ``target`` (:func:`pass_times_s`) from the rows of a slice of
    whole steps, for the CAVs that had not passed it in an earlier slice."""
    if target is None or track.empty:
        return
    for vehicle, t in pass_times_s(_as_text(track), tuple(passed), target).items():
        if t is not None and passed[vehicle] is None:
            passed[vehicle] = t


def _upstream_ids(at_ref: pd.DataFrame, n_rank: int, excluded: set[str]) -> set[str]:
    """The vehicles :func:`~sumo_swarm.sim.metrics.upstream_impact` (``behind_of="front"``)
    selects at the reference step ``at_ref``: behind the swarm's front, up to ``n_rank`` per
    lane, nearest first (empty: no CAV at that step)."""
    swarm = at_ref[at_ref["kind"] == metrics.CAV]
    if swarm.empty:
        return set()
    names = at_ref["vehicle"].astype(str)
    behind = at_ref[
        (at_ref["kind"] != metrics.CAV)
        & (at_ref["s_m"] < float(swarm["s_m"].max()))
        & ~names.isin(excluded)
    ]
    behind = behind.assign(vehicle_key=behind["vehicle"].astype(str)).sort_values(
        ["lane", "s_m", "vehicle_key"], ascending=[True, False, True], kind="mergesort"
    )
    ranked = behind[behind.groupby("lane").cumcount() < n_rank]
    return set(ranked["vehicle_key"])


def _concat(parts: list[pd.DataFrame], columns: list[str] | None = None) -> pd.DataFrame:
    """Slices' rows in one table, their names as text (each slice has its own categories);
    with ``columns`` and no rows, an empty table of them."""
    parts = [p for p in parts if not p.empty]
    if not parts:
        return pd.DataFrame(columns=columns or [])
    return pd.concat([_as_text(p) for p in parts])


def _first_of_each_row(df: pd.DataFrame) -> pd.DataFrame:
    return df[~df.index.duplicated()]


def _as_text(df: pd.DataFrame) -> pd.DataFrame:
    cats = [c for c in df.columns if isinstance(df[c].dtype, pd.CategoricalDtype)]
    return df.astype(dict.fromkeys(cats, object)) if cats else df


def rows_between_cavs(slices: Callable[[], Iterator[pd.DataFrame]]):
    """``rows_of`` (:data:`sumo_swarm.sim.summary.RowsOf`) of a table on disk: a reading of
    the slices for the rows :func:`overtake_times_s` needs of one manoeuvre, in its span."""
    tol = metrics.TIME_TOLERANCE_S

    def rows_of(cav_ids: tuple[str, ...], target: str, t_from_s: float, t_to_s: float):
        def spans() -> Iterator[pd.DataFrame]:
            for part in slices():
                times = part["time_s"].to_numpy(dtype=float)
                if times.size and (times[-1] < t_from_s - tol or times[0] > t_to_s + tol):
                    continue
                yield part[(times >= t_from_s - tol) & (times <= t_to_s + tol)]

        return _between_cavs(spans(), cav_ids, set(cav_ids) | {target})

    return rows_of


def _between_cavs(
    slices: Iterator[pd.DataFrame], cav_ids: tuple[str, ...], followed: set[str]
) -> pd.DataFrame:
    """The rows of the CAVs and the target, and of every vehicle between the rearmost and the
    front-most CAV at its step: all that :func:`overtake_times_s` looks at."""
    cavs = set(cav_ids)
    keep = []
    for part in slices:
        names = part["vehicle"].astype(str)
        mine = part[names.isin(cavs).to_numpy()]
        span = mine.groupby("time_s")["s_m"].agg(["min", "max"])
        others = part[~names.isin(followed).to_numpy()].join(span, on="time_s", how="inner")
        between = others[(others["s_m"] >= others["min"]) & (others["s_m"] <= others["max"])]
        keep += [part[names.isin(followed).to_numpy()], between[part.columns]]
    return _concat(keep).sort_index()
