"""What every controller is: the small interface the run loop and the plugin API rely on."""

from __future__ import annotations

import logging
import math
import traceback
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Protocol

from sumo_swarm.controllers.session import SPEED_MODE_SAFE, SessionView
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.swarming.guards import lateral_refusal
from sumo_swarm.errors import ConfigError

if TYPE_CHECKING:
    from sumo_swarm.config import CavSettings, Scenario

log = logging.getLogger(__name__)

# Lane-change mode 0: no autonomous lane changes and no safety vetoes of our own sublane moves;
# the planner and its validator own lateral safety (SUMO's safe-speed check stays on, below).
LC_MODE_CONTROLLED = 0
# Lane-change mode 513 for the longitudinal-only CACC platoon: SUMO's strategic changes only
# (bits 0-1 = 1: the ones its route needs, where its lane ends or its route turns off), with
# SUMO's own gap checks; no cooperative, speed-gain or keep-right changes. Mode 0 left a CACC
# platoon in the right lane of a lane drop: its front CAV stopped at the lane's end from
# 25 m/s and the next one hit it (users' lane-drop road).
LC_MODE_STRATEGIC = 0b10_00_00_00_01
# [cav] speeds = "world": speed changes below this are ignored [m/s]
WORLD_SPEED_TOLERANCE_MPS = 0.05
WORLD_SPEED_SOURCE = "SUMO: min over the CAVs of min(vType maxSpeed, lane limit * speedFactor)"
# [cav] speed_factor = "type": the CAVs were given their vType's speedFactor (configure_cav)
WORLD_SPEED_SOURCE_TYPE = (
    "SUMO: min over the CAVs of min(vType maxSpeed, lane limit * the vType's speedFactor)"
)


@dataclass
class CavSpeeds:
    """The CAVs' settings in force (``cav``): the scenario's ``[cav]``, with ``[cav] speeds =
    "world"`` its cruising and highest speed [m/s] following SUMO's desired speed for the CAVs
    where they drive (:meth:`RunContext.follow_world_speeds`). One object, shared by a swarm's
    context and its parts (the reformer), read where they read those speeds: the scenario a run
    was configured with stays as it was."""

    cav: CavSettings
    world_mps: float | None = None  # the last speed taken from the world (None: not yet)

    def follow(self, speed_mps: float) -> None:
        """Cruise at, and never above, ``speed_mps`` [m/s] from now on."""
        self.cav = replace(self.cav, cruising_speed_mps=speed_mps, max_speed_mps=speed_mps)
        self.world_mps = speed_mps


def _no_other_plans() -> Mapping[str, Callable[[float], float]]:
    return {}


def _may_always_start(t_s: float, s_from_m: float, s_to_m: float, target_id: str) -> bool:
    return True


