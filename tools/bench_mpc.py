"""Benchmark of the tracking MPCs: wall time per warm-started call (not a test).

One CAV drives a swarming plan (a row forward, a lane change, a row back, a lane change
back, repeated) in closed loop: a point-mass longitudinal model and a kinematic bicycle
laterally, one control step every ``--dt`` seconds. Each step samples the reference
(``Reference.sample_time`` / ``sample_space``) and calls both MPCs; ``TrackingResult.solve_ms``
(updates included) is recorded. The lateral MPC is timed twice: with ``ds = v * dt`` changing
every call (the constraint matrix is updated and refactorised) and with ``ds`` rounded to
``--ds-quantum`` metres (refactorised only when the rounded value changes).

Usage::

    python tools/bench_mpc.py                       # K = 20, 30, 50; 2000 calls each
    python tools/bench_mpc.py --horizons 30 --calls 500 --out /tmp/mpc

Writes ``<out>.csv`` and ``<out>.md`` (default ``docs/bench/mpc``).
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import platform
import time
from pathlib import Path

import numpy as np

from sumo_swarm.core.model import RoadSection
from sumo_swarm.core.tracking import (
    LateralMpc,
    LateralSettings,
    LongitudinalMpc,
    LongitudinalSettings,
)
from sumo_swarm.core.trajectory import GridFrame, Reference, reference_from_cells

TARGET_MS = 1.0  # budget per CAV per control step, both MPCs together [ms]
COLUMNS = (
    "mpc",
    "horizon",
    "dt_s",
    "ds",
    "calls",
    "solved",
    "median_ms",
    "p95_ms",
    "max_ms",
    "cpu_median_ms",
    "cpu_p95_ms",
)


def swarming_reference(calls: int, dt_s: float) -> Reference:
    """A plan long enough for ``calls`` control steps: forward, left, back, right, ..."""
    road = RoadSection(lane_widths_m=(3.5, 3.5, 3.5))
    frame = GridFrame(0.0, 0.0, 17.5, 15.0, 3.0, road)
    pattern = [(0, 1), (1, 1), (1, 2), (1, 2), (0, 2), (0, 1), (0, 1)]
    steps = math.ceil(calls * dt_s / frame.behaving_interval_s) + 4
    cells = [pattern[k % len(pattern)] for k in range(steps)]
    return reference_from_cells(cells, frame, t_now=0.0, s_now=22.5, v_now=17.5, y_now=3.5)


def run(
    horizon: int, dt_s: float, calls: int, ds_quantum_m: float | None
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, float]]:
    """Closed loop over ``calls`` control steps.

    Returns per-stage wall times [ms], thread CPU times [ms] (not inflated when other
    processes preempt this one) and the fraction of calls each MPC solved.
    """
    ref = swarming_reference(calls, dt_s)
    lon = LongitudinalMpc(LongitudinalSettings(dt_s=dt_s, horizon=horizon))
    lat_settings = LateralSettings(dt_s=dt_s, horizon=horizon)
    lat = LateralMpc(lat_settings)
    wheelbase = lat_settings.wheelbase_m
    kappa = np.zeros(horizon)
    s, v = ref.s_at(0.0), ref.v_at(0.0)
    lat_pos, phi = ref.y_at(0.0), 0.0
    names = ("reference", "lon", "lat")
    times = {name: np.empty(calls) for name in names}
    cpu = {name: np.empty(calls) for name in names}
    solved = {"lon": 0, "lat": 0}
    for step in range(calls):
        t_now = step * dt_s
        started, cpu_started = time.perf_counter(), time.thread_time()
        _, s_ref, v_ref, _ = ref.sample_time(t_now, dt_s, horizon)
        ds = max(v, 0.1) * dt_s
        if ds_quantum_m:
            ds = max(round(ds / ds_quantum_m), 1) * ds_quantum_m
        _, y_ref, dy_ref, _ = ref.sample_space(s, ds, horizon)
        times["reference"][step] = (time.perf_counter() - started) * 1e3
        cpu["reference"][step] = (time.thread_time() - cpu_started) * 1e3
        cpu_started = time.thread_time()
        lon_result = lon.solve(s, v, s_ref, v_ref)
        cpu["lon"][step] = (time.thread_time() - cpu_started) * 1e3
        cpu_started = time.thread_time()
        lat_result = lat.solve(lat_pos, phi, y_ref, np.arctan(dy_ref), kappa, ds)
        cpu["lat"][step] = (time.thread_time() - cpu_started) * 1e3
        times["lon"][step] = lon_result.solve_ms
        times["lat"][step] = lat_result.solve_ms
        solved["lon"] += lon_result.status == "solved"
        solved["lat"] += lat_result.status == "solved"
        accel, delta = lon_result.u0, lat_result.u0
        travelled = v * dt_s + 0.5 * accel * dt_s**2
        s, v = s + travelled, v + accel * dt_s
        lat_pos += travelled * math.tan(phi)
        phi += travelled * math.tan(delta) / wheelbase
    times["both"] = times["lon"] + times["lat"]
    cpu["both"] = cpu["lon"] + cpu["lat"]
    fractions = {name: count / calls for name, count in solved.items()}
    return times, cpu, fractions


def summarise(
    name: str,
    horizon: int,
    dt_s: float,
    ds: str,
    values: np.ndarray,
    cpu_values: np.ndarray,
    solved: float,
) -> dict[str, object]:
    return {
        "mpc": name,
        "horizon": horizon,
        "dt_s": dt_s,
        "ds": ds,
        "calls": len(values),
        "solved": f"{solved:.3f}",
        "median_ms": f"{np.median(values):.3f}",
        "p95_ms": f"{np.percentile(values, 95):.3f}",
        "max_ms": f"{values.max():.3f}",
        "cpu_median_ms": f"{np.median(cpu_values):.3f}",
        "cpu_p95_ms": f"{np.percentile(cpu_values, 95):.3f}",
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--horizons", default="20,30,50", help="comma-separated K values")
    parser.add_argument("--dt", type=float, default=0.1, help="control step [s]")
    parser.add_argument("--calls", type=int, default=2000, help="warm-started calls per run")
    parser.add_argument(
        "--ds-quantum", type=float, default=0.1, help="rounding of ds in the second run [m]"
    )
    parser.add_argument("--out", default="docs/bench/mpc", help="output path without suffix")
    args = parser.parse_args()

    rows = []
    for horizon in (int(k) for k in args.horizons.split(",")):
        for ds_label, quantum in (("v*dt", None), (f"round {args.ds_quantum} m", args.ds_quantum)):
            times, cpu, solved = run(horizon, args.dt, args.calls, quantum)
            stages = [("lateral", "lat", solved["lat"]), ("both", "both", min(solved.values()))]
            if quantum is None:  # the longitudinal MPC and the sampling do not depend on ds
                stages = [
                    ("reference sampling", "reference", 1.0),
                    ("longitudinal", "lon", solved["lon"]),
                    *stages,
                ]
            rows.extend(
                summarise(name, horizon, args.dt, ds_label, times[key], cpu[key], fraction)
                for name, key, fraction in stages
            )

    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with out.with_suffix(".csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    header = "| " + " | ".join(COLUMNS) + " |\n|" + "---|" * len(COLUMNS) + "\n"
    table = header + "".join("| " + " | ".join(str(r[c]) for c in COLUMNS) + " |\n" for r in rows)
    note = (
        f"# MPC solve time per call\n\n"
        f"{args.calls} warm-started calls per row, closed loop on a swarming plan; "
        f"`solve_ms` (wall) includes OSQP's vector/matrix updates; `cpu_*` is the thread's CPU "
        f"time, which other processes on a shared machine do not inflate. Budget: {TARGET_MS} "
        f"ms per CAV per control step for both MPCs. Machine: "
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"load average {os.getloadavg()[0]:.2f} at the end of the run, "
        f"Python {platform.python_version()}.\n\n"
    )
    out.with_suffix(".md").write_text(note + table)
    print(table, end="")
    print(f"wrote {out.with_suffix('.csv')} and {out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
