"""Parse users' XML files safely with defusedxml: no DTD, so no entity expansion (billion
laughs) and no external entities, whatever the file's encoding; every problem is a ConfigError
naming the file."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

from defusedxml import DefusedXmlException
from defusedxml.ElementTree import fromstring

from sumo_swarm.errors import ConfigError
from sumo_swarm.userfiles import MAX_DATA_BYTES, read_user_bytes


def parse_xml(path: Path, what: str = "XML file", max_bytes: int = MAX_DATA_BYTES) -> ET.Element:
    """The root element of ``path``; ConfigError if missing, no regular file, larger than
    ``max_bytes``, unreadable, malformed or with a DTD."""
    data = read_user_bytes(path, what, max_bytes)
    try:
        # The parser sees the document after decoding (UTF-8, UTF-16, ...), so a DTD is found
        # in any encoding; forbid_dtd refuses even a DTD without entities.
        return fromstring(data, forbid_dtd=True)
    except DefusedXmlException:
        unsafe = f"{what} with a DTD or entities is refused (unsafe XML)"
        raise ConfigError(f"{path}: {unsafe}") from None
    except ET.ParseError as exc:
        raise ConfigError(f"{path}: malformed {what}: {exc}") from None
