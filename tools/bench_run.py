"""Benchmark: the cost of a whole `swarm` run against the `cacc` run of the same scenario.

Runs the two controllers alternately (so both see the same machine load), each run in its own
process (libsumo holds one simulation per process), and prints and saves a table of wall time
(median, p95, max), the swarm/cacc ratio, and the MPC's solve time per CAV.

With ``--sweep FILE --cases 3,29``: those cases of a sweep file (e.g. scenarios/variants.toml)
instead, one after the other, each ``--repeats`` times with cacc and swarm alternated, one run
at a time: the run cost of issue 11 ("a run costing <= 3x a cacc run") measured the way a
batch cannot, where the two runs of a scene are minutes apart and share the 2 cores with
whatever the other worker runs (the same scene's ratio went 2.1x in one batch, 3.7x in the
next). The table gives per case the process-time ratio (``timing.cpu_s``: SUMO and controller,
the loop's CPU) and the wall ratio, median / p95 / max over the repeats.

Usage: python tools/bench_run.py [--repeats 5] [--scenario scenarios/paper.toml]
                                 [--out docs/bench/run]
       python tools/bench_run.py --sweep scenarios/variants.toml --cases 3,29 [--repeats 3]
                                 [--out docs/bench/run_variants]
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import subprocess
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd

from sumo_swarm.errors import ConfigError
from sumo_swarm.sim.runner import run_scenario
from sumo_swarm.study.batch import find_case

ROOT = Path(__file__).resolve().parent.parent


def one_run(scenario: Path, controller: str) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            [sys.executable, "-m", "sumo_swarm", "run", str(scenario), "--controller",
             controller, "--out", tmp],
            check=True, capture_output=True,
        )  # fmt: skip
        return json.loads((Path(tmp) / "summary.json").read_text())


def case_run(sweep_path: str, case: int, controller: str) -> dict:
    """One run of case ``case`` of a sweep file under ``controller`` (call it in a fresh
    process: libsumo holds one simulation per process); its summary."""
    spec = find_case(sweep_path, case, controller)
    with tempfile.TemporaryDirectory() as tmp:
        return run_scenario(spec.scenario(), controller, tmp, seed=spec.seed, progress=False)


def bench_cases(sweep: Path, cases: dict[int, int], repeats: int, out: Path) -> int:
    """The ``--sweep`` benchmark (module docstring) of ``cases`` (index -> CAV count): prints
    and saves the table."""
    context = multiprocessing.get_context("spawn")
    rows = []
    for case in cases:
        for i in range(repeats):
            for controller in ("cacc", "swarm"):
                with ProcessPoolExecutor(1, mp_context=context) as pool:
                    s = pool.submit(case_run, str(sweep), case, controller).result()
                t = s["timing"]
                rows.append({"case": case, "repeat": i, "controller": controller,
                             "cavs": cases[case], **t})  # fmt: skip
                print(f"case {case} run {i} {controller:6s} cpu {t['cpu_s']:.2f} s "
                      f"wall {t['wall_s']:.2f} s", flush=True)  # fmt: skip
    df = pd.DataFrame(rows)
    table = []
    for case in cases:
        sub = df[df["case"] == case]
        swarm, cacc = sub[sub.controller == "swarm"], sub[sub.controller == "cacc"]
        for measure, key in (("cpu ratio", "cpu_s"), ("wall ratio", "wall_s")):
            ratio = swarm[key].to_numpy() / cacc[key].to_numpy()
            table.append({"case": case, "measure": measure, **stats(list(ratio))})
        table.append({"case": case, "measure": "swarm cpu_s", **stats(list(swarm["cpu_s"]))})
        table.append({"case": case, "measure": "cacc cpu_s", **stats(list(cacc["cpu_s"]))})
    result = pd.DataFrame(table)
    out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(out.with_suffix(".runs.csv"), index=False)
    result.to_csv(out.with_suffix(".csv"), index=False)
    head = (f"Run cost, cases {', '.join(map(str, cases))} of {_shown(sweep)}, {repeats} repeats "
            "(cacc and swarm alternated, one run at a time): "
            f"`python tools/bench_run.py --sweep {_shown(sweep)} --cases "
            f"{','.join(map(str, cases))} --repeats {repeats}`\n\n")  # fmt: skip
    md = result.to_markdown(index=False, floatfmt=".2f") if _has_tabulate() else result.to_string()
    out.with_suffix(".md").write_text(head + md + "\n", encoding="utf-8")
    print(md)
    return 0


def _shown(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(ROOT))
    except ValueError:
        return str(path)


def stats(values: list[float]) -> dict[str, float]:
    a = np.asarray(values, dtype=float)
    return {"median": float(np.median(a)), "p95": float(np.percentile(a, 95)), "max": a.max()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--scenario", type=Path, default=ROOT / "scenarios" / "paper.toml")
    parser.add_argument("--out", type=Path, default=None,
                        help="path without extension (default docs/bench/run, with --sweep "
                             "docs/bench/run_variants)")  # fmt: skip
    parser.add_argument("--sweep", type=Path, help="a sweep file: bench its --cases instead")
    parser.add_argument("--cases", default="", help="with --sweep: case indices, e.g. 3,29")
    args = parser.parse_args(argv)
    if args.sweep is not None:
        try:
            cases = [int(c) for c in args.cases.split(",") if c.strip()]
        except ValueError:
            parser.error(f"--cases: expected indices like 3,29, got {args.cases!r}")
        if not cases:
            parser.error("--sweep needs --cases")
        try:
            counts = {c: find_case(args.sweep, c).params.get("cav.count") for c in cases}
        except ConfigError as exc:
            parser.error(f"--sweep: {exc}")
        out = args.out or ROOT / "docs" / "bench" / "run_variants"
        return bench_cases(args.sweep, counts, args.repeats, out)
    args.out = args.out or ROOT / "docs" / "bench" / "run"
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
