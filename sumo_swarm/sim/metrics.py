"""Measures of effectiveness of the paper's Section IV, computed from a run's trajectory table.

Pure functions over the trajectory table (no SUMO import). The table is a pandas DataFrame with
one row per vehicle per SUMO step and the columns

``time_s, vehicle, kind, edge, lane, x_m, y_m, s_m, lat_m, speed_mps, accel_mps2, length_m``
(and, recorded by sumo-swarm for exact gaps, ``lane_pos_m, width_m, lane_width_m``)

where ``kind`` is ``"cav"`` or ``"hv"``, ``lane`` is the lane index (0 = rightmost) and ``s_m``
the front bumper along the route, one coordinate shared by all vehicles of a scenario. Each
function reads only the columns it needs and raises :class:`~sumo_swarm.errors.ConfigError`
naming any that are missing.

Conventions shared by every function here:

* "Same lane" means the same lane of the same edge at the same ``time_s`` (with ``edge``;
  junction lanes included), or reaching into it sideways, with the two vehicles' widths
  overlapping sideways (with ``width_m``, ``lane_width_m`` and ``lat_m``): see :func:`gaps`.
* The *leader* of a vehicle at a step is the nearest such vehicle strictly ahead of it (ties in
  position are broken by vehicle id, so an overlapping pair still gets a leader). The *gap* is
  bumper to bumper: ``leader position - leader.length_m - position`` [m] (positions on the lane,
  ``lane_pos_m``, when recorded, else ``s_m``), negative only when the two overlap.
* Everything returned for a summary is a plain Python ``int``/``float``/``str``; a measure that
  is undefined (no samples, NaN, infinite) is ``None``, so the result is valid JSON.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from sumo_swarm.checks import check_fields, finite_or_none, require_number
from sumo_swarm.errors import ConfigError

CAV = "cav"
HV = "hv"

HARD_BRAKE_MPS2 = 4.0  # [m/s^2] contract: "decelerated harder than 4 m/s^2"
ACCEL_TOLERANCE_MPS2 = 1e-6  # [m/s^2] float noise allowed around the hard-brake threshold
STOPPED_MPS = 1e-6  # [m/s] below this a follower's time headway is infinite
CLOSING_MPS = 1e-6  # [m/s] a pair closes in only when the follower is faster by more than this
TIME_TOLERANCE_S = 1e-6  # [s] slack on window bounds and reference times (float time stamps)
# An upstream HV counts as influenced when its speed dropped by more than this [%]. The paper
# (IV-E-4) calls the 4th follower, at 0.42 %, still influenced, and the ones after it not.
INFLUENCE_THRESHOLD_PCT = 0.1


# --------------------------------------------------------------------------------------------
# helpers


def _require(df: pd.DataFrame, columns: Iterable[str]) -> None:
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise ConfigError(f"trajectory table lacks column(s) {', '.join(missing)}")


# --------------------------------------------------------------------------------------------
# evaluation window


@dataclass(frozen=True, slots=True)
class EvaluationWindow:
    """Closed time interval ``[start_s, end_s]`` of simulation time [s].

    ``None`` leaves that end open. Both bounds are inclusive, with a slack of
    ``TIME_TOLERANCE_S`` so that float time stamps such as ``12.300000000000001`` fall inside a
    window that ends at ``12.3``.
    """

    start_s: float | None = None
    end_s: float | None = None

    def __post_init__(self) -> None:
        check_fields(self, "start_s", "end_s")  # finite (or None: open)
        if self.start_s is not None and self.end_s is not None and self.end_s < self.start_s:
            raise ConfigError(
                f"evaluation window ends ({self.end_s} s) before it starts ({self.start_s} s)"
            )


def window(df: pd.DataFrame, w: EvaluationWindow | None) -> pd.DataFrame:
    """Rows of ``df`` whose ``time_s`` lies in ``w`` (all rows when ``w`` is None): ``df``
    itself when every row does (a run's table is large; callers only read it)."""
    if w is None:
        return df
    _require(df, ["time_s"])
    t = df["time_s"].to_numpy(dtype=float)
    keep = np.ones(len(df), dtype=bool)
    if w.start_s is not None:
        keep &= t >= w.start_s - TIME_TOLERANCE_S
    if w.end_s is not None:
        keep &= t <= w.end_s + TIME_TOLERANCE_S
    return df if keep.all() else df[keep]


# The metric functions take their window as a parameter named ``window``, which hides the
# function of that name inside them.
_select = window


# --------------------------------------------------------------------------------------------
# mobility


def cav_speed_stats(
    df: pd.DataFrame, window: EvaluationWindow | None = None, *, kind: str = CAV
) -> dict[str, float | int | None]:
    """Speed statistics of the platoon (all CAV speed samples in the window).

    Returns
    -------
    dict
        ``mean_speed_mps``: mean of all CAV speed samples in the window, i.e. the platoon's
        average speed over CAVs and steps [m/s] (the paper's Fig. 9 measure).
        ``min_speed_mps`` / ``max_speed_mps``: extreme samples [m/s].
        ``speed_var_m2ps2``: population variance (ddof 0) of those samples [m^2/s^2].
        ``count``: number of distinct CAVs with at least one sample in the window.
        ``samples``: number of samples.
        Speeds are None when there is no sample.
    """
    _require(df, ["time_s", "vehicle", "kind", "speed_mps"])
    cav = _select(df, window)
    cav = cav[cav["kind"] == kind]
    return speed_stats(cav["speed_mps"].to_numpy(dtype=float), int(cav["vehicle"].nunique()))


def speed_stats(speeds: np.ndarray, count: int) -> dict[str, float | int | None]:
    """:func:`cav_speed_stats` of the speed samples ``speeds`` of ``count`` CAVs."""
    if speeds.size == 0:
        return {
            "mean_speed_mps": None,
            "min_speed_mps": None,
            "max_speed_mps": None,
            "speed_var_m2ps2": None,
            "count": 0,
            "samples": 0,
        }
    return {
        "mean_speed_mps": finite_or_none(speeds.mean()),
        "min_speed_mps": finite_or_none(speeds.min()),
        "max_speed_mps": finite_or_none(speeds.max()),
        "speed_var_m2ps2": finite_or_none(speeds.var()),
        "count": count,
        "samples": int(speeds.size),
    }


def _time_to_cover(
    t: np.ndarray, s: np.ndarray, distance_m: float, start: tuple[float, float]
) -> float | None:
    """Time from ``start = (t0, s0)``, a vehicle's first sample, until ``s`` first reaches
    ``s0 + distance_m``, linearly interpolated between samples; ``t`` and ``s`` begin with
    ``start`` or continue the track from a sample that did not reach the distance
    (:class:`TravelClock`)."""
    t0, s0 = start
    target = s0 + distance_m
    reached = np.flatnonzero(s >= target - 1e-9)
    if reached.size == 0:
        return None
    i = int(reached[0])
    if i == 0:
        return float(t[0] - t0)
    ds = s[i] - s[i - 1]
    frac = (target - s[i - 1]) / ds if ds > 0 else 1.0
    return float(t[i - 1] + frac * (t[i] - t[i - 1]) - t0)


class TravelClock:
    """Each vehicle's travel time over ``distance_m`` (see :func:`travel_time_s`) from its
    samples in time order, given in as many calls of :meth:`add` as come: the whole track at
    once (:func:`travel_times_s`) or a slice of the run at a time (the streamed summary).
    Holds two samples per vehicle, whatever the length of the run."""

    def __init__(self, distance_m: float) -> None:
        require_number("travel distance_m", distance_m, gt=0.0)
        self.distance_m = distance_m
        self._start: dict[str, tuple[float, float]] = {}
        self._last: dict[str, tuple[float, float]] = {}
        self._times: dict[str, float | None] = {}

    def add(self, vehicle: str, t: np.ndarray, s: np.ndarray) -> None:
        """The next samples of ``vehicle``: times ``t`` [s] and positions ``s`` [m]."""
        if t.size == 0 or self._times.get(vehicle) is not None:
            return
        start = self._start.setdefault(vehicle, (float(t[0]), float(s[0])))
        last = self._last.get(vehicle)
        if last is not None:  # from the last sample, which did not reach the distance
            t, s = np.concatenate(([last[0]], t)), np.concatenate(([last[1]], s))
        self._times[vehicle] = _time_to_cover(t, s, self.distance_m, start)
        self._last[vehicle] = (float(t[-1]), float(s[-1]))

    def times(self) -> dict[str, float | None]:
        """``{vehicle: seconds or None}`` as :func:`travel_times_s` gives them."""
        return {v: self._times[v] for v in sorted(self._times)}


def travel_times_s(
    df: pd.DataFrame,
    window: EvaluationWindow | None = None,
    distance_m: float | None = None,
    *,
    kind: str = CAV,
) -> dict[str, float | None]:
    """Per-CAV travel time [s] over ``distance_m``: see :func:`travel_time_s` for the definition.

    Returns ``{vehicle: seconds or None}`` (None: the CAV did not cover the distance inside the
    window), ordered by vehicle id.
    """
    _require(df, ["time_s", "vehicle", "kind", "s_m"])
    cav = _select(df, window)
    cav = cav[cav["kind"] == kind].sort_values(["vehicle", "time_s"], kind="mergesort")
    tracks = {
        str(v): (g["time_s"].to_numpy(dtype=float), g["s_m"].to_numpy(dtype=float))
        for v, g in cav.groupby("vehicle", sort=True, observed=True)
    }
    if not tracks:
        return {}
    if distance_m is None:
        distance_m = min(s[-1] - s[0] for _, s in tracks.values())
        if not distance_m > 0 or not math.isfinite(distance_m):  # NaN too: nothing covered
            return {v: None for v in tracks}
    clock = TravelClock(distance_m)
    for v, (t, s) in tracks.items():
        clock.add(v, t, s)
    return clock.times()


def travel_time_s(
    df: pd.DataFrame,
    window: EvaluationWindow | None = None,
    distance_m: float | None = None,
    *,
    kind: str = CAV,
) -> float | None:
    """Mean time the CAVs need to travel ``distance_m`` [s].

    For each CAV with samples in the window, its start is its first sample in the window
    (time ``t0``, position ``s0``); its travel time is the first time its front bumper reaches
    ``s0 + distance_m``, linearly interpolated between steps, minus ``t0``. The result is the
    mean over the CAVs.

    ``distance_m=None`` uses the shortest distance any CAV covers inside the window, so every
    CAV reaches it. That default depends on the run; to compare controllers, pass the same
    ``distance_m`` to each.

    Returns None when there is no CAV in the window, when a CAV does not cover the distance
    before the window ends (the platoon's travel time is then undefined), or when the default
    distance is zero.
    """
    return mean_travel_time_s(travel_times_s(df, window, distance_m, kind=kind))


def mean_travel_time_s(per_cav: dict[str, float | None]) -> float | None:
    """:func:`travel_time_s` of the per-CAV times :func:`travel_times_s` gives."""
    times = list(per_cav.values())
    if not times or any(t is None for t in times):
        return None
    return finite_or_none(np.mean(times))


# --------------------------------------------------------------------------------------------
# gaps, headways, time to collision


# Optional columns of the trajectory table that make the pairing exact (recorded by sumo-swarm;
# hand-made tables without them fall back to ``s_m`` and to vehicles as wide as their lane).
LANE_POS = "lane_pos_m"  # front bumper along its lane [m] (SUMO's lanePosition)
WIDTH = "width_m"  # vehicle width [m]
LANE_WIDTH = "lane_width_m"  # width of the lane the vehicle is on [m]
LATERAL_TOLERANCE_M = 1e-6  # [m] vehicles that only touch sideways do not overlap
# Candidates looked at ahead of a vehicle in one lane for the first one that overlaps it
# sideways (the others drive beside it in the same lane, sublane model).
LEADER_LOOKAHEAD = 6


def _finite_column(df: pd.DataFrame, column: str) -> np.ndarray | None:
    """``df[column]`` as floats when present (NaN where unknown), else None."""
    return df[column].to_numpy(dtype=float) if column in df.columns else None


# Rows of a trajectory table paired at once by :func:`gaps` (whole steps each time): the
# pairing's temporaries take about 500 bytes a row, so a long run is paired in slices.
GAPS_SLICE_ROWS = 200_000


def gaps(df: pd.DataFrame) -> pd.DataFrame:
    """Leader, gap, headway and time to collision of every vehicle at every step.

    Two vehicles are a follower/leader pair only when they really share a lane at that step:

    * the same lane of the same edge (``edge`` and ``lane``: one SUMO lane id, junction lanes
      ``:J_0_0`` included); lane indices change at junctions and where a lane ends, so lane 1 of
      one edge need not be lane 1 of the next, and a leader just across an edge boundary is not
      paired;
    * a vehicle part-way into the neighbouring lane (sublane model, or mid lane change: its
      ``lat_m`` plus half its ``width_m`` past half its ``lane_width_m``) is in both lanes;
    * their widths overlap sideways: two narrow vehicles side by side in one lane are no pair.

    The leader is the nearest such vehicle ahead (ties in position broken by vehicle id, so an
    overlapping pair still gets a leader). Positions are ``lane_pos_m`` when the table has it
    for every row of the step (SUMO's own position on the lane, exact on any edge), else
    ``s_m``. Without
    ``width_m``/``lane_width_m`` every vehicle fills its lane and pairs are by lane alone.
    Vectorised: rows are sorted by (time, edge, lane, position, vehicle) once and each row's
    leader is among the next ``LEADER_LOOKAHEAD`` rows of the same lane.

    Returns
    -------
    pandas.DataFrame
        Same index and row order as ``df``, with columns
        ``time_s, vehicle, kind, lane`` (copied from ``df``),
        ``leader`` (vehicle id, missing when nobody is ahead in the lane), ``leader_kind``,
        ``gap_m`` (bumper to bumper ``leader position - leader.length_m - position`` [m],
        negative only when the two overlap; NaN without a leader),
        ``headway_s`` (``gap_m / speed_mps`` [s]; ``inf`` when the follower is stopped,
        ``speed_mps <= STOPPED_MPS``; NaN without a leader),
        ``closing_speed_mps`` (``speed_mps - leader speed`` [m/s], positive when closing in),
        ``ttc_s`` (time to collision ``max(gap_m, 0) / closing_speed_mps`` [s] when closing
        faster than ``CLOSING_MPS``, else ``inf``; NaN without a leader).
    """
    _require(df, ["time_s", "vehicle", "kind", "lane", "s_m", "speed_mps", "length_m"])
    if len(df) <= GAPS_SLICE_ROWS:
        return _gaps(df)
    # Steps are independent: pair whole steps a slice at a time, then put the rows back in order.
    t = df["time_s"].to_numpy(dtype=float)
    times = np.unique(t)
    per_slice = max(1, int(len(times) * GAPS_SLICE_ROWS / len(df)))
    parts, where = [], []
    for lo in range(0, len(times), per_slice):
        hi = lo + per_slice
        keep = t >= times[lo]
        if hi < len(times):
            keep &= t < times[hi]
        rows = np.flatnonzero(keep)
        parts.append(_gaps(df.iloc[rows]))
        where.append(rows)
    out = pd.concat(parts)
    order = np.argsort(np.concatenate(where), kind="stable")
    return out.iloc[order]


def _sorted_codes(column: pd.Series) -> np.ndarray:
    """Integers in the order of ``column``'s values as text (equal values, equal integers):
    a categorical column's codes ranked by their categories, without making a text array."""
    if isinstance(column.dtype, pd.CategoricalDtype) and not column.isna().any():
        names = column.cat.categories.astype(str).to_numpy(dtype=object)
        rank = np.empty(len(names), dtype=np.int64)
        rank[np.argsort(names, kind="stable")] = np.arange(len(names))
        return rank[column.cat.codes.to_numpy()]
    return pd.factorize(column.astype(str), sort=True)[0]


def _gaps(df: pd.DataFrame) -> pd.DataFrame:
    """:func:`gaps` of a table small enough to pair at once."""
    n = len(df)
    edge = _sorted_codes(df["edge"]) if "edge" in df.columns else np.zeros(n, dtype=np.int64)
    lane = df["lane"].to_numpy(dtype=np.int64)
    t = df["time_s"].to_numpy(dtype=float)
    pos = _finite_column(df, LANE_POS)
    if pos is None:
        pos = df["s_m"].to_numpy(dtype=float)
    elif not np.isfinite(pos).all():
        # Step by step (so that a slice of steps is paired as the whole table): a step with a
        # position on the lane unknown is paired on the route coordinate, all of its rows.
        unknown = np.isin(t, t[~np.isfinite(pos)])
        pos = np.where(unknown, df["s_m"].to_numpy(dtype=float), pos)
    lat = _finite_column(df, "lat_m")
    lat = np.zeros(n) if lat is None else np.nan_to_num(lat)
    width = _finite_column(df, WIDTH)
    lane_width = _finite_column(df, LANE_WIDTH)
    if width is None or lane_width is None:
        width = np.full(n, np.nan)
        lane_width = np.full(n, np.nan)
    known = np.isfinite(width) & np.isfinite(lane_width)
    half_w = np.where(known, 0.5 * width, 0.0)
    half_lane = np.where(known, 0.5 * lane_width, 0.0)
    into_left = known & (lat + half_w > half_lane + LATERAL_TOLERANCE_M)
    into_right = known & (lat - half_w < -half_lane - LATERAL_TOLERANCE_M)

    # One entry per lane a vehicle is in: its own, and the neighbour it reaches into.
    rows = np.concatenate([np.arange(n), np.flatnonzero(into_left), np.flatnonzero(into_right)])
    occ_lane = np.concatenate([lane, lane[into_left] + 1, lane[into_right] - 1])
    vid_code = _sorted_codes(df["vehicle"])
    order = np.lexsort((vid_code[rows], pos[rows], occ_lane, edge[rows], t[rows]))
    rows = rows[order]
    group_t, group_e, group_l = t[rows], edge[rows], occ_lane[order]
    m = len(rows)

    leader_row = np.full(m, -1, dtype=np.int64)  # per entry: the row of its leader
    # Entries still looking, tried against the entry k places on. A lane's entries of a step
    # are contiguous, so one whose k-th next is in another lane has no leader further on.
    pending = np.arange(m)
    for k in range(1, LEADER_LOOKAHEAD + 1):
        pending = pending[pending + k < m]
        if pending.size == 0:
            break
        i, j = pending, pending + k
        same = (group_t[j] == group_t[i]) & (group_e[j] == group_e[i]) & (group_l[j] == group_l[i])
        i, j = i[same], j[same]
        a, b = rows[i], rows[j]
        # lateral distance of b's centre from a's: lanes apart times the mean lane width
        both = known[a] & known[b]
        centre = (lane[b] - lane[a]) * (half_lane[a] + half_lane[b]) + lat[b] - lat[a]
        overlap = ~both | (np.abs(centre) < half_w[a] + half_w[b] - LATERAL_TOLERANCE_M)
        leader_row[i[overlap]] = b[overlap]
        pending = i[~overlap]

    # Per vehicle row: the nearest of the leaders found in the lanes it is in.
    entry_gap = np.full(m, np.inf)
    found = leader_row >= 0
    lr = leader_row[found]
    length = df["length_m"].to_numpy(dtype=float)
    entry_gap[found] = pos[lr] - length[lr] - pos[rows[found]]
    best = np.full(n, -1, dtype=np.int64)
    best_gap = np.full(n, np.inf)
    # a vehicle in two lanes has two candidates: sort entries by (row, gap), the first wins
    pick = np.lexsort((entry_gap[found], rows[found]))
    frows = rows[found][pick]
    first = np.ones(len(frows), dtype=bool)
    first[1:] = frows[1:] != frows[:-1]
    best[frows[first]] = lr[pick][first]
    best_gap[frows[first]] = entry_gap[found][pick][first]

    has_leader = best >= 0
    nxt = np.where(has_leader, best, 0)
    speed = df["speed_mps"].to_numpy(dtype=float)
    gap = np.where(has_leader, best_gap, np.nan)
    closing = np.where(has_leader, speed - speed[nxt], np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        headway = np.where(speed > STOPPED_MPS, gap / np.maximum(speed, STOPPED_MPS), np.inf)
        ttc = np.where(
            closing > CLOSING_MPS, np.maximum(gap, 0.0) / np.maximum(closing, CLOSING_MPS), np.inf
        )
    headway[~has_leader] = np.nan
    ttc[~has_leader] = np.nan
    vehicle, leader = _with_leaders(df["vehicle"], nxt, has_leader)
    kind, leader_kind = _with_leaders(df["kind"], nxt, has_leader)
    return pd.DataFrame(
        {
            "time_s": df["time_s"].to_numpy(),
            "vehicle": vehicle,
            "kind": kind,
            "lane": df["lane"].to_numpy(),
            "leader": leader,
            "leader_kind": leader_kind,
            "gap_m": gap,
            "headway_s": headway,
            "closing_speed_mps": closing,
            "ttc_s": ttc,
        },
        index=df.index,
    )


def _with_leaders(column: pd.Series, nxt: np.ndarray, has_leader: np.ndarray) -> tuple:
    """``column``'s values and, per row, its leader's (``nxt``; missing where ``has_leader``
    is False). A categorical column stays categorical: as text, a table of a run's rows takes
    pandas longer to make than the pairing itself."""
    if isinstance(column.dtype, pd.CategoricalDtype):
        codes = column.cat.codes.to_numpy()
        lead = np.where(has_leader, codes[nxt], -1)
        return column.array, pd.Categorical.from_codes(lead, dtype=column.dtype)
    values = column.to_numpy(dtype=object)
    lead = np.full(len(values), None, dtype=object)
    lead[has_leader] = values[nxt][has_leader]
    return values, lead


def cav_gap_stats(
    df: pd.DataFrame,
    window: EvaluationWindow | None = None,
    *,
    kind: str = CAV,
    max_gap_m: float | None = None,
    gap_table: pd.DataFrame | None = None,
) -> dict[str, float | int | None]:
    """Following distance of the CAVs (the paper's Fig. 10 measure).

    Over every step in the window and every CAV that has a leader in its lane (a CAV or an HV),
    the bumper-to-bumper gap as defined by :func:`gaps`. ``max_gap_m`` (optional) drops samples
    with a larger gap, i.e. a CAV that is not following anyone in particular.

    Returns ``gap_mean_m`` (mean of the samples) [m], ``gap_min_m`` (smallest sample) [m],
    the smallest behind a CAV (``gap_min_cav_m``: the swarm's own spacing) and behind an HV
    (``gap_min_hv_m``: HVs may cut in closer than the swarm would ever go) [m], and
    ``samples``; the gaps are None when there is no sample. ``gap_table``: :func:`gaps` of
    the window, when the caller has it already (it is the costly part).
    """
    g = gaps(_select(df, window)) if gap_table is None else gap_table
    g = g[(g["kind"] == kind) & g["gap_m"].notna()]
    if max_gap_m is not None:
        g = g[g["gap_m"] <= max_gap_m]
    return gap_stats(g["gap_m"].to_numpy(dtype=float), (g["leader_kind"] == kind).to_numpy())


def gap_stats(values: np.ndarray, behind_cav: np.ndarray) -> dict[str, float | int | None]:
    """:func:`cav_gap_stats` of the gap samples ``values`` [m] (none NaN); ``behind_cav``:
    which of them are behind a CAV."""
    if values.size == 0:
        return {"gap_mean_m": None, "gap_min_m": None, "gap_min_cav_m": None,
                "gap_min_hv_m": None, "samples": 0}  # fmt: skip
    return {
        "gap_mean_m": finite_or_none(values.mean()),
        "gap_min_m": finite_or_none(values.min()),
        "gap_min_cav_m": finite_or_none(values[behind_cav].min()) if behind_cav.any() else None,
        "gap_min_hv_m": finite_or_none(values[~behind_cav].min()) if (~behind_cav).any() else None,
        "samples": int(values.size),
    }


def min_ttc_s(
    df: pd.DataFrame,
    window: EvaluationWindow | None = None,
    gap_table: pd.DataFrame | None = None,
) -> float | None:
    """Smallest time to collision [s] over all follower/leader pairs and steps in the window.

    Time to collision is ``max(gap_m, 0) / (v_follower - v_leader)`` for a follower and its
    leader in the same lane (see :func:`gaps`), counted only while the follower closes in faster
    than ``CLOSING_MPS``. Vehicles of any kind. None when no pair ever closes in.
    ``gap_table``: :func:`gaps` of the window, when the caller has it already.
    """
    g = gaps(_select(df, window)) if gap_table is None else gap_table
    ttc = g["ttc_s"].to_numpy(dtype=float)
    ttc = ttc[np.isfinite(ttc)]
    return finite_or_none(ttc.min()) if ttc.size else None


# --------------------------------------------------------------------------------------------
# hard braking


def hard_brake_events(
    df: pd.DataFrame,
    threshold_mps2: float = HARD_BRAKE_MPS2,
    window: EvaluationWindow | None = None,
) -> pd.DataFrame:
    """Episodes of braking harder than ``threshold_mps2``, vehicles of any kind.

    A sample brakes hard when ``accel_mps2 < -(threshold_mps2 + ACCEL_TOLERANCE_MPS2)``: strictly
    beyond the threshold, so a deceleration of exactly 4 m/s^2 (give or take float noise) is not
    hard braking. An episode is a run of consecutive samples of one vehicle (in time order) that
    all brake hard.

    Returns
    -------
    pandas.DataFrame
        One row per episode, ordered by ``start_s`` then vehicle, with columns
        ``vehicle, kind, start_s, end_s`` (first and last hard-braking sample [s]),
        ``min_accel_mps2`` (the strongest deceleration, negative) and ``samples``.
    """
    columns = ["time_s", "vehicle", "kind", "accel_mps2"]
    _require(df, columns)
    d = _select(df, window)[columns].sort_values(["vehicle", "time_s"], kind="mergesort")
    hard = (d["accel_mps2"] < -(threshold_mps2 + ACCEL_TOLERANCE_MPS2)).to_numpy()
    vehicle = d["vehicle"].to_numpy(dtype=object)
    new_vehicle = np.ones(len(d), dtype=bool)
    new_vehicle[1:] = vehicle[1:] != vehicle[:-1]
    prev_hard = np.zeros(len(d), dtype=bool)
    prev_hard[1:] = hard[:-1]
    starts = hard & (new_vehicle | ~prev_hard)
    episode = np.cumsum(starts)
    events = (
        d[hard]
        .assign(episode=episode[hard])
        .groupby("episode", sort=True)
        .agg(
            vehicle=("vehicle", "first"),
            kind=("kind", "first"),
            start_s=("time_s", "min"),
            end_s=("time_s", "max"),
            min_accel_mps2=("accel_mps2", "min"),
            samples=("time_s", "size"),
        )
    )
    columns = ["vehicle", "kind", "start_s", "end_s", "min_accel_mps2", "samples"]
    return events.sort_values(["start_s", "vehicle"], kind="mergesort").reset_index(drop=True)[
        columns
    ]


class HardBrakeCounter:
    """Hard brakes counted step by step, of every vehicle, whatever a run records.

    The same test and the same episodes as :func:`hard_brake_events` on a table of every
    vehicle at every step: a sample brakes hard below ``-(threshold_mps2 +
    ACCEL_TOLERANCE_MPS2)``, an episode is a run of a vehicle's consecutive samples that do.
    """

    def __init__(self, threshold_mps2: float = HARD_BRAKE_MPS2) -> None:
        self.limit_mps2 = -(threshold_mps2 + ACCEL_TOLERANCE_MPS2)
        self.episodes = 0
        self.vehicles: dict[str, str] = {}  # every vehicle that ever braked hard -> its kind
        self._last_hard: set[str] = set()  # vehicles whose latest sample braked hard

    def update(self, ids: Sequence[str], accels: Sequence[float], kinds: Mapping[str, str]) -> None:
        """One step: vehicle ``ids[i]``'s acceleration at it is ``accels[i]`` [m/s^2] (every
        vehicle of the step)."""
        limit = self.limit_mps2
        hard = {v for v, a in zip(ids, accels, strict=True) if a < limit}
        starts = hard - self._last_hard
        self.episodes += len(starts)
        for v in starts:
            self.vehicles.setdefault(v, kinds.get(v, "hv"))
        # a vehicle absent this step keeps its latest sample's state (as in a table)
        if self._last_hard - hard:
            present = set(ids)
            hard |= {v for v in self._last_hard if v not in present}
        self._last_hard = hard

    def update_steps(
        self, times: np.ndarray, ids: np.ndarray, accels: np.ndarray, kinds: Mapping[str, str]
    ) -> None:
        """Whole steps in time order (row ``i``: vehicle ``ids[i]`` at ``times[i]`` [s],
        acceleration ``accels[i]`` [m/s^2]), as :meth:`update` step by step; a step without a
        hard sample, after one without, changes nothing and is passed over."""
        starts = np.flatnonzero(np.diff(times)) + 1
        hard = accels < self.limit_mps2
        bounds = zip(np.r_[0, starts], np.r_[starts, len(times)], strict=True)
        for a, b in bounds:
            if self._last_hard or hard[a:b].any():
                self.update(ids[a:b].tolist(), accels[a:b].tolist(), kinds)

    def count(self, kind: str | None = None) -> int:
        """Vehicles (of ``kind``, or any) that ever braked hard (:func:`hard_brakes`)."""
        return sum(1 for k in self.vehicles.values() if kind is None or k == kind)


def hard_brakes(
    df: pd.DataFrame,
    threshold_mps2: float = HARD_BRAKE_MPS2,
    window: EvaluationWindow | None = None,
) -> int:
    """Number of vehicles (any kind) that ever braked harder than ``threshold_mps2`` [m/s^2].

    Each vehicle counts once however many hard-braking samples or episodes it has; see
    :func:`hard_brake_events` for the test applied to a sample.
    """
    return int(hard_brake_events(df, threshold_mps2, window)["vehicle"].nunique())


# --------------------------------------------------------------------------------------------
# influence on upstream traffic


def upstream_impact(
    df: pd.DataFrame,
    ref_time_s: float | None,
    *,
    swarm_kind: str = CAV,
    n_rank: int = 5,
    window: EvaluationWindow | None = None,
    undisturbed: Mapping[str, float] | None = None,
    behind_of: str = "rear",
    exclude: Iterable[str] = (),
    gap_table: pd.DataFrame | None = None,
) -> list[dict[str, object]]:
    """Speed and following distance of the vehicles upstream of the swarm (paper's Fig. 12).

    ``behind_of="front"`` selects the vehicles behind the swarm's *front* (its front-most
    bumper) instead of its rear: with it the HVs beside the platoon at the reference step, the
    ones a swarm blocks, are ranked too (nearest the swarm's front first). ``exclude`` leaves
    vehicles out (e.g. the slow vehicle being overtaken).

    Selection, at the reference step (the first recorded step at or after ``ref_time_s``, the
    start of the manoeuvre; the table's first step when None): the swarm's rear is the smallest
    rear bumper (``s_m - length_m``) of the vehicles of ``swarm_kind``; the upstream vehicles
    are the other vehicles whose front bumper is behind it (``s_m <`` swarm rear). In each lane
    (the lane at the reference step), they are ranked nearest first (largest ``s_m``; rank 1 =
    right behind the swarm), up to ``n_rank`` per lane.

    Measures of each, over ``window`` (default: from the reference step to the end of the
    table), whatever lane it drives in then:

    * ``undisturbed_speed_mps``: ``undisturbed[vehicle]`` when given (e.g. its speed in a run
      without the swarm), else its speed at the reference step [m/s];
    * ``min_speed_mps``: its smallest speed sample [m/s];
    * ``speed_reduction_pct``: ``max(0, (undisturbed - min) / undisturbed * 100)`` [%]
      (0 when the undisturbed speed is not positive);
    * ``min_gap_m`` / ``min_headway_s``: its smallest gap [m] and time headway [s] to the
      vehicle ahead in its lane, any kind (see :func:`gaps`); None if nobody was ever ahead
      (or, for the headway, if it never moved).

    ``gap_table``: :func:`gaps` of a table holding every row of the window (the same index),
    when the caller has it already; its rows of the window are used.

    Returns
    -------
    list of dict
        Keys ``lane, rank, vehicle, undisturbed_speed_mps, min_speed_mps, speed_reduction_pct,
        min_gap_m, min_headway_s``, ordered by lane then rank. Empty when the table has no step
        at or after ``ref_time_s`` (before the end of ``window``, when given) or no vehicle of
        ``swarm_kind`` at that step.
    """
    if n_rank < 1:
        raise ConfigError(f"n_rank must be at least 1, got {n_rank}")
    _require(df, ["time_s", "vehicle", "kind", "lane", "s_m", "speed_mps", "length_m"])
    times = df["time_s"].to_numpy(dtype=float)
    later = times if ref_time_s is None else times[times >= ref_time_s - TIME_TOLERANCE_S]
    if later.size == 0:
        return []
    t_ref = float(later.min())
    if window is not None and window.end_s is not None and t_ref > window.end_s + TIME_TOLERANCE_S:
        return []  # the reference step comes after the window: nothing of it to measure
    at_ref = df[times == t_ref]
    swarm = at_ref[at_ref["kind"] == swarm_kind]
    if swarm.empty:
        return []
    if behind_of == "front":
        limit = float(swarm["s_m"].max())
    elif behind_of == "rear":
        limit = float((swarm["s_m"] - swarm["length_m"]).min())
    else:
        raise ConfigError(f"behind_of must be 'rear' or 'front', got {behind_of!r}")
    excluded = {str(v) for v in exclude}
    behind = at_ref[
        (at_ref["kind"] != swarm_kind)
        & (at_ref["s_m"] < limit)
        & ~at_ref["vehicle"].astype(str).isin(excluded)
    ]
    behind = behind.assign(vehicle_key=behind["vehicle"].astype(str)).sort_values(
        ["lane", "s_m", "vehicle_key"], ascending=[True, False, True], kind="mergesort"
    )
    behind = behind.assign(rank=behind.groupby("lane").cumcount() + 1)
    behind = behind[behind["rank"] <= n_rank]
    if behind.empty:
        return []

    in_window = _select(df, window if window is not None else EvaluationWindow(t_ref, None))
    if gap_table is None:
        followed = gaps(in_window)
    else:  # the pairing is step by step: the window's rows of a larger table are the same
        followed = gap_table[gap_table.index.isin(in_window.index)]
    ids = behind["vehicle"].to_numpy()
    speeds = _smallest_by_vehicle(in_window[in_window["vehicle"].isin(ids)], "speed_mps")
    mine = followed[followed["vehicle"].isin(ids) & followed["gap_m"].notna()]
    min_gap = _smallest_by_vehicle(mine, "gap_m")
    min_headway = _smallest_by_vehicle(mine, "headway_s")
    undisturbed = undisturbed or {}

    rows: list[dict[str, object]] = []
    for row in behind.itertuples(index=False):
        vid = str(row.vehicle)
        reference = finite_or_none(undisturbed.get(vid, row.speed_mps))
        slowest = finite_or_none(speeds.get(vid))
        if reference is None or slowest is None or reference <= 0:
            reduction = 0.0 if reference is not None and slowest is not None else None
        else:
            reduction = max(0.0, (reference - slowest) / reference * 100.0)
        rows.append(
            {
                "lane": int(row.lane),
                "rank": int(row.rank),
                "vehicle": vid,
                "undisturbed_speed_mps": reference,
                "min_speed_mps": slowest,
                "speed_reduction_pct": reduction,
                "min_gap_m": finite_or_none(min_gap.get(vid)),
                "min_headway_s": finite_or_none(min_headway.get(vid)),
            }
        )
    return rows


def upstream_window(ref_time_s: float, end_s: float) -> EvaluationWindow | None:
    """The window of a summary's upstream block: from the reference time (the manoeuvre's
    start) to the end of the evaluation window [s]; None when the manoeuvre began after that
    end (a run evaluated over its first minute, a swarm that overtook later): no block."""
    return EvaluationWindow(ref_time_s, end_s) if ref_time_s <= end_s else None


def _smallest_by_vehicle(rows: pd.DataFrame, column: str) -> dict[str, float]:
    """Each vehicle's smallest ``column`` in ``rows`` (NaN skipped), keyed by its name as text.

    Grouped on the names as text and looked up in a dict, never in a categorical index: in
    pandas 3.1 an empty group-by of a categorical column gives an index with int8 codes however
    many categories it has, and looking up a name beyond the 127th raises OverflowError instead
    of missing (a busy road whose upstream vehicles never follow anyone)."""
    if rows.empty:
        return {}
    values = pd.Series(rows[column].to_numpy(dtype=float))
    smallest = values.groupby(rows["vehicle"].astype(str).to_numpy(dtype=object)).min()
    return {str(v): float(x) for v, x in smallest.items()}


def influenced_count(
    upstream: Iterable[Mapping[str, object]], threshold_pct: float = INFLUENCE_THRESHOLD_PCT
) -> dict[int, int]:
    """Number of upstream vehicles per lane whose speed dropped by more than ``threshold_pct``.

    ``upstream`` is the list :func:`upstream_impact` returns. A vehicle counts when its
    ``speed_reduction_pct`` is strictly greater than ``threshold_pct`` [%] (None never counts).
    Every lane that appears in ``upstream`` is a key, with 0 when nobody there was slowed;
    keys in ascending order.
    """
    counts: dict[int, int] = {}
    for entry in upstream:
        lane = int(entry["lane"])  # type: ignore[call-overload]
        reduction = entry.get("speed_reduction_pct")
        hit = reduction is not None and float(reduction) > threshold_pct  # type: ignore[arg-type]
        counts[lane] = counts.get(lane, 0) + int(hit)
    return dict(sorted(counts.items()))


# --------------------------------------------------------------------------------------------
# small summaries
