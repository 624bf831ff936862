"""Time-to-collision conflicts counted from the vehicles a run reads at every step.

summary.json's ``network.ttc_below_1_5s_events`` counts conflicts: encounters of two vehicles
during which the time to collision fell below a threshold (1.5 s). SUMO's SSM device counts
them too, but it keeps every step of every open encounter in memory until the encounter ends,
and in a jam encounters last as long as the jam: over the hour of ``scenarios/corridor.toml``
under sumo-cacc it held 11.6-12 GB (docs/bench/memory.md). :class:`TtcConflictCounter` counts
the same thing with a few numbers per pair of vehicles:

- the pairs are :func:`~sumo_swarm.sim.metrics.gaps`' (a follower and the vehicle ahead of it in
  its lane, sublane overlaps included), with its time to collision;
- an encounter of a pair lasts while the two are paired, with breaks of up to
  ``extra_time_s`` (SSM's ``device.ssm.extratime``, 5 s by default): a pair that meets again
  later is a new encounter;
- an encounter is a conflict when its time to collision fell below ``threshold_s`` at some
  step; it counts once, at the step it first did.

Where it differs from SSM (the two on the same runs: docs/bench/memory.md): SSM writes each
conflict twice, once from each vehicle's device (ego and foe swapped), where this counts the
encounter once; and SSM sees two vehicles side by side in one lane (SUMO's sublane model) as
one behind the other, overlapping, with a time to collision of 0, where
:func:`~sumo_swarm.sim.metrics.gaps` pairs only vehicles whose widths overlap sideways.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pandas as pd

SSM_EXTRA_TIME_S = 5.0  # SUMO's default device.ssm.extratime [s]


class TtcConflictCounter:
    """Conflicts (encounters whose time to collision fell below ``threshold_s``), counted from
    :func:`~sumo_swarm.sim.metrics.gaps`' pairs given a batch of whole steps at a time, in time
    order. Held between batches: the pairs whose encounter may still go on (seen within
    ``extra_time_s``), a time and a flag each."""

    def __init__(self, threshold_s: float = 1.5, extra_time_s: float = SSM_EXTRA_TIME_S) -> None:
        self.threshold_s = threshold_s
        self.extra_time_s = extra_time_s
        self.events = 0  # encounters that were conflicts, each counted once
        # pair "follower\nleader" -> (last time paired [s], already counted)
        self._open: dict[str, tuple[float, bool]] = {}

    def add(self, pairs: pd.DataFrame) -> None:
        """A batch of whole steps, later than any batch before: :func:`metrics.gaps`' table
        (``time_s, vehicle, leader, ttc_s``)."""
        paired = pairs["leader"].notna().to_numpy()
        if not paired.any():
            self._forget_before(None)
            return
        sub = pairs.loc[paired, ["time_s", "vehicle", "leader", "ttc_s"]]
        code, name_of = _pair_codes(sub["vehicle"], sub["leader"])
        t = sub["time_s"].to_numpy(dtype=float)
        below = sub["ttc_s"].to_numpy(dtype=float) < self.threshold_s  # NaN/inf: not below
        order = np.lexsort((t, code))
        code, t, below = code[order], t[order], below[order]
        rows = np.arange(len(sub))[order]  # each sorted row's place in ``sub``
        n = len(code)
        # Rows split into encounters at each pair's first row and after a break longer than the
        # extra time; a pair's first encounter here may go on from the batch before (carried).
        first_of_pair = np.ones(n, dtype=bool)
        first_of_pair[1:] = code[1:] != code[:-1]
        start = first_of_pair.copy()
        start[1:] |= t[1:] - t[:-1] > self.extra_time_s + 1e-9
        carried = np.zeros(n, dtype=bool)  # the row's encounter was counted before this batch
        for i in np.flatnonzero(first_of_pair):
            held = self._open.get(name_of(rows[i]))
            if held is not None and t[i] - held[0] <= self.extra_time_s + 1e-9:
                carried[i] = held[1]
        encounter = np.cumsum(start) - 1
        m = int(encounter[-1]) + 1
        any_below = np.zeros(m, dtype=bool)
        np.logical_or.at(any_below, encounter, below)
        was_counted = np.zeros(m, dtype=bool)
        np.logical_or.at(was_counted, encounter, carried)
        self.events += int((any_below & ~was_counted).sum())
        # What stays open: each pair's last encounter, its last time and whether it counted.
        last_of_pair = np.ones(n, dtype=bool)
        last_of_pair[:-1] = code[1:] != code[:-1]
        for i in np.flatnonzero(last_of_pair):
            e = encounter[i]
            self._open[name_of(rows[i])] = (float(t[i]), bool(any_below[e] or was_counted[e]))
        self._forget_before(float(t.max()))

    def _forget_before(self, now_s: float | None) -> None:
        """Drop pairs whose encounter ended (not paired for longer than the extra time)."""
        if now_s is None:
            return
        horizon = now_s - self.extra_time_s - 1e-9
        self._open = {k: v for k, v in self._open.items() if v[0] >= horizon}


def _pair_codes(vehicle: pd.Series, leader: pd.Series) -> tuple[np.ndarray, Callable[[int], str]]:
    """One integer per (vehicle, leader) pair of the rows, and the name of row ``i``'s pair (asked
    only for a pair's first and last rows: it keys the pairs held between batches): from the
    category codes when both columns share their categories (as :func:`metrics.gaps` makes
    them), else from the names as text."""
    v_cat = isinstance(vehicle.dtype, pd.CategoricalDtype)
    if v_cat and vehicle.dtype == leader.dtype:
        names = vehicle.cat.categories.astype(str).to_numpy(dtype=object)
        v = vehicle.cat.codes.to_numpy().astype(np.int64)
        lead = leader.cat.codes.to_numpy().astype(np.int64)
        return v * len(names) + lead, lambda i: f"{names[v[i]]}\n{names[lead[i]]}"
    key = vehicle.astype(str).to_numpy(dtype=object) + "\n"
    key = key + leader.astype(str).to_numpy(dtype=object)
    return pd.factorize(key)[0].astype(np.int64), lambda i: key[i]
