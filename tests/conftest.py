"""Shared fixtures: the repository's paper scenario and a writer of variant scenario files; and a
check, after every test, that each run it wrote has a summary that agrees with its events."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from tests.contract import manoeuvre_problems

ROOT = Path(__file__).resolve().parent.parent
PAPER = ROOT / "scenarios" / "paper.toml"


@pytest.fixture
def paper_path() -> Path:
    return PAPER


@pytest.fixture
def scenario_file(tmp_path: Path):
    """Write a scenario TOML next to a copy of the paper's network reference; return its path.

    ``scenario_file(text)`` writes ``text`` as-is (the network path is made absolute so the
    file can live in tmp_path).
    """

    def write(text: str, name: str = "s.toml") -> Path:
        net = (ROOT / "networks" / "highway3.net.xml").as_posix()
        path = tmp_path / name
        path.write_text(text.replace("@NET@", net), encoding="utf-8")
        return path

    return write


# (path, modification time) of every run folder's summary.json already checked
_checked: set[tuple[str, int]] = set()


def written_runs(root: Path) -> list[Path]:
    """The run folders under ``root`` written since the last call: a ``summary.json`` of the
    contract's schema beside an ``events.jsonl``."""
    found = []
    for folder, dirs, files in os.walk(root):
        dirs[:] = [d for d in dirs if d != "sumo" and not d.startswith(".")]  # SUMO's inputs
        if "summary.json" not in files or "events.jsonl" not in files:
            continue
        path = Path(folder) / "summary.json"
        stamp = (str(path), path.stat().st_mtime_ns)
        if stamp not in _checked:
            _checked.add(stamp)
            found.append(Path(folder))
    return found


def run_problems(folder: Path) -> list[str]:
    """:func:`tests.contract.manoeuvre_problems` of the run in ``folder`` (a summary of another
    schema, or one without a manoeuvres list written by hand for a test: none)."""
    try:
        summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
        lines = (folder / "events.jsonl").read_text(encoding="utf-8").splitlines()
        events = [json.loads(line) for line in lines if line.strip()]
    except (OSError, ValueError):
        return []  # a file a test damaged on purpose
    if not isinstance(summary, dict) or summary.get("schema") != "sumo-swarm/summary/1":
        return []
    if "manoeuvres" not in summary or not isinstance(summary.get("overtake"), dict):
        return []
    return [f"{folder}: {p}" for p in manoeuvre_problems(summary, events)]


def _fail_on_disagreement(root: Path) -> None:
    problems = [p for folder in written_runs(root) for p in run_problems(folder)]
    if problems:
        pytest.fail("summary.json disagrees with events.jsonl:\n" + "\n".join(problems))


@pytest.fixture(autouse=True)
def _runs_agree_with_their_events(request):
    """After each test: every run it wrote into its ``tmp_path`` has ``overtake``, ``swarms``
    and ``manoeuvres`` that agree with its events.jsonl (the test fails if not)."""
    own = request.getfixturevalue("tmp_path") if "tmp_path" in request.fixturenames else None
    yield
    if own is not None:
        _fail_on_disagreement(own)


@pytest.fixture(scope="module", autouse=True)
def _module_runs_agree_with_their_events(tmp_path_factory):
    """After each test module: the same of every run written anywhere under the session's
    temporary folders (module fixtures' runs, ``tmp_path_factory``): one walk a module, not
    one a test."""
    yield
    _fail_on_disagreement(tmp_path_factory.getbasetemp())
