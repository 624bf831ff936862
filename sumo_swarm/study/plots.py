"""Figures of the paper's Section IV (Figs. 7-12), drawn from the outputs of finished runs.

Every function reads plain data (the trajectory table, summary.json, a plans.jsonl record) and
writes one PNG. No SUMO import and no pyplot: figures are built on matplotlib's object API with
the Agg canvas, so drawing never touches a global backend or opens a window.

The trajectory table has the columns of the output contract (``time_s, vehicle, kind, lane,
s_m, lat_m, speed_mps, length_m, ...``; ``s_m`` is the front bumper along the route [m]).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch, Rectangle

from sumo_swarm.config import Scenario
from sumo_swarm.core.grid import MovingGrid, hv_blocked_cells
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.errors import ConfigError
from sumo_swarm.safexml import parse_xml
from sumo_swarm.sim import metrics

DPI = 110
SUMO_DEFAULT_LANE_WIDTH_M = 3.2  # SUMO's lane width when the network does not give one [m]
# The paper colours the leading CAV green and the second yellow (Fig. 8); the rest follow.
CAV_COLOURS = ("#2ca02c", "#e0a800", "#1f77b4", "#d62728", "#9467bd", "#8c564b", "#e377c2")
HV_COLOUR = "#9a9a9a"
TARGET_COLOUR = "#303030"
CONTROLLER_STYLES = {
    "swarm": {"color": "#1f77b4", "lw": 2.2, "ls": "-"},
    "cacc": {"color": "#d62728", "lw": 1.8, "ls": "--"},
    "sumo-cacc": {"color": "#ff7f0e", "lw": 1.4, "ls": "-."},
    "sumo-lc": {"color": "#2ca02c", "lw": 1.4, "ls": ":"},
}
# Fig. 12's speed axes span at least this much: with 17.5 m/s traffic a 1 % change is 1/23 of it
MIN_SPEED_SPAN_MPS = 4.0
EVENT_GID = "event"  # gid of the event lines, so that labels do not avoid them
SNAPSHOT_MARGIN_M = 10.0  # road shown behind the last and ahead of the first vehicle, Fig. 8(b) [m]
RANK_COLOURS = ("#08306b", "#2171b5", "#4292c6", "#6baed6", "#9ecae1", "#c6dbef")

# file stem -> caption (the report lists the figures in this order)
FIGURES = {
    "fig7_plan": "Fig. 7: planned cells of each CAV per behaving step (the first plan)",
    "fig8_trajectories": "Fig. 8: vehicle trajectories of the swarm",
    "fig9_speeds": "Fig. 9: CAV speeds and the platoon's average speed",
    "fig10_gaps": "Fig. 10: following distances of the CAVs",
    "fig11_time_space": "Fig. 11: traffic in the left lane (time-space diagram)",
    "fig12_upstream": "Fig. 12: speeds and following distances of the upstream HVs",
}


# --------------------------------------------------------------------------------------------
# inputs


@dataclass
class RunData:
    """The outputs of one finished run, loaded lazily from its folder."""

    controller: str
    folder: Path
    summary: dict[str, Any]
    _df: pd.DataFrame | None = field(default=None, repr=False)

    @property
    def df(self) -> pd.DataFrame:
        if self._df is None:
            df = pd.read_parquet(self.folder / "trajectories.parquet")
            df["vehicle"] = df["vehicle"].astype(str)
            df["kind"] = df["kind"].astype(str)
            self._df = df
        return self._df

    def plans(self) -> list[dict[str, Any]]:
        path = self.folder / "plans.jsonl"
        if not path.is_file():
            return []
        lines = path.read_text(encoding="utf-8").splitlines()
        return [json.loads(line) for line in lines if line.strip()]


def lane_widths_m(scenario: Scenario) -> tuple[float, ...]:
    """Widths of the lanes of the route's first edge, read from the network file [m]."""
    edge_id = scenario.simulation.route_edges[0]
    root = parse_xml(scenario.network_path, what="SUMO network")
    for edge in root.iter("edge"):
        if edge.get("id") == edge_id:
            lanes = sorted(edge.iter("lane"), key=lambda lane: int(lane.get("index", "0")))
            return tuple(float(lane.get("width", SUMO_DEFAULT_LANE_WIDTH_M)) for lane in lanes)
    raise ConfigError(f"network {scenario.network_path} has no edge '{edge_id}'")


def lateral_position_m(df: pd.DataFrame, road: RoadSection) -> np.ndarray:
    """Lateral position of every row, from the centre of lane 0, left positive [m]."""
    centres = np.array([road.lane_centre_y(q) for q in range(road.n_lanes)])
    lanes = np.clip(df["lane"].to_numpy(dtype=int), 0, road.n_lanes - 1)
    return centres[lanes] + df["lat_m"].to_numpy(dtype=float)


def cav_colour(index: int) -> str:
    return CAV_COLOURS[index % len(CAV_COLOURS)]


def cav_ids(df: pd.DataFrame) -> list[str]:
    """CAV ids in platoon order (cav0 = leader), natural sort."""
    ids = df.loc[df["kind"] == metrics.CAV, "vehicle"].unique().tolist()
    return sorted(ids, key=_natural_key)


def _natural_key(text: str) -> tuple:
    head = text.rstrip("0123456789")
    tail = text[len(head) :]
    return (head, int(tail) if tail else -1)


def wide(df: pd.DataFrame, value: str) -> pd.DataFrame:
    """Time x vehicle table of one column (NaN where the vehicle has no sample)."""
    return df.pivot_table(index="time_s", columns="vehicle", values=value, observed=True)


