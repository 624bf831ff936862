"""The largest SUMO step length the swarm drives safely at, and the check that refuses more.

The swarm reads the vehicles and commands each CAV's speed and lateral move once per SUMO step;
a command holds for the whole step. It is measured safe up to SUMO's default step, 1 s (below);
``sumo-swarm run`` (scenario file or ``--sumocfg``) and :func:`sumo_swarm.attach` refuse a
longer step than :data:`MAX_SWARM_STEP_S` with a :class:`~sumo_swarm.errors.ConfigError`. The
baselines (``cacc``, ``sumo-cacc``, ``sumo-lc``) run at any step.
"""

from __future__ import annotations

from sumo_swarm.errors import ConfigError

# The commands hold for a whole step; at steps longer than the CAVs' tau the bridge makes them
# safe for it (core/stepsafe.py: speeds capped on the leaders' commands or worst braking, SUMO's
# own leader along the route among them, sublane moves that meet another body by the end of the
# step held, the others moving on sideways and maybe braking, a move under way stopped when
# the next command is no move), the tracker drives the step on the MPC's clock
# (core/swarming/tracker.py), and the gap guard works in discrete time, on the speeds the CAVs
# ahead drive in the step (core/swarming/guards.py, GuardSettings.gap_gains). Measured with the
# swarm, collisions counted with --collision.mingap-factor 0 (docs/results.md, "SUMO's step
# length"):
#   0.5 s: the 40 paper-scene variants of scenarios/variants.toml 0 collisions, 0 hard brakes;
#          the paper scene +16.2 % over cacc, regrouped; the seven users' roads 0 collisions,
#          0 CAV hard brakes; the corridor checks (4 roads x 2 shares x 2 seeds, 300 s) 0 swarm
#          collisions.
#   1 s:   the paper scene +17.0 %, regrouped, min CAV gap 5.8 m; the 40 variants 0 collisions,
#          0 CAV hard brakes, two human drivers braking beyond 4 m/s^2 (an HV changing lanes
#          1.7 m behind another, in SUMO's sublane model; one that moved in 11 m behind a
#          braking platoon; 12 behind platoons' tails before the discrete gap guard); the users'
#          roads 0 collisions, 0 CAV hard brakes; the corridor checks 0 swarm collisions
#          (sumo-cacc: 136).
MAX_SWARM_STEP_S = 1.0  # [s]
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
            f"swarm is measured safe at; use a step of at most {MAX_SWARM_STEP_S:g} s, or a "
            f"baseline controller"
        )
