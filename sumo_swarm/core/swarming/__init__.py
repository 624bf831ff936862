"""The parts of the swarm controller, each testable without SUMO.

``decision``  when to overtake, whom, whether it still pays, progress and giving up
``guards``    the safety checks under every plan (pure functions)
``manoeuvre`` grid, HV margins and prediction, the cell MIP, plan checks, references
``tracker``   the MPCs that follow the references (injected like the planner)
``planlog``   plans.jsonl and plan listeners (sumo-gui drawing)

:class:`sumo_swarm.controllers.swarm.SwarmController` strings them together each SUMO step.
"""