def lane_name(lane: int, n_lanes: int) -> str:
    if n_lanes == 3:
        return ("right", "middle", "left")[lane]
    if lane == 0:
        return "right"
    if lane == n_lanes - 1:
        return "left"
    return f"lane {lane}"


# --------------------------------------------------------------------------------------------
# shared drawing helpers


def _new_figure(width_in: float, height_in: float) -> Figure:
    fig = Figure(figsize=(width_in, height_in), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def _save(fig: Figure, path: Path) -> Path:
    tmp = path.with_name(path.stem + ".tmp.png")
    fig.savefig(tmp, dpi=DPI)
    tmp.replace(path)
    return path


def _event_times(summary: Mapping[str, Any]) -> list[tuple[float, str]]:
    ot = summary.get("overtake") or {}
    events = [
        (ot.get("t_start_s"), "decision"),
        (ot.get("t_end_s"), "all CAVs past"),
        (ot.get("t_regrouped_s"), "regrouped"),
    ]
    return [(float(t), label) for t, label in events if t is not None]


def _mark_events(ax: Axes, summary: Mapping[str, Any]) -> None:
    """Dotted vertical lines at the manoeuvre's decision, pass and regroup times (label them
    with :func:`_label_events` once the axes hold their data and limits)."""
    for t, _ in _event_times(summary):
        ax.axvline(t, color="0.35", ls=":", lw=1.0, zorder=0, gid=EVENT_GID)


def _label_events(ax: Axes, summary: Mapping[str, Any], fontsize: float = 8.0) -> None:
    """Name the event lines, each in the tallest stretch of its line free of curves.

    Call after everything is plotted and the limits are set. A label is written upwards just
    right of its line; the curves it must not cover are the parts of every line (horizontal
    reference lines too) that pass through the label's column.
    """
    fig = ax.get_figure()
    width_px = max(ax.get_position().width * fig.get_figwidth() * fig.dpi, 1.0)
    height_px = max(ax.get_position().height * fig.get_figheight() * fig.dpi, 1.0)
    column = (fontsize * 1.6) * fig.dpi / 72.0 / width_px  # the label's width [axes fraction]
    to_axes = ax.transAxes.inverted()
    curves = []
    for line in ax.get_lines():
        if line.get_gid() == EVENT_GID or not line.get_visible():
            continue
        xy = np.asarray(line.get_xydata(), dtype=float)
        if len(xy):
            curves.append(to_axes.transform(line.get_transform().transform(xy)))
    x_lo, x_hi = ax.get_xlim()
    for t, label in _event_times(summary):
        if not x_lo <= t <= x_hi:
            continue
        xf = (t - x_lo) / (x_hi - x_lo)
        covered = _covered_heights(curves, xf - 0.1 * column, xf + column)
        low, high = _largest_gap(covered)
        needed = len(label) * 0.6 * fontsize * fig.dpi / 72.0 / height_px
        centre = 0.5 * (low + high)
        if high - low > needed + 0.04:  # room to spare: sit near the top of the gap
            centre = high - 0.02 - 0.5 * needed
        ax.annotate(
            label,
            (t, centre),
            xycoords=("data", "axes fraction"),
            xytext=(2, 0),
            textcoords="offset points",
            fontsize=fontsize,
            color="0.3",
            va="center",
            ha="left",
            rotation=90,
        )


def _covered_heights(
    curves: Sequence[np.ndarray], x_from: float, x_to: float
) -> list[tuple[float, float]]:
    """Height intervals [axes fraction] the curves (n x 2 arrays, axes fraction) cover between
    ``x_from`` and ``x_to``."""
    out = []
    for xy in curves:
        x, y = xy[:, 0], xy[:, 1]
        x0, x1, y0, y1 = x[:-1], x[1:], y[:-1], y[1:]
        ok = np.isfinite(x0) & np.isfinite(x1) & np.isfinite(y0) & np.isfinite(y1)
        lo_x, hi_x = np.minimum(x0, x1), np.maximum(x0, x1)
        hit = ok & (hi_x >= x_from) & (lo_x <= x_to)
        for a_x, b_x, a_y, b_y in zip(x0[hit], x1[hit], y0[hit], y1[hit], strict=True):
            if b_x == a_x:
                out.append((min(a_y, b_y), max(a_y, b_y)))
                continue
            ends = np.clip([x_from, x_to], min(a_x, b_x), max(a_x, b_x))
            ys = a_y + (ends - a_x) * (b_y - a_y) / (b_x - a_x)
            out.append((float(ys.min()), float(ys.max())))
    return out


def _largest_gap(covered: Sequence[tuple[float, float]], pad: float = 0.02) -> tuple[float, float]:
    """The tallest stretch of [0, 1] outside the ``covered`` intervals (each padded)."""
    edges = sorted(
        (max(lo - pad, 0.0), min(hi + pad, 1.0))
        for lo, hi in covered
        if hi >= -pad and lo <= 1.0 + pad
    )
    best, start = (0.0, 0.0), 0.0
    for lo, hi in edges:
        if lo > start and lo - start > best[1] - best[0]:
            best = (start, lo)
        start = max(start, hi)
    if 1.0 - start > best[1] - best[0]:
        best = (start, 1.0)
    return best


def _mark_window_end(ax: Axes, end_s: float | None, sim_end_s: float) -> None:
    """Shade the time after the evaluation window (not counted in the measures)."""
    if end_s is not None and end_s < sim_end_s:
        ax.axvspan(end_s, sim_end_s, color="0.92", zorder=-1, lw=0)


# --------------------------------------------------------------------------------------------
# Fig. 7: the plan


def plan_blocked_cells(
    record: Mapping[str, Any],
    df: pd.DataFrame,
    scenario: Scenario,
    road: RoadSection,
    target: str | None,
) -> tuple[list[dict[tuple[int, int], str]], list[dict[str, tuple[int, int]]]]:
    """Cells the HVs claimed in a plan, per behaving step, as the planner predicted them.

    Rebuilds the planner's view from the trajectory table: each HV's state at the plan's time,
    moved at constant speed to each behaving step, and the cells its safety margins cover
    (:func:`sumo_swarm.core.grid.hv_blocked_cells`, margins scaled as recorded in the plan).

    Returns ``(claimed, centres)``: per step, ``{cell: hv}`` of every claimed cell and
    ``{hv: cell}`` of the cell holding each HV's centre (in the grid only). The target HV
    wins a cell claimed by several HVs.
    """
    g = record["grid"]
    t0 = float(record["time_s"])
    grid = MovingGrid(
        g["origin_s_m"], g["t0_s"], g["speed_mps"], g["cell_length_m"], g["n_rows"], road
    )
    scale = float(record.get("margin_scale", 1.0))
    settings = replace(
        scenario.grid, cell_length_m=g["cell_length_m"], cav_length_m=scenario.cav.length_m
    )
    settings = replace(
        settings,
        headway_s=settings.headway_s * scale,
        gap_behind_m=settings.gap_behind_m * scale,
    )
    times = df["time_s"].to_numpy(dtype=float)
    t_row = times[np.argmin(np.abs(times - t0))]
    now = df[(times == t_row) & (df["kind"] != metrics.CAV)]
    n_steps = len(next(iter(record["cells"].values())))
    interval = scenario.planner.behaving_interval_s
    claimed: list[dict[tuple[int, int], str]] = [{} for _ in range(n_steps)]
    centres: list[dict[str, tuple[int, int]]] = [{} for _ in range(n_steps)]
    order = sorted(now.itertuples(index=False), key=lambda r: r.vehicle == target)
    for row in order:  # the target last, so its claim wins
        hv = VehicleState(
            str(row.vehicle), float(row.s_m), int(row.lane), float(row.lat_m),
            float(row.speed_mps), float(row.length_m),
        )  # fmt: skip
        for k in range(n_steps):
            t = t0 + k * interval
            moved = replace(hv, s_m=hv.s_m + hv.speed_mps * (t - t0))
            for cell in hv_blocked_cells(grid, moved, t, settings):
                claimed[k][cell] = hv.vehicle_id
            r = grid.row_of(moved.centre_s_m, t)
            c = road.lane_of(moved)
            if grid.contains(r, c):
                centres[k][hv.vehicle_id] = (r, c)
    return claimed, centres


def figure_plan(
    record: Mapping[str, Any],
    claimed: Sequence[Mapping[tuple[int, int], str]],
    centres: Sequence[Mapping[str, tuple[int, int]]],
    target: str | None,
    interval_s: float,
    path: Path,
) -> Path:
    """Small multiples: the grid at each behaving step with the cell planned for each CAV.

    Columns are lanes drawn as seen from the driver's seat (left lane on the left), rows count
    forward from the tail CAV's row. Grey hatched cells are claimed by an HV's footprint and
    safety margins; dark squares hold an HV's centre (T = the slow vehicle to overtake, B = an
    HV a CAV is assigned to block).
    """
    cells = {cav: [tuple(c) for c in seq] for cav, seq in record["cells"].items()}
    cav_order = sorted(cells, key=_natural_key)
    n_rows = int(record["grid"]["n_rows"])
    n_cols = int(record["grid"]["n_cols"])
    n_steps = len(next(iter(cells.values())))
    blockers = record.get("blockers") or {}
    blocked_hvs = set(blockers.values())
    per_row = min(n_steps, 7)
    n_fig_rows = math.ceil(n_steps / per_row)
    fig = _new_figure(1.55 * per_row + 0.6, 0.27 * n_rows * n_fig_rows + 1.6)
    axes = fig.subplots(n_fig_rows, per_row, squeeze=False, sharey=True)

    def x_of(col: int) -> int:
        return n_cols - 1 - col

    for k in range(n_fig_rows * per_row):
        ax = axes[k // per_row][k % per_row]
        if k >= n_steps:
            ax.set_visible(False)
            continue
        ax.set_xlim(-0.5, n_cols - 0.5)
        ax.set_ylim(-0.5, n_rows - 0.5)
        ax.set_aspect("equal")
        for r in range(n_rows + 1):
            ax.axhline(r - 0.5, color="0.85", lw=0.5)
        for c in range(n_cols + 1):
            ax.axvline(c - 0.5, color="0.6", lw=0.8)
        for r, c in claimed[k]:
            ax.add_patch(
                Rectangle(
                    (x_of(c) - 0.5, r - 0.5), 1, 1, facecolor="0.88", edgecolor="0.6",
                    hatch="////", lw=0.0, zorder=1,
                )
            )  # fmt: skip
        for hv, (r, c) in centres[k].items():
            ax.add_patch(
                Rectangle(
                    (x_of(c) - 0.42, r - 0.42), 0.84, 0.84, facecolor=TARGET_COLOUR,
                    zorder=2,
                )
            )  # fmt: skip
            tag = "T" if hv == target else "B" if hv in blocked_hvs else ""
            if tag:
                ax.text(x_of(c), r, tag, color="white", ha="center", va="center",
                        fontsize=7, fontweight="bold", zorder=3)  # fmt: skip
        for i, cav in enumerate(cav_order):
            r, c = cells[cav][k]
            ax.add_patch(
                Rectangle(
                    (x_of(c) - 0.42, r - 0.42), 0.84, 0.84, facecolor=cav_colour(i),
                    edgecolor="black" if cav in blockers else "none", lw=1.4, zorder=4,
                )
            )  # fmt: skip
            ax.text(x_of(c), r, str(i), color="white", ha="center", va="center",
                    fontsize=7, fontweight="bold", zorder=5)  # fmt: skip
        ax.set_title(f"step {k + 1}\n(+{k * interval_s:g} s)", fontsize=9)
        ax.set_xticks(range(n_cols))
        ax.set_xticklabels([lane_name(n_cols - 1 - x, n_cols)[0].upper() for x in range(n_cols)])
        ax.tick_params(labelsize=8)
        if k % per_row == 0:
            ax.set_ylabel("row (cells ahead of the tail CAV)", fontsize=9)
    handles = [
        Patch(facecolor=cav_colour(i), label=f"{cav}" + (" (blocks)" if cav in blockers else ""))
        for i, cav in enumerate(cav_order)
    ]
    handles += [
        Patch(facecolor=TARGET_COLOUR, label="HV's centre (T = slow HV, B = HV to block)"),
        Patch(facecolor="0.88", edgecolor="0.6", hatch="////", label="claimed by an HV"),
    ]
    g = record["grid"]
    blocks = ", ".join(f"{c} blocks {h}" for c, h in blockers.items()) or "no blocking"
    fig.suptitle(
        f"Planned cells of each CAV, plan made at t = {float(record['time_s']):.2f} s; "
        f"cells {g['cell_length_m']:g} m long moving at {g['speed_mps']:.2f} m/s; {blocks}\n"
        "columns: L = left, M = middle, R = right lane; black outline: a CAV assigned to block",
        fontsize=10,
    )
    fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 8),
               fontsize=8, frameon=False)  # fmt: skip
    return _save(fig, path)


