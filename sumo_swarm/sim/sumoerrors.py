"""SUMO's errors about a user's files, said as bad input: one line naming the file.

SUMO (through libsumo) says what is wrong ("The edge 'nowhere' within the route 'r' is not
known.", "Invalid departLane definition for vehicle 'c0'.", "maxSpeed must be greater than
0") but, but for XML errors, not in which file. :func:`blame` finds it: the file the message
names, else the user's file that defines an id the message quotes (``id="r"``), else one that
names it in an attribute, else one that sets an attribute the message names (``maxSpeed``).
Pure (no SUMO import).
"""

from __future__ import annotations

import contextlib
import mmap
import os
import re
import sys
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path

from sumo_swarm.errors import ConfigError

_QUOTED = re.compile(r"'([^'\s]{1,200})'")
# An XML attribute as SUMO's messages name them: maxSpeed, departLane, vClass, ...
_ATTRIBUTE = re.compile(r"\b([a-z]+[A-Z][A-Za-z]*)\b")
_PREFIX = re.compile(r"^(SUMO did not start|SUMO stopped at t = [0-9.]+ s): ")


def one_line(text: str) -> str:
    """SUMO's message in one line (it breaks some in two: "... is not known.\\n The route
    can not be build.")."""
    return " ".join(text.split())


def _contains(path: Path, patterns: Sequence[bytes]) -> bool:
    """Whether ``path`` holds any of ``patterns`` (read by mmap: a network may be large)."""
    try:
        with path.open("rb") as fh:
            if path.stat().st_size == 0:
                return False
            with mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ) as data:
                return any(data.find(p) >= 0 for p in patterns)
    except (OSError, ValueError):
        return False


def blame(message: str, files: Sequence[Path]) -> Path | None:
    """The file of ``files`` (in the order given: routes and additionals before the network)
    that SUMO's error ``message`` is about, or None when no file is recognisably it."""
    for path in files:  # SUMO names the file of an XML error ("In file '...'")
        if str(path) in message or f"'{path.name}'" in message:
            return path
    ids = [q.encode() for q in _QUOTED.findall(message)]
    searches: list[list[bytes]] = [
        [b'id="' + i + b'"' for i in ids],  # the file that defines what the message quotes
        [p for i in ids for p in (b'="' + i + b'"', b" " + i + b'"', b'"' + i + b" ")],
        [a.encode() + b'="' for a in _ATTRIBUTE.findall(message)],  # sets the attribute named
    ]
    for patterns in searches:
        if patterns:
            for path in files:
                if _contains(path, patterns):
                    return path
    return None


def input_error(
    message: str,
    files: Sequence[Path],
    configuration: Path,
    *,
    strict: bool = False,
    generated: Sequence[Path] = (),
) -> ConfigError | None:
    """SUMO's error ``message`` as bad input naming the user's file it is about (of
    ``files``) or, failing that, the ``configuration`` that named them; with ``strict``,
    None unless a file is recognisably it (an error mid-run may be SUMO's own).
    ``generated``: files sumo-swarm wrote from the configuration (a scenario's routes): an
    error about them is the configuration's."""
    text = one_line(_PREFIX.sub("", message)) or "an error without a message"
    path = blame(text, [*files, *generated])
    if path is None and strict:
        return None
    if path is None or path in generated:
        what = "SUMO stopped" if strict else "SUMO did not start"
        return ConfigError(f"{configuration}: {what}: {text}")
    named = "" if path == configuration else f" (named in {configuration})"
    return ConfigError(f"{path}: SUMO refuses it: {text}{named}")


@contextlib.contextmanager
def sumo_stderr() -> Iterator[list[str]]:
    """Hold what SUMO writes to the process's standard error (file descriptor 2: libsumo's C++
    messages, which Python's sys.stderr never sees) while the block runs; the list yielded
    gets the text at the end. While a network loads SUMO prints each error itself and raises
    only "Process Error": the caller says it in one line, or passes the text on."""
    sys.stderr.flush()
    saved = os.dup(2)
    held: list[str] = []
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            yield held
        finally:
            sys.stderr.flush()
            os.dup2(saved, 2)
            os.close(saved)
            tmp.seek(0)
            held.append(tmp.read().decode("utf-8", errors="replace"))


def first_error(said: str) -> str | None:
    """SUMO's first ``Error:`` message in ``said`` (its lines continued with a space joined)."""
    found = re.search(r"^Error: (.+(?:\n [^\n]*)*)", said, re.MULTILINE)
    return one_line(found[1]) if found else None
