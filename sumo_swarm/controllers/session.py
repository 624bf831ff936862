"""The controllers' view of SUMO: one declared interface, :class:`SessionView`.

Everything a controller reads of the simulation or commands in it goes through these names
(the bridge's :class:`~sumo_swarm.sim.bridge.SumoSession` answers them from a running SUMO; a
swarm's :class:`~sumo_swarm.controllers.fleet.PlatoonSession` passes them on, its own CAVs the
only CAVs). The controllers call them directly: no name is probed for.

:class:`SessionBase` gives every answer as SUMO's absence would: no vehicle, no road, no lane
that ends, no driver's wish, commands that go nowhere. The bridge's session and the tests'
hand-made sessions build on it, so a stand-in answers every name and says only what its test
is about.
"""

from __future__ import annotations

import inspect
from collections.abc import Mapping
from typing import TYPE_CHECKING, Protocol, runtime_checkable

from sumo_swarm.core.hvmodel import SUMO_DEFAULTS, DriverModel
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.swarming.decision import secure_gap_m

if TYPE_CHECKING:
    from sumo_swarm.core.routeframe import RouteFrame

__all__ = [
    "ALONE_DECEL_MPS2", "CAV_LC_ACCEL_LAT_MPS2", "CAV_MIN_GAP_M", "SESSION_DATA",
    "SESSION_METHODS", "SPEED_MODE_SAFE", "STANDING_MPS", "SUMO_MIN_GAP_M", "SUMO_TAU_S",
    "SessionBase", "SessionView",
]  # fmt: skip

SUMO_TAU_S, SUMO_MIN_GAP_M = SUMO_DEFAULTS.tau_s, SUMO_DEFAULTS.min_gap_m  # [s], [m]
STANDING_MPS = 0.1  # a vehicle slower than this stands [m/s]
# How hard SUMO brakes a CAV it drives alone, or one that left its platoon [m/s^2]: the
# contract's hard-brake line (sim.metrics.HARD_BRAKE_MPS2). One that left is still commanded by
# our CACC for a while, down to [cav] accel_min_mps2 (-4), and SUMO holds a commanded speed's
# braking to the vehicle's decel: at 3.5 m/s^2 a CAV just parted from a platoon, 9 m behind a
# CAV braking at 4, ran into it (5-lane OSM motorway, 40 % CAVs, seed 8).
ALONE_DECEL_MPS2 = 4.0
# What SUMO is told of a CAV our controllers drive (SessionView.configure_cav). Speed mode 31
# (SUMO's default): commanded speeds still respect the safe speed towards the vehicle ahead
# and the vType's accel/decel limits, a last safety net under our controllers.
SPEED_MODE_SAFE = 31
# lcAccelLat so high that per-step sublane moves are executed as commanded
# (docs/closed-loop.md) [m/s^2]
CAV_LC_ACCEL_LAT_MPS2 = 40.0
# tau (core.stepsafe.CAV_TAU_S) and minGap so small that SUMO's safe-speed check is a
# last-resort net binding only within a few metres of the vehicle ahead [m]; at longer SUMO
# steps than that tau the bridge caps the commanded speeds itself (core.stepsafe)
CAV_MIN_GAP_M = 0.5


