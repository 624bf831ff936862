"""Speeds that stay safe for a whole SUMO step: the net under every speed our controllers give.

A speed commanded through TraCI holds for the whole step, and the CAV reacts to what happens in
it only at the next one. SUMO's own check (speed mode 31) assumes the reaction time is the
vType's tau, which for the controllers' CAVs (0.2 s) is shorter than SUMO's usual steps of
0.5-1 s: at those steps a platoon's CAV accelerated on the speed its leader had, while the
leader braked within the same step, and ran into it. The net caps each CAV's speed for the step
so that, whatever its leader does, the CAV can still stop behind it braking at its own
deceleration from the next step on. A leader whose command for this step is known (a CAV of
ours) is taken at that speed; any other vehicle may brake at its deceleration within the step.
The net applies at steps longer than the CAVs' tau (:func:`net_applies`); at shorter ones
SUMO's own check holds within the step, and the commands are sent as they are.

Distances follow SUMO's default (Euler) update: a vehicle moves ``v' * dt`` in a step in which
its speed becomes ``v'``, and braking at ``b`` from ``v`` it covers

    D(v) = v^2 / (2 b) - v dt / 2 + b dt^2 f (1 - f) / 2,   f = frac(v / (b dt)),

between ``v^2/(2b) - v dt/2`` and that plus ``b dt^2 / 8``: the net takes the upper bound for
the CAV and the lower one for its leader. At 1 s it keeps a CAV following a human driver about
one step's travel further back, and a platoon's CAVs as close as their commands allow.
"""

from __future__ import annotations

import math
from bisect import bisect_left, bisect_right
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass

from sumo_swarm.core.model import VehicleState

# The controllers' CAVs' SUMO tau [s] (SessionView.configure_cav): so short that SUMO's
# safe-speed check binds only within a few metres of the vehicle ahead. At steps up to it that
# check holds within the step, and the net is not applied (the paper's 0.1 s runs, the corridor
# studies' 0.2 s, stay as they were); at longer steps it is.
CAV_TAU_S = 0.2
# What a commanded CAV keeps to the vehicle ahead once both stopped [m]: the controllers' SUMO
# minGap (controllers.session.CAV_MIN_GAP_M), under which SUMO's own check would brake it anyway
STEP_SAFE_MARGIN_M = 0.5


def net_applies(step_s: float) -> bool:
    """Does the net cap speeds at SUMO steps of ``step_s`` [s]?"""
    return step_s > CAV_TAU_S + 1e-9


def safe_speed(
    gap_m: float, lead_mps: float, lead_decel_mps2: float, decel_mps2: float, dt_s: float
) -> float:
    """The highest speed [m/s] a vehicle can drive for the next step of ``dt_s`` [s] and still
    stop, braking at ``decel_mps2`` from the step after, behind a leader ``gap_m`` [m] ahead
    that drives ``lead_mps`` in the step and may brake at ``lead_decel_mps2`` from then on.

    Solves ``v dt + D_up(v) <= gap + lead dt + D_low(lead)`` (the module's bounds of D), the
    leader braking at least as hard as the vehicle: then the gap only shrinks once it does
    (the leader is never faster again), so the stops are the closest the two come. A leader
    that brakes less gently only leaves more room; one that brakes harder than the vehicle
    can was taken at its stop alone, and a vehicle faster than it could come closer on the
    way there than at the end."""
    b, dt = max(decel_mps2, 1e-6), max(dt_s, 0.0)
    lead = max(lead_mps, 0.0)
    lead_decel = max(lead_decel_mps2, b)
    room = gap_m + 0.5 * lead * dt + lead * lead / (2.0 * lead_decel) - b * dt * dt / 8.0
    if room <= 0.0:
        return 0.0
    # v^2 / (2b) + v dt / 2 <= room
    return b * (-0.5 * dt + math.sqrt(0.25 * dt * dt + 2.0 * room / b))


