"""The settings reference (docs' settings page), generated from the settings dataclasses.

Every key of a scenario file, section by section as ``sumo_swarm.config.SECTIONS`` lists them,
with its type, unit, default, range and one sentence. Nothing is written by hand here:

- the sentence is the first sentence of the key's entry in its class's numpydoc ``Attributes``
  section (or ``field(metadata={"doc": ...})``);
- the unit is the ``[unit]`` of that entry, else the unit in the key's name (``_mps`` -> m/s),
  else ``metadata["unit"]``; keys that hold no quantity (flags, choices, names) have none;
- the range is read from the class's own checks (``sumo_swarm.checks`` records every bound the
  defaults are checked against), from a ``Literal`` type's choices, or ``metadata["range"]``.

Run ``python tools/settings_reference.py [--out FILE]`` to print or write the page; the docs
build generates it with the hook in docs/hooks.py, and tests/test_docs.py checks that every key
has a unit (where it holds a quantity), a default and a range.
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import re
import sys
import types
import typing
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:  # run as a script from anywhere
    sys.path.insert(0, str(ROOT))

from sumo_swarm import checks  # noqa: E402
from sumo_swarm.config import DERIVED_KEYS, SECTIONS, nested_dataclass  # noqa: E402

# The unit a key's name ends with (longest suffix first): the project's naming rule.
NAME_UNITS = {
    "_mps2": "m/s²",
    "_m2ps2": "m²/s²",
    "_mps": "m/s",
    "_vph": "veh/h",
    "_deg": "deg",
    "_rad": "rad",
    "_ms": "ms",
    "_pct": "%",
    "_share": "1 (share)",
    "_ratio": "1 (ratio)",
    "_rows": "rows",
    "_steps": "steps",
    "_intervals": "intervals",
    "_plans": "plans",
    "_s": "s",
    "_m": "m",
}
NO_UNIT = "—"  # keys that hold no quantity: flags, choices, names


@dataclass(frozen=True)
class Key:
    """One line of the reference."""

    section: str  # e.g. "swarm", "planner.weights", "scene.hv"
    name: str
    type_name: str
    unit: str
    default: str
    range: str
    doc: str

    @property
    def is_quantity(self) -> bool:
        return self.type_name.startswith(("float", "int", "list of float", "list of int"))


# --------------------------------------------------------------------------- sources


def attribute_docs(cls: type) -> dict[str, str]:
    """The numpydoc ``Attributes`` entries of ``cls``'s docstring: name -> text (an entry
    naming several keys, ``a, b``, is given to each)."""
    doc = inspect.getdoc(cls) or ""
    match = re.search(r"^Attributes\n-+\n(.*?)(?=^\S.*\n-+\n|\Z)", doc, re.S | re.M)
    if match is None:
        return {}
    entries: dict[str, str] = {}
    names: list[str] = []
    for line in match.group(1).splitlines():
        if line and not line[0].isspace():
            names = [n.strip() for n in line.split(":")[0].split(",")]
            for name in names:
                entries[name] = ""
        elif names:
            for name in names:
                entries[name] = (entries[name] + " " + line.strip()).strip()
    return entries


def first_sentence(text: str) -> str:
    """Up to the first full stop followed by a space and a capital or the end, backticks kept."""
    text = " ".join(text.split())
    match = re.search(r"(?<!e\.g)(?<!i\.e)(?<!vs)\.(\s+(?=[A-Z(`\"])|$)", text)
    return text[: match.start() + 1] if match else text


def unit_of(name: str, doc: str, meta: dict[str, Any]) -> str:
    if "unit" in meta:
        return str(meta["unit"])
    bracket = re.search(r"\[([^\]]+)\]", doc)
    if bracket and not bracket.group(1).startswith(("rows,", "`")):
        return bracket.group(1).replace("^2", "²")
    if bracket:
        return bracket.group(1).split(",")[0]
    for suffix, unit in NAME_UNITS.items():
        if name.endswith(suffix):
            return unit
    return ""


def recorded_ranges(cls: type) -> dict[str, tuple[dict[str, float], bool]]:
    """The bounds ``cls``'s own checks hold each key to, read by building its default."""
    checks.recorded_checks = []
    try:
        cls()
        found = list(checks.recorded_checks)
    finally:
        checks.recorded_checks = None
    names = {f.name for f in dataclasses.fields(cls)}
    ranges: dict[str, tuple[dict[str, float], bool]] = {}
    for name, bounds, integer in found:
        key = name.rpartition(".")[2]
        if key in names:
            merged = ranges.get(key, ({}, False))
            ranges[key] = ({**merged[0], **bounds}, merged[1] or integer)
    return ranges


