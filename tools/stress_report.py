"""Check a finished stress sweep (tools/make_stress.py, run with `sumo-swarm batch`).

For every scene, its `swarm` run against its `cacc` run: zero collisions, no CAV braking harder
than 4 m/s^2, no more HVs braking harder than 4 m/s^2 than under `cacc`, no failed run. Also
reports, per swarm run and over the sweep (median / p95 / max), the guard's refusals
(`lateral_hold`: `overtake.lateral_holds`, else the events in the run's events.jsonl) and the
planner's solve times (p95 and max per run), against issue 11's goals: lateral holds median 0,
planner p95 <= 50 ms and max <= 250 ms in every run (reported, not part of the exit status).
Prints and writes DIR/stress.md and DIR/stress.csv (one row per scene); exit status 1 when a
check fails anywhere.

Version 2 (issue 12; the sweep has `sumo-lc` runs, tools/make_stress.py --version 2) judges only
the scenes whose three runs (swarm, cacc, sumo-lc) have all finished, so a batch still under way
can be reported ("partial: N of M scenes"), and adds per scene: swarm mean CAV speed >= cacc's
- 1 %; completed and regrouped (the swarm's summary) wherever every CAV of the sumo-lc run got
past the slow vehicle `hv_target` (decided from that run's trajectories.parquet as summary.py
decides an overtake's end: `pass_times_s`, each CAV's rear bumper ahead of the target's front
bumper at some step); smallest CAV-to-CAV gap >= 5 m (`cav.gap_min_cav_m`, else
`cav.gap_min_m`), the smallest gap behind an HV reported apart. Over the sweep it lists issue
12's "Done when" figures against their goals. Mean gain over cacc: the mean over the scenes of
100 * (swarm / cacc - 1) of the CAVs' mean speeds.

Usage: python tools/stress_report.py DIR
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import pandas as pd

from sumo_swarm.sim.summary import pass_times_s

CHECKS = ("no_collision", "no_cav_hard_brake", "hv_hard_brakes_not_above_cacc", "ran")
V2_CHECKS = ("not_slower_than_cacc", "passes_where_sumo_lc_passes", "cav_gap_ok")
PLANNER_P95_GOAL_MS = 50.0  # issue 11
PLANNER_MAX_GOAL_MS = 250.0
LC = "sumo-lc"  # the v2 sweep's third controller: SUMO's drivers, free to change lanes
TARGET = "hv_target"  # the slow vehicle of every stress scene (tools/make_stress.py)
SLOWER_TOLERANCE = 0.01  # issue 12: swarm mean CAV speed >= cacc's - 1 %
CAV_GAP_GOAL_M = 5.0  # issue 12: min CAV-to-CAV gap
# issue 12's "Done when" for the sweep
SCENES_GOAL = 200
LANE_CHANGE_SHARE_GOAL_PCT = 30.0
PASS_SHARE_GOAL_PCT = 95.0
GAIN_ALL_GOAL_PCT = 12.0
GAIN_LANE_CHANGE_GOAL_PCT = 8.0
TRAJECTORY_COLUMNS = ["time_s", "vehicle", "kind", "s_m", "length_m"]


class BadInputError(Exception):
    """A folder that is not a (started) batch: one line for the user, exit status 2."""


def lateral_holds(folder: Path, row: pd.Series) -> float:
    """One run's `lateral_hold` count: the summary's, else its events.jsonl's (NaN: neither)."""
    value = row.get("overtake.lateral_holds")
    if value is not None and pd.notna(value):
        return float(value)
    events = folder / "runs" / str(row["run_id"]) / "events.jsonl"
    if not events.is_file():
        return float("nan")
    lines = events.read_text(encoding="utf-8").splitlines()
    return float(sum(json.loads(line).get("event") == "lateral_hold" for line in lines if line))


def with_lateral_holds(results: pd.DataFrame, folder: Path) -> pd.DataFrame:
    holds = [lateral_holds(folder, row) for _, row in results.iterrows()]
    return results.assign(lateral_holds=holds)


def spread(values: pd.Series) -> str:
    """median / p95 / max of the finite values, or n/a."""
    values = pd.to_numeric(values, errors="coerce").dropna()
    if values.empty:
        return "n/a"
    return f"{values.median():.4g} / {values.quantile(0.95):.4g} / {values.max():.4g}"


