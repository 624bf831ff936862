"""Network measures from SUMO's own outputs: what a traffic-impact study reads from a run.

A run asks SUMO for three outputs (:func:`network_options`, ``[outputs]`` in the scenario):

- ``tripinfo.xml``: one trip per vehicle, with the emissions device's CO2 and fuel, written also
  for vehicles still driving when the run ends (their trip so far);
- ``ssm.xml``: the SSM device's conflicts, every encounter whose time to collision fell below
  ``ttc_threshold_s``;
- ``edgedata.xml``: flow, speed and density of every edge per ``edge_data_period_s``.

After the run, :func:`read_network` turns them into three tables (``network_trips.parquet``,
``network_conflicts.parquet``, ``network_edges.parquet``) and :func:`network_block` into
summary.json's ``network`` block; :func:`speed_field` makes the space-time speed field of the
route from the run's trajectories (``network_speed_field.parquet``). Vehicle classes: ``cav``
for the swarm's vehicle type, then SUMO's vClass of the vehicle's type grouped as
:data:`CLASS_OF_VCLASS` says, ``hv`` for the rest.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any
from xml.sax.saxutils import quoteattr

import numpy as np
import pandas as pd

from sumo_swarm.checks import finite_or_none
from sumo_swarm.errors import ConfigError
from sumo_swarm.files import write_parquet_atomic

if TYPE_CHECKING:
    from sumo_swarm.config import OutputSettings

TRIPINFO = "tripinfo.xml"
SSM = "ssm.xml"
EDGE_DATA = "edgedata.xml"
ADDITIONAL = "network.add.xml"
EDGE_DATA_ID = "sumo-swarm"
SPEED_FIELD_FILE = "network_speed_field.parquet"
EDGES_FILE = "network_edges.parquet"

# SUMO vClasses reported as their own class; every other HV is "hv".
CLASS_OF_VCLASS = {"truck": "truck", "trailer": "truck", "bus": "bus", "coach": "bus"}

TRIP_COLUMNS = (
    "vehicle",
    "vtype",
    "vehicle_class",
    "departed",  # False: still waiting to enter the network when the run ended
    "depart_s",
    "depart_delay_s",  # SUMO's departDelay: from the planned to the actual departure (so far)
    "arrival_s",  # NaN: still driving when the run ended
    "finished",
    "duration_s",
    "route_length_m",  # the distance driven (so far, for an unfinished trip)
    "time_loss_s",  # SUMO's timeLoss: the time lost to driving below the desired speed
    "waiting_time_s",
    "co2_mg",
    "fuel_mg",
)
CONFLICT_COLUMNS = ("ego", "foe", "begin_s", "end_s", "min_ttc_s", "min_ttc_time_s")
EDGE_COLUMNS = (
    "begin_s",
    "end_s",
    "edge",
    "sampled_s",  # vehicle-seconds spent on the edge in the interval
    "speed_mps",
    "density_veh_per_km",
    "lane_density_veh_per_km",
    "flow_veh_per_h",
    "entered",
    "left",
    "distance_m",
)


@dataclass(frozen=True)
class NetworkTables:
    trips: pd.DataFrame
    conflicts: pd.DataFrame | None  # None: no SSM output to read
    edges: pd.DataFrame | None  # None: no edge data to read


def vehicle_class(kind: str, vclass: str | None) -> str:
    """``cav`` for a CAV; otherwise the class of SUMO's ``vclass`` (:data:`CLASS_OF_VCLASS`)."""
    if kind == "cav":
        return "cav"
    return CLASS_OF_VCLASS.get(vclass or "", "hv")


# --------------------------------------------------------------------------- asking SUMO


