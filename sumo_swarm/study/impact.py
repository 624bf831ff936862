"""Traffic-impact study of a batch: tables (CSV + markdown) and PNG plots across the sweep.

``impact(DIR)`` reads ``DIR/results.parquet`` and ``DIR/sweep.json`` (written by
``sumo-swarm batch``) and writes, in ``DIR/impact/``:

* ``runs.csv``: one row per successful run, its parameters, key measures and its gains;
* ``mobility.csv``: per swept parameter value and controller, the CAVs' mean speed, travel
  time, share of runs that overtook, and the **mobility gain** over the reference controller
  (``cacc``, the paper's baseline): ``gain.mean_speed_pct = (v - v_ref) / v_ref * 100`` and
  ``gain.travel_time_pct = (T_ref - T) / T_ref * 100``, each run compared with the reference
  run of the same parameters and seed, then averaged;
* ``upstream.csv``: per value and controller, the upstream influence: HVs influenced, the
  first follower's speed reduction (means over runs), the smallest gap and headway (minimum);
* ``network.csv``: per value and controller, the ``network`` block's measures from SUMO's own
  outputs (throughput, hard brakes per 1000 vehicle-km, TTC conflicts, and travel time, delay
  and CO2 per km for each vehicle class), means over runs, when the runs have that block;
* ``speed_field.csv`` and ``speed_field.png``: per controller, the space-time speed field along
  the route (each run's ``network_speed_field.parquet``, weighted by samples), a row per value
  of the first swept parameter (all runs in one when it has more than ``SPEED_FIELD_ROWS``
  values or nothing is swept), heatmaps on one colour scale;
* ``flow_density.csv`` and ``flow_density.png``: every edge and interval of SUMO's edge data
  (each run's ``network_edges.parquet``) as a point of flow against density per lane, a panel
  per controller, coloured by the first swept parameter: the fundamental diagram each
  controller's traffic drew;
* ``safety.csv``: per controller, collisions, hard brakes, teleports (sums), the smallest TTC
  and CAV gap;
* ``impact.md`` (the same tables) and the plots ``mobility_vs_<param>.png``,
  ``upstream_vs_<param>.png``, ``network_vs_<param>.png`` (one per swept parameter) and
  ``safety.png``.

Means are over the runs of a group (seeds, and the other parameters' values).
"""

from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from sumo_swarm.errors import ConfigError
from sumo_swarm.sim.network import (
    EDGES_FILE,
    SPEED_FIELD_COLUMNS,
    SPEED_FIELD_FILE,
    mean_speed_field,
)
from sumo_swarm.userfiles import read_user_json, read_user_parquet

REFERENCE = "cacc"
ALL = "(all)"  # the parameter name of the one group of a sweep that varies nothing

SPEED, TRAVEL = "cav.mean_speed_mps", "cav.travel_time_s"
GAIN_SPEED, GAIN_TRAVEL = "gain.mean_speed_pct", "gain.travel_time_pct"

# (column, how runs are aggregated, heading, plotted)
MOBILITY = (
    (SPEED, "mean", "CAV mean speed [m/s]", True),
    (TRAVEL, "mean", "CAV travel time [s]", False),
    ("overtake.all_past", "mean", "all CAVs got past (share of runs)", False),
    (GAIN_SPEED, "mean", "mobility gain, speed [%]", True),
    (GAIN_TRAVEL, "mean", "mobility gain, travel time [%]", False),
)
UPSTREAM = (
    ("upstream.hv_influenced", "mean", "upstream HVs influenced", True),
    ("upstream.first_follower_reduction_pct", "mean", "1st follower's speed reduction [%]", True),
    ("upstream.max_reduction_pct", "mean", "largest speed reduction [%]", False),
    ("upstream.min_gap_m", "min", "smallest upstream gap [m]", False),
    ("upstream.min_headway_s", "min", "smallest upstream headway [s]", True),
)
SAFETY = (
    ("safety.collisions", "sum", "collisions", True),
    ("safety.hard_brakes", "sum", "hard brakes", True),
    ("safety.teleports", "sum", "teleports", True),
    ("safety.min_ttc_s", "min", "smallest TTC [s]", False),
    ("cav.gap_min_m", "min", "smallest CAV gap [m]", False),
)

