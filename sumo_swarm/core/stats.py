"""Summary statistics of samples the controllers collect (solve times, tracking errors).

Pure (numpy), below the controllers that use them (the measures of a whole run are in
:mod:`sumo_swarm.sim.metrics`).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from sumo_swarm.checks import finite_or_none


def _finite(samples: Iterable[float | None]) -> np.ndarray:
    """The finite values of ``samples`` as a float array (None, NaN and inf dropped)."""
    values = np.array([np.nan if x is None else float(x) for x in samples], dtype=float)
    return values[np.isfinite(values)]


def lateral_rms(errors: Iterable[float | None]) -> float | None:
    """Root mean square of lateral tracking errors [m]: ``sqrt(mean(e^2))``.

    None and non-finite entries (steps without a reference) are skipped; None when nothing is
    left.
    """
    values = _finite(errors)
    return finite_or_none(np.sqrt(np.mean(values**2))) if values.size else None


def summarise_ms(samples: Iterable[float | None], prefix: str = "") -> dict[str, float | None]:
    """Median, 95th percentile and maximum of durations in milliseconds.

    Percentiles interpolate linearly between samples (numpy's default). None and non-finite
    samples are skipped. Keys are ``{prefix}median, {prefix}p95, {prefix}max``, e.g.
    ``prefix="solve_ms_"`` gives the contract's planner keys; values are None when empty.
    """
    values = _finite(samples)
    if values.size == 0:
        stats: list[float | None] = [None, None, None]
    else:
        picks = (np.median(values), np.percentile(values, 95), values.max())
        stats = [finite_or_none(x) for x in picks]
    return {
        f"{prefix}{name}": value
        for name, value in zip(("median", "p95", "max"), stats, strict=True)
    }