# --------------------------------------------------------------------------------------------
# Fig. 8: trajectories


def snapshot_times(summary: Mapping[str, Any], sim_end_s: float) -> list[tuple[float, str]]:
    """Instants of Fig. 8: the decision, +3 s, +9 s (as in the paper), all past, regrouped."""
    ot = summary.get("overtake") or {}
    t0 = ot.get("t_start_s")
    if t0 is None:
        return [(0.0, "start")]
    out = [(t0, "decision"), (t0 + 3.0, "+3 s"), (t0 + 9.0, "+9 s")]
    if ot.get("t_end_s") is not None:
        out.append((ot["t_end_s"], "all CAVs past"))
    if ot.get("t_regrouped_s") is not None:
        out.append((ot["t_regrouped_s"], "regrouped"))
    out = sorted({round(t, 6): label for t, label in out if t <= sim_end_s}.items())
    return [(t, label) for t, label in out]


def figure_trajectories(
    df: pd.DataFrame,
    summary: Mapping[str, Any],
    road: RoadSection,
    widths_m: Mapping[str, float],
    path: Path,
) -> Path:
    """Write :func:`draw_trajectories` to ``path`` (PNG)."""
    return _save(draw_trajectories(df, summary, road, widths_m), path)


def draw_trajectories(
    df: pd.DataFrame,
    summary: Mapping[str, Any],
    road: RoadSection,
    widths_m: Mapping[str, float],
) -> Figure:
    """(a) lateral position against distance along the road during the manoeuvre;
    (b) snapshots of the scene around the slow HV at the key instants."""
    target = (summary.get("overtake") or {}).get("target")
    times = np.sort(df["time_s"].unique())
    sim_end = float(times[-1])
    events = [t for t, _ in _event_times(summary)]
    t_from = max(float(times[0]), (min(events) if events else 0.0) - 3.0)
    t_to = min(sim_end, (max(events) if events else sim_end) + 6.0)
    d = df[(df["time_s"] >= t_from) & (df["time_s"] <= t_to)].copy()
    d["y"] = lateral_position_m(d, road)
    snaps = snapshot_times(summary, sim_end)

    fig = _new_figure(12.5, 3.2 + 1.05 * len(snaps))
    gs = fig.add_gridspec(1 + len(snaps), 1, height_ratios=[3.0] + [1.0] * len(snaps))
    ax = fig.add_subplot(gs[0])
    cavs = cav_ids(df)
    y_lines = _lane_edges(road)
    for y in y_lines:
        ax.axhline(y, color="0.75", lw=0.8, ls="--" if y not in (y_lines[0], y_lines[-1]) else "-")
    for vid, g in d[d["kind"] != metrics.CAV].groupby("vehicle", sort=True):
        is_target = vid == target
        ax.plot(g["s_m"], g["y"], color=TARGET_COLOUR if is_target else HV_COLOUR,
                lw=2.0 if is_target else 0.9, zorder=3 if is_target else 1)  # fmt: skip
    for i, vid in enumerate(cavs):
        g = d[d["vehicle"] == vid]
        ax.plot(g["s_m"], g["y"], color=cav_colour(i), lw=1.8, label=vid, zorder=2)
    for lane in range(road.n_lanes):
        ax.annotate(f"{lane_name(lane, road.n_lanes)} lane", (0.0, road.lane_centre_y(lane)),
                    xycoords=("axes fraction", "data"), xytext=(4, 3),
                    textcoords="offset points", fontsize=8, color="0.4")  # fmt: skip
    ax.set_xlabel("distance along the road s (m, front bumper)")
    ax.set_ylabel("lateral position y (m)")
    ax.set_ylim(y_lines[0] - 0.3, y_lines[-1] + 0.3)
    ax.set_title(
        f"(a) Trajectories from t = {t_from:.1f} s to {t_to:.1f} s "
        "(y from the centre of the right lane, left positive)",
        fontsize=10,
    )
    handles = [Line2D([], [], color=cav_colour(i), lw=2, label=v) for i, v in enumerate(cavs)]
    handles += [
        Line2D([], [], color=TARGET_COLOUR, lw=1.6, label=f"slow HV ({target})"),
        Line2D([], [], color=HV_COLOUR, lw=1, label="other HVs"),
    ]
    ax.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)

    scenes = []  # per snapshot: the rows, x of each front bumper, the window's centre
    for t, _ in snaps:
        at = df[np.isclose(df["time_s"], t, atol=1e-6)]
        if at.empty:
            at = df[df["time_s"] == times[np.argmin(np.abs(times - t))]]
        ref = at.loc[at["vehicle"] == target, "s_m"]
        s_ref = float(ref.iloc[0]) if not ref.empty else float(at["s_m"].median())
        x = at["s_m"].to_numpy(dtype=float) - s_ref
        main = ((at["kind"] == metrics.CAV) | (at["vehicle"] == target)).to_numpy()
        if not main.any():
            main[:] = True
        rear = x[main] - at["length_m"].to_numpy(dtype=float)[main]
        scenes.append((at, x, float(rear.min()), float(x[main].max())))
    # one window length for all snapshots, to scale (1 m across = 1 m along): the swarm and
    # the slow HV with room around them
    span = max(hi - lo for _, _, lo, hi in scenes) + 2.0 * SNAPSHOT_MARGIN_M
    centres = [road.lane_centre_y(q) for q in range(road.n_lanes)]
    for j, ((t, label), (at, x, lo, hi)) in enumerate(zip(snaps, scenes, strict=True)):
        sub = fig.add_subplot(gs[1 + j])
        x_from = 0.5 * (lo + hi) - 0.5 * span
        ys = lateral_position_m(at, road)
        for row, xf, y in zip(at.itertuples(index=False), x, ys, strict=True):
            if not x_from - 10.0 <= xf <= x_from + span + 10.0:
                continue
            is_cav = row.kind == metrics.CAV
            colour = (
                cav_colour(cavs.index(row.vehicle))
                if is_cav
                else TARGET_COLOUR
                if row.vehicle == target
                else HV_COLOUR
            )
            w = widths_m["cav" if is_cav else "hv"]
            sub.add_patch(
                Rectangle(
                    (xf - row.length_m, y - w / 2),
                    row.length_m,
                    w,
                    facecolor=colour,
                    edgecolor="black",
                    lw=0.4,
                )
            )
        for y in y_lines:
            sub.axhline(
                y, color="0.75", lw=0.8, ls="--" if y not in (y_lines[0], y_lines[-1]) else "-"
            )
        sub.set_xlim(x_from, x_from + span)
        sub.set_ylim(y_lines[0] - 0.5, y_lines[-1] + 0.5)
        sub.set_aspect("equal", adjustable="box")
        sub.set_yticks(centres, [lane_name(q, road.n_lanes) for q in range(road.n_lanes)])
        sub.tick_params(labelsize=7)
        sub.set_ylabel("lane", fontsize=8)
        sub.text(
            1.005,
            0.5,
            f"t = {t:.2f} s\n{label}",
            transform=sub.transAxes,
            fontsize=8,
            va="center",
        )
        if j == 0:
            sub.set_title(
                "(b) The scene around the slow HV (black) at key instants, to scale", fontsize=10
            )
    sub.set_xlabel("distance ahead of the slow HV's front bumper (m)")
    return fig


