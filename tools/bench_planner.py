"""Benchmark the cell planner (not a test): solve time and optimality over random scenes.

Scenes: a platoon of ``n`` CAVs (15 m apart) in the middle lane behind a target HV, with HVs
placed at random (45 to 160 m apart front to front, speeds 17.5 +- 1 m/s) in every lane from
60 m behind the tail to 90 m ahead of the target (in the platoon's lane only ahead of the
target's 45 m); the Figure 7 scene of the paper is added and solved
``--repeat`` times. Each scene is solved by every backend on one core with the default
planner settings. Writes ``<out>.csv`` and ``<out>.md`` (median, p95, max solve time, status
counts, worst gap) and prints the markdown table.

    python tools/bench_planner.py                  # full run, docs/bench/planner.{csv,md}
    python tools/bench_planner.py --quick --out /tmp/planner
"""

from __future__ import annotations

import argparse
import csv
import random
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from sumo_swarm.grid import GridSettings, build_grid
from sumo_swarm.model import RoadSection, VehicleState
from sumo_swarm.planner import (
    PlannerSettings,
    PlanStatus,
    build_problem,
    make_planner,
    validate_plan,
)

SPEED_MPS = 17.5


def vehicle(vid: str, s_m: float, lane: int, speed: float = SPEED_MPS) -> VehicleState:
    return VehicleState(vid, s_m, lane, 0.0, speed, 5.0, is_cav=vid.startswith("cav"))


def fig7_scene() -> tuple[list[VehicleState], VehicleState, list[VehicleState], RoadSection]:
    cavs = [vehicle(f"cav{i}", 300.0 - 15.0 * i, 1) for i in range(6)]
    target = vehicle("target", 315.0, 1)
    hvs = [target, vehicle("left", 255.0, 2), vehicle("right", 240.0, 0)]
    hvs += [vehicle(f"up1_{s}", s, 1) for s in (195.0, 165.0, 135.0)]
    hvs += [vehicle(f"up2_{s}", s, 2) for s in (225.0, 195.0)]
    hvs += [vehicle(f"up0_{s}", s, 0) for s in (210.0, 180.0)]
    return cavs, target, hvs, RoadSection((3.0, 3.0, 3.0))


def random_scene(
    n_cavs: int, n_lanes: int, rng: random.Random
) -> tuple[list[VehicleState], VehicleState, list[VehicleState], RoadSection]:
    lane = n_lanes // 2
    leader_front = 500.0
    cavs = [vehicle(f"cav{i}", leader_front - 15.0 * i, lane) for i in range(n_cavs)]
    target = vehicle("target", leader_front + 15.0, lane)
    hvs = [target]
    tail_front = leader_front - 15.0 * (n_cavs - 1)
    for q in range(n_lanes):
        s = tail_front - 60.0 + rng.uniform(0.0, 30.0)
        while s < leader_front + 105.0:
            if q != lane or s > leader_front + 60.0:
                speed = SPEED_MPS + rng.uniform(-1.0, 1.0)
                hvs.append(vehicle(f"hv{q}_{len(hvs)}", s, q, speed))
            s += rng.uniform(45.0, 160.0)
    return cavs, target, hvs, RoadSection((3.2,) * n_lanes)


def solve(scene, settings: PlannerSettings) -> dict:
    cavs, target, hvs, road = scene
    grid_settings = GridSettings()
    grid = build_grid(cavs, target, road, 0.0, SPEED_MPS, grid_settings)
    problem = build_problem(grid, cavs, hvs, target, 0.0, settings, grid_settings)
    plan = make_planner(settings).plan(problem)
    errors = validate_plan(problem, plan) if plan.ok else []
    passed = sum(path[-1][0] >= problem.goal_rows[-1] for path in plan.cells) if plan.ok else 0
    gap = None
    if plan.ok and plan.best_bound is not None and plan.objective:
        gap = max(0.0, (plan.objective - plan.best_bound) / abs(plan.objective))
    return {
        "backend": plan.backend,
        "status": plan.status.value,
        "objective": plan.objective,
        "best_bound": plan.best_bound,
        "gap": gap,
        "solve_ms": round(plan.solve_ms, 2),
        "build_ms": round(plan.build_ms, 2),
        "n_rows": problem.n_rows,
        "blockers": len(problem.blockers),
        "cavs_past": f"{passed}/{len(cavs)}",
        "valid": not errors,
    }


