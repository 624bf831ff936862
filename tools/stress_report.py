"""Check a finished stress sweep (tools/make_stress.py, run with `sumo-swarm batch`).

For every scene, its `swarm` run against its `cacc` run: zero collisions, no CAV braking harder
than 4 m/s^2, no more HVs braking harder than 4 m/s^2 than under `cacc`, no failed run. Prints
and writes DIR/stress.md and DIR/stress.csv (one row per scene); exit status 1 when a check
fails anywhere.

Usage: python tools/stress_report.py DIR
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import pandas as pd

CHECKS = ("no_collision", "no_cav_hard_brake", "hv_hard_brakes_not_above_cacc", "ran")


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
    ]  # fmt: skip
    return pd.DataFrame(rows, columns=["measure", "value"])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("folder", type=Path)
    args = parser.parse_args(argv)
    results = pd.read_parquet(args.folder / "results.parquet")
    # The swept parameters, as the batch recorded them.
    params = json.loads((args.folder / "sweep.json").read_text())["parameters"]
    table = scene_table(results, params)
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
