"""``sumo-swarm reproduce``: the paper's evaluation (Section IV) regenerated headless.

The scenario runs once under every controller (same traffic, same seed), each run in its own
process (libsumo holds one simulation per process). Every run writes its outputs under
``DIR/runs/<controller>/`` as it finishes; ``DIR/report.json`` and ``DIR/report.md`` (rewritten
atomically after each run, so a finished run is never lost) hold one row per measure of the
paper's Section IV-E with the paper's value and one column per controller, then Figs. 7-12 as
PNG files in ``DIR``.

Every number of the table comes from the runs' ``summary.json`` (the output contract), either
as it stands or through a stated formula (e.g. the mobility gain over cacc), except the upstream
HVs' speed reductions and influenced counts: those pair each run with the cacc run, HV by HV,
from the runs' ``trajectories.parquet`` (:func:`paired_upstream`). The summary's own upstream
numbers, which measure against each HV's speed at the decision, stay in a secondary table.
"""

from __future__ import annotations

import importlib.resources
import json
import logging
import math
import multiprocessing
import os
import re
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from tqdm import tqdm

import sumo_swarm
from sumo_swarm import metrics
from sumo_swarm.config import Scenario, load_scenario
from sumo_swarm.controllers import CONTROLLERS
from sumo_swarm.errors import ConfigError
from sumo_swarm.runner import prepare_out_dir, run_scenario, write_json_atomic

log = logging.getLogger(__name__)

SCHEMA = "sumo-swarm/report/1"
BASELINE = "cacc"  # the paper's baseline: mobility gains are measured against it
FOCUS = "swarm"  # the paper's method: the single-run figures and the targets are about it
INFLUENCE_THRESHOLD_PCT = 0.1  # an upstream HV is "influenced" above this speed reduction [%]

# The paper's numbers (Section IV-E; Fig. 8 text for the times).
PAPER_SPEED_MPS = 19.43
PAPER_GAIN_PCT = 12.04
PAPER_CACC_SPEED_MPS = PAPER_SPEED_MPS / (1 + PAPER_GAIN_PCT / 100)  # 17.34 m/s
PAPER_GAP_MEAN_M = 16.80
PAPER_GAP_EXCESS_PCT = 68.0  # 16.80 m against the 10 m desired distance
PAPER_UPSTREAM_REDUCTION_PCT = (2.19, 1.51, 0.92, 0.42)  # 1st..4th following HV
PAPER_UPSTREAM_GAP_M = 23.87
PAPER_UPSTREAM_HEADWAY_S = 1.4
PAPER_INFLUENCED = 4  # "limits its influence on traffic within four following HVs"
PAPER_BEHAVING_STEPS = 14
PAPER_PASS_S = 27.0  # "from time 9 s to 27 s all following CAVs cut through"
PAPER_REGROUP_S = 42.0  # "from time 27 s to 42 s, CAVs reform into a platoon"

WALL_TARGET_S = 180.0  # the whole reproduction should take at most this long [s]

# sumo_swarm.plots (matplotlib) is imported inside the functions that draw or name things: the
# worker processes import this module to run a simulation and need none of it.


# --------------------------------------------------------------------------------------------
# scenario


def default_scenario_path() -> Path:
    """``scenarios/paper.toml`` of a source checkout, else the copy shipped in the package."""
    repo = Path(sumo_swarm.__file__).resolve().parent.parent / "scenarios" / "paper.toml"
    if repo.is_file():
        return repo
    shipped = Path(str(importlib.resources.files("sumo_swarm") / "data" / "paper.toml"))
    if not shipped.is_file():
        raise ConfigError(
            f"the paper scenario is neither at {repo} nor at {shipped}; give --scenario FILE"
        )
    return shipped


# --------------------------------------------------------------------------------------------
# running


@dataclass
class RunResult:
    """How one controller's run went (the numbers are in its summary.json)."""

    controller: str
    status: str  # "pending", "ok" or "failed"
    folder: Path
    error: str | None = None
    wall_s: float | None = None

    def as_json(self, out_dir: Path) -> dict[str, Any]:
        return {
            "status": self.status,
            "error": self.error,
            "dir": self.folder.relative_to(out_dir).as_posix(),
            "wall_s": self.wall_s,
        }


def _run_one(scenario: Scenario, controller: str, folder: str) -> tuple[str, float]:
    """Worker: one run in a fresh process. Returns (error or "", wall seconds)."""
    t0 = time.perf_counter()
    try:
        run_scenario(scenario, controller, folder, progress=False)
    except Exception as exc:  # reported in the report; the other runs go on
        return f"{type(exc).__name__}: {exc}", time.perf_counter() - t0
    return "", time.perf_counter() - t0


def _run_all(
    scenario: Scenario,
    results: dict[str, RunResult],
    workers: int,
    on_done: Callable[[RunResult], None],
    progress: bool,
) -> None:
    """Run every pending controller, ``workers`` processes at a time, one run per process.

    A worker that dies (a crash inside SUMO) breaks the pool and every run then in it; those
    runs are tried once more, each alone in its own pool, so one crash costs only its own run.
    """
    context = multiprocessing.get_context("spawn")
    bar = tqdm(total=len(results), desc="reproduce", unit="run", disable=not progress)

    def finish(res: RunResult, error: str, wall_s: float | None) -> None:
        res.status = "failed" if error else "ok"
        res.error = error or None
        res.wall_s = wall_s
        bar.update()
        bar.set_postfix_str(f"{res.controller} {res.status}")
        on_done(res)

    def run_batch(batch: Sequence[RunResult], n_workers: int) -> list[RunResult]:
        crashed: list[RunResult] = []
        with ProcessPoolExecutor(n_workers, mp_context=context, max_tasks_per_child=1) as pool:
            futures: dict[Future, RunResult] = {
                pool.submit(_run_one, scenario, r.controller, str(r.folder)): r for r in batch
            }
            pending = set(futures)
            while pending:
                done, pending = wait(pending, return_when=FIRST_COMPLETED)
                for fut in done:
                    res = futures[fut]
                    try:
                        error, wall = fut.result()
                    except BrokenProcessPool:
                        crashed.append(res)
                        continue
                    except Exception as exc:  # e.g. the scenario could not be sent
                        error, wall = f"{type(exc).__name__}: {exc}", None
                    finish(res, error, wall)
        return crashed

    try:
        todo = [r for r in results.values() if r.status == "pending"]
        crashed = run_batch(todo, min(workers, len(todo))) if todo else []
        for res in crashed:
            if run_batch([res], 1):
                finish(res, "the worker process died (a crash inside SUMO?)", None)
    finally:
        bar.close()


