"""SUMO through libsumo with nothing read and nothing recorded, and one command per CAV: the
lane-change mode sumo-cacc sets (SUMO's strategic changes only). The same simulation as
``sumo-swarm run ... --controller sumo-cacc``, without the project's plumbing: what that run
costs is compared with this (tools/bench_corridor.py). The sumo binary on the configuration
alone is not the same simulation: its CAVs change lanes to gain speed and cooperate too.

Usage: python tools/libsumo_plain.py CAV_TYPE LANE_CHANGE_MODE SUMO_ARGS...
"""

from __future__ import annotations

import sys

import libsumo


def main(argv: list[str]) -> int:
    cav_type, mode, sumo_args = argv[0], int(argv[1]), argv[2:]
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
    finally:
        libsumo.close()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
