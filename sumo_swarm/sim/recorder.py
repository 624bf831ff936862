"""One recording path: trajectories step by step, then a run finished the same way everywhere.

Both ways of running the swarm use it: ``sumo-swarm run`` (:mod:`sumo_swarm.sim.runner`, which
starts SUMO itself) and ``attach()`` (:mod:`sumo_swarm.sim.plugin`, on a simulation someone else
steps). After every SUMO step, before the controller acts, :meth:`RunRecorder.record` appends
one row per vehicle; :meth:`RunRecorder.summary` builds summary.json from what was recorded at
any time; :meth:`RunRecorder.finish` closes the controller and writes ``trajectories.parquet``,
``events.jsonl`` and ``summary.json``. A run whose controller reads no vehicle (sumo-cacc,
sumo-lc) has SUMO write the rows itself (:mod:`sumo_swarm.sim.fcd`): :meth:`RunRecorder.finish`
packs them then, the same way, into the same tables.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from itertools import chain
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
from pandas.api.types import union_categoricals

from sumo_swarm.config import OutputSettings
from sumo_swarm.controllers.base import Controller, StandDown, close_controller
from sumo_swarm.files import write_json_atomic, write_parquet_atomic
from sumo_swarm.sim import metrics
from sumo_swarm.sim.conflicts import TtcConflictCounter
from sumo_swarm.sim.fcd import FcdReading, fcd_chunks
from sumo_swarm.sim.metrics import HardBrakeCounter
from sumo_swarm.sim.network import mean_speed_field, speed_field
from sumo_swarm.sim.streamed import TrajectoryFile, rows_between_cavs, streamed_measures
from sumo_swarm.sim.summary import build_summary

log = logging.getLogger(__name__)

if TYPE_CHECKING:
    from sumo_swarm.config import Scenario
    from sumo_swarm.sim.bridge import SumoSession
    from sumo_swarm.sim.scene import Scene

# The trajectory table's columns: the contract's, plus each vehicle's length, its position on
# its lane, its width and its lane's width (gaps are measured between vehicles that really share
# a lane: :func:`sumo_swarm.sim.metrics.gaps`).
RECORD_COLUMNS = (
    "time_s",
    "vehicle",
    "kind",
    "edge",
    "lane",
    "x_m",
    "y_m",
    "s_m",
    "lat_m",
    "speed_mps",
    "accel_mps2",
    "length_m",
    "lane_pos_m",
    "width_m",
    "lane_width_m",
)

EMPTY_WINDOW_S = 1e-3  # the evaluation window of a run with nothing to evaluate [s]
# Rows held as the session read them (Python lists and objects, several hundred bytes a row)
# before they are packed into a typed table (about 100 bytes a row): 30 min of a motorway,
# 1.46 M rows, peaked at 1.96 GB unpacked and 1.44 GB packed (with the summary's own needs).
CHUNK_ROWS = 50_000
CATEGORY_COLUMNS = ("kind", "vehicle", "edge")
NAN = float("nan")
TRAJECTORIES = "trajectories.parquet"


# The columns :meth:`RunRecorder.record` takes from the session's read as they are.
_STATE_COLUMNS = ("s_m", "lat_m", "speed_mps", "accel_mps2")


def _typed(df: pd.DataFrame) -> pd.DataFrame:
    """The trajectory table's dtypes: categories for the names, int16 lanes, floats."""
    if not df.empty:
        for col in CATEGORY_COLUMNS:
            df[col] = df[col].astype("category")
        df["lane"] = df["lane"].astype("int16")
    return df


