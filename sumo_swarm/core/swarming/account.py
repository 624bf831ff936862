"""One account of manoeuvres: every way a swarm gets (or tries to get) past a slow vehicle.

A swarm's controller keeps a :class:`ManoeuvreBook`. The book writes each manoeuvre into the
run's events as it happens, and the summary's ``manoeuvres`` list is folded back out of those
events (:func:`manoeuvres_from_events`): one set of records, so the list and events.jsonl
cannot disagree. summary.json's ``overtake`` (the first manoeuvre) and ``swarms`` counts are
derived from that list (:func:`overtake_outcome`, :func:`overtake_counts`).

Kinds (:data:`KINDS`):

- ``cells``: the paper's cell plan (the planner, the MPCs, the guards);
- ``lane_pass``: the platoon moves over to a faster lane as one and passes there, the cruise
  driving it (chosen at the decision, or a cell plan handing over to the cruise once the
  platoon is in one faster lane: ``how = "handover"``);
- ``one_by_one``: after a give-up that found no way past together, each CAV passes on its own
  and the platoon re-forms ahead;
- ``wait``: after a give-up that split the platoon at the slow vehicle, the CAVs past it wait
  ahead of it for the others.

Events (one JSON object each in events.jsonl; ``platoon`` added by the run's context):

- ``overtake_start``: ``target, kind, manoeuvre`` (the book's number), ``cavs`` (their ids);
- ``cav_past``: ``target, kind, manoeuvre, vehicle``, when a CAV of it first gets past the
  target while it lasts (its rear ahead of the target's front by ``min_gap_m``);
- ``overtake_end``: ``target, kind, manoeuvre, completed, reason, outcome, cavs, cavs_past``.

Outcomes: ``completed`` (every CAV of it past the target), ``aborted:<reason>`` (the
controller's own word for why not), ``running`` (still under way when the run ended).

Pure: no SUMO import; the book's events go through a callback.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from sumo_swarm.core.model import VehicleState
from sumo_swarm.core.swarming.decision import is_past

KINDS = ("cells", "lane_pass", "one_by_one", "wait")
START, END, PAST = "overtake_start", "overtake_end", "cav_past"
COMPLETED, RUNNING, ABORTED = "completed", "running", "aborted"
# Reasons of the book's own ends: another manoeuvre of the platoon began, the platoon dissolved
SUPERSEDED, DISSOLVED = "superseded", "platoon_dissolved"


def outcome_of(completed: bool, reason: str) -> str:
    """``completed`` or ``aborted:<reason>``."""
    return COMPLETED if completed else f"{ABORTED}:{reason}"


@dataclass
class Open:
    """A manoeuvre under way."""

    number: int
    kind: str
    target_id: str
    cav_ids: tuple[str, ...]
    t_start_s: float
    past: set[str] = field(default_factory=set)
    # The book ends it on its own (a pass the cruise drives): when every CAV is past, the
    # target is gone, or at until_s [s] (timeout)
    watched: bool = False
    until_s: float = math.inf


class ManoeuvreBook:
    """One swarm's manoeuvres, written as events (see the module) through ``event(kind,
    **data)``; ``min_gap_m`` [m]: how far ahead of the target's front a CAV's rear must be to
    count as past it (the controller's own test, :func:`is_past`)."""

    def __init__(self, event: Callable[..., Any], min_gap_m: float) -> None:
        self.event = event
        self.min_gap_m = min_gap_m
        self.open: list[Open] = []
        self.started = 0

    def start(
        self,
        t_s: float,
        kind: str,
        target_id: str,
        cav_ids: Sequence[str],
        *,
        watched: bool = False,
        until_s: float = math.inf,
        **data: Any,
    ) -> Open:
        """A manoeuvre of ``kind`` on ``target_id`` begins with ``cav_ids``; the ones under way
        end first (``superseded``): a swarm does one thing at a time."""
        if kind not in KINDS:
            raise ValueError(f"unknown manoeuvre kind {kind!r} (known: {', '.join(KINDS)})")
        self.end_all(t_s, SUPERSEDED)
        self.started += 1
        m = Open(self.started, kind, target_id, tuple(cav_ids), t_s, watched=watched,
                 until_s=until_s)  # fmt: skip
        self.open.append(m)
        self.event(START, target=target_id, kind=kind, manoeuvre=m.number,
                   cavs=list(m.cav_ids), **data)  # fmt: skip
        return m

    def current(self, kind: str | None = None) -> Open | None:
        """The manoeuvre under way (of ``kind``), or None."""
        return next((m for m in self.open if kind is None or m.kind == kind), None)

    def watch(
        self,
        t_s: float,
        states: Mapping[str, VehicleState],
        members: Collection[str] | None = None,
    ) -> None:
        """Count the CAVs that got past their manoeuvre's target this step (``cav_past``), and
        end the watched manoeuvres that are over: every CAV of it still on the road (and in
        ``members``, the platoon now) past the target, the target gone, or out of time."""
        for m in list(self.open):
            target = states.get(m.target_id)
            if target is not None:
                self._count_past(m, target, states)
            if not m.watched:
                continue
            present = [v for v in m.cav_ids if v in states and (members is None or v in members)]
            if target is None:
                self.end(t_s, m, completed=False, reason="target_gone", states=states)
            elif present and all(v in m.past for v in present):
                self.end(t_s, m, completed=True, states=states)
            elif t_s > m.until_s:
                self.end(t_s, m, completed=False, reason="timeout", states=states)

    def _count_past(
        self, m: Open, target: VehicleState, states: Mapping[str, VehicleState]
    ) -> None:
        for vid in m.cav_ids:
            st = states.get(vid)
            if vid not in m.past and st is not None and is_past(st, target, self.min_gap_m):
                m.past.add(vid)
                self.event(PAST, target=m.target_id, kind=m.kind, manoeuvre=m.number, vehicle=vid)

    def end(
        self,
        t_s: float,
        m: Open | None,
        *,
        completed: bool,
        reason: str = COMPLETED,
        states: Mapping[str, VehicleState] | None = None,
        **data: Any,
    ) -> None:
        """End ``m`` (None: nothing under way, nothing to do). ``completed``: every CAV of it is
        past its target (the caller's judgement, made on ``states``, whose passes are counted
        first); else ``reason`` says why it ended."""
        if m is None or m not in self.open:
            return
        if states is not None and m.target_id in states:
            self._count_past(m, states[m.target_id], states)
        self.open.remove(m)
        self.event(END, target=m.target_id, kind=m.kind, manoeuvre=m.number,
                   completed=bool(completed), reason=COMPLETED if completed else reason,
                   outcome=outcome_of(completed, reason), cavs=len(m.cav_ids),
                   cavs_past=len(m.past), **data)  # fmt: skip

    def end_all(self, t_s: float, reason: str) -> None:
        """End every manoeuvre under way, none completed (``reason``)."""
        for m in list(self.open):
            self.end(t_s, m, completed=False, reason=reason)


# --------------------------------------------------------------------------- the summary's


def manoeuvres_from_events(events: Iterable[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The summary's ``manoeuvres`` list, in order of start, from a run's events: the
    contract's fields, and ``reason`` (the end's, None while running or completed),
    ``cav_ids`` (the CAVs at its start), ``past_ids`` (those that got past the target).
    ``regrouped`` and ``t_regrouped_s`` are False and None here: the summary measures them on
    the trajectories (:func:`sumo_swarm.sim.summary.measure_manoeuvres`)."""
    out: list[dict[str, Any]] = []
    by_key: dict[tuple[Any, Any], dict[str, Any]] = {}
    for e in events:
        kind = e.get("event")
        if kind not in (START, END, PAST):
            continue
        key = (e.get("platoon"), e.get("manoeuvre"))
        if kind == START:
            cav_ids = [str(v) for v in e.get("cavs") or []]
            entry = {
                "platoon": int(e.get("platoon") or 0),
                "kind": str(e.get("kind", "cells")),
                "target": e.get("target"),
                "t_start_s": float(e["time_s"]),
                "t_end_s": None,
                "cavs": len(cav_ids),
                "cavs_past": 0,
                "regrouped": False,
                "t_regrouped_s": None,
                "outcome": RUNNING,
                "reason": None,
                "cav_ids": cav_ids,
                "past_ids": [],
            }
            by_key[key] = entry
            out.append(entry)
            continue
        entry = by_key.get(key)
        if entry is None or entry["outcome"] != RUNNING:
            continue  # a record of no manoeuvre under way (a corrupt log): left out
        if kind == PAST:
            entry["cavs_past"] += 1
            entry["past_ids"].append(str(e.get("vehicle")))
        else:
            entry["t_end_s"] = float(e["time_s"])
            entry["cavs"] = int(e.get("cavs", entry["cavs"]))
            entry["cavs_past"] = int(e.get("cavs_past", entry["cavs_past"]))
            completed = bool(e.get("completed"))
            entry["reason"] = None if completed else str(e.get("reason"))
            entry["outcome"] = outcome_of(completed, str(e.get("reason")))
    return out


def abort_reason(outcome: str) -> str | None:
    """``x`` of ``aborted:x``; None for any other outcome."""
    prefix = f"{ABORTED}:"
    return outcome[len(prefix) :] if outcome.startswith(prefix) else None


def overtake_counts(manoeuvres: Sequence[Mapping[str, Any]]) -> dict[str, int]:
    """The ``swarms`` block's overtake counts: started, completed, aborted (and running)."""
    outcomes = [m["outcome"] for m in manoeuvres]
    return {
        "overtakes_started": len(outcomes),
        "overtakes_completed": sum(o == COMPLETED for o in outcomes),
        "overtakes_aborted": sum(abort_reason(o) is not None for o in outcomes),
        "overtakes_running": sum(o == RUNNING for o in outcomes),
    }


def overtake_outcome(
    manoeuvres: Sequence[Mapping[str, Any]], behaving_interval_s: float
) -> dict[str, Any]:
    """The ``overtake`` block's outcome fields, of the first manoeuvre (``t_end_s``: the time
    by which every CAV of it had been past the target, ``t_past_s``; ``behaving_steps``: its
    length in behaving intervals of ``behaving_interval_s`` [s]), and the give-ups of them all
    (``aborted``, ``abort_reasons``)."""
    reasons = Counter(r for m in manoeuvres if (r := abort_reason(m["outcome"])) is not None)
    out: dict[str, Any] = {
        "triggered": bool(manoeuvres),
        "completed": False,
        "regrouped": False,
        "target": None,
        "t_start_s": None,
        "t_end_s": None,
        "t_regrouped_s": None,
        "behaving_steps": None,
        "aborted": sum(reasons.values()),
        "abort_reasons": dict(reasons),
    }
    if not manoeuvres:
        return out
    first = manoeuvres[0]
    done = first["outcome"] == COMPLETED
    out.update(
        completed=done,
        regrouped=bool(first["regrouped"]),
        target=first["target"],
        t_start_s=first["t_start_s"],
        t_end_s=first.get("t_past_s") if done else None,
        t_regrouped_s=first["t_regrouped_s"],
    )
    if done and first["t_end_s"] is not None:
        span_s = first["t_end_s"] - first["t_start_s"]
        out["behaving_steps"] = math.ceil(span_s / behaving_interval_s - 1e-9)
    return out
