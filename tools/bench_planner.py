"""Benchmark the cell planner (not a test): solve time and optimality over random scenes.

Scenes: a platoon of ``n`` CAVs (15 m apart) in the middle lane behind a target HV, with HVs
placed at random (45 to 160 m apart front to front, speeds 17.5 +- 1 m/s) in every lane from
60 m behind the tail to 90 m ahead of the target (in the platoon's lane only ahead of the
target's 45 m); the Figure 7 scene of the paper is added and solved ``--repeat`` times cold
and ``--repeat`` times with the cold plan as a warm-start hint. Each scene is solved by every
backend on one core with the default planner settings. Times: ``wall`` is the whole
``plan()`` call (model build included), ``cpu`` the process time of that call (what the call
costs on one free core; the machine may be shared). Writes ``<out>.csv`` and ``<out>.md``
(median, p95, max, status counts, worst gap) and prints the markdown.

``--baseline DIR`` first runs the same benchmark on the code in ``DIR`` (e.g. an older commit
exported with ``git archive <commit> | tar -x -C DIR``) in a child process, then the current
code, and puts both side by side with their ratios (baseline / current).

    python tools/bench_planner.py                  # full run, docs/bench/planner.{csv,md}
    python tools/bench_planner.py --baseline /tmp/base --seeds 3
    python tools/bench_planner.py --quick --out /tmp/planner
    python tools/bench_planner.py --problems-only  # only the problems the swarm built

The problems the swarm really built (``--problems``, default
``tests/data/planner_problems.json.gz``, recorded by ``tools/collect_problems.py``: the paper
scene and three 12-CAV variants) are solved
with the warm-start hint the swarm gave, twice: ``before`` is CP-SAT alone as the swarm ran it
until now (``network_work = 0``, 1 s wall, work limit 0.25), ``after`` the default settings.
Their table gives median / p95 / max of wall and cpu per source, the statuses, and the
objectives against the best one known for each problem (either run's or the recorded run's).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import gzip
import json
import os
import random
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# The code under test: this checkout, or the baseline's when run as the --baseline child.
sys.path.insert(0, os.environ.get("SUMO_SWARM_BENCH_CODE", str(Path(__file__).parents[1])))

from sumo_swarm.core.grid import GridSettings, build_grid
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.planner import (
    Plan,
    PlannerSettings,
    PlanStatus,
    build_problem,
    make_planner,
    validate_plan,
)

SPEED_MPS = 17.5
CODE_ENV = "SUMO_SWARM_BENCH_CODE"
PROBLEMS = Path(__file__).parents[1] / "tests" / "data" / "planner_problems.json.gz"


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


def solve(scene, settings: PlannerSettings, warm: bool = False) -> dict:
    """Solve one scene; with ``warm`` solve it once first and pass that plan as the hint."""
    cavs, target, hvs, road = scene
    grid_settings = GridSettings()
    grid = build_grid(cavs, target, road, 0.0, SPEED_MPS, grid_settings)
    problem = build_problem(grid, cavs, hvs, target, 0.0, settings, grid_settings)
    planner = make_planner(settings)
    hint = planner.plan(problem) if warm else None
    cpu_started = time.process_time()
    plan = planner.plan(problem) if hint is None else planner.plan(problem, hint=hint)
    cpu_ms = (time.process_time() - cpu_started) * 1e3
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
        "cpu_ms": round(cpu_ms, 2),
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


def stats(values: list[float]) -> tuple[float, float, float]:
    """Median, p95 and max."""
    return statistics.median(values), percentile(values, 0.95), max(values)


def group_rows(rows: list[dict]) -> dict[tuple[str, str], list[dict]]:
    groups: dict[tuple[str, str], list[dict]] = {}
    for row in rows:
        groups.setdefault((row["group"], row["backend"]), []).append(row)
    return groups


def summarise(rows: list[dict]) -> str:
    lines = [
        "| scenes | backend | runs | wall median ms | wall p95 ms | wall max ms | cpu median ms "
        "| cpu p95 ms | cpu max ms | build median ms | optimal | feasible | infeasible | timeout "
        "| error | worst gap | invalid | CAVs past target |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (group, backend), items in group_rows(rows).items():
        wall = stats([r["solve_ms"] for r in items])
        cpu = stats([r["cpu_ms"] for r in items]) if "cpu_ms" in items[0] else (0.0,) * 3
        build = statistics.median(r["build_ms"] for r in items)
        counts = {s.value: sum(r["status"] == s.value for r in items) for s in PlanStatus}
        gaps = [r["gap"] for r in items if r["gap"] is not None]
        past = sum(int(r["cavs_past"].split("/")[0]) for r in items)
        total = sum(int(r["cavs_past"].split("/")[1]) for r in items)
        worst = f"{max(gaps):.2%}" if gaps else "-"
        lines.append(
            f"| {group} | {backend} | {len(items)} | "
            + " | ".join(f"{v:.1f}" for v in (*wall, *cpu, build))
            + f" | {counts['optimal']} | {counts['feasible']} | {counts['infeasible']} | "
            f"{counts['timeout']} | {counts['error']} | {worst} | "
            f"{sum(not r['valid'] for r in items)} | {past / total:.0%} |"
        )
    return "\n".join(lines)


def side_by_side(base: list[dict], current: list[dict]) -> str:
    """Wall (and cpu) median / p95 / max of baseline and current code, with ratios."""
    lines = [
        "| scenes | backend | measure | baseline median | p95 | max | current median | p95 | "
        "max | ratio median | p95 | max | optimal baseline / current |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    base_groups = group_rows(base)
    for key, items in group_rows(current).items():
        old = base_groups.get(key)
        if not old:
            continue
        for measure in ("solve_ms", "cpu_ms"):
            if measure not in old[0]:
                continue
            before, after = stats([r[measure] for r in old]), stats([r[measure] for r in items])
            ratios = [b / a if a else float("nan") for b, a in zip(before, after, strict=True)]
            optimal = (
                f"{sum(r['status'] == 'optimal' for r in old)}/{len(old)} / "
                f"{sum(r['status'] == 'optimal' for r in items)}/{len(items)}"
            )
            lines.append(
                f"| {key[0]} | {key[1]} | {'wall' if measure == 'solve_ms' else 'cpu'} | "
                + " | ".join(f"{v:.1f}" for v in (*before, *after))
                + " | "
                + " | ".join(f"{v:.2f}x" for v in ratios)
                + f" | {optimal} |"
            )
    return "\n".join(lines)


def run_scenes(args: argparse.Namespace) -> list[dict]:
    n_cavs_options, lanes_options, seeds, repeat = (2, 4, 6, 9, 12), (2, 3, 4, 5), args.seeds, 30
    if args.quick:
        n_cavs_options, lanes_options, seeds, repeat = (2, 6, 12), (3, 5), 1, 5
    repeat = args.repeat if not args.quick else repeat
    rows: list[dict] = []
    for backend in args.backends.split(","):
        settings = PlannerSettings(backend=backend, time_limit_s=args.time_limit)
        for warm in (False, True):
            group = "fig7 (6 CAV, 3 lanes)" + (", hinted" if warm else "")
            for run in range(repeat):
                rows.append({"group": group, "scene": f"fig7#{run}"})
                rows[-1].update(solve(fig7_scene(), settings, warm))
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
    return rows


def pooled(rows: list[dict]) -> list[dict]:
    """Random-scene rows pooled by CAV count, the figure the targets are stated in."""
    out = [dict(r, group=r["group"].split(",")[0] + " (all lanes)") for r in rows]
    return [r for r in out if not r["group"].startswith("fig7")]


def run_baseline(args: argparse.Namespace, argv: list[str]) -> list[dict]:
    """The same benchmark on the code in ``args.baseline``, in a child process."""
    child_argv = [a for a in argv if not a.startswith("--baseline")]
    if "--baseline" in argv:  # "--baseline DIR" as two words
        i = argv.index("--baseline")
        child_argv = argv[:i] + argv[i + 2 :]
    with tempfile.TemporaryDirectory() as tmp:
        rows_path = Path(tmp) / "rows.json"
        env = dict(os.environ, **{CODE_ENV: str(Path(args.baseline).resolve())})
        env["PYTHONDONTWRITEBYTECODE"] = "1"
        env["PYTHONPATH"] = env[CODE_ENV]
        command = [sys.executable, __file__, *child_argv, "--rows-json", str(rows_path)]
        subprocess.run(command, env=env, check=True, stdout=subprocess.DEVNULL)
        return json.loads(rows_path.read_text())


def _shown(path: str) -> str:
    """``path`` relative to the repository when it is inside it (for the report)."""
    try:
        return str(Path(path).resolve().relative_to(Path(__file__).parents[1].resolve()))
    except ValueError:
        return path


def load_problems(path: Path) -> list[dict]:
    """The stored problems (see tools/collect_problems.py), each with its hint as a Plan."""
    from sumo_swarm.core.planner.dump import problem_from_dict

    opener = gzip.open if path.suffix == ".gz" else open
    with opener(path, "rt") as handle:
        calls = json.load(handle)["calls"]
    out = []
    for call in calls:
        problem = problem_from_dict(call["problem"])
        hint = None
        if call["hint"]:
            cells = tuple(tuple((r, c) for r, c in path) for path in call["hint"])
            hint = Plan(PlanStatus.OPTIMAL, cells, None, 0.0, "hint", cav_ids=problem.cav_ids)
        out.append({**call, "problem": problem, "hint": hint})
    return out


def run_problems(args: argparse.Namespace) -> list[dict]:
    """Every stored problem solved before (CP-SAT alone) and after (the defaults)."""
    settings = {
        "before": PlannerSettings(network_work=0, time_limit_s=args.time_limit),
        "after": dataclasses.replace(PlannerSettings(), time_limit_s=args.time_limit),
    }
    rows = []
    for i, call in enumerate(load_problems(Path(args.problems))):
        problem = call["problem"]
        for code, config in settings.items():
            planner = make_planner(config)
            cpu_started = time.process_time()
            plan = planner.plan(problem, hint=call["hint"])
            cpu_ms = (time.process_time() - cpu_started) * 1e3
            rows.append({
                "code": code, "source": call["source"], "index": i, "cavs": problem.n_cavs,
                "status": plan.status.value, "objective": plan.objective,
                "best_bound": plan.best_bound, "solve_ms": round(plan.solve_ms, 2),
                "cpu_ms": round(cpu_ms, 2), "build_ms": round(plan.build_ms, 2),
                "valid": not validate_plan(problem, plan) if plan.ok else True,
                "run_objective": call["run_objective"],
            })  # fmt: skip
        print(f"problem {i:2d} {call['source']}: " + ", ".join(
            f"{r['code']} {r['status']} {r['solve_ms']:.0f} ms" for r in rows[-2:]
        ), file=sys.stderr)  # fmt: skip
    return rows


def summarise_problems(rows: list[dict]) -> str:
    """Before / after per source and over all problems: times, statuses, objectives."""
    best: dict[int, float] = {}
    for r in rows:
        for value in (r["objective"], r["run_objective"]):
            if value is not None:
                best[r["index"]] = min(best.get(r["index"], value), value)
    lines = [
        "| problems | code | n | wall median ms | wall p95 ms | wall max ms | cpu median ms | "
        "cpu p95 ms | cpu max ms | optimal | feasible | infeasible | timeout | error | "
        "invalid | at best known | worst excess over best known |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    sources = [*dict.fromkeys(r["source"] for r in rows), "all"]
    for source in sources:
        for code in ("before", "after"):
            items = [r for r in rows if r["code"] == code and source in ("all", r["source"])]
            if not items:
                continue
            wall = stats([r["solve_ms"] for r in items])
            cpu = stats([r["cpu_ms"] for r in items])
            counts = {s.value: sum(r["status"] == s.value for r in items) for s in PlanStatus}
            with_plan = [r for r in items if r["objective"] is not None]
            at_best = sum(r["objective"] <= best[r["index"]] + 1e-9 for r in with_plan)
            excess = [
                (r["objective"] - best[r["index"]]) / abs(best[r["index"]])
                for r in with_plan
                if best[r["index"]]
            ]
            lines.append(
                f"| {source} | {code} | {len(items)} | "
                + " | ".join(f"{v:.1f}" for v in (*wall, *cpu))
                + f" | {counts['optimal']} | {counts['feasible']} | {counts['infeasible']} | "
                f"{counts['timeout']} | {counts['error']} | "
                f"{sum(not r['valid'] for r in items)} | {at_best}/{len(with_plan)} | "
                f"{max(excess, default=0.0):.2%} |"
            )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="docs/bench/planner", help="path without extension")
    parser.add_argument("--quick", action="store_true", help="a few scenes, one backend run")
    parser.add_argument("--seeds", type=int, default=2, help="random scenes per (n, lanes)")
    parser.add_argument("--repeat", type=int, default=30, help="solves of the Figure 7 scene")
    parser.add_argument("--time-limit", type=float, default=1.0, help="per solve [s]")
    parser.add_argument("--backends", default="cp-sat,scip")
    parser.add_argument("--baseline", help="directory with older code to compare against")
    parser.add_argument("--rows-json", help=argparse.SUPPRESS)  # the baseline child's output
    parser.add_argument("--problems", default=str(PROBLEMS), help="stored problems to solve")
    parser.add_argument(
        "--problems-only", action="store_true", help="only the stored problems, no scenes"
    )
    args = parser.parse_args(argv)
    if args.problems_only:
        started = time.perf_counter()
        load_before = os.getloadavg()[0]
        rows = run_problems(args)
        text = (
            f"Stored problems: `python tools/bench_planner.py {' '.join(argv)}`\n\n"
            f"{time.perf_counter() - started:.0f} s in all, load average {load_before:.1f} "
            f"before and {os.getloadavg()[0]:.1f} after on {os.cpu_count()} cores.\n\n"
            f"{summarise_problems(rows)}\n"
        )
        out = Path(args.out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.with_suffix(".md").write_text(text)
        print(text)
        return 0

    started = time.perf_counter()
    load_before = os.getloadavg()[0]
    base_rows = run_baseline(args, argv) if args.baseline else []
    rows = run_scenes(args)
    if args.rows_json:
        Path(args.rows_json).write_text(json.dumps(rows))
        return 0
    load_after = os.getloadavg()[0]
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fields = ["group", "scene", *[k for k in rows[0] if k not in ("group", "scene")]]
    with out.with_suffix(".csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=["code", *fields])
        writer.writeheader()
        writer.writerows({"code": "current", **r} for r in rows)
        writer.writerows({"code": "baseline", **r} for r in base_rows)
    text = (
        f"Planner benchmark: `python tools/bench_planner.py {' '.join(argv)}`\n\n"
        f"Default settings, time limit {args.time_limit} s, one core, "
        f"{time.perf_counter() - started:.0f} s in all, load average {load_before:.1f} before "
        f"and {load_after:.1f} after on {os.cpu_count()} cores. 'wall': whole `plan()` "
        f"calls (model build included); 'cpu': process time of the call (on a shared machine "
        f"wall exceeds cpu by the time the process waited for a core). 'CAVs past target': "
        f"share of CAVs planned to end ahead of the target's footprint.\n\n"
    )
    if base_rows:
        text += (
            f"Baseline (`{args.baseline}`) against the current code, ratio = baseline / "
            f"current:\n\n{side_by_side(base_rows, rows)}\n\n"
            f"Pooled by CAV count:\n\n{side_by_side(pooled(base_rows), pooled(rows))}\n\n"
            f"Current code in full:\n\n"
        )
    text += f"{summarise(rows)}\n\nPooled by CAV count:\n\n{summarise(pooled(rows))}\n"
    if not args.rows_json and args.problems:
        text += (
            f"\nProblems the swarm built (`{_shown(args.problems)}`), before (CP-SAT alone) and "
            f"after "
            f"(the defaults), each with the run's warm-start hint:\n\n"
            f"{summarise_problems(run_problems(args))}\n"
        )
    out.with_suffix(".md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
