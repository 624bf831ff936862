"""Benchmark: what running a user's SUMO configuration through sumo-swarm costs over sumo itself.

On one of the users' roads (sumo_swarm/sim/userroads.py: SUMO's defaults, flows with
``departLane="best"``), the same simulation run several ways, alternated so that each sees the
same machine load, each in its own process. The yardstick is the sumo binary given the run's own
saved configuration: a run writes ``sumo/scenario.sumocfg`` (every option it gave SUMO, the
network outputs included), and ``sumo -c`` of it is the run's simulation with the run's SUMO
outputs. One untimed sumo-cacc run of each kind writes the configurations the sumo modes run.

- ``sumo``: the sumo binary on the configuration a run with ``[outputs] network = false`` saved
  (the user's configuration, the options ``run --sumocfg`` adds: the sublane model, collisions
  counted, the seed);
- ``sumo + outputs``: the sumo binary on the configuration a default run saved (the same with
  the network outputs: tripinfo with emissions, edge data,
  ``sumo_swarm.sim.network.network_options``);
- ``libsumo + outputs``: that configuration stepped through libsumo, nothing read, with the one
  command per CAV that defines sumo-cacc (tools/libsumo_plain.py): the same simulation as
  sumo-cacc's (the sumo binary's CAVs also change lanes to gain speed);
- ``libsumo reads + outputs``: the same, reading every vehicle's state at every step as the
  bridge does for the swarm (``libsumo_plain.py --reads``);
- ``sumo-cacc``: ``sumo-swarm run --sumocfg ... --controller sumo-cacc`` with ``[outputs]
  network = false``: the plumbing alone (SUMO's FCD made the trajectories, the summary);
- ``sumo-cacc + outputs``: the same with the network outputs read into the summary (the
  default).

A sumo-cacc run has SUMO write every vehicle at every step (its FCD output in Parquet, which
the run makes trajectories.parquet of: sumo_swarm/sim/fcd.py), and the saved configuration
holds that output too: every sumo and libsumo mode here writes it, as the runs do.

Prints and saves a table of process wall time, CPU time and peak memory (median, p95, max)
and the ratios of each mode's wall and CPU time to the sumo binary's with the same outputs, run
by run.

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
from libsumo_plain import READ_VARIABLES  # tools/

from sumo_swarm.controllers.base import LC_MODE_STRATEGIC
from sumo_swarm.sim.bridge import SumoSession, sumo_binary
from sumo_swarm.sim.userroads import ROADS, write_road

ROOT = Path(__file__).resolve().parent.parent
MODES = ("sumo", "sumo-cacc", "sumo + outputs", "libsumo + outputs", "libsumo reads + outputs",
         "sumo-cacc + outputs")  # fmt: skip
CAV_TYPE = "cav"  # the users' roads' CAV vType


def timed(cmd: list[str]) -> tuple[float, float, float]:
    """Run ``cmd``; its wall time [s], peak resident memory [MB] and CPU time [s] (user +
    system, its own and its subprocesses'). Raises if it fails.

    The wall time also counts the time the process waited for a core while others held it; the
    CPU time does not. On the 2-core machine of docs/bench the two agreed within 1-2 %: its
    20-40 % spread between repeats of one run is in how fast the cores ran, which both count
    (medians over alternated repeats are what to compare).

    The peak memory is GNU time's (``/usr/bin/time``, which starts ``cmd`` from its own small
    process): a process started from this one carries this one's peak resident memory (Linux
    keeps it across exec), so the sumo binary read as this script's size (141 MB)."""
    with tempfile.TemporaryDirectory() as tmp:
        peak_file = Path(tmp) / "peak_kb"
        gnu_time = ["/usr/bin/time", "-f", "%M", "-o", str(peak_file)]
        with (Path(tmp) / "stderr").open("w+b") as err:  # a file: a chatty run never blocks
            t0 = time.perf_counter()
            proc = subprocess.Popen([*gnu_time, *cmd], stdout=subprocess.DEVNULL, stderr=err)
            _, status, usage = os.wait4(proc.pid, 0)
            wall = time.perf_counter() - t0
            if os.waitstatus_to_exitcode(status) != 0:
                err.seek(0)
                tail = err.read().decode(errors="replace")[-400:]
                raise RuntimeError(f"{' '.join(cmd[:4])} ... failed: {tail}")
        peak_kb = float(peak_file.read_text(encoding="utf-8").split()[-1])
    return wall, peak_kb / 1024.0, usage.ru_utime + usage.ru_stime


