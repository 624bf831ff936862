"""The SUMO bridge: the only module that imports libsumo (or traci, for users of sumo-gui).

It starts and stops SUMO, reads every vehicle's state in bulk through subscriptions, counts
collisions and teleports, and applies the controllers' commands. Route positions come from the
pure :mod:`sumo_swarm.core.routeframe` (fed from the running network), trajectories are recorded by
:mod:`sumo_swarm.sim.recorder`, and the CAVs' driving parameters are set as the controllers ask
(:meth:`SumoSession.configure_cav`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import logging
import os
import re
import socket
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from operator import itemgetter
from pathlib import Path
from types import ModuleType

from sumo_swarm.checks import unknown_name
from sumo_swarm.controllers.session import (
    ALONE_DECEL_MPS2,
    CAV_LC_ACCEL_LAT_MPS2,
    CAV_MIN_GAP_M,
    SPEED_MODE_SAFE,
    STANDING_MPS,
    SUMO_MIN_GAP_M,
    SUMO_TAU_S,
    SessionBase,
)
from sumo_swarm.core.hvmodel import (
    SUMO_DEFAULTS,
    DriverModel,
    idm_follow_speed,
    krauss_follow_speed,
)
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.neighbours import PassSnapshots, overlapping_ahead, within
from sumo_swarm.core.routeframe import RouteFrame, carried_route_s
from sumo_swarm.core.stepsafe import (
    CAV_TAU_S,
    STEP_SAFE_MARGIN_M,
    Footprint,
    braking_short_m,
    capped_speeds,
    net_applies,
    sideways_conflicts,
)
from sumo_swarm.core.swarming.decision import keep_right_due_s, secure_gap_m
from sumo_swarm.errors import ConfigError, SimulationError

log = logging.getLogger(__name__)

DEFAULT_WIDTHS_M = (3.2, 3.2)  # the road assumed until a route is known (SUMO's lane width) [m]
# SUMO's default lane-change mode, for a CAV that leaves the swarm: every lane-change motive on
# while respecting others' speed and gaps (TraCI's documented default).
LC_MODE_DEFAULT = 0b011001010101
# SUMO's lane-change state bits (libsumo vehicle.getLaneChangeState): a change to the right is
# wanted, for the keep-right reason.
LCA_LEFT = 1 << 1
LCA_RIGHT = 1 << 2
LCA_STRATEGIC = 1 << 3
LCA_COOPERATIVE = 1 << 4
LCA_SPEEDGAIN = 1 << 5
LCA_KEEPRIGHT = 1 << 6
# A wish of these reasons moves a driver to another lane (not the sublane model's alignment
# within its lane); the blocked bits say a vehicle there keeps it from moving now.
LCA_REASONS = LCA_STRATEGIC | LCA_COOPERATIVE | LCA_SPEEDGAIN | LCA_KEEPRIGHT
LCA_BLOCKED = 0xF << 9
# The rate of a keep-right build-up is taken between readings at most this far apart [s].
KEEP_RIGHT_RATE_WINDOW_S = 1.0
LEADER_REACH_EXTRA_M = 30.0  # beyond a CAV's stopping reach, for a truck's length [m]
SIDEWAYS_REACH_M = 60.0  # vehicles whose fronts are this near a CAV moving sideways [m]
SIDEWAYS_CLEARANCE_M = 0.3  # what two bodies keep at the end of a step (guards' side_clearance)


def sumo_binary(gui: bool = False) -> str:
    """Path of the sumo (or sumo-gui) binary shipped with the eclipse-sumo package."""
    import sumo

    name = "sumo-gui" if gui else "sumo"
    return str(Path(sumo.SUMO_HOME) / "bin" / name)


def require_display(env: Mapping[str, str] | None = None, platform: str | None = None) -> None:
    """ConfigError, at once, when sumo-gui could not open a window: on X11 systems (Linux,
    BSD) without DISPLAY, or with a DISPLAY no X server answers at. (traci would start
    sumo-gui about 60 times over a minute before it gave up.) ``env`` and ``platform``:
    os.environ and sys.platform unless given."""
    env = os.environ if env is None else env
    platform = sys.platform if platform is None else platform
    if platform.startswith(("win", "darwin", "cygwin")):
        return  # sumo-gui draws without an X display there (or XQuartz starts on demand)
    display = env.get("DISPLAY", "")
    if not display:
        raise ConfigError(
            "--gui: no display to show sumo-gui on (DISPLAY is not set); run without --gui, "
            "or under a display (e.g. xvfb-run sumo-swarm ...)"
        )
    if not _x_server_answers(display):
        raise ConfigError(
            f"--gui: no X server answers at DISPLAY={display}; run without --gui, or set "
            "DISPLAY to a running display (e.g. xvfb-run sumo-swarm ...)"
        )


def _x_server_answers(display: str, timeout_s: float = 2.0) -> bool:
    """Whether an X server listens at ``display`` (``[host]:N[.screen]``): its socket
    ``/tmp/.X11-unix/XN`` (or Linux's abstract one), or TCP port 6000 + N of ``host``."""
    host, _, rest = display.rpartition(":")
    number = rest.split(".")[0]
    if not number.isdigit():
        return True  # a form we do not know (a launchd path, ...): let sumo-gui try
    if host in ("", "unix"):
        for address in (f"/tmp/.X11-unix/X{number}", f"\0/tmp/.X11-unix/X{number}"):
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
                sock.settimeout(timeout_s)
                try:
                    sock.connect(address)
                    return True
                except OSError:
                    continue
        return False
    try:
        with socket.create_connection((host, 6000 + int(number)), timeout=timeout_s):
            return True
    except OSError:
        return False


def _api(use_traci: bool) -> ModuleType:
    if use_traci:
        import traci

        return traci
    import libsumo

    return libsumo


# libsumo writes SUMO's outputs in Parquet from 1.25 on (its wheels bring Arrow); 1.24 writes
# XML whatever the file's name (measured: CI's oldest-releases pass).
PARQUET_SINCE = (1, 25)


@functools.cache
def writes_parquet() -> bool:
    """Whether the libsumo in use writes SUMO's outputs in Parquet (``getVersion``: "SUMO
    1.28.0"; a version it cannot read: no)."""
    import libsumo

    found = re.findall(r"\d+", libsumo.getVersion()[1])
    return len(found) >= 2 and (int(found[0]), int(found[1])) >= PARQUET_SINCE


def traci_errors() -> tuple[type[Exception], ...]:
    """What SUMO raises for a call it cannot serve: the ``TraCIException`` of libsumo, traci
    and libtraci, of those loaded. A vehicle that left is one such call; so are a parameter
    its lane-change model lacks and a destination it has no route to, which the session's
    reads answer as SUMO not telling. The session catches these alone: anything else (a
    defect of ours, SUMO itself gone: ``FatalTraCIError``) goes on to the run loop's
    stand-down. ``traci.TraCIException``, not ``traci.exceptions.TraCIException``: importing
    libsumo rebinds the latter to libsumo's class, while a traci connection raises the
    former."""
    modules = (sys.modules.get(name) for name in ("libsumo", "traci", "libtraci"))
    return tuple(module.TraCIException for module in modules if module is not None)


def _constants(api) -> ModuleType:
    """TraCI's variable ids: the same numbers for libsumo, traci and traci connections."""
    consts = getattr(api, "constants", None)
    if consts is None:
        import traci.constants as consts
    return consts


def is_of_type(type_id: str, vtype: str) -> bool:
    """Whether a vehicle whose vType id is ``type_id`` belongs to vType ``vtype``.

    Setting a vType parameter for one vehicle (``vehicle.setMinGap``, ``setParameter``, ...)
    makes SUMO give that vehicle its own copy of the type, named ``vtype@vehicle_id``
    (e.g. ``cav@cav0``): the copy still belongs to ``vtype``.
    """
    return type_id == vtype or type_id.startswith(vtype + "@")


def unknown_vtype(vtype: str, present: Iterable[str]) -> str | None:
    """None if ``vtype`` is among the vType ids ``present`` in a simulation; else the message
    naming the nearest and listing them (without SUMO's per-vehicle copies, ``cav@c0``, and
    its built-in ``DEFAULT_...`` types, which are accepted all the same)."""
    present = list(present)
    if vtype in present:
        return None
    own = [t for t in present if "@" not in t and not t.startswith("DEFAULT_")]
    return unknown_name("vType", vtype, own, listed_as="vTypes in the simulation")


@dataclass(slots=True)
class StepColumns:
    """One read of the simulation, column by column: row ``i`` of every list is vehicle
    ``ids[i]`` (SUMO's order). The recorder takes its rows from here as they are; the
    per-vehicle views (:attr:`SumoSession.states` and the dicts beside it) are made from it
    when a controller first asks, once per step."""

    time_s: float = 0.0
    ids: list[str] = field(default_factory=list)
    edge: list[str] = field(default_factory=list)
    lane: list[int] = field(default_factory=list)
    lane_pos_m: list[float] = field(default_factory=list)  # front bumper along its lane [m]
    s_m: list[float] = field(default_factory=list)  # along the route frame [m]
    lat_m: list[float] = field(default_factory=list)
    speed_mps: list[float] = field(default_factory=list)
    accel_mps2: list[float] = field(default_factory=list)
    xy: list[tuple[float, float]] = field(default_factory=list)
    lane_width_m: list[float] = field(default_factory=list)


@dataclass
class Collision:
    time_s: float
    collider: str
    victim: str
    kind: str


class SumoNetwork:
    """The network data of :class:`~sumo_swarm.core.routeframe.RouteFrame`, read from a running
    simulation (libsumo module, traci module or traci connection). Lane counts and lengths are
    read once each: the road ahead of every CAV is measured at each membership review (a
    corridor's 70 CAVs, each over the edges left of its route, every second). A lane length a
    user's script changes during the run (TraCI's ``lane.setLength``) is not seen, as the route
    frame's positions, fixed when the route is set, do not see it either."""

    def __init__(self, api) -> None:
        self.api = api
        self._lane_counts: dict[str, int] = {}
        self._lane_lengths: dict[str, float] = {}

    def lane_count(self, edge: str) -> int:
        count = self._lane_counts.get(edge)
        if count is None:
            count = self._lane_counts[edge] = self.api.edge.getLaneNumber(edge)
        return count

    def lane_length_m(self, lane_id: str) -> float:
        length = self._lane_lengths.get(lane_id)
        if length is None:
            length = self._lane_lengths[lane_id] = self.api.lane.getLength(lane_id)
        return length

    def lane_width_m(self, lane_id: str) -> float:
        return self.api.lane.getWidth(lane_id)

    def lane_shape(self, lane_id: str) -> Sequence[tuple[float, float]]:
        return self.api.lane.getShape(lane_id)

    def lane_links(self, lane_id: str) -> list[tuple[str, str]]:
        # TraCI's link tuples: (lane reached, has priority, is open, has foe, via lane, ...)
        return [(link[0], link[4]) for link in self.api.lane.getLinks(lane_id)]


class SumoSession(SessionBase):
    """A running SUMO simulation: the controllers' view of it is
    :class:`~sumo_swarm.controllers.session.SessionView`.

    Use as a context manager::

        with SumoSession(["-c", "scenario.sumocfg"]) as sumo:
            while sumo.time_s < end:
                sumo.step()
                states = sumo.states

    ``route_edges`` defines the route coordinate ``s_m`` (:class:`RouteFrame`, in
    :attr:`frame`); empty: the route of the first CAV that departs. ``is_cav(vehicle_id,
    type_id)`` tells which vehicles are CAVs; their ids collect in :attr:`cav_ids`.

    :meth:`attached` wraps a simulation someone else started and steps (the plugin API): then
    call :meth:`refresh` after each step instead of :meth:`step`.

    ``fcd_path``: SUMO writes every vehicle at every step there itself (its FCD output in
    Parquet, ``args`` holding :func:`~sumo_swarm.sim.fcd.fcd_args`, in the run's saved
    configuration too) and the session reads no vehicle's state: for a
    controller that reads nothing (SUMO drives every vehicle), :attr:`states` stay empty, and
    :meth:`exists` answers from the departures and arrivals; the lanes' edges, indices and
    widths are read at the start (:attr:`lane_table`), for the table made of the file once SUMO
    has closed.
    """

    # Every variable costs SUMO and the conversion to Python about the same for every vehicle
    # at every step (callgrind, 150 s of scenarios/corridor.toml: 7 variables 2.1 G
    # instructions over the bare simulation's 12.9 G, 1 variable 0.46 G). Two are not read:
    # - the lane id gives the edge and the lane index (ROAD_ID and LANE_INDEX), read once per
    #   lane (:meth:`_lane_of`); for a vehicle on no lane (teleporting, parked) it is "": edge
    #   "", lane INVALID_INT_VALUE;
    # - the acceleration is SUMO's own (vehicle.getAcceleration: SPEED2ACCEL(vNext - v), the
    #   speed change over the step divided by the step length, every vehicle, every step)
    #   from the speeds read one step apart, to the last bit (:meth:`_read`); SUMO is
    #   asked for it where there is no such pair (a vehicle's first step, a vehicle back from
    #   off the lanes, a read that skipped steps).
    VARS = (
        "LANE_ID",
        "LANEPOSITION",
        "LANEPOSITION_LAT",
        "POSITION",
        "SPEED",
    )

    def __init__(
        self,
        args: list[str],
        *,
        route_edges: Iterable[str] = (),
        is_cav=None,
        use_traci: bool = False,
        gui: bool = False,
        label: str | None = None,
        fcd_path: Path | None = None,
    ) -> None:
        self.fcd_path = fcd_path
        self.args = list(args)
        self.use_traci = use_traci or gui
        self.gui = gui
        self.label = label
        self.api = _api(self.use_traci)
        self.sumo_errors = traci_errors()  # a vehicle that vanished: see traci_errors
        self._vars = [getattr(_constants(self.api), f"VAR_{v}") for v in self.VARS]
        self._route_edges = list(route_edges)  # set on the frame once SUMO runs
        self.frame = RouteFrame(SumoNetwork(self.api))
        self._is_cav = is_cav or (lambda vid, type_id: False)
        self.kinds: dict[str, str] = {}
        self.lengths: dict[str, float] = {}
        self.widths: dict[str, float] = {}
        self.released: set[str] = set()  # CAVs handed back to SUMO (they left the swarm)
        self._standing_since: dict[str, float] = {}  # released CAV -> since when it stands [s]
        self._lanes: dict[str, tuple[str, int, float]] = {}  # lane id -> edge, index, width
        self.types: dict[str, str] = {}
        self.vehicle_classes: dict[str, str] = {}  # SUMO's vClass of each vehicle's type
        self._type_classes: dict[str, str] = {}
        self.columns = StepColumns()  # the last read (what :meth:`_read` gives)
        self._speeds: dict[str, float] = {}  # the last read's speeds, by vehicle [m/s]
        self._forgotten: set[str] = set()  # taken out since the last read (:meth:`_forget`)
        # Called before a vehicle id seen before departs again (TraCI can add one of an id
        # that arrived) and gets its new kind, length and width: the recorder packs the rows
        # it holds of the old one first.
        self.on_id_reused: list[Callable[[], None]] = []
        self._released_at_read: frozenset[str] = frozenset()  # :attr:`released` then
        # The views of the last read, each made when first asked (None: not yet).
        self._states: dict[str, VehicleState] | None = None
        self._positions: dict[str, tuple[float, float]] | None = None
        self._edges: dict[str, str] | None = None
        self._lane_positions: dict[str, float] | None = None
        # states_in_lanes_of's tables of this step, per lane numbering (of the table held)
        self._lane_views_of: dict[str, VehicleState] | None = None
        self._lane_views: dict[int | None, dict[str, VehicleState]] = {}
        self._lane_views_by_edge: dict[str | None, list[str]] | None = None
        self._lane_views_renumbered: dict[tuple[str, int], VehicleState] = {}
        self.collisions: list[Collision] = []
        self.teleports: int = 0
        self.departed: list[str] = []
        self._alone_types: set[str] = set()  # vTypes drive_alone set
        self._moving_sideways: set[str] = set()  # vehicles whose last sublane command moved
        self._speeds_commanded: dict[str, float] = {}  # this step's, until flush_commands
        self._sideways: dict[str, float] = {}  # this step's sublane moves [m], by vehicle
        self._stays: set[str] = set()  # this step's vehicles told to move no further
        self.arrived: list[str] = []
        self.time_s = 0.0
        self.step_length_s = 0.0
        self.cav_ids: list[str] = []
        self.vanished: list[tuple[float, str]] = []
        self._open = False
        self._owned = True
        self._present: set[str] = set()  # with fcd_path: departed, not arrived
        # with fcd_path: every vehicle on the road at the end of a step (in SUMO's FCD output)
        self.drove: set[str] = set()
        # with fcd_path: every lane's edge, index and width, read at the start
        self.lane_table: dict[str, tuple[str, int, float]] = {}
        self._driver_types: dict[str, DriverModel] = {}
        self._keeps_right: dict[str, bool] = {}
        self._keep_right_seen: dict[str, tuple[float, float]] = {}
        self._lc_params: dict[str, tuple[float, float]] = {}
        self._driver_models: dict[str, tuple[str, DriverModel]] = {}

    @classmethod
    def attached(
        cls, api: ModuleType, *, route_edges: Iterable[str] = (), is_cav=None
    ) -> SumoSession:
        """A session on a simulation that is already running (libsumo module or traci)."""
        session = cls([], route_edges=route_edges, is_cav=is_cav)
        session.api = api
        session.frame = RouteFrame(SumoNetwork(api))
        session._vars = [getattr(_constants(api), f"VAR_{v}") for v in cls.VARS]
        session._owned = False
        session._open = True
        session.step_length_s = api.simulation.getDeltaT()
        session.time_s = api.simulation.getTime()
        session._set_route(session._route_edges)
        for vid in api.vehicle.getIDList():  # vehicles already driving when attached
            session._register(vid)
        return session

    # ------------------------------------------------------------------ life cycle
    def __enter__(self) -> SumoSession:
        self.start()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def start(self) -> None:
        """Start SUMO (once: a session started before its ``with`` block is not restarted)."""
        if self._open:
            return
        if self.gui:
            require_display()
        cmd = [sumo_binary(self.gui), *self.args]
        try:
            if self.use_traci:
                self.api.start(cmd, label=self.label) if self.label else self.api.start(cmd)
            else:
                self.api.start(cmd)
        except Exception as exc:  # SUMO refuses its input: report it as a simulation error
            raise SimulationError(f"SUMO did not start: {exc}") from None
        self._open = True
        self.step_length_s = self.api.simulation.getDeltaT()
        self.time_s = self.api.simulation.getTime()
        self._set_route(self._route_edges)
        if self.fcd_path is not None:
            self.lane_table = {lane: self._lane_of(lane) for lane in self.api.lane.getIDList()}

    def _set_route(self, edges: Iterable[str]) -> None:
        self._route_edges = list(edges)
        self.frame.set_route(self._route_edges)

    @property
    def route_edges(self) -> list[str]:
        return list(self._route_edges)

    def near_lane_shift(self, s_m: float, within_m: float) -> bool:
        """See :meth:`RouteFrame.near_lane_shift`."""
        return self.frame.near_lane_shift(s_m, within_m)

    def states_in_lanes_of(self, vid: str) -> dict[str, VehicleState]:
        """:attr:`states` with every vehicle's lane index counted as on ``vid``'s edge (on a
        junction edge, the route edge it leaves: :meth:`RouteFrame.route_edge`), so that
        vehicles on either side of a place where lane indices shift (a lane drop, an on-ramp's
        added lane) compare lanes. A vehicle in a lane that does not exist on that edge (an
        acceleration lane that ends, a lane that begins later) gets the index that lane would
        have there, outside the edge's lanes (-1 beside lane 0): given its own index instead, a
        CAV SUMO drove, standing at the end of an on-ramp's acceleration lane, was taken to be
        in the lane beside it, and a platoon's CAV there braked to 1.4 m/s behind it and
        stopped that lane (the 5-lane OSM road at 40 % CAVs, seed 6). A vehicle off the route
        keeps its own index. SUMO's outputs keep SUMO's indices: this is the controllers' view
        only."""
        frame = self.frame
        edge = self.edges.get(vid)
        if edge is None or not frame.lane_shifts_m:  # every edge numbers its lanes alike
            return self.states
        reference = frame.route_edge(edge)
        # One table per lane numbering and step, whoever asks (many swarms share an edge, and
        # the edges between two lane shifts number their lanes alike: the table renumbers
        # every vehicle by its edge's lane offset less the reference's, nothing else).
        if self._lane_views_of is not self.states:
            self._lane_views_of, self._lane_views = self.states, {}
            self._lane_views_by_edge = None
        numbering = frame.lane_offset.get(reference)
        out = self._lane_views.get(numbering)
        if out is None:
            out = self._lane_views[numbering] = self._in_lanes_of(reference)
        return out

    def _in_lanes_of(self, reference: str) -> dict[str, VehicleState]:
        """:attr:`states` renumbered as on ``reference``: a copy with only the vehicles whose
        lane index differs there replaced, found edge by edge (one lane offset per edge; a
        junction edge's per lane)."""
        frame = self.frame
        states = self.states
        if self._lane_views_by_edge is None:  # the vehicles of each edge, once per step
            by_edge: dict[str | None, list[str]] = {}
            edges = self.edges
            for vid in states:
                by_edge.setdefault(edges.get(vid), []).append(vid)
            self._lane_views_by_edge = by_edge
            self._lane_views_renumbered = {}
        out = dict(states)
        offset_ref = frame.lane_offset.get(reference)
        for own, vids in self._lane_views_by_edge.items():
            if own is None or own == reference:
                continue
            if own in frame.junction_from:  # each lane its own offset (via_lane_offset)
                moved = [(vid, frame.lane_as_on(states[vid].lane, own, reference)) for vid in vids]
            else:
                offset = frame.lane_offset.get(own)
                if offset is None or offset_ref is None or offset == offset_ref:
                    continue
                shift = offset - offset_ref
                moved = [(vid, states[vid].lane + shift) for vid in vids]
            renumbered = self._lane_views_renumbered
            for vid, lane in moved:
                state = states[vid]
                if lane is None or lane == state.lane:
                    continue
                again = renumbered.get((vid, lane))
                if again is None:  # made once per step, whichever edge's table asks
                    again = renumbered[vid, lane] = VehicleState(
                        state.vehicle_id, state.s_m, lane, state.lat_m, state.speed_mps,
                        state.length_m, state.accel_mps2, state.is_cav, state.width_m,
                    )  # fmt: skip
                out[vid] = again
        return out

    def lanes_ending(self, edge: str, s_from_m: float, s_to_m: float) -> list[tuple[int, float]]:
        """Lanes that end between ``s_from_m`` and ``s_to_m`` [m]: see
        :meth:`RouteFrame.lanes_ending`."""
        return self.frame.lanes_ending(edge, s_from_m, s_to_m)

    def close(self) -> None:
        if self._open and self._owned:
            self._open = False
            try:
                self._read_type_classes()
            except Exception as exc:  # SUMO failed: the types stay as the run saw them
                log.debug("reading vTypes at the end: %s", exc)
            try:
                self.api.close()
            except Exception as exc:  # already gone: nothing left to release
                log.debug("closing SUMO: %s", exc)

    def _read_type_classes(self) -> None:
        """Every vType's vClass while SUMO still runs (for vehicles that never departed)."""
        for type_id in self.api.vehicletype.getIDList():
            self._type_class(type_id)

    def _type_class(self, type_id: str) -> str:
        """SUMO's vClass of vType ``type_id``, read once."""
        vclass = self._type_classes.get(type_id)
        if vclass is None:
            vclass = self._type_classes[type_id] = self.api.vehicletype.getVehicleClass(type_id)
        return vclass

    def classify(self, vid: str, type_id: str) -> tuple[str, str | None]:
        """``(kind, vClass)`` of vehicle ``vid`` of vType ``type_id``: as registered when it
        departed, or from its type for one that never did (``kind`` "cav" or "hv")."""
        kind = self.kinds.get(vid) or ("cav" if self._is_cav(vid, type_id) else "hv")
        return kind, self.vehicle_classes.get(vid) or self._type_classes.get(type_id)

    # ------------------------------------------------------------------ stepping
    def step(self) -> None:
        """Advance SUMO by one step and refresh :attr:`states` (bulk, by subscription)."""
        self.flush_commands()
        try:
            self.api.simulation.step()
        except Exception as exc:
            raise SimulationError(f"SUMO stopped at t = {self.time_s:.2f} s: {exc}") from None
        self.refresh()

    def refresh(self) -> None:
        """Read what the last SUMO step did: departures, collisions, every vehicle's state."""
        api = self.api
        try:
            self.time_s = api.simulation.getTime()
            self.departed = list(api.simulation.getDepartedIDList())
            self.arrived = list(api.simulation.getArrivedIDList())
            for vid in self.departed:
                self._register(vid)
            for vid in self.arrived:  # what was kept per vehicle goes with it (an hour's flows)
                self.released.discard(vid)
                self._standing_since.pop(vid, None)
                self._lc_params.pop(vid, None)
                self._keeps_right.pop(vid, None)
                self._keep_right_seen.pop(vid, None)
                self._driver_models.pop(vid, None)
            for c in api.simulation.getCollisions():
                self.collisions.append(Collision(self.time_s, c.collider, c.victim, c.type))
            self.teleports += api.simulation.getStartingTeleportNumber()
            if self.fcd_path is not None:  # SUMO records: nothing read of the vehicles
                self._present.update(self.departed)
                self._present.difference_update(self.arrived)
                self.drove.update(set(self.departed).difference(self.arrived))
                self.columns = StepColumns(self.time_s)
                return
            results = api.vehicle.getAllSubscriptionResults()
        except Exception as exc:
            raise SimulationError(f"SUMO stopped at t = {self.time_s:.2f} s: {exc}") from None
        self._read(results)

    def _register(self, vid: str) -> None:
        api = self.api
        if vid in self.kinds:
            for hook in self.on_id_reused:
                hook()
        if self.fcd_path is None:
            api.vehicle.subscribe(vid, self._vars)
        type_id = api.vehicle.getTypeID(vid)
        self.types[vid] = type_id
        self.vehicle_classes[vid] = self._type_class(type_id)
        self.lengths[vid] = api.vehicle.getLength(vid)
        self.widths[vid] = api.vehicle.getWidth(vid)
        is_cav = self._is_cav(vid, type_id)
        self.kinds[vid] = "cav" if is_cav else "hv"
        if is_cav:
            self.cav_ids.append(vid)
            if not self._route_edges:
                self._set_route(api.vehicle.getRoute(vid))

    def _read(self, results: dict) -> None:
        """Take one step's subscription results as :attr:`columns`, a list per quantity (the
        per-vehicle views follow when asked: :attr:`states`)."""
        c = _constants(self.api)
        ids = list(results)
        rows = list(results.values())
        lane_ids = list(map(itemgetter(c.VAR_LANE_ID), rows))
        lane_pos = list(map(itemgetter(c.VAR_LANEPOSITION), rows))
        speed = list(map(itemgetter(c.VAR_SPEED), rows))
        where = list(map(self._lanes.get, lane_ids))
        if None in where:  # a lane seen for the first time, or none
            where = [w or self._lane_of(lane) for w, lane in zip(where, lane_ids, strict=True)]
        edges = list(map(itemgetter(0), where))
        lanes = list(map(itemgetter(1), where))
        widths = list(map(itemgetter(2), where))
        dt = self.step_length_s
        # Along the route frame: the edge's offset plus the lane position on a route edge.
        offsets = list(map(self.frame.edge_offset_m.get, edges))
        s = [p if o is None else o + p for o, p in zip(offsets, lane_pos, strict=True)]
        if None in offsets:  # another edge (a junction's, a ramp): the frame's projection
            previous = dict(zip(self.columns.ids, self.columns.s_m, strict=True))
            for vid in self._forgotten:
                previous.pop(vid, None)
            route_s = self.frame.route_s
            for i, o in enumerate(offsets):
                if o is None:
                    x = route_s(edges[i], lanes[i], lane_pos[i])
                    if x is None:  # a junction edge off the route: integrate the speed
                        x = carried_route_s(lane_pos[i], speed[i], previous.get(ids[i]), dt)
                    s[i] = x
        # SUMO's acceleration from the speeds one step apart (see VARS); else SUMO's answer
        # (before the first read the columns are empty, and so are the speeds)
        one_step = abs(self.time_s - dt - self.columns.time_s) < 1e-6
        before = list(map(self._speeds.get, ids)) if one_step else [None] * len(ids)
        accel = [
            None if was is None or was < 0.0 or v < 0.0 else (v - was) / dt
            for v, was in zip(speed, before, strict=True)
        ]
        if None in accel:  # a first step, back on a lane, a skipped step
            asked = self.api.vehicle.getAcceleration
            accel = [asked(vid) if a is None else a for vid, a in zip(ids, accel, strict=True)]
        self.columns = StepColumns(
            self.time_s, ids, edges, lanes, lane_pos, s,
            list(map(itemgetter(c.VAR_LANEPOSITION_LAT), rows)), speed, accel,
            list(map(itemgetter(c.VAR_POSITION), rows)), widths,  # (x, y): tuples already
        )  # fmt: skip
        self._speeds = speeds = dict(zip(ids, speed, strict=True))
        self._forgotten.clear()
        self._released_at_read = frozenset(self.released)
        self._states = self._positions = self._edges = self._lane_positions = None
        for vid in self.released:  # how long each released CAV has stood (standing_s)
            v = speeds.get(vid)
            if v is not None and v < STANDING_MPS:
                self._standing_since.setdefault(vid, self.time_s)
            else:
                self._standing_since.pop(vid, None)

    # The last read as dicts by vehicle, each made when first asked in a step.
    @property
    def states(self) -> dict[str, VehicleState]:
        """Every vehicle of the last read (a released CAV counts as an HV: SUMO drives it)."""
        if self._states is None:
            c = self.columns
            lengths, widths, kinds = self.lengths, self.widths, self.kinds
            released = self._released_at_read
            rows = zip(c.ids, c.s_m, c.lane, c.lat_m, c.speed_mps, c.accel_mps2, strict=True)
            self._states = {
                vid: VehicleState(
                    vid,
                    s,
                    lane,
                    lat,
                    v,
                    lengths.get(vid, 5.0),
                    a,
                    kinds.get(vid) == "cav" and vid not in released,
                    widths.get(vid, 1.8),
                )
                for vid, s, lane, lat, v, a in rows
            }
        return self._states

    @states.setter
    def states(self, states: dict[str, VehicleState]) -> None:
        self._states = states

    @property
    def positions(self) -> dict[str, tuple[float, float]]:
        """``(x, y)`` of every vehicle of the last read [m]."""
        if self._positions is None:
            self._positions = dict(zip(self.columns.ids, self.columns.xy, strict=True))
        return self._positions

    @property
    def edges(self) -> dict[str, str]:
        """The edge of every vehicle of the last read ("" on no lane)."""
        if self._edges is None:
            self._edges = dict(zip(self.columns.ids, self.columns.edge, strict=True))
        return self._edges

    @property
    def lane_positions(self) -> dict[str, float]:
        """Front bumper along its lane of every vehicle of the last read [m]."""
        if self._lane_positions is None:
            c = self.columns
            self._lane_positions = dict(zip(c.ids, c.lane_pos_m, strict=True))
        return self._lane_positions

    def _lane_of(self, lane_id: str) -> tuple[str, int, float]:
        """``(edge, lane index, lane width [m])`` of SUMO lane ``lane_id`` (read once); ""
        (a vehicle on no lane): ``("", INVALID_INT_VALUE, nan)``, what ROAD_ID and LANE_INDEX
        give a teleporting one."""
        if not lane_id:
            return "", _constants(self.api).INVALID_INT_VALUE, float("nan")
        lane = self.api.lane
        where = self._lanes[lane_id] = (
            lane.getEdgeID(lane_id), int(lane_id.rpartition("_")[2]), lane.getWidth(lane_id)
        )  # fmt: skip
        return where

    def has_vehicles_to_come(self) -> bool:
        return self.api.simulation.getMinExpectedNumber() > 0

    # ------------------------------------------------------------------ road
    def road_section(self, edge: str) -> RoadSection:
        """Lane widths and curvature of ``edge``: see :meth:`RouteFrame.road_section`."""
        return self.frame.road_section(edge)

    # ------------------------------------------------------------------ commands
    def _command(self, vid: str, call, *args) -> bool:
        """Send one command; a vehicle SUMO no longer knows is a warning, not a crash.

        It is dropped from :attr:`states` at once (so the controller stops commanding it this
        step) and listed in :attr:`vanished`. Returns whether the command went through.
        """
        try:
            call(vid, *args)
        except self.sumo_errors as exc:
            if not self._gone(vid):
                raise
            log.warning("vehicle %s vanished: %s", vid, exc)
            self.vanished.append((self.time_s, vid))
            self._forget(vid)
            return False
        return True

    def _gone(self, vid: str) -> bool:
        try:
            return vid not in self.api.vehicle.getIDList()
        except Exception:
            return True

    def remove_vehicle(self, vid: str) -> None:
        """Take ``vid`` out of the simulation.

        Unsubscribes first: with libsumo 1.28, ``vehicle.remove`` on a subscribed vehicle makes
        the next ``simulation.step()`` fail with "Vehicle ... is not known" (measured).
        """
        self.api.vehicle.unsubscribe(vid)
        self.api.vehicle.remove(vid)
        self._forget(vid)

    def _forget(self, vid: str) -> None:
        """Take ``vid`` out of this step's views and out of what the next read carries over
        (its speed for the acceleration, its route position on a junction): a vehicle of the
        same id read later starts afresh, as one that departs."""
        self.states.pop(vid, None)
        self._lane_views_of = None  # the step's renumbered tables are made again without it
        self._speeds.pop(vid, None)
        self._present.discard(vid)
        self._moving_sideways.discard(vid)
        self._forgotten.add(vid)

    def route_of(self, vid: str) -> tuple[tuple[str, ...], int] | None:
        """``vid``'s route edges and the index of the edge it is on (None if it vanished)."""
        vehicle = self.api.vehicle
        try:
            return tuple(vehicle.getRoute(vid)), int(vehicle.getRouteIndex(vid))
        except self.sumo_errors:
            return None

    def distance_to_parting_m(
        self, vid: str, route: tuple[str, ...], index: int, ours: frozenset[str]
    ) -> float | None:
        """Distance [m] from ``vid``'s front along ``route`` (from edge ``index``) to the first
        edge not in ``ours``; None if the rest of the route stays within ``ours``."""
        position = self.lane_positions.get(vid)
        if position is None or not 0 <= index < len(route):
            return None
        distance = -position
        for edge in route[index:]:
            if edge not in ours:
                return max(distance, 0.0)
            distance += self.frame.net.lane_length_m(f"{edge}_0")
        return None

    def release(self, vid: str) -> None:
        """Let SUMO change ``vid``'s lanes again (its default lane-change mode: strategic
        changes for its own route included); it leaves the swarm for its own route. Its speed
        stays commanded (a controller follows with CACC): handed back to SUMO's car-following
        at the platoon's short gap, SUMO braked it at 4.9 m/s^2 to open a gap at once."""
        self.released.add(vid)
        self.set_modes(vid, None, LC_MODE_DEFAULT)
        vehicle = self.api.vehicle
        try:
            # SUMO's own lane changes may brake at up to decel (4.5 m/s^2 by default): a CAV,
            # even one that left the swarm, stays inside the 4 m/s^2 hard-brake line.
            decel = self.api.vehicletype.getDecel(vehicle.getTypeID(vid))
            vehicle.setDecel(vid, min(decel, ALONE_DECEL_MPS2))
        except self.sumo_errors:  # vanished: nothing to hand back
            pass

    def drive_alone(self, vid: str) -> None:
        """SUMO drives CAV ``vid`` alone until a platoon takes it (:meth:`configure_cav`): it
        keeps at least SUMO's default headway and minGap (SUMO_TAU_S, SUMO_MIN_GAP_M; its vType's
        where larger, a user's type as it is) and brakes at most at the hard-brake line
        (ALONE_DECEL_MPS2). Set on its vType too, once per vType, so that SUMO inserts the
        next CAVs of that type within them: set on each CAV only after its insertion, a CAV
        inserted at departSpeed="max" at the short tau of the scenarios' CAV type then braked
        beyond 4 m/s^2 to open SUMO's gap (693 of 1101 CAV hard-brake steps of a corridor run at
        40 % CAVs, all within 2 s of departure)."""
        vehicle, vtypes = self.api.vehicle, self.api.vehicletype
        try:
            base, tau, min_gap = self._alone_gaps(vid)
            if base not in self._alone_types:
                self._alone_types.add(base)
                vtypes.setTau(base, tau)
                vtypes.setMinGap(base, min_gap)
                if vtypes.getDecel(base) > ALONE_DECEL_MPS2:
                    vtypes.setDecel(base, ALONE_DECEL_MPS2)
            vehicle.setTau(vid, tau)
            vehicle.setMinGap(vid, min_gap)
        except self.sumo_errors:  # vanished: nothing to set
            pass

    def alone_gap_m(
        self, vid: str, speed_mps: float, lead_mps: float, lead_id: str | None = None
    ) -> float:
        """The gap [m] SUMO wants ahead of CAV ``vid`` once it drives alone (:meth:`drive_alone`)
        at ``speed_mps`` behind vehicle ``lead_id`` at ``lead_mps``, which SUMO takes to brake at
        its apparentDecel; SUMO's defaults where SUMO cannot tell. Taken as braking at the
        CAV's own decel, a leader at 4.5 m/s^2 was 12.5 m closer than SUMO wants at 30 m/s
        behind it, and SUMO braked the CAV handed to it there beyond 4 m/s^2."""
        vehicle = self.api.vehicle
        try:
            _, tau, min_gap = self._alone_gaps(vid)
            decel = min(vehicle.getDecel(vid), ALONE_DECEL_MPS2)
        except self.sumo_errors:  # vanished
            tau, min_gap, decel = SUMO_TAU_S, SUMO_MIN_GAP_M, ALONE_DECEL_MPS2
        lead_decel = SUMO_DEFAULTS.decel_mps2
        if lead_id:
            with contextlib.suppress(*self.sumo_errors):  # vanished: SUMO's default
                lead_decel = vehicle.getApparentDecel(lead_id)
        return min_gap + secure_gap_m(tau, decel, speed_mps, lead_mps, lead_decel)

    def _alone_gaps(self, vid: str) -> tuple[str, float, float]:
        """``(its user's vType, headway [s], minGap [m])`` of CAV ``vid`` driving alone: at
        least SUMO's defaults, its vType's where larger."""
        vtypes = self.api.vehicletype
        base = self._user_type(vid)
        return (
            base,
            max(vtypes.getTau(base), SUMO_TAU_S),
            max(vtypes.getMinGap(base), SUMO_MIN_GAP_M),
        )

    def _user_type(self, vid: str) -> str:
        """The user's vType of ``vid``, not SUMO's copy of it (``cav@vid``, made when one of
        its parameters was set for ``vid`` alone)."""
        return self.api.vehicle.getTypeID(vid).split("@")[0]

    def reclaim(self, vid: str) -> None:
        """``vid``, released before, is a swarm's CAV again (a platoon took it in: its
        controller sets its modes); :attr:`states` shows it as a CAV from the next read."""
        self.released.discard(vid)

    def lane_change_need(self, vid: str) -> tuple[float, int] | None:
        """``(distance [m], lanes)``: how far ``vid`` can still drive in its lane before its
        route needs another one, and how many lanes over that one is (SUMO's best lanes); None
        while its lane goes on along its route, or if SUMO cannot tell."""
        state, edge = self.states.get(vid), self.edges.get(vid)
        if state is None or edge is None:
            return None
        lane = f"{edge}_{state.lane}"  # this step's read: no further call for it
        try:
            best = self.api.vehicle.getBestLanes(vid)
        except self.sumo_errors:  # vanished
            return None
        for lane_id, length, _, offset, _, _ in best:
            if lane_id == lane:  # (a junction lane is not among them)
                if offset == 0:
                    return None
                return length - self.lane_positions.get(vid, 0.0), abs(int(offset))
        return None

    def standing_s(self, vid: str) -> float:
        """How long [s] released CAV ``vid`` has stood still (0 while it moves)."""
        since = self._standing_since.get(vid)
        return 0.0 if since is None else self.time_s - since

    def miss_exit(self, vid: str) -> str | None:
        """Let ``vid`` drive on along the road instead of taking the exit its route needs (a
        new route to the route frame's last edge, through the lane it is in); the edge it was
        heading for, or None when its lane does not go on (it ends) or SUMO finds no such
        route (it keeps its own)."""
        vehicle = self.api.vehicle
        edges, edge, state = self.route_edges, self.edges.get(vid), self.states.get(vid)
        if not edges or edge is None or state is None or edge.startswith(":"):
            return None
        try:
            if not self.api.lane.getLinks(f"{edge}_{state.lane}"):
                return None  # a lane that ends: driving on does not need it less
            was = vehicle.getRoute(vid)[-1]
            if was == edges[-1]:
                return None
            vehicle.changeTarget(vid, edges[-1])
        except self.sumo_errors:  # vanished, or no route there from where it is
            return None
        return was

    def set_speed(self, vid: str, speed_mps: float) -> None:
        """Command ``vid``'s speed for the next step [m/s]: sent by :meth:`flush_commands`,
        capped so that it is safe for the whole step (:mod:`sumo_swarm.core.stepsafe`)."""
        self._speeds_commanded[vid] = max(0.0, speed_mps)

    def release_speed(self, vid: str) -> None:
        """Hand the speed back to SUMO's car-following model."""
        self._speeds_commanded.pop(vid, None)
        self._command(vid, self.api.vehicle.setSpeed, -1.0)

    def flush_commands(self) -> None:
        """Send this step's speed commands; at steps longer than the CAVs' tau
        (:func:`~sumo_swarm.core.stepsafe.net_applies`), each capped by the step-safety net
        (:func:`~sumo_swarm.core.stepsafe.capped_speeds`) towards the vehicle ahead in its lane
        and, moving sideways, in the lane it moves to; a commanded leader at its capped
        command; and each sublane move that would bring the CAV's body against another's by the
        end of the step held (:func:`~sumo_swarm.core.stepsafe.sideways_conflicts`). Called once
        the controllers have commanded the step (and before SUMO steps)."""
        commands, self._speeds_commanded = self._speeds_commanded, {}
        sideways, self._sideways = self._sideways, {}
        stays, self._stays = self._stays, set()
        if not net_applies(self.step_length_s):  # SUMO's own check holds within the step
            for vid, speed in commands.items():
                self._command(vid, self.api.vehicle.setSpeed, speed)
            self._send_sideways(sideways, stays)
            return
        states = self.states
        decels: dict[str, float] = {}

        def decel_of(vid: str) -> float:
            decel = decels.get(vid)
            if decel is None:
                try:
                    decel = decels[vid] = self.api.vehicle.getDecel(vid)
                except self.sumo_errors:  # vanished: it brakes as SUMO's default
                    decel = decels[vid] = SUMO_DEFAULTS.decel_mps2
            return decel

        snapshots = PassSnapshots()  # the tables hold still until SUMO steps
        moved: dict[int, tuple[dict, dict]] = {}  # by table id: (table, table moved)

        def after_moves(table: dict[str, VehicleState]) -> dict[str, VehicleState]:
            """``table`` with every vehicle moving sideways this step where it ends up."""
            entry = moved.get(id(table))
            if entry is None or entry[0] is not table:
                end = dict(table)
                for vid, dlat in sideways.items():
                    st = end.get(vid)
                    if st is not None:
                        end[vid] = dataclasses.replace(st, lat_m=st.lat_m + dlat)
                entry = moved[id(table)] = (table, end)
            return entry[1]

        def leaders_of(vid: str) -> list[tuple[VehicleState, float]]:
            ego = states.get(vid)
            if ego is None:
                return []
            v = max(commands[vid], ego.speed_mps)
            reach = 2.0 * v * dt + v * v / (2.0 * decel_of(vid)) + LEADER_REACH_EXTRA_M
            found: dict[str, tuple[VehicleState, float]] = {}
            road = self.road_at(vid)
            table = self.states_in_lanes_of(vid) if road is not None else {}
            here = table.get(vid)
            if road is not None and here is not None:
                # Every vehicle ahead within what ego covers stopping from a step at its
                # command, not only the nearest; where ego and the others are now, and where
                # those moving sideways end the step (two CAVs moving into one lane in the same
                # step, one behind the other, each saw the lane free and met there). A vehicle
                # found in several of these is one leader: a sideways move changes no gap along
                # the road.
                y = road.y_of(here.lane, here.lat_m)
                ys = (y, y + sideways[vid]) if vid in sideways else (y,)
                layouts = (table, after_moves(table)) if sideways else (table,)
                for layout in layouts:
                    others = snapshots(layout, road)
                    for y_m in ys:
                        for leader in overlapping_ahead(here, others, road, y_m, here.width_m,
                                                        reach):  # fmt: skip
                            found.setdefault(leader[0].vehicle_id, leader)
            # And the leader SUMO sees along ego's route, across junctions and onto the next
            # edges: the search above looks within the road section only (a CAV on the junction
            # towards an off-ramp saw nobody, and at 1 s ran into a CAV standing beyond it).
            try:
                sumo_leader = self.api.vehicle.getLeader(vid, reach)
            except self.sumo_errors:  # vanished
                sumo_leader = None
            if sumo_leader and sumo_leader[0] in states:
                # SUMO's gap is the bumper gap less ego's minGap: the smaller, the safer
                found.setdefault(sumo_leader[0], (states[sumo_leader[0]], max(sumo_leader[1], 0.0)))
            return list(found.values())

        dt = self.step_length_s
        capped = capped_speeds(commands, states, leaders_of, decel_of, dt, STEP_SAFE_MARGIN_M)
        for vid, speed in capped.items():
            self._command(vid, self.api.vehicle.setSpeed, speed)
        lateral: dict[str, float] = {}

        def sideways_of(vid: str) -> float:
            """How far [m] ``vid`` moves sideways this step: as commanded (a CAV told to stay,
            not at all), any other vehicle at SUMO's lateral speed now (a car changing lanes
            moves on: at 1 s a CAV moving into the middle lane met a car moving in from the
            other side)."""
            if vid in sideways:
                return sideways[vid]
            if vid in stays:
                return 0.0
            move = lateral.get(vid)
            if move is None:
                try:
                    move = lateral[vid] = self.api.vehicle.getLateralSpeed(vid) * dt
                except self.sumo_errors:  # vanished
                    move = lateral[vid] = 0.0
            return move

        held = set()
        for vid in sideways:  # moves that meet another vehicle's at the end of the step
            road = self.road_at(vid)
            table = self.states_in_lanes_of(vid)
            if road is None or vid not in table:
                continue
            prints = {}
            for other in within(snapshots(table, road), table[vid].s_m, SIDEWAYS_REACH_M):
                y = road.y_of(other.lane, other.lat_m)
                v = capped.get(other.vehicle_id, other.speed_mps)
                # A vehicle of no command may brake within the step (as the speeds' net takes
                # it): its front anywhere from there to where it keeps its speed (a car moving
                # into the middle lane braked, 25.3 -> 22.6 m/s in the 1 s step, and came level
                # with a CAV moving in from the other side).
                short = 0.0 if other.vehicle_id in capped else braking_short_m(
                    v, decel_of(other.vehicle_id), dt
                )  # fmt: skip
                prints[other.vehicle_id] = Footprint(
                    other.s_m, y, other.s_m + v * dt, y + sideways_of(other.vehicle_id),
                    other.length_m, other.width_m, short,
                )  # fmt: skip
            held |= sideways_conflicts([vid], prints, SIDEWAYS_CLEARANCE_M)
        self._send_sideways({v: d for v, d in sideways.items() if v not in held}, stays | held)

    def change_sublane(self, vid: str, lateral_m: float) -> None:
        """Move ``vid`` sideways by ``lateral_m`` (left positive), within maxSpeedLat per second;
        0: no further. SUMO carries a sublane command on until the whole distance is covered,
        whatever comes after, unless a new command replaces it: so a move that stops after one
        that moved is commanded too (a CAV commanded 6.8 m across, then held beside a car
        moving alongside, went on moving into it at a step of 0.5 s)."""
        if abs(lateral_m) > 1e-4:
            self._sideways[vid] = lateral_m
        else:
            self._sideways.pop(vid, None)
            self._stays.add(vid)

    def _send_sideways(self, moves: Mapping[str, float], stays: Iterable[str]) -> None:
        """Send the step's sublane moves; a vehicle that stays and moved at the last step is
        told to stop (:meth:`change_sublane`)."""
        for vid, lateral_m in moves.items():
            self._moving_sideways.add(vid)
            self._command(vid, self.api.vehicle.changeSublane, lateral_m)
        for vid in stays:
            if vid in self._moving_sideways and vid not in moves:
                self._moving_sideways.discard(vid)
                self._command(vid, self.api.vehicle.changeSublane, 0.0)

    def set_modes(self, vid: str, speed_mode: int | None, lane_change_mode: int | None) -> bool:
        """Set SUMO's speed mode and lane-change mode of ``vid`` (None: leave it); False if the
        vehicle vanished."""
        vehicle = self.api.vehicle
        if speed_mode is not None and not self._command(vid, vehicle.setSpeedMode, speed_mode):
            return False
        if lane_change_mode is not None:
            return self._command(vid, vehicle.setLaneChangeMode, lane_change_mode)
        return True

    def configure_cav(
        self,
        vid: str,
        *,
        lane_change_mode: int,
        lateral_speed_mps: float | None = None,
        type_speed_factor: bool = False,
        decel_mps2: float | None = None,
    ) -> None:
        """Our controllers drive CAV ``vid``: see :meth:`SessionView.configure_cav`. The decel
        lowered to ``decel_mps2``: our controllers never brake harder, and SUMO's safe-speed
        net under them brakes at the vType's decel (SUMO's default 4.5: a CAV cut in 17 m
        ahead of a CAV 3.3 m/s faster at 32 m/s, within the guard's rule, braked its follower
        at 4.5 m/s^2)."""
        if not self.set_modes(vid, SPEED_MODE_SAFE, lane_change_mode):
            return  # vanished
        vehicle = self.api.vehicle
        vehicle.setParameter(vid, "laneChangeModel.lcAccelLat", f"{CAV_LC_ACCEL_LAT_MPS2:g}")
        vehicle.setTau(vid, CAV_TAU_S)
        vehicle.setMinGap(vid, CAV_MIN_GAP_M)
        if lateral_speed_mps is not None:
            vehicle.setMaxSpeedLat(vid, lateral_speed_mps)
        if decel_mps2 is not None and vehicle.getDecel(vid) > decel_mps2:
            vehicle.setDecel(vid, decel_mps2)
            # The decel the CAVs behind assume of it, too (SUMO's apparentDecel, left at the
            # vType's 4.5 otherwise): a follower that can brake less than its leader is
            # assumed to keeps a wider gap, and SUMO's safe speed held every follower 17 m
            # behind at 28.7 m/s against the platoon's 10 m, so the leader eased off for good
            # (users' roads: the platoon cruised at 28.7 m/s with lanes at 33.3).
            vehicle.setApparentDecel(vid, decel_mps2)
        if type_speed_factor:
            type_id = vehicle.getTypeID(vid)  # its own copy (``cav@vid``) has the same factor
            factor = self.api.vehicletype.getSpeedFactor(type_id)
            # Never below the speed it drives now (a CAV that departed at "max" with a higher
            # draw): SUMO would brake it to the new limit at its decel in one step.
            limit = vehicle.getAllowedSpeed(vid) / max(vehicle.getSpeedFactor(vid), 1e-6)
            if limit > 0.0:
                factor = max(factor, vehicle.getSpeed(vid) / limit)
            vehicle.setSpeedFactor(vid, factor)

    def restore_gaps(self, vid: str, *, tau: bool = False) -> None:
        """CAV ``vid``'s minGap (with ``tau``, its headway too) its vType's again: the user's
        vType (:meth:`_user_type`). A CAV SUMO drives keeps the gaps its type keeps (exiting
        CAVs queued 0.5 m apart at an off-ramp with the controllers' minGap)."""
        vehicle, vtypes = self.api.vehicle, self.api.vehicletype
        try:
            type_id = self._user_type(vid)
            if tau:
                vehicle.setTau(vid, vtypes.getTau(type_id))
            vehicle.setMinGap(vid, vtypes.getMinGap(type_id))
        except self.sumo_errors:  # vanished
            pass

    def _keep_right_params(self, vid: str) -> tuple[float, float]:
        """(lcKeepRight, lcSpeedGain) of ``vid``'s lane-change model, read once per vehicle
        (0 and 1 where the model has no such parameter)."""
        cached = self._lc_params.get(vid)
        if cached is None:
            cached = self._lc_params[vid] = (
                self._lc_param(vid, "lcKeepRight", 0.0),
                self._lc_param(vid, "lcSpeedGain", 1.0),
            )
        return cached

    def _lc_param(self, vid: str, name: str, default: float) -> float:
        """A lane-change model parameter of ``vid`` (``default`` where the model has none)."""
        try:
            return float(self.api.vehicle.getParameter(vid, f"laneChangeModel.{name}") or default)
        except ValueError:  # a lane-change model without the parameter
            return default

    def keeps_right(self, vid: str) -> bool:
        """Does ``vid``'s lane-change model keep right: its lcKeepRight above 0 and its
        lane-change mode allowing right-drive changes (bits 6-7)? Read once per vehicle; False
        for one that vanished."""
        cached = self._keeps_right.get(vid)
        if cached is None:
            try:
                eager = self._keep_right_params(vid)[0]
                mode = self.api.vehicle.getLaneChangeMode(vid)
            except self.sumo_errors:  # vanished
                return False
            cached = eager > 0.0 and (mode >> 6) & 3 != 0
            self._keeps_right[vid] = cached
        return cached

    def wants_right(self, vid: str) -> bool:
        """Does ``vid``'s lane-change model want to move right to keep right now, whether the
        lane there lets it or not (SUMO's own state of it: LCA_RIGHT with LCA_KEEPRIGHT, the
        wish a keep-right driver shows while the right lane is taken)? False when it vanished."""
        try:
            state = self.api.vehicle.getLaneChangeState(vid, -1)[0]
        except self.sumo_errors:  # the vehicle left
            return False
        return state & LCA_RIGHT != 0 and state & LCA_KEEPRIGHT != 0

    def lane_wish(self, vid: str) -> tuple[int, bool]:
        """The lane ``vid``'s driver wants to move to now, as SUMO's lane-change model shows it
        (any reason: its route, speed gain, keeping right, cooperation): +1 left, -1 right, 0
        none; and whether a vehicle there blocks it. (0, False) when it vanished."""
        try:
            for direction, side in ((1, LCA_LEFT), (-1, LCA_RIGHT)):
                state = self.api.vehicle.getLaneChangeState(vid, direction)[0]
                if state & side and state & LCA_REASONS:
                    return direction, bool(state & LCA_BLOCKED)
        except self.sumo_errors:  # the vehicle left
            pass
        return 0, False

    def must_change(self, vid: str, direction: int) -> bool:
        """Does ``vid``'s lane-change model want to move one lane ``direction`` (+1 left, -1
        right) for its route (SUMO's LCA_STRATEGIC), whether the lane there lets it or not?
        False when it vanished."""
        try:
            state = self.api.vehicle.getLaneChangeState(vid, direction)[0]
        except self.sumo_errors:  # the vehicle left
            return False
        side = LCA_LEFT if direction > 0 else LCA_RIGHT
        return state & side != 0 and state & LCA_STRATEGIC != 0

    def keep_right_due_s(self, vid: str) -> float | None:
        """Seconds until ``vid``'s keep-right wish shows (0: it shows), from the build-up of its
        lane-change model (keepRightProbability, read through libsumo; see
        :func:`~sumo_swarm.core.swarming.decision.keep_right_due_s`); None when SUMO cannot
        tell (the vehicle left, a model without it, LC2013's whole-number reading: the swarm
        runs with the sublane model, SL2015, which reads to 0.01)."""
        try:
            reading = self.api.vehicle.getParameter(vid, "laneChangeModel.keepRightProbability")
            if "." not in reading:  # LC2013 rounds it to a whole number: too coarse to time
                return None
            probability = float(reading)
            keep_right, speed_gain = self._keep_right_params(vid)
        except self.sumo_errors:  # the vehicle left, or a lane-change model without these
            return None
        before = self._keep_right_seen.get(vid)
        if before is None or self.time_s - before[0] > KEEP_RIGHT_RATE_WINDOW_S:
            self._keep_right_seen[vid] = (self.time_s, probability)
            if before is not None and self.time_s - before[0] > 2.0 * KEEP_RIGHT_RATE_WINDOW_S:
                before = None  # too old to say how fast it builds now
        return keep_right_due_s(
            probability, before, self.time_s, keep_right=keep_right, speed_gain=speed_gain
        )

    def speed_limits(self, vid: str) -> tuple[float, float] | None:
        """(vType maxSpeed, speed allowed on its lane with its speedFactor) of a vehicle [m/s];
        None for one that vanished."""
        vehicle = self.api.vehicle
        try:
            return vehicle.getMaxSpeed(vid), vehicle.getAllowedSpeed(vid)
        except self.sumo_errors:  # vanished
            return None

    def first_road(self) -> RoadSection:
        """The road section where the route starts; two 3.2 m lanes while it is not known."""
        edges = self.frame.route_edges
        return self.road_section(edges[0]) if edges else RoadSection(DEFAULT_WIDTHS_M)

    def road_at(self, vid: str) -> RoadSection | None:
        """The road section under vehicle ``vid`` (None if it is not in the simulation)."""
        edge = self.edges.get(vid)
        return self.road_section(edge) if edge is not None else None

    def exists(self, vid: str) -> bool:
        """Whether ``vid`` was in the last read (and has not vanished since); with
        ``fcd_path``, whether it departed and has not arrived."""
        if self.fcd_path is not None:
            return vid in self._present
        return vid in (self._speeds if self._states is None else self._states)

    # ------------------------------------------------------------------ driver models
    def driver_model(self, vehicle_id: str) -> DriverModel:
        """How ``vehicle_id`` drives: its car-following model and parameters.

        Read once per vType (a vehicle whose parameters were changed has its own copy, e.g.
        ``hv@x``) and once per vehicle for its speedFactor. ``desired_speed_mps`` is SUMO's
        vehicle maxSpeed; on a lane SUMO takes ``min(maxSpeed, limit * speedFactor)``
        (:meth:`DriverModel.desired_speed_on`). A vehicle that vanished: the cautious bound,
        ``DriverModel(model="unknown")``.
        """
        vehicle = self.api.vehicle
        try:
            type_id = vehicle.getTypeID(vehicle_id)
        except self.sumo_errors:  # vanished
            return DriverModel(model="unknown")
        cached = self._driver_models.get(vehicle_id)
        if cached is not None and cached[0] == type_id:
            return cached[1]
        base = self._driver_types.get(type_id)
        if base is None:
            base = self._read_driver_type(vehicle_id)
            self._driver_types[type_id] = base
        model = dataclasses.replace(
            base,
            desired_speed_mps=vehicle.getMaxSpeed(vehicle_id),
            speed_factor=vehicle.getSpeedFactor(vehicle_id),
        )
        self._driver_models[vehicle_id] = (type_id, model)
        return model

    def _read_driver_type(self, vid: str) -> DriverModel:
        """Parameters through TraCI; the model's name by experiment.

        TraCI does not tell the car-following model (libsumo 1.28: ``getParameter`` of
        ``carFollowModel.*`` keys returns ""). SUMO's own ``getFollowSpeed`` does answer
        with the vehicle's model, so a few probe situations are compared with our IDM
        (its delta fitted on a free-road probe) and Krauss formulas: "IDM" or "Krauss" when
        every probe agrees to 1e-6 m/s, "unknown" (conservative bound) otherwise.
        """
        veh = self.api.vehicle
        m = DriverModel(
            model="unknown",
            accel_mps2=veh.getAccel(vid),
            decel_mps2=veh.getDecel(vid),
            emergency_decel_mps2=veh.getEmergencyDecel(vid),
            tau_s=veh.getTau(vid),
            min_gap_m=veh.getMinGap(vid),
            desired_speed_mps=veh.getMaxSpeed(vid),
            length_m=veh.getLength(vid),
            sigma=max(0.0, veh.getImperfection(vid)),  # -1: the model has no sigma
        )
        try:
            return _identify_model(m, vid, veh, self.api.simulation.getDeltaT())
        except Exception as exc:  # a vehicle TraCI cannot probe: keep the conservative bound
            log.warning("car-following model of %s not identified: %s", vid, exc)
            return m


def _identify_model(m: DriverModel, vid: str, veh, step_s: float) -> DriverModel:
    """``m`` named "IDM" (with its delta) or "Krauss" if SUMO's followSpeed of ``vid``
    matches that model in every probe, else ``m`` unchanged ("unknown")."""
    v0 = veh.getAllowedSpeed(vid)  # the desired speed SUMO's followSpeed uses on this lane

    def sumo(v: float, gap_m: float, v_lead: float) -> float:
        # TraCI's gap has minGap removed; ours is the bumper gap
        return veh.getFollowSpeed(vid, v, gap_m - m.min_gap_m, v_lead, m.decel_mps2, "")

    probes = [(0.6 * v0, 20.0, 0.4 * v0), (0.3 * v0, 8.0, 0.3 * v0 + 2.0),
              (0.9 * v0, 60.0, 0.8 * v0), (0.5 * v0, 3.0, 0.2 * v0)]  # fmt: skip
    answers = [sumo(*p) for p in probes]

    def matches(follow) -> bool:
        return all(
            abs(follow(*p) - a) <= 1e-6 * max(1.0, a) for p, a in zip(probes, answers, strict=True)
        )

    idm = _fit_idm_delta(dataclasses.replace(m, model="IDM"), sumo, v0, step_s)
    if idm is not None and matches(lambda v, g, vl: idm_follow_speed(idm, v, vl, g, step_s, v0)):
        return idm
    krauss = dataclasses.replace(m, model="Krauss")
    if matches(lambda v, g, vl: krauss_follow_speed(krauss, v, vl, g, step_s)):
        return krauss
    return m


def _fit_idm_delta(m: DriverModel, sumo, v0: float, step_s: float) -> DriverModel | None:
    """IDM's delta from SUMO's free-road speed at half the desired speed (it rises with delta);
    None if no delta in [0.1, 50] gives it."""
    v = 0.5 * v0
    target = sumo(v, 1e5, v)

    def speed(delta: float) -> float:
        return idm_follow_speed(dataclasses.replace(m, delta=delta), v, v, 1e5, step_s, v0)

    lo, hi = 0.1, 50.0
    if not speed(lo) - 1e-6 <= target <= speed(hi) + 1e-6:
        return None
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if speed(mid) < target:
            lo = mid
        else:
            hi = mid
    delta = 0.5 * (lo + hi)
    # SUMO reads delta from XML as a decimal; a value within 1e-6 of a round one is that one.
    rounded = round(delta, 6)
    return dataclasses.replace(m, delta=rounded if abs(rounded - delta) < 1e-6 else delta)
