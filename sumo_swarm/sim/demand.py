"""The CAV share of a user's demand: derived route files in which SUMO itself draws the CAVs.

A share ``p`` of CAVs (vType ``cav_type``) is given to a user's SUMO configuration by rewriting
the type of its vehicles, trips and flows (in the run's own copy of the files, the user's stay as
they are). Every type a vehicle refers to (a vType or a ``vTypeDistribution``) becomes a
distribution of plain vTypes; where that changes its members, the reference is replaced by a
derived ``vTypeDistribution`` defined in the copy just before its first use:

* ``share_of = "distribution"``: in each distribution holding the CAV type, the CAV type gets
  probability ``p`` and the other members share ``1 - p`` in their old proportions;
* ``share_of = "passenger"``: each passenger vehicle (vClass ``passenger``, SUMO's default, and
  the CAVs) is a CAV with probability ``p``: wherever a vehicle's type is drawn among passenger
  types, the CAV type gets ``p`` of their probability and the other passenger types share the
  rest in their old proportions; other classes (trucks, buses, ...) keep theirs, and a vehicle
  that can only be a CAV (``type="cav"``) stays one.

SUMO draws each vehicle's type from the distribution when it builds the vehicle, with the random
number generator of ``--seed``: the CAVs are known from their first step (inserted with the CAV
type's length, speed and lane rules), and the same seed gives the same CAVs. Pure file work: no
SUMO import.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO
from xml.sax.saxutils import XMLGenerator
from xml.sax.xmlreader import AttributesImpl

import defusedxml.sax as safe_sax
from defusedxml import DefusedXmlException
from defusedxml.ElementTree import ParseError, iterparse

from sumo_swarm.errors import ConfigError

SHARE_OF = ("distribution", "passenger")
DEFAULT_VEHTYPE = "DEFAULT_VEHTYPE"  # SUMO's type of a vehicle that names none (passenger)
PASSENGER = "passenger"
VEHICLE_TAGS = frozenset({"vehicle", "trip", "flow"})
DERIVED_PREFIX = "swarm_share_"  # id of the derived distribution of a type reference
# The probabilities written into a derived distribution (SUMO reads them as doubles).
PROBABILITY_DIGITS = 12


@dataclass
class Demand:
    """What a configuration's route and additional files say about vehicle types.

    ``classes``: vType id -> vClass; ``own_probability``: vType id -> its ``probability``
    attribute (the weight a ``vTypes`` list without ``probabilities`` gives it);
    ``distributions``: id -> its members ``(type or distribution id, weight)``; ``first_use``:
    file -> reference -> index of the file's first top-level element that uses it.
    """

    classes: dict[str, str] = field(default_factory=lambda: {DEFAULT_VEHTYPE: PASSENGER})
    own_probability: dict[str, float] = field(default_factory=dict)
    distributions: dict[str, list[tuple[str, float]]] = field(default_factory=dict)
    first_use: dict[Path, dict[str, int]] = field(default_factory=dict)

    @property
    def used(self) -> set[str]:
        """Every type reference of a vehicle, trip or flow."""
        return {ref for refs in self.first_use.values() for ref in refs}

    def vtypes(self) -> list[str]:
        """The vTypes defined in the files (SUMO's implicit default not counted)."""
        return sorted(t for t in self.classes if t != DEFAULT_VEHTYPE)

    def members(self, ref: str, depth: int = 0) -> dict[str, float]:
        """The plain vTypes a reference draws from, with their probabilities (summing to 1)."""
        if ref not in self.distributions:
            return {ref: 1.0}
        if depth > len(self.distributions):
            raise ConfigError(f"vTypeDistribution '{ref}' contains itself")
        weights = self.distributions[ref]
        total = sum(w for _, w in weights)
        if total <= 0.0:
            raise ConfigError(f"vTypeDistribution '{ref}' has no member with a probability > 0")
        out: dict[str, float] = {}
        for member, weight in weights:
            for vtype, q in self.members(member, depth + 1).items():
                out[vtype] = out.get(vtype, 0.0) + weight / total * q
        return out


def _number(text: str, what: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise ConfigError(f"{what}: expected a number, got {text!r}") from None
    if not math.isfinite(value) or value < 0.0:
        raise ConfigError(f"{what}: expected a finite number >= 0, got {text!r}")
    return value


def read_demand(files: Iterable[Path]) -> Demand:
    """Read the vTypes, distributions and type references of ``files`` (additional files first,
    as SUMO loads them, then route files), streaming; ConfigError naming the file if one is
    malformed or unsafe."""
    demand = Demand()
    pending: list[tuple[str, str, str, Path]] = []  # (distribution, vTypes, probabilities, file)
    for path in files:
        uses: dict[str, int] = {}
        demand.first_use[path] = uses
        stack: list[str] = []
        top = -1
        distribution = ""  # the vTypeDistribution being read
        try:
            for event, elem in iterparse(path, events=("start", "end"), forbid_dtd=True):
                if event == "end":
                    stack.pop()
                    if len(stack) <= 1:
                        elem.clear()  # keep memory flat over a long route file
                    continue
                if len(stack) == 1:
                    top += 1
                parent = stack[-1] if stack else None
                stack.append(elem.tag)
                attrs = elem.attrib
                if elem.tag == "vType" and "id" in attrs:
                    vid = attrs["id"]
                    demand.classes[vid] = attrs.get("vClass", PASSENGER)
                    weight = _number(attrs.get("probability", "1"), f"{path}: vType '{vid}'")
                    demand.own_probability[vid] = weight
                    if parent == "vTypeDistribution":
                        demand.distributions[distribution].append((vid, weight))
                elif elem.tag == "vTypeDistribution" and "id" in attrs:
                    did = attrs["id"]
                    demand.distributions[did] = []
                    distribution = did
                    if "vTypes" in attrs:
                        pending.append((did, attrs["vTypes"], attrs.get("probabilities", ""), path))
                elif elem.tag in VEHICLE_TAGS:
                    uses.setdefault(attrs.get("type", DEFAULT_VEHTYPE), max(top, 0))
        except FileNotFoundError:
            raise ConfigError(f"file not found: {path}") from None
        except DefusedXmlException:
            raise ConfigError(f"{path}: an XML file with a DTD or entities is refused") from None
        except ParseError as exc:
            raise ConfigError(f"{path}: malformed XML: {exc}") from None
    for did, listed, probabilities, path in pending:
        names = listed.split()
        if probabilities.strip():
            where = f"{path}: vTypeDistribution '{did}': probabilities"
            weights = [_number(p, where) for p in probabilities.replace(",", " ").split()]
            if len(weights) != len(names):
                raise ConfigError(f"{where}: {len(weights)} values for {len(names)} vTypes")
        else:
            weights = [demand.own_probability.get(n, 1.0) for n in names]
        demand.distributions[did].extend(zip(names, weights, strict=True))
    return demand


def shared_members(
    demand: Demand, ref: str, cav_type: str, share: float, share_of: str
) -> dict[str, float] | None:
    """The vTypes (and probabilities) a vehicle of type ``ref`` draws from with the CAV share
    ``share``; None where the share leaves ``ref`` as it is."""
    members = demand.members(ref)
    if share_of == "distribution":
        if ref not in demand.distributions or cav_type not in members:
            return None
        others = {t: q for t, q in members.items() if t != cav_type}
        rest = sum(others.values())
        if rest <= 0.0 and share < 1.0:
            raise ConfigError(
                f"vTypeDistribution '{ref}' holds only '{cav_type}': no other type to share with"
            )
        new = {t: q / rest * (1.0 - share) for t, q in others.items()} if rest > 0.0 else {}
        new[cav_type] = share
    elif share_of == "passenger":
        cars = {
            t: q
            for t, q in members.items()
            if t != cav_type and demand.classes.get(t, PASSENGER) == PASSENGER
        }
        if not cars:  # only CAVs (a CAV the user placed stays one) or no passenger vehicle
            return None
        pool = sum(cars.values()) + members.get(cav_type, 0.0)  # the passenger vehicles
        new = {t: q for t, q in members.items() if t not in cars and t != cav_type}
        rest = sum(cars.values())
        new.update({t: q / rest * (1.0 - share) * pool for t, q in cars.items()})
        new[cav_type] = share * pool
    else:
        raise ConfigError(f"cav_share_of: expected one of {', '.join(SHARE_OF)}, got {share_of!r}")
    new = {t: q for t, q in new.items() if q > 0.0}
    if new.keys() == members.keys() and all(math.isclose(new[t], members[t]) for t in new):
        return None
    return new


def check_share_applies(demand: Demand, cav_type: str, share_of: str, cfg: Path) -> None:
    """ConfigError unless a share of ``share_of`` changes some vehicle of ``cfg``'s files."""
    if cav_type not in demand.classes or cav_type == DEFAULT_VEHTYPE:
        raise ConfigError(
            f"cav_type: no vType '{cav_type}' in {cfg} (its vTypes: "
            f"{', '.join(demand.vtypes()) or 'none'})"
        )
    used = sorted(demand.used)
    if share_of == "distribution":
        holding = [r for r in used if shared_members(demand, r, cav_type, 0.5, share_of)]
        if not holding:
            raise ConfigError(
                f'cav_share_of = "distribution": no vehicle or flow of {cfg} draws its type '
                f"from a vTypeDistribution holding '{cav_type}' (use \"passenger\" to turn "
                "passenger cars into CAVs)"
            )
    elif share_of == "passenger":
        if not any(shared_members(demand, r, cav_type, 1.0, share_of) for r in used):
            raise ConfigError(
                f'cav_share_of = "passenger": no vehicle or flow of {cfg} is of a vType of '
                f"vClass passenger other than '{cav_type}'"
            )
    else:
        raise ConfigError(f"cav_share_of: expected one of {', '.join(SHARE_OF)}, got {share_of!r}")


def derived_id(ref: str) -> str:
    return f"{DERIVED_PREFIX}{ref}"


def _format(q: float) -> str:
    return f"{q:.{PROBABILITY_DIGITS}g}"


class _Rewriter(XMLGenerator):
    """Copies a file event by event (SAX's method names), defining the derived distributions
    before their first use and pointing the vehicles, trips and flows at them."""

    def __init__(
        self, out: TextIO, changed: Mapping[str, dict[str, float]], first_use: dict[str, int]
    ) -> None:
        super().__init__(out, "utf-8", short_empty_elements=True)
        self.changed = changed
        self.defined_at: dict[int, list[str]] = {}
        for ref, index in first_use.items():
            if ref in changed:
                self.defined_at.setdefault(index, []).append(ref)
        self.depth = 0
        self.top = -1

    def startElement(self, name: str, attrs) -> None:  # noqa: N802
        if self.depth == 1:
            self.top += 1
            for ref in self.defined_at.get(self.top, []):
                members = self.changed[ref]
                super().startElement(
                    "vTypeDistribution",
                    AttributesImpl({
                        "id": derived_id(ref),
                        "vTypes": " ".join(members),
                        "probabilities": " ".join(_format(q) for q in members.values()),
                    }),
                )  # fmt: skip
                super().endElement("vTypeDistribution")
                self.characters("\n    ")
        values = dict(attrs)
        if name in VEHICLE_TAGS:
            ref = values.get("type", DEFAULT_VEHTYPE)
            if ref in self.changed:
                values["type"] = derived_id(ref)
        super().startElement(name, AttributesImpl(values))
        self.depth += 1

    def endElement(self, name: str) -> None:  # noqa: N802
        self.depth -= 1
        super().endElement(name)


def write_shared_demand(
    files: list[Path],
    folder: Path,
    cav_type: str,
    share: float,
    share_of: str,
    demand: Demand | None = None,
) -> dict[Path, Path]:
    """Copies of the ``files`` whose vehicles the share changes, written into ``folder``;
    returns ``{original: copy}`` (files the share leaves alone are not copied). ``demand``:
    :func:`read_demand` of the ``files``, if read already."""
    demand = demand or read_demand(files)
    taken = set(demand.classes) | set(demand.distributions)
    changed: dict[str, dict[str, float]] = {}
    for ref in sorted(demand.used):
        members = shared_members(demand, ref, cav_type, share, share_of)
        if members is not None:
            if derived_id(ref) in taken:
                raise ConfigError(f"vType id '{derived_id(ref)}' is reserved for the CAV share")
            changed[ref] = members
    copies: dict[Path, Path] = {}
    folder.mkdir(parents=True, exist_ok=True)
    for k, path in enumerate(files):
        uses = demand.first_use.get(path, {})
        if not changed.keys() & uses.keys():
            continue
        target = folder / f"{k}_{path.name}"
        with target.open("w", encoding="utf-8") as fh:
            safe_sax.parse(str(path), _Rewriter(fh, changed, uses), forbid_dtd=True)
        copies[path] = target
    return copies