def all_cavs_passed(df: pd.DataFrame, target: str = TARGET) -> bool:
    """Whether every CAV (``kind == "cav"``) of a run's trajectories got past ``target`` at some
    step: summary.py's :func:`pass_times_s` (rear bumper ahead of the target's front bumper)."""
    cav_ids = tuple(sorted(df.loc[df["kind"] == "cav", "vehicle"].astype(str).unique()))
    if not cav_ids:
        return False
    times = pass_times_s(df, cav_ids, target)
    return all(t is not None for t in times.values())


def lc_passes(folder: Path, run_ids: list[str]) -> pd.Series:
    """Per sumo-lc run id: whether all its CAVs got past the target (NA: no trajectories)."""
    out: dict[str, object] = {}
    for run_id in run_ids:
        path = folder / "runs" / run_id / "trajectories.parquet"
        if not path.is_file():
            out[run_id] = pd.NA
            continue
        out[run_id] = all_cavs_passed(pd.read_parquet(path, columns=TRAJECTORY_COLUMNS))
    return pd.Series(out, dtype="boolean")


def scene_table(
    results: pd.DataFrame, params: list[str], lc_passed: pd.Series | None = None
) -> pd.DataFrame:
    """One row per scene: the swarm's and cacc's safety numbers side by side, and the checks.

    With sumo-lc runs in ``results`` (sweep v2), only the scenes whose swarm, cacc and sumo-lc
    runs are all there, and the v2 columns and checks; ``lc_passed`` maps a sumo-lc run id to
    whether all its CAVs got past the target (:func:`lc_passes`; missing: NA, not a pass).
    """
    key = [p for p in params if p in results.columns]
    results = results.assign(_scene=results[key].astype(str).agg("|".join, axis=1))
    swarm = results[results["controller"] == "swarm"].set_index("_scene")
    cacc = results[results["controller"] == "cacc"].set_index("_scene")
    lc = results[results["controller"] == LC].set_index("_scene")
    v2 = not lc.empty
    if v2:  # a batch under way: the scenes whose three runs have all finished
        swarm = swarm[swarm.index.isin(cacc.index) & swarm.index.isin(lc.index)]
    out = pd.DataFrame(index=swarm.index)
    for col in ("cav.count", "simulation.network", "hv.lane_changes"):
        if col in swarm:
            out[col] = swarm[col]
    out["status"] = swarm["status"]
    out["collisions"] = swarm["safety.collisions"]
    out["cav_hard_brakes"] = swarm["safety.hard_brakes_cav"]
    out["hv_hard_brakes"] = swarm["safety.hard_brakes_hv"]
    out["hv_hard_brakes_cacc"] = cacc["safety.hard_brakes_hv"].reindex(out.index)
    out["cacc_collisions"] = cacc["safety.collisions"].reindex(out.index)
    out["completed"] = swarm["overtake.all_past"].astype("boolean")
    out["regrouped"] = swarm["overtake.all_past_regrouped"].astype("boolean")
    out["gap_min_m"] = swarm["cav.gap_min_m"]
    out["mean_speed_mps"] = swarm["cav.mean_speed_mps"]
    out["mean_speed_cacc_mps"] = cacc["cav.mean_speed_mps"].reindex(out.index)
    out["lateral_holds"] = swarm["lateral_holds"] if "lateral_holds" in swarm else float("nan")
    for col, name in (
        ("planner.solve_ms_p95", "planner_p95_ms"),
        ("planner.solve_ms_max", "planner_max_ms"),
        ("planner.solve_cpu_ms_p95", "planner_cpu_p95_ms"),
        ("planner.solve_cpu_ms_max", "planner_cpu_max_ms"),
    ):
        out[name] = swarm[col] if col in swarm else float("nan")
    out["ran"] = (swarm["status"] == "ok") & (cacc["status"].reindex(out.index) == "ok")
    out["no_collision"] = out["collisions"].fillna(1) == 0
    out["no_cav_hard_brake"] = out["cav_hard_brakes"].fillna(1) == 0
    out["hv_hard_brakes_not_above_cacc"] = out["hv_hard_brakes"].fillna(1) <= out[
        "hv_hard_brakes_cacc"
    ].fillna(0)
    if v2:
        out = with_v2_checks(out, swarm, lc, lc_passed)
    return out.reset_index(drop=True)


