"""The largest SUMO step length the swarm drives safely at, and the check that refuses more.

The swarm reads the vehicles and commands each CAV's speed and lateral move once per SUMO step;
a command holds for the whole step. At long steps that is too coarse: at 1 s CAVs ran into the
slow vehicle and into each other (rear-end overlaps in the paper scene). So ``sumo-swarm run``
(scenario file or ``--sumocfg``) and :func:`sumo_swarm.attach` refuse a step above
:data:`MAX_SWARM_STEP_S` with a :class:`~sumo_swarm.errors.ConfigError`. The baselines
(``cacc``, ``sumo-cacc``, ``sumo-lc``) run at any step.
"""

from __future__ import annotations

from sumo_swarm.errors import ConfigError

# Measured with tools/step_limit.py (swarm, collisions counted with --collision.mingap-factor 0)
# on the paper scene, the paper scene with 10 CAVs, with HV lane changes, and cases of
# scenarios/variants.toml:
#   1.0 s (SUMO's default): collisions in 7 of 11 scenes (4, 4, 2, 16, 12, 3 and 11);
#   0.5 s: 1 collision (10 CAVs) in 11 scenes, and the paper scene's overtake no longer
#          completes;
#   0.3 s: 0 collisions and 0 hard brakes in 23 scenes (variants 0-19); 0.25 and 0.2 s: the
#          same in 10 scenes each; 0.1 s: in 4.
# A 3-lane user road with a 2700 veh/h flow (tools/open_road.py, truck in lane 0) had 0
# collisions and no CAV hard brake at 0.3, 0.5 and 1 s: one road does not make the longer steps
# safe when the paper's scenes collide there.
MAX_SWARM_STEP_S = 0.3  # [s]
STEP_TOLERANCE_S = 1e-9  # [s] SUMO keeps the step in milliseconds; float noise is no excess

# Controllers (by name) that need the limit: the swarm; the baselines run at any step.
LIMITED_CONTROLLERS = frozenset({"swarm"})


def check_step_length(step_s: float, controller: str, where: str) -> None:
    """ConfigError when ``controller`` cannot run at a SUMO step of ``step_s`` [s].

    ``where`` names the file and option (or the call) the step came from; the message, one
    line, names the step, the largest supported and ``where``.
    """
    if controller in LIMITED_CONTROLLERS and step_s > MAX_SWARM_STEP_S + STEP_TOLERANCE_S:
        raise ConfigError(
            f"{where}: step length {step_s:g} s is longer than the {MAX_SWARM_STEP_S:g} s the "
            f"swarm supports (its CAVs collide at longer steps); use a step of at most "
            f"{MAX_SWARM_STEP_S:g} s, or a baseline controller"
        )
