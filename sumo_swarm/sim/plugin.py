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
import time
from dataclasses import replace
from pathlib import Path
from types import ModuleType
from typing import Any

from sumo_swarm.checks import require_number
from sumo_swarm.config import Scenario
from sumo_swarm.controllers import make_controller
from sumo_swarm.controllers.base import Controller, RunContext
from sumo_swarm.errors import ConfigError
from sumo_swarm.sim.bridge import SumoSession, is_of_type
from sumo_swarm.sim.gui import attach_plan_drawer
from sumo_swarm.sim.recorder import EMPTY_WINDOW_S, RunRecorder
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
        t0 = time.perf_counter()
        self.session.refresh()
        self.recorder.record()
        if not self._controller_attached and self.session.cav_ids:
            self._adopt_cav_settings()
            self.controller.attach(self.ctx)
            attach_plan_drawer(self.controller, self.ctx.session)
            self._controller_attached = True
        if self._controller_attached:
            self.controller.control(self.session.time_s)
        self.recorder.controller_s += time.perf_counter() - t0

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
        self.ctx.scenario = self.settings

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
        When the swarm controller is asked to run at a SUMO step longer than
        :data:`~sumo_swarm.sim.steplimit.MAX_SWARM_STEP_S`, when SUMO runs without the sublane
        model (``--lateral-resolution``) that ``swarm`` and ``cacc`` need, or when the CAVs are
        named twice.
    """
    if connection is None:
        connection = importlib.import_module("libsumo")
    if (cav_type is None) == (cav_ids is None):
        raise ConfigError("attach: give exactly one of cav_type or cav_ids")
    if cruising_speed_mps is not None:
        require_number("attach: cruising_speed_mps", cruising_speed_mps, gt=0.0)
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

    ctrl = make_controller(controller) if isinstance(controller, str) else controller
    step_s = connection.simulation.getDeltaT()
    check_step_length(step_s, getattr(ctrl, "name", ""), "attach: SUMO's --step-length")
    check_sublane_model(connection, getattr(ctrl, "name", ""))
    warn_if_sumo_teleports(connection)
    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    return SwarmHandle(connection, ctrl, settings, is_cav, cruising_speed_mps, out)


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
            "needs: start SUMO with --lateral-resolution 0.5"
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