def with_v2_checks(
    out: pd.DataFrame, swarm: pd.DataFrame, lc: pd.DataFrame, lc_passed: pd.Series | None
) -> pd.DataFrame:
    """Add the sumo-lc columns and issue 12's per-scene checks to ``out`` (index: scene)."""
    lc = lc.reindex(out.index)
    out["ran"] = out["ran"] & (lc["status"] == "ok").to_numpy()
    out["mean_speed_sumo_lc_mps"] = lc["cav.mean_speed_mps"]
    out["gain_over_cacc_pct"] = 100.0 * (out["mean_speed_mps"] / out["mean_speed_cacc_mps"] - 1.0)
    passed = pd.Series(pd.NA, index=out.index, dtype="boolean")
    if lc_passed is not None:
        passed = lc["run_id"].map(lc_passed).astype("boolean")
    out["sumo_lc_passed"] = passed
    # The swarm's own target (its summary's completed/regrouped are about it): hv_target, or
    # none when it never started an overtake.
    out["swarm_target"] = swarm.get("overtake.target")
    cav_gap = swarm.get("cav.gap_min_cav_m")
    out["gap_min_cav_m"] = (
        swarm["cav.gap_min_m"] if cav_gap is None else cav_gap.fillna(swarm["cav.gap_min_m"])
    )
    out["gap_min_hv_m"] = swarm.get("cav.gap_min_hv_m")
    slowest_ok = out["mean_speed_cacc_mps"] * (1.0 - SLOWER_TOLERANCE)
    out["not_slower_than_cacc"] = (out["mean_speed_mps"] >= slowest_ok).fillna(False).astype(bool)
    done = (out["completed"] & out["regrouped"]).fillna(False)
    # An unknown sumo-lc outcome (no trajectories) is not a pass.
    out["passes_where_sumo_lc_passes"] = (
        (~passed & passed.notna()) | (passed.fillna(False) & done)
    ).astype(bool)
    out["cav_gap_ok"] = (out["gap_min_cav_m"] >= CAV_GAP_GOAL_M).fillna(False).astype(bool)
    return out


def checks_of(table: pd.DataFrame) -> list[str]:
    """The per-scene checks of ``table``: v1's, and v2's when it has them."""
    return list(CHECKS) + [c for c in V2_CHECKS if c in table.columns]


def done_when(table: pd.DataFrame, total_scenes: int) -> pd.DataFrame:
    """Issue 12's "Done when" figures of a v2 table: measure, value, goal, met."""
    n = len(table)
    lane_changes = table["hv.lane_changes"].astype(bool) if n else pd.Series(dtype=bool)
    lc_share = 100.0 * lane_changes.mean() if n else float("nan")
    passed = table["sumo_lc_passed"].fillna(False).astype(bool)
    done = (table["completed"] & table["regrouped"]).fillna(False).astype(bool)
    done_share = 100.0 * done[passed].mean() if passed.any() else float("nan")
    gain_all = table["gain_over_cacc_pct"].mean()
    gain_lc = table.loc[lane_changes, "gain_over_cacc_pct"].mean()
    collisions = int(table["collisions"].fillna(0).sum())
    slower = int((~table["not_slower_than_cacc"]).sum())
    gap_cav = _min(table["gap_min_cav_m"])
    rows = [
        ("scenes judged (all three runs finished)", f"{n} of {total_scenes}",
         f">= {SCENES_GOAL}", n >= SCENES_GOAL),
        ("scenes with HV lane changes (%)", _r(lc_share), f">= {LANE_CHANGE_SHARE_GOAL_PCT:g}",
         lc_share >= LANE_CHANGE_SHARE_GOAL_PCT),
        ("collisions in all (swarm)", collisions, "0", collisions == 0),
        (f"scenes where swarm is > {100 * SLOWER_TOLERANCE:g} % slower than cacc", slower, "0",
         slower == 0),
        ("scenes where all sumo-lc CAVs got past the slow vehicle",
         f"{int(passed.sum())} ({_r(100.0 * passed.mean() if n else float('nan'))} %)", "",
         None),
        ("  of these, swarm completed and regrouped (%)", _r(done_share),
         f">= {PASS_SHARE_GOAL_PCT:g}", done_share >= PASS_SHARE_GOAL_PCT),
        ("mean gain over cacc, all scenes (%)", _r(gain_all), f">= +{GAIN_ALL_GOAL_PCT:g}",
         gain_all >= GAIN_ALL_GOAL_PCT),
        (f"mean gain over cacc, lane-change scenes (%) [{int(lane_changes.sum())}]", _r(gain_lc),
         f">= +{GAIN_LANE_CHANGE_GOAL_PCT:g}", gain_lc >= GAIN_LANE_CHANGE_GOAL_PCT),
        ("min CAV-to-CAV gap (m)", _r(gap_cav, 2), f">= {CAV_GAP_GOAL_M:g}",
         gap_cav >= CAV_GAP_GOAL_M),
        ("min gap of a CAV behind an HV (m), reported apart", _r(_min(table["gap_min_hv_m"]), 2),
         "", None),
    ]  # fmt: skip
    frame = pd.DataFrame(rows, columns=["measure", "value", "goal", "met"])
    frame["met"] = frame["met"].map({True: "yes", False: "NO", None: ""})
    return frame


