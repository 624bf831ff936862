"""The penetration study's headline table (README), from a batch's results.parquet.

One row per CAV share and controller at one demand: the delay of each class (SUMO's tripinfo
timeLoss, mean per vehicle), throughput, hard brakes per 1000 vehicle-km, SSM conflicts with a
TTC below 1.5 s, CO2 per km of the cars, collisions and CAV hard brakes; a CAV share of 0 has
one row (no CAV: every controller drives the same traffic). Each figure is the mean over the
runs of the row (``runs``: one per seed; batches of other seeds of the same sweep may be given
together).

Usage: python tools/study_headline.py DIR [DIR ...] [--demand 1500] [--out docs/bench/penetration]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

SHARE, DEMAND = "corridor.cav_share", "corridor.main_demand_vph_per_lane"
ORDER = ("swarm", "cacc", "sumo-cacc", "sumo-lc")
COLUMNS = {
    "network.delay_s.cav": "CAV delay [s]",
    "network.delay_s.hv": "car delay [s]",
    "network.delay_s.truck": "truck delay [s]",
    "network.throughput_vph": "throughput [veh/h]",
    "network.hard_brakes_per_1000_vkm": "hard brakes /1000 veh-km",
    "network.ttc_below_1_5s_events": "TTC < 1.5 s",
    "network.co2_g_per_km.hv": "car CO2 [g/km]",
    "safety.collisions": "collisions",
    "safety.hard_brakes_cav": "CAV hard brakes",
    "swarms.platoons_formed": "platoons formed",
}


def headline(results: pd.DataFrame, demand: float) -> pd.DataFrame:
    df = results[(results["status"] == "ok") & (results[DEMAND] == demand)]
    rows = []
    for share, group in df.groupby(SHARE, sort=True):
        for controller in ORDER if share > 0 else ORDER[:1]:
            run = group[group["controller"] == controller]
            if run.empty:
                continue
            row = {
                "CAVs [%]": round(100 * share),
                "controller": controller if share > 0 else "(no CAV)",
                "runs": len(run),
            }
            for column, heading in COLUMNS.items():
                row[heading] = run[column].mean() if column in run else float("nan")
            rows.append(row)
    out = pd.DataFrame(rows)
    if "platoons formed" in out:  # only the swarm forms platoons
        out.loc[out["controller"] != "swarm", "platoons formed"] = float("nan")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("batch", type=Path, nargs="+", help="batch folders (seeds averaged)")
    parser.add_argument("--demand", type=float, default=1500.0)
    parser.add_argument("--out", type=Path, default=None, help="write OUT.md and OUT.csv")
    args = parser.parse_args(argv)
    results = pd.concat(
        [pd.read_parquet(folder / "results.parquet") for folder in args.batch], ignore_index=True
    )
    table = headline(results, args.demand)
    md = table.to_markdown(index=False, floatfmt=".1f")
    print(md)
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        table.to_csv(args.out.with_suffix(".csv"), index=False)
        head = (
            f"Penetration study, demand {args.demand:g} veh/h/lane: "
            f"`python tools/study_headline.py {' '.join(map(str, args.batch))} "
            f"--demand {args.demand:g}`\n\n"
        )
        args.out.with_suffix(".md").write_text(head + md + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