class _Steps:
    """Recorded steps not packed yet: each step's columns as the session read them (lists, kept
    as they are: no row is copied until :meth:`table`)."""

    # The parts of a step, in the order :meth:`add` takes them.
    PARTS = ("vehicle", "edge", "lane", "xy", *_STATE_COLUMNS, "lane_pos_m", "lane_width_m")

    def __init__(self) -> None:
        self.times: list[float] = []
        self.counts: list[int] = []
        self.parts: list[list[list]] = [[] for _ in self.PARTS]
        self.rows = 0

    def add(self, t: float, columns: list[list]) -> None:
        n = len(columns[0])
        self.times.append(t)
        self.counts.append(n)
        for held, column in zip(self.parts, columns, strict=True):
            held.append(column)
        self.rows += n

    def table(self, info: Callable[[str], tuple[str, float, float]]) -> pd.DataFrame:
        """The rows as a table of :func:`_typed`'s dtypes, each column made straight from the
        values (not inferred, then converted). ``info(vehicle)``: its kind, length and width,
        asked once per vehicle of the table."""
        n = self.rows
        flat = dict(zip(self.PARTS, map(chain.from_iterable, self.parts), strict=True))
        vehicle = pd.Categorical(np.array(list(flat["vehicle"]), dtype=object))
        static = list(zip(*map(info, vehicle.categories), strict=True))  # (rows > 0)
        codes = vehicle.codes
        xy = np.fromiter(chain.from_iterable(flat["xy"]), dtype=float, count=2 * n)
        data: dict[str, Any] = {
            "time_s": np.repeat(np.array(self.times, dtype=float), self.counts),
            "vehicle": vehicle,
            "kind": pd.Categorical(np.array(static[0], dtype=object)[codes]),
            "edge": pd.Categorical(np.array(list(flat["edge"]), dtype=object)),
            "lane": np.fromiter(flat["lane"], dtype=np.int16, count=n),
            "x_m": xy[0::2].copy(),
            "y_m": xy[1::2].copy(),
        }
        for column in _STATE_COLUMNS:
            data[column] = np.fromiter(flat[column], dtype=float, count=n)
        data["length_m"] = np.array(static[1], dtype=float)[codes]
        data["lane_pos_m"] = np.fromiter(flat["lane_pos_m"], dtype=float, count=n)
        data["width_m"] = np.array(static[2], dtype=float)[codes]
        data["lane_width_m"] = np.fromiter(flat["lane_width_m"], dtype=float, count=n)
        return pd.DataFrame({col: data[col] for col in RECORD_COLUMNS})


def _concat(chunks: list[pd.DataFrame]) -> pd.DataFrame:
    """Tables of :func:`_typed` (or their :func:`metrics.gaps`) one after the other, each
    category column on the sorted union of their categories (what one table of all the rows
    would have)."""
    data = {}
    for col in chunks[0].columns:
        parts = [c[col] for c in chunks]
        if isinstance(parts[0].dtype, pd.CategoricalDtype):
            data[col] = union_categoricals(parts, sort_categories=True)
        else:
            data[col] = np.concatenate([part.to_numpy() for part in parts])
    return pd.DataFrame(data)


def _near_cavs(
    ids: Sequence[str],
    xy: Sequence[tuple[float, float]],
    kinds: Mapping[str, str],
    range_m: float,
) -> list[int]:
    """The rows of ``ids`` (at positions ``xy``) that are CAVs or within ``range_m`` of one
    (straight line), in order."""
    cavs = [i for i, v in enumerate(ids) if kinds.get(v) == "cav"]
    if not cavs:
        return []
    points = np.array(xy, dtype=float).reshape(-1, 2)
    d2 = ((points[:, None, :] - points[None, cavs, :]) ** 2).sum(axis=2).min(axis=1)
    return np.flatnonzero(d2 <= range_m * range_m).tolist()


def records_every_row(outputs: OutputSettings) -> bool:
    """Whether a run with these outputs records every vehicle at every step (as SUMO's FCD
    output does)."""
    o = outputs
    return o.trajectories == "all" and o.record_from_s <= 0.0 and o.record_to_s is None


def with_completeness(summary: dict[str, Any], incomplete_reason: str | None) -> dict[str, Any]:
    """``summary`` with ``complete`` and ``incomplete_reason`` after ``seed`` (the contract's
    order): complete unless a reason is given."""
    marks = {"complete": incomplete_reason is None, "incomplete_reason": incomplete_reason}
    keys = [k for k in summary if k not in marks]
    at = keys.index("seed") + 1 if "seed" in keys else len(keys)
    order = [*keys[:at], *marks, *keys[at:]]
    return {k: marks[k] if k in marks else summary[k] for k in order}


