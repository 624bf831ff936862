"""Sweep files: a base scenario, the parameters to vary, seeds and controllers -> run specs.

A sweep file (TOML)::

    name = "demo"                      # optional; default: the file's stem
    base = "paper.toml"                # the base scenario, relative to this file
    controllers = ["swarm", "cacc"]    # optional; default: swarm and cacc
    seeds = [42, 43]                   # optional; default: the base scenario's seed

    [fixed]                            # applied to every run (not a column of the results)
    "simulation.duration_s" = 60.0

    [grid]                             # cartesian product of these values
    "scene.upstream_gap_m" = [20.0, 25.0, 30.0]

    [[cases]]                          # and/or a list of cases (each crossed with the grid)
    "scene.hv.hv_target.speed_mps" = 15.0
    "scene.hv.hv_target.desired_speed_mps" = 15.0

A sweep over a user's own SUMO configuration names it instead of a base::

    sumocfg = "road.sumocfg"           # relative to this file
    cav_type = "cav"                   # the CAVs' vType
    cav_share_of = "distribution"      # or "passenger" (see sumo_swarm.sim.demand)
    config = "swarm.toml"              # optional: the swarm's settings

    [grid]                             # [fixed] and [[cases]] as above
    cav_share = [0.1, 0.3]             # the CAV share
    scale = [1.0, 1.5]                 # SUMO's --scale

Runs = cases x grid x seeds x controllers. A parameter is a dotted key of the scenario file:
``section.key`` (``cav.count``), a key of a nested table (``planner.weights.w_tar``) or a key of
one item of a list of tables picked by its ``id`` (``scene.hv.hv_target.speed_mps``). Bare
dotted TOML keys (``scene.initial_speed_mps = [...]``) and quoted ones mean the same. Every
value of every run is validated by :func:`sumo_swarm.config.load_scenario` before anything runs.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import itertools
import json
import math
import re
import tomllib
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sumo_swarm.checks import SEED_MAX, require_number, unknown_name
from sumo_swarm.config import (
    SECTIONS,
    Scenario,
    load_scenario,
    nested_dataclass,
    read_toml,
)
from sumo_swarm.controllers import CONTROLLERS
from sumo_swarm.errors import ConfigError
from sumo_swarm.sim.demand import SHARE_OF, check_share_applies, read_demand
from sumo_swarm.sim.runner import (
    SUMO_DEFAULT_SEED,
    check_sumocfg_inputs,
    demand_files,
    normalized_sumocfg_options,
    run_scenario,
    run_sumocfg,
    sumocfg_seed,
    sumocfg_time_s,
)
from sumo_swarm.sim.scene import default_settings
from sumo_swarm.sim.steplimit import check_step_length

SWEEP_KEYS = ("name", "description", "base", "controllers", "seeds", "fixed", "grid", "cases")
# A sweep over a user's SUMO configuration names it (``sumocfg``) instead of a ``base``.
SUMOCFG_SWEEP_KEYS = (
    "name", "description", "sumocfg", "cav_type", "cav_share_of", "config", "controllers",
    "seeds", "fixed", "grid", "cases",
)  # fmt: skip
# Its parameters: SUMO's --scale (the demand factor) and the CAV share (sumo_swarm.sim.demand).
SUMOCFG_PARAMETERS = ("scale", "cav_share")
DEFAULT_CONTROLLERS = ("swarm", "cacc")
# Rough CPU cost per simulated step of each controller, relative to the baselines (measured on
# the paper's scene: a swarm run takes 3-10x a cacc run). Only the order of the runs uses it:
# long runs start first, so that no long run is left alone at the end of a batch.
CONTROLLER_COST = {"swarm": 5.0}
RUN_ID_HASH_CHARS = 12
RUN_ID_PREFIX_CHARS = 48


# --------------------------------------------------------------------------- parameter paths


@dataclass(frozen=True)
class ParamPath:
    """A dotted key compiled against the scenario's dataclasses.

    ``steps`` walks from the section: ``("field", name)`` selects a field (or a key of a nested
    table), ``("item", id)`` selects the item with that ``id`` in a list of tables.
    """

    key: str
    section: str
    steps: tuple[tuple[str, str], ...]

    @property
    def top_field(self) -> str:
        return self.steps[0][1]


def _init_fields(cls: type) -> list[str]:
    return [f.name for f in dataclasses.fields(cls) if f.init]


def compile_key(key: str) -> ParamPath:
    """Check ``key`` against the scenario's structure; ConfigError names what is wrong."""
    if key == "simulation.seed":
        raise ConfigError("'simulation.seed' is not a parameter: list the seeds in seeds = [...]")
    parts = key.split(".")
    if len(parts) < 2 or not all(parts):
        raise ConfigError(f"'{key}': a parameter is a dotted key 'section.key'")
    section = parts[0]
    if section not in SECTIONS:
        raise ConfigError(f"'{key}': {unknown_name('section', section, SECTIONS)}")
    cls: type = SECTIONS[section]
    steps: list[tuple[str, str]] = []
    i = 1
    while i < len(parts):
        name = parts[i]
        known = _init_fields(cls)
        if name not in known:
            where = ".".join(parts[:i]) + "."
            raise ConfigError(unknown_name("key", name, known, prefix=where))
        steps.append(("field", name))
        i += 1
        if i == len(parts):
            break
        nested = nested_dataclass(typing.get_type_hints(cls)[name])
        if nested is not None and nested[0] == "table":
            cls = nested[1]
            continue
        if nested is not None and "id" in _init_fields(nested[1]):
            steps.append(("item", parts[i]))
            i += 1
            if i == len(parts):
                raise ConfigError(f"'{key}': name a key of that item, e.g. '{key}.speed_mps'")
            cls = nested[1]
            continue
        raise ConfigError(f"'{key}': '{'.'.join(parts[:i])}' has no sub-keys")
    return ParamPath(key, section, tuple(steps))


