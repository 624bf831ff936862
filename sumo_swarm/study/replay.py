"""An animation of a finished run, drawn from its outputs (``sumo-swarm replay RUN_DIR``).

Reads ``trajectories.parquet`` (positions, speeds), ``plans.jsonl`` (the swarm's plans),
``events.jsonl`` (when an overtake ended), ``summary.json`` (the target) and the SUMO inputs
under ``sumo/`` (the network's lane shapes and the vehicle widths). Each frame shows the real
lanes, every vehicle to scale along its direction of travel and coloured by its role, the grid of
the current plan with the cell each CAV is heading for, and the speeds. The camera follows the
swarm (or one vehicle) and turns with the road.

Frames are drawn with matplotlib's Agg canvas: the artists are made once and updated in place
each frame, the static parts are blitted, and the text that changes every frame (time, speeds)
is stamped from cached glyphs. The 80 s paper run at 10 fps takes about 20 s. MP4 goes through
the ffmpeg binary of ``imageio-ffmpeg``; GIF through Pillow, streamed frame by frame (a long GIF
is not held in memory; unchanged pixels are written transparent, which keeps it small).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.colors import to_rgba
from matplotlib.figure import Figure
from matplotlib.patches import Patch, Rectangle
from matplotlib.transforms import Affine2D

from sumo_swarm.errors import ConfigError
from sumo_swarm.safexml import parse_xml
from sumo_swarm.sim.routeshape import (
    LaneGeometry,
    PlanRecord,
    RouteGeometry,
    read_net_lanes,
    route_from_net,
)
from sumo_swarm.userfiles import (
    MAX_DATA_BYTES,
    read_user_json,
    read_user_parquet,
    read_user_text,
    sumo_saved_path,
)

FORMATS = (".mp4", ".gif")
GIF_CLEAR = 255  # palette index of "unchanged since the last frame" (transparent) in a GIF
LABEL_PT = 7.0  # size of the speeds written on the vehicles [pt]
MIN_LABELLED_LENGTH_M = 4.5  # speeds are written when a car this long is as wide as the text [m]
HEADER_PT = 11.0  # size of the line with the time and speeds [pt]
HEADER_AT = (0.01, 0.955)  # its top-left corner [figure fraction]
DEFAULT_WIDTH_M = 1.8  # SUMO's default vehicle width [m], when the routes give none
FOLLOW_VIEW_M = 160.0  # length of road in view when following one vehicle [m]
FRAME_PX = (1600, 608)  # multiples of 16: ffmpeg's codecs need no resize
ROAD_RECT = (0.0, 0.45, 1.0, 0.45)  # the road view in the frame (figure fractions)
ROAD_ASPECT = (ROAD_RECT[2] * FRAME_PX[0]) / (ROAD_RECT[3] * FRAME_PX[1])  # width / height
ROAD_MARGIN_M = 12.0  # verge shown beside the road, both sides together [m]

ROLE_COLOURS = {
    "target": "#d62728",
    "blocker": "#ff7f0e",
    "cav": "#1f77b4",
    "blocked": "#5b5b5b",
    "hv": "#b4b4b4",
}
ROLE_LABELS = {
    "target": "slow vehicle (target)",
    "blocker": "CAV assigned to block",
    "cav": "other CAVs",
    "blocked": "HV being blocked",
    "hv": "other HVs",
}


# --------------------------------------------------------------------------------------------
# inputs


@dataclass
class RunRecord:
    """Everything a replay needs from a run folder."""

    folder: Path
    df: pd.DataFrame  # sorted by time_s, with heading_rad and width_m added
    times_s: np.ndarray  # the distinct step times [s]
    starts: np.ndarray  # row index where each step time begins in df (len(times_s) + 1)
    target: str | None
    plans: list[PlanRecord]
    route: RouteGeometry
    lanes: list[tuple[LaneGeometry, ...]] = field(default_factory=list)  # lanes of each edge
    title: str = ""
    # every manoeuvre's target (cells, lane pass, passing alone, ...), the first one first
    targets: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        # plain arrays: a frame slices them (pandas indexing per frame is the slow way)
        df = self.df
        self.col = {
            name: df[name].to_numpy(dtype=float)
            for name in ("x_m", "y_m", "s_m", "speed_mps", "length_m", "width_m", "heading_rad")
        }
        self.vehicle = df["vehicle"].astype(str).to_numpy()
        self.is_cav = (df["kind"].astype(str) == "cav").to_numpy()
        if self.target is not None and self.target not in self.targets:
            self.targets = (self.target, *self.targets)

    @property
    def first_cav_s(self) -> float | None:
        """When the first CAV appears [s] (None: a run without CAVs)."""
        times = self.df["time_s"].to_numpy()[self.is_cav]
        return float(times.min()) if len(times) else None

    def rows_at(self, t_s: float) -> slice:
        """The rows (a slice of ``df`` and of the arrays) of the step time nearest ``t_s``."""
        k = int(np.clip(np.searchsorted(self.times_s, t_s), 0, len(self.times_s) - 1))
        if k > 0 and abs(self.times_s[k - 1] - t_s) <= abs(self.times_s[k] - t_s):
            k -= 1
        return slice(int(self.starts[k]), int(self.starts[k + 1]))

    def plan_at(self, t_s: float) -> PlanRecord | None:
        current = None
        for plan in self.plans:
            if plan.time_s <= t_s + 1e-9:
                current = plan
        return current if current is not None and t_s < current.until_s else None


def _read_jsonl(path: Path) -> list[dict[str, Any]]:
    """The records of a JSON-lines file of the run (none when it has no such file)."""
    if not path.exists():
        return []
    out = []
    text = read_user_text(path, "run output", MAX_DATA_BYTES)
    for n, line in enumerate(text.splitlines(), 1):
        if line.strip():
            try:
                record = json.loads(line)
            except json.JSONDecodeError as exc:
                raise ConfigError(f"{path}:{n}: not JSON: {exc.msg}") from None
            if not isinstance(record, dict):
                raise ConfigError(f"{path}:{n}: not a JSON object")
            out.append(record)
    return out


def _sumo_inputs(folder: Path) -> tuple[Path, list[Path]]:
    """The network file and the route files named by the run's ``sumo/*.sumocfg``."""
    cfgs = sorted((folder / "sumo").glob("*.sumocfg"))
    if not cfgs:
        raise ConfigError(f"no SUMO configuration in {folder / 'sumo'}: the network is needed")
    cfg = cfgs[0]
    root = parse_xml(cfg, "SUMO configuration")

    def files(key: str) -> list[Path]:
        node = root.find(f".//{key}")
        names = (node.get("value", "") if node is not None else "").split(",")
        return [(cfg.parent / sumo_saved_path(n.strip())).resolve() for n in names if n.strip()]

    nets = files("net-file")
    if not nets:
        raise ConfigError(f"{cfg} names no net-file")
    if not nets[0].exists():
        raise ConfigError(f"network file not found: {nets[0]} (named in {cfg})")
    return nets[0], [p for p in files("route-files") if p.exists()]


