"""The largest SUMO step length the swarm drives safely at, and the check that refuses more.

The swarm reads the vehicles and commands each CAV's speed and lateral move once per SUMO step;
a command holds for the whole step. At 1 s that is still too coarse for the swarm's lane
changes among human drivers (below). So ``sumo-swarm run``
(scenario file or ``--sumocfg``) and :func:`sumo_swarm.attach` refuse a step above
:data:`MAX_SWARM_STEP_S` with a :class:`~sumo_swarm.errors.ConfigError`. The baselines
(``cacc``, ``sumo-cacc``, ``sumo-lc``) run at any step.
"""

from __future__ import annotations

from sumo_swarm.errors import ConfigError

# The commands hold for a whole step; at steps longer than the CAVs' tau the bridge makes them
# safe for it (core/stepsafe.py: speeds capped on the leaders' commands or worst braking,
# sublane moves that meet another body by the end of the step held, a move under way stopped
# when the next command is no move). Measured at 5e83ad6 with the swarm, collisions counted
# with --collision.mingap-factor 0:
#   0.5 s: the 40 paper-scene variants of scenarios/variants.toml 0 collisions, 0 hard brakes
#          (family gain over cacc +18.4 %, 90 % of scenes within 1 %, worst -5.1 %); the paper
#          scene 20.50 m/s, +17.1 % over cacc at 0.5 s, regrouped, gap 5.5 m; the seven users'
#          roads 0 collisions, 0 CAV hard brakes; the corridor checks (4 roads x 2 shares x 2
#          seeds, 300 s) 0 swarm collisions, 16 CAV hard brakes in 16 runs (31 at 0.2 s;
#          sumo-cacc 950, sumo-lc 661), 80 of 112 checks (76 at 0.2 s).
#   1 s:   the 40 variants 1 collision (a CAV into an HV braking at 7.6 m/s^2, beyond its
#          decel), 74 HV hard brakes (cacc's run: 30); the paper scene +8.5 %, not regrouped.
MAX_SWARM_STEP_S = 0.5  # [s]
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