def _apply(section_table: dict[str, Any], path: ParamPath, value: Any) -> None:
    """Set ``path`` to ``value`` in a section's raw TOML table (modified in place)."""
    node: Any = section_table
    steps = path.steps
    for j, (kind, name) in enumerate(steps):
        last = j == len(steps) - 1
        if kind == "item":
            matches = [x for x in node if isinstance(x, dict) and x.get("id") == name]
            if not matches:
                ids = [x.get("id") for x in node if isinstance(x, dict)]
                raise ConfigError(
                    f"'{path.key}': no item with id '{name}' in the base (ids: {ids})"
                )
            node = matches[0]
            continue
        if last:
            node[name] = value
            return
        child = node.get(name)
        if steps[j + 1][0] == "item":
            if not isinstance(child, list):
                raise ConfigError(f"'{path.key}': the base scenario has no list '{name}'")
        elif not isinstance(child, dict):
            child = {}  # a nested table the base leaves at its defaults
            node[name] = child
        node = child


def _jsonable(value: Any) -> Any:
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {k: _jsonable(v) for k, v in dataclasses.asdict(value).items()}
    if isinstance(value, Mapping):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_jsonable(v) for v in value]
    if isinstance(value, Path):
        return str(value)
    return value


def read_value(scenario: Scenario, path: ParamPath) -> Any:
    """The value ``path`` has in a loaded (validated, typed) scenario, as plain JSON data."""
    node: Any = getattr(scenario, path.section)
    for kind, name in path.steps:
        if kind == "item":
            node = next(x for x in node if getattr(x, "id", None) == name)
        elif isinstance(node, Mapping):
            node = node[name]
        else:
            node = getattr(node, name)
    return _jsonable(node)


# --------------------------------------------------------------------------- bases


