"""The swarm of a code change against the swarm before it, on the same baseline runs.

A change to the swarm controller changes only its ``swarm`` runs; the ``cacc`` and ``sumo-lc``
runs of a finished batch stay valid. This copies such a batch without its swarm runs, resumes
the batch there (so only the swarm runs are made, with the code of ``--tree``), judges it with
the sweep's report tool and prints the scenes whose verdict or swarm mean speed changed:

    python tools/swarm_ab.py scenarios/variants.toml --before variants --out variants-new
    python tools/swarm_ab.py scenarios/stress2.toml --before stress2 --out stress2-new \\
        --tree /path/to/other/checkout

``--tree`` is the checkout whose ``sumo_swarm`` package runs (default: this one; a
``git worktree add DIR REV`` gives any commit). The batch and the report run in their own
processes with that tree first on ``PYTHONPATH``. Variant sweeps are judged by
tools/variants_report.py, stress sweeps (a sweep named ``stress*``) by tools/stress_report.py.
Half the runs of a full batch, and the two columns compared are the ones the issues judge.

Exit status: 0 when nothing changed, 1 when a scene changed, 2 on bad input.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
SPEED_TOLERANCE_MPS = 0.005  # mean speeds closer than this are the same run


def prepare(before: Path, out: Path) -> int:
    """Copy the finished batch ``before`` to ``out`` without its swarm runs and its reports;
    return how many swarm runs were left out. ``out`` must not exist."""
    if not (before / "runs").is_dir():
        raise ValueError(f"{before}: not a batch folder (no runs/)")
    if out.exists():
        raise ValueError(f"{out}: exists already")
    left_out = 0

    def ignore(folder: str, names: list[str]) -> list[str]:
        nonlocal left_out
        if Path(folder) == before / "runs":
            skipped = [n for n in names if n.startswith("swarm-")]
            left_out += len(skipped)
            return skipped
        if Path(folder) == before:
            return [n for n in names if n.startswith(("variants.", "stress.")) or n == "impact"]
        return []

    shutil.copytree(before, out, ignore=ignore)
    return left_out


def _keyed(table: pd.DataFrame) -> pd.DataFrame:
    """The report table with a ``scene`` column (a stress report numbers its rows)."""
    if "scene" in table.columns:
        return table
    return table.assign(scene=range(len(table)))


def verdict_column(table: pd.DataFrame) -> str:
    """The column holding a scene's overall verdict in a report table."""
    for name in ("all", "passes_where_sumo_lc_passes"):
        if name in table.columns:
            return name
    raise ValueError("the table has no verdict column ('all' or 'passes_where_sumo_lc_passes')")


def compare(before: pd.DataFrame, after: pd.DataFrame) -> tuple[dict[str, float], pd.DataFrame]:
    """Scene by scene, two report tables of the same sweep: the sweep's figures (scenes
    passing, mean swarm speed, before and after) and the scenes whose verdict changed or whose
    swarm mean speed moved by more than SPEED_TOLERANCE_MPS."""
    verdict = verdict_column(before)
    a, b = _keyed(before), _keyed(after)
    both = a.merge(b, on="scene", suffixes=("_before", "_after"))
    speed = both["mean_speed_mps_after"] - both["mean_speed_mps_before"]
    moved = speed.abs() > SPEED_TOLERANCE_MPS
    flipped = both[f"{verdict}_before"].astype(str) != both[f"{verdict}_after"].astype(str)
    rows = both[moved | flipped]
    changed = pd.DataFrame(
        {
            "scene": rows["scene"],
            "verdict_before": rows[f"{verdict}_before"],
            "verdict_after": rows[f"{verdict}_after"],
            "speed_before_mps": rows["mean_speed_mps_before"].round(3),
            "speed_after_mps": rows["mean_speed_mps_after"].round(3),
            "change_mps": speed[moved | flipped].round(3),
        }
    )

    def passing(table: pd.DataFrame) -> int:
        return int(table[verdict].astype(str).isin(["pass", "True"]).sum())

    figures = {
        "scenes": float(len(both)),
        "passing_before": float(passing(a)),
        "passing_after": float(passing(b)),
        "mean_speed_before_mps": float(a["mean_speed_mps"].mean()),
        "mean_speed_after_mps": float(b["mean_speed_mps"].mean()),
    }
    return figures, changed.reset_index(drop=True)


def _report(sweep_name: str, folder: Path, env: dict[str, str]) -> Path:
    """Judge ``folder`` with the sweep's report tool; the path of its CSV table."""
    stress = sweep_name.startswith("stress")
    tool = ROOT / "tools" / ("stress_report.py" if stress else "variants_report.py")
    subprocess.run([sys.executable, str(tool), str(folder)], env=env, capture_output=True)
    table = folder / ("stress.csv" if stress else "variants.csv")
    if not table.is_file():
        raise RuntimeError(f"{tool.name} wrote no {table.name} into {folder}")
    return table


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweep", type=Path, help="the sweep file the batch was made from")
    parser.add_argument("--before", type=Path, required=True, help="the finished batch folder")
    parser.add_argument("--out", type=Path, required=True, help="the new batch folder")
    parser.add_argument("--tree", type=Path, default=ROOT, help="the checkout to run")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args(argv)
    if not args.sweep.is_file():
        print(f"swarm_ab: {args.sweep}: no such sweep file", file=sys.stderr)
        return 2
    if not (args.tree / "sumo_swarm").is_dir():
        print(f"swarm_ab: {args.tree}: no sumo_swarm package there", file=sys.stderr)
        return 2
    try:
        left_out = prepare(args.before, args.out)
    except ValueError as exc:
        print(f"swarm_ab: {exc}", file=sys.stderr)
        return 2
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(args.tree.resolve()), env.get("PYTHONPATH", "")])
    batch = [sys.executable, "-m", "sumo_swarm.cli", "batch", str(args.sweep.resolve()),
             "--out", str(args.out.resolve()), "--workers", str(args.workers)]  # fmt: skip
    print(f"{left_out} swarm runs to make in {args.out} with {args.tree}", flush=True)
    # Run from the tree: "python -m" puts the working folder first on the path, before
    # PYTHONPATH (from another checkout its package would run instead).
    done = subprocess.run(batch, env=env, cwd=args.tree.resolve())
    if done.returncode not in (0, 1):
        print(f"swarm_ab: the batch failed (exit {done.returncode})", file=sys.stderr)
        return 2
    name = args.sweep.stem
    before_table = args.before / ("stress.csv" if name.startswith("stress") else "variants.csv")
    if not before_table.is_file():
        before_table = _report(name, args.before, env=dict(os.environ))
    after_table = _report(name, args.out, env)
    figures, changed = compare(pd.read_csv(before_table), pd.read_csv(after_table))
    print(
        f"scenes passing {figures['passing_before']:.0f} -> {figures['passing_after']:.0f} "
        f"of {figures['scenes']:.0f}; mean swarm speed {figures['mean_speed_before_mps']:.3f} "
        f"-> {figures['mean_speed_after_mps']:.3f} m/s; {len(changed)} scenes changed"
    )
    if len(changed):
        print(changed.to_markdown(index=False))
    return 1 if len(changed) else 0


if __name__ == "__main__":
    sys.exit(main())