# The network block's measures (from SUMO's own outputs): per class where the block has classes,
# found in the batch's columns (network.delay_s.cav, network.delay_s.truck, ...).
NETWORK_SCALARS = (
    ("network.throughput_vph", "mean", "throughput [veh/h]", False),
    ("network.hard_brakes_per_1000_vkm", "mean", "hard brakes per 1000 veh-km", True),
    ("network.ttc_below_1_5s_events", "mean", "TTC < 1.5 s conflicts", False),
)
NETWORK_PER_CLASS = (
    ("network.travel_time_s", "travel time {} [s]", False),
    ("network.delay_s", "delay {} [s]", True),
    ("network.co2_g_per_km", "CO2 {} [g/km]", True),
)


def network_measures(columns) -> tuple:
    """The impact measures of the ``network`` block found among ``columns``: its scalars, then
    each per-class measure for every class present (means over runs)."""
    present = set(columns)
    measures = [m for m in NETWORK_SCALARS if m[0] in present]
    for prefix, heading, plotted in NETWORK_PER_CLASS:
        for column in sorted(c for c in present if c.startswith(prefix + ".")):
            cls = column.removeprefix(prefix + ".")
            measures.append((column, "mean", heading.format(cls), plotted))
    return tuple(measures)


# --------------------------------------------------------------------------- tables


def _to_float(value: Any) -> float:
    if value is None or isinstance(value, str):
        return math.nan
    try:
        return float(value)
    except (TypeError, ValueError):
        return math.nan


def numeric(series: pd.Series) -> pd.Series:
    """A column as floats (booleans as 0/1, missing and text as NaN)."""
    return series.map(_to_float).astype("float64")


def _yes_no(value: Any) -> Any:
    return ("yes" if value else "no") if isinstance(value, bool | np.bool_) else value


def markdown_table(df: pd.DataFrame, digits: int = 3) -> str:
    """``df`` as a GitHub markdown table (floats to ``digits`` decimals, missing as ``-``)."""
    cells = df.map(_yes_no).astype(object)
    cells = cells.where(cells.notna(), None)  # tabulate shows None, not NaN, as missing
    return cells.to_markdown(index=False, floatfmt=f".{digits}f", missingval="-")


def read_batch(batch_dir: str | Path) -> tuple[pd.DataFrame, list[str]]:
    """``results.parquet`` and the sweep's parameter names; ConfigError if it is no batch."""
    d = Path(batch_dir)
    path = d / "results.parquet"
    if not path.exists():
        raise ConfigError(f"{d}: no results.parquet (is it the --out folder of a batch?)")
    df = read_table(path, "batch results", ("run_id", "status", "controller", "seed"))
    parameters: list[str] = []
    sweep = d / "sweep.json"
    if sweep.exists():
        named = read_user_json(sweep, "sweep record")
        named = named.get("parameters") if isinstance(named, dict) else None
        if not isinstance(named, list) or not all(isinstance(p, str) for p in named):
            raise ConfigError(f"{sweep}: malformed sweep record: no list of parameters")
        parameters = [p for p in named if p in df.columns]
    return df, parameters


# The columns of a run's edge data that flow_density reads.
EDGE_COLUMNS = (
    "edge", "begin_s", "density_veh_per_km", "lane_density_veh_per_km", "flow_veh_per_h",
    "speed_mps",
)  # fmt: skip


def read_table(path: Path, what: str, columns: tuple[str, ...] = ()) -> pd.DataFrame:
    """A table of the batch folder with ``columns``; ConfigError naming the file otherwise."""
    df = read_user_parquet(path, what)
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise ConfigError(f"{path}: malformed {what}: no column '{missing[0]}'")
    return df


def with_gains(ok: pd.DataFrame, parameters: list[str], reference: str = REFERENCE) -> pd.DataFrame:
    """``ok`` with the gain columns: each run against the ``reference`` run of the same
    parameters and seed (NaN where there is none)."""
    key = [*parameters, "seed"]
    out = ok.copy()
    for col in (SPEED, TRAVEL):
        out[col] = numeric(out[col]) if col in out else math.nan
    ref = out.loc[out["controller"] == reference, [*key, SPEED, TRAVEL]]
    ref = ref.drop_duplicates(key).rename(columns={SPEED: "_ref_speed", TRAVEL: "_ref_travel"})
    out = out.merge(ref, on=key, how="left")
    out[GAIN_SPEED] = (out[SPEED] - out["_ref_speed"]) / out["_ref_speed"] * 100.0
    out[GAIN_TRAVEL] = (out["_ref_travel"] - out[TRAVEL]) / out["_ref_travel"] * 100.0
    return out.drop(columns=["_ref_speed", "_ref_travel"])


