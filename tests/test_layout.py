"""The package's layout: no import cycles anywhere, and one recording path.

Imports are read from the source (``ast``), not by importing: every ``import`` counts, at module
level, inside functions (deferred imports) and under ``TYPE_CHECKING``, since each is a
dependency a reader has to follow. A cycle is found by :mod:`graphlib`'s topological sort.
"""

from __future__ import annotations

import ast
import graphlib
from pathlib import Path

import pytest

import sumo_swarm


def module_name(path: Path, root: Path) -> str:
    """``root/pkg/sub/mod.py`` -> ``pkg.sub.mod``; a package's ``__init__.py`` -> the package."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def import_graph(package_dir: Path) -> dict[str, set[str]]:
    """Each module of the package -> the package's modules it imports (itself left out)."""
    root = package_dir.parent
    files = {module_name(p, root): p for p in sorted(package_dir.rglob("*.py"))}
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        is_package = path.name == "__init__.py"
        deps: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Import):
                deps.update(a.name for a in node.names if a.name in files)
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:  # relative: from the module's package, up level - 1 more
                    anchor = name.split(".")
                    anchor = anchor[: len(anchor) - node.level + (1 if is_package else 0)]
                    base = ".".join([*anchor, base] if base else anchor)
                for alias in node.names:
                    sub = f"{base}.{alias.name}"  # ``from pkg import mod`` imports pkg.mod
                    if sub in files:
                        deps.add(sub)
                    elif base in files:
                        deps.add(base)
        graph[name] = deps - {name}
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One import cycle (``[a, b, ..., a]``), or None."""
    try:
        tuple(graphlib.TopologicalSorter(graph).static_order())
    except graphlib.CycleError as exc:
        return list(exc.args[1])
    return None


def write_package(root: Path, modules: dict[str, str]) -> Path:
    pkg = root / "pkg"
    for rel, text in {"__init__.py": "", **modules}.items():
        (pkg / rel).parent.mkdir(parents=True, exist_ok=True)
        (pkg / rel).write_text(text, encoding="utf-8")
    return pkg


@pytest.mark.parametrize(
    "modules",
    [
        {"a.py": "import pkg.b\n", "b.py": "import pkg.a\n"},
        # deferred, and through ``from pkg import mod``
        {"a.py": "def f():\n    from pkg import b\n", "b.py": "from pkg.a import f\n"},
        # under TYPE_CHECKING, three modules long, one in a subpackage
        {
            "a.py": "import typing\nif typing.TYPE_CHECKING:\n    from pkg.b import B\n",
            "b.py": "from pkg.sub.c import C\n",
            "sub/__init__.py": "",
            "sub/c.py": "from pkg import a\n",
        },
        # relative imports
        {
            "a.py": "from . import b\n",
            "b.py": "from .sub import c\n",
            "sub/c.py": "from .. import a\n",
        },
    ],
)
def test_a_cycle_is_found(tmp_path, modules):
    cycle = find_cycle(import_graph(write_package(tmp_path, modules)))
    assert cycle is not None and cycle[0] == cycle[-1]
    assert set(cycle) >= {"pkg.a"}


def test_no_cycle_in_a_layered_package(tmp_path):
    modules = {
        "a.py": "from pkg import b\nfrom pkg.sub import c\n",
        "b.py": "def f():\n    import pkg.sub.c\n",
        "sub/__init__.py": "",
        "sub/c.py": "import os\n",
    }
    graph = import_graph(write_package(tmp_path, modules))
    assert graph["pkg.a"] == {"pkg.b", "pkg.sub.c"}
    assert graph["pkg.b"] == {"pkg.sub.c"}
    assert find_cycle(graph) is None


PACKAGE = Path(sumo_swarm.__file__).parent


def test_the_package_has_no_import_cycle():
    graph = import_graph(PACKAGE)
    assert len(graph) > 20  # the walk found the package's modules
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle or [])


def test_runner_and_plugin_share_the_recorder_and_not_each_other():
    graph = import_graph(PACKAGE)
    for user in ("sumo_swarm.sim.runner", "sumo_swarm.sim.plugin"):
        assert "sumo_swarm.sim.recorder" in graph[user]
    assert "sumo_swarm.sim.plugin" not in graph["sumo_swarm.sim.runner"]
    assert "sumo_swarm.sim.runner" not in graph["sumo_swarm.sim.plugin"]


def test_the_route_frame_needs_no_sumo():
    """routeframe is pure: no SUMO import, directly or through the package's modules."""
    graph = import_graph(PACKAGE)
    reached, todo = set(), ["sumo_swarm.core.routeframe"]
    while todo:
        name = todo.pop()
        if name not in reached:
            reached.add(name)
            todo.extend(graph[name])
    for name in reached:
        path = PACKAGE.parent / (name.replace(".", "/") + ".py")
        tree = ast.parse(path.read_text(encoding="utf-8"))
        imported = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        imported |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        assert not {m for m in imported if m and m.split(".")[0] in ("libsumo", "traci", "sumo")}