def _lane_edges(road: RoadSection) -> list[float]:
    edges = [-0.5 * road.lane_widths_m[0]]
    for w in road.lane_widths_m:
        edges.append(edges[-1] + w)
    return edges


# --------------------------------------------------------------------------------------------
# Fig. 9: speeds


def platoon_speed(df: pd.DataFrame) -> pd.Series:
    """Average speed over the CAVs at each step [m/s] (index: time_s)."""
    cav = df[df["kind"] == metrics.CAV]
    return cav.groupby("time_s")["speed_mps"].mean()


def figure_speeds(
    runs: Mapping[str, RunData],
    focus: str,
    window: tuple[float, float],
    paper_speeds: Mapping[str, float],
    path: Path,
) -> Path:
    """Write :func:`draw_speeds` to ``path`` (PNG)."""
    return _save(draw_speeds(runs, focus, window, paper_speeds), path)


def draw_speeds(
    runs: Mapping[str, RunData],
    focus: str,
    window: tuple[float, float],
    paper_speeds: Mapping[str, float],
) -> Figure:
    """(a) each CAV's speed under ``focus`` and the platoon average, with cacc's average;
    (b) the platoon average speed of every controller."""
    main = runs[focus]
    df = main.df
    fig = _new_figure(11, 7.5)
    ax_a, ax_b = fig.subplots(2, 1, sharex=True)
    sim_end = float(df["time_s"].max())
    for ax in (ax_a, ax_b):
        _mark_window_end(ax, window[1], sim_end)
        _mark_events(ax, main.summary)
    speeds = wide(df[df["kind"] == metrics.CAV], "speed_mps")
    for i, vid in enumerate(cav_ids(df)):
        ax_a.plot(speeds.index, speeds[vid], color=cav_colour(i), lw=1.0, label=vid)
    ax_a.plot(*_xy(platoon_speed(df)), color="black", lw=2.2, label=f"{focus}: platoon average")
    if "cacc" in runs and focus != "cacc":
        ax_a.plot(*_xy(platoon_speed(runs["cacc"].df)), **CONTROLLER_STYLES["cacc"],
                  label="cacc: platoon average")  # fmt: skip
    ax_a.set_ylabel("speed (m/s)")
    ax_a.set_title(f"(a) Speed of each CAV ({focus})", fontsize=10)
    ax_a.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    for name, run in runs.items():
        mean = (run.summary.get("cav") or {}).get("mean_speed_mps")
        label = f"{name} (window mean {mean:.2f} m/s)" if mean is not None else name
        style = CONTROLLER_STYLES.get(name, {"color": "0.3", "lw": 1.2, "ls": "-"})
        ax_b.plot(*_xy(platoon_speed(run.df)), **style, label=label)
    for name, value in paper_speeds.items():
        ax_b.axhline(value, color=CONTROLLER_STYLES.get(name, {}).get("color", "0.3"), lw=0.8,
                     ls=(0, (1, 3)), label=f"paper, {name}: {value:.2f} m/s (mean)")  # fmt: skip
    ax_b.set_xlabel("time (s)   [shaded: after the evaluation window]")
    ax_b.set_ylabel("platoon average speed (m/s)")
    ax_b.set_title("(b) Average speed of the six CAVs, per controller", fontsize=10)
    ax_b.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    ax_b.set_xlim(0, sim_end)
    _label_events(ax_a, main.summary)
    return fig


