"""Hand-made sessions and contexts for the controllers' parts, built on the declared interface
(:class:`~sumo_swarm.controllers.session.SessionBase`): a stand-in answers every name the
controllers use, and a name it is given that the interface does not declare is refused (a
misspelt stand-in would otherwise never be asked)."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

from sumo_swarm.config import Scenario
from sumo_swarm.controllers.base import RunContext
from sumo_swarm.controllers.session import SESSION_DATA, SESSION_METHODS, SessionBase
from sumo_swarm.core.model import RoadSection, VehicleState


class FakeSession(SessionBase):
    """:class:`SessionBase` (nothing SUMO could tell) with some answers given by name, e.g.
    ``FakeSession(states, keeps_right=lambda vid: True)``."""

    def __init__(
        self,
        states: Mapping[str, VehicleState] | None = None,
        *,
        edges: Mapping[str, str] | None = None,
        step_length_s: float = 0.1,
        **answers: Any,
    ) -> None:
        super().__init__(states, edges=edges, step_length_s=step_length_s)
        for name, answer in answers.items():
            if name not in SESSION_METHODS and name not in SESSION_DATA:
                raise TypeError(f"SessionView declares no {name!r}")
            setattr(self, name, answer)


def run_context(
    session: SessionBase,
    scenario: Scenario | None = None,
    road: RoadSection | None = None,
    cav_ids: Iterable[str] = (),
) -> RunContext:
    """A run's context over ``session`` (default: the default scenario on three 3.2 m lanes)."""
    scenario = Scenario(name="t", path=None) if scenario is None else scenario
    road = RoadSection((3.2, 3.2, 3.2)) if road is None else road
    return RunContext(session, scenario, tuple(cav_ids), road)


def said(ctx: RunContext) -> list[tuple[str, dict[str, Any]]]:
    """``ctx``'s events as ``(kind, data)``, without their time."""
    return [
        (e["event"], {k: v for k, v in e.items() if k not in ("time_s", "event")})
        for e in ctx.events
    ]
