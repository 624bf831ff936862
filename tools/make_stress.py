"""Generate the stress sweep ``scenarios/stress.toml``: randomised scenes around the paper's.

Each case varies (seeded, reproducible): the lanes (2 to 4, on networks/highway{2,3,4}), the
platoon's lane, the number of CAVs (2 to 10), the slow vehicle's speed (12-17 m/s) and length
(5-15 m), the speeds of the HVs beside the platoon (17.5 m/s +-20 %) and where they are, the
upstream traffic's gap (15-40 m) and density (2-6 HVs per lane), the HVs' IDM parameters
(a, b, T), and whether HVs change lanes on their own (SUMO's lane-change model: they may cut
into the gaps the swarm opens). Every case runs under `swarm` and `cacc`.

Version 2 (issue 12, `--version 2`): the same randomisation with a new seed (default 2), a
third controller `sumo-lc` (SUMO's own drivers, free to change lanes: did the slow vehicle let
itself be passed?), and HV lane changes on in exactly 40 % of the scenes (rounded up; drawn
with the same generator after the scenes, so every share of scenes holds >= 30 %). It writes
scenarios/stress2.toml. Version 1 (the default) is unchanged: the same command writes the same
scenarios/stress.toml.

Usage: python tools/make_stress.py [--version 1|2] [--scenes 200] [--seed S] [--out FILE]
Run:   sumo-swarm batch scenarios/stress.toml --out stress --workers 2
       sumo-swarm batch scenarios/stress2.toml --out stress2 --workers 2
Check: python tools/stress_report.py stress   (or stress2)
"""

from __future__ import annotations

import argparse
import math
import random
import sys
from pathlib import Path

from sumo_swarm.study.batch.sweep import cases_toml

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_SEED = {1: 1, 2: 2}
DEFAULT_OUT = {1: "stress.toml", 2: "stress2.toml"}
CONTROLLERS = {1: ("swarm", "cacc"), 2: ("swarm", "cacc", "sumo-lc")}
V2_LANE_CHANGE_SHARE = 0.4  # issue 12 asks >= 30 %; a margin, and more lane-change scenes


def case(rng: random.Random) -> dict[str, object]:
    lanes = rng.choice((2, 3, 3, 4))
    platoon_lane = rng.randrange(lanes)
    others = [q for q in range(lanes) if q != platoon_lane]
    n_cav = rng.randint(2, 10)
    leader = 300.0 + 15.0 * max(0, n_cav - 6)  # room behind for the platoon and traffic
    target_len = round(rng.uniform(5.0, 15.0), 1)
    target_speed = round(rng.uniform(12.0, 17.0), 2)
    tail_front = leader - 15.0 * (n_cav - 1)
    side_speed = [round(17.5 * rng.uniform(0.8, 1.2), 2) for _ in range(2)]
    # The two side HVs (ids hv_left, hv_right of the base scene) anywhere beside or behind the
    # platoon, in lanes next to it where there are any.
    side_lanes = [rng.choice(others), rng.choice(others)]
    side_front = [round(rng.uniform(tail_front - 40.0, leader - 10.0), 1) for _ in range(2)]
    if side_lanes[0] == side_lanes[1]:
        if abs(side_front[0] - side_front[1]) < 30.0:
            side_front[1] = side_front[0] - 30.0
        # one lane, one behind the other: the rear one starts no faster than the front one
        front, rear = (0, 1) if side_front[0] > side_front[1] else (1, 0)
        side_speed[rear] = min(side_speed[rear], side_speed[front])
    return {
        "simulation.network": f"../networks/highway{lanes}.net.xml",
        "cav.count": n_cav,
        "scene.platoon_lane": platoon_lane,
        "scene.leader_front_m": leader,
        "scene.initial_speed_mps": target_speed,
        "scene.hv.hv_target.lane": platoon_lane,
        "scene.hv.hv_target.front_m": leader + 10.0 + target_len,
        "scene.hv.hv_target.length_m": target_len,
        "scene.hv.hv_target.speed_mps": target_speed,
        "scene.hv.hv_target.desired_speed_mps": target_speed,
        "scene.hv.hv_left.lane": side_lanes[0],
        "scene.hv.hv_left.front_m": side_front[0],
        "scene.hv.hv_left.speed_mps": side_speed[0],
        "scene.hv.hv_left.desired_speed_mps": side_speed[0],
        "scene.hv.hv_right.lane": side_lanes[1],
        "scene.hv.hv_right.front_m": side_front[1],
        "scene.hv.hv_right.speed_mps": side_speed[1],
        "scene.hv.hv_right.desired_speed_mps": side_speed[1],
        "scene.upstream_gap_m": round(rng.uniform(15.0, 40.0), 1),
        "scene.upstream_per_lane": rng.randint(2, 6),
        # Upstream HVs start no faster than the slowest vehicle ahead of them, so that no scene
        # begins with an HV braking hard behind a slower one (an artefact, not a swarm effect).
        "scene.upstream_speed_mps": min(target_speed, *side_speed),
        "hv.accel_mps2": round(rng.uniform(0.6, 1.5), 2),
        "hv.decel_mps2": round(rng.uniform(1.5, 2.5), 2),
        "hv.headway_s": round(rng.uniform(1.0, 1.6), 2),
        "hv.lane_changes": rng.random() < 0.3,
    }


