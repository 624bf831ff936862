"""Benchmark: what a corridor run costs under the swarm, against sumo-cacc and plain SUMO.

On ``scenarios/corridor.toml`` (6 km, 3 lanes, ramps, 1500 veh/h/lane, one flow per origin,
destination and class), three ways of running the same traffic, each in its own process,
alternated point by point so that each sees the same machine load:

- ``sumo-fcd``: the sumo binary on the configuration a ``sumo-swarm run`` under sumo-cacc
  saved (``sumo/scenario.sumocfg`` of one untimed run per point: the same network, flows, step,
  sublane model, collision options and outputs: tripinfo with emissions, edge data, and every
  vehicle at every step as SUMO's FCD output in Parquet, which the run makes its
  trajectories.parquet of): the yardstick of "the same configuration and outputs";
- ``sumo``: the same without the FCD output (a copy of the configuration beside it without
  its ``fcd-output`` options): SUMO's cost before any trajectory is written;
- ``libsumo``: the saved configuration stepped through libsumo, nothing read, with the one
  command per CAV that defines sumo-cacc (its lane-change mode: SUMO's strategic changes
  only; tools/libsumo_plain.py), SUMO writing its FCD output: the floor of a sumo-cacc run.
  This is the same simulation as sumo-cacc's; the sumo binary's is not (its CAVs change lanes
  to gain speed and cooperate too: over the hour sumo-cacc's CAVs jam the corridor and the
  binary's do not);
- ``libsumo-reads``: the same, also reading every vehicle's state at every step as the bridge
  does for the swarm (``libsumo_plain.py --reads``);
- ``sumo-cacc``: ``sumo-swarm run ... --controller sumo-cacc``: SUMO drives and records (its FCD
  output), the project makes the trajectories and the summary of it (the plumbing);
- ``swarm``: ``sumo-swarm run ... --controller swarm``;
- ``cacc``, ``sumo-lc``: the other two controllers, likewise (not run unless named in
  ``--modes``: with ``--times 300,1200`` they give the peak memory of every controller, a long
  run's against a short one's, docs/bench/memory.md).

Two axes: the simulated time (``--times``, at the scenario's CAV share) and the number of CAVs
(``--shares`` of the demand, at ``--share-time`` simulated seconds). Prints and saves a table of
process wall time, CPU time (user + system: without the waits for a core) and peak resident
memory per point and mode (median, p95 and max over ``--repeats``), the ratios of wall and of
CPU time run by run (sumo-cacc, libsumo and libsumo-reads against the sumo binary, sumo-cacc
against it with FCD output, against libsumo and libsumo-reads, swarm against sumo-cacc), each
mode's peak memory against its shortest run's, and what the runs did (CAVs that entered,
platoons formed, collisions).

Usage: python tools/bench_corridor.py [--times 300,1200,3600] [--shares 0.1,0.2,0.4]
                                      [--share-time 300] [--repeats 1]
                                      [--out docs/bench/corridor]
                                      [--modes sumo,sumo-fcd,libsumo,libsumo-reads,sumo-cacc,swarm]
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
from bench_plumbing import stats, timed  # tools/: one process's wall time and peak memory
from libsumo_plain import READ_VARIABLES  # tools/

from sumo_swarm.config import load_scenario
from sumo_swarm.controllers.base import LC_MODE_STRATEGIC
from sumo_swarm.sim.bridge import SumoSession, sumo_binary
from sumo_swarm.sim.scene import CAV_TYPE

ROOT = Path(__file__).resolve().parent.parent
CORRIDOR = ROOT / "scenarios" / "corridor.toml"
MODES = ("sumo", "sumo-fcd", "libsumo", "libsumo-reads", "sumo-cacc", "swarm", "cacc", "sumo-lc")
DEFAULT_MODES = ("sumo", "sumo-fcd", "libsumo", "sumo-cacc", "swarm")
# The modes that run the saved configuration without sumo-swarm (no summary to read).
PLAIN_MODES = ("sumo", "sumo-fcd", "libsumo", "libsumo-reads")


def scenario_file(folder: Path, duration_s: float, share: float) -> Path:
    """corridor.toml with its duration and CAV share replaced (each key once, or an error)."""
    text = CORRIDOR.read_text(encoding="utf-8")
    for key, value in (("duration_s", duration_s), ("cav_share", share)):
        text, n = re.subn(rf"(?m)^{key} = [0-9.]+", f"{key} = {value!r}", text)
        if n != 1:
            raise SystemExit(f"{CORRIDOR}: expected one '{key} = ' line, found {n}")
    path = folder / f"corridor-{duration_s:g}s-{share:g}.toml"
    path.write_text(text, encoding="utf-8")
    return path


def run_command(mode: str, scenario: Path, work: Path) -> list[str]:
    return [sys.executable, "-m", "sumo_swarm", "run", str(scenario), "--controller", mode,
            "--out", str(work)]  # fmt: skip


def command(mode: str, scenario: Path, work: Path, reference: Path) -> list[str]:
    """The process of ``mode``; ``reference``: the untimed sumo-cacc run of the point, whose
    saved configuration the sumo and libsumo modes run."""
    if mode in PLAIN_MODES:
        saved = reference / "sumo" / "scenario.sumocfg"
        cfg = str(saved)
        if mode == "sumo":
            return [sumo_binary(), "-c", str(without_fcd(saved))]
        if mode == "sumo-fcd":
            return [sumo_binary(), "-c", cfg]
        plain = ROOT / "tools" / "libsumo_plain.py"
        reads = ["--reads"] if mode == "libsumo-reads" else []
        return [sys.executable, str(plain), *reads, CAV_TYPE, str(LC_MODE_STRATEGIC), "-c", cfg]
    return run_command(mode, scenario, work)


def without_fcd(cfg: Path) -> Path:
    """A copy of SUMO configuration ``cfg`` beside it, without its FCD output."""
    copy = cfg.with_name(f"{cfg.stem}-without-fcd.sumocfg")
    lines = cfg.read_text(encoding="utf-8").splitlines(keepends=True)
    copy.write_text("".join(x for x in lines if "<fcd-output" not in x), encoding="utf-8")
    return copy


def what_it_did(mode: str, work: Path) -> dict[str, float]:
    if mode in PLAIN_MODES:
        return {}
    summary = json.loads((work / "summary.json").read_text(encoding="utf-8"))
    network = summary.get("network") or {}
    swarms = summary.get("swarms") or {}
    return {
        "cavs": (network.get("vehicles_per_class") or {}).get("cav", np.nan),
        "vehicles": network.get("vehicles", np.nan),
        "platoons_formed": swarms.get("platoons_formed", np.nan),
        "collisions": summary["safety"]["collisions"],
        "cav_mean_speed_mps": summary["cav"]["mean_speed_mps"],
        "ttc_events": network.get("ttc_below_1_5s_events", np.nan),
        "ttc_events_ssm": network.get("ttc_below_1_5s_events_ssm", np.nan),
    }


def _floats(text: str) -> list[float]:
    return [float(x) for x in text.split(",") if x.strip()]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--times", default="300,1200,3600", help="simulated seconds, comma list")
    parser.add_argument("--shares", default="0.1,0.2,0.4", help="CAV shares, comma list")
    parser.add_argument("--share-time", type=float, default=300.0)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "bench" / "corridor")
    parser.add_argument("--modes", default=",".join(DEFAULT_MODES),
                        help=f"modes to run, comma list of {', '.join(MODES)}")  # fmt: skip
    args = parser.parse_args(argv)
    if READ_VARIABLES != SumoSession.VARS:
        raise SystemExit("tools/libsumo_plain.py: READ_VARIABLES differ from SumoSession.VARS")
    chosen = {m.strip() for m in args.modes.split(",") if m.strip()}
    if not chosen or chosen - set(MODES):
        parser.error(f"--modes: expected some of {', '.join(MODES)}, got {args.modes!r}")
    modes = tuple(m for m in MODES if m in chosen)
    base_share = load_scenario(CORRIDOR).corridor.cav_share
    points = [("time", t, base_share) for t in _floats(args.times)]
    points += [("cavs", args.share_time, s) for s in _floats(args.shares)]
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeats):
            for axis, duration, share in points:
                if axis == "cavs" and ("time", duration, share) in points:
                    continue  # the same runs as a point of the time axis: measured there
                scenario = scenario_file(Path(tmp), duration, share)
                reference = Path(tmp) / f"reference-{duration:g}-{share:g}"
                if not reference.exists():  # the configuration the sumo modes run, saved once
                    timed(run_command("sumo-cacc", scenario, reference))
                for mode in modes:
                    work = Path(tmp) / f"{i}-{duration:g}-{share:g}-{mode}"
                    wall, rss, cpu = timed(command(mode, scenario, work, reference))
                    row = {"repeat": i, "duration_s": duration, "cav_share": share,
                           "mode": mode, "wall_s": wall, "cpu_s": cpu, "peak_rss_mb": rss,
                           **what_it_did(mode, work)}  # fmt: skip
                    rows.append(row)
                    print(f"run {i} {duration:6g} s share {share:4g} {mode:10s} "
                          f"wall {wall:8.2f} s  cpu {cpu:8.2f} s  peak {rss:6.0f} MB",
                          flush=True)  # fmt: skip
    df = pd.DataFrame(rows)
    keys = ["repeat", "duration_s", "cav_share"]
    wide = df.pivot_table(index=keys, columns="mode", values=["wall_s", "cpu_s", "peak_rss_mb"])
    table = []
    for (duration, share), sub in wide.groupby(level=["duration_s", "cav_share"]):
        runs = df[(df["duration_s"] == duration) & (df["cav_share"] == share)]
        did = runs[runs["mode"] == "swarm"]
        cacc = runs[runs["mode"] == "sumo-cacc"]
        head = {"simulated_s": duration, "cav_share": share,
                "cavs": cacc["cavs"].median() if len(cacc) else np.nan,
                "platoons_formed": did["platoons_formed"].median() if len(did) else np.nan,
                "collisions_swarm": did["collisions"].max() if len(did) else np.nan}  # fmt: skip
        for mode in modes:
            for measure, column in (("wall [s]", "wall_s"), ("cpu [s]", "cpu_s"),
                                    ("peak memory [MB]", "peak_rss_mb")):  # fmt: skip
                table.append({**head, "mode": mode, "measure": measure,
                              **stats(sub[(column, mode)])})  # fmt: skip
        ratios = (
            ("sumo-cacc", "sumo-fcd", "the sumo binary's with FCD"),
            ("sumo-cacc", "sumo", "the sumo binary's without FCD"),
            ("libsumo", "sumo-fcd", "the sumo binary's with FCD"),
            ("libsumo-reads", "sumo-fcd", "the sumo binary's with FCD"),
            ("sumo-cacc", "libsumo", "libsumo's"),
            ("sumo-cacc", "libsumo-reads", "libsumo-reads'"),
            ("swarm", "sumo-cacc", "sumo-cacc's"),
        )
        for mode, against, whose in ratios:
            if mode in modes and against in modes:
                for what in ("wall", "cpu"):
                    ratio = sub[f"{what}_s"][mode] / sub[f"{what}_s"][against]
                    table.append({**head, "mode": mode, "measure": f"{what} / {whose}",
                                  **stats(ratio)})  # fmt: skip
    out = pd.DataFrame(table)
    shortest = df["duration_s"].min()
    growth = []
    for mode in modes:
        mine = df[(df["mode"] == mode) & (df["cav_share"] == base_share)]
        first = mine[mine["duration_s"] == shortest]["peak_rss_mb"].median()
        for duration, sub in mine.groupby("duration_s"):
            peak = sub["peak_rss_mb"].median()
            growth.append({"mode": mode, "simulated_s": duration, "peak_memory_mb": peak,
                           f"x the {shortest:g} s run's": peak / first})  # fmt: skip
    growth = pd.DataFrame(growth)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out.with_suffix(".runs.csv"), index=False)
    out.to_csv(args.out.with_suffix(".csv"), index=False)
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True).stdout.strip()  # fmt: skip
    command_line = (f"python tools/bench_corridor.py --times {args.times} --shares {args.shares} "
                    f"--share-time {args.share_time:g} --repeats {args.repeats}")  # fmt: skip
    if modes != DEFAULT_MODES:
        command_line += f" --modes {','.join(modes)}"
    md = (
        f"Corridor cost (`scenarios/corridor.toml`), {args.repeats} repeat(s), modes alternated, "
        f"one process each, at commit {commit}: `{command_line}`\n\n"
        + out.to_markdown(index=False, floatfmt=".2f")
        + "\n\nPeak memory against simulated time (CAV share "
        + f"{base_share:g}):\n\n"
        + growth.to_markdown(index=False, floatfmt=".2f")
        + "\n"
    )
    args.out.with_suffix(".md").write_text(md, encoding="utf-8")
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
