"""The plugin API in SUMO's convention (as SUMO's own simpla): attach to a running simulation.

::

    import libsumo  # or: import traci (then sumo-gui works too)
    import sumo_swarm

    libsumo.start(["sumo", "-c", "my.sumocfg", "--lateral-resolution", "0.5",
                   "--time-to-teleport", "-1", "--collision.action", "warn",
                   "--collision.mingap-factor", "0"])
    swarm = sumo_swarm.attach(libsumo, cav_type="cav")
    while libsumo.simulation.getMinExpectedNumber() > 0:
        libsumo.simulation.step()
    print(swarm.summary()["overtake"])
    swarm.detach()
    libsumo.close()

The swarm runs as a StepListener: after every SUMO step it reads the vehicles and commands the
CAVs for the next step. CAVs are the vehicles of vType ``cav_type`` (or of SUMO's copy of it for
one vehicle, ``cav_type@vehicle``) or the ids in ``cav_ids``, including vehicles that depart
later.
"""

from __future__ import annotations

import importlib
import logging
import os
import time
import weakref
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path
from types import ModuleType
from typing import Any

from sumo_swarm.checks import require_number
from sumo_swarm.config import Scenario
from sumo_swarm.controllers import CONTROLLERS, make_controller
from sumo_swarm.controllers.base import Controller, RunContext, StandDown
from sumo_swarm.errors import ConfigError, SessionError
from sumo_swarm.files import writable_folder
from sumo_swarm.sim.bridge import SumoSession, is_of_type, unknown_vtype
from sumo_swarm.sim.gui import attach_plan_drawer
from sumo_swarm.sim.recorder import EMPTY_WINDOW_S, RunRecorder
from sumo_swarm.sim.runfolder import check_out_folder
from sumo_swarm.sim.scene import LiveScene, default_settings
from sumo_swarm.sim.steplimit import check_step_length

log = logging.getLogger(__name__)

__all__ = ["SwarmHandle", "attach", "default_settings", "detach", "warn_if_sumo_teleports"]