@dataclass
class RunContext:
    """What a controller may use: the SUMO session, the scenario and the road."""

    session: SessionView
    scenario: Scenario  # as configured: never replaced during the run
    cav_ids: tuple[str, ...]  # leader first, as placed at t = 0
    road: RoadSection
    out_dir: Any = None  # pathlib.Path of the run's output folder, or None
    events: list[dict[str, Any]] = field(default_factory=list)
    speeds: CavSpeeds | None = None  # the CAVs' speeds in force (None: the scenario's [cav])
    # Many swarms (controllers.fleet) set these three; the defaults are one swarm's answers.
    platoon_id: int | None = None  # this swarm's number (None: the run's only swarm)
    # The other swarms' CAVs' planned front positions s(t) [m] (t [s]); one swarm: none.
    planned_paths: Callable[[], Mapping[str, Callable[[float], float]]] = _no_other_plans
    # may_start(t_s, s_from_m, s_to_m, target_id): whether a manoeuvre may start on that
    # stretch of road [m]; one swarm: always.
    may_start: Callable[[float, float, float, str], bool] = _may_always_start

    def __post_init__(self) -> None:
        if self.speeds is None:
            self.speeds = CavSpeeds(self.scenario.cav)

    @property
    def cav(self) -> CavSettings:
        """The CAVs' settings in force: ``[cav]`` with the speeds the CAVs drive at now."""
        return self.speeds.cav

    @property
    def dt_s(self) -> float:
        return self.session.step_length_s

    def event(self, kind: str, /, **data: Any) -> None:
        """Record a notable event (fallbacks, vanished vehicles, ...) for the run's outputs
        (``kind`` positional only: a manoeuvre's events have a ``kind`` of their own)."""
        if self.platoon_id is not None:
            data = {"platoon": self.platoon_id, **data}
        self.events.append({"time_s": self.session.time_s, "event": kind, **data})

    def configure_cav(self, vid: str, lane_change_mode: int = LC_MODE_CONTROLLED) -> None:
        """Hand CAV ``vid`` to the controllers (:meth:`SessionView.configure_cav`): its
        maxSpeedLat the trajectories' lateral speed, its braking within ``[cav]
        accel_min_mps2``, and with ``[cav] speeds = "world"`` and ``speed_factor = "type"``
        its vType's speedFactor."""
        cav = self.scenario.cav
        self.session.configure_cav(
            vid, lane_change_mode=lane_change_mode, lateral_speed_mps=cav.max_lateral_speed_mps,
            type_speed_factor=cav.speeds == "world" and cav.speed_factor == "type",
            decel_mps2=-cav.accel_min_mps2,
        )  # fmt: skip

    def follow_world_speeds(self, cav_ids: Sequence[str]) -> None:
        """With ``[cav] speeds = "world"``: set the cruising and highest speed of the CAVs
        (:attr:`speeds`) to SUMO's desired speed for them where they drive, the lowest over
        ``cav_ids`` of min(vType maxSpeed, lane limit * speedFactor) (``session.speed_limits``;
        none where SUMO cannot tell)."""
        if self.scenario.cav.speeds != "world":
            return
        speed = math.inf
        for vid in cav_ids:
            limits = self.session.speed_limits(vid)
            if limits is not None:
                speed = min(speed, *limits)
        if not (math.isfinite(speed) and speed > 0.0):
            return
        cav = self.cav
        if abs(speed - cav.cruising_speed_mps) > WORLD_SPEED_TOLERANCE_MPS or (
            cav.max_speed_mps != cav.cruising_speed_mps
        ):
            first = self.speeds.world_mps is None
            self.speeds.follow(speed)
            if first:
                self.event("world_speeds", cruising_speed_mps=speed, source=self._world_source())

    def _world_source(self) -> str:
        type_factor = self.scenario.cav.speed_factor == "type"
        return WORLD_SPEED_SOURCE_TYPE if type_factor else WORLD_SPEED_SOURCE

    def speeds_block(self) -> dict[str, Any]:
        """The ``speeds`` block of summary.json: the speeds the CAVs were given, and whence."""
        cav = self.cav
        return {
            "cruising_speed_mps": cav.cruising_speed_mps,
            "max_speed_mps": cav.max_speed_mps,
            "source": self._world_source() if cav.speeds == "world" else "config [cav]",
        }


class Controller(Protocol):
    """A controller is attached once, then called after every SUMO step.

    One that reads no vehicle's state at any step (SUMO drives them all) says so with a
    class attribute ``reads_vehicles = False``: SUMO then records the run's trajectories
    itself (:mod:`sumo_swarm.sim.fcd`) and the session reads nothing per vehicle."""

    name: str

    def attach(self, ctx: RunContext) -> None: ...

    def control(self, t_s: float) -> None:
        """Read ``ctx.session.states`` and issue commands that act on the next step."""

    def summary(self) -> dict[str, Any]:
        """Blocks of summary.json this controller fills (``overtake``, ``planner``, ...).

        May be called at any time, also while the run goes on."""