# --------------------------------------------------------------------------------------------
# measures


def _get(summary: Mapping[str, Any] | None, *keys: str) -> Any:
    value: Any = summary
    for key in keys:
        if not isinstance(value, Mapping):
            return None
        value = value.get(key)
    return value


def upstream_entry(summary: Mapping[str, Any] | None, lane: int, rank: int) -> dict | None:
    for entry in _get(summary, "upstream") or []:
        if entry["lane"] == lane and entry["rank"] == rank:
            return entry
    return None


def _min_of(summary: Mapping[str, Any] | None, key: str) -> float | None:
    values = [e[key] for e in _get(summary, "upstream") or [] if e.get(key) is not None]
    return min(values) if values else None


def _minus(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else a - b


def _gain_pct(value: float | None, base: float | None) -> float | None:
    if value is None or base is None or base <= 0:
        return None
    return (value / base - 1.0) * 100.0


@dataclass(frozen=True)
class Measure:
    """One row of the report: how to read a controller's number from its summary.

    ``basis="paired"`` rows read the same way from ``{"upstream": <the run's paired upstream
    entries>}`` (see :func:`paired_upstream`) instead of from summary.json.
    """

    key: str
    label: str  # with the unit, e.g. "platoon average speed (m/s)"
    definition: str  # key into the report's definitions
    source: str  # where in summary.json the number comes from (or the formula over it)
    value: Callable[[Mapping[str, Any] | None, Mapping[str, Any] | None], Any]
    paper: float | int | bool | None = None
    paper_text: str | None = None  # what the paper says when it gives no single number
    digits: int = 2
    basis: str = "summary"  # "summary" or "paired"


def measures(scenario: Scenario, n_lanes: int, compared_lane: int) -> list[Measure]:
    """The rows of the report, in the order of the paper's Section IV-E."""
    desired = scenario.cav.desired_gap_m
    rows = [
        Measure("cav.mean_speed", "platoon average speed (m/s)", "speed",
                "cav.mean_speed_mps", lambda s, b: _get(s, "cav", "mean_speed_mps"),
                PAPER_SPEED_MPS,
                f"{PAPER_SPEED_MPS:.2f} (cacc {PAPER_CACC_SPEED_MPS:.2f})"),
        Measure("cav.mobility_gain", f"mobility gain over {BASELINE} (%)", "gain",
                f"(cav.mean_speed_mps / {BASELINE}'s - 1) * 100",
                lambda s, b: _gain_pct(_get(s, "cav", "mean_speed_mps"),
                                       _get(b, "cav", "mean_speed_mps")),
                PAPER_GAIN_PCT),
        Measure("cav.min_speed", "minimum CAV speed (m/s)", "speed", "cav.min_speed_mps",
                lambda s, b: _get(s, "cav", "min_speed_mps"), paper_text="Fig. 9 only"),
        Measure("cav.max_speed", "maximum CAV speed (m/s)", "speed", "cav.max_speed_mps",
                lambda s, b: _get(s, "cav", "max_speed_mps"), paper_text="Fig. 9 only"),
        Measure("cav.speed_var", "variance of CAV speed (m²/s²)", "speed",
                "cav.speed_var_m2ps2", lambda s, b: _get(s, "cav", "speed_var_m2ps2"),
                paper_text="Fig. 9 only", digits=3),
        Measure("cav.travel_time",
                f"travel time over {scenario.evaluation.travel_distance_m:g} m (s)",
                "travel_time", "cav.travel_time_s",
                lambda s, b: _get(s, "cav", "travel_time_s"), paper_text="not given"),
        Measure("cav.gap_mean", "mean CAV following distance (m)", "gap", "cav.gap_mean_m",
                lambda s, b: _get(s, "cav", "gap_mean_m"), PAPER_GAP_MEAN_M),
        Measure("cav.gap_min", "minimum CAV following distance (m)", "gap", "cav.gap_min_m",
                lambda s, b: _get(s, "cav", "gap_min_m"),
                paper_text=f"> {scenario.cav.min_gap_m:g}"),
        Measure("cav.gap_excess", f"mean following distance above the desired {desired:g} m (%)",
                "gap", f"(cav.gap_mean_m / {desired:g} - 1) * 100",
                lambda s, b: _gain_pct(_get(s, "cav", "gap_mean_m"), desired),
                PAPER_GAP_EXCESS_PCT, digits=1),
    ]  # fmt: skip
    rows += upstream_measures(scenario, n_lanes, compared_lane, paired=True)
    rows += [
        Measure("upstream.min_gap", "minimum upstream following distance (m)", "upstream_gap",
                "min of upstream[].min_gap_m", lambda s, b: _min_of(s, "min_gap_m"),
                PAPER_UPSTREAM_GAP_M),
        Measure("upstream.min_headway", "minimum upstream time headway (s)", "upstream_gap",
                "min of upstream[].min_headway_s", lambda s, b: _min_of(s, "min_headway_s"),
                PAPER_UPSTREAM_HEADWAY_S),
        Measure("overtake.completed", "overtake completed (all CAVs past the slow HV)",
                "overtake", "overtake.completed",
                lambda s, b: _get(s, "overtake", "completed"), True),
        Measure("overtake.regrouped", "regrouped into one platoon", "overtake",
                "overtake.regrouped", lambda s, b: _get(s, "overtake", "regrouped"), True),
        Measure("overtake.behaving_steps", "overtake duration (behaving steps)", "overtake",
                "overtake.behaving_steps", lambda s, b: _get(s, "overtake", "behaving_steps"),
                PAPER_BEHAVING_STEPS, digits=0),
        Measure("overtake.pass_s", "decision to all CAVs past the slow HV (s)", "overtake",
                "overtake.t_end_s - overtake.t_start_s",
                lambda s, b: _minus(_get(s, "overtake", "t_end_s"),
                                    _get(s, "overtake", "t_start_s")),
                PAPER_PASS_S, digits=1),
        Measure("overtake.duration_s", "overtake duration, decision to regrouped (s)",
                "overtake", "overtake.t_regrouped_s - overtake.t_start_s",
                lambda s, b: _minus(_get(s, "overtake", "t_regrouped_s"),
                                    _get(s, "overtake", "t_start_s")),
                PAPER_REGROUP_S, digits=1),
        Measure("safety.collisions", "collisions (count)", "safety", "safety.collisions",
                lambda s, b: _get(s, "safety", "collisions"), 0, digits=0),
        Measure("safety.hard_brakes", "vehicles braking harder than 4 m/s² (count)", "safety",
                "safety.hard_brakes", lambda s, b: _get(s, "safety", "hard_brakes"), 0,
                digits=0),
        Measure("safety.teleports", "teleports (count)", "safety", "safety.teleports",
                lambda s, b: _get(s, "safety", "teleports"), paper_text="n/a (MATLAB)",
                digits=0),
    ]  # fmt: skip
    return rows


def upstream_measures(
    scenario: Scenario, n_lanes: int, compared_lane: int, *, paired: bool
) -> list[Measure]:
    """Speed reduction per lane and rank, then the influenced count per lane.

    ``paired=True``: the report's rows, each upstream HV against itself in the cacc run, with
    the paper's numbers; ``paired=False``: the same rows as summary.json measures them (the
    secondary table, no paper column: the paper's numbers are compared with the paired rows).
    """
    from sumo_swarm.plots import lane_name

    ranks = scenario.evaluation.upstream_ranks
    prefix, suffix, basis = ("upstream", "", "paired") if paired else (
        "upstream.summary", ", summary.json", "summary")  # fmt: skip
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
                    if paired else f"{entry}.speed_reduction_pct",
                    lambda s, b, q=lane, r=rank: _get(upstream_entry(s, q, r),
                                                      "speed_reduction_pct"),
                    paper, basis=basis,
                )
            )  # fmt: skip
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
                    metrics.influenced_count(_get(s, "upstream"), INFLUENCE_THRESHOLD_PCT).get(q)
                    if _get(s, "upstream") is not None else None
                ),
                PAPER_INFLUENCED if paired and lane == compared_lane else None, digits=0,
                basis=basis,
            )
        )  # fmt: skip
    return rows


