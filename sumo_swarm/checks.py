"""Checks of numbers, shared by every settings class and reader: one range check, one
finite-or-None. Pure (no SUMO import); errors are :class:`~sumo_swarm.errors.ConfigError`."""

from __future__ import annotations

import math
import operator
from typing import Any

from sumo_swarm.errors import ConfigError

SEED_MAX = 2**31 - 1  # SUMO's --seed is a signed 32-bit integer
_COMPARE = {">": operator.gt, ">=": operator.ge, "<": operator.lt, "<=": operator.le}


def is_number(value: object) -> bool:
    """True for an int or float that is finite (booleans are not numbers here)."""
    return (
        isinstance(value, int | float)
        and not isinstance(value, bool)
        and math.isfinite(float(value))
    )


def require_number(
    name: str,
    value: object,
    *,
    gt: float | None = None,
    ge: float | None = None,
    lt: float | None = None,
    le: float | None = None,
    integer: bool = False,
) -> None:
    """Raise ConfigError naming ``name`` unless ``value`` is a finite number within the bounds.

    ``gt``/``ge``/``lt``/``le``: the bounds (>, >=, <, <=); ``integer``: an int is required.
    NaN and inf never pass, whatever the bounds.
    """
    bounds = [(op, b) for op, b in ((">", gt), (">=", ge), ("<", lt), ("<=", le)) if b is not None]
    ok = is_number(value) and (isinstance(value, int) or not integer)
    if ok:
        ok = all(_COMPARE[op](value, bound) for op, bound in bounds)
    if not ok:
        kind = "an integer " if integer else ("" if is_number(value) else "a finite number ")
        limits = " and ".join(f"{op} {_show(bound)}" for op, bound in bounds)
        raise ConfigError(f"{name} must be {kind}{limits}".rstrip() + f", got {value!r}")


def _show(bound: float) -> str:
    return f"{bound:g}" if isinstance(bound, float) else str(bound)


def check_fields(owner: object, *names: str, **bounds: Any) -> None:
    """:func:`require_number` on each named field of ``owner`` (fields set to None are skipped)."""
    for name in names:
        value = getattr(owner, name)
        if value is not None:
            require_number(name, value, **bounds)


def finite_or_none(value: object) -> float | None:
    """``value`` as a plain float, or None when it is None, NaN or infinite (JSON has no NaN)."""
    if value is None:
        return None
    x = float(value)  # type: ignore[arg-type]
    return x if math.isfinite(x) else None
