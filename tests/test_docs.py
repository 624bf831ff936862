"""The documentation cannot drift from the code.

- Every code block of README.md and docs/tutorial.md runs, in order, in one empty folder: a
  block with ``title="FILE"`` is written to FILE, a ``bash`` block runs in bash (``set -e``), a
  ``python`` block runs in Python; the README's set-up commands are checked against .ci/run
  instead (CI runs them).
- The settings reference (docs/settings.md) is what tools/settings_reference.py makes from the
  code, and every key in it has a unit (where it holds a quantity), a default and a range.
- The README's results table is what tools/readme_results.py makes from the stored report.
- The site builds with ``mkdocs build --strict`` (a broken link or a missing page fails).
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.toolload import ROOT, load_tool

README = ROOT / "README.md"
TUTORIAL = ROOT / "docs" / "tutorial.md"
# The README's set-up commands: they install the project, so CI runs them (.ci/run), not this.
SETUP_COMMANDS = (
    "pip install . && sumo-swarm reproduce --out reproduce",
    'pip install -e ".[test,cluster]" && python -m pytest',
)
FENCE = re.compile(r"^```(\w*)([^\n]*)\n(.*?)^```\s*$", re.S | re.M)


@dataclass(frozen=True)
class Block:
    language: str
    title: str | None
    code: str
    line: int


def code_blocks(path: Path) -> list[Block]:
    text = path.read_text(encoding="utf-8")
    blocks = []
    for match in FENCE.finditer(text):
        title = re.search(r'title="([^"]+)"', match.group(2))
        line = text.count("\n", 0, match.start()) + 1
        blocks.append(
            Block(match.group(1), title.group(1) if title else None, match.group(3), line)
        )
    return blocks


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    # sumo-swarm on PATH runs this checkout (the tests' python, with PYTHONPATH above)
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env["PATH"]])
    env["MPLBACKEND"] = "Agg"
    return env


def run_blocks(blocks: list[Block], where: Path, source: Path) -> list[str]:
    """Run every block in ``where``; returns what ran (one line per block)."""
    env = _env()
    ran = []
    for block in blocks:
        label = f"{source.name}:{block.line}"
        if block.title is not None:
            (where / block.title).write_text(block.code, encoding="utf-8")
            ran.append(f"{label} wrote {block.title}")
            continue
        if block.language == "bash":
            command = ["bash", "-e", "-c", block.code.replace("sumo-swarm ", "sumo_swarm_cli ")]
        elif block.language == "python":
            command = [sys.executable, "-c", block.code]
        else:
            raise AssertionError(f"{label}: a {block.language!r} block is neither run nor a file")
        result = subprocess.run(
            command, cwd=where, env=env, capture_output=True, text=True, timeout=600
        )
        assert result.returncode == 0, (
            f"{label} failed ({result.returncode}):\n{block.code}\n"
            f"stdout: {result.stdout[-2000:]}\nstderr: {result.stderr[-3000:]}"
        )
        ran.append(f"{label} ran {block.language}")
    return ran


@pytest.fixture
def cli_on_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A ``sumo_swarm_cli`` command that runs this checkout's CLI (bash blocks call it for
    ``sumo-swarm``, so an installed copy elsewhere is never what runs)."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    script = bin_dir / "sumo_swarm_cli"
    script.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m sumo_swarm "$@"\n')
    script.chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    work = tmp_path / "work"
    work.mkdir()
    return work


@pytest.mark.sumo
def test_readme_snippets_run(cli_on_path: Path) -> None:
    blocks = code_blocks(README)
    setup = [b for b in blocks if b.code.strip() in SETUP_COMMANDS]
    assert [b.code.strip() for b in setup] == list(SETUP_COMMANDS), "the set-up commands moved"
    assert blocks[: len(setup)] == setup, "the set-up commands must come first"
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert SETUP_COMMANDS[1].replace('"', "") in ci.replace('"', ""), "CI runs the 2nd command"
    rest = [b for b in blocks if b not in setup]
    ran = run_blocks(rest, cli_on_path, README)
    assert len(ran) == len(rest) >= 5
    # the plugin snippet counts collisions as SUMO does at zero gap (the README says so)
    plugin = next(b for b in rest if "attach(" in b.code)
    assert '"--collision.mingap-factor", "0"' in plugin.code
    import json

    for run_dir in ("my-run", "plugin-run"):
        summary = json.loads((cli_on_path / run_dir / "summary.json").read_text())
        assert summary["safety"]["collisions"] == 0, run_dir
        assert summary["overtake"]["completed"], run_dir


@pytest.mark.sumo
def test_tutorial_snippets_run(cli_on_path: Path) -> None:
    blocks = code_blocks(TUTORIAL)
    ran = run_blocks(blocks, cli_on_path, TUTORIAL)
    assert len(ran) == len(blocks) >= 10
    assert (cli_on_path / "sweep-out" / "results.parquet").is_file()
    assert (cli_on_path / "penetration-out" / "results.parquet").is_file()


def test_code_blocks_are_found() -> None:
    """The block reader sees titles, languages and every block (the snippet tests rely on it)."""
    text = 'a\n```bash\necho 1\n```\n\n```xml title="x.xml"\n<a/>\n```\n```python\nx = 1\n```\n'
    path = ROOT / "tests" / "data" / "_blocks.md"
    path.write_text(text, encoding="utf-8")
    try:
        blocks = code_blocks(path)
    finally:
        path.unlink()
    assert [(b.language, b.title, b.code) for b in blocks] == [
        ("bash", None, "echo 1\n"),
        ("xml", "x.xml", "<a/>\n"),
        ("python", None, "x = 1\n"),
    ]


# --------------------------------------------------------------------------- settings reference


def test_settings_reference_has_every_key_with_unit_default_and_range() -> None:
    reference = load_tool("settings_reference")
    from sumo_swarm.config import DERIVED_KEYS, SECTIONS

    keys = reference.all_keys()
    page = (ROOT / "docs" / "settings.md").read_text(encoding="utf-8")
    assert page == reference.render(keys), "docs/settings.md is stale: run the tool with --out"
    import dataclasses

    for section, cls in SECTIONS.items():
        names = {f.name for f in dataclasses.fields(cls)} - set(DERIVED_KEYS.get(section, {}))
        listed = {k.name for k in keys if k.section.split(".")[0] == section}
        assert names <= listed | {
            k.section.split(".")[1] for k in keys if k.section.startswith(f"{section}.")
        }, section
    missing = [
        f"{k.section}.{k.name}: "
        + ", ".join(
            what
            for what, ok in (
                ("sentence", k.doc),
                ("unit", k.unit or not k.is_quantity),
                ("default", k.default),
                ("range", k.range),
            )
            if not ok
        )
        for k in keys
        if not (k.doc and (k.unit or not k.is_quantity) and k.default and k.range)
    ]
    assert not missing, "settings without " + "; ".join(missing)
    for k in keys:  # every line of the page carries them
        assert f"| `{k.name}` |" in page


def test_settings_reference_reads_ranges_from_the_checks() -> None:
    """The range comes from the class's own checks: a check changed is a page changed."""
    reference = load_tool("settings_reference")
    by_key = {(k.section, k.name): k for k in reference.all_keys()}
    assert by_key[("simulation", "step_length_s")].range == "> 0"
    assert by_key[("simulation", "step_length_s")].unit == "s"
    assert by_key[("simulation", "seed")].range.startswith(">= 0 and <= ")  # both bounds
    assert by_key[("cav", "accel_min_mps2")].range == "< 0"
    assert by_key[("longitudinal", "v_min")].range == "< v_max"
    assert by_key[("outputs", "trajectories")].range == '"all", "cavs"'
    assert by_key[("planner", "release_idle_holds")].range == 'true, false; "stranded"'
    assert by_key[("scene.hv", "front_m")].default == "required"

    from dataclasses import dataclass

    from sumo_swarm.checks import check_fields

    @dataclass(frozen=True)
    class Made:
        """A made-up section.

        Attributes
        ----------
        gap_m
            A gap [m].
        count
            How many [CAVs].
        """

        gap_m: float = 2.0
        count: int = 3

        def __post_init__(self) -> None:
            check_fields(self, "gap_m", ge=1.0, lt=9.0)

    keys = {k.name: k for k in reference.section_keys("made", Made)}
    assert (keys["gap_m"].range, keys["gap_m"].unit, keys["gap_m"].doc) == (
        ">= 1 and < 9",
        "m",
        "A gap [m].",
    )
    assert keys["count"].range == ""  # unchecked: the reference test above would refuse it


def test_readme_results_table_is_generated() -> None:
    tool = load_tool("readme_results")
    assert tool.main(["--check"]) == 0


# --------------------------------------------------------------------------- the site


def test_docs_build_strict(tmp_path: Path) -> None:
    """``mkdocs build --strict``: a broken link, a missing page or a bad docstring fails."""
    if shutil.which("mkdocs") is None and not _has_module("mkdocs"):
        pytest.fail("mkdocs is missing: pip install -e '.[docs]'")
    result = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path)],
        cwd=ROOT,
        env=_env(),
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-4000:]
    assert (tmp_path / "settings" / "index.html").is_file()
    assert (tmp_path / "api" / "index.html").is_file()


def _has_module(name: str) -> bool:
    import importlib.util

    return importlib.util.find_spec(name) is not None