def _xy(series: pd.Series) -> tuple[np.ndarray, np.ndarray]:
    return series.index.to_numpy(dtype=float), series.to_numpy(dtype=float)


# --------------------------------------------------------------------------------------------
# Fig. 10: CAV gaps


def figure_gaps(
    df: pd.DataFrame,
    summary: Mapping[str, Any],
    min_gap_m: float,
    desired_gap_m: float,
    window: tuple[float, float],
    path: Path,
) -> Path:
    """Write :func:`draw_gaps` to ``path`` (PNG)."""
    return _save(draw_gaps(df, summary, min_gap_m, desired_gap_m, window), path)


def draw_gaps(
    df: pd.DataFrame,
    summary: Mapping[str, Any],
    min_gap_m: float,
    desired_gap_m: float,
    window: tuple[float, float],
) -> Figure:
    """Bumper-to-bumper gap of each CAV to the vehicle ahead in its lane, over time."""
    g = metrics.gaps(df)
    g = g[(g["kind"] == metrics.CAV)]
    table = g.pivot_table(index="time_s", columns="vehicle", values="gap_m", observed=True)
    fig = _new_figure(11, 4.8)
    ax = fig.subplots()
    sim_end = float(df["time_s"].max())
    _mark_window_end(ax, window[1], sim_end)
    _mark_events(ax, summary)
    for i, vid in enumerate(cav_ids(df)):
        if vid in table.columns:
            ax.plot(table.index, table[vid], color=cav_colour(i), lw=1.2, label=vid)
    ax.axhline(desired_gap_m, color="0.2", ls="--", lw=1.2,
               label=f"desired safety distance {desired_gap_m:g} m")  # fmt: skip
    ax.axhline(min_gap_m, color="black", ls="-", lw=1.6,
               label=f"minimum safety distance {min_gap_m:g} m")  # fmt: skip
    cav = summary.get("cav") or {}
    if cav.get("gap_mean_m") is not None:
        ax.axhline(cav["gap_mean_m"], color="0.5", ls=(0, (1, 2)), lw=1.0,
                   label=f"mean over the window {cav['gap_mean_m']:.2f} m")  # fmt: skip
    top = np.nanmax(table.to_numpy()) if table.size else desired_gap_m
    ax.set_ylim(0, max(2.0 * desired_gap_m, float(top) * 1.08))
    ax.set_xlim(0, sim_end)
    ax.set_xlabel("time (s)   [shaded: after the evaluation window; a gap ends when no "
                  "vehicle is ahead in the lane]")  # fmt: skip
    ax.set_ylabel("following distance (m, bumper to bumper)")
    ax.set_title("Following distance of each CAV to the vehicle ahead in its lane", fontsize=10)
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    _label_events(ax, summary)
    return fig