def draw(scenes: int, seed: int, version: int = 1) -> list[dict[str, object]]:
    """The sweep's cases. Version 2 then sets HV lane changes in exactly
    ``ceil(V2_LANE_CHANGE_SHARE * scenes)`` scenes chosen by the same generator."""
    rng = random.Random(seed)
    cases = [case(rng) for _ in range(scenes)]
    if version == 2:
        chosen = set(rng.sample(range(scenes), math.ceil(V2_LANE_CHANGE_SHARE * scenes)))
        for i, c in enumerate(cases):
            c["hv.lane_changes"] = i in chosen
    return cases


def render(cases: list[dict[str, object]], seed: int, version: int = 1) -> str:
    controllers = CONTROLLERS[version]
    name = "stress" if version == 1 else "stress2"
    generated = f"--scenes {len(cases)} --seed {seed}"
    if version != 1:
        generated = f"--version {version} " + generated
    lines = [
        f"# Generated by tools/make_stress.py {generated}; do not edit.",
        f"# Run: sumo-swarm batch scenarios/{name}.toml --out {name} --workers 2",
        f"# Check: python tools/stress_report.py {name}",
        f'name = "{name}"',
        f"description = \"{len(cases)} randomised scenes around the paper's, "
        f'{" vs ".join(controllers)}"',
        'base = "paper.toml"',
        "controllers = [" + ", ".join(f'"{c}"' for c in controllers) + "]",
        "seeds = [42]",
        "",
        "[fixed]",
        '"simulation.duration_s" = 60.0',
        '"evaluation.end_s" = 60.0',
    ]
    lines += cases_toml(cases)
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--version", type=int, choices=(1, 2), default=1)
    parser.add_argument("--scenes", type=int, default=200)
    parser.add_argument("--seed", type=int, default=None, help="default: 1 (v1), 2 (v2)")
    parser.add_argument("--out", type=Path, default=None, help="default: scenarios/stress.toml "
                        "(v1), scenarios/stress2.toml (v2)")  # fmt: skip
    args = parser.parse_args(argv)
    seed = DEFAULT_SEED[args.version] if args.seed is None else args.seed
    out = args.out or ROOT / "scenarios" / DEFAULT_OUT[args.version]
    if args.scenes < 1:
        print(f"make_stress: --scenes must be >= 1, got {args.scenes}", file=sys.stderr)
        return 2
    cases = draw(args.scenes, seed, args.version)
    out.write_text(render(cases, seed, args.version), encoding="utf-8")
    print(f"wrote {len(cases)} cases to {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