def definitions(
    scenario: Scenario, compared_lane: int, n_lanes: int, paired_from_s: float | None = None
) -> dict[str, str]:
    """Each measure's definition, stated once (rows point to these by key).

    ``paired_from_s``: where the paired upstream window starts (the swarm run's decision) [s],
    once known.
    """
    from sumo_swarm.plots import lane_name
    from sumo_swarm.scene import build_scene

    ev = scenario.evaluation
    interval = scenario.planner.behaving_interval_s
    blocked = sorted(((v.lane, v.id) for v in build_scene(scenario).vehicles
                      if v.role == "adjacent"), reverse=True)  # fmt: skip
    blocked_text = " and ".join(f"{vid} in lane {lane}" for lane, vid in blocked) or "none"
    platoon_lane = scenario.scene.platoon_lane
    since = "the swarm run's overtaking decision" + (
        f" (t = {paired_from_s:g} s)" if paired_from_s is not None else "")  # fmt: skip
    return {
        "speed": (
            f"Platoon average speed = mean of every CAV speed sample (all {scenario.cav.count} "
            f"CAVs, every SUMO step of {scenario.simulation.step_length_s:g} s) in the "
            f"evaluation window {ev.start_s:g}-{ev.end_s:g} s; minimum and maximum = the "
            "extreme samples; variance = population variance of the same samples."
        ),
        "gain": (
            f"Mobility gain = (platoon average speed / the {BASELINE} run's platoon average "
            "speed - 1) x 100 %, same traffic and seed. The paper's CACC speed is "
            f"{PAPER_SPEED_MPS} / {1 + PAPER_GAIN_PCT / 100:.4f} = {PAPER_CACC_SPEED_MPS:.2f} m/s."
        ),
        "travel_time": (
            "Travel time = mean over the CAVs of the time from the CAV's first sample in the "
            f"window until its front bumper has advanced {ev.travel_distance_m:g} m; empty when "
            "a CAV does not get that far inside the window."
        ),
        "gap": (
            "CAV following distance = bumper-to-bumper gap from a CAV to the vehicle (CAV or HV) "
            "right ahead of it in the lane SUMO reports it on, every step of the window; mean "
            "and minimum over all CAVs and steps. Excess over the desired distance = (mean / "
            f"{scenario.cav.desired_gap_m:g} m - 1) x 100 % (the paper: 16.80 m vs 10 m = 68 %)."
        ),
        "upstream": (
            "Upstream HVs = the HVs whose front bumper is behind the front bumper of the "
            "swarm's leading CAV at the overtaking decision (t_start; at the window start for a "
            "controller that never decides), the slow HV being overtaken left out, ranked per "
            f"lane nearest first, at most {ev.upstream_ranks} per lane (summary.json's "
            "ranking). #1, the first following HV, is thus the HV the swarm blocks beside the "
            f"platoon in a side lane ({blocked_text}) and the first HV behind the platoon in "
            f"the platoon's lane (lane {platoon_lane}). Speed reduction, paired with the "
            f"{BASELINE} run = max(0, (v_{BASELINE} - v_run) / v_{BASELINE} x 100) %, where "
            f"v_run is the HV's minimum speed in this run and v_{BASELINE} the same HV's "
            f"minimum speed in the {BASELINE} run (same traffic and seed, no manoeuvre), both "
            f"from {since} to the window end ({ev.end_s:g} s), for every controller, so the "
            f"columns compare; the {BASELINE} column is 0 by construction. Computed from the "
            "runs' trajectories.parquet (summary.json does not hold it). The paper's four "
            f"numbers are compared with the {lane_name(compared_lane, n_lanes)} lane (lane "
            f"{compared_lane}), the lane of its Fig. 11, where a CAV blocks an HV to open the "
            "cut-through gap."
        ),
        "upstream_summary": (
            "summary.json's own upstream speed reduction (secondary table), for the same "
            "ranked HVs = max(0, (v_ref - v_min) / v_ref x 100) %, where v_ref is the HV's "
            "speed at the run's reference time (the decision, or the window start for a "
            "controller that never decides) and v_min its minimum speed from then to the "
            "window end. The upstream HVs start 25 m apart at the initial speed, which is not "
            "an IDM equilibrium: in every run they first speed up a little and settle back, "
            "and a speed taken during that surge adds its overshoot to every reduction of a run "
            "that decides; a run that never decides is measured from the start, before the "
            "surge."
        ),
        "influenced": (
            f"Influenced upstream HVs = how many of the ranked upstream HVs of a lane (at most "
            f"{ev.upstream_ranks}) have a speed reduction above {INFLUENCE_THRESHOLD_PCT:g} % "
            "(the paired reduction in the main table, summary.json's in the secondary one). "
            "The paper: within four following HVs (Section IV-E), five (abstract)."
        ),
        "upstream_gap": (
            "Minimum upstream following distance / time headway = the smallest bumper-to-bumper "
            "gap / gap divided by the HV's own speed, over the ranked upstream HVs of every lane "
            "and every step from the decision to the window end."
        ),
        "overtake": (
            "Overtake: t_start = the overtaking decision; all CAVs past = from when on every "
            "CAV's rear bumper stays ahead of the slow HV's front bumper (t_end); regrouped = "
            "from when on the CAVs also stay one platoon in one lane (t_regrouped). Behaving "
            f"steps = ceil((end of the manoeuvre - t_start) / {interval:g} s), the end being "
            "when the swarm controller hands back to cruising. The paper plans 14 behaving "
            "steps of 3 s (42 s: decision at 0 s, cut-through done at 27 s, platoon at 42 s)."
        ),
        "safety": (
            "Collisions = pairs of vehicles SUMO reports physically overlapping; hard brakes = "
            "vehicles of any kind that ever decelerated harder than 4 m/s²; teleports = "
            "vehicles SUMO removed and reinserted (switched off: must stay 0)."
        ),
    }