class SwarmHandle:
    """A swarm attached to a running simulation; see :func:`attach`."""

    def __init__(
        self,
        api: Any,
        controller: Controller,
        settings: Scenario,
        is_cav,
        cruising_speed_mps: float | None,
        out_dir: Path | None,
    ) -> None:
        self.api = api
        self.settings = settings
        self.controller = controller
        self.session = SumoSession.attached(api, is_cav=is_cav)
        self._cruising_speed = cruising_speed_mps
        self.ctx = RunContext(
            self.session, settings, self.session.cav_ids, self.session.first_road(), out_dir=out_dir
        )
        self.out_dir = out_dir
        self.recorder = RunRecorder(
            self.session,
            controller,
            controller.name,
            LiveScene(self.session, controller),
            settings.outputs,
            out_dir=out_dir,
        )
        self._attached = False
        self._controller_attached = False
        self.guard = self.recorder.stand_down = StandDown(controller)  # an error: once
        self.attached_at_s = self.session.time_s
        self.token = f"{os.getpid()}:{id(self)}"  # names it in the simulation's parameters
        self._failed = False  # reading SUMO failed: the swarm stood down, nothing more is read
        base = _step_listener_base(api)
        handle = self

        class _Listener(base):  # type: ignore[misc, valid-type]
            def step(self, t: float = 0.0) -> bool:
                handle._on_step()
                return True

        self._listener = _Listener()
        self._listener_id = api.addStepListener(self._listener)
        self._attached = True

    def _on_step(self) -> None:
        if self._failed:
            return
        t0 = time.perf_counter()
        try:
            self.session.refresh()
            self.recorder.record()
            if not self._controller_attached and self.session.cav_ids:
                self._adopt_cav_settings()
                self.guard.attach(self.ctx)
                attach_plan_drawer(self.controller, self.ctx.session)
                self._controller_attached = True
        except Exception as exc:  # raised into SUMO's step it would repeat at every step
            self._failed = True
            self.guard.stand_down(self.session.time_s, exc, attached=False)
            return
        if self._controller_attached:
            self.guard.control(self.session.time_s)
        self.recorder.controller_s += time.perf_counter() - t0

    @property
    def attached(self) -> bool:
        """Whether the swarm still listens to its simulation (:meth:`detach` not called)."""
        return self._attached

    def _adopt_cav_settings(self) -> None:
        """Take the CAVs' length and cruising speed from their vType where config is silent."""
        api = self.api
        first = self.session.cav_ids[0]
        type_id = self.session.types[first]
        cav = self.settings.cav
        cruise = self._cruising_speed
        if cruise is None:  # [cav] speeds = "world": a start, followed step by step
            cruise = api.vehicletype.getMaxSpeed(type_id)
            if cav.speeds != "world":
                cruise = min(cruise, cav.max_speed_mps)
        length = api.vehicletype.getLength(type_id)
        cav = replace(
            cav,
            cruising_speed_mps=cruise,
            length_m=length,
            max_speed_mps=max(cav.max_speed_mps, cruise),
        )
        self.settings = replace(self.settings, cav=cav)
        # The controller's context, made once the settings are complete (before the controller
        # sees it): its scenario is never replaced during the run.
        ctx = self.ctx
        self.ctx = RunContext(
            self.session, self.settings, self.session.cav_ids, ctx.road, out_dir=ctx.out_dir,
            events=ctx.events,
        )  # fmt: skip

    @property
    def controller_s(self) -> float:
        """Wall time spent reading SUMO and in the controller so far [s]."""
        return self.recorder.controller_s

    def _settings_now(self) -> Scenario:
        """The settings with the evaluation window over what was recorded and SUMO's step."""
        first, last = self.recorder.first_time_s, self.recorder.last_time_s
        start, end = (first, last) if first is not None else (0.0, 0.0)
        end = max(end, start + EMPTY_WINDOW_S)
        evaluation = replace(self.settings.evaluation, start_s=start, end_s=end)
        step = replace(self.settings.simulation, step_length_s=self.session.step_length_s)
        return replace(self.settings, evaluation=evaluation, simulation=step)

    def summary(self) -> dict[str, Any]:
        """The summary of ``../shared/contract.md`` for everything seen so far."""
        own = None if self._controller_attached else {}
        return self.recorder.summary(self._settings_now(), controller_summary=own)

    def detach(self) -> None:
        """Stop controlling: remove the listener and hand the CAVs back to SUMO.

        With ``out_dir``, the run's outputs are written there as ``sumo-swarm run`` writes
        them: summary.json, trajectories.parquet, events.jsonl.
        """
        if not self._attached:
            return
        self._attached = False
        _ATTACHED.pop(self.token, None)
        if _attached_to(self.api) is None:  # the mark is ours (or gone with the simulation)
            _mark(self.api, "")
        self.recorder.close_controller()
        try:
            self.api.removeStepListener(self._listener_id)
        except Exception as exc:  # the simulation may already be closed
            log.debug("removing the step listener: %s", exc)
        for vid in list(self.session.cav_ids):
            if self.session.exists(vid):
                try:
                    self.session.release_speed(vid)
                except Exception as exc:
                    log.debug("releasing %s: %s", vid, exc)
        if self.out_dir is not None:
            own = None if self._controller_attached else {}
            self.recorder.finish(self.out_dir, self._settings_now(), self.ctx.events, own)


def _step_listener_base(api: Any) -> type:
    if isinstance(api, ModuleType) and api.__name__.startswith("libsumo"):
        return api.StepListener
    traci = importlib.import_module("traci")
    return traci.StepListener


