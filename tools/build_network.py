"""Rebuild ``networks/*.net.xml`` from the plain XML (nodes, edges) beside them with netconvert.

Usage: ``python tools/build_network.py [NAME ...]`` (default: every ``*.nod.xml`` in networks/).
netconvert comes with the ``eclipse-sumo`` package; no system SUMO is needed.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import sumo

NETWORKS = Path(__file__).resolve().parent.parent / "networks"


def netconvert_binary() -> str:
    return str(Path(sumo.SUMO_HOME) / "bin" / "netconvert")


def build(name: str) -> Path:
    """Build ``networks/NAME.net.xml`` from ``NAME.nod.xml`` and ``NAME.edg.xml``."""
    out = NETWORKS / f"{name}.net.xml"
    cmd = [
        netconvert_binary(),
        "--node-files", f"{name}.nod.xml",
        "--edge-files", f"{name}.edg.xml",
        "--output-file", out.name,
        "--no-turnarounds", "true",
        "--output.street-names", "false",
        "--no-warnings", "true",
    ]  # fmt: skip
    # relative paths, run inside networks/, keep absolute paths out of the committed header
    subprocess.run(cmd, check=True, cwd=NETWORKS)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help="network names (default: all)")
    args = parser.parse_args(argv)
    names = args.names or sorted(
        p.name.removesuffix(".nod.xml") for p in NETWORKS.glob("*.nod.xml")
    )
    for name in names:
        print(f"built {build(name)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
