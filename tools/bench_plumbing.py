"""Benchmark: what running a user's SUMO configuration through sumo-swarm costs over plain SUMO.

On one of the users' roads (sumo_swarm/sim/userroads.py: SUMO's defaults, flows with
``departLane="best"``), four ways of running the same simulation, alternated so that each sees
the same machine load, each in its own process:

- ``sumo``: the sumo binary on the configuration, with the options ``run --sumocfg`` adds (the
  sublane model, collisions counted), nothing else;
- ``sumo + outputs``: the same with the network outputs (tripinfo with emissions, SSM, edge
  data: ``sumo_swarm.sim.network.network_options``);
- ``sumo-cacc``: ``sumo-swarm run --sumocfg ... --controller sumo-cacc`` with ``[outputs]
  network = false``: the plumbing alone (bulk reads, recording, summary);
- ``sumo-cacc + outputs``: the same with the network outputs read into the summary (the
  default).

Prints and saves a table of process wall time, CPU time and peak memory (median, p95, max)
and the ratios of each mode's wall and CPU time to plain SUMO's, run by run.

Usage: python tools/bench_plumbing.py [--road motorway-ramps] [--end 300] [--repeats 5]
                                      [--out docs/bench/plumbing]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from sumo_swarm.config import OutputSettings
from sumo_swarm.sim.bridge import sumo_binary
from sumo_swarm.sim.network import network_options
from sumo_swarm.sim.userroads import ROADS, write_road

ROOT = Path(__file__).resolve().parent.parent
# What run --sumocfg adds to a configuration without them (sim/runner.py): plain SUMO gets the
# same, so both simulate the same thing.
RUN_OPTIONS = ["--lateral-resolution", "0.5", "--collision.mingap-factor", "0",
               "--collision.action", "warn", "--no-step-log", "true"]  # fmt: skip
MODES = ("sumo", "sumo + outputs", "sumo-cacc", "sumo-cacc + outputs")


def timed(cmd: list[str]) -> tuple[float, float, float]:
    """Run ``cmd``; its wall time [s], peak resident memory [MB] and CPU time [s] (user +
    system, its own and its subprocesses'). Raises if it fails.

    The wall time also counts the time the process waited for a core while others held it; the
    CPU time does not. On the 2-core machine of docs/bench the two agreed within 1-2 %: its
    20-40 % spread between repeats of one run is in how fast the cores ran, which both count
    (medians over alternated repeats are what to compare)."""
    with tempfile.TemporaryFile() as err:  # a file, not a pipe: a chatty run never blocks
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        if os.waitstatus_to_exitcode(status) != 0:
            err.seek(0)
            tail = err.read().decode(errors="replace")[-400:]
            raise RuntimeError(f"{' '.join(cmd[:4])} ... failed: {tail}")
    return wall, usage.ru_maxrss / 1024.0, usage.ru_utime + usage.ru_stime  # Linux: kB


def command(mode: str, cfg: Path, work: Path) -> list[str]:
    if mode.startswith("sumo-cacc"):
        cmd = [sys.executable, "-m", "sumo_swarm", "run", "--sumocfg", str(cfg), "--cav-type",
               "cav", "--controller", "sumo-cacc", "--out", str(work / "run")]  # fmt: skip
        if "outputs" not in mode:
            quiet = work / "no-outputs.toml"
            quiet.write_text("[outputs]\nnetwork = false\n", encoding="utf-8")
            cmd += ["--config", str(quiet)]
        return cmd
    cmd = [sumo_binary(), "-c", str(cfg), *RUN_OPTIONS]
    if "outputs" in mode:
        cmd += network_options(work / "sumo", OutputSettings())[0]
    return cmd


def stats(values) -> dict[str, float]:
    a = np.asarray(values, dtype=float)
    return {"median": float(np.median(a)), "p95": float(np.percentile(a, 95)), "max": a.max()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--road", default="motorway-ramps", choices=sorted(ROADS))
    parser.add_argument("--end", type=float, default=300.0, help="simulated seconds")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "bench" / "plumbing")
    args = parser.parse_args(argv)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        cfg = write_road(args.road, Path(tmp) / "road", end_s=args.end)
        for i in range(args.repeats):
            for mode in MODES:
                work = Path(tmp) / f"{i}-{mode.replace(' ', '')}"
                work.mkdir()
                wall, rss, cpu = timed(command(mode, cfg, work))
                rows.append({"repeat": i, "mode": mode, "wall_s": wall, "cpu_s": cpu,
                             "peak_rss_mb": rss})  # fmt: skip
                print(f"run {i} {mode:20s} wall {wall:6.2f} s  cpu {cpu:6.2f} s  "
                      f"peak {rss:6.0f} MB", flush=True)  # fmt: skip
    df = pd.DataFrame(rows)
    plain = df[df["mode"] == "sumo"].set_index("repeat")
    table = []
    for mode in MODES:
        sub = df[df["mode"] == mode].set_index("repeat")
        table.append({"mode": mode, "measure": "wall [s]", **stats(sub["wall_s"])})
        table.append({"mode": mode, "measure": "cpu [s]", **stats(sub["cpu_s"])})
        table.append({"mode": mode, "measure": "peak memory [MB]", **stats(sub["peak_rss_mb"])})
        if mode != "sumo":
            for what in ("wall", "cpu"):
                ratio = sub[f"{what}_s"] / plain[f"{what}_s"]
                table.append({"mode": mode, "measure": f"{what} / plain SUMO's", **stats(ratio)})
    out = pd.DataFrame(table)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out.with_suffix(".runs.csv"), index=False)
    out.to_csv(args.out.with_suffix(".csv"), index=False)
    head = (f"Plumbing cost on the users' road `{args.road}`, {args.end:g} s simulated, "
            f"{args.repeats} repeats (modes alternated, one process each): "
            f"`python tools/bench_plumbing.py --road {args.road} --end {args.end:g} "
            f"--repeats {args.repeats}`\n\n")  # fmt: skip
    md = out.to_markdown(index=False, floatfmt=".2f")
    args.out.with_suffix(".md").write_text(head + md + "\n", encoding="utf-8")
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