def run_command(cfg: Path, out: Path, outputs: bool) -> list[str]:
    """``sumo-swarm run`` of ``cfg`` under sumo-cacc into ``out``, with or without the network
    outputs."""
    cmd = [sys.executable, "-m", "sumo_swarm", "run", "--sumocfg", str(cfg), "--cav-type",
           CAV_TYPE, "--controller", "sumo-cacc", "--out", str(out), "--force"]  # fmt: skip
    if not outputs:
        quiet = out.parent / f"{out.name}-no-outputs.toml"
        quiet.write_text("[outputs]\nnetwork = false\n", encoding="utf-8")
        cmd += ["--config", str(quiet)]
    return cmd


def saved_configuration(run: Path) -> Path:
    """The SUMO configuration a run saved (every option it gave SUMO)."""
    return run / "sumo" / "scenario.sumocfg"


def command(mode: str, cfg: Path, work: Path, reference: dict[bool, Path]) -> list[str]:
    """The process of ``mode`` on the user's configuration ``cfg``; ``reference``: the
    untimed runs whose saved configurations the sumo and libsumo modes run, by whether they
    write the network outputs."""
    outputs = "outputs" in mode
    if mode.startswith("sumo-cacc"):
        return run_command(cfg, work / "run", outputs)
    saved = str(saved_configuration(reference[outputs]))
    if mode.startswith("libsumo"):
        plain = ROOT / "tools" / "libsumo_plain.py"
        reads = ["--reads"] if "reads" in mode else []
        return [sys.executable, str(plain), *reads, CAV_TYPE, str(LC_MODE_STRATEGIC), "-c", saved]
    return [sumo_binary(), "-c", saved]


def yardstick(mode: str) -> str:
    """The sumo binary's mode with the same outputs as ``mode``."""
    return "sumo + outputs" if "outputs" in mode else "sumo"


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
    if READ_VARIABLES != SumoSession.VARS:
        raise SystemExit("tools/libsumo_plain.py: READ_VARIABLES differ from SumoSession.VARS")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        cfg = write_road(args.road, Path(tmp) / "road", end_s=args.end)
        reference = {}
        for outputs in (False, True):  # the configurations the runs save, run once untimed
            reference[outputs] = Path(tmp) / f"reference-{'outputs' if outputs else 'none'}"
            timed(run_command(cfg, reference[outputs], outputs))
        for i in range(args.repeats):
            for mode in MODES:
                work = Path(tmp) / f"{i}-{mode.replace(' ', '')}"
                work.mkdir()
                wall, rss, cpu = timed(command(mode, cfg, work, reference))
                rows.append({"repeat": i, "mode": mode, "wall_s": wall, "cpu_s": cpu,
                             "peak_rss_mb": rss})  # fmt: skip
                print(f"run {i} {mode:24s} wall {wall:6.2f} s  cpu {cpu:6.2f} s  "
                      f"peak {rss:6.0f} MB", flush=True)  # fmt: skip
    df = pd.DataFrame(rows)
    table = []
    for mode in MODES:
        sub = df[df["mode"] == mode].set_index("repeat")
        table.append({"mode": mode, "measure": "wall [s]", **stats(sub["wall_s"])})
        table.append({"mode": mode, "measure": "cpu [s]", **stats(sub["cpu_s"])})
        table.append({"mode": mode, "measure": "peak memory [MB]", **stats(sub["peak_rss_mb"])})
        against = yardstick(mode)
        if mode != against:
            base = df[df["mode"] == against].set_index("repeat")
            for what in ("wall", "cpu"):
                ratio = sub[f"{what}_s"] / base[f"{what}_s"]
                table.append({"mode": mode, "measure": f"{what} / {against}'s", **stats(ratio)})
    out = pd.DataFrame(table)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out.with_suffix(".runs.csv"), index=False)
    out.to_csv(args.out.with_suffix(".csv"), index=False)
    commit = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                            capture_output=True, text=True).stdout.strip()  # fmt: skip
    head = (f"Plumbing cost on the users' road `{args.road}`, {args.end:g} s simulated, "
            f"{args.repeats} repeats (modes alternated, one process each), at commit {commit}: "
            f"`python tools/bench_plumbing.py --road {args.road} --end {args.end:g} "
            f"--repeats {args.repeats}`\n\n")  # fmt: skip
    md = out.to_markdown(index=False, floatfmt=".2f")
    args.out.with_suffix(".md").write_text(head + md + "\n", encoding="utf-8")
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
