"""Typed exceptions of sumo-swarm."""


class SwarmError(Exception):
    """Base class of every error sumo-swarm raises on purpose."""


class ConfigError(SwarmError, ValueError):
    """Bad input: a wrong key, type or value in a configuration or input file.

    The message names the problem and the file; the command line turns it into exit status 2.
    """


class SimulationError(SwarmError, RuntimeError):
    """SUMO failed or exited while a run was under way."""


class RunInterrupted(KeyboardInterrupt):
    """A run stopped by a signal (SIGINT, SIGTERM) or Ctrl-C.

    A KeyboardInterrupt, so that code catching ``Exception`` (a batch worker recording a failed
    run) lets it through. ``message`` says what was kept (one line); ``exit_status`` is the
    shell's for the signal (128 + its number).
    """

    def __init__(self, message: str, exit_status: int = 130) -> None:
        super().__init__(message)
        self.message = message
        self.exit_status = exit_status


class SessionError(SwarmError, RuntimeError):
    """The plugin API used on a simulation it cannot work with: none is running, or a swarm is
    attached to it already."""
