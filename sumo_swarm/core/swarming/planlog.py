"""plans.jsonl: one JSON line per plan (time, trigger, status, cells, ...), and plan listeners.

A listener is any callable taking the plan record (a dict): sumo-gui drawing of the grid and
the planned cells uses it. A listener that fails is logged and dropped, never the run.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

PlanListener = Callable[[dict[str, Any]], None]


class PlanLog:
    """Writes every plan record to ``out_dir/plans.jsonl`` (if given) and tells listeners."""

    def __init__(self, out_dir: Path | None) -> None:
        self._file = None
        if out_dir is not None:
            self._file = (Path(out_dir) / "plans.jsonl").open("w", encoding="utf-8")
        self.listeners: list[PlanListener] = []
        self.count = 0

    def write(self, record: dict[str, Any]) -> None:
        self.count += 1
        if self._file is not None:
            self._file.write(json.dumps(record, default=_json_default) + "\n")
            self._file.flush()
        for listener in list(self.listeners):
            try:
                listener(record)
            except Exception:  # drawing must never stop the simulation
                log.exception("plan listener failed; it is removed")
                self.listeners.remove(listener)

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None


def _json_default(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, tuple | set | frozenset):
        return list(obj)
    return str(obj)
