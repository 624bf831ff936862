"""Every file a user names is checked here before anything reads it: it must be a regular file
(not a folder, a device, a FIFO or a socket, which would hang a reader or never end) of bounded
size. The one way sumo-swarm reads a user's file; every problem is a ConfigError naming the
file (exit status 2 on the command line).

Pure (no SUMO import).
"""

from __future__ import annotations

import json
import os
import re
import stat
import urllib.parse
from pathlib import Path
from typing import Any

from sumo_swarm.errors import ConfigError

# Files sumo-swarm reads whole into memory and parses (scenario, sweep and settings TOML,
# SUMO configurations, JSON records) [bytes]: the largest real one is a few kB.
MAX_TEXT_BYTES = 64 * 2**20
# SUMO networks, route files and a run's tables [bytes]: a country's network is about 1 GB.
MAX_DATA_BYTES = 4 * 2**30


def check_user_file(path: str | Path, what: str, max_bytes: int = MAX_TEXT_BYTES) -> Path:
    """``path`` if it is a regular file of at most ``max_bytes``; ConfigError naming the file
    (``what`` says what it is: "scenario file", "SUMO network", ...) otherwise."""
    path = Path(path)
    try:
        info = path.stat()  # follows symbolic links: a link to a regular file is fine
    except FileNotFoundError:
        raise ConfigError(f"{what} not found: {path}") from None
    except (OSError, ValueError) as exc:  # ValueError: a NUL byte in the name
        raise ConfigError(f"cannot read {what} {path}: {_reason(exc)}") from None
    if stat.S_ISDIR(info.st_mode):
        raise ConfigError(f"cannot read {what} {path}: it is a folder, not a file")
    if not stat.S_ISREG(info.st_mode):
        raise ConfigError(f"cannot read {what} {path}: not a regular file ({_kind(info.st_mode)})")
    if info.st_size > max_bytes:
        raise ConfigError(
            f"cannot read {what} {path}: {info.st_size} bytes, more than the "
            f"{_size(max_bytes)} a {what} may have"
        )
    return path


def read_user_bytes(path: str | Path, what: str, max_bytes: int = MAX_TEXT_BYTES) -> bytes:
    """The bytes of a user's file, checked by :func:`check_user_file`; a file that grows past
    ``max_bytes`` while read (``/proc`` files say they are empty) is refused too."""
    path = check_user_file(path, what, max_bytes)
    try:
        # O_NONBLOCK: should the file be swapped for a FIFO after the check, open does not wait
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
        with os.fdopen(fd, "rb") as fh:
            data = fh.read(max_bytes + 1)
    except OSError as exc:
        raise ConfigError(f"cannot read {what} {path}: {_reason(exc)}") from None
    if len(data) > max_bytes:
        raise ConfigError(f"cannot read {what} {path}: more than {_size(max_bytes)}")
    return data


# How much of an XML file is read to find its root element [bytes]: past any declaration and
# leading comments of a real file.
ROOT_SNIFF_BYTES = 64 * 2**10
_FIRST_TAG = re.compile(r"<\s*([A-Za-z_][\w.:-]*)")
_SKIPPED = re.compile(r"<!--.*?-->|<\?.*?\?>|<!\w[^>]*>", re.DOTALL)


def xml_root_name(path: str | Path) -> str | None:
    """The name of the root element of XML file ``path``, read from its first bytes only (a
    network may be a gigabyte); None if not found there, or not readable as text."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(ROOT_SNIFF_BYTES)
    except OSError:
        return None
    utf16 = head[:2] in (b"\xff\xfe", b"\xfe\xff")  # a byte-order mark
    text = head.decode("utf-16" if utf16 else "utf-8", errors="ignore")
    found = _FIRST_TAG.search(_SKIPPED.sub("", text))
    return found.group(1) if found else None


def read_user_text(path: str | Path, what: str, max_bytes: int = MAX_TEXT_BYTES) -> str:
    """A user's file as UTF-8 text (see :func:`read_user_bytes`)."""
    data = read_user_bytes(path, what, max_bytes)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"cannot read {what} {path}: not UTF-8 text ({exc.reason})") from None


def read_user_json(path: str | Path, what: str) -> Any:
    """A user's JSON file; ConfigError naming it when it is unreadable or not JSON."""
    text = read_user_text(path, what)
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}: malformed {what}: {exc}") from None


def read_user_parquet(path: str | Path, what: str, **kwargs: Any):
    """A Parquet table a user's folder holds (a run's or a batch's); ConfigError naming the
    file when it is not a regular file or not Parquet. ``kwargs`` go to ``pd.read_parquet``."""
    import pandas as pd

    path = check_user_file(path, what, MAX_DATA_BYTES)
    try:
        return pd.read_parquet(path, **kwargs)
    except (MemoryError, KeyboardInterrupt):
        raise
    except Exception as exc:  # pyarrow's errors have no common base but Exception
        raise ConfigError(f"cannot read {what} {path}: {_reason(exc)}") from None


def check_sumo_path(path: str | Path, what: str) -> None:
    """ConfigError unless SUMO can take ``path`` as it is: SUMO reads a ``%`` and two hex
    digits in a file path it is given (``my%41road``) as an escaped character (``myAroad``)
    and looks for a file that is not there. Spaces and non-ASCII letters are fine."""
    escaped = re.search(r"%[0-9A-Fa-f]{2}", str(path))
    if escaped:
        raise ConfigError(
            f"{what} {path}: SUMO reads '{escaped[0]}' in a path as an escaped character and "
            "would not find it; rename the folder or file without '%'"
        )


def sumo_saved_path(value: str) -> str:
    """A file path as SUMO writes it into a configuration it saves (``--save-configuration``):
    an absolute one percent-encoded (a space as %20, '%' as %25, ';' as %3b), a relative one
    as it is. Read back as written, a folder "my road" became "my%20road", not found."""
    return urllib.parse.unquote(value) if os.path.isabs(value) else value


def _reason(exc: BaseException) -> str:
    text = getattr(exc, "strerror", None) or str(exc) or type(exc).__name__
    return " ".join(str(text).split())  # one line


def _kind(mode: int) -> str:
    kinds = (
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISCHR, "a character device"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
    )
    return next((name for test, name in kinds if test(mode)), "a special file")


def _size(n_bytes: int) -> str:
    return f"{n_bytes / 2**30:g} GiB" if n_bytes >= 2**30 else f"{n_bytes / 2**20:g} MiB"