# --------------------------------------------------------------------------------------------
# the report


def _finite(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, np.generic):
        return _finite(value.item())
    return value


def build_rows(
    rows: Sequence[Measure],
    summaries: Mapping[str, Mapping[str, Any] | None],
    controllers: Sequence[str],
    paired: Mapping[str, Sequence[Mapping[str, Any]] | None] | None = None,
) -> list[dict[str, Any]]:
    """One dict per measure: ``measure, paper, <controller>...`` plus key, source, definition.

    ``paired`` holds each controller's :func:`paired_upstream` entries (None where they could
    not be computed), read by the rows of ``basis="paired"``.
    """
    base = summaries.get(BASELINE)
    paired = paired or {}
    out = []
    for m in rows:
        sources: dict[str, Mapping[str, Any] | None] = {}
        for c in controllers:
            if m.basis == "paired":
                entries = paired.get(c)
                sources[c] = {"upstream": entries} if entries is not None else None
            else:
                sources[c] = summaries.get(c)
        row: dict[str, Any] = {"measure": m.label, "paper": m.paper}
        for c in controllers:
            s = sources[c]
            row[c] = _finite(m.value(s, base)) if s is not None else None
        row.update(key=m.key, paper_text=m.paper_text, definition=m.definition,
                   source=m.source, digits=m.digits, basis=m.basis)  # fmt: skip
        if ".reduction." in m.key:
            lane, rank = _lane_rank(m.key)
            row["vehicles"] = {
                c: _get(upstream_entry(sources[c], lane, rank), "vehicle") for c in controllers
            }
        out.append(row)
    return out


def _lane_rank(key: str) -> tuple[int, int]:
    lane_part, rank_part = key.split(".")[-2:]
    return int(lane_part.removeprefix("lane")), int(rank_part.removeprefix("rank"))


def _per_lane(
    rows: Sequence[Mapping[str, Any]], prefix: str, suffix: str = ""
) -> dict[int, Mapping[str, Any]]:
    """The rows whose key is ``<prefix>lane<q><suffix>``, by lane q."""
    pattern = re.compile(rf"{re.escape(prefix)}lane(\d+){re.escape(suffix)}")
    return {int(m[1]): r for r in rows if (m := pattern.fullmatch(r["key"]))}


def _worst(per_lane: Mapping[int, tuple[Any, str]]) -> tuple[Any, str | None]:
    """The largest value over the lanes and where it occurs (every lane that ties)."""
    known = {q: vw for q, vw in sorted(per_lane.items(), reverse=True) if vw[0] is not None}
    if not known:
        return None, None
    top = max(v for v, _ in known.values())
    return top, "; ".join(where for v, where in known.values() if v == top)


def targets(rows: Sequence[Mapping[str, Any]], wall_s: float | None) -> list[dict[str, Any]]:
    """The issue's targets for the swarm, each with its value, where it is worst, and whether
    it is met. The upstream targets read the report's (paired) upstream rows."""
    by_key = {r["key"]: r for r in rows}

    def value(key: str) -> Any:
        return by_key[key][FOCUS] if key in by_key and FOCUS in by_key[key] else None

    influenced = _worst(
        {q: (r.get(FOCUS), f"lane {q}") for q, r in _per_lane(rows, "upstream.influenced.").items()}
    )
    first = _worst(
        {
            q: (r.get(FOCUS), f"lane {q}, {r['vehicles'].get(FOCUS)}")
            for q, r in _per_lane(rows, "upstream.reduction.", ".rank1").items()
        }
    )
    checks = [
        ("mobility gain over cacc >= 10 %", (value("cav.mobility_gain"), None),
         lambda v: v >= 10.0),
        ("minimum CAV following distance >= 5 m", (value("cav.gap_min"), None),
         lambda v: v >= 5.0),
        (f"upstream HVs influenced (paired, > {INFLUENCE_THRESHOLD_PCT:g} %) <= 5 in every "
         "lane", influenced, lambda v: v <= 5),
        ("first following HV's speed reduction (paired) <= 5 % in every lane", first,
         lambda v: v <= 5.0),
        ("minimum upstream time headway >= 1.2 s", (value("upstream.min_headway"), None),
         lambda v: v >= 1.2),
        ("zero collisions", (value("safety.collisions"), None), lambda v: v == 0),
        (f"whole reproduction within {WALL_TARGET_S:g} s", (wall_s, None),
         lambda v: v <= WALL_TARGET_S),
    ]  # fmt: skip
    return [
        {"target": text, "value": _finite(v), "where": where,
         "met": None if v is None else bool(ok(v))}
        for text, (v, where), ok in checks
    ]  # fmt: skip


