"""The command line: exit status 2 and one line for bad input, no traceback."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest


def sumo_swarm(*args: str, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "sumo_swarm", *args],
        capture_output=True, text=True, cwd=cwd, timeout=300,
    )  # fmt: skip


def assert_bad_input(proc: subprocess.CompletedProcess, *fragments: str) -> None:
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    for fragment in fragments:
        assert fragment in lines[0]


def test_missing_scenario_file(tmp_path):
    missing = tmp_path / "nope.toml"
    assert_bad_input(sumo_swarm("run", str(missing)), "not found", str(missing))


def test_unknown_key(tmp_path, scenario_file):
    path = scenario_file('[simulation]\nnetwork = "@NET@"\nstep_lenght_s = 0.1\n')
    assert_bad_input(sumo_swarm("run", str(path)), "simulation.step_lenght_s", str(path))


def test_unknown_controller(paper_path):
    assert_bad_input(sumo_swarm("run", str(paper_path), "--controller", "magic"), "magic")


def test_unwritable_output_folder(paper_path, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert_bad_input(
        sumo_swarm("run", str(paper_path), "--out", str(blocker / "sub")), "cannot be written"
    )


@pytest.mark.sumo
def test_run_writes_summary(paper_path, tmp_path):
    proc = sumo_swarm("run", str(paper_path), "--controller", "cacc", "--out", str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["safety"]["collisions"] == 0
    assert "paper/cacc" in proc.stdout