def _aggregate(df: pd.DataFrame, by: list[str], measures: tuple) -> pd.DataFrame:
    rows = []
    for values, group in df.groupby(by, sort=True, dropna=False):
        values = values if isinstance(values, tuple) else (values,)
        row: dict[str, Any] = dict(zip(by, values, strict=True))
        row["runs"] = len(group)
        for column, how, _, _ in measures:
            x = numeric(group[column]) if column in group else pd.Series(dtype=float)
            row[column] = getattr(x, how)() if x.notna().any() else math.nan
        rows.append(row)
    return pd.DataFrame(rows, columns=[*by, "runs", *(m[0] for m in measures)])


def swept_parameters(df: pd.DataFrame, parameters: list[str]) -> dict[str, list[str]]:
    """The parameters that vary in ``df``, each with those that move in step with it.

    A parameter whose values split the runs exactly as an earlier one's do (the slow vehicle's
    speed and desired speed set together) is not studied twice.
    """
    swept: dict[str, list[str]] = {}
    for p in parameters:
        if df[p].nunique(dropna=False) < 2:
            continue
        twin = next((q for q in swept if _same_partition(df[q], df[p])), None)
        if twin is None:
            swept[p] = []
        else:
            swept[twin].append(p)
    return swept


def _same_partition(a: pd.Series, b: pd.Series) -> bool:
    pairs = pd.DataFrame({"a": a.astype(str), "b": b.astype(str)}).drop_duplicates()
    return pairs["a"].is_unique and pairs["b"].is_unique


def by_parameter(df: pd.DataFrame, parameters: list[str], measures: tuple) -> pd.DataFrame:
    """Per swept parameter, per value and controller: ``measures`` aggregated over runs."""
    swept = list(swept_parameters(df, parameters)) or [ALL]
    tables = []
    for p in swept:
        data = df.assign(**{ALL: ""}) if p == ALL else df
        t = _aggregate(data, [p, "controller"], measures).rename(columns={p: "value"})
        t.insert(0, "parameter", p)
        tables.append(t)
    return pd.concat(tables, ignore_index=True)


def safety_table(df: pd.DataFrame) -> pd.DataFrame:
    ok = df[df["status"] == "ok"]
    table = _aggregate(ok, ["controller"], SAFETY) if not ok.empty else pd.DataFrame()
    failed = df.groupby("controller")["status"].apply(lambda s: int((s != "ok").sum()))
    if table.empty:
        return failed.rename("failed").reset_index()
    table.insert(2, "failed", table["controller"].map(failed).fillna(0).astype(int))
    runs_hit = ok.groupby("controller")["safety.collisions"].apply(
        lambda s: int((numeric(s) > 0).sum())
    )
    table.insert(4, "runs with a collision", table["controller"].map(runs_hit))
    return table


# --------------------------------------------------------------------------- plots


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", text).strip("_") or "all"


def _x_positions(values: pd.Series) -> tuple[np.ndarray, list[str] | None]:
    x = numeric(values)
    if x.notna().all():
        return x.to_numpy(), None
    labels = sorted(values.astype(str).unique())
    return values.astype(str).map(labels.index).to_numpy(dtype=float), labels


def _line_panels(table: pd.DataFrame, parameter: str, measures: tuple, path: Path) -> None:
    shown = [m for m in measures if m[3] and table[m[0]].notna().any()]
    if not shown:
        return
    fig = Figure(figsize=(4.2 * len(shown), 3.4), layout="constrained")
    axes = fig.subplots(1, len(shown), squeeze=False)[0]
    for ax, (column, _, heading, _) in zip(axes, shown, strict=True):
        for controller, group in table.groupby("controller", sort=True):
            if group[column].notna().any():
                x, labels = _x_positions(group["value"])
                order = np.argsort(x)
                ax.plot(x[order], group[column].to_numpy()[order], marker="o", label=controller)
                if labels:
                    ax.set_xticks(range(len(labels)), labels)
        ax.set_xlabel(parameter if parameter != ALL else "")
        ax.set_ylabel(heading)
        ax.grid(alpha=0.3)
        ax.legend(fontsize="small")
    fig.savefig(path, dpi=120)


