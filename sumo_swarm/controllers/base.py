"""What every controller is: the small interface the run loop and the plugin API rely on."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

from sumo_swarm.model import RoadSection

if TYPE_CHECKING:
    from sumo_swarm.bridge import SumoSession
    from sumo_swarm.config import Scenario


@dataclass
class RunContext:
    """What a controller may use: the SUMO session, the scenario and the road."""

    session: SumoSession
    scenario: Scenario
    cav_ids: tuple[str, ...]  # leader first, as placed at t = 0
    road: RoadSection
    out_dir: Any = None  # pathlib.Path of the run's output folder, or None
    events: list[dict[str, Any]] = field(default_factory=list)

    @property
    def dt_s(self) -> float:
        return self.session.step_length_s

    def event(self, kind: str, **data: Any) -> None:
        """Record a notable event (fallbacks, vanished vehicles, ...) for the run's outputs."""
        self.events.append({"time_s": self.session.time_s, "event": kind, **data})


class Controller(Protocol):
    """A controller is attached once, then called after every SUMO step."""

    name: str

    def attach(self, ctx: RunContext) -> None: ...

    def control(self, t_s: float) -> None:
        """Read ``ctx.session.states`` and issue commands that act on the next step."""

    def summary(self) -> dict[str, Any]:
        """Blocks of summary.json this controller fills (``overtake``, ``planner``, ...).

        May be called at any time, also while the run goes on."""


def close_controller(controller: Controller) -> None:
    """Let a controller release what it holds open (files), if it has a ``close`` method."""
    close = getattr(controller, "close", None)
    if close is not None:
        close()