def _widths(route_files: list[Path]) -> dict[str, float]:
    """Width of each vehicle [m], from the vTypes of the route files."""
    type_width: dict[str, float] = {}
    vehicle_type: dict[str, str] = {}
    for path in route_files:
        root = parse_xml(path, "route file")
        for vt in root.iter("vType"):
            try:
                width_m = float(vt.get("width", DEFAULT_WIDTH_M))
            except ValueError:
                raise ConfigError(f"{path}: vType '{vt.get('id')}': width is no number") from None
            type_width[vt.get("id", "")] = width_m
        for tag in ("vehicle", "flow", "trip"):
            for v in root.iter(tag):
                vehicle_type[v.get("id", "")] = v.get("type", "")
    return {v: type_width.get(t, DEFAULT_WIDTH_M) for v, t in vehicle_type.items()}


def _route_edges(df: pd.DataFrame) -> list[str]:
    """The route of the swarm: the edges the most-travelled CAV drove, in order (no junctions)."""
    cav = df[df["kind"] == "cav"]
    best: list[str] = []
    for _, g in cav.groupby("vehicle", observed=True, sort=False):
        edges = [e for e in dict.fromkeys(g["edge"].astype(str)) if not e.startswith(":")]
        if len(edges) > len(best):
            best = edges
    if not best:  # no CAV: the edges of every vehicle in the order they are first used
        best = [e for e in dict.fromkeys(df["edge"].astype(str)) if not e.startswith(":")]
    return best


def _headings(df: pd.DataFrame, route: RouteGeometry) -> np.ndarray:
    """Direction of travel of every row [rad], from successive positions; where a vehicle
    stands still, the lane's direction."""
    _, _, lane_h = route.xy(df["s_m"].to_numpy(), df["lane"].to_numpy())
    out = lane_h.copy()
    order = np.lexsort((df["time_s"].to_numpy(), df["vehicle"].cat.codes.to_numpy()))
    x = df["x_m"].to_numpy()[order]
    y = df["y_m"].to_numpy()[order]
    veh = df["vehicle"].cat.codes.to_numpy()[order]
    dx, dy = np.diff(x), np.diff(y)
    moved = (np.hypot(dx, dy) > 1e-3) & (veh[1:] == veh[:-1])
    h = np.full(len(order), np.nan)
    h[1:][moved] = np.arctan2(dy[moved], dx[moved])
    # a vehicle's first row takes the heading of its second
    first = np.r_[True, veh[1:] != veh[:-1]]
    nxt = np.r_[h[1:], np.nan]
    same_next = np.r_[veh[1:] == veh[:-1], False]
    h[first & same_next] = nxt[first & same_next]
    ok = ~np.isnan(h)
    out[order[ok]] = h[ok]
    return out


