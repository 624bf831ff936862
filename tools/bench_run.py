"""Benchmark: the cost of a whole `swarm` run against the `cacc` run of the same scenario.

Runs the two controllers alternately (so both see the same machine load), each run in its own
process (libsumo holds one simulation per process), and prints and saves a table of wall time
(median, p95, max), the swarm/cacc ratio, and the MPC's solve time per CAV.

Usage: python tools/bench_run.py [--repeats 5] [--scenario scenarios/paper.toml]
                                 [--out docs/bench/run]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parent.parent


def one_run(scenario: Path, controller: str) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            [sys.executable, "-m", "sumo_swarm", "run", str(scenario), "--controller",
             controller, "--out", tmp],
            check=True, capture_output=True,
        )  # fmt: skip
        return json.loads((Path(tmp) / "summary.json").read_text())


def stats(values: list[float]) -> dict[str, float]:
    a = np.asarray(values, dtype=float)
    return {"median": float(np.median(a)), "p95": float(np.percentile(a, 95)), "max": a.max()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--scenario", type=Path, default=ROOT / "scenarios" / "paper.toml")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "bench" / "run")
    args = parser.parse_args(argv)
    rows = []
    for i in range(args.repeats):
        for controller in ("cacc", "swarm"):
            s = one_run(args.scenario, controller)
            t = s["timing"]
            rows.append({"repeat": i, "controller": controller, **t,
                         "mpc_ms_per_cav_median": (s.get("tracking") or {}).get(
                             "solve_ms_per_cav_median"),
                         "mpc_ms_per_cav_p95": (s.get("tracking") or {}).get(
                             "solve_ms_per_cav_p95"),
                         "planner_ms_max": s["planner"]["solve_ms_max"]})  # fmt: skip
            print(f"run {i} {controller:6s} wall {t['wall_s']:.2f} s", flush=True)
    df = pd.DataFrame(rows)
    table = []
    for controller in ("cacc", "swarm"):
        sub = df[df["controller"] == controller]
        for measure in ("wall_s", "sumo_s", "controller_s"):
            table.append({"controller": controller, "measure": measure, **stats(sub[measure])})
    ratio = (df[df.controller == "swarm"]["wall_s"].to_numpy()
             / df[df.controller == "cacc"]["wall_s"].to_numpy())  # fmt: skip
    table.append({"controller": "swarm/cacc", "measure": "wall ratio", **stats(list(ratio))})
    swarm = df[df["controller"] == "swarm"]
    table.append({"controller": "swarm", "measure": "MPC ms per CAV per solve (run median)",
                  **stats(list(swarm["mpc_ms_per_cav_median"]))})  # fmt: skip
    table.append({"controller": "swarm", "measure": "MPC ms per CAV per solve (run p95)",
                  **stats(list(swarm["mpc_ms_per_cav_p95"]))})  # fmt: skip
    out = pd.DataFrame(table)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out.with_suffix(".runs.csv"), index=False)
    out.to_csv(args.out.with_suffix(".csv"), index=False)
    md = out.to_markdown(index=False, floatfmt=".3f") if _has_tabulate() else out.to_string()
    args.out.with_suffix(".md").write_text(md + "\n", encoding="utf-8")
    print(md)
    return 0


def _has_tabulate() -> bool:
    try:
        import tabulate  # noqa: F401
    except ImportError:
        return False
    return True


if __name__ == "__main__":
    sys.exit(main())