class TomlBase:
    """A scenario TOML file as the base of a sweep; parameters are overrides of its keys.
    (:class:`SumocfgBase`: a user's SUMO configuration.)"""

    kind = "toml"

    def __init__(self, path: Path) -> None:
        self.path = path.resolve()
        self.default = load_scenario(self.path)  # the base must load on its own
        self.raw = tomllib.loads(self.path.read_text(encoding="utf-8"))

    @property
    def name(self) -> str:
        return self.default.name

    def overrides(self, values: Mapping[str, Any]) -> dict[str, dict[str, Any]]:
        """``load_scenario`` overrides (section -> key -> value) setting the dotted ``values``."""
        data = copy.deepcopy(self.raw)
        touched: set[tuple[str, str]] = set()
        for key, value in values.items():
            path = compile_key(key)
            section = data.setdefault(path.section, {})
            if not isinstance(section, dict):
                raise ConfigError(f"'{key}': [{path.section}] is not a table in the base")
            _apply(section, path, copy.deepcopy(value))
            touched.add((path.section, path.top_field))
        out: dict[str, dict[str, Any]] = {}
        for section, field in sorted(touched):
            out.setdefault(section, {})[field] = data[section][field]
        return out

    def scenario(self, overrides: Mapping[str, Mapping[str, Any]]) -> Scenario:
        return load_scenario(self.path, overrides={k: dict(v) for k, v in overrides.items()})


def load_base(path: Path) -> TomlBase:
    if path.suffix == ".sumocfg":
        raise ConfigError(
            f'{path}: a SUMO configuration is named by sumocfg = "..." (with cav_type), not base'
        )
    if path.suffix != ".toml":
        raise ConfigError(f"{path}: the base must be a scenario .toml file")
    if not path.is_file():
        raise ConfigError(f"base scenario not found: {path}")
    return TomlBase(path)


class SumocfgBase:
    """A user's SUMO configuration as the base of a sweep, its vehicles of vType ``cav_type``
    the swarm; parameters: :data:`SUMOCFG_PARAMETERS`. Checked when loaded: the configuration
    and its files (SUMO reads it), the CAV type among its vTypes, the swarm's settings file."""

    kind = "sumocfg"

    def __init__(
        self, path: Path, cav_type: str, share_of: str | None, config: Path | None
    ) -> None:
        self.path = path.resolve()
        self.options = normalized_sumocfg_options(path)
        check_sumocfg_inputs(path, self.options)
        self.demand = read_demand(demand_files(self.options))
        if cav_type not in self.demand.vtypes():
            vtypes = ", ".join(self.demand.vtypes()) or "none"
            raise ConfigError(f"cav_type: no vType '{cav_type}' in {path} (its vTypes: {vtypes})")
        self.cav_type = cav_type
        self.share_of = share_of
        self.config = str(config.resolve()) if config is not None else None
        self.settings = default_settings(config)  # the settings file must load on its own
        self.step_s = sumocfg_time_s(path, self.options, "step-length", 1.0)
        begin = sumocfg_time_s(path, self.options, "begin", 0.0)
        self.steps = (sumocfg_time_s(path, self.options, "end", 3600.0) - begin) / self.step_s
        # A configuration that asks for a seed from the clock gets SUMO's default here: the
        # seeds are part of the run ids, which must not change between two loads.
        clock = "random" in self.options and self.options["random"].lower() != "false"
        self.seed = SUMO_DEFAULT_SEED if clock else sumocfg_seed(path, self.options)
        self.scale = float(self.options.get("scale", "1"))

    @property
    def name(self) -> str:
        return self.path.stem

    def identity(self) -> dict[str, Any]:
        """What makes the runs of this base what they are, beside the parameters."""
        return {"cav_type": self.cav_type, "cav_share_of": self.share_of, "config": self.config}

    def value(self, key: str, value: Any, where: str) -> float:
        """A parameter's value, checked, as a canonical number (``1`` and ``1.0`` alike)."""
        try:
            if key == "scale":
                require_number(key, value, gt=0.0)
            else:
                require_number(key, value, ge=0.0, le=1.0)
        except ConfigError as exc:
            raise ConfigError(f'{where}."{key}" = {value!r}: {exc}') from None
        return float(value)

    def default(self, key: str) -> float | None:
        """A parameter's value where a run does not set it: the configuration's."""
        return self.scale if key == "scale" else None

    def job(self, values: Mapping[str, Any]) -> SumocfgRun:
        return SumocfgRun(
            cav_type=self.cav_type,
            config=self.config,
            scale=values.get("scale"),
            cav_share=values.get("cav_share"),
            cav_share_of=self.share_of or "distribution",
        )


