"""Run one case of a sweep under the swarm and store every planning problem it builds.

The swarm gets a recording planner (the scenario's own planner behind a wrapper), so the run
is the real one; each call's problem (:mod:`sumo_swarm.core.planner.dump`), its warm-start
hint cells and the plan's status, objective and time go to ``OUT`` as one JSON document:

    PYTHONPATH=$PWD python tools/collect_problems.py scenarios/variants.toml /tmp/p23.json --case 23
    PYTHONPATH=$PWD python tools/collect_problems.py scenarios/paper.toml /tmp/paper.json

``--case`` counts the ``[[cases]]`` of a sweep file from 0; without it the file is a scenario.
Bad input: exit status 2 and one line.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path
from typing import Any

from sumo_swarm.config import load_scenario
from sumo_swarm.controllers.swarm import SwarmController
from sumo_swarm.core.planner import CellPlanner, Plan, PlanningProblem, make_planner
from sumo_swarm.core.planner.dump import problem_to_dict
from sumo_swarm.errors import ConfigError
from sumo_swarm.sim.runner import run_scenario
from sumo_swarm.study.batch.sweep import find_case


class RecordingPlanner:
    """Passes every call to ``inner`` and keeps the problem, hint and outcome."""

    def __init__(self, inner: CellPlanner) -> None:
        self.inner = inner
        self.records: list[dict[str, Any]] = []

    def plan(self, problem: PlanningProblem, hint: Plan | None = None) -> Plan:
        plan = self.inner.plan(problem, hint=hint)
        self.records.append(
            {
                "problem": problem_to_dict(problem),
                "hint": [list(map(list, path)) for path in hint.cells]
                if hint is not None and hint.cells
                else None,
                "status": plan.status.value,
                "objective": plan.objective,
                "solve_ms": round(plan.solve_ms, 2),
            }
        )
        return plan


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", type=Path, help="scenario file, or sweep file with --case")
    parser.add_argument("out", type=Path)
    parser.add_argument("--case", type=int, help="case of a sweep file (0-based)")
    args = parser.parse_args(argv)
    try:
        if args.case is None:
            scenario, seed = load_scenario(args.source), None
        else:
            spec = find_case(args.source, args.case)
            scenario, seed = spec.scenario(), spec.seed
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    recorder = RecordingPlanner(make_planner(scenario.planner))
    with tempfile.TemporaryDirectory() as tmp:
        summary = run_scenario(
            scenario, "swarm", tmp, seed=seed, progress=False,
            controller=SwarmController(planner=recorder),
        )  # fmt: skip
    args.out.write_text(
        json.dumps({"source": str(args.source), "case": args.case, "calls": recorder.records})
    )
    planner = summary.get("planner", {})
    print(
        f"{len(recorder.records)} problems -> {args.out}; solve_ms p95 "
        f"{planner.get('solve_ms_p95')} max {planner.get('solve_ms_max')}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