def failures_by_check(table: pd.DataFrame) -> pd.DataFrame:
    """Per check: the scenes failing it, and how many of them have HV lane changes."""
    lane_changes = table["hv.lane_changes"].astype(bool)
    rows = [
        (check, int((~table[check]).sum()), int((~table[check] & lane_changes).sum()))
        for check in checks_of(table)
    ]
    return pd.DataFrame(rows, columns=["check", "scenes failing", "of which lane-change"])


def _min(values: pd.Series) -> float:
    values = pd.to_numeric(values, errors="coerce").dropna()
    return float("nan") if values.empty else float(values.min())


def _r(value: float, digits: int = 1) -> object:
    return "n/a" if pd.isna(value) else round(float(value), digits)


def figures(table: pd.DataFrame) -> pd.DataFrame:
    n = len(table)
    rows = [
        ("scenes", n),
        ("runs that failed", int((~table["ran"]).sum())),
        ("scenes with a collision (swarm)", int((~table["no_collision"]).sum())),
        ("collisions in all (swarm)", int(table["collisions"].fillna(0).sum())),
        ("scenes with a CAV braking beyond -4 m/s^2", int((~table["no_cav_hard_brake"]).sum())),
        ("scenes with more HV hard brakes than cacc",
         int((~table["hv_hard_brakes_not_above_cacc"]).sum())),
        ("HV hard brakes, swarm / cacc (sum)",
         f"{int(table['hv_hard_brakes'].fillna(0).sum())} / "
         f"{int(table['hv_hard_brakes_cacc'].fillna(0).sum())}"),
        ("overtake completed (%)", round(100 * table["completed"].fillna(False).mean(), 1)),
        ("overtake completed and regrouped (%)",
         round(100 * (table["completed"] & table["regrouped"]).fillna(False).mean(), 1)),
        ("min CAV gap over all scenes (m)", round(float(table["gap_min_m"].min()), 2)),
        ("mean CAV speed, swarm / cacc (m/s)",
         f"{table['mean_speed_mps'].mean():.2f} / {table['mean_speed_cacc_mps'].mean():.2f}"),
    ]  # fmt: skip
    if "mean_speed_sumo_lc_mps" in table:
        rows.append(("mean CAV speed, sumo-lc (m/s)",
                     f"{table['mean_speed_sumo_lc_mps'].mean():.2f}"))  # fmt: skip
    rows += [
        ("lateral_hold per swarm run, median / p95 / max", spread(table["lateral_holds"])),
        ("planner p95 per swarm run (ms), median / p95 / max", spread(table["planner_p95_ms"])),
        ("planner max per swarm run (ms), median / p95 / max", spread(table["planner_max_ms"])),
        ("planner max over the sweep (ms)", _max(table["planner_max_ms"])),
        (f"runs with planner p95 > {PLANNER_P95_GOAL_MS:g} ms",
         int((table["planner_p95_ms"] > PLANNER_P95_GOAL_MS).sum())),
        (f"runs with planner max > {PLANNER_MAX_GOAL_MS:g} ms",
         int((table["planner_max_ms"] > PLANNER_MAX_GOAL_MS).sum())),
        # The same on one core: the solves' process time (wall time grows with the machine's
        # other jobs; a sweep runs two at a time on this 2-core machine).
        ("planner CPU p95 per swarm run (ms), median / p95 / max",
         spread(table["planner_cpu_p95_ms"])),
        ("planner CPU max over the sweep (ms)", _max(table["planner_cpu_max_ms"])),
        (f"runs with planner CPU p95 > {PLANNER_P95_GOAL_MS:g} ms",
         int((table["planner_cpu_p95_ms"] > PLANNER_P95_GOAL_MS).sum())),
        (f"runs with planner CPU max > {PLANNER_MAX_GOAL_MS:g} ms",
         int((table["planner_cpu_max_ms"] > PLANNER_MAX_GOAL_MS).sum())),
    ]  # fmt: skip
    return pd.DataFrame(rows, columns=["measure", "value"])