def attach(
    connection: Any = None,
    *,
    cav_type: str | None = None,
    cav_ids: list[str] | tuple[str, ...] | None = None,
    config: str | Path | Scenario | None = None,
    controller: str | Controller = "swarm",
    cruising_speed_mps: float | None = None,
    out_dir: str | Path | None = None,
) -> SwarmHandle:
    """Attach a swarm to a running SUMO simulation and return its handle.

    Parameters
    ----------
    connection
        ``libsumo`` (default), the ``traci`` module, or a ``traci`` connection object.
    cav_type, cav_ids
        The swarm's CAVs: every vehicle of this vType, or these vehicle ids (one is required).
        A vehicle SUMO gave its own copy of the vType (``cav_type@vehicle``, made when a vType
        parameter is set for that vehicle alone) is of the vType too.
    config
        A scenario or settings TOML (its ``[cav]``, ``[planner]``, ``[grid]``, ... sections), or a
        :class:`~sumo_swarm.config.Scenario`; default settings otherwise.
    controller
        ``"swarm"`` (default), a baseline name, or a controller object.
    cruising_speed_mps
        The swarm's cruising speed; default: ``[cav] cruising_speed_mps`` of ``config`` when it
        sets the CAVs' speeds, else SUMO's desired speed of the CAVs where they drive
        (``[cav] speeds = "world"``: min of vType maxSpeed and lane limit * speedFactor).
    out_dir
        Where the swarm writes ``plans.jsonl`` as it goes and, at :meth:`SwarmHandle.detach`,
        ``summary.json``, ``trajectories.parquet`` and ``events.jsonl`` (optional).

    Raises
    ------
    ConfigError
        (a ValueError) for an argument the command line would refuse too: not exactly one of
        ``cav_type`` and ``cav_ids``, ``cav_ids`` not a collection of ids (a string is one id,
        not a swarm of its characters), a ``cav_type`` the simulation has no vType of (the
        message lists those it has), an unknown controller, an unwritable ``out_dir``; and
        for a simulation the controller cannot drive: the swarm without SUMO's sublane model
        (``--lateral-resolution``) or at a SUMO step longer than
        :data:`~sumo_swarm.sim.steplimit.MAX_SWARM_STEP_S`.
    SessionError
        (a RuntimeError) when no simulation runs on ``connection`` yet, or a swarm is
        attached to it already (:meth:`SwarmHandle.detach` it first).

    A controller's error later, at a step, is not raised into SUMO's step: the swarm stands
    down (one warning; ``summary()["stood_down"]`` says when and why).
    """
    if connection is None:
        connection = importlib.import_module("libsumo")
    # The arguments first, then the simulation they are for.
    if (cav_type is None) == (cav_ids is None):
        raise ConfigError("attach: give exactly one of cav_type or cav_ids")
    if cav_ids is not None:
        cav_ids = _id_list(cav_ids)
    elif not isinstance(cav_type, str) or not cav_type:
        raise ConfigError(f"attach: cav_type must be a vType id (a string), got {cav_type!r}")
    if cruising_speed_mps is not None:
        require_number("attach: cruising_speed_mps", cruising_speed_mps, gt=0.0)
    if not (config is None or isinstance(config, str | os.PathLike | Scenario)):
        raise ConfigError(
            f"attach: config must be a settings file or a Scenario, got {type(config).__name__}"
        )
    if not isinstance(controller, str):
        missing = [
            m
            for m in ("attach", "control", "summary")
            if not callable(getattr(controller, m, None))
        ]
        if missing:
            raise ConfigError(
                f"attach: controller must be a name ({', '.join(CONTROLLERS)}) or an object "
                f"with attach, control and summary methods; {type(controller).__name__} has "
                f"no {missing[0]}"
            )
    _check_running(connection)
    if cav_type is not None:
        message = unknown_vtype(cav_type, connection.vehicletype.getIDList())
        if message is not None:
            raise ConfigError(f"attach: cav_type: {message}")
    settings = default_settings(config)
    if cruising_speed_mps is not None:  # the caller's speed, not the world's
        settings = replace(settings, cav=replace(settings.cav, speeds="config"))
    elif settings.cav.speeds == "config":
        cruising_speed_mps = settings.cav.cruising_speed_mps
    if cav_ids is not None:
        wanted = frozenset(cav_ids)

        def is_cav(vid: str, type_id: str) -> bool:
            return vid in wanted
    else:

        def is_cav(vid: str, type_id: str) -> bool:
            return is_of_type(type_id, cav_type)

    try:
        ctrl = make_controller(controller) if isinstance(controller, str) else controller
    except ConfigError as exc:
        raise ConfigError(f"attach: controller: {exc}") from None
    step_s = connection.simulation.getDeltaT()
    name = getattr(ctrl, "name", "")
    check_step_length(step_s, name, "attach: SUMO's --step-length")
    check_sublane_model(connection, name)
    held = _attached_to(connection)
    if held is not None:
        raise SessionError(
            f"attach: a swarm is attached to this simulation already (since t = "
            f"{held.attached_at_s:g} s): call detach() on it first"
        )
    if out_dir is not None and not isinstance(out_dir, str | os.PathLike):
        raise ConfigError(f"attach: out_dir must be a folder path, got {type(out_dir).__name__}")
    if out_dir is not None and not os.fspath(out_dir):
        # Path("") is the working folder: the outputs would land among whatever it holds
        raise ConfigError("attach: out_dir is empty: name a folder (or leave out_dir None)")
    if out_dir is not None:
        # As the command line's --out: a folder of other files is never written into (an
        # earlier swarm's outputs are replaced, as with --force)
        check_out_folder(Path(out_dir), force=True)
    out = writable_folder(out_dir) if out_dir is not None else None
    warn_if_sumo_teleports(connection)
    handle = SwarmHandle(connection, ctrl, settings, is_cav, cruising_speed_mps, out)
    _mark(connection, handle.token)
    _ATTACHED[handle.token] = handle
    return handle


# A simulation's own parameter naming the swarm attached to it: a new simulation (after
# close and start) has none, whatever connection object reaches it.
ATTACHED_PARAMETER = "sumo_swarm.attached"
_ATTACHED: weakref.WeakValueDictionary[str, SwarmHandle] = weakref.WeakValueDictionary()