def _safety_plot(table: pd.DataFrame, path: Path) -> None:
    shown = [m for m in SAFETY if m[3] and m[0] in table]
    if table.empty or not shown:
        return
    fig = Figure(figsize=(1.6 + 1.2 * len(table) * len(shown) / 2, 3.4), layout="constrained")
    ax = fig.subplots()
    width = 0.8 / len(shown)
    x = np.arange(len(table))
    for i, (column, _, heading, _) in enumerate(shown):
        ax.bar(x + i * width, table[column].fillna(0), width, label=heading)
    ax.set_xticks(x + width * (len(shown) - 1) / 2, table["controller"])
    ax.set_ylabel("count over all runs")
    top = float(np.nanmax(table[[m[0] for m in shown]].to_numpy(dtype=float), initial=0.0))
    ax.set_ylim(0, max(1.0, top * 1.15))
    ax.yaxis.set_major_locator(MaxNLocator(integer=True))
    ax.legend(fontsize="small")
    ax.grid(axis="y", alpha=0.3)
    fig.savefig(path, dpi=120)


# Rows of the speed-field figure at most: one per value of the first swept parameter; a sweep
# of more values is drawn as one row, all its runs in one.
SPEED_FIELD_ROWS = 6


def speed_fields(
    batch_dir: Path, runs: pd.DataFrame, parameter: str | None = None
) -> dict[tuple[str, str], pd.DataFrame]:
    """The space-time speed field of each controller's runs in one (each run's
    ``network_speed_field.parquet``, weighted by samples: :func:`mean_speed_field`), per
    value of ``parameter`` when given (else every run in one: value ``ALL``). Keys
    ``(value, controller)``; a group without any field is left out."""
    by = [parameter, "controller"] if parameter else ["controller"]
    fields = {}
    for key, group in runs.groupby(by, sort=True):
        key = key if isinstance(key, tuple) else (key,)
        value, controller = (str(key[0]), str(key[1])) if parameter else (ALL, str(key[0]))
        paths = [batch_dir / "runs" / str(r) / SPEED_FIELD_FILE for r in group["run_id"]]
        field = mean_speed_field(
            read_table(p, "speed field", SPEED_FIELD_COLUMNS) for p in paths if p.exists()
        )
        if not field.empty:
            fields[(value, controller)] = field
    return fields


def _cell_edges(values: np.ndarray) -> np.ndarray:
    """The edges of cells that start at ``values`` (sorted, evenly spaced but for gaps)."""
    step = float(np.min(np.diff(values))) if len(values) > 1 else 1.0
    return np.append(values, values[-1] + step)


def _speed_field_plot(
    fields: dict[tuple[str, str], pd.DataFrame], parameter: str | None, path: Path
) -> None:
    if not fields:
        return
    values = list(dict.fromkeys(v for v, _ in fields))
    controllers = sorted({c for _, c in fields})
    speeds = np.concatenate([f["speed_mps"].to_numpy(dtype=float) for f in fields.values()])
    low, high = float(np.nanmin(speeds)), float(np.nanmax(speeds))
    fig = Figure(
        figsize=(1.0 + 4.0 * len(controllers), 0.6 + 3.2 * len(values)), layout="constrained"
    )
    axes = fig.subplots(len(values), len(controllers), squeeze=False, sharex=True, sharey=True)
    mesh = None
    for i, value in enumerate(values):
        for j, controller in enumerate(controllers):
            ax = axes[i][j]
            field = fields.get((value, controller))
            title = controller if value == ALL else f"{controller}, {parameter} = {value}"
            ax.set_title(title, fontsize="small")
            if field is None:
                continue
            grid = field.pivot_table(index="s_m", columns="t_s", values="speed_mps")
            t, s_m = grid.columns.to_numpy(dtype=float), grid.index.to_numpy(dtype=float)
            mesh = ax.pcolormesh(
                _cell_edges(t), _cell_edges(s_m), np.ma.masked_invalid(grid.to_numpy(float)),
                cmap="RdYlGn", vmin=low, vmax=high,
            )  # fmt: skip
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    for row in axes:
        row[0].set_ylabel("position along the route [m]")
    fig.colorbar(mesh, ax=axes.ravel().tolist(), label="space-mean speed [m/s]")
    fig.savefig(path, dpi=120)


