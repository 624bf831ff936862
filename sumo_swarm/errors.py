"""Typed exceptions of sumo-swarm."""


class SwarmError(Exception):
    """Base class of every error sumo-swarm raises on purpose."""


class ConfigError(SwarmError, ValueError):
    """Bad input: a wrong key, type or value in a configuration or input file.

    The message names the problem and the file; the command line turns it into exit status 2.
    """


class SimulationError(SwarmError, RuntimeError):
    """SUMO failed or exited while a run was under way."""