def load_sumocfg_base(sweep: Path, data: Mapping[str, Any]) -> SumocfgBase:
    """The ``sumocfg`` of a sweep file's ``data``, its CAV type, share and settings checked."""
    for key in ("sumocfg", "cav_type"):
        if key not in data:
            raise ConfigError(f"{key}: missing (a sumocfg sweep names sumocfg and cav_type)")
        if not isinstance(data[key], str) or not data[key]:
            raise ConfigError(f"{key}: expected a non-empty string, got {data[key]!r}")
    path = sweep.parent / data["sumocfg"]
    if not path.is_file():
        raise ConfigError(f"sumocfg: file not found: {path}")
    share_of = data.get("cav_share_of")
    if share_of is not None and share_of not in SHARE_OF:
        raise ConfigError(f"cav_share_of: expected one of {', '.join(SHARE_OF)}, got {share_of!r}")
    config = data.get("config")
    if config is not None:
        if not isinstance(config, str) or not config:
            raise ConfigError(f"config: expected a file name, got {config!r}")
        config = sweep.parent / config
        if not config.is_file():
            raise ConfigError(f"config: file not found: {config}")
    return SumocfgBase(path, data["cav_type"], share_of, config)


# --------------------------------------------------------------------------- runs


@dataclass(frozen=True)
class SumocfgRun:
    """How a run of a user's SUMO configuration differs from the configuration as it is."""

    cav_type: str
    config: str | None  # the swarm's settings file (absolute), None for the defaults
    scale: float | None  # SUMO's --scale; None: the configuration's
    cav_share: float | None  # the CAV share; None: the configuration's own
    cav_share_of: str  # "distribution" or "passenger" (sumo_swarm.sim.demand)


@dataclass(frozen=True)
class RunSpec:
    """One run of a sweep: everything a worker needs (picklable, no open resources)."""

    run_id: str
    base_path: str  # absolute path of the base scenario file (or of the user's sumocfg)
    overrides: dict[str, dict[str, Any]]  # load_scenario overrides, fixed values included
    params: dict[str, Any]  # the swept parameters of this run (dotted key -> value)
    seed: int
    controller: str
    cost: float = 1.0  # a rough relative run time, to start long runs first
    sumocfg: SumocfgRun | None = None  # set when the base is a user's SUMO configuration

    def scenario(self) -> Scenario:
        if self.sumocfg is not None:
            raise ConfigError(f"{self.base_path}: a SUMO configuration, not a scenario file")
        return load_scenario(self.base_path, overrides=copy.deepcopy(self.overrides))

    def run(self, out_dir: Path) -> dict[str, Any]:
        """Run it into ``out_dir`` (headless, no progress bar); the summary."""
        job = self.sumocfg
        # in place: ``out_dir`` is the batch's own staging folder, renamed at the end
        if job is None:
            return run_scenario(
                self.scenario(), self.controller, out_dir, seed=self.seed, progress=False,
                in_place=True,
            )  # fmt: skip
        return run_sumocfg(
            self.base_path, job.cav_type, self.controller, out_dir, config=job.config,
            seed=self.seed, progress=False, scale=job.scale, cav_share=job.cav_share,
            cav_share_of=job.cav_share_of, require_cavs=False, in_place=True,
        )  # fmt: skip


@dataclass(frozen=True)
class Sweep:
    """A loaded and validated sweep file."""

    path: Path
    name: str
    description: str
    base: TomlBase | SumocfgBase
    fixed: dict[str, Any]
    parameters: tuple[str, ...]  # swept keys, grid first, in file order
    controllers: tuple[str, ...]
    seeds: tuple[int, ...]
    runs: tuple[RunSpec, ...]

    def to_json(self) -> dict[str, Any]:
        return {
            "schema": "sumo-swarm/sweep/1",
            "sweep_file": str(self.path),
            "name": self.name,
            "description": self.description,
            "base": str(self.base.path),
            "base_kind": self.base.kind,
            "base_name": self.base.name,
            "fixed": self.fixed,
            "parameters": list(self.parameters),
            "controllers": list(self.controllers),
            "seeds": list(self.seeds),
            "runs": [r.run_id for r in self.runs],
        }