def flow_density(batch_dir: Path, runs: pd.DataFrame, parameter: str | None = None) -> pd.DataFrame:
    """Every edge and interval of each run's edge data (``network_edges.parquet``) with
    vehicles on it: ``density_veh_per_km_lane`` and ``flow_veh_per_h_lane`` (the edge's flow
    spread over its lanes, as its density is), with the run's controller, run id and, when
    given, its value of ``parameter``. Empty when no run has edge data."""
    frames = []
    for row in runs.to_dict("records"):
        path = batch_dir / "runs" / str(row["run_id"]) / EDGES_FILE
        if not path.exists():
            continue
        edges = read_table(path, "edge data", EDGE_COLUMNS)
        edges = edges[(edges["density_veh_per_km"] > 0) & edges["flow_veh_per_h"].notna()]
        lanes = edges["density_veh_per_km"] / edges["lane_density_veh_per_km"]
        frames.append(
            pd.DataFrame({
                "run_id": row["run_id"],
                "controller": row["controller"],
                "value": str(row[parameter]) if parameter else ALL,
                "edge": edges["edge"],
                "begin_s": edges["begin_s"],
                "density_veh_per_km_lane": edges["lane_density_veh_per_km"],
                "flow_veh_per_h_lane": edges["flow_veh_per_h"] / lanes,
                "speed_mps": edges["speed_mps"],
            })
        )  # fmt: skip
    return pd.concat(frames, ignore_index=True) if frames else pd.DataFrame()


def _flow_density_plot(points: pd.DataFrame, parameter: str | None, path: Path) -> None:
    if points.empty:
        return
    controllers = sorted(points["controller"].unique())
    values = sorted(points["value"].unique(), key=lambda v: (numeric(pd.Series([v]))[0], v))
    colours = {v: f"C{i % 10}" for i, v in enumerate(values)}
    fig = Figure(figsize=(1.0 + 3.6 * len(controllers), 3.6), layout="constrained")
    axes = fig.subplots(1, len(controllers), squeeze=False, sharex=True, sharey=True)[0]
    for ax, controller in zip(axes, controllers, strict=True):
        mine = points[points["controller"] == controller]
        for value in values:
            group = mine[mine["value"] == value]
            label = value if parameter is None else f"{parameter} = {value}"
            ax.scatter(
                group["density_veh_per_km_lane"], group["flow_veh_per_h_lane"], s=6,
                alpha=0.5, color=colours[value], label=label if value != ALL else None,
            )  # fmt: skip
        ax.set_title(controller, fontsize="small")
        ax.set_xlabel("density [veh/km/lane]")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("flow [veh/h/lane]")
    if parameter is not None:
        axes[-1].legend(fontsize="x-small", markerscale=2)
    fig.savefig(path, dpi=120)


# --------------------------------------------------------------------------- entry point


def _headings(table: pd.DataFrame, measures: tuple) -> pd.DataFrame:
    return table.rename(columns={m[0]: m[2] for m in measures})


