"""Trajectories that SUMO writes itself: its FCD output in Parquet, made into the run's table.

A run whose controller reads nothing of the vehicles at each step (``sumo-cacc``, ``sumo-lc``:
SUMO drives every vehicle) does not read every vehicle through libsumo at every step only to
record it: SUMO writes the same quantities as its FCD output (:func:`fcd_args`), and once SUMO
has closed, :func:`fcd_chunks` turns that file into the tables the recorder packs (its columns
and dtypes: :data:`sumo_swarm.sim.recorder.RECORD_COLUMNS`), whole steps at a time.

What differs from a run read step by step (``SumoSession.refresh``):

- SUMO's FCD Parquet holds speeds, lane positions, lateral offsets and accelerations as 32-bit
  floats (about 7 significant digits); positions (x, y) and times are 64-bit;
- SUMO labels each step's states with the time the step began: here, as read after the
  step, with the time it ended;
- the acceleration is SUMO's own (``acceleration``: the speed change over the step divided by
  the step length), as the session's read gives it;
- ``s_m``, the route coordinate, is measured on the route frame as it stands at the end of the
  run for every row (read step by step, rows before the frame's route is known, the first CAV's
  departure, are integrated from the speed);
- a vehicle SUMO teleports is not in its FCD output during the jump (read step by step it is a
  row with no edge).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq

from sumo_swarm.core.routeframe import carried_route_s

# What trajectories.parquet holds of each vehicle at each step, as SUMO's FCD attributes.
FCD_ATTRIBUTES = ("x", "y", "lane", "pos", "posLat", "speed", "acceleration")
FCD_FILE = "fcd.parquet"
_TIME = "timestep_time"
_COLUMN = {a: f"vehicle_{a}" for a in ("id", *FCD_ATTRIBUTES)}

# A lane's edge, its index on the edge and its width [m], by SUMO lane id.
LaneTable = Mapping[str, tuple[str, int, float]]
# Kind ("cav" or "hv"), length [m] and width [m] of a vehicle.
VehicleInfo = Callable[[str], tuple[str, float, float]]
SAME_TIME_S = 1e-6  # two simulated times closer than this are one step's [s]


class RouteCoordinate(Protocol):
    """What the conversion needs of the route frame
    (:class:`~sumo_swarm.core.routeframe.RouteFrame`)."""

    edge_offset_m: Mapping[str, float]  # start of each route edge along the route [m]

    def route_s(self, edge: str, lane: int, pos_m: float) -> float | None: ...


@dataclass(frozen=True)
class FcdReading:
    """How to read one run's FCD output: ``lanes``, every lane's edge, index and width;
    ``frame``, the route coordinate; ``info(vehicle)``, its kind, length and width;
    ``step_s``, SUMO's step length [s], over which a vehicle on a junction edge off the route
    has its route position carried on at its speed; ``columns``, the table's columns in order
    (of ``time_s, vehicle, kind, edge, lane, x_m, y_m, s_m, lat_m, speed_mps, accel_mps2,
    length_m, lane_pos_m, width_m, lane_width_m``)."""

    lanes: LaneTable
    frame: RouteCoordinate
    info: VehicleInfo
    step_s: float
    columns: Sequence[str]


def fcd_args(path: Path) -> list[str]:
    """SUMO options that write the run's trajectories to ``path`` (a ``.parquet`` file)."""
    return ["--fcd-output", str(path), "--fcd-output.attributes", ",".join(FCD_ATTRIBUTES)]


class _Carry:
    """What the next step needs of the last one read: its time and each vehicle's route
    position [m]; and the last time in the file, vehicle or not (every step is in it)."""

    def __init__(self) -> None:
        self.time_s: float | None = None
        self.s_m: dict[str, float] = {}
        self.file_time_s: float | None = None


def fcd_chunks(path: Path, reading: FcdReading, rows: int = 50_000) -> Iterator[pd.DataFrame]:
    """The trajectory table of SUMO's FCD output ``path``, whole steps at a time (about
    ``rows`` rows each, more when one step holds more), in time order; steps with no vehicle
    give no rows, a file with no vehicle at all none.

    ValueError if the file misses a step (SUMO writes every step, a step with no vehicle as a
    row of its own, unless the configuration's ``device.fcd`` options thin it out).
    """
    carry = _Carry()
    held: list[pa.RecordBatch] = []
    held_rows = 0
    file = pq.ParquetFile(path)
    if _COLUMN["id"] not in file.schema_arrow.names:  # nobody ever drove
        return
    read = [_TIME, *_COLUMN.values()]
    for batch in file.iter_batches(batch_size=rows, columns=read):
        _check_steps(batch.column(_TIME).to_numpy(), reading.step_s, carry)
        batch = batch.filter(pc.is_valid(batch.column(_COLUMN["id"])))
        if batch.num_rows == 0:
            continue
        held.append(batch)
        held_rows += batch.num_rows
        if held_rows < rows:
            continue
        table = pa.Table.from_batches(held)
        times = table.column(_TIME).to_numpy()
        cut = int(np.searchsorted(times, times[-1], side="left"))  # the last step may go on
        if cut == 0:
            continue
        yield _table(table.slice(0, cut), reading, carry)
        rest = table.slice(cut)
        held, held_rows = rest.to_batches(), rest.num_rows
    if held_rows:
        yield _table(pa.Table.from_batches(held), reading, carry)


def _check_steps(times: np.ndarray, step_s: float, carry: _Carry) -> None:
    """ValueError unless ``times`` (the file's, in order) go on one step at a time."""
    if carry.file_time_s is not None:
        times = np.r_[carry.file_time_s, times]
    if len(times):
        carry.file_time_s = float(times[-1])
        jumps = np.diff(times)
        if ((jumps > SAME_TIME_S) & (np.abs(jumps - step_s) > SAME_TIME_S)).any():
            raise ValueError(
                "SUMO's FCD output skips steps (a device.fcd period or begin in the configuration?)"
            )