# --------------------------------------------------------------------------- formatting


def type_name(tp: Any) -> str:
    origin = typing.get_origin(tp)
    if origin is Literal:
        return " | ".join(f'"{a}"' if isinstance(a, str) else str(a) for a in typing.get_args(tp))
    if origin in (typing.Union, types.UnionType):
        parts = [a for a in typing.get_args(tp) if a is not type(None)]
        text = " or ".join(type_name(a) for a in parts)
        return f"{text} or none" if len(parts) < len(typing.get_args(tp)) else text
    if origin is tuple:
        args = [a for a in typing.get_args(tp) if a is not Ellipsis]
        return f"list of {type_name(args[0])}" if args else "list"
    return getattr(tp, "__name__", str(tp))


def toml_value(value: Any) -> str:
    if value is None:
        return "none"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, tuple | list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    if isinstance(value, float):
        return f"{value:g}" if abs(value) < 1e6 else f"{value:.0f}"
    return str(value)


def _bound(value: float) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def range_of(tp: Any, recorded: tuple[dict[str, float], bool] | None, meta: dict[str, Any]) -> str:
    if "range" in meta:
        return str(meta["range"])
    choices = [
        a for m in _members(tp) if typing.get_origin(m) is Literal for a in typing.get_args(m)
    ]
    flags = any(m is bool for m in _members(tp))
    parts: list[str] = []
    if recorded is not None and recorded[0]:
        bounds = recorded[0]
        low = next((f"{op} {_bound(bounds[op])}" for op in (">", ">=") if op in bounds), "")
        high = next((f"{op} {_bound(bounds[op])}" for op in ("<", "<=") if op in bounds), "")
        parts.append(" and ".join(p for p in (low, high) if p))
    if flags:
        parts.append("true, false")
    if choices:
        parts.append(", ".join(f'"{c}"' if isinstance(c, str) else str(c) for c in choices))
    if type(None) in _members(tp) and parts:
        parts.append("none")
    return "; ".join(parts)


def _members(tp: Any) -> tuple[Any, ...]:
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return typing.get_args(tp)
    return (tp,)


# --------------------------------------------------------------------------- the keys


def section_keys(section: str, cls: type) -> Iterator[Key]:
    """The keys of one section (a nested table or list of tables after its parent's keys)."""
    hints = typing.get_type_hints(cls)
    docs = attribute_docs(cls)
    ranges = recorded_ranges(cls)
    derived = DERIVED_KEYS.get(section, {})
    default = cls()
    nested: list[tuple[str, type]] = []
    for f in dataclasses.fields(cls):
        if not f.init or f.name in derived:
            continue
        inner = nested_dataclass(hints[f.name])
        if inner is not None and typing.get_origin(hints[f.name]) is not Literal:
            nested.append((f"{section}.{f.name}", inner[1]))
            continue
        meta = dict(f.metadata)
        doc = str(meta.get("doc", docs.get(f.name, "")))
        yield Key(
            section=section,
            name=f.name,
            type_name=type_name(hints[f.name]),
            unit=unit_of(f.name, doc, meta),
            default=toml_value(getattr(default, f.name)),
            range=range_of(hints[f.name], ranges.get(f.name), meta),
            doc=first_sentence(doc),
        )
    for sub_section, sub_cls in nested:
        yield from _nested_keys(sub_section, sub_cls)


def _nested_keys(section: str, cls: type) -> Iterator[Key]:
    try:
        cls()
    except TypeError:  # a list item with required keys (scene.hv): no default instance
        yield from _item_keys(section, cls)
        return
    yield from section_keys(section, cls)


