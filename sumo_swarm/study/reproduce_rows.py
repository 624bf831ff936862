"""The rows of the reproduce report: each measure's definition, source and paper value, and the
targets, each threshold read from the scenario where the scenario holds one.

A row reads one number per run from the run's ``summary.json`` (the output contract): the dotted
``source`` as it stands, or a stated formula over it. The upstream HVs' speed reductions and
influenced counts (``basis="paired"``) pair each run with the baseline run, HV by HV, from the
runs' ``trajectories.parquet`` (:func:`paired_upstream`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd

from sumo_swarm.config import Scenario
from sumo_swarm.sim import metrics
from sumo_swarm.study.batch.store import INFLUENCE_THRESHOLD_PCT
from sumo_swarm.study.plots import lane_name

BASELINE = "cacc"  # the paper's baseline: mobility gains are measured against it
FOCUS = "swarm"  # the paper's method: the single-run figures and the targets are about it

# The paper's numbers (Section IV-E; Fig. 8 text for the times; IV-C for the cell length).
PAPER_SPEED_MPS = 19.43
PAPER_GAIN_PCT = 12.04
PAPER_CACC_SPEED_MPS = PAPER_SPEED_MPS / (1 + PAPER_GAIN_PCT / 100)  # 17.34 m/s
PAPER_GAP_MEAN_M = 16.80
PAPER_DESIRED_GAP_M = 10.0
PAPER_GAP_EXCESS_PCT = 68.0  # 16.80 m against the 10 m desired distance
PAPER_UPSTREAM_REDUCTION_PCT = (2.19, 1.51, 0.92, 0.42)  # 1st..4th following HV
PAPER_UPSTREAM_GAP_M = 23.87
PAPER_UPSTREAM_HEADWAY_S = 1.4
PAPER_INFLUENCED = 4  # "limits its influence on traffic within four following HVs"
PAPER_BEHAVING_STEPS = 14
PAPER_BEHAVING_INTERVAL_S = 3.0
PAPER_PASS_S = 27.0  # "from time 9 s to 27 s all following CAVs cut through"
PAPER_REGROUP_S = 42.0  # "from time 27 s to 42 s, CAVs reform into a platoon"
PAPER_CELL_LENGTH_M = 5.0  # IV-C's value (II-B-1's rule gives vehicle + safety distance)


def get(summary: Mapping[str, Any] | None, *keys: str) -> Any:
    """``summary[k0][k1]...``, None where a level is missing."""
    value: Any = summary
    for key in keys:
        if not isinstance(value, Mapping):
            return None
        value = value.get(key)
    return value


def finite(value: Any) -> Any:
    """A value for JSON: numpy scalars as Python numbers, NaN and inf as None."""
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def upstream_entry(summary: Mapping[str, Any] | None, lane: int, rank: int) -> dict | None:
    for entry in get(summary, "upstream") or []:
        if entry["lane"] == lane and entry["rank"] == rank:
            return entry
    return None


def _min_of(summary: Mapping[str, Any] | None, key: str) -> float | None:
    values = [e[key] for e in get(summary, "upstream") or [] if e.get(key) is not None]
    return min(values) if values else None


def _minus(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else a - b


def gain_pct(value: float | None, base: float | None) -> float | None:
    """(value / base - 1) x 100 [%]; None without both or with base <= 0."""
    if value is None or base is None or base <= 0:
        return None
    return (value / base - 1.0) * 100.0


Reader = Callable[[Mapping[str, Any] | None, Mapping[str, Any] | None], Any]


@dataclass(frozen=True)
class Measure:
    """One row: how to read a run's number (from its summary and the baseline's).

    ``value`` None reads the dotted ``source`` from the summary. ``basis="paired"`` rows read
    from ``{"upstream": <the run's paired upstream entries>}`` instead of summary.json.
    """

    key: str
    label: str  # with the unit, e.g. "platoon average speed (m/s)"
    definition: str  # key into :func:`definitions`
    source: str  # where in summary.json the number comes from (or the formula over it)
    value: Reader | None = None
    paper: float | int | bool | None = None
    paper_text: str | None = None  # what the paper says when it gives no single number
    digits: int = 2
    basis: str = "summary"  # "summary" or "paired"

    def read(self, summary: Mapping[str, Any] | None, base: Mapping[str, Any] | None) -> Any:
        if self.value is not None:
            return self.value(summary, base)
        return get(summary, *self.source.split("."))


def measures(scenario: Scenario, n_lanes: int, compared_lane: int) -> list[Measure]:
    """The rows of the report, in the order of the paper's Section IV-E."""
    desired = scenario.cav.desired_gap_m
    fig9 = "Fig. 9 only"
    rows = [
        Measure("cav.mean_speed", "platoon average speed (m/s)", "speed", "cav.mean_speed_mps",
                paper=PAPER_SPEED_MPS,
                paper_text=f"{PAPER_SPEED_MPS:.2f} ({BASELINE} {PAPER_CACC_SPEED_MPS:.2f})"),
        Measure("cav.mobility_gain", f"mobility gain over {BASELINE} (%)", "gain",
                f"(cav.mean_speed_mps / {BASELINE}'s - 1) * 100",
                lambda s, b: gain_pct(get(s, "cav", "mean_speed_mps"),
                                      get(b, "cav", "mean_speed_mps")), PAPER_GAIN_PCT),
        Measure("cav.min_speed", "minimum CAV speed (m/s)", "speed", "cav.min_speed_mps",
                paper_text=fig9),
        Measure("cav.max_speed", "maximum CAV speed (m/s)", "speed", "cav.max_speed_mps",
                paper_text=fig9),
        Measure("cav.speed_var", "variance of CAV speed (m²/s²)", "speed",
                "cav.speed_var_m2ps2", paper_text=fig9, digits=3),
        Measure("cav.travel_time",
                f"travel time over {scenario.evaluation.travel_distance_m:g} m (s)",
                "travel_time", "cav.travel_time_s", paper_text="not given"),
        Measure("cav.gap_mean", "mean CAV following distance (m)", "gap", "cav.gap_mean_m",
                paper=PAPER_GAP_MEAN_M),
        Measure("cav.gap_min", "minimum CAV following distance (m)", "gap", "cav.gap_min_m",
                paper_text=f"> {scenario.cav.min_gap_m:g}"),
        Measure("cav.gap_excess", f"mean following distance above the desired {desired:g} m (%)",
                "gap", f"(cav.gap_mean_m / {desired:g} - 1) * 100",
                lambda s, b: gain_pct(get(s, "cav", "gap_mean_m"), desired),
                PAPER_GAP_EXCESS_PCT, digits=1),
    ]  # fmt: skip  # one measure per group of lines: a table reads better so
    rows += upstream_measures(scenario, n_lanes, compared_lane, paired=True)
    rows += [
        Measure("upstream.min_gap", "minimum upstream following distance (m)", "upstream_gap",
                "min of upstream[].min_gap_m", lambda s, b: _min_of(s, "min_gap_m"),
                PAPER_UPSTREAM_GAP_M),
        Measure("upstream.min_headway", "minimum upstream time headway (s)", "upstream_gap",
                "min of upstream[].min_headway_s", lambda s, b: _min_of(s, "min_headway_s"),
                PAPER_UPSTREAM_HEADWAY_S),
        Measure("overtake.completed", "overtake completed (all CAVs past the slow HV)",
                "overtake", "overtake.completed", paper=True),
        Measure("overtake.regrouped", "regrouped into one platoon", "overtake",
                "overtake.regrouped", paper=True),
        Measure("overtake.behaving_steps", "overtake duration (behaving steps)", "overtake",
                "overtake.behaving_steps", paper=PAPER_BEHAVING_STEPS, digits=0),
        Measure("overtake.pass_s", "decision to all CAVs past the slow HV (s)", "overtake",
                "overtake.t_end_s - overtake.t_start_s",
                lambda s, b: _minus(get(s, "overtake", "t_end_s"),
                                    get(s, "overtake", "t_start_s")), PAPER_PASS_S, digits=1),
        Measure("overtake.duration_s", "overtake duration, decision to regrouped (s)",
                "overtake", "overtake.t_regrouped_s - overtake.t_start_s",
                lambda s, b: _minus(get(s, "overtake", "t_regrouped_s"),
                                    get(s, "overtake", "t_start_s")), PAPER_REGROUP_S, digits=1),
        Measure("safety.collisions", "collisions (count)", "safety", "safety.collisions",
                paper=0, digits=0),
        Measure("safety.hard_brakes",
                f"vehicles braking harder than {metrics.HARD_BRAKE_MPS2:g} m/s² (count)",
                "safety", "safety.hard_brakes", paper=0, digits=0),
        Measure("safety.teleports", "teleports (count)", "safety", "safety.teleports",
                paper_text="n/a (MATLAB)", digits=0),
    ]  # fmt: skip  # one measure per group of lines: a table reads better so
    return rows


def upstream_measures(
    scenario: Scenario, n_lanes: int, compared_lane: int, *, paired: bool
) -> list[Measure]:
    """Speed reduction per lane and rank, then the influenced count per lane.

    ``paired=True``: the report's rows, each upstream HV against itself in the baseline run,
    with the paper's numbers; ``paired=False``: the same rows as summary.json measures them
    (the secondary table, no paper column).
    """
    ranks = scenario.evaluation.upstream_ranks
    prefix, suffix, basis = (
        ("upstream", "", "paired") if paired else ("upstream.summary", ", summary.json", "summary")
    )
    lanes = sorted(range(n_lanes), key=lambda q: (q != compared_lane, -q))
    rows = []
    for lane in lanes:
        name = f"{lane_name(lane, n_lanes)} lane ({lane})"
        for rank in range(1, ranks + 1):
            paper = None
            if paired and lane == compared_lane and rank <= len(PAPER_UPSTREAM_REDUCTION_PCT):
                paper = PAPER_UPSTREAM_REDUCTION_PCT[rank - 1]
            entry = f"upstream[lane={lane}, rank={rank}]"
            rows.append(
                Measure(
                    f"{prefix}.reduction.lane{lane}.rank{rank}",
                    f"speed reduction of upstream HV #{rank}, {name}{suffix} (%)",
                    "upstream" if paired else "upstream_summary",
                    f"paired {entry} of trajectories.parquet against {BASELINE}'s"
                    if paired
                    else f"{entry}.speed_reduction_pct",
                    lambda s, b, q=lane, r=rank: get(
                        upstream_entry(s, q, r), "speed_reduction_pct"
                    ),
                    paper,
                    basis=basis,
                )
            )
    for lane in lanes:
        rows.append(
            Measure(
                f"{prefix}.influenced.lane{lane}",
                f"upstream HVs slowed > {INFLUENCE_THRESHOLD_PCT:g} %, "
                f"{lane_name(lane, n_lanes)} lane ({lane}){suffix} (count)",
                "influenced",
                f"count of {'paired ' if paired else ''}upstream[lane={lane}]"
                f".speed_reduction_pct > {INFLUENCE_THRESHOLD_PCT:g}",
                lambda s, b, q=lane: (
                    metrics.influenced_count(get(s, "upstream"), INFLUENCE_THRESHOLD_PCT).get(q)
                    if get(s, "upstream") is not None
                    else None
                ),
                PAPER_INFLUENCED if paired and lane == compared_lane else None,
                digits=0,
                basis=basis,
            )
        )
    return rows


def build_rows(
    rows: Sequence[Measure],
    summaries: Mapping[str, Mapping[str, Any] | None],
    columns: Sequence[str],
    paired: Mapping[str, Sequence[Mapping[str, Any]] | None] | None = None,
) -> list[dict[str, Any]]:
    """One dict per measure: ``measure, paper, <column>...`` plus key, source, definition.

    ``summaries`` and ``paired`` (each run's :func:`paired_upstream` entries, None where they
    could not be computed) are keyed by the report's columns (the runs).
    """
    base = summaries.get(BASELINE)
    paired = paired or {}
    out = []
    for m in rows:
        sources: dict[str, Mapping[str, Any] | None] = {}
        for c in columns:
            if m.basis == "paired":
                entries = paired.get(c)
                sources[c] = {"upstream": entries} if entries is not None else None
            else:
                sources[c] = summaries.get(c)
        row: dict[str, Any] = {"measure": m.label, "paper": m.paper}
        for c in columns:
            row[c] = finite(m.read(sources[c], base)) if sources[c] is not None else None
        row.update(
            key=m.key,
            paper_text=m.paper_text,
            definition=m.definition,
            source=m.source,
            digits=m.digits,
            basis=m.basis,
        )
        if ".reduction." in m.key:
            lane, rank = (int(x[4:]) for x in m.key.split(".")[-2:])  # "lane2", "rank1"
            row["vehicles"] = {
                c: get(upstream_entry(sources[c], lane, rank), "vehicle") for c in columns
            }
        out.append(row)
    return out


def per_lane(
    rows: Sequence[Mapping[str, Any]], prefix: str, suffix: str = ""
) -> dict[int, Mapping[str, Any]]:
    """The rows whose key is ``<prefix>lane<q><suffix>``, by lane q."""
    pattern = re.compile(rf"{re.escape(prefix)}lane(\d+){re.escape(suffix)}")
    return {int(m[1]): r for r in rows if (m := pattern.fullmatch(r["key"]))}


# --------------------------------------------------------------------------------------------
# targets


@dataclass(frozen=True)
class Target:
    """A goal for the swarm run: ``<what> <op> <threshold><unit>``, checked on a row's value
    (or the worst lane of a per-lane row family: ``rows`` = (prefix, suffix))."""

    what: str
    rows: str | tuple[str, str]  # a row key, or the (prefix, suffix) of per-lane rows
    op: str  # ">=", "<=" or "=="
    threshold: Callable[[Scenario], float]
    unit: str
    origin: str  # where the threshold comes from: the scenario's key, or why it is fixed


WALL_TARGET_S = 180.0  # the whole reproduction should take at most this long [s]
TARGETS = (
    Target(f"mobility gain over {BASELINE}", "cav.mobility_gain", ">=", lambda sc: 10.0, " %",
           "the project's goal (issue 11), not in the scenario; the paper reports "
           f"{PAPER_GAIN_PCT} %"),
    Target("minimum CAV following distance", "cav.gap_min", ">=", lambda sc: sc.cav.min_gap_m,
           " m", "scenario [cav] min_gap_m (the paper's minimum safety distance, IV-C)"),
    Target(f"upstream HVs influenced (paired, > {INFLUENCE_THRESHOLD_PCT:g} %) in every lane",
           ("upstream.influenced.", ""), "<=", lambda sc: 5, "",
           "the paper's abstract (influence within five HVs), not in the scenario"),
    Target("first following HV's speed reduction (paired) in every lane",
           ("upstream.reduction.", ".rank1"), "<=", lambda sc: 5.0, " %",
           "the project's goal, not in the scenario"),
    Target("minimum upstream time headway", "upstream.min_headway", ">=",
           lambda sc: sc.hv.headway_s, " s",
           "scenario [hv] headway_s (the paper's minimum car-following headway, IV-C)"),
    Target("collisions", "safety.collisions", "==", lambda sc: 0, "",
           "the paper's and the project's: none"),
    Target("whole reproduction wall time", "wall_s", "<=", lambda sc: WALL_TARGET_S, " s",
           "the project's goal, not in the scenario"),
)  # fmt: skip  # one target per group of lines: a table reads better so

_OPS: dict[str, Callable[[float, float], bool]] = {
    ">=": lambda v, t: v >= t,
    "<=": lambda v, t: v <= t,
    "==": lambda v, t: v == t,
}


def _worst(per_lane_values: Mapping[int, tuple[Any, str]]) -> tuple[Any, str | None]:
    """The largest value over the lanes and where it occurs (every lane that ties)."""
    known = {q: vw for q, vw in sorted(per_lane_values.items(), reverse=True) if vw[0] is not None}
    if not known:
        return None, None
    top = max(v for v, _ in known.values())
    return top, "; ".join(where for v, where in known.values() if v == top)


def targets(
    rows: Sequence[Mapping[str, Any]], scenario: Scenario, wall_s: float | None
) -> list[dict[str, Any]]:
    """Each target of :data:`TARGETS` for the swarm run: its value, where it is worst, whether
    it is met, the threshold and where the threshold comes from."""
    by_key = {r["key"]: r for r in rows}
    out = []
    for t in TARGETS:
        where = None
        if t.rows == "wall_s":
            value = wall_s
        elif isinstance(t.rows, tuple):
            family = per_lane(rows, *t.rows)
            value, where = _worst(
                {
                    q: (
                        r.get(FOCUS),
                        f"lane {q}"
                        + (f", {r['vehicles'].get(FOCUS)}" if r.get("vehicles") else ""),
                    )
                    for q, r in family.items()
                }
            )
        else:
            value = by_key.get(t.rows, {}).get(FOCUS)
        threshold = t.threshold(scenario)
        value = finite(value)
        out.append(
            {
                "target": f"{t.what} {t.op} {threshold:g}{t.unit}",
                "value": value,
                "where": where,
                "met": None if value is None else bool(_OPS[t.op](value, threshold)),
                "threshold": threshold,
                "origin": t.origin,
            }
        )
    return out


# --------------------------------------------------------------------------------------------
# measures from the trajectories


def slowest_mps(df: pd.DataFrame, window: metrics.EvaluationWindow) -> dict[str, float]:
    """Each vehicle's minimum speed inside ``window`` [m/s]."""
    inside = metrics.window(df, window)
    grouped = inside.groupby(inside["vehicle"].astype(str), observed=True)["speed_mps"]
    return {str(k): float(v) for k, v in grouped.min().items()}


def _paired(vehicle: str, reference: Mapping[str, float], own: Mapping[str, float]) -> dict:
    undisturbed, slowest = finite(reference.get(vehicle)), finite(own.get(vehicle))
    reduction = None
    if undisturbed is not None and slowest is not None:
        reduction = (
            max(0.0, (undisturbed - slowest) / undisturbed * 100.0) if undisturbed > 0 else 0.0
        )
    return {
        "vehicle": vehicle,
        "undisturbed_speed_mps": undisturbed,
        "min_speed_mps": slowest,
        "speed_reduction_pct": reduction,
    }


def paired_upstream(
    summary: Mapping[str, Any] | None,
    df: pd.DataFrame,
    baseline_df: pd.DataFrame,
    window: metrics.EvaluationWindow,
    blocked: Iterable[str] = (),
) -> list[dict[str, Any]] | None:
    """Each ranked upstream HV of a run against the same HV in the baseline run.

    For every entry of the run's ``summary["upstream"]`` (its lane, rank and vehicle):
    ``undisturbed_speed_mps`` = the HV's minimum speed in ``baseline_df`` over ``window``,
    ``min_speed_mps`` = its minimum speed in ``df`` over ``window`` [m/s], and
    ``speed_reduction_pct`` = ``max(0, (undisturbed - min) / undisturbed * 100)`` [%] (None when
    the HV is missing from either table inside the window). Also ``summary_reduction_pct``
    (the summary's own number) and ``role``: ``"blocked"`` for the vehicles in ``blocked``
    (the HVs beside the platoon at the start), else ``"upstream"``. None when the summary has
    no upstream list.
    """
    entries = get(summary, "upstream")
    if entries is None:
        return None
    reference, own = slowest_mps(baseline_df, window), slowest_mps(df, window)
    blocked = set(blocked)
    return [
        {
            "lane": int(e["lane"]),
            "rank": int(e["rank"]),
            "role": "blocked" if str(e["vehicle"]) in blocked else "upstream",
            **_paired(str(e["vehicle"]), reference, own),
            "summary_reduction_pct": e.get("speed_reduction_pct"),
        }
        for e in entries
    ]


def paired_vehicle(
    vehicle: str, df: pd.DataFrame, baseline_df: pd.DataFrame, window: metrics.EvaluationWindow
) -> dict[str, Any]:
    """One vehicle's minimum speed against its own in the baseline run, as
    :func:`paired_upstream` measures an upstream HV (used for the slow HV being overtaken)."""
    return _paired(vehicle, slowest_mps(baseline_df, window), slowest_mps(df, window))


def upstream_surge_mps(summary: Mapping[str, Any] | None, df: pd.DataFrame) -> float | None:
    """How far the fastest ranked upstream HV of a run rises above its first recorded speed
    [m/s] (0 when none speeds up); None without upstream HVs."""
    ids = {str(e["vehicle"]) for e in get(summary, "upstream") or []}
    hv = df[df["vehicle"].astype(str).isin(ids)]
    if hv.empty:
        return None
    by_vehicle = hv.sort_values("time_s").groupby(hv["vehicle"].astype(str))["speed_mps"]
    return max(0.0, float((by_vehicle.max() - by_vehicle.first()).max()))


def platoon_min_speed_mps(df: pd.DataFrame, start_s: float, end_s: float) -> float | None:
    """The lowest average speed over the CAVs between ``start_s`` and ``end_s`` [m/s]."""
    cav = df[(df["kind"].astype(str) == metrics.CAV) & df["time_s"].between(start_s, end_s)]
    if cav.empty:
        return None
    return float(cav.groupby("time_s")["speed_mps"].mean().min())