# --------------------------------------------------------------------------------------------
# Fig. 11: time-space diagram of one lane


def figure_time_space(
    df: pd.DataFrame,
    summary: Mapping[str, Any],
    lane: int,
    n_lanes: int,
    frame_speed_mps: float,
    path: Path,
) -> Path:
    """Write :func:`draw_time_space` to ``path`` (PNG)."""
    return _save(draw_time_space(df, summary, lane, n_lanes, frame_speed_mps), path)


def draw_time_space(
    df: pd.DataFrame,
    summary: Mapping[str, Any],
    lane: int,
    n_lanes: int,
    frame_speed_mps: float,
) -> Figure:
    """(a) Front-bumper position against time of every vehicle while it is in ``lane``;
    (b) the same positions in a frame moving at ``frame_speed_mps`` (shows small speed changes).
    """
    target = (summary.get("overtake") or {}).get("target")
    s = wide(df, "s_m")
    in_lane = wide(df.assign(in_lane=(df["lane"] == lane).astype(float)), "in_lane")
    s = s.where(in_lane.reindex_like(s) > 0.5)
    t = s.index.to_numpy(dtype=float)
    fig = _new_figure(11, 8.5)
    ax_a, ax_b = fig.subplots(2, 1, sharex=True, height_ratios=[1.3, 1.0])
    cavs = cav_ids(df)
    for ax, offset in ((ax_a, 0.0 * t), (ax_b, frame_speed_mps * t)):
        _mark_events(ax, summary)
        for vid in sorted(s.columns, key=_natural_key):
            if vid in cavs or s[vid].isna().all():
                continue
            y = s[vid] - offset
            ax.plot(t, y, color=TARGET_COLOUR if vid == target else HV_COLOUR, lw=1.0)
            if ax is ax_b:  # name the HVs where their lines end
                last = y.last_valid_index()
                ax.annotate(vid, (last, y[last]), xytext=(3, 0), textcoords="offset points",
                            fontsize=7, color="0.35", va="center")  # fmt: skip
        for i, vid in enumerate(cavs):
            if vid in s.columns and not s[vid].isna().all():
                ax.plot(t, s[vid] - offset, color=cav_colour(i), lw=2.0, label=vid)
    handles, _ = ax_a.get_legend_handles_labels()
    handles.append(Line2D([], [], color=HV_COLOUR, lw=1, label="HVs"))
    ax_a.legend(handles=handles, loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=8)
    ax_b.set_xlim(0, float(df["time_s"].max()))
    ax_b.set_xlabel("time (s)")
    ax_a.set_ylabel("distance along the road s (m)")
    ax_b.set_ylabel(f"s − {frame_speed_mps:g} m/s × t (m)")
    ax_a.set_title(
        f"(a) Time-space diagram of the {lane_name(lane, n_lanes)} lane (lane {lane}): each "
        "line is a vehicle's front bumper while it drives in that lane",
        fontsize=10,
    )
    ax_b.set_title(
        f"(b) The same, seen from a frame moving at {frame_speed_mps:g} m/s: a line bending "
        "down is a vehicle slower than that",
        fontsize=10,
    )
    _label_events(ax_a, summary)
    return fig