def _mark(connection: Any, token: str) -> None:
    try:
        connection.simulation.setParameter("", ATTACHED_PARAMETER, token)
    except Exception as exc:  # a SUMO without simulation parameters: attaching twice passes
        log.debug("cannot mark the simulation as attached: %s", exc)


def _attached_to(connection: Any) -> SwarmHandle | None:
    """The swarm attached to the simulation ``connection`` runs and not detached, or None."""
    try:
        token = connection.simulation.getParameter("", ATTACHED_PARAMETER)
    except Exception:
        return None
    handle = _ATTACHED.get(token) if token else None
    return handle if handle is not None and handle.attached else None


def _check_running(connection: Any) -> None:
    """SessionError unless ``connection`` has a simulation running; ConfigError if it is no
    connection at all."""
    simulation = getattr(connection, "simulation", None)
    if simulation is None or not callable(getattr(simulation, "getTime", None)):
        raise ConfigError(
            "attach: connection must be libsumo, the traci module or a traci connection, got "
            f"{type(connection).__name__}"
        )
    is_loaded = getattr(simulation, "isLoaded", None)  # libsumo; traci raises when unconnected
    try:
        running = bool(is_loaded()) if is_loaded is not None else simulation.getTime() >= 0.0
    except Exception:
        running = False
    if not running:
        raise SessionError(
            "attach: no simulation is running: start SUMO first (libsumo.start([...]) or "
            "traci.start([...])), then attach"
        )


def _id_list(cav_ids: Any) -> tuple[str, ...]:
    """``cav_ids`` as a tuple of vehicle ids; ConfigError for a string (it would be a swarm of
    its characters), a non-collection, an id that is no string, or none at all."""
    if isinstance(cav_ids, str | bytes) or not isinstance(cav_ids, Iterable):
        raise ConfigError(
            f"attach: cav_ids must be a list of vehicle ids, got {type(cav_ids).__name__} "
            f"{cav_ids!r}" + (f" (write cav_ids=[{cav_ids!r}])" if isinstance(cav_ids, str) else "")
        )
    ids = tuple(cav_ids)
    bad = [v for v in ids if not isinstance(v, str) or not v]
    if bad:
        raise ConfigError(
            f"attach: cav_ids: a vehicle id must be a non-empty string, got {bad[0]!r}"
        )
    if not ids:
        raise ConfigError("attach: cav_ids is empty: name at least one vehicle")
    return ids


# The controllers that move CAVs across lanes by sublane moves (lcAccelLat, changeSublane).
SUBLANE_CONTROLLERS = frozenset({"swarm", "cacc"})


def check_sublane_model(api: Any, controller: str) -> None:
    """ConfigError when ``controller`` needs SUMO's sublane model and the simulation was started
    without it (without ``--lateral-resolution``, every CAV command fails at every step)."""
    if controller not in SUBLANE_CONTROLLERS:
        return
    try:
        resolution_m = float(api.simulation.getOption("lateral-resolution"))
    except Exception:  # a SUMO too old to tell: the controller reports what fails
        return
    if resolution_m <= 0:
        raise ConfigError(
            f"attach: SUMO runs without the sublane model, which the {controller} controller "
            "needs: start SUMO with --lateral-resolution 0.5 (or <lateral-resolution "
            'value="0.5"/> in the sumocfg\'s <processing>)'
        )


def warn_if_sumo_teleports(api: Any) -> bool:
    """Log one warning, and return True, when the running SUMO teleports vehicles away.

    SUMO's own runs of sumo-swarm count every collision and never teleport (``sumo-swarm run``
    sets the options); a simulation someone else started keeps its options, and TraCI cannot
    change them after the start, so the swarm can only say so.
    """
    try:
        wait_s = float(api.simulation.getOption("time-to-teleport"))
        on_collision = str(api.simulation.getOption("collision.action"))
    except Exception as exc:  # a SUMO too old for getOption (before 1.19): nothing to read
        log.debug("cannot read SUMO's teleport options: %s", exc)
        return False
    jams = wait_s > 0  # SUMO: a non-positive time-to-teleport switches jam teleports off
    collisions = on_collision in ("teleport", "remove")
    if not (jams or collisions):
        return False
    log.warning(
        "SUMO teleports vehicles in this simulation (time-to-teleport %g s, collision.action "
        "%s): colliding or stuck vehicles may vanish and be missing from the swarm's safety "
        "counts; start SUMO with --time-to-teleport -1 --collision.action warn to keep them",
        wait_s,
        on_collision,
    )
    return True


def detach(handle: SwarmHandle) -> None:
    """Detach a swarm returned by :func:`attach` (same as ``handle.detach()``)."""
    handle.detach()
