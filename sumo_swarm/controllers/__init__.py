"""Controllers of the CAVs: the swarm (the paper's method) and the baselines it is judged by."""

from __future__ import annotations

from sumo_swarm.checks import unknown_name
from sumo_swarm.controllers.base import Controller, RunContext
from sumo_swarm.errors import ConfigError

CONTROLLERS = ("swarm", "cacc", "sumo-cacc", "sumo-lc")


def make_controller(name: str) -> Controller:
    """Build the controller called ``name`` (one of :data:`CONTROLLERS`)."""
    if name == "cacc":
        from sumo_swarm.controllers.cacc import CaccController

        return CaccController()
    if name in ("sumo-cacc", "sumo-lc"):
        from sumo_swarm.controllers.sumo_baselines import SumoModelController

        return SumoModelController(name, lane_changes=name == "sumo-lc")
    if name == "swarm":
        # Many swarms, as [platoons] groups the CAVs (grouping = "one": the whole run's CAVs).
        from sumo_swarm.controllers.fleet import Fleet
        from sumo_swarm.controllers.swarm import SwarmController

        return Fleet(SwarmController, name="swarm")
    raise ConfigError(unknown_name("controller", str(name), CONTROLLERS))


__all__ = ["CONTROLLERS", "Controller", "RunContext", "make_controller"]