def network_options(
    folder: Path,
    settings: OutputSettings,
    given: Mapping[str, str] | None = None,
    given_dir: Path | None = None,
) -> tuple[list[str], dict[str, Path]]:
    """SUMO options that write the network outputs into ``folder``, and where each will be.

    ``given``: options a user's configuration already sets, by SUMO's full names (a
    configuration saved by SUMO itself: ``<additional>`` and ``<tripinfo>`` are synonyms SUMO
    accepts), paths relative to ``given_dir``. An output the user asks for stays theirs and is
    read from their file (with the unfinished and undeparted trips and the emissions added
    unless they set those too); the edge-data definition is added to their additional files,
    not put in their place; their ``output-prefix`` names every file, ours too. Returns
    ``(options, {"tripinfo" | "ssm" | "edgedata": path})``; no "ssm" when the user set up the
    SSM device without a file of theirs or without TTC. ConfigError for a folder whose path
    holds a comma (SUMO splits its lists of files on commas).
    """
    given = dict(given or {})
    base = given_dir or Path(".")
    folder.mkdir(parents=True, exist_ok=True)
    folder = folder.resolve()  # SUMO reads paths in an additional file from that file's folder
    if "," in str(folder):
        raise ConfigError(f"{folder}: SUMO cannot be given a path with a comma in it")
    prefix = given.get("output-prefix", "")

    def written(path: Path) -> Path:  # where SUMO writes an output named ``path``
        return path.with_name(prefix + path.name)

    opts: list[str] = []
    files: dict[str, Path] = {}
    if "tripinfo-output" in given:
        files["tripinfo"] = written(base / given["tripinfo-output"])
    else:
        opts += ["--tripinfo-output", str(folder / TRIPINFO)]
        files["tripinfo"] = written(folder / TRIPINFO)
    # Trips still under way at the end count (their delay so far), and so do vehicles still
    # waiting to enter (their insertion delay): added to a user's own tripinfo output too, as
    # are the emissions, unless their configuration says otherwise.
    for option in ("tripinfo-output.write-unfinished", "tripinfo-output.write-undeparted"):
        if option not in given:
            opts += [f"--{option}", "true"]
    if "device.emissions.probability" not in given:
        opts += ["--device.emissions.probability", "1"]
    if any(k.startswith("device.ssm.") for k in given):
        measures = given.get("device.ssm.measures", "")  # SUMO's default: no TTC
        if "device.ssm.file" in given and "TTC" in measures.replace(",", " ").split():
            files["ssm"] = written(base / given["device.ssm.file"])
    elif settings.ssm:
        files["ssm"] = written(folder / SSM)
        # One option and its value a line: the formatter would split each pair over two lines.
        opts += [
            "--device.ssm.probability", "1",
            "--device.ssm.measures", "TTC",
            "--device.ssm.thresholds", f"{settings.ttc_threshold_s}",
            "--device.ssm.range", f"{settings.ssm_range_m}",
            "--device.ssm.trajectories", "false",
            "--device.ssm.file", str(folder / SSM),
        ]  # fmt: skip
    files["edgedata"] = written(folder / EDGE_DATA)
    additional = folder / ADDITIONAL
    period = quoteattr(f"{settings.edge_data_period_s}")
    additional.write_text(
        f"<additional>\n    <edgeData id={quoteattr(EDGE_DATA_ID)} period={period}"
        f" file={quoteattr(str(folder / EDGE_DATA))}/>\n</additional>\n",
        encoding="utf-8",
    )
    theirs = [
        str((base / name.strip()).resolve())
        for name in given.get("additional-files", "").split(",")
        if name.strip()
    ]
    opts += ["--additional-files", ",".join([*theirs, str(additional)])]
    return opts, files


# --------------------------------------------------------------------------- reading SUMO


def _float(value: Any, default: float = math.nan) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        return default


def _first_child(node: Any, name: str) -> Any | None:
    """The first child element ``name`` of a sumolib element, or None."""
    return node.getChild(name)[0] if node.hasChild(name) else None


Classify = Callable[[str, str], str]  # (vehicle, vType) -> vehicle class

# The attributes read of each element of SUMO's outputs. sumolib makes one class per element
# type from these (an attribute an element lacks reads None), instead of a class per element
# from the element's own attributes (heterogeneous=True): reading the outputs of 300 s of
# scenarios/corridor.toml took 0.057 s that way, 0.030 s this way. Other children of an element
# (a trip's stops, say) are read alike, from the first one's attributes.
_TRIP_ATTRS = {
    "tripinfo": ["id", "depart", "departDelay", "arrival", "duration", "routeLength",
                 "waitingTime", "timeLoss", "vType"],
    "emissions": ["CO2_abs", "fuel_abs"],
}  # fmt: skip
_CONFLICT_ATTRS = {"conflict": ["begin", "end", "ego", "foe"], "minTTC": ["time", "value"]}
_EDGE_DATA_ATTRS = {
    "interval": ["begin", "end"],
    "edge": ["id", "sampledSeconds", "speed", "density", "laneDensity", "flow", "entered",
             "left", "distance"],
}  # fmt: skip