def percentile(values: list[float], q: float) -> float:
    ordered = sorted(values)
    index = min(len(ordered) - 1, max(0, round(q * (len(ordered) - 1))))
    return ordered[index]


def summarise(rows: list[dict]) -> str:
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault((row["group"], row["backend"]), []).append(row)
    lines = [
        "| scenes | backend | runs | median ms | p95 ms | max ms | optimal | feasible | "
        "infeasible | timeout | error | worst gap | invalid | CAVs past target |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (group, backend), items in groups.items():
        times = [r["solve_ms"] for r in items]
        counts = {s.value: sum(r["status"] == s.value for r in items) for s in PlanStatus}
        gaps = [r["gap"] for r in items if r["gap"] is not None]
        past = sum(int(r["cavs_past"].split("/")[0]) for r in items)
        total = sum(int(r["cavs_past"].split("/")[1]) for r in items)
        worst = f"{max(gaps):.2%}" if gaps else "-"
        lines.append(
            f"| {group} | {backend} | {len(items)} | {statistics.median(times):.1f} | "
            f"{percentile(times, 0.95):.1f} | {max(times):.1f} | {counts['optimal']} | "
            f"{counts['feasible']} | {counts['infeasible']} | {counts['timeout']} | "
            f"{counts['error']} | {worst} | {sum(not r['valid'] for r in items)} | "
            f"{past / total:.0%} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/bench/planner", help="path without extension")
    parser.add_argument("--quick", action="store_true", help="a few scenes, one backend run")
    parser.add_argument("--seeds", type=int, default=2, help="random scenes per (n, lanes)")
    parser.add_argument("--repeat", type=int, default=30, help="solves of the Figure 7 scene")
    parser.add_argument("--time-limit", type=float, default=1.0, help="per solve [s]")
    parser.add_argument("--backends", default="cp-sat,scip")
    args = parser.parse_args(argv)

    n_cavs_options, lanes_options, seeds, repeat = (2, 4, 6, 9, 12), (2, 3, 4, 5), args.seeds, 30
    if args.quick:
        n_cavs_options, lanes_options, seeds, repeat = (2, 6, 12), (3, 5), 1, 5
    repeat = args.repeat if not args.quick else repeat
    backends = args.backends.split(",")
    rows: list[dict] = []
    started = time.perf_counter()
    for backend in backends:
        settings = PlannerSettings(backend=backend, time_limit_s=args.time_limit)
        for run in range(repeat):
            rows.append({"group": "fig7 (6 CAV, 3 lanes)", "scene": f"fig7#{run}"})
            rows[-1].update(solve(fig7_scene(), settings))
        for n_cavs in n_cavs_options:
            for n_lanes in lanes_options:
                for seed in range(seeds):
                    rng = random.Random(1000 * n_cavs + 10 * n_lanes + seed)
                    scene = random_scene(n_cavs, n_lanes, rng)
                    group = f"{n_cavs} CAV, {n_lanes} lanes"
                    rows.append({"group": group, "scene": f"n{n_cavs}_l{n_lanes}_s{seed}"})
                    rows[-1].update(solve(scene, settings))
                    print(
                        f"{backend:7s} {group:16s} seed {seed}: {rows[-1]['status']:10s} "
                        f"{rows[-1]['solve_ms']:8.1f} ms",
                        file=sys.stderr,
                    )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fields = ["group", "scene", *[k for k in rows[0] if k not in ("group", "scene")]]
    with out.with_suffix(".csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)
    table = summarise(rows)
    # Per-size rows also pooled by CAV count, the figure the targets are stated in.
    pooled = [dict(r, group=r["group"].split(",")[0] + " (all lanes)") for r in rows]
    pooled = [r for r in pooled if not r["group"].startswith("fig7")]
    text = (
        f"Planner benchmark: `python tools/bench_planner.py {' '.join(argv or sys.argv[1:])}`"
        f"\n\nDefault settings, time limit {args.time_limit} s, one core, "
        f"{time.perf_counter() - started:.0f} s in all. Times are whole `plan()` calls "
        f"(model build included). 'CAVs past target': share of CAVs planned to end ahead "
        f"of the target's footprint.\n\n{table}\n\nPooled by CAV count:\n\n{summarise(pooled)}\n"
    )
    out.with_suffix(".md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
