"""Shared fixtures: the repository's paper scenario and a writer of variant scenario files."""

from __future__ import annotations

from pathlib import Path

import pytest

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