def capped_speeds(
    commands: Mapping[str, float],
    states: Mapping[str, VehicleState],
    leaders_of: Callable[[str], Iterable[tuple[VehicleState, float]]],
    decel_of: Callable[[str], float],
    dt_s: float,
    margin_m: float,
) -> dict[str, float]:
    """``commands`` (speed [m/s] for the next step, by vehicle), each capped by
    :func:`safe_speed` towards each of its leaders (``leaders_of``: (state, bumper gap [m]);
    a leader alongside, gap <= 0, is the lateral guards' to judge) keeping ``margin_m`` [m].
    A commanded leader is taken at its capped command: the commands are capped front to back.
    Any other leader may brake at ``decel_of`` its id [m/s^2] within the step."""
    out: dict[str, float] = {}
    front_first = sorted(commands, key=lambda v: -states[v].s_m if v in states else math.inf)
    for vid in front_first:
        speed = commands[vid]
        if vid in states:
            own = decel_of(vid)
            for leader, gap in leaders_of(vid):
                if gap <= 0.0:
                    continue
                lead_decel = decel_of(leader.vehicle_id)
                lead_cap = leader_cap(
                    gap - margin_m, leader.speed_mps, out.get(leader.vehicle_id), lead_decel,
                    own, dt_s,
                )  # fmt: skip
                speed = min(speed, lead_cap)
        out[vid] = speed
    return out


def leader_cap(
    gap_m: float,
    lead_mps: float,
    lead_command_mps: float | None,
    lead_decel_mps2: float,
    decel_mps2: float,
    dt_s: float,
) -> float:
    """:func:`safe_speed` behind one leader as :func:`capped_speeds` takes it: at its command
    for the step (``lead_command_mps``, a CAV commanded first) or, with none, braking at its
    decel within the step from ``lead_mps``."""
    lead = lead_command_mps
    if lead is None:
        lead = max(lead_mps - lead_decel_mps2 * dt_s, 0.0)
    return safe_speed(gap_m, lead, lead_decel_mps2, decel_mps2, dt_s)


@dataclass(frozen=True)
class Footprint:
    """Where a vehicle's body is at the start and at the end of a step: its front [m] along
    the road and its centre [m] across it (the road's y), with its size [m]. ``short_m``: how
    far behind ``s_end_m`` its front may end the step (a vehicle of no command braking within
    it: :func:`braking_short_m`)."""

    s_m: float
    y_m: float
    s_end_m: float
    y_end_m: float
    length_m: float
    width_m: float
    short_m: float = 0.0


def braking_short_m(speed_mps: float, decel_mps2: float, dt_s: float) -> float:
    """How far [m] short of ``speed * dt`` a vehicle at ``speed_mps`` ends a step of ``dt_s``
    braking at ``decel_mps2`` from its start (to a stop at most)."""
    v, b = max(speed_mps, 0.0), max(decel_mps2, 0.0)
    if b <= 0.0 or dt_s <= 0.0:
        return 0.0
    if v <= b * dt_s:  # it stops within the step
        return v * dt_s - v * v / (2.0 * b)
    return 0.5 * b * dt_s * dt_s


def _overlap(a: Footprint, b: Footprint, end: bool, clearance_m: float) -> bool:
    sa, ya = (a.s_end_m, a.y_end_m) if end else (a.s_m, a.y_m)
    sb, yb = (b.s_end_m, b.y_end_m) if end else (b.s_m, b.y_m)
    # At the end, each body anywhere from where it brakes to where it keeps its speed.
    la = a.length_m + (a.short_m if end else 0.0)
    lb = b.length_m + (b.short_m if end else 0.0)
    lengthwise = sa - la < sb + clearance_m and sb - lb < sa + clearance_m
    return lengthwise and abs(ya - yb) < 0.5 * (a.width_m + b.width_m) + clearance_m


def sideways_conflicts(
    movers: Iterable[str], footprints: Mapping[str, Footprint], clearance_m: float
) -> set[str]:
    """The vehicles of ``movers`` (moving sideways this step) whose body at the end of the step
    comes within ``clearance_m`` [m] of another's, at its own end of the step, when it was not
    at the start: two CAVs moving into one lane from either side, level with each other, each
    judged against where the other was and met in the middle (a step of 1 s). Their moves are
    to be held, every mover of such a pair."""
    ordered = sorted(footprints.items(), key=lambda item: item[1].s_end_m)
    fronts = [fp.s_end_m for _, fp in ordered]
    reach = max((fp.length_m + fp.short_m for fp in footprints.values()), default=0.0)
    reach += clearance_m
    held = set()
    for vid in movers:
        a = footprints.get(vid)
        if a is None:
            continue
        lo = bisect_left(fronts, a.s_end_m - a.length_m - a.short_m - clearance_m)
        hi = bisect_right(fronts, a.s_end_m + reach)
        for other, b in ordered[lo:hi]:
            new = _overlap(a, b, True, clearance_m) and not _overlap(a, b, False, clearance_m)
            if other != vid and new:
                held.add(vid)
                break
    return held