def _slowest_mps(df: pd.DataFrame, window: metrics.EvaluationWindow) -> dict[str, float]:
    """Each vehicle's minimum speed inside ``window`` [m/s]."""
    inside = metrics.window(df, window)
    grouped = inside.groupby(inside["vehicle"].astype(str), observed=True)["speed_mps"]
    return {str(k): float(v) for k, v in grouped.min().items()}


def _paired(vehicle: str, reference: Mapping[str, float], own: Mapping[str, float]) -> dict:
    undisturbed, slowest = _finite(reference.get(vehicle)), _finite(own.get(vehicle))
    reduction = None
    if undisturbed is not None and slowest is not None:
        reduction = (
            max(0.0, (undisturbed - slowest) / undisturbed * 100.0) if undisturbed > 0 else 0.0
        )
    return {"vehicle": vehicle, "undisturbed_speed_mps": undisturbed,
            "min_speed_mps": slowest, "speed_reduction_pct": reduction}  # fmt: skip


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
    entries = _get(summary, "upstream")
    if entries is None:
        return None
    reference, own = _slowest_mps(baseline_df, window), _slowest_mps(df, window)
    blocked = set(blocked)
    rows = []
    for e in entries:
        vid = str(e["vehicle"])
        rows.append({
            "lane": int(e["lane"]), "rank": int(e["rank"]),
            "role": "blocked" if vid in blocked else "upstream",
            **_paired(vid, reference, own),
            "summary_reduction_pct": e.get("speed_reduction_pct"),
        })  # fmt: skip
    return rows


def paired_vehicle(
    vehicle: str, df: pd.DataFrame, baseline_df: pd.DataFrame, window: metrics.EvaluationWindow
) -> dict[str, Any]:
    """One vehicle's minimum speed against its own in the baseline run, as
    :func:`paired_upstream` measures an upstream HV (used for the slow HV being overtaken)."""
    return _paired(vehicle, _slowest_mps(baseline_df, window), _slowest_mps(df, window))


def _fmt(value: Any, digits: int = 2) -> str:
    if value is None:
        return "—"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if abs(value) < 0.5 * 10.0**-digits:
            value = 0.0  # no "-0.00"
        return f"{value:.{digits}f}" if digits > 0 else f"{value:.0f}"
    return str(value)


def _paper_cell(row: Mapping[str, Any]) -> str:
    if row.get("paper_text"):
        return str(row["paper_text"])
    if row.get("paper") is None:
        return "—"
    return _fmt(row["paper"], row["digits"])