def load_run(folder: Path) -> RunRecord:
    """Read a run folder; ConfigError (exit 2) naming the file when something is missing."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError(f"run folder not found: {folder}")
    traj = folder / "trajectories.parquet"
    if not traj.exists():
        raise ConfigError(f"no trajectories.parquet in {folder} (not a finished run?)")
    df = read_user_parquet(traj, "trajectory table")
    needed = {"time_s", "vehicle", "kind", "edge", "lane", "x_m", "y_m", "s_m", "speed_mps"}
    if needed - set(df.columns) or df.empty:
        missing = ", ".join(sorted(needed - set(df.columns))) or "rows"
        raise ConfigError(f"{traj} lacks {missing}")
    df = df.sort_values(["time_s", "vehicle"], kind="stable").reset_index(drop=True)
    df["vehicle"] = df["vehicle"].astype(str).astype("category")
    if "length_m" not in df.columns:
        df["length_m"] = 5.0
    net, route_files = _sumo_inputs(folder)
    edges = _route_edges(df)
    route = route_from_net(net, edges)
    lanes, _ = read_net_lanes(net)
    widths = _widths(route_files)
    df["width_m"] = df["vehicle"].astype(str).map(widths).fillna(DEFAULT_WIDTH_M).to_numpy()
    df["heading_rad"] = _headings(df, route)
    times, starts = np.unique(df["time_s"].to_numpy(), return_index=True)

    summary_path = folder / "summary.json"
    summary = read_user_json(summary_path, "run summary") if summary_path.exists() else {}
    if not isinstance(summary, dict):
        raise ConfigError(f"{summary_path}: malformed run summary: not a JSON object")
    try:
        target, targets = manoeuvre_targets(summary)
    except (AttributeError, TypeError):  # a block that is no JSON object
        raise ConfigError(f"{summary_path}: malformed run summary: its overtake block") from None
    events = folder / "events.jsonl"
    try:
        ends = sorted(
            float(e["time_s"])
            for e in _read_jsonl(events)
            # a cell plan handed over to the cruise (its manoeuvre goes on): no plan in force
            if e.get("event") in ("overtake_end", "overtake_handover", "target_left")
        )
    except (KeyError, TypeError, ValueError):
        raise ConfigError(f"{events}: an overtake's end without a time_s number") from None
    records = [r for r in _read_jsonl(folder / "plans.jsonl") if PlanRecord.is_valid(r)]
    plans = []
    for i, r in enumerate(records):
        plan = PlanRecord.from_record(r)
        # in force until the next plan or the end of the overtake, if sooner than its last step
        later = [e for e in ends if e > plan.time_s]
        if i + 1 < len(records):
            later.append(float(records[i + 1]["time_s"]))
        plans.append(replace(plan, until_s=min([plan.until_s, *later])))
    all_lanes = [tuple(ls) for eid, ls in lanes.items() if not eid.startswith(":")]
    return RunRecord(
        folder,
        df,
        times,
        np.r_[starts, len(df)],
        target,
        plans,
        route,
        all_lanes,
        f"{summary.get('scenario', '?')} / {summary.get('controller', '?')}   (run {folder.name})",
        targets,
    )


def manoeuvre_targets(summary: dict) -> tuple[str | None, tuple[str, ...]]:
    """The first target and every manoeuvre's target, in order and once each: from the
    summary's ``manoeuvres`` list where it has one, else ``overtake.targets`` and
    ``overtake.target`` (summaries written before that list)."""
    overtake = summary.get("overtake") or {}
    manoeuvres = summary.get("manoeuvres")
    if isinstance(manoeuvres, list):
        found = [m.get("target") for m in manoeuvres if isinstance(m, dict)]
    else:
        found = [*(overtake.get("targets") or []), overtake.get("target")]
    targets = tuple(dict.fromkeys(str(t) for t in found if t))
    first = overtake.get("target") or (targets[0] if targets else None)
    return first, targets


# --------------------------------------------------------------------------------------------
# drawing


def vehicle_polygons(
    x_m: np.ndarray,
    y_m: np.ndarray,
    heading_rad: np.ndarray,
    length_m: np.ndarray,
    width_m: np.ndarray,
) -> np.ndarray:
    """Corners (n x 4 x 2) [m] of vehicles whose front bumper centre is at (x, y)."""
    d = np.stack([np.cos(heading_rad), np.sin(heading_rad)], axis=-1)
    n = np.stack([-d[:, 1], d[:, 0]], axis=-1)
    front = np.stack([x_m, y_m], axis=-1)
    rear = front - length_m[:, None] * d
    half = 0.5 * width_m[:, None] * n
    return np.stack([front + half, front - half, rear - half, rear + half], axis=1)


def _border(lane: LaneGeometry, side: float) -> np.ndarray:
    """A lane's left (``side`` +1) or right (-1) border line (k x 2) [m]."""
    s = np.linspace(0.0, lane.length_m, max(2, len(lane.shape_xy) * 4))
    x, y, h = lane.along(s)
    off = 0.5 * side * lane.width_m
    return np.column_stack([x - np.sin(h) * off, y + np.cos(h) * off])