def _parse(path: Path, element: str, attrs: Mapping[str, list[str]]):
    """sumolib's compound objects of every ``element`` in ``path``, with ``attrs`` only."""
    import sumolib.xml

    return sumolib.xml.parse(str(path), element, element_attrs=attrs, heterogeneous=False)


def read_trips(path: Path, classify: Classify) -> pd.DataFrame:
    """SUMO's tripinfo output as a table (:data:`TRIP_COLUMNS`); ``classify(vehicle, vtype)``
    gives each trip its class. A vehicle that never entered the network (SUMO's undeparted
    trip: ``depart="-1"``) has ``departed`` False and its insertion delay so far."""
    rows = []
    for trip in _parse(path, "tripinfo", _TRIP_ATTRS):
        vid = trip.id
        depart = _float(trip.depart)
        arrival = _float(trip.arrival)
        emissions = _first_child(trip, "emissions")
        rows.append(
            (
                vid,
                trip.vType,
                classify(vid, trip.vType),
                depart >= 0.0,
                depart if depart >= 0.0 else math.nan,
                _float(trip.departDelay, 0.0),
                arrival if arrival >= 0.0 else math.nan,
                arrival >= 0.0,
                _float(trip.duration),
                _float(trip.routeLength),
                _float(trip.timeLoss),
                _float(trip.waitingTime),
                _float(emissions.CO2_abs) if emissions is not None else math.nan,
                _float(emissions.fuel_abs) if emissions is not None else math.nan,
            )
        )
    return pd.DataFrame(rows, columns=list(TRIP_COLUMNS))


def read_conflicts(path: Path) -> pd.DataFrame:
    """The SSM device's conflicts (:data:`CONFLICT_COLUMNS`); an encounter without a TTC value
    (SUMO writes NA) has ``min_ttc_s`` NaN."""
    rows = []
    for c in _parse(path, "conflict", _CONFLICT_ATTRS):
        ttc = _first_child(c, "minTTC")
        rows.append(
            (
                c.ego,
                c.foe,
                _float(c.begin),
                _float(c.end),
                _float(ttc.value) if ttc is not None else math.nan,
                _float(ttc.time) if ttc is not None else math.nan,
            )
        )
    return pd.DataFrame(rows, columns=list(CONFLICT_COLUMNS))


def read_edge_data(path: Path) -> pd.DataFrame:
    """SUMO's edge data (:data:`EDGE_COLUMNS`); an edge no vehicle used in an interval is not
    written by SUMO, and its speed is NaN where SUMO leaves it out."""
    rows = []
    for interval in _parse(path, "interval", _EDGE_DATA_ATTRS):
        begin, end = _float(interval.begin), _float(interval.end)
        for e in interval.getChild("edge") if interval.hasChild("edge") else ():
            rows.append(
                (
                    begin,
                    end,
                    e.id,
                    _float(e.sampledSeconds, 0.0),
                    _float(e.speed),
                    _float(e.density),
                    _float(e.laneDensity),
                    _float(e.flow),
                    int(_float(e.entered, 0.0)),
                    int(_float(e.left, 0.0)),
                    _float(e.distance, 0.0),
                )
            )
    return pd.DataFrame(rows, columns=list(EDGE_COLUMNS))


def read_network(files: Mapping[str, Path], classify: Classify) -> NetworkTables:
    """The three tables from the files :func:`network_options` named: no "ssm" or "edgedata"
    gives None for that table; a file named but not written (or not readable) is an error
    (FileNotFoundError, or the XML parser's), never an empty table."""
    trips = read_trips(_written(files, "tripinfo"), classify)
    conflicts = read_conflicts(_written(files, "ssm")) if "ssm" in files else None
    edges = read_edge_data(_written(files, "edgedata")) if "edgedata" in files else None
    return NetworkTables(trips, conflicts, edges)


