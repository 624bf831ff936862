"""Where a run's time goes: one ``sumo-swarm run`` under cProfile, its time split by part.

Runs the command line given after ``--`` in this process (``python -m sumo_swarm`` minus the
interpreter), profiled, and prints and saves a table of each part's cumulative time: SUMO's
steps, reading the states, recording, finishing, the controllers and what they spend it on
(the fleet's membership reviews, the cell plans, cruising, following a plan, setting up the
MPCs), the step-safety net and the imports. Parts nest (the plans are part of the
controllers); the share is of the whole run.

cProfile charges every Python call a little, so the Python parts count about 1.5-2x more
against SUMO's steps than in a run without it: compare parts of one profile, or one part
between two commits, not a part against the run's timing in summary.json.

Usage: python tools/profile_run.py [--out docs/bench/profile] -- run SCENARIO.toml
                                   --controller swarm --seed 42 --out DIR
"""

from __future__ import annotations

import argparse
import cProfile
import importlib
import inspect
import pstats
import subprocess
import sys
from pathlib import Path
from typing import Any

import pandas as pd

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))  # run from a checkout: this tree's package, not an installed one

# (part, the functions whose cumulative time it is, as "module:qualified name"). Parts nest
# (the controllers' parts are theirs); a part's functions do not call each other.
PARTS: tuple[tuple[str, tuple[str, ...]], ...] = (
    ("SUMO's steps", ("libsumo.libsumo:simulation.step",)),
    ("reading the states", ("sumo_swarm.sim.bridge:SumoSession.refresh",)),
    ("recording", ("sumo_swarm.sim.recorder:RunRecorder.record",)),
    ("finishing (summary, outputs)", ("sumo_swarm.sim.recorder:RunRecorder.finish",)),
    ("controllers", ("sumo_swarm.controllers.base:StandDown.control",)),
    ("controllers: membership reviews", ("sumo_swarm.controllers.fleet:Fleet._review",)),
    ("controllers: deciding", ("sumo_swarm.controllers.swarm:SwarmController._cruise_decision",)),
    ("controllers: cell plans", ("sumo_swarm.controllers.replanner:Replanner.replan",)),
    ("controllers: cruising", ("sumo_swarm.controllers.cruise:Cruiser.step",)),
    ("controllers: following a plan", ("sumo_swarm.controllers.follower:PlanFollower.drive",)),
    ("controllers: MPC set-up", ("sumo_swarm.core.tracking:_ChainQp.__init__",)),
    ("step-safety net (SUMO steps > tau)", ("sumo_swarm.sim.bridge:SumoSession.flush_commands",)),
)
IMPORTS = ("<frozen importlib._bootstrap>", "_find_and_load")  # pstats' key of an import


def _key(spec: str) -> tuple[str, int, str]:
    """pstats' key (file, first line, name) of the function ``module:qualified.name``."""
    module_name, qualname = spec.split(":")
    obj: Any = importlib.import_module(module_name)
    for name in qualname.split("."):
        obj = getattr(obj, name)
    obj = inspect.unwrap(obj)
    code = obj.__code__
    return code.co_filename, code.co_firstlineno, code.co_name


def part_times(stats: pstats.Stats) -> list[tuple[str, float]]:
    """Each part of :data:`PARTS`, and the imports, with its cumulative time [s] in ``stats``."""
    # stats.stats: {(file, line, function): (calls, primitive calls, tottime, cumtime, callers)}
    table = stats.stats  # type: ignore[attr-defined]
    out = []
    for name, functions in PARTS:
        keys = [_key(spec) for spec in functions]
        out.append((name, sum(table[k][3] for k in keys if k in table)))
    imports = sum(row[3] for (file, _, func), row in table.items() if (file, func) == IMPORTS)
    out.append(("imports", imports))
    return out


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if "--" not in argv:
        print("profile_run: give the run's arguments after --, e.g. -- run corridor.toml "
              "--controller swarm --out DIR", file=sys.stderr)  # fmt: skip
        return 2
    at = argv.index("--")
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "bench" / "profile",
                    help="write OUT.md and OUT.csv")  # fmt: skip
    args = ap.parse_args(argv[:at])
    run_args = argv[at + 1 :]
    from sumo_swarm.cli import main as cli_main

    profile = cProfile.Profile()
    profile.enable()
    try:
        status = cli_main(run_args)
    except SystemExit as exc:
        status = exc.code if isinstance(exc.code, int) else 1
    finally:
        profile.disable()
    if status:
        print(f"profile_run: the run ended with status {status}", file=sys.stderr)
        return 1
    stats = pstats.Stats(profile)
    whole = max(row[3] for row in stats.stats.values())  # type: ignore[attr-defined]
    rows = [{"part": name, "seconds": s, "share": s / whole} for name, s in part_times(stats)]
    df = pd.DataFrame([{"part": "the whole run", "seconds": whole, "share": 1.0}, *rows])
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True).stdout.strip()  # fmt: skip
    table = df.to_markdown(index=False, floatfmt=".2f")
    print(table)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out.with_suffix(".csv"), index=False)
    command = " ".join(["python tools/profile_run.py", *argv])
    args.out.with_suffix(".md").write_text(
        f"Where the run's time goes (cProfile; parts nest), commit {commit}: `{command}`\n\n"
        + table
        + "\n",
        encoding="utf-8",
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