def canonical_json(data: Any) -> str:
    return json.dumps(data, sort_keys=True, separators=(",", ":"), allow_nan=False)


def make_run_id(
    base_name: str, values: Mapping[str, Any], params: Mapping[str, Any], seed: int, controller: str
) -> str:
    """Stable id: readable prefix + hash of base name, every override, seed and controller.

    ``values`` are all the overrides of the run (fixed and swept), as read back from the
    validated scenario, so ``20`` and ``20.0`` give the same id.
    """
    ident = {"base": base_name, "overrides": dict(values), "seed": seed, "controller": controller}
    digest = hashlib.sha256(canonical_json(ident).encode()).hexdigest()[:RUN_ID_HASH_CHARS]
    shown = [f"{v:g}" if isinstance(v, float) else str(v) for v in params.values()]
    prefix = "-".join([controller, f"s{seed}", *shown])
    prefix = re.sub(r"[^A-Za-z0-9.=_-]+", "_", prefix)[:RUN_ID_PREFIX_CHARS].rstrip("-_.")
    return f"{prefix}-{digest}"


# --------------------------------------------------------------------------- loading


def _flatten(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in table.items():
        dotted = f"{prefix}.{key}" if prefix else key
        if isinstance(value, Mapping):
            out.update(_flatten(value, dotted))
        else:
            out[dotted] = value
    return out


def _str_list(value: Any, key: str) -> list[str]:
    if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
        raise ConfigError(f"{key}: expected a non-empty list of strings, got {value!r}")
    if len(set(value)) != len(value):
        raise ConfigError(f"{key}: values must be unique, got {value!r}")
    return value


def _seed_list(value: Any, key: str) -> list[int]:
    ok = isinstance(value, list) and value
    if not ok or not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
        raise ConfigError(f"{key}: expected a non-empty list of integers, got {value!r}")
    for i, seed in enumerate(value):
        require_number(f"{key}[{i}]", seed, ge=0, le=SEED_MAX, integer=True)
    if len(set(value)) != len(value):
        raise ConfigError(f"{key}: values must be unique, got {value!r}")
    return value


def _table(value: Any, key: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise ConfigError(f"{key}: expected a table, got {type(value).__name__}")
    return _flatten(value)


def _strip_base(message: str, base: Path) -> str:
    for prefix in (f"{base}: ", f"{base.name}: "):
        if message.startswith(prefix):
            return message[len(prefix) :]
    return message


def _explain(
    base: TomlBase, values: Mapping[str, Any], where: Mapping[str, str], exc: Exception
) -> str:
    """Name the key that makes a run invalid: the one whose removal makes the run load."""
    for key, value in values.items():
        rest = {k: v for k, v in values.items() if k != key}
        try:
            base.scenario(base.overrides(rest))
        except ConfigError:
            continue
        return f'{where[key]}."{key}" = {value!r}: {_strip_base(str(exc), base.path)}'
    return f"the run with {dict(values)}: {_strip_base(str(exc), base.path)}"


def load_sweep(path: str | Path) -> Sweep:
    """Load and validate a sweep file; any problem raises ConfigError naming the key and file."""
    path = Path(path)
    data = read_toml(path, "sweep file")
    try:
        return _build(path, data)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def find_case(path: str | Path, index: int, controller: str = "swarm") -> RunSpec:
    """The run of case ``index`` (0-based, in the order of the file's ``[[cases]]``) of the
    sweep file ``path`` under ``controller``; ConfigError when there is no such case or run."""
    path = Path(path)
    sweep = load_sweep(path)
    cases = read_toml(path, "sweep file").get("cases", [])
    if not 0 <= index < len(cases):
        raise ConfigError(f"{path}: no case {index} (it lists {len(cases)}: 0..{len(cases) - 1})")
    want = cases[index]

    def matches(params: dict[str, Any]) -> bool:
        return all(
            abs(params[k] - v) < 1e-9 if isinstance(v, float) else params[k] == v
            for k, v in want.items()
        )

    for run in sweep.runs:
        if run.controller == controller and matches(run.params):
            return run
    raise ConfigError(f"{path}: case {index} has no {controller} run")


def _build(path: Path, data: dict[str, Any]) -> Sweep:
    if "sumocfg" in data:
        if "base" in data:
            raise ConfigError("base and sumocfg: give one (a scenario file or a sumocfg)")
        return _build_sumocfg(path, data)
    if "base" not in data and set(data) & set(SECTIONS):
        raise ConfigError(
            "this is a scenario file, not a sweep: run it with 'sumo-swarm run FILE', or write a "
            'sweep whose base = "FILE" (format: sumo-swarm batch --help)'
        )
    unknown = sorted(set(data) - set(SWEEP_KEYS))
    if unknown:
        raise ConfigError(unknown_name("key", unknown[0], SWEEP_KEYS))
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name:
        raise ConfigError(f"name: expected a non-empty string, got {name!r}")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise ConfigError(f"description: expected a string, got {description!r}")
    if "base" not in data:
        raise ConfigError("base: missing (the base scenario file, relative to the sweep file)")
    if not isinstance(data["base"], str) or not data["base"]:
        raise ConfigError(f"base: expected a file name, got {data['base']!r}")
    try:
        base = load_base(path.parent / data["base"])
    except ConfigError as exc:
        raise ConfigError(f"base: {exc}") from None
    controllers = _controllers(data)
    seeds = _seed_list(data.get("seeds", [base.default.simulation.seed]), "seeds")

    fixed = _table(data.get("fixed", {}), "fixed")
    grid = _table(data.get("grid", {}), "grid")
    raw_cases = data.get("cases", [{}])
    if not isinstance(raw_cases, list) or not raw_cases:
        raise ConfigError("cases: expected a non-empty array of tables ([[cases]])")
    cases = [_table(c, f"cases[{i}]") for i, c in enumerate(raw_cases)]

    where: dict[str, str] = {}  # key -> the table it is set in, for messages
    tables = [("fixed", fixed), ("grid", grid)]
    tables += [(f"cases[{i}]", c) for i, c in enumerate(cases)]
    for name_, table in tables:
        for key in table:
            try:
                compile_key(key)
            except ConfigError as exc:
                raise ConfigError(f"{name_}: {exc}") from None
            if where.get(key, name_).split("[")[0] != name_.split("[")[0]:
                raise ConfigError(f'{name_}."{key}": also set in [{where[key].split("[")[0]}]')
            where.setdefault(key, name_)
    parameters, points = _grid_points(grid, cases, seeds, controllers)
    paths = {key: compile_key(key) for key in (*fixed, *parameters)}
    runs: list[RunSpec] = []
    seen: dict[str, dict[str, Any]] = {}
    for i, case in enumerate(cases):
        for point in points:
            values = {**fixed, **case, **point}
            places = {**where, **{k: f"cases[{i}]" for k in case}}
            try:
                overrides = base.overrides(values)
                scenario = base.scenario(overrides)
            except ConfigError as exc:
                raise ConfigError(_explain(base, values, places, exc)) from None
            steps = scenario.simulation.duration_s / scenario.simulation.step_length_s
            canonical = {key: read_value(scenario, paths[key]) for key in values}
            params = {key: read_value(scenario, paths[key]) for key in parameters}
            keys = _run_keys(seen, i, values, base.name, canonical, params, seeds, controllers)
            for run_id, seed, controller, cost in keys:
                runs.append(
                    RunSpec(run_id, str(base.path), overrides, params, seed, controller,
                            steps * cost)
                )  # fmt: skip
    fixed_scenario = base.scenario(base.overrides(fixed))
    return Sweep(
        path=path.resolve(),
        name=name,
        description=description,
        base=base,
        fixed={key: read_value(fixed_scenario, paths[key]) for key in fixed},
        parameters=parameters,
        controllers=tuple(controllers),
        seeds=tuple(seeds),
        runs=tuple(runs),
    )


# The most runs one sweep may hold. Each run is checked (its scenario built) before any starts
# and has a row, a folder and a record: a grid of a million runs would take minutes and
# gigabytes before the first one ran. Split a larger study into several sweeps.
MAX_RUNS = 100_000


def check_run_count(
    cases: Sequence[Mapping[str, Any]],
    grid: Mapping[str, Sequence[Any]],
    seeds: Sequence[int],
    controllers: Sequence[str],
) -> None:
    """ConfigError if the sweep holds more than :data:`MAX_RUNS` runs, counted from the sizes
    of its lists before any run is built."""
    sizes = {"cases": len(cases), **{f'grid."{k}"': len(v) for k, v in grid.items()}}
    sizes.update(seeds=len(seeds), controllers=len(controllers))
    count = math.prod(sizes.values())
    if count > MAX_RUNS:
        product = " x ".join(f"{n} {name}" for name, n in sizes.items() if n > 1)
        raise ConfigError(
            f"{count} runs ({product}) are more than the {MAX_RUNS} a sweep may hold; "
            "split the study into several sweeps"
        )


def _controllers(data: Mapping[str, Any]) -> list[str]:
    controllers = _str_list(data.get("controllers", list(DEFAULT_CONTROLLERS)), "controllers")
    for c in controllers:
        if c not in CONTROLLERS:
            raise ConfigError(f"controllers: {unknown_name('controller', c, CONTROLLERS)}")
    return controllers


def _build_sumocfg(path: Path, data: dict[str, Any]) -> Sweep:
    """A sweep over a user's SUMO configuration: seeds, controllers, ``scale``, ``cav_share``."""
    unknown = sorted(set(data) - set(SUMOCFG_SWEEP_KEYS))
    if unknown:
        listed = "a sumocfg sweep has"
        raise ConfigError(unknown_name("key", unknown[0], SUMOCFG_SWEEP_KEYS, listed_as=listed))
    name = data.get("name", path.stem)
    if not isinstance(name, str) or not name:
        raise ConfigError(f"name: expected a non-empty string, got {name!r}")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise ConfigError(f"description: expected a string, got {description!r}")
    controllers = _controllers(data)
    base = load_sumocfg_base(path, data)
    for controller in controllers:
        check_step_length(base.step_s, controller, f"{base.path}: step-length")
    seeds = _seed_list(data.get("seeds", [base.seed]), "seeds")

    fixed = _table(data.get("fixed", {}), "fixed")
    grid = _table(data.get("grid", {}), "grid")
    raw_cases = data.get("cases", [{}])
    if not isinstance(raw_cases, list) or not raw_cases:
        raise ConfigError("cases: expected a non-empty array of tables ([[cases]])")
    cases = [_table(c, f"cases[{i}]") for i, c in enumerate(raw_cases)]
    tables = [("fixed", fixed), ("grid", grid), *((f"cases[{i}]", c) for i, c in enumerate(cases))]
    for where, table in tables:
        for key in table:
            if key not in SUMOCFG_PARAMETERS:
                known = ", ".join(SUMOCFG_PARAMETERS)
                raise ConfigError(
                    f"{where}: unknown parameter '{key}' (a sumocfg sweep varies: {known})"
                )
    both = sorted(set(fixed) & {k for _, t in tables[1:] for k in t})
    if both:
        raise ConfigError(f'fixed."{both[0]}": also swept in [grid] or [[cases]]')
    both = sorted(set(grid) & {k for _, t in tables[2:] for k in t})
    if both:
        raise ConfigError(f'grid."{both[0]}": also set in [[cases]]')
    shared = any("cav_share" in t for _, t in tables)
    if shared and base.share_of is None:
        raise ConfigError(
            'cav_share_of: missing: say what cav_share is a share of: "distribution" (the CAV '
            'type\'s probability in the vTypeDistributions holding it) or "passenger" (of all '
            "passenger vehicles)"
        )
    if base.share_of is not None and not shared:
        raise ConfigError("cav_share_of: no cav_share in [fixed], [grid] or [[cases]] to apply to")
    if shared:
        check_share_applies(base.demand, base.cav_type, base.share_of or "", base.path)

    parameters, points = _grid_points(grid, cases, seeds, controllers)
    runs: list[RunSpec] = []
    seen: dict[str, dict[str, Any]] = {}
    for i, case in enumerate(cases):
        for point in points:
            raw = {**fixed, **case, **point}
            places = {**dict.fromkeys(fixed, "fixed"), **dict.fromkeys(case, f"cases[{i}]")}
            places.update(dict.fromkeys(point, "grid"))
            values = {key: base.value(key, value, places[key]) for key, value in raw.items()}
            params = {key: values.get(key, base.default(key)) for key in parameters}
            job = base.job(values)
            identity = {**base.identity(), **values}
            overrides = {"sumocfg": dataclasses.asdict(job)}
            keys = _run_keys(seen, i, raw, base.name, identity, params, seeds, controllers)
            for run_id, seed, controller, cost in keys:
                spec = RunSpec(run_id, str(base.path), overrides, params, seed, controller)
                runs.append(dataclasses.replace(spec, cost=base.steps * cost, sumocfg=job))
    return Sweep(
        path=path.resolve(),
        name=name,
        description=description,
        base=base,
        fixed={key: base.value(key, value, "fixed") for key, value in fixed.items()},
        parameters=parameters,
        controllers=tuple(controllers),
        seeds=tuple(seeds),
        runs=tuple(runs),
    )


def _grid_points(
    grid: dict[str, Any],
    cases: list[dict[str, Any]],
    seeds: Sequence[int],
    controllers: Sequence[str],
) -> tuple[tuple[str, ...], list[dict[str, Any]]]:
    """The sweep's parameters (the keys of ``grid`` and ``cases``) and the points of its grid,
    each a ``{key: value}``; every grid entry must be a non-empty list, and the runs are
    counted (:func:`check_run_count`) before any point is made."""
    for key, values in grid.items():
        if not isinstance(values, list) or not values:
            raise ConfigError(f'grid."{key}": expected a non-empty list of values, got {values!r}')
    parameters = tuple(dict.fromkeys([*grid, *(k for c in cases for k in c)]))
    check_run_count(cases, grid, seeds, controllers)
    points = [dict(zip(grid, combo, strict=True)) for combo in itertools.product(*grid.values())]
    return parameters, points


def _run_keys(
    seen: dict[str, dict[str, Any]],
    case: int,
    values: dict[str, Any],
    base_name: str,
    identity: dict[str, Any],
    params: dict[str, Any],
    seeds: Sequence[int],
    controllers: Sequence[str],
) -> list[tuple[str, int, str, float]]:
    """``(run_id, seed, controller, cost per step)`` of each run of one point of a sweep
    (``values``, of ``cases[case]``), every seed under every controller; ``seen`` (run id ->
    the values that made it) refuses a point whose runs repeat an earlier point's."""
    keys = []
    for seed in seeds:
        for controller in controllers:
            run_id = make_run_id(base_name, identity, params, seed, controller)
            if run_id in seen:
                raise ConfigError(
                    f"cases[{case}]: the runs of {values} repeat those of {seen[run_id]}"
                )
            seen[run_id] = values
            keys.append((run_id, seed, controller, CONTROLLER_COST.get(controller, 1.0)))
    return keys


def cases_toml(cases: Sequence[Mapping[str, object]]) -> list[str]:
    """``[[cases]]`` tables of a sweep file, one ``"dotted.key" = value`` line per parameter
    (the generators of tools/ write their sweeps with it)."""
    lines: list[str] = []
    for case in cases:
        lines += ["", "[[cases]]"]
        lines += [f'"{key}" = {_toml_literal(value)}' for key, value in case.items()]
    return lines


def _toml_literal(value: object) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    return repr(value)
