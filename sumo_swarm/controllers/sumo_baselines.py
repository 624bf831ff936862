"""Baselines that leave the CAVs to SUMO's own models (the vType differs, see scene.py)."""

from __future__ import annotations

from typing import Any

from sumo_swarm.controllers.base import LC_MODE_CONTROLLED, RunContext


class SumoModelController:
    """CAVs driven by SUMO itself.

    ``sumo-cacc``: SUMO's ``carFollowModel="CACC"`` with lane changes off.
    ``sumo-lc``: ordinary SUMO vehicles with SUMO's own (sublane) lane changing: each CAV
    overtakes on its own, the "disengage and change lanes one by one" strategy.
    """

    def __init__(self, name: str, lane_changes: bool) -> None:
        self.name = name
        self.lane_changes = lane_changes
        self.ctx: RunContext | None = None
        self._configured: set[str] = set()

    def attach(self, ctx: RunContext) -> None:
        self.ctx = ctx

    def control(self, t_s: float) -> None:
        if self.lane_changes:
            return
        ctx = self.ctx
        for vid in ctx.cav_ids:
            if vid in ctx.session.states and vid not in self._configured:
                ctx.session.set_modes(vid, None, LC_MODE_CONTROLLED)
                self._configured.add(vid)

    def summary(self) -> dict[str, Any]:
        return {}