def write_events(path: Path, events: list[dict[str, Any]]) -> None:
    """The run's events, one JSON object a line."""
    with path.open("w", encoding="utf-8") as fh:
        for e in events:
            fh.write(json.dumps(e, default=str) + "\n")


class RunRecorder:
    """The trajectories of one run and what it cost, and the run's outputs at its end.

    ``scene`` tells the summary the CAVs and the target (a scenario's placed scene, or a
    :class:`~sumo_swarm.sim.scene.LiveScene`). The wall time counts from its creation, the
    simulated time from the step before the first one recorded.
    """

    def __init__(
        self,
        session: SumoSession,
        controller: Controller,
        controller_name: str,
        scene: Scene,
        outputs: OutputSettings | None = None,
        out_dir: Path | None = None,
        count_conflicts: bool = False,
    ) -> None:
        self.session = session
        self.outputs = outputs or OutputSettings()  # which rows to record
        self.hard_brakes = HardBrakeCounter()  # of every vehicle, recorded or not
        self.controller = controller
        self.controller_name = controller_name
        self.scene = scene
        # The run loop's guard of the controller (StandDown): the summary's stood_down
        self.stand_down: StandDown | None = None
        self._steps = _Steps()  # rows recorded, not packed yet
        # The network block's TTC conflicts (``count_conflicts``: a run that reads SUMO's
        # outputs into it), of every vehicle at every step whatever is recorded
        # (sim/conflicts.py: instead of SUMO's SSM device, whose memory grows with a jam); the
        # steps wait here, as the session read them, until a chunk's worth is paired.
        self.conflicts = (
            TtcConflictCounter(self.outputs.ttc_threshold_s) if count_conflicts else None
        )
        self._conflict_steps = _Steps()  # steps not recorded whole
        # Every vehicle of a recorded step is recorded: the counter pairs the packed rows
        # (one table made of a step's rows, not two).
        self._whole_steps = self.outputs.trajectories != "cavs"
        # metrics.gaps of each chunk held (the counter's pairs), in order: the summary's pairs
        # of the table, not made a second time (None: not kept, or rows went to disk).
        self._pairs: list[pd.DataFrame] | None = [] if self._whole_steps else None
        # Kind, length and width are taken per vehicle when rows are packed: rows of a vehicle
        # id that departs again are packed before the new one's values replace the old. (Rows
        # SUMO records are packed at the end: a reused id's rows take its last vehicle's.)
        hooks = getattr(session, "on_id_reused", None)
        if hooks is not None:
            hooks.append(self._pack)
            hooks.append(self._count_conflicts)
        self.sumo_s: float | None = None  # measured by the caller, else wall minus controller
        self.controller_s = 0.0
        self._wall0 = time.perf_counter()
        self._wall_end: float | None = None  # set when the run ends
        # Process time [s]: the run's cost on one core, whatever else the machine runs (a
        # batch runs one simulation per process).
        self._cpu0 = time.process_time()
        self._cpu_end: float | None = None
        self._t0_s: float | None = None  # simulated time when recording began [s]
        self._first_time_s: float | None = None
        self._last_time_s: float | None = None
        self._chunks: list[pd.DataFrame] = []  # rows packed so far, in order
        self._closed = False
        # Beyond outputs.memory_rows the packed rows go to out_dir/trajectories.parquet as they
        # come (sim/streamed.py); without out_dir they all stay in memory.
        self._file = TrajectoryFile(out_dir / TRAJECTORIES) if out_dir is not None else None
        self._held_rows = 0
        # SUMO records every vehicle at every step into this file (sim/fcd.py); its rows are
        # taken once SUMO has closed. Only for a run that records every vehicle at every step.
        self._fcd_path: Path | None = getattr(session, "fcd_path", None)
        self.hard_brakes_unread = False  # SUMO's FCD output could not be read whole
        if self._fcd_path is not None and not records_every_row(self.outputs):
            raise ValueError("SUMO's FCD output records every vehicle at every step")

    def record(self) -> None:
        """Append the session's vehicles as they are after the last step (one row each); a
        session whose steps SUMO records itself (its ``fcd_path``) gives its rows at the end
        (:meth:`finish`)."""
        s = self.session
        if self._t0_s is None:
            self._t0_s = s.time_s - s.step_length_s
        if self._fcd_path is not None:
            return
        c = s.columns
        self.hard_brakes.update(c.ids, c.accel_mps2, s.kinds)
        o = self.outputs
        t = s.time_s
        # in _Steps.PARTS' order
        columns = [c.ids, c.edge, c.lane, c.xy, c.s_m, c.lat_m, c.speed_mps, c.accel_mps2,
                   c.lane_pos_m, c.lane_width_m]  # fmt: skip
        to_s = o.record_to_s
        recorded = t >= o.record_from_s - 1e-9 and (to_s is None or t <= to_s + 1e-9)
        if self.conflicts is not None and c.ids and not (recorded and self._whole_steps):
            if self._steps.rows and self._whole_steps:
                self._pack()  # the counter takes the steps in time order
            self._conflict_steps.add(t, columns)  # the same lists: no copy
            if self._conflict_steps.rows >= CHUNK_ROWS:
                self._count_conflicts()
        if not recorded:
            return
        if o.trajectories == "cavs":
            rows = _near_cavs(c.ids, c.xy, s.kinds, o.neighbour_range_m)
            columns = [list(map(column.__getitem__, rows)) for column in columns]
        if not columns[0]:
            return
        if self._first_time_s is None:
            self._first_time_s = t
        self._last_time_s = t
        self._steps.add(t, columns)
        if self._steps.rows >= CHUNK_ROWS:
            self._pack()

    def _take_fcd(self) -> str | None:
        """The rows SUMO recorded (its FCD output, once it closed), packed as the recorder's
        own, the file removed after (its rows are in trajectories.parquet). A file that cannot
        be read whole (SUMO failed before closing it, or the configuration thinned it out)
        stays as SUMO left it; returns why (None: read whole, or nothing to read)."""
        path, self._fcd_path = self._fcd_path, None
        if path is None:
            return None
        s = self.session
        if not path.exists():
            return f"{path}: SUMO wrote no FCD output" if s.drove else None
        reading = FcdReading(s.lane_table, s.frame, self._vehicle_info, s.step_length_s,
                             RECORD_COLUMNS)  # fmt: skip
        seen: set[str] = set()
        try:
            # rows beyond what is held in memory go to disk from the first chunk on (the file
            # says how many there are)
            to_disk = self._file is not None and (
                pq.ParquetFile(path).metadata.num_rows > self.memory_rows
            )
            for chunk in fcd_chunks(path, reading, CHUNK_ROWS):
                times = chunk["time_s"].to_numpy()
                if self._first_time_s is None:
                    self._first_time_s = float(times[0])
                self._last_time_s = float(times[-1])
                vehicles = chunk["vehicle"]
                seen.update(vehicles.cat.categories)
                self.hard_brakes.update_steps(
                    times, vehicles.to_numpy(), chunk["accel_mps2"].to_numpy(), s.kinds
                )
                self._add_chunk(chunk)
                if to_disk:
                    self._spill()
            missing = len(s.drove - seen)
            if missing:  # a vehicle or type without SUMO's FCD device (has.fcd.device)
                raise ValueError(f"{missing} vehicles that drove are not in it")
        except Exception as exc:  # a damaged output costs its rows, never the run
            why = f"{path}: SUMO's FCD output not read whole: {type(exc).__name__}: {exc}"
            log.warning("%s", why)
            return why
        path.unlink()
        return None

    def _vehicle_info(self, vid: str) -> tuple[str, float, float]:
        """Kind, length [m] and width [m] of ``vid``, as the session registered it when it
        departed (they do not change)."""
        s = self.session
        return s.kinds.get(vid, "hv"), s.lengths.get(vid, 5.0), s.widths.get(vid, NAN)

    @property
    def first_time_s(self) -> float | None:
        """Simulated time of the first step recorded [s] (None: nothing recorded yet)."""
        return self._first_time_s

    @property
    def last_time_s(self) -> float | None:
        """Simulated time of the last step recorded [s]."""
        return self._last_time_s

    def _pack(self) -> None:
        """Turn the rows gathered as Python lists into a typed table (a tenth of the memory);
        past ``outputs.memory_rows`` held, write the tables held to the trajectory file."""
        if self._steps.rows:
            chunk = self._steps.table(self._vehicle_info)
            self._steps = _Steps()
            self._add_chunk(chunk)
        elif self._file is not None and (self._file.open or self._held_rows > self.memory_rows):
            self._spill()

    def _add_chunk(self, chunk: pd.DataFrame) -> None:
        """Hold ``chunk`` (whole steps, after those held), its pairs counted for conflicts;
        past ``outputs.memory_rows`` held, write the tables held to the trajectory file."""
        if self.conflicts is not None and self._whole_steps:
            self._count_conflicts()  # steps before these, recorded in part or not at all
            pairs = metrics.gaps(chunk)
            self.conflicts.add(pairs)
            if self._pairs is not None:
                self._pairs.append(pairs)
        self._chunks.append(chunk)
        self._held_rows += len(chunk)
        if self._file is not None and (self._file.open or self._held_rows > self.memory_rows):
            self._spill()

    def _count_conflicts(self) -> None:
        """Pair the steps waiting for the conflict counter and count them."""
        if self.conflicts is not None and self._conflict_steps.rows:
            table = self._conflict_steps.table(self._vehicle_info)
            self._conflict_steps = _Steps()
            self.conflicts.add(metrics.gaps(table))

    @property
    def memory_rows(self) -> int:
        return self.outputs.memory_rows

    def _spill(self) -> None:
        for chunk in self._chunks:
            self._file.append(chunk)
        self._chunks, self._held_rows = [], 0
        self._pairs = None  # the summary reads the rows back a slice at a time

    def _pairs_of(self, df: pd.DataFrame) -> pd.DataFrame | None:
        """:func:`metrics.gaps` of ``df`` when ``df`` is the table held (:meth:`_table`) and
        its rows were paired as they were packed; else None."""
        if self._pairs is None or len(self._chunks) != 1 or df is not self._chunks[0]:
            return None
        if len(self._pairs) > 1:
            self._pairs = [_concat(self._pairs)]
        pairs = self._pairs[0] if self._pairs else None
        return pairs if pairs is not None and len(pairs) == len(df) else None

    @property
    def on_disk(self) -> bool:
        """True once rows went to the trajectory file (the summary then reads them back)."""
        return self._file is not None and self._file.rows > 0

    def frame(self) -> pd.DataFrame:
        """The trajectory table recorded so far (the contract's trajectories.parquet); for a
        run whose rows went to disk, read back whole (as much memory as they take)."""
        if self.on_disk:
            self._pack()
            return _concat(
                [_typed(p.astype(dict.fromkeys(CATEGORY_COLUMNS, object))) for p in self._slices()]
            )
        return self._table().copy()

    def _slices(self):
        """The recorded rows a slice of whole steps at a time (sim/streamed.py)."""
        return self._file.slices(list(self._chunks))

    def _table(self) -> pd.DataFrame:
        """The recorded table itself (not a copy: for reading only)."""
        self._pack()
        if not self._chunks:  # nothing recorded
            return pd.DataFrame({col: [] for col in RECORD_COLUMNS})
        if len(self._chunks) > 1:  # one table; the category columns on one sorted vocabulary
            self._chunks = [_concat(self._chunks)]
        return self._chunks[0]

    def timing(self) -> dict[str, float | None]:
        """summary.json's ``timing`` block: wall, SUMO and controller time [s], the process
        time ``cpu_s`` [s] and the simulated time per wall time since the recorder was made."""
        wall = (self._wall_end or time.perf_counter()) - self._wall0
        cpu = (self._cpu_end or time.process_time()) - self._cpu0
        sumo = self.sumo_s if self.sumo_s is not None else max(wall - self.controller_s, 0.0)
        simulated = self.timing_simulated_s()
        return {
            "wall_s": wall,
            "sumo_s": sumo,
            "controller_s": self.controller_s,
            "cpu_s": cpu,
            "realtime_factor": simulated / wall if wall > 0 else None,
        }

    def summary(
        self,
        scenario: Scenario,
        df: pd.DataFrame | None = None,
        controller_summary: dict[str, Any] | None = None,
    ) -> dict[str, Any]:
        """summary.json of what was recorded so far; the evaluation window ends with the data.

        ``controller_summary``: the controller's blocks, default its ``summary()``."""
        return self._summary(scenario, df, controller_summary)[0]

    def _summary(
        self,
        scenario: Scenario,
        df: pd.DataFrame | None = None,
        controller_summary: dict[str, Any] | None = None,
        field_of: Any = None,
    ) -> tuple[dict[str, Any], list[pd.DataFrame]]:
        """:meth:`summary`, and, for a run on disk, the speed fields ``field_of`` made of each
        slice while it was read (:func:`~sumo_swarm.sim.streamed.streamed_measures`)."""
        streamed = df is None and self.on_disk
        if not streamed:
            df = self.frame() if df is None else df
        last = self._last_time_s if streamed else (None if df.empty else float(df["time_s"].max()))
        if last is not None:
            ev = scenario.evaluation
            end = min(ev.end_s, last)
            # a run that ended before the window opened: an empty window just after its start
            end = max(end, ev.start_s + EMPTY_WINDOW_S)
            scenario = replace(scenario, evaluation=replace(ev, end_s=end))
        own = self.controller.summary() if controller_summary is None else controller_summary
        measures, fields, rows_of = None, [], None
        if streamed:
            self._pack()
            overtake = own.get("overtake", {})
            measures, fields = streamed_measures(
                self._slices,
                scenario,
                self.scene.cav_ids,
                overtake.get("target") or self.scene.target_id,
                overtake.get("t_start_s"),
                speed_field=field_of,
                scratch_dir=self._file.path.parent,
            )
            rows_of = rows_between_cavs(self._slices)
        summary = build_summary(
            scenario=scenario,
            controller=self.controller_name,
            df=df,
            gap_table=None if streamed else self._pairs_of(df),
            scene=self.scene,
            session=self.session,
            controller_summary=own,
            timing=self.timing(),
            hard_brakes=self.hard_brakes,
            measures=measures,
            rows_of=rows_of,
        )
        # Extra (not in the contract): None, or when the controller failed and stood down,
        # and why, and what drove the CAVs on ({"t_s", "reason", "then"}).
        summary["stood_down"] = None if self.stand_down is None else self.stand_down.block
        return summary, fields

    def close_controller(self) -> None:
        """Let the controller release what it holds open (once)."""
        if not self._closed:
            self._closed = True
            close_controller(self.controller)

    def finish(
        self,
        out: Path,
        scenario: Scenario,
        events: list[dict[str, Any]],
        controller_summary: dict[str, Any] | None = None,
        network_files: Mapping[str, Path] | None = None,
        incomplete_reason: str | None = None,
    ) -> dict[str, Any]:
        """End the run: close the controller, write trajectories.parquet, events.jsonl and
        summary.json into ``out``; return the summary. The run's wall time ends here.

        ``incomplete_reason``: why the run ended before its end (interrupted, or SUMO or the
        controller failed); the summary says ``"complete": false`` and the reason.

        ``network_files``: SUMO's outputs of a finished simulation
        (:func:`~sumo_swarm.sim.network.network_options`), read into the ``network`` block and
        the network tables once everything else is written; if they cannot be read, the block
        is None, ``network_error`` says why, and the rest of the run stays."""
        unread = self._take_fcd()  # the recording's cost is the run's, as step by step
        self._wall_end = self._wall_end or time.perf_counter()
        self._cpu_end = self._cpu_end or time.process_time()
        self.close_controller()
        for stale in out.glob("network_*.parquet"):  # an earlier run's, in the same folder
            stale.unlink()
        self._pack()
        if self.on_disk and Path(out).resolve() == self._file.path.parent.resolve():
            self._spill()  # the last rows, then the file is in place
            self._file.close()
            df = None
        else:  # in memory (or asked to finish elsewhere: the whole table, read back)
            df = self.frame() if self.on_disk else self._table()  # read only: no copy
            write_parquet_atomic(out / TRAJECTORIES, df)
        write_events(out / "events.jsonl", self._with_collisions(events))
        route = self.session.route_edges
        o = scenario.outputs

        def field_of(part: pd.DataFrame) -> pd.DataFrame:
            return speed_field(part, route, o.speed_field_cell_m, o.speed_field_period_s)

        wanted = field_of if network_files is not None else None
        summary, fields = self._summary(scenario, df, controller_summary, wanted)
        if unread is not None:  # the measures of the rows are of the rows read
            summary.setdefault("errors", {})["trajectories"] = unread
            incomplete_reason = incomplete_reason or unread
            self.conflicts = None  # the network block's TTC and hard brakes: not counted
            self.hard_brakes_unread = True
        summary = with_completeness(summary, incomplete_reason)
        write_json_atomic(out / "summary.json", summary)
        if network_files is not None:

            def field() -> pd.DataFrame:
                return mean_speed_field(fields) if df is None else field_of(df)

            missed = sum(1 for e in events if e.get("event") == "exit_missed")
            self._add_network(out, scenario, field, summary, network_files, missed)
            write_json_atomic(out / "summary.json", summary)
        return summary

    def _with_collisions(self, events: list[dict[str, Any]]) -> list[dict[str, Any]]:
        """``events`` with SUMO's collisions among them, in time order (``collision``: who ran
        into whom, and SUMO's type of collision), so that a collision counted in the summary
        can be found: the first step of each pair, as the summary counts them (SUMO reports
        two vehicles that stay overlapped again at every step)."""
        hits, seen = [], set()
        for c in getattr(self.session, "collisions", ()):
            if (c.collider, c.victim) not in seen:
                seen.add((c.collider, c.victim))
                hits.append({"time_s": c.time_s, "event": "collision", "collider": c.collider,
                             "victim": c.victim, "type": c.kind})  # fmt: skip
        return sorted([*events, *hits], key=lambda e: e["time_s"]) if hits else events

    def _add_network(
        self,
        out: Path,
        scenario: Scenario,
        field: Callable[[], pd.DataFrame],
        summary: dict[str, Any],
        files: Mapping[str, Path],
        exits_missed: int = 0,
    ) -> None:
        from sumo_swarm.sim import network

        s = self.session
        self._count_conflicts()
        try:
            tables = network.read_network(
                files, lambda vid, vtype: network.vehicle_class(*s.classify(vid, vtype))
            )
            network.write_network_tables(out, tables)
            write_parquet_atomic(out / network.SPEED_FIELD_FILE, field())
            summary["network"] = network.network_block(
                tables,
                hard_brake_events=self.hard_brakes.episodes,
                duration_s=self.timing_simulated_s(),
                ttc_threshold_s=scenario.outputs.ttc_threshold_s,
                ttc_events=self.conflicts.events if self.conflicts is not None else None,
                exits_missed=exits_missed,
            )
            if self.hard_brakes_unread:
                summary["network"]["hard_brakes_per_1000_vkm"] = None
        except Exception as exc:  # a damaged output costs the block, never the run
            log.warning("network measures not read: %s", exc)
            summary["network"] = None
            summary["network_error"] = f"{type(exc).__name__}: {exc}"
            summary.setdefault("errors", {})["network"] = summary["network_error"]

    def timing_simulated_s(self) -> float:
        """Simulated time since recording began [s]."""
        return self.session.time_s - self._t0_s if self._t0_s is not None else 0.0