@dataclass
class RouteWatch:
    """CAVs whose routes part from the platoon's leave it before the parting point.

    The platoon's route is that of its front CAV among those heading for the most common
    destination; a CAV whose own route leaves it within ``reach_s`` at its speed (at least
    ``reach_min_m``) is handed back to SUMO (its own car-following and lane changing, so it
    makes the lane changes its exit needs: the controllers' lane-change mode allows none) and a
    ``cav_leaves`` event says so. Checked every ``every_s``; where SUMO cannot tell the routes
    (``route_of`` None), nobody leaves."""

    every_s: float = 1.0
    reach_s: float = 25.0
    reach_min_m: float = 600.0
    left: set[str] = field(default_factory=set)
    _checked_s: float = -math.inf

    def members(self, ctx: RunContext, t_s: float, platoon: Sequence[str]) -> list[str]:
        """``platoon`` (front first) without the CAVs that left it; those follow whatever is
        ahead of them by CACC (``follow``) while SUMO changes their lanes."""
        if t_s - self._checked_s >= self.every_s:
            self._checked_s = t_s
            self._check(ctx, [v for v in platoon if v not in self.left])
        return [v for v in platoon if v not in self.left]

    def follow(self, ctx: RunContext, command: Callable[[RunContext, list[str]], None]) -> None:
        """Drive every CAV that left with ``command`` (the controllers give their CACC step,
        ``cacc.command_cacc``); a no-op while none has left."""
        if self.left:
            command(ctx, [v for v in self.left if ctx.session.exists(v)])

    def _check(self, ctx: RunContext, platoon: list[str]) -> None:
        session = ctx.session
        routes = {vid: session.route_of(vid) for vid in platoon}
        routes = {vid: r for vid, r in routes.items() if r is not None and r[0]}
        if len(routes) < 2:
            return
        main = Counter(route[-1] for route, _ in routes.values()).most_common(1)[0][0]
        front = next(vid for vid in platoon if vid in routes and routes[vid][0][-1] == main)
        ours = frozenset(routes[front][0])
        for vid, (route, index) in routes.items():
            if route[-1] == main:
                continue
            distance = session.distance_to_parting_m(vid, route, index, ours)
            state = session.states.get(vid)
            speed = state.speed_mps if state is not None else 0.0
            if distance is not None and distance <= max(self.reach_min_m, self.reach_s * speed):
                self.left.add(vid)
                session.release(vid)
                ctx.event("cav_leaves", vehicle=vid, reason="route_parts",
                          parting_in_m=round(distance, 1))  # fmt: skip


def _where(exc: BaseException) -> str | None:
    """``file:line in function`` of the innermost frame of ``exc``'s traceback in this
    package (where a bug report starts), else the innermost frame; None without one."""
    frames = traceback.extract_tb(exc.__traceback__)
    ours = [f for f in frames if "sumo_swarm" in f.filename.replace("\\", "/")]
    frame = (ours or frames or [None])[-1]
    if frame is None:
        return None
    name = frame.filename.replace("\\", "/").rsplit("sumo_swarm/", 1)[-1]
    return f"{name}:{frame.lineno} in {frame.name}"


