"""Checks of numbers, shared by every settings class and reader: one range check, one
finite-or-None. Pure (no SUMO import); errors are :class:`~sumo_swarm.errors.ConfigError`."""

from __future__ import annotations

import difflib
import math
import operator
from collections.abc import Iterable
from typing import Any

from sumo_swarm.errors import ConfigError

SEED_MAX = 2**31 - 1  # SUMO's --seed is a signed 32-bit integer
_COMPARE = {">": operator.gt, ">=": operator.ge, "<": operator.lt, "<=": operator.le}

# The settings reference (tools/settings_reference.py) reads each key's range from the checks
# themselves, so the page cannot drift from them: while this is a list, every check appends
# (name, bounds, integer) to it. None (always, outside that tool): nothing is kept.
recorded_checks: list[tuple[str, dict[str, float], bool]] | None = None


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
    if recorded_checks is not None:
        recorded_checks.append((name, dict(bounds), integer))
    ok = is_number(value) and (isinstance(value, int) or not integer)
    if ok:
        ok = all(_COMPARE[op](value, bound) for op, bound in bounds)
    if not ok:
        kind = "an integer " if integer else ("" if is_number(value) else "a finite number ")
        limits = " and ".join(f"{op} {_show(bound)}" for op, bound in bounds)
        raise ConfigError(f"{name} must be {kind}{limits}".rstrip() + f", got {value!r}")


_OPS = {"gt": ">", "ge": ">=", "lt": "<", "le": "<="}


def require_order(
    low_name: str, low: float, high_name: str, high: float, *, strict: bool = True
) -> None:
    """Raise ConfigError unless ``low`` < ``high`` (``strict=False``: <=), both finite."""
    if recorded_checks is not None:
        op_low, op_high = ("<", ">") if strict else ("<=", ">=")
        recorded_checks.append((low_name, {op_low: _short(high_name)}, False))  # type: ignore[dict-item]
        recorded_checks.append((high_name, {op_high: _short(low_name)}, False))  # type: ignore[dict-item]
    ok = is_number(low) and is_number(high) and (low < high if strict else low <= high)
    if not ok:
        relation = "<" if strict else "<="
        raise ConfigError(f"{low_name} must be {relation} {high_name}, got {low!r} and {high!r}")


def _short(name: str) -> str:
    return name.rpartition(".")[2]


def _show(bound: float) -> str:
    return f"{bound:g}" if isinstance(bound, float) else str(bound)


def check_fields(owner: object, *names: str, **bounds: Any) -> None:
    """:func:`require_number` on each named field of ``owner`` (fields set to None are skipped)."""
    for name in names:
        value = getattr(owner, name)
        if value is not None:
            require_number(name, value, **bounds)
        elif recorded_checks is not None:  # a None default still has a range when set
            recorded_checks.append(
                (
                    name,
                    {_OPS[k]: b for k, b in bounds.items() if k in _OPS and b is not None},
                    bool(bounds.get("integer")),
                )
            )


def finite_or_none(value: object) -> float | None:
    """``value`` as a plain float, or None when it is None, NaN or infinite (JSON has no NaN)."""
    if value is None:
        return None
    x = float(value)  # type: ignore[arg-type]
    return x if math.isfinite(x) else None


def did_you_mean(name: str, known: Iterable[str]) -> str | None:
    """The known name nearest to a mistyped ``name`` (difflib's ratio, at least 0.6), or None.

    Case is ignored (``Cav`` for ``cav``); for a dotted name the last part is matched too, so
    ``cav.lenght_m`` finds ``cav.length_m`` among other sections' keys.
    """
    names = [str(k) for k in known]
    by_lower = {k.lower(): k for k in names}
    if name.lower() in by_lower:
        return by_lower[name.lower()]
    close = difflib.get_close_matches(name.lower(), list(by_lower), n=1, cutoff=0.6)
    return by_lower[close[0]] if close else None


def unknown_name(
    kind: str,
    name: str,
    known: Iterable[str],
    *,
    prefix: str = "",
    listed_as: str = "known",
    shown: str = "{}",
) -> str:
    """The message for an unknown ``kind`` (key, section, controller, vType, ...) called
    ``name``: the nearest known one first, then all of them (``listed_as`` heads the list).
    ``prefix`` (``"cav."``) is put before ``name`` and the suggestion, not the listed names;
    ``shown`` formats every name shown (``"[{}]"`` for a section)."""
    names = [str(k) for k in known]
    near = did_you_mean(name, names)
    hint = f": did you mean '{prefix}{shown.format(near)}'?" if near is not None else ""
    listed = ", ".join(shown.format(k) for k in names) or "none"
    return f"unknown {kind} '{prefix}{shown.format(name)}'{hint} ({listed_as}: {listed})"