def lane_borders(
    edges: list[tuple[LaneGeometry, ...]],
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Lines (k x 2 arrays) [m] of the roads: their outer edges, and the markings between lanes."""
    outer, marks = [], []
    for lanes in edges:
        if not lanes:
            continue
        outer.append(_border(lanes[0], -1.0))
        outer.append(_border(lanes[-1], 1.0))
        marks.extend(_border(lane, 1.0) for lane in lanes[:-1])
    return outer, marks


class TextStamps:
    """Text drawn straight into an RGBA frame from cached anti-aliased glyphs: the strings of a
    replay change every frame but are made of a few dozen characters."""

    def __init__(self, size_px: float) -> None:
        from matplotlib import font_manager
        from PIL import ImageFont

        path = font_manager.findfont(font_manager.FontProperties(family="DejaVu Sans"))
        self.font = ImageFont.truetype(path, max(round(size_px), 1))
        ascent, descent = self.font.getmetrics()
        self.height_px = ascent + descent
        self.glyphs: dict[str, tuple[np.ndarray, float]] = {}

    def glyph(self, char: str) -> tuple[np.ndarray, float]:
        """Coverage of a character's cell (height x width x 1, 0-1) and its advance [px]."""
        found = self.glyphs.get(char)
        if found is None:
            from PIL import Image, ImageDraw

            advance = self.font.getlength(char)
            width = max(math.ceil(advance), self.font.getbbox(char)[2], 1)
            im = Image.new("L", (width, self.height_px), 0)
            ImageDraw.Draw(im).text((0, 0), char, fill=255, font=self.font)
            found = (np.asarray(im, dtype=np.float32)[..., None] / 255.0, advance)
            self.glyphs[char] = found
        return found

    def width_px(self, text: str) -> float:
        return sum(self.glyph(c)[1] for c in text)

    def stamp(
        self,
        image: np.ndarray,
        text: str,
        x_px: float,
        y_px: float,
        rgb: tuple[int, int, int],
        *,
        centred: bool = False,
    ) -> None:
        """Draw ``text`` into ``image`` (rows from the top) with its top-left corner at
        ``(x_px, y_px)``, or its centre there when ``centred``."""
        if centred:
            x_px -= 0.5 * self.width_px(text)
            y_px -= 0.5 * self.height_px
        colour = np.asarray(rgb, np.float32)
        y0 = round(y_px)
        for char in text:
            alpha, advance = self.glyph(char)
            x0 = round(x_px)
            x_px += advance
            h, w = alpha.shape[:2]
            ya, yb = max(y0, 0), min(y0 + h, image.shape[0])
            xa, xb = max(x0, 0), min(x0 + w, image.shape[1])
            if ya >= yb or xa >= xb or char == " ":
                continue
            a = alpha[ya - y0 : yb - y0, xa - x0 : xb - x0]
            region = image[ya:yb, xa:xb, :3]
            region[...] = (region * (1.0 - a) + colour * a).astype(np.uint8)


class Renderer:
    """Draws frames of a run; every artist is made once and updated in place."""

    def __init__(self, run: RunRecord, follow: str | None, view_m: float) -> None:
        self.run = run
        self.follow = follow
        self.view_m = view_m
        w_px, h_px = FRAME_PX
        self.fig = Figure(figsize=(w_px / 100, h_px / 100), dpi=100)
        self.canvas = FigureCanvasAgg(self.fig)
        self.ax = self.fig.add_axes(ROAD_RECT)
        self.view_h_m = view_m / ROAD_ASPECT
        self.ax.set_xlim(-view_m / 2, view_m / 2)
        self.ax.set_ylim(-self.view_h_m / 2, self.view_h_m / 2)
        self.ax.set_axis_off()
        self.ax.add_patch(
            Rectangle((0, 0), 1, 1, transform=self.ax.transAxes, facecolor="#e8efe0", zorder=-5)
        )  # the verge: drawn once, under the road
        self.camera = Affine2D()
        data = self.camera + self.ax.transData
        lanes_edges, lanes_marks = lane_borders(run.lanes)
        surface = [lane_polygon(lane) for lanes in run.lanes for lane in lanes]
        self.animated = []
        self._add(PolyCollection(surface, facecolors="#d9d9d9", edgecolors="none"), data)
        self._add(
            LineCollection(lanes_marks, colors="white", linewidths=1.2, linestyles=(0, (4, 4))),
            data,
        )
        self._add(LineCollection(lanes_edges, colors="#4d4d4d", linewidths=1.4), data)
        self.grid_cells = self._add(
            PolyCollection([], facecolors="none", edgecolors="#7f7f7f", linewidths=0.5), data
        )
        self.plan_cells = self._add(PolyCollection([], linewidths=1.4), data)
        self.vehicles = self._add(PolyCollection([], edgecolors="black", linewidths=0.5), data)
        self.fig.text(0.01, 0.995, run.title, fontsize=9, color="0.35", va="top")
        # text that changes every frame is stamped into the pixels from cached glyph masks:
        # matplotlib lays out and renders every string anew, most of a frame's cost
        self.label_stamps = TextStamps(LABEL_PT * self.fig.dpi / 72.0)
        self.header_stamps = TextStamps(HEADER_PT * self.fig.dpi / 72.0)
        self.header_text = ""
        self.labels: list[tuple[str, float, float]] = []  # text and its centre [px, from top]
        # the plan's line changes every few seconds: part of the background, redrawn on change
        self.plan_line = self.fig.text(0.40, HEADER_AT[1], "", fontsize=HEADER_PT, va="top")
        handles = [
            Patch(facecolor=c, edgecolor="black", lw=0.5, label=ROLE_LABELS[r])
            for r, c in ROLE_COLOURS.items()
        ]
        handles.append(
            Patch(
                facecolor=to_rgba(ROLE_COLOURS["cav"], 0.25),
                edgecolor=ROLE_COLOURS["cav"],
                label="planned cell (next step)",
            )
        )
        handles.append(Patch(facecolor="none", edgecolor="#7f7f7f", label="plan grid"))
        self.fig.legend(
            handles=handles,
            loc="upper left",
            bbox_to_anchor=(0.83, 0.41),
            fontsize=8,
            frameon=False,
        )
        self._speed_axes()
        self.canvas.draw()
        self.background = self.canvas.copy_from_bbox(self.fig.bbox)

    def _add(self, artist: Any, transform: Any) -> Any:
        """Register an artist of the road view: placed by the camera, redrawn every frame."""
        artist.set_transform(transform)
        artist.set_animated(True)
        if isinstance(artist, LineCollection | PolyCollection):
            self.ax.add_collection(artist, autolim=False)
        self.animated.append(artist)
        return artist

    def _speed_axes(self) -> None:
        run = self.run
        ax = self.fig.add_axes((0.05, 0.09, 0.62, 0.30))
        df = run.df
        cav = df[df["kind"] == "cav"]
        for i, (_, g) in enumerate(cav.groupby("vehicle", observed=True)):
            ax.plot(
                g["time_s"],
                g["speed_mps"],
                color=ROLE_COLOURS["cav"],
                lw=0.7,
                alpha=0.6,
                label="CAVs" if i == 0 else None,
            )
        if not cav.empty:
            mean = cav.groupby("time_s")["speed_mps"].mean()
            ax.plot(mean.index, mean.to_numpy(), color="black", lw=1.6, label="swarm mean")
        if run.target is not None:
            g = df[df["vehicle"] == run.target]
            ax.plot(
                g["time_s"],
                g["speed_mps"],
                color=ROLE_COLOURS["target"],
                lw=1.4,
                label=f"target ({run.target})",
            )
        if self.follow is not None and self.follow != run.target:
            g = df[df["vehicle"] == self.follow]
            ax.plot(
                g["time_s"],
                g["speed_mps"],
                color="#9467bd",
                lw=1.4,
                ls="--",
                label=f"followed ({self.follow})",
            )
        for plan in run.plans:
            ax.axvspan(plan.time_s, plan.until_s, color="#fff2cc", lw=0, zorder=-1)
        lo, hi = ax.get_ylim()
        ax.set_ylim(min(lo, math.floor(hi - 4.0)), hi)  # at least 4 m/s of range
        ax.set_xlim(float(run.times_s[0]), float(run.times_s[-1]))
        ax.set_xlabel("time (s)   [shaded: a plan in force]", fontsize=9)
        ax.set_ylabel("speed (m/s)", fontsize=9)
        ax.tick_params(labelsize=8)
        ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8, frameon=False)
        self.cursor = ax.axvline(0.0, color="#d62728", lw=1.2)
        self.cursor.set_animated(True)
        self.speed_ax = ax

    # ---------------------------------------------------------------------------------------
    def camera_at(self, rows: slice) -> tuple[float, float, float]:
        """Centre (x, y) [m] and heading [rad] of the view on the rows of one step."""
        run = self.run
        col = run.col
        if self.follow is not None:
            me = np.flatnonzero(run.vehicle[rows] == self.follow)
            if len(me):
                i = rows.start + int(me[0])
                h = col["heading_rad"][i]
                half = 0.5 * col["length_m"][i]
                x = col["x_m"][i] - half * math.cos(h)
                y = col["y_m"][i] - half * math.sin(h)
                return float(x), float(y), self._road_heading(float(col["s_m"][i]))
        s = col["s_m"][rows]
        cav = s[run.is_cav[rows]]
        pool = cav if len(cav) else s  # no CAV (or the followed vehicle gone): everyone
        s_c = 0.5 * (float(pool.min()) + float(pool.max())) if len(pool) else 0.0
        top = len(run.route.lanes_at(s_c)) - 1  # the view centres on the road's middle
        x, y, _ = run.route.xy([s_c, s_c], [0, top])
        return float(x.mean()), float(y.mean()), self._road_heading(s_c)

    def _road_heading(self, s_m: float) -> float:
        """Heading of the road around ``s_m`` [rad], over +-40 m so curves turn smoothly."""
        x, y, _ = self.run.route.xy([s_m - 40.0, s_m + 40.0], 0)
        return math.atan2(y[1] - y[0], x[1] - x[0])

    def frame(self, t_s: float) -> np.ndarray:
        """The picture at ``t_s`` as an RGBA array (height x width x 4)."""
        run = self.run
        rows = run.rows_at(t_s)
        cx, cy, ch = self.camera_at(rows)
        self.camera.clear().translate(-cx, -cy).rotate(-ch)
        plan = run.plan_at(t_s)
        col = {name: values[rows] for name, values in run.col.items()}
        along = (col["x_m"] - cx) * math.cos(ch) + (col["y_m"] - cy) * math.sin(ch)
        vis = np.flatnonzero(np.abs(along) < 0.5 * self.view_m + 10.0)  # in view, with margin
        polys = vehicle_polygons(
            col["x_m"][vis],
            col["y_m"][vis],
            col["heading_rad"][vis],
            col["length_m"][vis],
            col["width_m"][vis],
        )
        roles = self.roles(run.vehicle[rows][vis], run.is_cav[rows][vis], plan)
        self.vehicles.set_verts(polys)
        self.vehicles.set_facecolors([ROLE_COLOURS[r] for r in roles])
        centres = polys.mean(axis=1)
        speeds = col["speed_mps"][vis]
        # speeds written on the swarm, the target and the blocked HVs
        named = [i for i, role in enumerate(roles) if role != "hv"]
        to_px = (self.camera + self.ax.transData).transform
        height_px = self.fig.bbox.height
        self.labels = (
            [
                (f"{speeds[i]:.1f}", float(x), float(height_px - y))
                for i, (x, y) in zip(named, to_px(centres[named]), strict=True)
            ]
            if named
            else []
        )
        self._draw_plan(plan, t_s)
        self.cursor.set_xdata([t_s, t_s])
        self.header_text = self._header(t_s, rows)
        plan_line = self._plan_line(t_s, plan)
        if plan_line != self.plan_line.get_text():
            self.plan_line.set_text(plan_line)
            self.canvas.draw()
            self.background = self.canvas.copy_from_bbox(self.fig.bbox)
        self.canvas.restore_region(self.background)
        for artist in self.animated:
            self.ax.draw_artist(artist)
        self.speed_ax.draw_artist(self.cursor)
        image = np.array(self.canvas.buffer_rgba())
        road = self.ax.bbox
        px_per_m = road.width / self.view_m
        if px_per_m * MIN_LABELLED_LENGTH_M < self.label_stamps.width_px("00.0"):
            self.labels = []  # zoomed out too far: the speeds would cover the cars
        for text, x, y in self.labels:
            if road.x0 <= x <= road.x1 and road.y0 <= height_px - y <= road.y1:
                self.label_stamps.stamp(image, text, x, y, (255, 255, 255), centred=True)
        x, y = HEADER_AT
        self.header_stamps.stamp(
            image, self.header_text, x * image.shape[1], (1.0 - y) * image.shape[0], (0, 0, 0)
        )
        return image

    def roles(self, vehicles: np.ndarray, is_cav: np.ndarray, plan: PlanRecord | None) -> list[str]:
        """Role of each vehicle (a key of ROLE_COLOURS) under the plan in force."""
        blockers = plan.blockers if plan is not None else {}
        blocked = set(blockers.values())
        out = []
        for vid, cav in zip(vehicles, is_cav, strict=True):
            if vid in self.run.targets:
                out.append("target")
            elif cav:
                out.append("blocker" if vid in blockers else "cav")
            else:
                out.append("blocked" if vid in blocked else "hv")
        return out

    def _draw_plan(self, plan: PlanRecord | None, t_s: float) -> None:
        if plan is None:
            self.grid_cells.set_verts([])
            self.plan_cells.set_verts([])
            return
        grid, cells = plan.polygons(self.run.route, t_s)
        self.grid_cells.set_verts(grid)
        colours = [ROLE_COLOURS["blocker" if cav in plan.blockers else "cav"] for cav in cells]
        self.plan_cells.set_verts(list(cells.values()))
        self.plan_cells.set_facecolors([to_rgba(c, 0.22) for c in colours])
        self.plan_cells.set_edgecolors([to_rgba(c, 0.9) for c in colours])

    def _header(self, t_s: float, rows: slice) -> str:
        run = self.run
        speed = run.col["speed_mps"][rows]
        cav = speed[run.is_cav[rows]]
        parts = [f"t = {t_s:6.2f} s"]
        if len(cav):
            parts.append(f"swarm mean {cav.mean():5.2f} m/s")
        tgt = speed[run.vehicle[rows] == run.target]
        if len(tgt):
            parts.append(f"target {tgt[0]:5.2f} m/s")
        return "    ".join(parts)

    @staticmethod
    def _plan_line(t_s: float, plan: PlanRecord | None) -> str:
        if plan is None:
            return "no plan in force"
        n = len(next(iter(plan.cells.values())))
        line = f"plan of t = {plan.time_s:.2f} s, heading for step {plan.step_at(t_s) + 1}/{n}"
        blocks = ", ".join(f"{c} blocks {h}" for c, h in plan.blockers.items())
        return f"{line};  {blocks}" if blocks else line


