"""SUMO through libsumo with nothing read by Python, and one command per CAV: the lane-change
mode sumo-cacc sets (SUMO's strategic changes only). The same simulation as ``sumo-swarm run
... --controller sumo-cacc``, without the project's plumbing: what that run costs is compared
with this (tools/bench_corridor.py). On a sumo-cacc run's saved configuration SUMO also writes
the run's FCD output (the trajectories the run makes its table of): the floor of such a run.
The sumo binary on the configuration alone is not the same simulation: its CAVs change lanes
to gain speed and cooperate too.

``--reads``: also read every vehicle's state at every step as sumo-swarm's bridge does for the
swarm (the same variables by subscription, ``vehicle.getAllSubscriptionResults``), and nothing
else: what reading the trajectories through libsumo costs at the least.

Usage: python tools/libsumo_plain.py [--reads] CAV_TYPE LANE_CHANGE_MODE SUMO_ARGS...
"""

from __future__ import annotations

import sys

import libsumo

# sumo_swarm.sim.bridge.SumoSession.VARS, spelt out: importing the bridge would add its imports
# to what this process costs (tools/bench_plumbing.py checks that the two agree).
READ_VARIABLES = ("LANE_ID", "LANEPOSITION", "LANEPOSITION_LAT", "POSITION", "SPEED")


def main(argv: list[str]) -> int:
    reads = bool(argv) and argv[0] == "--reads"
    if reads:
        argv = argv[1:]
    cav_type, mode, sumo_args = argv[0], int(argv[1]), argv[2:]
    c = libsumo.constants
    variables = [getattr(c, f"VAR_{name}") for name in READ_VARIABLES]
    libsumo.start(["sumo", *sumo_args])
    try:
        end = libsumo.simulation.getEndTime()  # stepped to it, as sumo-swarm run does
        while libsumo.simulation.getTime() < end - 1e-6 and (
            libsumo.simulation.getMinExpectedNumber() > 0
        ):
            libsumo.simulationStep()
            for vid in libsumo.simulation.getDepartedIDList():
                type_id = libsumo.vehicle.getTypeID(vid)
                if type_id == cav_type or type_id.startswith(cav_type + "@"):
                    libsumo.vehicle.setLaneChangeMode(vid, mode)
                if reads:
                    libsumo.vehicle.subscribe(vid, variables)
            if reads:
                libsumo.vehicle.getAllSubscriptionResults()
    finally:
        libsumo.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