def differences(report: Mapping[str, Any]) -> list[str]:
    """Markdown paragraphs comparing the swarm's numbers with the paper's, from the report."""
    rows = {r["key"]: r for r in report["rows"]}
    lines: list[str] = []
    if report["runs"].get(FOCUS, {}).get("status") != "ok":
        return [f"The {FOCUS} run did not finish, so there is nothing to compare."]

    def v(key: str, c: str = FOCUS) -> Any:
        return rows[key].get(c) if key in rows else None

    compared = []
    for r in report["rows"]:
        ours = r.get(FOCUS)
        paper = r.get("paper")
        if isinstance(paper, bool) or paper is None or ours is None or isinstance(ours, bool):
            continue
        d = r["digits"]
        rel = f", {(ours / paper - 1) * 100:+.0f} %" if paper not in (0, 0.0) else ""
        compared.append(f"| {r['measure']} | {_fmt(paper, d)} | {_fmt(ours, d)} | "
                        f"{_fmt(ours - paper, d)}{rel} |")  # fmt: skip
    lines.append("Every measure the paper gives as a number, against ours (swarm run):\n")
    lines.append("| measure | paper | ours | ours - paper |\n| --- | --- | --- | --- |")
    lines.append("\n".join(compared) + "\n")

    speed, base, gain = v("cav.mean_speed"), v("cav.mean_speed", BASELINE), v("cav.mobility_gain")
    if None not in (speed, base, gain):
        lines.append(
            f"* **Mobility.** Our {BASELINE} platoon drives at {base:.2f} m/s (the paper's "
            f"{PAPER_CACC_SPEED_MPS:.2f} m/s): it sits behind the slow HV, whose speed is "
            f"{report['scenario_info']['initial_speed_mps']:g} m/s in both. The swarm averages "
            f"{speed:.2f} m/s, a gain of {gain:.2f} % against the paper's {PAPER_GAIN_PCT} %. "
            "The gain depends on the averaging window, which the paper does not state: ours is "
            f"{report['scenario_info']['window']}, and it includes the cruise at "
            f"{report['scenario_info']['cruising_speed_mps']:g} m/s after the regroup."
        )
    gm, gmin = v("cav.gap_mean"), v("cav.gap_min")
    if gm is not None and gmin is not None:
        lines.append(
            f"* **Safety.** Mean CAV following distance {gm:.2f} m (paper "
            f"{PAPER_GAP_MEAN_M:.2f} m), minimum {gmin:.2f} m (paper: above 5 m). The mean "
            "mixes the desired distance the CAVs keep while following in one lane with the "
            "larger gaps while they are spread over the grid's cells (whole cells of "
            f"{report['scenario_info']['cell_length_m']:g} m minus a car length); how long each "
            "lasts inside the window sets the mean."
        )
    steps, dur, pas = v("overtake.behaving_steps"), v("overtake.duration_s"), v("overtake.pass_s")
    if steps is not None and dur is not None:
        lines.append(
            f"* **Overtake.** {steps} behaving steps and {dur:.1f} s from the decision to the "
            f"regrouped platoon ({pas:.1f} s until every CAV is past the slow HV) against the "
            f"paper's {PAPER_BEHAVING_STEPS} steps, {PAPER_REGROUP_S:g} s and "
            f"{PAPER_PASS_S:g} s. Our cells are 15 m long instead of 5 m, so one behaving step "
            "moves a CAV three times as far relative to the slow HV."
        )
    lines += _upstream_differences(report)
    lines.append(
        "\nWhy our numbers differ (the fixed list):\n\n"
        "1. **Simulator.** SUMO (libsumo, step 0.03 s) instead of the authors' MATLAB platform; "
        "the HVs follow SUMO's IDM implementation with Treiber et al.'s (2000) parameters and "
        "T = 1.2 s (the paper cites [27] without values), and keep their lanes.\n"
        "2. **Cell length 15 m, not 5 m.** Section II-B-1 defines a cell as the CAV length plus "
        "the safety distance (5 + 10 m); Section IV-C lists 5 m, which would put CAVs of "
        "adjacent rows bumper to bumper. Longer cells mean fewer rows and coarser moves, so "
        "behaving steps and the gaps while swarming differ.\n"
        "3. **Sublane model, not a bicycle model.** SUMO moves the CAVs laterally through its "
        "sublane model (0.5 m resolution, lateral speed capped at 2 m/s); the paper tracks a "
        "front-wheel angle. A CAV between two lanes counts in the lane SUMO reports it on, for "
        "gaps and for the upstream ranking.\n"
        "4. **The scene's geometry.** The paper gives the speeds and the 25 m upstream spacing "
        "but not where the slow, left-rear and right-rear HVs are; ours are in "
        "scenarios/paper.toml. Our upstream HVs start 25 m apart at 17.5 m/s, which is not an "
        "IDM equilibrium with these parameters, so they surge slightly in every run.\n"
        "5. **Measurement windows.** The paper does not say over which time its averages run; "
        "ours are over the evaluation window, the upstream measures from the decision on.\n"
        "6. **Regrouping.** Our swarm finishes its plan inside the grid, which moves at the "
        "slow HV's speed: once past, the CAVs slow down to that speed to take their regroup "
        "cells and accelerate to the cruising speed only when the controller hands back to "
        "cruising (Fig. 9). The paper's speed profile (its Fig. 9) is not given numerically."
    )
    return lines


def _upstream_differences(report: Mapping[str, Any]) -> list[str]:
    """The upstream paragraph of "where we differ": the paired numbers of the swarm run."""
    rows = report["rows"]
    lane = report["compared_lane"]
    reduction = _per_lane(rows, "upstream.reduction.", ".rank1")
    if not reduction or all(r.get(FOCUS) is None for r in reduction.values()):
        return []
    by_key = {r["key"]: r for r in rows}
    summary_rows = {r["key"]: r for r in report.get("upstream_summary_rows", [])}
    n_paper = len(PAPER_UPSTREAM_REDUCTION_PCT)
    ranked = [by_key.get(f"upstream.reduction.lane{lane}.rank{k}") for k in range(1, n_paper + 1)]
    ranked = [r for r in ranked if r is not None and r.get(FOCUS) is not None]
    window = report.get("upstream_window_s") or [None, None]

    def named(r: Mapping[str, Any]) -> str:
        return f"{r['vehicles'][FOCUS]} {_fmt(r[FOCUS])} %"

    paper = ", ".join(f"{x:.2f}" for x in PAPER_UPSTREAM_REDUCTION_PCT)
    text = (
        f"* **Upstream traffic.** Against the same HVs in the {BASELINE} run (from the decision, "
        f"t = {_fmt(window[0])} s, to {_fmt(window[1], 0)} s), the 1st-{len(ranked)}th "
        f"following HVs of lane {lane} (the paper's Fig. 11 lane) slow down by "
        + ", ".join(named(r) for r in ranked)
        + f" (paper {paper} %). "
    )
    blocked = {
        e["vehicle"] for e in (report.get("upstream_paired") or {}).get(FOCUS) or []
        if e["role"] == "blocked"
    }  # fmt: skip
    firsts = [
        f"lane {q}: {r['vehicles'][FOCUS]}"
        + (" (blocked beside the platoon)" if r["vehicles"][FOCUS] in blocked else "")
        + f" {_fmt(r[FOCUS])} %"
        for q, r in sorted(reduction.items(), reverse=True)
        if r.get(FOCUS) is not None
    ]
    text += "The first following HV of each lane: " + "; ".join(firsts) + ". "
    influenced = _per_lane(rows, "upstream.influenced.")
    text += (
        f"HVs slowed by more than {INFLUENCE_THRESHOLD_PCT:g} %: "
        + ", ".join(f"{_fmt(r.get(FOCUS), 0)} in lane {q}"
                    for q, r in sorted(influenced.items(), reverse=True))
        + f" (paper: {PAPER_INFLUENCED}). "
    )  # fmt: skip
    target = (report.get("overtaken_paired") or {}).get(FOCUS)
    if target and target.get("speed_reduction_pct") is not None:
        text += (
            f"The slow HV itself ({target['vehicle']}, left out of the ranking) drops to "
            f"{_fmt(target['min_speed_mps'])} m/s, {_fmt(target['speed_reduction_pct'])} % "
            "below its speed in the cacc run, as the platoon merges back in front of it; the "
            "HVs behind it in its lane follow it down. "
        )
    old = [summary_rows.get(f"upstream.summary.reduction.lane{lane}.rank{k}")
           for k in range(1, len(ranked) + 1)]  # fmt: skip
    if old and all(r is not None and r.get(FOCUS) is not None for r in old):
        text += (
            "summary.json's own reductions of the same HVs (secondary table) are "
            + ", ".join(_fmt(r[FOCUS]) for r in old)
            + " %: measured against each HV's speed at the decision, they include the "
            "settling of the upstream HVs' start-up surge, which happens in the cacc run too."
        )
    return [text]