def lane_polygon(lane: LaneGeometry) -> np.ndarray:
    """Surface of one lane (k x 2) [m]."""
    s = np.linspace(0.0, lane.length_m, max(2, len(lane.shape_xy) * 4))
    x, y, h = lane.along(s)
    half = 0.5 * lane.width_m
    left = np.column_stack([x - np.sin(h) * half, y + np.cos(h) * half])
    right = np.column_stack([x + np.sin(h) * half, y - np.cos(h) * half])
    return np.vstack([left, right[::-1]])


# --------------------------------------------------------------------------------------------
# writing


@dataclass(frozen=True)
class ReplayResult:
    path: Path
    frames: int
    wall_s: float


def frame_times(run: RunRecord, t_from: float | None, t_to: float | None, fps: float) -> np.ndarray:
    """Times of the frames [s] within the run (ConfigError on an empty or inverted range); by
    default from when the first CAV appears (a user's sumocfg may run long before)."""
    first, last = float(run.times_s[0]), float(run.times_s[-1])
    first_cav = run.first_cav_s
    start = (first if first_cav is None else first_cav) if t_from is None else float(t_from)
    stop = last if t_to is None else float(t_to)
    if not (math.isfinite(start) and math.isfinite(stop)) or stop <= start:
        raise ConfigError(f"replay: --from {start:g} must be before --to {stop:g}")
    if start >= last or stop <= first:
        raise ConfigError(
            f"replay: --from/--to ({start:g}-{stop:g} s) outside the run ({first:g}-{last:g} s)"
        )
    start, stop = max(start, first), min(stop, last)
    return start + np.arange(math.floor((stop - start) * fps + 1e-9) + 1) / fps