def impact(
    batch_dir: str | Path, out_dir: str | Path | None = None, reference: str = REFERENCE
) -> Path:
    """Write the impact tables and plots of the batch in ``batch_dir``; returns impact.md."""
    df, parameters = read_batch(batch_dir)
    out = Path(out_dir) if out_dir is not None else Path(batch_dir) / "impact"
    out.mkdir(parents=True, exist_ok=True)
    ok = df[df["status"] == "ok"]
    runs = with_gains(ok, parameters, reference)
    keep = [*parameters, "controller", "seed", "run_id"]
    net = network_measures(runs.columns)
    keep += [m[0] for m in (*MOBILITY, *UPSTREAM, *SAFETY, *net) if m[0] in runs.columns]
    runs = runs[list(dict.fromkeys(keep))]
    mobility = by_parameter(runs, parameters, MOBILITY)
    upstream = by_parameter(runs, parameters, UPSTREAM)
    network = by_parameter(runs, parameters, net) if net else pd.DataFrame()
    safety = safety_table(df)
    runs.to_csv(out / "runs.csv", index=False)
    mobility.to_csv(out / "mobility.csv", index=False)
    upstream.to_csv(out / "upstream.csv", index=False)
    if net:
        network.to_csv(out / "network.csv", index=False)
    safety.to_csv(out / "safety.csv", index=False)

    has_reference = (runs["controller"] == reference).any()
    lines = [f"# Traffic impact: {Path(batch_dir).resolve().name}", ""]
    lines.append(
        f"{len(df)} runs ({int((df['status'] == 'ok').sum())} ok), parameters: "
        f"{', '.join(f'`{p}`' for p in parameters) or 'none'}. Gains are against "
        f"`{reference}` runs with the same parameters and seed"
        + ("." if has_reference else " (none in this batch).")
    )
    for p, twins in swept_parameters(runs, parameters).items():
        if twins:
            moved = ", ".join(f"`{t}`" for t in twins)
            lines += ["", f"{moved} moved in step with `{p}`: shown by `{p}` only."]
    for p, group in mobility.groupby("parameter", sort=False):
        slug = _slug(p)
        _line_panels(group, p, MOBILITY, out / f"mobility_vs_{slug}.png")
        _line_panels(
            upstream[upstream["parameter"] == p], p, UPSTREAM, out / f"upstream_vs_{slug}.png"
        )
        if net:
            _line_panels(network[network["parameter"] == p], p, net, out / f"network_vs_{slug}.png")
    sections = [
        ("Mobility", mobility, MOBILITY, "mobility"),
        ("Upstream influence", upstream, UPSTREAM, "upstream"),
    ]
    if net:
        sections.append(("Network, from SUMO's outputs", network, net, "network"))
    for title, table, measures, stem in sections:
        lines += ["", f"## {title}", ""]
        if table.empty:
            lines += ["No successful run.", ""]
        for p, group in table.groupby("parameter", sort=False):
            lines += [f"By `{p}`:" if p != ALL else "All runs:", ""]
            lines += [markdown_table(_headings(group.drop(columns="parameter"), measures)), ""]
            png = out / f"{stem}_vs_{_slug(p)}.png"
            if png.is_file():
                lines += [f"![{title} vs {p}]({png.name})", ""]
    swept = list(swept_parameters(runs, parameters))
    by = swept[0] if swept and runs[swept[0]].nunique() <= SPEED_FIELD_ROWS else None
    fields = speed_fields(Path(batch_dir), runs, by)
    if fields:
        pd.concat(
            [f.assign(value=v, controller=c) for (v, c), f in fields.items()], ignore_index=True
        ).to_csv(out / "speed_field.csv", index=False)
        _speed_field_plot(fields, by, out / "speed_field.png")
        per = f"for each value of `{by}`" if by else "all its runs in one"
        lines += ["", "## Space-time speed", ""]
        lines += [
            f"The speed along the route over time: each controller's runs {per} (every "
            "cell's space-mean speed, total distance over total time), on one colour scale.",
            "",
            "![Space-time speed per controller](speed_field.png)",
        ]
    colour_by = swept[0] if swept else None
    points = flow_density(Path(batch_dir), runs, colour_by)
    if not points.empty:
        points.to_csv(out / "flow_density.csv", index=False)
        _flow_density_plot(points, colour_by, out / "flow_density.png")
        lines += ["", "## Flow and density", ""]
        lines += [
            "Every edge and interval of SUMO's edge data as one point, flow against density "
            "per lane, a panel per controller"
            + (f", coloured by `{colour_by}`." if colour_by else "."),
            "",
            "![Flow against density per controller](flow_density.png)",
        ]
    _safety_plot(safety, out / "safety.png")
    lines += ["", "## Safety", "", markdown_table(_headings(safety, SAFETY)), ""]
    if (out / "safety.png").is_file():
        lines += ["![Safety per controller](safety.png)", ""]
    md = out / "impact.md"
    md.write_text("\n".join(lines), encoding="utf-8")
    return md