def _item_keys(section: str, cls: type) -> Iterator[Key]:
    hints = typing.get_type_hints(cls)
    docs = attribute_docs(cls)
    for f in dataclasses.fields(cls):
        meta = dict(f.metadata)
        doc = str(meta.get("doc", docs.get(f.name, "")))
        has_default = f.default is not dataclasses.MISSING
        yield Key(
            section=section,
            name=f.name,
            type_name=type_name(hints[f.name]),
            unit=unit_of(f.name, doc, meta),
            default=toml_value(f.default) if has_default else "required",
            range=range_of(hints[f.name], _item_range(cls, f.name), meta),
            doc=first_sentence(doc),
        )


def _item_range(cls: type, name: str) -> tuple[dict[str, float], bool] | None:
    """Bounds of a list item's key, from the checks of an item built with its required keys
    set to a value in range (``metadata["example"]``, else 1)."""
    required = {
        f.name: f.metadata.get("example", 1)
        for f in dataclasses.fields(cls)
        if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    }
    checks.recorded_checks = []
    try:
        cls(**required)
        found = list(checks.recorded_checks)
    finally:
        checks.recorded_checks = None
    bounds: dict[str, float] = {}
    integer = False
    for key, b, i in found:
        if key.rpartition(".")[2] == name:
            bounds.update(b)
            integer = integer or i
    return (bounds, integer) if bounds else None


def all_keys() -> list[Key]:
    return [key for section, cls in SECTIONS.items() for key in section_keys(section, cls)]


# --------------------------------------------------------------------------- the page


def _cell(text: str) -> str:
    return text.replace("|", "\\|") or " "


def render(keys: list[Key] | None = None) -> str:
    keys = all_keys() if keys is None else keys
    lines = [
        "# Settings reference",
        "",
        "Every key of a scenario file (and of the `--config` file of `run --sumocfg`), generated",
        "from the settings classes of `sumo_swarm/config.py` and the modules they come from by",
        "`tools/settings_reference.py`: type, unit, default, the range the loader accepts, and",
        "what the key does. An unknown key, a wrong type or a value out of range is refused",
        "(exit status 2, one line naming the key and the file). Where a default came from is",
        "in [Results history](results-history.md).",
        "",
        "A key is written `key = value` in its `[section]`; a nested table as",
        "`[planner.weights]`, and the placed HVs of a scene as `[[scene.hv]]` items.",
        "",
    ]
    derived = [
        f"`{section}.{key}` (from `{source}`)"
        for section, keys_ in DERIVED_KEYS.items()
        for key, source in keys_.items()
    ]
    lines += [
        "Set elsewhere, so refused in their own section: " + ", ".join(derived) + ".",
        "",
    ]
    section = None
    for key in keys:
        if key.section != section:
            section = key.section
            cls = _class_of(section)
            lines += ["", f"## [{section}]", ""]
            summary = first_sentence(inspect.getdoc(cls) or "") if cls is not None else ""
            if summary:
                lines += [summary, ""]
            lines += [
                "| key | type | unit | default | range | what it does |",
                "| --- | --- | --- | --- | --- | --- |",
            ]
        lines.append(
            f"| `{key.name}` | {_cell(key.type_name)} | {_cell(key.unit or NO_UNIT)} | "
            f"`{_cell(key.default)}` | {_cell(key.range)} | {_cell(key.doc)} |"
        )
    return "\n".join(lines) + "\n"


def _class_of(section: str) -> type | None:
    head, *rest = section.split(".")
    cls: Any = SECTIONS.get(head)
    for part in rest:
        if cls is None:
            return None
        inner = nested_dataclass(typing.get_type_hints(cls)[part])
        cls = inner[1] if inner else None
    return cls


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, help="write the page here (default: print it)")
    args = parser.parse_args(argv)
    page = render()
    if args.out is None:
        sys.stdout.write(page)
    else:
        args.out.write_text(page, encoding="utf-8")
        print(f"settings reference: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
