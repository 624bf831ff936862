"""sumo-swarm: vehicles swarm intelligence for Eclipse SUMO.

Connected automated vehicles (CAVs) blocked by a slow vehicle overtake it as a swarm
and regroup into a platoon (Hu et al., "Vehicles Swarm Intelligence: Cooperation in
both Longitudinal and Lateral Dimensions").
"""

__version__ = "0.1.0"

from sumo_swarm.sim.plugin import SwarmHandle, attach, detach

__all__ = ["SwarmHandle", "__version__", "attach", "detach"]
