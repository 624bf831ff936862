"""The pipeline's pure parts, no SUMO import: value objects (``model``), the moving grid, the
cell MIP (``planner``), reference trajectories, the MPC trackers, the HVs' driver models and
predictions, neighbour look-ups, the route frame, and the swarm controller's parts
(``swarming``: decision, guards, manoeuvre, tracker, plan log). Imports only the foundation
modules (errors, checks, files, safexml)."""