def _written(files: Mapping[str, Path], name: str) -> Path:
    path = files.get(name)
    if path is None or not path.is_file():
        raise FileNotFoundError(f"SUMO wrote no {name} output at {path}")
    return path


def write_network_tables(out: Path, tables: NetworkTables) -> None:
    """``network_trips.parquet``, ``network_conflicts.parquet``, ``network_edges.parquet``."""
    write_parquet_atomic(out / "network_trips.parquet", tables.trips)
    if tables.conflicts is not None:
        write_parquet_atomic(out / "network_conflicts.parquet", tables.conflicts)
    if tables.edges is not None:
        write_parquet_atomic(out / EDGES_FILE, tables.edges)


# --------------------------------------------------------------------------- measures


def network_block(
    tables: NetworkTables,
    *,
    hard_brake_events: int,
    duration_s: float,
    ttc_threshold_s: float,
    ttc_events: int | None = None,
    exits_missed: int = 0,
) -> dict[str, Any]:
    """summary.json's ``network`` block.

    - ``vehicles``: vehicles that entered the network (a trip each, finished or not);
    - ``travel_time_s``: mean trip duration per class, over the trips that finished (None for
      a class none of whose trips finished);
    - ``delay_s``: mean per class of SUMO's timeLoss plus its departDelay, over every vehicle
      due to depart, so far for those still driving or still waiting to enter: a queue back
      to the entry counts. timeLoss is against the vehicle's own desired speed, so this
      compares runs whose vehicles of the class share a vType;
    - ``throughput_vph``: trips finished per hour of the run (``duration_s``);
    - ``hard_brakes_per_1000_vkm``: ``hard_brake_events`` (episodes, any vehicle) per thousand
      vehicle-kilometres driven (None when nobody drove);
    - ``ttc_below_1_5s_events``: conflicts, encounters of two vehicles whose time to collision
      fell below ``ttc_threshold_s``: ``ttc_events``, counted during the run from every
      vehicle's step (:mod:`sumo_swarm.sim.conflicts`); without it, SSM's conflicts (None
      without SSM output either);
    - ``ttc_below_1_5s_events_ssm``: SSM's conflicts below ``ttc_threshold_s`` as SUMO wrote
      them (each from both vehicles' sides), when there was SSM output and ``ttc_events``;
    - ``co2_g_per_km``, ``fuel_g_per_km``: emitted / driven per class (mg per m = g per km);
    - ``exits_missed``: CAVs that gave up the exit of their route after standing for it and
      drove on (``exit_missed`` events, controllers.cacc): they are counted as trips, to
      another end than their own;
    - ``delay_s_others``: the same delay's mean over every vehicle that is not a CAV, all
      classes together (what the CAVs cost the rest of the traffic; None without such a
      vehicle);
    - extras: ``vehicle_km``, ``trips_finished``, ``vehicles_per_class`` (entered),
      ``vehicles_not_departed`` (still waiting at the end), ``depart_delay_s`` per class.
    """
    every = tables.trips
    departed = every["departed"].astype(bool)
    trips = every[departed]  # vehicles that entered the network
    by_class = trips.groupby("vehicle_class", sort=True)
    finished = trips[trips["finished"].astype(bool)]
    travel = finished.groupby("vehicle_class", sort=True)["duration_s"].mean()
    distance_m = by_class["route_length_m"].sum()

    def per_class(values: pd.Series) -> dict[str, float | None]:
        return {str(k): finite_or_none(v) for k, v in values.items()}

    def per_km(column: str) -> dict[str, float | None]:
        mass = by_class[column].sum(min_count=1)
        return {
            str(k): finite_or_none(mass[k] / d) if d > 0 else None for k, d in distance_m.items()
        }

    vkm = float(trips["route_length_m"].sum()) / 1000.0 if len(trips) else 0.0
    conflicts = tables.conflicts
    ssm_events = None
    if conflicts is not None:
        ssm_events = int((conflicts["min_ttc_s"] < ttc_threshold_s).sum())
    extra = {}
    if ttc_events is None:
        ttc_events = ssm_events
    elif ssm_events is not None:
        extra["ttc_below_1_5s_events_ssm"] = ssm_events
    hours = duration_s / 3600.0
    delay = (every["time_loss_s"] + every["depart_delay_s"]).groupby(every["vehicle_class"])
    return {
        "vehicles": len(trips),
        "travel_time_s": {str(k): finite_or_none(travel.get(k)) for k in distance_m.index},
        "delay_s": per_class(delay.mean()),
        "delay_s_others": others_delay_s(every),
        "throughput_vph": float(len(finished) / hours) if hours > 0 else None,
        "hard_brakes_per_1000_vkm": (float(hard_brake_events / vkm * 1000.0) if vkm > 0 else None),
        "ttc_below_1_5s_events": ttc_events,
        "co2_g_per_km": per_km("co2_mg"),
        "fuel_g_per_km": per_km("fuel_mg"),
        "vehicle_km": vkm,
        "trips_finished": len(finished),
        "vehicles_per_class": {str(k): int(v) for k, v in by_class.size().items()},
        "vehicles_not_departed": int((~departed).sum()),
        "depart_delay_s": per_class(every.groupby("vehicle_class")["depart_delay_s"].mean()),
        "exits_missed": int(exits_missed),
        **extra,
    }


