"""Running a simulation: the SUMO bridge (the only libsumo/traci import), scenes and networks,
the runner and the plugin (``attach``), recording and measuring a run (recorder, metrics,
summary), and drawing plans in sumo-gui. Imports core, config and controllers."""