# --------------------------------------------------------------------------- layers

# The folders tell the pipeline's story; each layer imports only itself and the layers below.
LAYERS = {
    "foundation": 0,  # errors, checks, files, safexml, userfiles
    "core": 1,  # the pure pipeline: model, grid, planner, trajectory, tracking, swarming, ...
    "config": 2,  # the scenario's settings, built from core's settings classes
    "controllers": 3,  # swarm, cacc and SUMO's baselines over the core
    "sim": 4,  # SUMO: bridge, scenes, runner, plugin, recorder, metrics, summary, gui
    "study": 5,  # across runs: batch, impact, reproduce, plots, replay
    "top": 6,  # the CLI and the package's own entry points
}
FOUNDATION = {"errors", "checks", "files", "safexml", "userfiles"}


def layer_of(module: str) -> int:
    parts = module.split(".")
    if len(parts) == 1 or parts[1] in ("cli", "__main__"):
        return LAYERS["top"]
    if parts[1] in FOUNDATION:
        return LAYERS["foundation"]
    if parts[1] == "config":
        return LAYERS["config"]
    return LAYERS[parts[1]]


def runtime_imports(package_dir: Path) -> dict[str, set[str]]:
    """The import graph without imports under ``if TYPE_CHECKING:`` (annotations only)."""
    root = package_dir.parent
    files = {module_name(p, root): p for p in sorted(package_dir.rglob("*.py"))}
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
        skip = {
            id(n)
            for node in ast.walk(tree)
            if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
            for n in ast.walk(node)
        }
        deps = set()
        for node in ast.walk(tree):
            if id(node) in skip or not isinstance(node, ast.ImportFrom | ast.Import):
                continue
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [f"{node.module}.{a.name}" for a in node.names] + [node.module or ""]
            )
            deps.update(n for n in names if n in files)
        graph[name] = deps - {name}
    return graph


def test_every_module_imports_only_its_layer_and_those_below():
    graph = runtime_imports(Path(sumo_swarm.__file__).parent)
    wrong = sorted(
        f"{module} ({layer_of(module)}) imports {dep} ({layer_of(dep)})"
        for module, deps in graph.items()
        for dep in deps
        if layer_of(dep) > layer_of(module)
    )
    assert wrong == []


def test_the_layer_check_can_fail():
    assert layer_of("sumo_swarm.core.grid") < layer_of("sumo_swarm.sim.bridge")
    assert layer_of("sumo_swarm.controllers.swarm") < layer_of("sumo_swarm.study.batch.store")
    assert layer_of("sumo_swarm.errors") == 0 and layer_of("sumo_swarm.cli") == LAYERS["top"]
    assert layer_of("sumo_swarm") == LAYERS["top"]
