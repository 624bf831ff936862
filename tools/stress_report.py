"""Check a finished stress sweep (tools/make_stress.py, run with `sumo-swarm batch`).

For every scene, its `swarm` run against its `cacc` run: zero collisions, no CAV braking harder
than 4 m/s^2, no more HVs braking harder than 4 m/s^2 than under `cacc`, no failed run. Also
reports, per swarm run and over the sweep (median / p95 / max), the guard's refusals
(`lateral_hold`: `overtake.lateral_holds`, else the events in the run's events.jsonl) and the
planner's solve times (p95 and max per run), against issue 11's goals: lateral holds median 0,
planner p95 <= 50 ms and max <= 250 ms in every run (reported, not part of the exit status).
Prints and writes DIR/stress.md and DIR/stress.csv (one row per scene); exit status 1 when a
check fails anywhere.

Usage: python tools/stress_report.py DIR
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import pandas as pd

CHECKS = ("no_collision", "no_cav_hard_brake", "hv_hard_brakes_not_above_cacc", "ran")
PLANNER_P95_GOAL_MS = 50.0  # issue 11
PLANNER_MAX_GOAL_MS = 250.0


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


def scene_table(results: pd.DataFrame, params: list[str]) -> pd.DataFrame:
    """One row per scene: the swarm's and cacc's safety numbers side by side, and the checks."""
    key = [p for p in params if p in results.columns]
    results = results.assign(_scene=results[key].astype(str).agg("|".join, axis=1))
    swarm = results[results["controller"] == "swarm"].set_index("_scene")
    cacc = results[results["controller"] == "cacc"].set_index("_scene")
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
    out["completed"] = swarm["overtake.completed"].astype("boolean")
    out["regrouped"] = swarm["overtake.regrouped"].astype("boolean")
    out["gap_min_m"] = swarm["cav.gap_min_m"]
    out["mean_speed_mps"] = swarm["cav.mean_speed_mps"]
    out["mean_speed_cacc_mps"] = cacc["cav.mean_speed_mps"].reindex(out.index)
    out["lateral_holds"] = swarm["lateral_holds"] if "lateral_holds" in swarm else float("nan")
    for col, name in (
        ("planner.solve_ms_p95", "planner_p95_ms"),
        ("planner.solve_ms_max", "planner_max_ms"),
    ):
        out[name] = swarm[col] if col in swarm else float("nan")
    out["ran"] = (swarm["status"] == "ok") & (cacc["status"].reindex(out.index) == "ok")
    out["no_collision"] = out["collisions"].fillna(1) == 0
    out["no_cav_hard_brake"] = out["cav_hard_brakes"].fillna(1) == 0
    out["hv_hard_brakes_not_above_cacc"] = out["hv_hard_brakes"].fillna(1) <= out[
        "hv_hard_brakes_cacc"
    ].fillna(0)
    return out.reset_index(drop=True)


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
        ("lateral_hold per swarm run, median / p95 / max", spread(table["lateral_holds"])),
        ("planner p95 per swarm run (ms), median / p95 / max", spread(table["planner_p95_ms"])),
        ("planner max per swarm run (ms), median / p95 / max", spread(table["planner_max_ms"])),
        ("planner max over the sweep (ms)", _max(table["planner_max_ms"])),
        (f"runs with planner p95 > {PLANNER_P95_GOAL_MS:g} ms",
         int((table["planner_p95_ms"] > PLANNER_P95_GOAL_MS).sum())),
        (f"runs with planner max > {PLANNER_MAX_GOAL_MS:g} ms",
         int((table["planner_max_ms"] > PLANNER_MAX_GOAL_MS).sum())),
    ]  # fmt: skip
    return pd.DataFrame(rows, columns=["measure", "value"])


def _max(values: pd.Series) -> object:
    values = pd.to_numeric(values, errors="coerce").dropna()
    return "n/a" if values.empty else round(float(values.max()), 1)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    args = parser.parse_args(argv)
    results = pd.read_parquet(args.folder / "results.parquet")
    # The swept parameters, as the batch recorded them.
    params = json.loads((args.folder / "sweep.json").read_text())["parameters"]
    table = scene_table(with_lateral_holds(results, args.folder), params)
    summary = figures(table)
    table.to_csv(args.folder / "stress.csv", index=False)
    failing = table[~table[list(CHECKS)].all(axis=1)]
    md = summary.to_markdown(index=False)
    if not failing.empty:
        md += "\n\nScenes failing a check:\n\n" + failing.to_markdown(index=False)
    (args.folder / "stress.md").write_text(md + "\n", encoding="utf-8")
    print(md)
    return 1 if not failing.empty else 0


if __name__ == "__main__":
    sys.exit(main())