def _table(table: pa.Table, reading: FcdReading, carry: _Carry) -> pd.DataFrame:
    """Whole steps of FCD rows as the recorder's typed table (see :func:`fcd_chunks`)."""

    def column(name: str) -> np.ndarray:
        return table.column(name).to_numpy().astype(float, copy=False)

    step_s = reading.step_s
    # SUMO writes a step's states under the time the step began; read after the step, they
    # are the states at its end (SUMO's times are whole milliseconds)
    times = np.round((table.column(_TIME).to_numpy() + step_s) * 1000.0) / 1000.0
    vehicle = _categorical(table.column(_COLUMN["id"]))
    names = vehicle.categories.to_numpy()
    codes = vehicle.codes
    lane = _categorical(table.column(_COLUMN["lane"]))
    lane_codes = lane.codes
    if (lane_codes < 0).any():
        raise ValueError("SUMO's FCD output has a vehicle on no lane")
    where = [reading.lanes[name] for name in lane.categories]
    edges = np.array([w[0] for w in where], dtype=object)[lane_codes]
    offsets = reading.frame.edge_offset_m
    pos = column(_COLUMN["pos"])
    speed = column(_COLUMN["speed"])
    s = np.array([offsets.get(w[0], np.nan) for w in where], dtype=float)[lane_codes] + pos
    index = np.array([w[1] for w in where], dtype=np.int16)[lane_codes]
    off_frame = np.flatnonzero(np.isnan(s))
    if off_frame.size:
        _route_positions(s, off_frame, times, names, codes, edges, index, pos, speed, reading,
                         carry)  # fmt: skip
    last = times == times[-1]
    carry.time_s = float(times[-1])
    carry.s_m = dict(zip(names[codes[last]], s[last], strict=True))
    static = list(zip(*map(reading.info, names), strict=True))
    data = {
        "time_s": times,
        "vehicle": vehicle,
        "kind": pd.Categorical(np.array(static[0], dtype=object)[codes]),
        "edge": pd.Categorical(edges),
        "lane": index,
        "x_m": column(_COLUMN["x"]),
        "y_m": column(_COLUMN["y"]),
        "s_m": s,
        "lat_m": column(_COLUMN["posLat"]),
        "speed_mps": speed,
        "accel_mps2": column(_COLUMN["acceleration"]),
        "length_m": np.array(static[1], dtype=float)[codes],
        "lane_pos_m": pos,
        "width_m": np.array(static[2], dtype=float)[codes],
        "lane_width_m": np.array([w[2] for w in where], dtype=float)[lane_codes],
    }
    return pd.DataFrame({name: data[name] for name in reading.columns})


def _categorical(column: pa.ChunkedArray) -> pd.Categorical:
    """``column`` (strings) as a categorical of sorted categories, as ``pd.Categorical`` of
    its values makes it (Arrow's dictionary encoding: a tenth of the time); a null value gets
    code -1."""
    encoded = column.combine_chunks().dictionary_encode()
    names = np.array(encoded.dictionary.to_pylist(), dtype=object)
    order = np.argsort(names)
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    indices = encoded.indices.to_numpy(zero_copy_only=False)
    valid = ~np.isnan(indices) if indices.dtype.kind == "f" else np.ones(len(indices), bool)
    codes = np.full(len(indices), -1, dtype=np.int64)
    codes[valid] = rank[indices[valid].astype(np.int64)]
    return pd.Categorical.from_codes(codes, categories=names[order])


def _route_positions(
    s: np.ndarray,
    rows: np.ndarray,
    times: np.ndarray,
    names: np.ndarray,
    codes: np.ndarray,
    edges: np.ndarray,
    lanes: np.ndarray,
    pos: np.ndarray,
    speed: np.ndarray,
    reading: FcdReading,
    carry: _Carry,
) -> None:
    """Fill ``s[rows]``, rows on edges that are not the route's own, as ``SumoSession._read``
    does step by step: a junction lane of the route measured back from the next edge's start;
    elsewhere :func:`~sumo_swarm.core.routeframe.carried_route_s` from the vehicle's row one
    step before (``names[codes[i]]``: row ``i``'s vehicle)."""
    step_s = reading.step_s
    route_s = reading.frame.route_s
    prior = _previous_rows(times, codes, step_s)
    first_time = times[0]
    one_step_on = carry.time_s is not None and (
        abs(first_time - step_s - carry.time_s) < SAME_TIME_S
    )
    for i in rows:
        x = route_s(edges[i], int(lanes[i]), float(pos[i]))
        if x is None:
            j = prior[i]
            if j >= 0:
                was = s[j]
            elif one_step_on and times[i] == first_time:
                was = carry.s_m.get(names[codes[i]])
            else:
                was = None
            x = carried_route_s(pos[i], speed[i], was, step_s)
        s[i] = x


def _previous_rows(times: np.ndarray, codes: np.ndarray, step_s: float) -> np.ndarray:
    """For each row, the row of the same vehicle (``codes``: one number per vehicle) one step
    before (-1: none in these rows)."""
    order = np.lexsort((times, codes))
    prior = np.full(len(times), -1, dtype=np.int64)
    same = codes[order[1:]] == codes[order[:-1]]
    adjacent = np.abs(times[order[1:]] - step_s - times[order[:-1]]) < SAME_TIME_S
    follows = same & adjacent
    prior[order[1:][follows]] = order[:-1][follows]
    return prior