def _view_length(run: RunRecord, follow: str | None) -> float:
    """Road in view [m]: the swarm's usual spread plus room (or a fixed window when following
    one vehicle), and at least enough that the road's width fills the height of the view."""
    road_m = sum(lane.width_m for lane in run.route.edges[0].lanes) + ROAD_MARGIN_M
    cav = run.df[run.df["kind"] == "cav"]
    if follow is not None or cav.empty:
        length = FOLLOW_VIEW_M
    else:
        spread = cav.groupby("time_s")["s_m"].agg(lambda s: s.max() - s.min())
        length = float(np.nanpercentile(spread, 95)) + 50.0
    return float(np.clip(length, road_m * ROAD_ASPECT, 400.0))


def write_replay(
    run_dir: Path,
    out: Path | None = None,
    *,
    follow: str | None = None,
    t_from: float | None = None,
    t_to: float | None = None,
    fps: float = 10.0,
) -> ReplayResult:
    """Animate the run in ``run_dir`` into ``out`` (.mp4 or .gif; default RUN_DIR/replay.mp4)."""
    started = time.perf_counter()
    run_dir = Path(run_dir)
    out = Path(out) if out is not None else run_dir / "replay.mp4"
    suffix = out.suffix.lower()
    if suffix not in FORMATS:
        raise ConfigError(f"replay: --out {out} must end in .mp4 or .gif")
    if not (math.isfinite(fps) and 0 < fps <= 60):
        raise ConfigError(f"replay: --fps must be in (0, 60], got {fps:g}")
    if not run_dir.is_dir():
        raise ConfigError(f"run folder not found: {run_dir}")
    if not out.parent.is_dir():
        raise ConfigError(f"replay: folder of --out not found: {out.parent}")
    run = load_run(run_dir)
    if follow is not None and follow not in set(run.df["vehicle"].astype(str)):
        raise ConfigError(f"replay: vehicle '{follow}' not in {run_dir / 'trajectories.parquet'}")
    times = frame_times(run, t_from, t_to, fps)
    renderer = Renderer(run, follow, _view_length(run, follow))
    frames = (renderer.frame(float(t)) for t in times)
    tmp = out.with_name(out.stem + ".tmp" + out.suffix)
    try:
        if suffix == ".mp4":
            _write_mp4(tmp, frames, fps)
        else:
            samples = [renderer.frame(float(t)) for t in times[[0, len(times) // 2, -1]]]
            _write_gif(tmp, frames, fps, np.vstack(samples))
        tmp.replace(out)
    finally:
        tmp.unlink(missing_ok=True)
    return ReplayResult(out, len(times), time.perf_counter() - started)


def _write_mp4(path: Path, frames: Iterator[np.ndarray], fps: float) -> None:
    import imageio_ffmpeg

    writer = imageio_ffmpeg.write_frames(
        str(path),
        FRAME_PX,
        fps=fps,
        codec="libx264",
        quality=7,
        pix_fmt_in="rgba",
        pix_fmt_out="yuv420p",
        macro_block_size=16,
        ffmpeg_log_level="error",
        output_params=["-preset", "veryfast"],  # a third of the default's CPU, same look
    )
    writer.send(None)  # start ffmpeg
    try:
        for frame in frames:
            writer.send(np.ascontiguousarray(frame))
    finally:
        writer.close()


def _write_gif(
    path: Path, frames: Iterator[np.ndarray], fps: float, palette_rgba: np.ndarray
) -> None:
    """Stream a looping GIF of RGBA frames, each encoded and written as it comes.

    One palette of 255 colours for all frames (from a mosaic of sample frames); index 255 is
    transparent, and a frame after the first writes it wherever a pixel is unchanged, so the
    still parts (legend, speed chart) cost next to nothing.
    """
    from PIL import GifImagePlugin, Image

    palette = (
        Image.fromarray(palette_rgba)
        .convert("RGB")
        .quantize(colors=GIF_CLEAR, method=Image.Quantize.MEDIANCUT)
    )
    used = palette.getpalette()[: 3 * GIF_CLEAR]
    colours = [*used, *[0] * (3 * GIF_CLEAR + 3 - len(used))]  # 256 entries, the last unseen
    duration_ms = round(1000.0 / fps)
    previous = None
    with path.open("wb") as fh:
        for rgba in frames:
            rgb = Image.fromarray(rgba).convert("RGB")
            index = np.asarray(rgb.quantize(palette=palette, dither=Image.Dither.NONE))
            if previous is None:
                shown = index
            else:
                shown = np.where(index == previous, np.uint8(GIF_CLEAR), index)
            im = Image.fromarray(shown.astype(np.uint8), mode="P")
            im.putpalette(colours)
            if previous is None:
                info = {"loop": 0, "duration": duration_ms}
                fh.write(b"".join(GifImagePlugin.getheader(im, info=info)[0]))
            for chunk in GifImagePlugin.getdata(
                im, duration=duration_ms, transparency=GIF_CLEAR, disposal=1
            ):
                fh.write(chunk)
            previous = index
        fh.write(b";")


# --------------------------------------------------------------------------------------------
# command line


def replay_command(args: Any) -> int:
    """Run ``sumo-swarm replay``; returns the exit status."""
    result = write_replay(
        args.run_dir, args.out, follow=args.follow, t_from=args.t_from, t_to=args.t_to, fps=args.fps
    )
    print(f"replay: {result.frames} frames in {result.wall_s:.1f} s -> {result.path}")
    return 0
