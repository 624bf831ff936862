"""Benchmark helper: a command's resident memory over time, and its peak.

Runs the command, samples its resident memory (``VmRSS`` of /proc/PID/status) every
``--every-s`` seconds into ``OUT`` (``time_s rss_mb`` a line), and prints its peak resident
memory (``ru_maxrss``, the number ``/usr/bin/time -v`` and tools/bench_corridor.py report),
CPU time and wall time. The timeline shows what grows and when: during the simulation, or
in the end-of-run steps (docs/bench/memory.md).

Usage: python tools/rss_timeline.py OUT [--every-s 0.5] -- COMMAND...
e.g.   python tools/rss_timeline.py hour.rss -- sumo-swarm run scenarios/corridor.toml \
           --controller sumo-cacc --out /tmp/hour
"""

from __future__ import annotations

import argparse
import resource
import subprocess
import sys
import time
from pathlib import Path


def rss_mb(pid: int) -> float | None:
    """Resident memory of process ``pid`` [MB]; None once it is gone."""
    try:
        with open(f"/proc/{pid}/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024.0  # kB
    except OSError:
        return None
    return None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="the timeline: 'time_s rss_mb' a line")
    parser.add_argument("--every-s", type=float, default=0.5, help="sampling period [s]")
    argv = sys.argv[1:] if argv is None else argv
    cut = argv.index("--") if "--" in argv else len(argv)
    args, command = parser.parse_args(argv[:cut]), argv[cut + 1 :]
    if not command or args.every_s <= 0:
        parser.error("give a command after --, and --every-s > 0")
    t0 = time.perf_counter()
    proc = subprocess.Popen(command)
    with args.out.open("w", encoding="ascii") as out:
        while proc.poll() is None:
            rss = rss_mb(proc.pid)  # None between the end and the reaping
            if rss is not None:
                out.write(f"{time.perf_counter() - t0:.1f} {rss:.0f}\n")
                out.flush()
            time.sleep(args.every_s)
    wall_s = time.perf_counter() - t0
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)  # poll() reaped it: counted here
    print(f"exit {proc.returncode}, peak {usage.ru_maxrss / 1024.0:.0f} MB, "
          f"cpu {usage.ru_utime + usage.ru_stime:.0f} s, wall {wall_s:.0f} s")  # fmt: skip
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main())