# --------------------------------------------------------------------------------------------
# Fig. 12: upstream traffic


def figure_upstream(
    df: pd.DataFrame,
    summary: Mapping[str, Any],
    adjacent: Mapping[int, Iterable[str]],
    n_lanes: int,
    headway_s: float,
    initial_speed_mps: float | None,
    path: Path,
) -> Path:
    """Write :func:`draw_upstream` to ``path`` (PNG)."""
    return _save(draw_upstream(df, summary, adjacent, n_lanes, headway_s, initial_speed_mps), path)


def speed_limits(
    low_mps: float, high_mps: float, min_span_mps: float = MIN_SPEED_SPAN_MPS
) -> tuple[float, float]:
    """Speed-axis limits [m/s]: the data on whole m/s with a margin, at least ``min_span_mps``
    wide (centred on the data, ends on half m/s), so changes of a few tenths stay small."""
    floor = 0.0 if low_mps >= 0.0 else -math.inf  # no negative speeds on a forward-only axis
    low, high = max(math.floor(low_mps - 0.25), floor), math.ceil(high_mps + 0.25)
    if high - low < min_span_mps:
        mid = round(low_mps + high_mps) / 2.0  # the data's middle, to the nearest 0.5 m/s
        low = max(mid - min_span_mps / 2.0, floor)
        high = low + min_span_mps
    return float(low), float(high)


def draw_upstream(
    df: pd.DataFrame,
    summary: Mapping[str, Any],
    adjacent: Mapping[int, Iterable[str]],
    n_lanes: int,
    headway_s: float,
    initial_speed_mps: float | None,
) -> Figure:
    """Speed (top) and following distance (bottom) of the ranked upstream HVs, one column per
    lane (left lane first); the blocked HVs beside the platoon (``adjacent``) dashed, once each
    whether ranked or not. The distance axis fits the other ranked HVs: a blocked HV's gap
    grows while the swarm holds it back and would squash them, so a blocked HV whose gap leaves
    the scale is named in a note instead of drawn. The speed axes share their limits, at least
    ``MIN_SPEED_SPAN_MPS`` wide (:func:`speed_limits`)."""
    upstream = summary.get("upstream") or []
    by_lane: dict[int, list[tuple[int, str]]] = {}
    for entry in upstream:
        by_lane.setdefault(int(entry["lane"]), []).append((int(entry["rank"]), entry["vehicle"]))
    lanes = sorted(set(by_lane) | set(adjacent), reverse=True)
    speeds = wide(df, "speed_mps")
    g = metrics.gaps(df)
    gap = g.pivot_table(index="time_s", columns="vehicle", values="gap_m", observed=True)
    fig = _new_figure(4.0 * max(len(lanes), 1) + 1.5, 7.5)
    axes = fig.subplots(2, max(len(lanes), 1), squeeze=False, sharex=True)
    sim_end = float(df["time_s"].max())
    v_ref = initial_speed_mps
    speed_range = [math.inf, -math.inf]
    for j, lane in enumerate(lanes):
        ax_v, ax_g = axes[0][j], axes[1][j]
        for ax in (ax_v, ax_g):
            _mark_events(ax, summary)
        blocked = set(adjacent.get(lane, ()))
        ranked_here = sorted(by_lane.get(lane, []))
        rank_of = {vid: rank for rank, vid in ranked_here}
        ranked = [vid for _, vid in ranked_here if vid in gap.columns and vid not in blocked]
        off: list[str] = []
        if ranked:  # scale to the ranked HVs; a blocked HV's gap may run off the top
            low = float(np.nanmin(gap[ranked].to_numpy()))
            high = float(np.nanmax(gap[ranked].to_numpy()))
            ax_g.set_ylim(min(low, headway_s * v_ref if v_ref else low) - 3.0, high + 8.0)
            # a gap that leaves the scale is named in a note, not drawn as a stray fragment
            off = [v for v in sorted(blocked) if v in gap.columns and gap[v].max() > high + 8.0]
            if off:
                ax_g.text(
                    0.98,
                    0.96,
                    "\n".join(
                        f"{v} (blocked): {gap[v].min():.0f}-{gap[v].max():.0f} m, off the scale"
                        for v in off
                    ),
                    transform=ax_g.transAxes,
                    ha="right",
                    va="top",
                    fontsize=8,
                )
        # the blocked HVs beside the platoon that are not ranked, then the ranked ones
        entries = [(None, v) for v in adjacent.get(lane, ()) if v not in rank_of] + ranked_here
        for rank, vid in entries:
            if rank is None:
                style = {"color": "black", "ls": "--", "lw": 1.2, "label": f"{vid} (blocked)"}
            else:
                style = {
                    "color": RANK_COLOURS[min(rank - 1, len(RANK_COLOURS) - 1)],
                    "label": f"#{rank} {vid}" + (" (blocked)" if vid in blocked else ""),
                    **({"ls": "--", "lw": 1.6} if vid in blocked else {"lw": 1.3}),
                }
            if vid in speeds.columns:
                ax_v.plot(speeds.index, speeds[vid], **style)
                speed_range[0] = min(speed_range[0], float(speeds[vid].min()))
                speed_range[1] = max(speed_range[1], float(speeds[vid].max()))
            if vid in gap.columns and vid not in off:
                ax_g.plot(gap.index, gap[vid], **style)
        handles = list(ax_v.get_lines())
        if v_ref is not None:
            handles.append(
                ax_g.axhline(
                    headway_s * v_ref,
                    color="#d62728",
                    lw=1.0,
                    ls="-",
                    label=f"{headway_s:g} s headway at {v_ref:.1f} m/s",
                )
            )
        handles = [h for h in handles if not h.get_label().startswith("_")]
        ax_v.set_title(f"{lane_name(lane, n_lanes)} lane (lane {lane})", fontsize=10)
        ax_g.set_xlabel("time (s)")
        ax_g.set_xlim(0, sim_end)
        ax_g.legend(
            handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, fontsize=8
        )
    if math.isfinite(speed_range[0]):
        limits = speed_limits(*speed_range)
        for ax in axes[0]:
            ax.set_ylim(*limits)
    _label_events(axes[0][0], summary)
    axes[0][0].set_ylabel("speed (m/s)")
    axes[1][0].set_ylabel("following distance (m)")
    fig.suptitle(
        "Upstream HVs (#1 = nearest HV behind the swarm's front at the decision; dashed = the "
        "HV blocked beside the platoon)",
        fontsize=10,
    )
    return fig


