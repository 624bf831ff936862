"""Baselines that leave the CAVs to SUMO's own models (the vType differs, see scene.py)."""

from __future__ import annotations

from typing import Any

from sumo_swarm.controllers.base import LC_MODE_STRATEGIC, RunContext


class SumoModelController:
    """CAVs driven by SUMO itself.

    ``sumo-cacc``: SUMO's ``carFollowModel="CACC"`` making only the lane changes its route
    needs (SUMO's strategic ones, as ``cacc``): with every lane change off, on a corridor its
    on-ramp CAVs stood at the ends of the acceleration lanes and its exiting CAVs missed the
    off-ramp (at 300 s of scenarios/corridor.toml, all 23 on-ramp CAVs stood, 2 of 14 exited).
    ``sumo-lc``: ordinary SUMO vehicles with SUMO's own (sublane) lane changing: each CAV
    overtakes on its own, the "disengage and change lanes one by one" strategy.
    """

    # It reads no vehicle at any step (SUMO drives them all): SUMO records the run itself
    # (sim/fcd.py).
    reads_vehicles = False

    def __init__(self, name: str, lane_changes: bool) -> None:
        self.name = name
        self.lane_changes = lane_changes
        self.ctx: RunContext | None = None
        self._seen = 0  # CAVs of ctx.cav_ids (a growing list) looked at so far
        self._waiting: list[str] = []  # CAVs seen, not yet configured (not in a lane yet)

    def attach(self, ctx: RunContext) -> None:
        self.ctx = ctx

    def control(self, t_s: float) -> None:
        if self.lane_changes:
            return
        ctx = self.ctx
        session = ctx.session
        # Only the CAVs that departed since the last step (an hour's flows bring thousands).
        if len(ctx.cav_ids) > self._seen:
            self._waiting.extend(ctx.cav_ids[self._seen :])
            self._seen = len(ctx.cav_ids)
        if self._waiting:
            gone = set(session.arrived)
            waiting = []
            for vid in self._waiting:
                if session.exists(vid):
                    session.set_modes(vid, None, LC_MODE_STRATEGIC)
                elif vid not in gone:
                    waiting.append(vid)
            self._waiting = waiting

    def summary(self) -> dict[str, Any]:
        return {}
