"""Users' roads side by side: each road of ``sumo_swarm.sim.userroads`` under each controller.

Every run is what a user types, one process each (libsumo holds one simulation per process)::

    sumo-swarm run --sumocfg ROAD/user.sumocfg --cav-type cav --controller C --out ROAD/C

Each road is run at the step length 0.1 s and at SUMO's default 1 s (no step-length in the
sumocfg); a run that the swarm refuses (exit status 2) is recorded as "refused" with its message.
Prints and writes a table per road and step (``--table``: Markdown + CSV) with the commit the
figures came from; with ``--seeds`` every run is repeated under each of SUMO's seeds (other
draws of the same traffic, scenes the swarm was not tuned on) and a summary over the seeds
follows the tables::

    python tools/user_roads.py [--roads NAME ...] [--seeds N ...] [--out DIR] [--end S]
                               [--workers N]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import time
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # run from a checkout: this tree's package, not an installed one

from sumo_swarm.sim.metrics import hard_brake_events  # noqa: E402
from sumo_swarm.sim.userroads import (  # noqa: E402
    CAV_TYPE,
    MORE_ROADS,
    ROADS,
    user_road,
    write_road,
)

CONTROLLERS = ("swarm", "cacc", "sumo-cacc", "sumo-lc")
# Step lengths [s]; None is SUMO's default (1 s): the sumocfg does not name a step.
DEFAULT_STEP = "1 (default)"  # SUMO's own step: the configuration names none
STEPS: dict[str, float | None] = {"0.1": 0.1, "0.5": 0.5, DEFAULT_STEP: None}
EXIT_BAD_INPUT = 2
# SUMO's warning for a collision: "Warning: Vehicle 'a'; collision with vehicle 'b', lane=...".
COLLISION_WARNING = "collision with"


@dataclass(frozen=True)
class Job:
    road: str
    step: str
    controller: str
    cfg: Path
    out: Path
    seed: int | None = None  # SUMO's seed; None: the configuration's


def run_job(job: Job, timeout_s: float) -> dict[str, Any]:
    """Run one job as a user would (``sumo-swarm run``); return its table row."""
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    }
    cmd = [
        sys.executable, "-m", "sumo_swarm", "run", "--sumocfg", str(job.cfg),
        "--cav-type", CAV_TYPE, "--controller", job.controller, "--out", str(job.out),
    ]  # fmt: skip
    if job.seed is not None:
        cmd += ["--seed", str(job.seed)]
    row: dict[str, Any] = {"road": job.road, "step_s": job.step, "controller": job.controller}
    row["seed"] = seed_name(job.seed)
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s, env=env)
    except subprocess.TimeoutExpired:
        row.update(status="timeout", process_s=round(time.perf_counter() - t0, 1))
        return row
    row["process_s"] = round(time.perf_counter() - t0, 1)
    job.out.mkdir(parents=True, exist_ok=True)
    (job.out / "run.log").write_text(proc.stdout + proc.stderr, encoding="utf-8")
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    if proc.returncode == EXIT_BAD_INPUT:
        row.update(status="refused", message=lines[-1] if lines else "")
        return row
    if proc.returncode != 0:
        row.update(status=f"failed ({proc.returncode})", message=lines[-1] if lines else "")
        return row
    row["status"] = "ok"
    row.update(summary_row(job.out))
    row["collision_lines"] = [line for line in lines if COLLISION_WARNING in line]
    return row


def summary_row(run_dir: Path) -> dict[str, Any]:
    """The measures of one finished run, from its summary, trajectories and events."""
    s = json.loads((run_dir / "summary.json").read_text(encoding="utf-8"))
    ot = s["overtake"]
    df = pd.read_parquet(run_dir / "trajectories.parquet")
    cav = df[df["kind"] == "cav"]
    brakes = hard_brake_events(cav)
    passed, ahead_at_end = cavs_past_truck(df)
    ends = [
        e.get("reason", "")
        for e in _events(run_dir / "events.jsonl")
        if e.get("event") in ("overtake_end", "target_left")
    ]
    return {
        "cav_count": s["cav"]["count"],
        "cav_mean_speed_mps": s["cav"]["mean_speed_mps"],
        "cav_gap_min_m": s["cav"]["gap_min_m"],
        "cav_min_accel_mps2": float(cav["accel_mps2"].min()) if len(cav) else math.nan,
        "collisions": s["safety"]["collisions"],
        "hard_brakes": s["safety"]["hard_brakes"],
        "hard_brakes_cav": int(brakes["vehicle"].nunique()),
        "cavs_passed_truck": passed,
        "cavs_ahead_at_end": ahead_at_end,
        "triggered": ot["triggered"],
        "target": ot["target"],
        "completed": ot["completed"],
        "regrouped": ot["regrouped"],
        "aborted": ot.get("aborted", 0),
        "abort_reasons": ";".join(f"{k}:{v}" for k, v in (ot.get("abort_reasons") or {}).items()),
        "end_reasons": ";".join(r for r in ends if r),
        "planner_solves": s["planner"]["solves"],
        "planner_p95_ms": s["planner"]["solve_ms_p95"],
        "planner_max_ms": s["planner"]["solve_ms_max"],
        "wall_s": s["timing"]["wall_s"],
        "controller_s": s["timing"]["controller_s"],
        "hard_brake_episodes_cav": brake_lines(brakes),
    }


def brake_lines(episodes: pd.DataFrame) -> list[str]:
    """One line per vehicle: its hard-braking episodes, when, and the strongest [m/s^2]."""
    lines = []
    for vid, eps in episodes.groupby("vehicle", sort=False):
        lines.append(
            f"{vid}: {len(eps)} episode(s), {eps['start_s'].min():.1f}-{eps['end_s'].max():.1f} s, "
            f"strongest {eps['min_accel_mps2'].min():.2f} m/s^2"
        )
    return lines


def cavs_past_truck(df: pd.DataFrame, truck: str = "truck") -> tuple[int, int]:
    """CAVs that were ever ahead of the truck (front bumpers, distance along the route, at the
    same step), and those ahead of it at the last step both were in the simulation."""
    s_m = df.pivot_table(index="time_s", columns="vehicle", values="s_m")
    if truck not in s_m:
        return 0, 0
    cavs = [v for v in df.loc[df["kind"] == "cav", "vehicle"].unique() if v in s_m]
    ever = last = 0
    for vid in cavs:
        both = s_m[[vid, truck]].dropna()
        if both.empty:
            continue
        ahead = both[vid] > both[truck]
        ever += bool(ahead.any())
        last += bool(ahead.iloc[-1])
    return ever, last


def _events(path: Path) -> Iterable[dict[str, Any]]:
    if not path.is_file():
        return []
    return [json.loads(line) for line in path.read_text(encoding="utf-8").splitlines() if line]


def seed_name(seed: int | None) -> str:
    """How a seed shows in the table: its number, or the configuration's own."""
    return "sumocfg" if seed is None else str(seed)


