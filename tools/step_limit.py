"""Measure the swarm's safety against SUMO's step length (issue 12, item 4).

Runs the swarm on the paper scene and a few variants at several step lengths and prints, per
run, the collisions, hard brakes and whether the overtake completed. The largest step with 0
collisions and 0 hard brakes everywhere is ``MAX_SWARM_STEP_S`` in sumo_swarm/sim/steplimit.py.

    PYTHONPATH=$PWD python tools/step_limit.py --out /tmp/steps --steps 0.1 0.2 0.5 1.0
"""

from __future__ import annotations

import argparse
import json
import sys
import tomllib
from pathlib import Path

from sumo_swarm.sim import steplimit
from sumo_swarm.sim.runner import run_scenario
from sumo_swarm.study.batch.sweep import TomlBase

SCENES: dict[str, dict[str, object]] = {
    "paper": {},
    "paper-lc": {"hv.lane_changes": True},
    "paper-10cav": {"cav.count": 10},
}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--steps", type=float, nargs="+", default=[0.1, 0.2, 0.5, 1.0])
    ap.add_argument("--scenes", nargs="+", default=list(SCENES))
    ap.add_argument("--controller", default="swarm")
    ap.add_argument(
        "--variants", type=int, default=0, help="also the first N cases of variants.toml"
    )
    ap.add_argument("--skip", type=int, default=0, help="start at this case of variants.toml")
    args = ap.parse_args()
    steplimit.MAX_SWARM_STEP_S = float("inf")  # measure beyond the limit this tool sets
    root = Path(__file__).resolve().parents[1] / "scenarios"
    base = TomlBase(root / "paper.toml")
    scenes = {name: SCENES[name] for name in args.scenes}
    cases = tomllib.loads((root / "variants.toml").read_text())["cases"]
    chosen = range(args.skip, args.skip + args.variants)
    scenes.update({f"variant{i}": cases[i] for i in chosen if i < len(cases)})
    for step in args.steps:
        for name, values in scenes.items():
            scenario = base.scenario(base.overrides({**values, "simulation.step_length_s": step}))
            out = args.out / f"{name}-{step:g}-{args.controller}"
            s = run_scenario(scenario, args.controller, out, progress=False, force=True)
            row = {
                "scene": name,
                "step_s": step,
                "controller": args.controller,
                "collisions": s["safety"]["collisions"],
                "hard_brakes": s["safety"]["hard_brakes"],
                "hard_brakes_cav": s["safety"].get("hard_brakes_cav"),
                "completed": s["overtake"]["completed"],
                "regrouped": s["overtake"]["regrouped"],
                "cav_mean_speed_mps": s["cav"]["mean_speed_mps"],
                "gap_min_m": s["cav"]["gap_min_m"],
                "wall_s": round(s["timing"]["wall_s"], 1),
            }
            print(json.dumps(row), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