def render_markdown(report: Mapping[str, Any]) -> str:
    from sumo_swarm.plots import FIGURES

    controllers = report["controllers"]
    info = report["scenario_info"]
    out = [
        "# Reproduction of the paper's evaluation (Section IV)",
        "",
        f"Scenario `{report['scenario']}` ({report['scenario_file']}), seed {report['seed']}, "
        f"evaluation window {info['window']}; generated {report['created_utc']} by "
        f"`sumo-swarm reproduce` in {_fmt(report['wall_s'], 1)} s.",
        "",
        "## Runs",
        "",
        "| controller | status | wall (s) | outputs | error |",
        "| --- | --- | --- | --- | --- |",
    ]
    for c in controllers:
        r = report["runs"][c]
        out.append(f"| {c} | {r['status']} | {_fmt(r['wall_s'], 1)} | [{r['dir']}]({r['dir']}/) "
                   f"| {r['error'] or ''} |")  # fmt: skip

    def table(rows: Sequence[Mapping[str, Any]]) -> list[str]:
        lines = ["| measure | paper | " + " | ".join(controllers) + " |",
                 "| --- | --- |" + " --- |" * len(controllers)]  # fmt: skip
        for row in rows:
            if not _ranks_an_hv(row, controllers):
                continue
            cells = [_fmt(row[c], row["digits"]) for c in controllers]
            lines.append(f"| {row['measure']} | {_paper_cell(row)} | " + " | ".join(cells) + " |")
        return lines

    window = report.get("upstream_window_s") or [None, None]
    out += ["", "## Measures (Section IV-E)", ""]
    out += [
        "The upstream HVs' speed reductions pair each run with the cacc run, HV by HV, from "
        f"the swarm's decision (t = {_fmt(window[0])} s) to {_fmt(window[1], 0)} s (definitions "
        "below); every other number is read from the runs' summary.json. Upstream ranks no run "
        "has an HV for are left out here (report.json has every rank).",
        "",
    ]
    out += table(report["rows"])
    out += ["", "The upstream HV each rank refers to, per controller (both tables):", ""]
    out.append("| measure | " + " | ".join(controllers) + " |")
    out.append("| --- |" + " --- |" * len(controllers))
    for row in report["rows"]:
        if "vehicles" not in row or not _ranks_an_hv(row, controllers):
            continue
        label = row["measure"].removeprefix("speed reduction of ").removesuffix(" (%)")
        out.append(f"| {label} | " + " | ".join(row["vehicles"][c] or "—" for c in controllers)
                   + " |")  # fmt: skip
    out += ["", "### Upstream HVs as summary.json measures them (secondary)", ""]
    out += [
        "The same HVs, each reduction against the HV's own speed at the run's reference time "
        "(summary.json's `upstream[].speed_reduction_pct`, definition below). Not the report's "
        "measure: the upstream HVs' start-up surge inflates it for the runs that decide.",
        "",
    ]
    out += table(report.get("upstream_summary_rows", []))
    out += ["", "### Definitions", ""]
    for text in report["definitions"].values():
        out.append(f"* {text}")
    out += ["", "### Targets (swarm)", "", "| target | value | where | met |",
            "| --- | --- | --- | --- |"]  # fmt: skip
    for t in report["targets"]:
        met = "—" if t["met"] is None else ("yes" if t["met"] else "**no**")
        out.append(f"| {t['target']} | {_fmt(t['value'])} | {t.get('where') or ''} | {met} |")
    out += ["", "## Figures", ""]
    for name, caption in FIGURES.items():
        if name in report["figures"]:
            out += [f"### {caption}", "", f"![{caption}]({report['figures'][name]})", ""]
        elif name in report["figure_errors"]:
            out += [f"### {caption}", "", f"Not drawn: {report['figure_errors'][name]}", ""]
    if not report["complete"]:
        out += ["*Figures are drawn once every run has finished.*", ""]
    out += ["## Where we differ from the paper and why", ""]
    out += report["differences"]
    return "\n".join(out) + "\n"


def _ranks_an_hv(row: Mapping[str, Any], controllers: Sequence[str]) -> bool:
    """False for an upstream reduction row whose rank holds no HV in any run."""
    vehicles = row.get("vehicles")
    return vehicles is None or any(vehicles.get(c) for c in controllers)


def _write_text_atomic(path: Path, text: str) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    os.replace(tmp, path)