def others_delay_s(trips: pd.DataFrame) -> float | None:
    """Mean delay [s] (timeLoss plus departDelay, as ``delay_s``) of the vehicles of ``trips``
    (:data:`TRIP_COLUMNS`, departed or not) that are not CAVs; None without one."""
    others = trips[trips["vehicle_class"] != "cav"]
    if others.empty:
        return None
    return finite_or_none((others["time_loss_s"] + others["depart_delay_s"]).mean())


SPEED_FIELD_COLUMNS = ("t_s", "s_m", "speed_mps", "samples")


def speed_field(
    df: pd.DataFrame,
    route_edges: Iterable[str] = (),
    cell_m: float = 100.0,
    period_s: float = 10.0,
) -> pd.DataFrame:
    """The space-time speed field along the route: the space-mean speed [m/s] of each cell of
    ``cell_m`` of route by ``period_s``, total distance over total time (Edie's definition; a
    trajectory table samples every vehicle every step, so it is the mean of the samples).

    Only vehicles on ``route_edges`` count (all, when empty): the route coordinate ``s_m`` of a
    vehicle on a ramp beside the route is not a place on it. Columns
    :data:`SPEED_FIELD_COLUMNS`: each cell's start in time and along the route, its speed and
    how many samples it holds (the weight for averaging fields of several runs)."""
    if route_edges and not df.empty:
        df = df[df["edge"].isin(set(route_edges))]  # a categorical column as it is
    if df.empty:
        return pd.DataFrame(columns=list(SPEED_FIELD_COLUMNS))
    cells = pd.DataFrame(
        {
            "t_s": np.floor(df["time_s"].to_numpy(dtype=float) / period_s) * period_s,
            "s_m": np.floor(df["s_m"].to_numpy(dtype=float) / cell_m) * cell_m,
            "speed_mps": df["speed_mps"].to_numpy(dtype=float),
        }
    )
    field = cells.groupby(["t_s", "s_m"], sort=True)["speed_mps"].agg(["mean", "size"])
    return field.reset_index().rename(columns={"mean": "speed_mps", "size": "samples"})


def mean_speed_field(fields: Iterable[pd.DataFrame]) -> pd.DataFrame:
    """Several runs' speed fields in one: each cell's speed weighted by its samples (so still
    total distance over total time); columns :data:`SPEED_FIELD_COLUMNS`."""
    frames = [f for f in fields if not f.empty]
    if not frames:
        return pd.DataFrame(columns=list(SPEED_FIELD_COLUMNS))
    all_cells = pd.concat(frames, ignore_index=True)
    all_cells["weighted"] = all_cells["speed_mps"] * all_cells["samples"]
    sums = all_cells.groupby(["t_s", "s_m"], sort=True)[["weighted", "samples"]].sum()
    sums["speed_mps"] = sums["weighted"] / sums["samples"]
    return sums.reset_index()[list(SPEED_FIELD_COLUMNS)]
