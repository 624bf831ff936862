"""A baseline run that plans nothing loads no solver and no plotting library (issue 52): the
modules a ``sumo-swarm run`` process imports, read from ``python -X importtime``."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.test_cli import paper_variant

ROOT = Path(__file__).resolve().parent.parent
# What only the swarm's planner and tracking (OR-Tools, osqp, scipy) or the figures use.
NOT_FOR_A_BASELINE = ("ortools", "osqp", "scipy", "matplotlib")


def imported(argv: list[str], cwd: Path) -> set[str]:
    """The top-level packages a ``python -m sumo_swarm`` process with ``argv`` imported."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    done = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "sumo_swarm", *argv],
        cwd=cwd, env=env, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    names = re.findall(r"^import time:\s+\d+ \|\s+\d+ \|\s*(\S+)$", done.stderr, re.MULTILINE)
    return {n.split(".")[0] for n in names}


@pytest.mark.sumo
@pytest.mark.parametrize("controller", ["sumo-cacc", "sumo-lc"])
def test_a_baseline_run_loads_no_solver_and_no_plots(tmp_path, paper_path, controller):
    short = paper_variant(tmp_path, paper_path, 3.0)
    argv = ["run", str(short), "--controller", controller, "--out", str(tmp_path / "run")]
    packages = imported(argv, tmp_path)
    assert {"libsumo", "pandas", "sumo_swarm"} <= packages  # the log was read
    assert packages.isdisjoint(NOT_FOR_A_BASELINE), packages & set(NOT_FOR_A_BASELINE)
    assert (tmp_path / "run" / "summary.json").is_file()