def _read_summary(res: RunResult) -> dict[str, Any] | None:
    if res.status != "ok":
        return None
    try:
        return json.loads((res.folder / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        res.status, res.error = "failed", f"summary.json unreadable: {exc}"
        return None


# --------------------------------------------------------------------------------------------
# entry point


def reproduce(
    out_dir: str | Path,
    scenario_path: str | Path | None = None,
    *,
    scenario: Scenario | None = None,
    overrides: Mapping[str, Mapping[str, Any]] | None = None,
    progress: bool = True,
    workers: int = 2,
    controllers: Iterable[str] = CONTROLLERS,
) -> dict[str, Any]:
    """Run the paper's evaluation; write the report and figures in ``out_dir``; return the report.

    Parameters
    ----------
    out_dir
        Output folder: ``report.json``, ``report.md``, ``fig*.png`` and ``runs/<controller>/``
        (each run's summary.json, trajectories.parquet, ...).
    scenario_path
        Scenario TOML; default the paper's (:func:`default_scenario_path`).
    scenario
        An already loaded scenario (instead of ``scenario_path``).
    overrides
        ``{section: {key: value}}`` applied over the file (e.g. a shorter ``duration_s``).
    progress
        Show a progress bar over the runs.
    workers
        Runs at a time, each in its own process.
    controllers
        The controllers to run (default all; the mobility gain needs ``cacc``).
    """
    wall0 = time.perf_counter()
    controllers = list(dict.fromkeys(controllers))
    unknown = [c for c in controllers if c not in CONTROLLERS]
    if unknown or not controllers:
        name = unknown[0] if unknown else ""
        raise ConfigError(f"unknown controller '{name}' (known: {', '.join(CONTROLLERS)})")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"workers must be an integer >= 1, got {workers!r}")
    if scenario is None:
        path = Path(scenario_path) if scenario_path is not None else default_scenario_path()
        scenario = load_scenario(path, overrides={k: dict(v) for k, v in (overrides or {}).items()})
    elif overrides:
        raise ConfigError("give overrides with a scenario file, not with a loaded scenario")
    out = prepare_out_dir(out_dir)
    results = {c: RunResult(c, "pending", out / "runs" / c) for c in controllers}
    from sumo_swarm.plots import FIGURES, RunData, lane_widths_m, make_figures
    from sumo_swarm.scene import build_scene

    n_lanes = len(lane_widths_m(scenario))
    compared_lane = n_lanes - 1  # the left lane, as the paper's Figs. 11-12
    rows_spec = measures(scenario, n_lanes, compared_lane)
    summary_rows_spec = upstream_measures(scenario, n_lanes, compared_lane, paired=False)
    ev = scenario.evaluation
    blocked = [v.id for v in build_scene(scenario).vehicles if v.role == "adjacent"]
    runs: dict[str, RunData] = {}  # finished runs, each trajectory table read once

    def run_data(summaries: Mapping[str, Mapping[str, Any] | None]) -> dict[str, RunData]:
        for c, s in summaries.items():
            if s is not None and c not in runs:
                runs[c] = RunData(c, results[c].folder, s)
        return {c: runs[c] for c, s in summaries.items() if s is not None}

    def paired_window(
        summaries: Mapping[str, Mapping[str, Any] | None],
    ) -> metrics.EvaluationWindow | None:
        """From the swarm's decision (the window start without a swarm decision); None while
        the swarm run is still to come."""
        t_start = _get(summaries.get(FOCUS), "overtake", "t_start_s")
        if t_start is None and results.get(FOCUS) and results[FOCUS].status == "pending":
            return None
        return metrics.EvaluationWindow(ev.start_s if t_start is None else t_start, ev.end_s)

    def paired(
        summaries: Mapping[str, Mapping[str, Any] | None], w: metrics.EvaluationWindow | None
    ) -> tuple[dict[str, Any], dict[str, Any], str | None]:
        upstream: dict[str, Any] = {c: None for c in controllers}
        target: dict[str, Any] = {c: None for c in controllers}
        finished = run_data(summaries)
        if w is None or BASELINE not in finished:
            return upstream, target, None
        try:
            base = finished[BASELINE].df
            for c, run in finished.items():
                upstream[c] = paired_upstream(run.summary, run.df, base, w, blocked)
                slow = _get(run.summary, "overtake", "target")
                if slow is not None:
                    target[c] = paired_vehicle(str(slow), run.df, base, w)
        except Exception as exc:  # the paired rows must never cost the report
            log.warning("paired upstream measures failed: %s", exc)
            return upstream, target, f"{type(exc).__name__}: {exc}"
        return upstream, target, None

    def write_report(
        figures: Mapping[str, str] | None = None,
        figure_errors: Mapping[str, str] | None = None,
        complete: bool = False,
    ) -> dict[str, Any]:
        summaries = {c: _read_summary(r) for c, r in results.items()}
        w = paired_window(summaries)
        upstream_paired, overtaken_paired, paired_error = paired(summaries, w)
        rows = build_rows(rows_spec, summaries, controllers, upstream_paired)
        wall_s = time.perf_counter() - wall0
        report: dict[str, Any] = {
            "schema": SCHEMA,
            "scenario": scenario.name,
            "scenario_file": str(scenario.path),
            "seed": scenario.simulation.seed,
            "created_utc": datetime.now(UTC).strftime("%Y-%m-%d %H:%M UTC"),
            "complete": complete,
            "wall_s": wall_s,
            "controllers": controllers,
            "columns": ["measure", "paper", *controllers],
            "compared_lane": compared_lane,
            "scenario_info": {
                "window": f"{ev.start_s:g}-{ev.end_s:g} s",
                "initial_speed_mps": scenario.scene.initial_speed_mps,
                "cruising_speed_mps": scenario.cav.cruising_speed_mps,
                "cell_length_m": scenario.cell_length_m,
            },
            "runs": {c: r.as_json(out) for c, r in results.items()},
            "rows": rows,
            "upstream_summary_rows": build_rows(summary_rows_spec, summaries, controllers),
            "definitions": definitions(
                scenario, compared_lane, n_lanes, w.start_s if w is not None else None
            ),
            "targets": targets(rows, wall_s if complete else None),
            "figures": dict(figures or {}),
            "figure_errors": dict(figure_errors or {}),
            # Where the paired upstream rows come from: the window [s] and every run's entries.
            "upstream_window_s": [w.start_s, w.end_s] if w is not None else None,
            "upstream_paired": upstream_paired,
            "upstream_paired_error": paired_error,
            "overtaken_paired": overtaken_paired,
            # The swarm's paired entries under the name of the earlier diagnostic.
            "upstream_against_baseline": upstream_paired.get(FOCUS) or [],
        }
        report["differences"] = differences(report)
        write_json_atomic(out / "report.json", report)
        _write_text_atomic(out / "report.md", render_markdown(report))
        return report

    write_report()
    _run_all(scenario, results, workers, on_done=lambda res: write_report(), progress=progress)

    finished = run_data({c: _read_summary(r) for c, r in results.items()})
    paper_speeds = {FOCUS: PAPER_SPEED_MPS, BASELINE: PAPER_CACC_SPEED_MPS}
    with tqdm(total=len(FIGURES), desc="figures", unit="fig", disable=not progress) as bar:
        figures, figure_errors = make_figures(
            out, scenario, finished, focus=FOCUS,
            paper_speeds={k: v for k, v in paper_speeds.items() if k in finished},
            on_figure=lambda name: bar.update(),
        )  # fmt: skip
    return write_report(figures, figure_errors, complete=True)