def over_seeds(df: pd.DataFrame) -> pd.DataFrame:
    """Per road and step, over the seeds: the swarm's CAV mean speed against sumo-lc's and
    sumo-cacc's (mean and lowest ratio), how many runs had every CAV past the truck and
    regrouped, and the collisions and CAV hard brakes of the swarm's runs."""
    out = []
    for (road, step), rows in df.groupby(["road", "step_s"], sort=False):
        per_seed = [ratios(r) for _, r in rows.groupby("seed", sort=False)]
        swarm = rows[(rows["controller"] == "swarm") & (rows["status"] == "ok")]
        if swarm.empty:
            continue
        lc = pd.Series([r["speed swarm/sumo-lc"] for r in per_seed], dtype=float)
        cacc = pd.Series([r["speed swarm/sumo-cacc"] for r in per_seed], dtype=float)
        passed = swarm["cavs_passed_truck"] >= swarm["cav_count"]
        out.append({
            "road": road, "step [s]": step, "seeds": len(per_seed),
            "swarm/sumo-lc mean": lc.mean(), "swarm/sumo-lc min": lc.min(),
            "runs >= 0.9x sumo-lc": int((lc >= 0.9).sum()),
            "swarm/sumo-cacc min": cacc.min(),
            "all past and regrouped": int((passed & swarm["regrouped"].astype(bool)).sum()),
            "collisions": int(swarm["collisions"].sum()),
            "CAV hard brakes": int(swarm["hard_brakes_cav"].sum()),
        })  # fmt: skip
    return pd.DataFrame(out)


def ratios(rows: pd.DataFrame) -> dict[str, float]:
    """swarm / sumo-cacc and swarm / sumo-lc CAV mean speed, swarm / sumo-cacc wall time."""
    ok = rows[rows["status"] == "ok"].set_index("controller")

    def ratio(col: str, a: str, b: str) -> float:
        if a in ok.index and b in ok.index and ok.at[b, col]:
            return float(ok.at[a, col] / ok.at[b, col])
        return math.nan

    return {
        "speed swarm/sumo-cacc": ratio("cav_mean_speed_mps", "swarm", "sumo-cacc"),
        "speed swarm/sumo-lc": ratio("cav_mean_speed_mps", "swarm", "sumo-lc"),
        "wall swarm/sumo-cacc": ratio("wall_s", "swarm", "sumo-cacc"),
    }


