"""sumo-swarm: vehicles swarm intelligence for Eclipse SUMO.

Connected automated vehicles (CAVs) blocked by a slow vehicle overtake it as a swarm
and regroup into a platoon (Hu et al., "Vehicles Swarm Intelligence: Cooperation in
both Longitudinal and Lateral Dimensions").
"""

from typing import TYPE_CHECKING

from sumo_swarm.errors import ConfigError, SessionError, SimulationError, SwarmError

__version__ = "0.1.0"

if TYPE_CHECKING:
    from sumo_swarm.sim.plugin import SwarmHandle, attach, detach

__all__ = [
    "ConfigError",
    "SessionError",
    "SimulationError",
    "SwarmError",
    "SwarmHandle",
    "__version__",
    "attach",
    "detach",
]

_PLUGIN_API = ("SwarmHandle", "attach", "detach")


def __getattr__(name: str):
    # The plugin API is imported when first asked for (PEP 562): the command line starts, and
    # can answer Ctrl-C or SIGTERM in one line, before pandas and SUMO's bindings are loaded.
    if name in _PLUGIN_API:
        from sumo_swarm.sim import plugin

        return getattr(plugin, name)
    raise AttributeError(f"module 'sumo_swarm' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted({*globals(), *_PLUGIN_API})