@runtime_checkable
class SessionView(Protocol):
    """What the controllers use of a SUMO session. Vehicles are SUMO's ids; ``s`` is along the
    route frame [m]; "the last read" is the state after the last SUMO step."""

    # ---------------------------------------------------------------- the last read
    time_s: float  # simulation time of the last read [s]
    step_length_s: float  # SUMO's step length [s]
    cav_ids: list[str]  # every CAV that departed, in order of departure
    departed: list[str]  # vehicles that departed in the last step
    arrived: list[str]  # vehicles that arrived in the last step
    kinds: dict[str, str]  # "cav" or "hv" of every vehicle seen
    released: set[str]  # CAVs handed back to SUMO (they left the swarm for their route)
    frame: RouteFrame | None  # the route coordinate and the network along it (None: no route)

    @property
    def states(self) -> dict[str, VehicleState]:
        """Every vehicle of the last read (a released CAV counts as an HV: SUMO drives it)."""
        ...

    @property
    def edges(self) -> dict[str, str]:
        """The edge of every vehicle of the last read ("" on no lane)."""
        ...

    @property
    def lane_positions(self) -> dict[str, float]:
        """Front bumper along its lane of every vehicle of the last read [m]."""
        ...

    def exists(self, vid: str) -> bool:
        """Whether ``vid`` was in the last read and has not vanished since."""
        ...

    def states_in_lanes_of(self, vid: str) -> dict[str, VehicleState]:
        """:attr:`states` with every lane index counted as on ``vid``'s edge (across lane
        drops and on-ramps)."""
        ...

    # ---------------------------------------------------------------- the road
    def road_at(self, vid: str) -> RoadSection | None:
        """The road section under ``vid`` (None: not known)."""
        ...

    def lanes_ending(self, edge: str, s_from_m: float, s_to_m: float) -> list[tuple[int, float]]:
        """``(lane, s where it ends [m])`` of the lanes of ``edge`` that end in that stretch."""
        ...

    def near_lane_shift(self, s_m: float, within_m: float) -> bool:
        """Whether lane indices shift (a lane added or dropped on the right) near ``s_m``."""
        ...

    # ---------------------------------------------------------------- each vehicle
    def driver_model(self, vid: str) -> DriverModel:
        """How ``vid`` drives: its car-following model and parameters (one that vanished:
        the cautious bound, ``DriverModel(model="unknown")``)."""
        ...

    def speed_limits(self, vid: str) -> tuple[float, float] | None:
        """(vType maxSpeed, allowed speed on its lane with its speedFactor) [m/s]; None: it
        vanished, or SUMO cannot tell."""
        ...

    def route_of(self, vid: str) -> tuple[tuple[str, ...], int] | None:
        """``vid``'s route edges and the index of the edge it is on (None: not known)."""
        ...

    def distance_to_parting_m(
        self, vid: str, route: tuple[str, ...], index: int, ours: frozenset[str]
    ) -> float | None:
        """How far [m] ``vid`` drives along ``route`` before its first edge not in ``ours``."""
        ...

    def lane_change_need(self, vid: str) -> tuple[float, int] | None:
        """``(distance [m], lanes)`` ``vid`` has left in its lane before its route needs another
        one; None while its lane goes on (or SUMO cannot tell)."""
        ...

    def standing_s(self, vid: str) -> float:
        """How long [s] released CAV ``vid`` has stood still (0 while it moves)."""
        ...

    def keeps_right(self, vid: str) -> bool:
        """Does ``vid``'s lane-change model keep right (False: it vanished, or SUMO cannot
        tell)?"""
        ...

    def wants_right(self, vid: str) -> bool:
        """Does ``vid``'s driver want to move right to keep right now?"""
        ...

    def lane_wish(self, vid: str) -> tuple[int, bool]:
        """The lane ``vid``'s driver wants (+1 left, -1 right, 0 none), and whether blocked."""
        ...

    def must_change(self, vid: str, direction: int) -> bool:
        """Does ``vid`` need to move one lane ``direction`` (+1 left) for its route?"""
        ...

    def keep_right_due_s(self, vid: str) -> float | None:
        """Seconds until ``vid``'s keep-right wish shows (None: SUMO cannot tell)."""
        ...

    # ---------------------------------------------------------------- commands
    def set_speed(self, vid: str, speed_mps: float) -> None:
        """Command ``vid``'s speed for the next step [m/s] (sent by :meth:`flush_commands`)."""
        ...

    def flush_commands(self) -> None:
        """Send the step's speed commands, made safe for the whole step."""
        ...

    def release_speed(self, vid: str) -> None:
        """Hand ``vid``'s speed back to SUMO's car-following model (a vehicle that vanished:
        nothing to do, no error)."""
        ...

    def change_sublane(self, vid: str, lateral_m: float) -> None:
        """Move ``vid`` sideways by ``lateral_m`` (left positive) [m]; 0: stop a move under
        way."""
        ...

    def set_modes(self, vid: str, speed_mode: int | None, lane_change_mode: int | None) -> bool:
        """Set SUMO's speed and lane-change modes of ``vid`` (None: leave it); False: vanished."""
        ...

    def configure_cav(
        self,
        vid: str,
        *,
        lane_change_mode: int,
        lateral_speed_mps: float | None = None,
        type_speed_factor: bool = False,
        decel_mps2: float | None = None,
    ) -> None:
        """Our controllers drive CAV ``vid``, whatever vType the user gave it: speed mode
        :data:`SPEED_MODE_SAFE` and ``lane_change_mode``; lcAccelLat, tau and minGap
        (:data:`CAV_LC_ACCEL_LAT_MPS2`, ``CAV_TAU_S``, :data:`CAV_MIN_GAP_M`);
        ``lateral_speed_mps`` as its maxSpeedLat (None: its vType's); with
        ``type_speed_factor`` its vType's speedFactor instead of SUMO's draw for it (one
        platoon, one desired speed); its decel, and the decel the others assume of it, at most
        ``decel_mps2`` (a vehicle that vanished: nothing to do, no error)."""
        ...

    def restore_gaps(self, vid: str, *, tau: bool = False) -> None:
        """CAV ``vid``'s minGap (with ``tau``, its headway too) its user's vType's again (a
        vehicle that vanished: nothing to do, no error)."""
        ...

    def release(self, vid: str) -> None:
        """``vid`` leaves the swarm: SUMO changes its lanes again (its speed stays ours; a
        vehicle that vanished: no error)."""
        ...

    def drive_alone(self, vid: str) -> None:
        """SUMO drives CAV ``vid`` alone: at least SUMO's default headway and minGap, braking
        within the hard-brake line, set on its vType too (the next CAVs are inserted so; a
        vehicle that vanished: no error)."""
        ...

    def alone_gap_m(
        self, vid: str, speed_mps: float, lead_mps: float, lead_id: str | None = None
    ) -> float:
        """The gap [m] SUMO wants ahead of CAV ``vid`` driving alone (:meth:`drive_alone`) at
        ``speed_mps`` behind vehicle ``lead_id`` at ``lead_mps``: its minGap plus its secure gap
        (:func:`~sumo_swarm.core.swarming.decision.secure_gap_m`), the leader braking at the
        deceleration SUMO assumes of it (SUMO's default where unknown)."""
        ...

    def reclaim(self, vid: str) -> None:
        """``vid``, released before, is a swarm's CAV again."""
        ...

    def miss_exit(self, vid: str) -> str | None:
        """Let ``vid`` drive on past the exit its route needs: the edge it was heading for, or
        None when it cannot (or SUMO cannot tell)."""
        ...


