"""Parse users' XML files safely: no DTDs, so no entity expansion (billion laughs) and no
external entities; every problem is a ConfigError naming the file."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

from sumo_swarm.errors import ConfigError


def parse_xml(path: Path, what: str = "XML file") -> ET.Element:
    """The root element of ``path``; ConfigError if missing, unreadable, malformed or with a DTD."""
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise ConfigError(f"{what} not found: {path}") from None
    except OSError as exc:
        raise ConfigError(f"cannot read {what} {path}: {exc.strerror or exc}") from None
    if b"<!DOCTYPE" in data or b"<!ENTITY" in data:
        raise ConfigError(f"{path}: {what} with a DTD or entities is refused (unsafe XML)")
    try:
        return ET.fromstring(data)
    except ET.ParseError as exc:
        raise ConfigError(f"{path}: malformed {what}: {exc}") from None