# --------------------------------------------------------------------------------------------
# all figures of a reproduction


def make_figures(
    out_dir: Path,
    scenario: Scenario,
    runs: Mapping[str, RunData],
    *,
    focus: str = "swarm",
    paper_speeds: Mapping[str, float] | None = None,
    on_figure: Callable[[str], None] | None = None,
) -> tuple[dict[str, str], dict[str, str]]:
    """Draw Figs. 7-12 into ``out_dir`` from the finished runs.

    ``focus`` is the run the single-run figures show (the swarm). Returns ``(figures,
    errors)``: file name of each figure written, and why each other figure is missing. One
    figure failing does not stop the others. ``on_figure(name)`` is called after each.
    """
    from sumo_swarm.sim.scene import build_scene

    figures: dict[str, str] = {}
    errors: dict[str, str] = {}
    road = RoadSection(lane_widths_m(scenario))
    main = runs.get(focus)
    ev = scenario.evaluation
    window = (ev.start_s, ev.end_s)
    scene = build_scene(scenario)
    adjacent: dict[int, list[str]] = {}
    for v in scene.vehicles:
        if v.role == "adjacent":
            adjacent.setdefault(v.lane, []).append(v.id)
    left_lane = road.n_lanes - 1

    def plan_figure(path: Path) -> Path:
        plans = [p for p in main.plans() if p.get("cells")]
        if not plans:
            raise ValueError("the swarm run recorded no successful plan")
        target = main.summary["overtake"].get("target")
        claimed, centres = plan_blocked_cells(plans[0], main.df, scenario, road, target)
        return figure_plan(plans[0], claimed, centres, target,
                           scenario.planner.behaving_interval_s, path)  # fmt: skip

    jobs = {
        "fig7_plan": plan_figure,
        "fig8_trajectories": lambda p: figure_trajectories(
            main.df,
            main.summary,
            road,
            {"cav": scenario.cav.width_m, "hv": scenario.hv.width_m},
            p,
        ),
        "fig9_speeds": lambda p: figure_speeds(runs, focus, window, paper_speeds or {}, p),
        "fig10_gaps": lambda p: figure_gaps(
            main.df, main.summary, scenario.cav.min_gap_m, scenario.cav.desired_gap_m, window, p
        ),
        "fig11_time_space": lambda p: figure_time_space(
            main.df, main.summary, left_lane, road.n_lanes, scenario.scene.initial_speed_mps, p
        ),
        "fig12_upstream": lambda p: figure_upstream(
            main.df,
            main.summary,
            adjacent,
            road.n_lanes,
            scenario.hv.headway_s,
            scenario.scene.upstream_speed_mps,
            p,
        ),
    }
    for name, draw in jobs.items():
        if main is None:
            errors[name] = f"no finished '{focus}' run to draw"
            continue
        path = out_dir / f"{name}.png"
        try:
            draw(path)
            figures[name] = path.name
        except Exception as exc:  # a figure must never cost the report
            errors[name] = f"{type(exc).__name__}: {exc}"
        if on_figure is not None:
            on_figure(name)
    return figures, errors