TABLE_COLUMNS = {
    "controller": "controller",
    "status": "status",
    "cav_mean_speed_mps": "CAV mean speed [m/s]",
    "collisions": "collisions",
    "hard_brakes": "hard brakes (all)",
    "hard_brakes_cav": "hard brakes (CAV)",
    "cav_min_accel_mps2": "CAV min accel [m/s^2]",
    "cav_gap_min_m": "min CAV gap [m]",
    "cavs_passed_truck": "CAVs past truck",
    "cavs_ahead_at_end": "ahead at end",
    "completed": "completed",
    "regrouped": "regrouped",
    "aborted": "aborted",
    "abort_reasons": "abort reasons",
    "planner_p95_ms": "planner p95 [ms]",
    "planner_max_ms": "planner max [ms]",
    "wall_s": "wall [s]",
    "controller_s": "controller [s]",
}


def markdown(df: pd.DataFrame, command: str, end_s: float) -> str:
    """The report: a table per road and step, ratios below it, then every failure seen."""
    out = [
        "# Users' roads: swarm, cacc, sumo-cacc and sumo-lc side by side",
        "",
        f"Runs at commit {', '.join(f'`{c}`' for c in df['commit'].unique())}, "
        f"report by `{command}`; {end_s:g} s simulated per run, SUMO's seed "
        f"{', '.join(df['seed'].astype(str).unique())}. Roads "
        "(sumo_swarm/sim/userroads.py), written as a new user would: SUMO's default vType for "
        'the traffic, `<flow>` with `departLane="best"` and `departSpeed="max"`, a truck at '
        '15 m/s ahead of 5 CAVs (vType `cav`, SUMO\'s defaults but `sigma="0"`) in the same '
        "lane; `sumo-swarm run --sumocfg ... --cav-type cav` per run.",
        "",
        "Measures: CAV mean speed, collisions, hard brakes (vehicles braking harder than "
        "4 m/s^2), min CAV gap and the overtake flags are the run's summary.json; CAV min "
        "accel and the CAVs ever past the truck (and still ahead of it when both were last "
        "seen) come from trajectories.parquet; planner p95/max are the MIP solves alone "
        "(summary `planner`), wall and controller seconds the run's `timing` (SUMO start-up "
        "excluded). A run the CLI refuses (exit 2) is `refused`.",
        "",
    ]
    for (road, step, seed), rows in df.groupby(["road", "step_s", "seed"], sort=False):
        title = f"## {road}, step {step} s" + ("" if seed == "sumocfg" else f", seed {seed}")
        out += [title, "", f"{user_road(road).about}.", ""]
        table = rows.reindex(columns=list(TABLE_COLUMNS)).rename(columns=TABLE_COLUMNS)
        out += [table.to_markdown(index=False, floatfmt=".2f"), ""]
        out += [", ".join(f"{k}: {v:.2f}" for k, v in ratios(rows).items()), ""]
    failures = []
    for row in df.itertuples():
        what = []
        if row.status not in ("ok", "refused"):
            what.append(f"{row.status}: {getattr(row, 'message', '')}")
        if row.status == "refused":
            what.append(f"refused: {getattr(row, 'message', '')}")
        collisions = getattr(row, "collision_lines", None)
        if isinstance(collisions, list):
            what += collisions
        brakes = getattr(row, "hard_brake_episodes_cav", None)
        if isinstance(brakes, list):
            what += [f"CAV hard brake {e}" for e in brakes]
        if what:
            failures.append(f"- {row.road}, step {row.step_s} s, {row.controller}:")
            failures += [f"  - {w}" for w in what]
    out += ["## Collisions, CAV hard brakes, refusals", "", *(failures or ["None."]), ""]
    if df["seed"].nunique() > 1:
        out += ["## Over the seeds", ""]
        out += [over_seeds(df).to_markdown(index=False, floatfmt=".2f"), ""]
    return "\n".join(out)


def report_again(jobs: list[Job], csv: Path) -> pd.DataFrame:
    """The rows of ``csv`` (runs made earlier, with their commit, status and process time)
    with every measure read again from the run folders."""
    old = pd.read_csv(csv, dtype={"step_s": str, "seed": str})
    if "seed" not in old:
        old["seed"] = seed_name(None)
    old = old.set_index(["road", "step_s", "controller", "seed"])
    rows = []
    for job in jobs:
        prev = old.loc[(job.road, job.step, job.controller, seed_name(job.seed))]
        row = {"commit": prev["commit"], "road": job.road, "step_s": job.step}
        row["seed"] = seed_name(job.seed)
        row.update(controller=job.controller, process_s=prev["process_s"], status=prev["status"])
        if "message" in prev and isinstance(prev["message"], str):
            row["message"] = prev["message"]
        if row["status"] == "ok":
            row.update(summary_row(job.out))
            log = (job.out / "run.log").read_text(encoding="utf-8").splitlines()
            row["collision_lines"] = [line for line in log if COLLISION_WARNING in line]
        rows.append(row)
    return pd.DataFrame(rows)