def _max(values: pd.Series) -> object:
    values = pd.to_numeric(values, errors="coerce").dropna()
    return "n/a" if values.empty else round(float(values.max()), 1)


FAILING_COLUMNS = (
    "cav.count", "simulation.network", "hv.lane_changes", "collisions", "completed",
    "regrouped", "sumo_lc_passed", "mean_speed_mps", "mean_speed_cacc_mps",
    "gain_over_cacc_pct", "gap_min_cav_m",
)  # fmt: skip


def failing_view(failing: pd.DataFrame) -> pd.DataFrame:
    """The failing scenes for the markdown: v1 prints every column; v2 (wide) a few and the
    names of the checks each one fails (stress.csv has every column)."""
    if "sumo_lc_passed" not in failing:
        return failing
    checks = checks_of(failing)
    view = failing[[c for c in FAILING_COLUMNS if c in failing]].copy()
    view["failed"] = failing[checks].apply(
        lambda row: ", ".join(c for c in checks if not row[c]), axis=1
    )
    return view.round(2)


def read_batch(folder: Path) -> tuple[pd.DataFrame, dict]:
    """results.parquet and sweep.json of a batch folder (:class:`BadInputError` when not one)."""
    try:
        sweep = json.loads((folder / "sweep.json").read_text(encoding="utf-8"))
        results = pd.read_parquet(folder / "results.parquet")
    except (OSError, ValueError) as exc:
        raise BadInputError(
            f"{folder}: not a batch folder ({exc.__class__.__name__}: {exc})"
        ) from None
    if not isinstance(sweep, dict) or "parameters" not in sweep:
        raise BadInputError(f"{folder / 'sweep.json'}: no 'parameters' (not a batch's sweep.json)")
    return results, sweep


def total_scenes(sweep: dict) -> int:
    """The number of scenes (cases x seeds) of the sweep as the batch recorded it."""
    per_scene = max(1, len(sweep.get("controllers", [])))
    return len(sweep.get("runs", [])) // per_scene


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    args = parser.parse_args(argv)
    try:
        results, sweep = read_batch(args.folder)
    except BadInputError as exc:
        print(f"stress_report: {exc}".splitlines()[0], file=sys.stderr)
        return 2
    # The swept parameters, as the batch recorded them.
    params = sweep["parameters"]
    lc_passed = None
    if (results["controller"] == LC).any():
        lc_passed = lc_passes(args.folder, list(results.loc[results["controller"] == LC, "run_id"]))
    table = scene_table(with_lateral_holds(results, args.folder), params, lc_passed)
    summary = figures(table)
    table.to_csv(args.folder / "stress.csv", index=False)
    failing = table[~table[checks_of(table)].all(axis=1)]
    md = summary.to_markdown(index=False)
    if lc_passed is not None:
        total = total_scenes(sweep)
        head = f"partial: {len(table)} of {total} scenes\n\n" if len(table) < total else ""
        goals = done_when(table, total).to_markdown(index=False)
        by_check = failures_by_check(table).to_markdown(index=False)
        md = (
            f'{head}Issue 12\'s "Done when":\n\n{goals}\n\nScenes failing each check:\n\n'
            f"{by_check}\n\nAll figures:\n\n{md}"
        )
    if not failing.empty:
        md += "\n\nScenes failing a check:\n\n" + failing_view(failing).to_markdown(index=False)
    (args.folder / "stress.md").write_text(md + "\n", encoding="utf-8")
    print(md)
    return 1 if not failing.empty else 0


if __name__ == "__main__":
    sys.exit(main())
