"""A summary's measures taken one by one, so that one that fails costs itself, never the summary.

A run's summary is made of a dozen measures on its tables (speeds, gaps, the overtake's times,
the upstream block, ...). A measure that raises on a table nobody foresaw (a library's corner
case, a road of a shape never tried) must not lose the run's summary.json, and with it the other
measures and the simulation that made them. Each measure is taken through
:meth:`MeasureErrors.take`: its value, or, when it raises, its default (None) and the reason,
kept under the measure's name for summary.json's ``errors`` block (``{}`` when none failed).

Names are the summary keys the measure fills: ``cav.speed`` (the CAV speed statistics),
``cav.gap``, ``cav.travel_time_s``, ``overtake.times`` (``t_end_s``, ``t_regrouped_s``),
``upstream``, ``safety.min_ttc_s``, ``safety.hard_brakes``, ``network.speed_field``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any, TypeVar

log = logging.getLogger(__name__)

T = TypeVar("T")


class MeasureErrors:
    """The measures of one summary, each taken through :meth:`take`; ``reasons``: the measures
    that failed, name -> ``"ExceptionType: message"`` (the first failure of each)."""

    def __init__(self) -> None:
        self.reasons: dict[str, str] = {}

    def failed(self, name: str) -> bool:
        return name in self.reasons

    def take(self, name: str, measure: Callable[..., T], *args: Any, default: Any = None,
             **kwargs: Any) -> T | Any:  # fmt: skip
        """``measure(*args, **kwargs)``, or ``default`` when it raises (the reason kept under
        ``name``) or when ``name`` failed before: a measure taken a slice of the run at a time
        stops at its first failure, as what it gathered after it would be partial."""
        if name in self.reasons:
            return default
        try:
            return measure(*args, **kwargs)
        except Exception as exc:  # any failure of one measure is its own, not the summary's
            self.reasons[name] = f"{type(exc).__name__}: {exc}"
            log.warning("summary: %s not measured: %s", name, self.reasons[name])
            return default