def table_file(table: Path, ext: str) -> Path:
    """``table`` (a path without its extension, as ``--table`` takes it) with ``ext``
    (".md", ".csv", ".runs.csv"): a dot in the name stays ("cost0.5" gives "cost0.5.md", not
    "cost0.md"); an extension given (".md" or ".csv") is replaced."""
    name = table.name
    for known in (".runs.csv", ".md", ".csv"):
        if name.endswith(known):
            name = name[: -len(known)]
            break
    return table.with_name(name + ext)


def git_commit() -> str:
    """The commit of this checkout, ``+dirty`` when tracked files differ from it."""
    rev = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True, text=True
    ).stdout.strip()
    dirty = subprocess.run(
        ["git", "status", "--porcelain", "--untracked-files=no"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    ).stdout.strip()
    return rev + ("+dirty" if dirty else "")


def _step_name(text: str) -> str:
    """``--steps``' name of a step: 1 (or 1.0) is SUMO's default."""
    try:
        return DEFAULT_STEP if float(text) == 1.0 else text
    except ValueError:
        return text


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--roads",
        nargs="+",
        choices=sorted([*ROADS, *MORE_ROADS]),
        default=list(ROADS),
        help="default: the first set; the second (MORE_ROADS): " + " ".join(MORE_ROADS),
    )
    ap.add_argument("--controllers", nargs="+", choices=CONTROLLERS, default=list(CONTROLLERS))
    ap.add_argument("--steps", nargs="+", choices=list(STEPS), default=list(STEPS),
                    type=_step_name, metavar="STEP",
                    help="SUMO step lengths [s]: 0.1, 0.5, or 1 (SUMO's default)")  # fmt: skip
    ap.add_argument("--end", type=float, default=90.0, help="simulated seconds per run")
    ap.add_argument(
        "--seeds", nargs="+", type=int, default=None,
        help="run each road under each of these SUMO seeds (default: the configuration's)",
    )  # fmt: skip
    ap.add_argument("--out", type=Path, default=Path("/tmp/user_roads"), help="run folders")
    ap.add_argument("--workers", type=int, default=1, help="runs at once (one process each)")
    ap.add_argument("--timeout", type=float, default=3600.0, help="per run [s] of wall time")
    ap.add_argument(
        "--table",
        type=Path,
        default=ROOT / "docs" / "bench" / "user_roads",
        help="write TABLE.md and TABLE.csv (default docs/bench/user_roads)",
    )
    ap.add_argument(
        "--report-only",
        action="store_true",
        help="rebuild the report from the run folders of TABLE.csv's runs, without running",
    )
    args = ap.parse_args(argv)
    jobs = []
    for road in args.roads:
        for step_name in args.steps:
            step = STEPS[step_name]
            folder = args.out / road / (f"step-{step:g}" if step else "step-default")
            cfg = folder / "user.sumocfg"
            if not args.report_only:
                write_road(road, folder, end_s=args.end, step_length_s=STEPS[step_name])
            for seed in args.seeds or [None]:
                base = folder if seed is None else folder / f"seed-{seed}"
                jobs += [Job(road, step_name, c, cfg, base / c, seed) for c in args.controllers]
    # The slowest runs (the swarm at 0.1 s) first, so that the workers finish together.
    if args.report_only:
        df = report_again(jobs, table_file(args.table, ".csv"))
    else:
        order = sorted(jobs, key=lambda j: (j.controller != "swarm", j.step != "0.1"))
        with ThreadPoolExecutor(max_workers=max(1, args.workers)) as pool:
            runs = pool.map(lambda j: run_job(j, args.timeout), order)
            done = dict(zip(order, runs, strict=True))
        df = pd.DataFrame([done[j] for j in jobs])
        df.insert(0, "commit", git_commit())
    command = "python tools/user_roads.py " + " ".join(argv if argv is not None else sys.argv[1:])
    text = markdown(df, command.strip(), args.end)
    print(text)
    args.table.parent.mkdir(parents=True, exist_ok=True)
    table_file(args.table, ".md").write_text(text, encoding="utf-8")
    csv = df.copy()
    for col in ("collision_lines", "hard_brake_episodes_cav"):
        if col in csv:
            csv[col] = csv[col].map(lambda v: " | ".join(v) if isinstance(v, list) else "")
    csv.to_csv(table_file(args.table, ".csv"), index=False)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
