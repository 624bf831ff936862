"""Run tests against the oldest releases pyproject.toml allows (the other end of every range).

A fresh install gets the newest release of every dependency; this checks the floors. It makes a
virtual environment (its own: nothing of the system's site-packages leaks in), installs the
project with each dependency pinned to the release line of its floor (``pandas>=2.1`` ->
``pandas==2.1.*``: the floor's last patch, the oldest line the file allows) and runs the given
tests there (default: the summary, metrics and bridge tests).

    python tools/oldest_deps.py [--venv DIR] [--print-pins] [PYTEST ARGS...]

Exit status: pytest's (or 1 when the install fails). CI runs it (.ci/run).
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tomllib
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# What the floors are tested on: every summary measure (in memory and streamed, on random
# tables), the bridge to SUMO, the recorder's Parquet round trip (PyArrow), the busy roads under
# all four controllers (OR-Tools, OSQP, SciPy, defusedxml), the figures and the replay
# (Matplotlib, imageio, imageio-ffmpeg) and a markdown table (tabulate).
DEFAULT_TESTS = [
    "tests/test_metrics.py",
    "tests/test_summary.py",
    "tests/test_measures_robust.py",
    "tests/test_bridge_reads.py",
    "tests/test_recorder.py",
    "tests/test_busy_roads.py",
    "tests/test_plots.py",
    "tests/test_replay.py",
    "tests/test_batch.py::test_markdown_table_formats_numbers_flags_and_missing_values",
]
# Extras whose floors are installed with the project's own (ray, of "cluster", is left out:
# only the batch runner on a cluster uses it, and it weighs more than the rest together).
EXTRAS = ("test",)
# The linter and the documentation site's tools: none of the tests run here uses them.
NOT_NEEDED = {"ruff", "mkdocs", "mkdocstrings"}
_FLOOR = re.compile(r"^\s*([A-Za-z0-9_.\-]+(?:\[[^\]]*\])?)\s*>=\s*([0-9][0-9A-Za-z.]*)")


def floor_pin(requirement: str) -> str:
    """``"pandas>=2.1"`` -> ``"pandas==2.1.*"``; a requirement without a floor as it is.

    Upper bounds are dropped: the floor's line lies below them (checked by pip, which refuses
    a pin outside the range it was given)."""
    match = _FLOOR.match(requirement)
    if match is None:
        return requirement.strip()
    name, version = match.groups()
    return f"{name}=={version}.*"


def pins(pyproject: Path = ROOT / "pyproject.toml") -> list[str]:
    """The pins of every dependency of the project and of its :data:`EXTRAS`."""
    project = tomllib.loads(pyproject.read_text(encoding="utf-8"))["project"]
    requirements = list(project["dependencies"])
    for extra in EXTRAS:
        requirements += project.get("optional-dependencies", {}).get(extra, [])
    names = [re.split(r"[<>=!~;\[ ]", r.strip(), maxsplit=1)[0] for r in requirements]
    return [floor_pin(r) for r, n in zip(requirements, names, strict=True) if n not in NOT_NEEDED]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--venv", type=Path, default=ROOT / ".venv-oldest")
    parser.add_argument("--print-pins", action="store_true", help="print the pins and stop")
    args, pytest_args = parser.parse_known_args(argv)
    wanted = pins()
    if args.print_pins:
        print("\n".join(wanted))
        return 0
    python = args.venv / "bin" / "python"
    if not python.exists():
        venv.EnvBuilder(with_pip=True).create(args.venv)
    install = [str(python), "-m", "pip", "install", "--quiet", "--disable-pip-version-check"]
    # The project itself without its dependencies: they are the pins, resolved together.
    for cmd in ([*install, *wanted], [*install, "--no-deps", "-e", str(ROOT)]):
        if subprocess.run(cmd).returncode != 0:
            print(f"oldest_deps: install failed: {' '.join(cmd)}", file=sys.stderr)
            return 1
    shown = ("numpy", "pandas", "pyarrow", "scipy", "libsumo", "ortools", "osqp")
    versions = subprocess.run(
        [str(python), "-c", "from importlib.metadata import version; "
         f"print(', '.join(f'{{n}} {{version(n)}}' for n in {shown!r}))"],
        capture_output=True, text=True,
    )  # fmt: skip
    print(f"oldest_deps: {versions.stdout.strip() or versions.stderr.strip()}", flush=True)
    tests = pytest_args or DEFAULT_TESTS
    # The tests spawn ``python -m sumo_swarm``: the venv's interpreter, the project's code.
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env["PATH"] = f"{python.parent}{os.pathsep}{env.get('PATH', '')}"
    return subprocess.run(
        [str(python), "-m", "pytest", "-q", "-p", "no:cacheprovider", *tests], cwd=ROOT, env=env
    ).returncode


if __name__ == "__main__":
    sys.exit(main())