class StandDown:
    """Calls a controller until its first error; then the swarm stands down for the rest of
    the simulation: one warning (the traceback only at debug level) and one
    ``controller_error`` event. From then on the controller's ``fallback(t_s)``, if it has one
    (the swarm: a CACC platoon in its lanes), drives the CAVs; without one, or once that fails
    too, every CAV is handed back to SUMO (:func:`hand_back`). A bug of ours never crashes the
    user's simulation, and never repeats at every step (it did: 2,753 tracebacks in one run).

    :attr:`block` is the summary's ``stood_down``: None, or when, why and what drove on.
    """

    def __init__(self, controller: Controller) -> None:
        self.controller = controller
        self.ctx: RunContext | None = None
        self.at_s: float | None = None
        self.reason: str | None = None
        self.then: str | None = None  # "fallback" or "sumo": what drives the CAVs after

    @property
    def block(self) -> dict[str, Any] | None:
        if self.at_s is None:
            return None
        return {"t_s": self.at_s, "reason": self.reason, "then": self.then}

    def attach(self, ctx: RunContext) -> None:
        self.ctx = ctx
        try:
            self.controller.attach(ctx)
        except ConfigError:  # the controller refuses its settings: bad input, not a bug
            raise
        except Exception as exc:
            self.stand_down(ctx.session.time_s, exc, attached=False)

    def control(self, t_s: float) -> None:
        if self.at_s is None:
            try:
                self.controller.control(t_s)
            except Exception as exc:
                self.stand_down(t_s, exc)
        elif self.then == "fallback":
            try:
                self.controller.fallback(t_s)  # type: ignore[attr-defined]
            except Exception as exc:
                log.debug("the fallback failed at t = %.2f s: %s", t_s, exc)
                self._hand_back_all()
        if self.ctx is not None:  # the step's speeds, safe for the whole step
            try:
                self.ctx.session.flush_commands()
            except Exception as exc:
                self.stand_down(t_s, exc)

    def stand_down(self, t_s: float, exc: Exception, *, attached: bool = True) -> None:
        """Stop calling the controller (at ``t_s`` [s], for ``exc``); ``attached``: whether
        its attach succeeded (else it has no fallback to run)."""
        if self.at_s is not None:
            return
        name = getattr(self.controller, "name", type(self.controller).__name__)
        self.at_s, self.reason = float(t_s), " ".join(f"{type(exc).__name__}: {exc}".split())
        has_fallback = attached and callable(getattr(self.controller, "fallback", None))
        self.then = "fallback" if has_fallback else "sumo"
        drive_on = "as a CACC platoon in their lanes" if has_fallback else "as SUMO drives them"
        log.warning(
            "the %s controller failed at t = %.2f s and stood down; its CAVs drive on %s (%s)",
            name, t_s, drive_on, self.reason,
        )  # fmt: skip
        log.debug("the controller's error", exc_info=exc)
        if self.ctx is None:
            return
        self.ctx.event("controller_error", message=self.reason, action="stood_down",
                       where=_where(exc))  # fmt: skip
        if has_fallback:
            self.control(t_s)  # this step's commands, from the fallback
        else:
            self._hand_back_all()

    def _hand_back_all(self) -> None:
        self.then = "sumo"
        if self.ctx is None:
            return
        for vid in list(self.ctx.session.cav_ids):
            try:
                hand_back(self.ctx.session, vid)
            except Exception as exc:  # SUMO itself failed: nothing left to hand back
                log.debug("handing %s back to SUMO: %s", vid, exc)


def hand_back(session: SessionView, vid: str) -> None:
    """CAV ``vid`` driven by SUMO again: the lane changes its route needs, SUMO's speed mode,
    its speed left to SUMO's car-following, braking within ALONE_DECEL_MPS2
    (:meth:`SumoSession.release`).
    Its minGap is its vType's again; its tau stays the controllers' short one:
    with its vType's (1 s), SUMO braked the CAVs hard to open the gaps at once. A vehicle that
    vanished is left alone."""
    if not session.exists(vid):
        return
    session.release(vid)
    # Only the lane changes its route needs: SUMO's speed-gain changes at the short tau cut in
    # and braked CAVs beyond 4 m/s^2 (the paper scene, the swarm stood down at 3 s).
    session.set_modes(vid, SPEED_MODE_SAFE, LC_MODE_STRATEGIC)
    session.release_speed(vid)
    session.restore_gaps(vid, tau=True)


def close_controller(controller: Controller) -> None:
    """Let a controller release what it holds open (files), if it has a ``close`` method."""
    close = getattr(controller, "close", None)
    if close is not None:
        close()


def lateral_guard(
    scenario: Scenario,
    model_of: Callable[[str], Any],
    ego: VehicleState,
    y: float,
    dlat: float,
    others: Any,  # the vehicles around: a Snapshot or a sequence of VehicleState
    road: RoadSection,
    step_s: float,
    commit: tuple[float, float] | None = None,
) -> str | None:
    """The lateral guard (:func:`~sumo_swarm.core.swarming.guards.lateral_refusal`) on ego's
    move ``dlat`` [m] from ``y``, with the scenario's CAV, HV-model and guard settings: why it
    refuses, or None. ``commit``: ego speeds up at this rate [m/s^2] to this speed [m/s] as it
    moves (the plan follower's moves and the reformer's)."""
    sc = scenario
    accel, final = commit if commit is not None else (0.0, None)
    return lateral_refusal(
        ego, y, dlat, others, road, min_gap_m=sc.cav.min_gap_m, width_m=sc.cav.width_m,
        model_of=model_of, b_safe_mps2=sc.hvmodel.b_safe_mps2, step_s=step_s,
        settings=sc.guards, brake_mps2=-sc.cav.accel_min_mps2,
        ego_accel_mps2=accel, ego_final_mps=final,
    )  # fmt: skip