def _members(kind: str) -> tuple[str, ...]:
    """The names :class:`SessionView` declares: its methods (``kind`` "methods") or its data,
    annotated attributes and properties ("data")."""
    own = {name: value for name, value in vars(SessionView).items() if not name.startswith("_")}
    if kind == "methods":
        return tuple(name for name, value in own.items() if inspect.isfunction(value))
    props = [name for name, value in own.items() if isinstance(value, property)]
    return (*SessionView.__annotations__, *props)


SESSION_METHODS = _members("methods")  # called with a vehicle (or a road stretch)
SESSION_DATA = _members("data")  # read as attributes


class SessionBase:
    """A session with nothing in it: every :class:`SessionView` answer as where SUMO cannot
    tell (None, False, empty, no-op commands). ``states`` (and the other tables) may be given;
    a subclass overrides what its test is about."""

    def __init__(
        self,
        states: Mapping[str, VehicleState] | None = None,
        *,
        edges: Mapping[str, str] | None = None,
        time_s: float = 0.0,
        step_length_s: float = 0.1,
    ) -> None:
        self._states = dict(states or {})
        self._edges = dict(edges or {})
        self.lane_positions: dict[str, float] = {}
        self.time_s = time_s
        self.step_length_s = step_length_s
        self.cav_ids: list[str] = []
        self.departed: list[str] = []
        self.arrived: list[str] = []
        self.kinds: dict[str, str] = {}
        self.released: set[str] = set()
        self.frame: RouteFrame | None = None

    @property
    def states(self) -> dict[str, VehicleState]:
        return self._states

    @states.setter
    def states(self, states: dict[str, VehicleState]) -> None:
        self._states = states

    @property
    def edges(self) -> dict[str, str]:
        return self._edges

    @edges.setter
    def edges(self, edges: dict[str, str]) -> None:
        self._edges = edges

    def exists(self, vid: str) -> bool:
        return vid in self.states

    def states_in_lanes_of(self, vid: str) -> dict[str, VehicleState]:
        return self.states  # one lane numbering everywhere

    def road_at(self, vid: str) -> RoadSection | None:
        return None

    def lanes_ending(self, edge: str, s_from_m: float, s_to_m: float) -> list[tuple[int, float]]:
        return []

    def near_lane_shift(self, s_m: float, within_m: float) -> bool:
        return False

    def driver_model(self, vid: str) -> DriverModel:
        return DriverModel(model="unknown")  # the cautious bound

    def speed_limits(self, vid: str) -> tuple[float, float] | None:
        return None

    def route_of(self, vid: str) -> tuple[tuple[str, ...], int] | None:
        return None

    def distance_to_parting_m(
        self, vid: str, route: tuple[str, ...], index: int, ours: frozenset[str]
    ) -> float | None:
        return None

    def lane_change_need(self, vid: str) -> tuple[float, int] | None:
        return None

    def standing_s(self, vid: str) -> float:
        return 0.0

    def keeps_right(self, vid: str) -> bool:
        return False

    def wants_right(self, vid: str) -> bool:
        return False

    def lane_wish(self, vid: str) -> tuple[int, bool]:
        return 0, False

    def must_change(self, vid: str, direction: int) -> bool:
        return False

    def keep_right_due_s(self, vid: str) -> float | None:
        return None

    def set_speed(self, vid: str, speed_mps: float) -> None:
        pass

    def flush_commands(self) -> None:
        pass

    def release_speed(self, vid: str) -> None:
        pass

    def change_sublane(self, vid: str, lateral_m: float) -> None:
        pass

    def set_modes(self, vid: str, speed_mode: int | None, lane_change_mode: int | None) -> bool:
        return False  # no vehicle to set them on

    def configure_cav(
        self,
        vid: str,
        *,
        lane_change_mode: int,
        lateral_speed_mps: float | None = None,
        type_speed_factor: bool = False,
        decel_mps2: float | None = None,
    ) -> None:
        self.set_modes(vid, SPEED_MODE_SAFE, lane_change_mode)  # the modes, as SUMO's session

    def restore_gaps(self, vid: str, *, tau: bool = False) -> None:
        pass

    def release(self, vid: str) -> None:
        self.released.add(vid)

    def drive_alone(self, vid: str) -> None:
        pass

    def alone_gap_m(
        self, vid: str, speed_mps: float, lead_mps: float, lead_id: str | None = None
    ) -> float:
        return SUMO_MIN_GAP_M + secure_gap_m(
            SUMO_TAU_S, ALONE_DECEL_MPS2, speed_mps, lead_mps, SUMO_DEFAULTS.decel_mps2
        )

    def reclaim(self, vid: str) -> None:
        self.released.discard(vid)

    def miss_exit(self, vid: str) -> str | None:
        return None
