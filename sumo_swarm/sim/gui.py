"""The swarm's plan drawn live in sumo-gui: the grid and each CAV's planned cell as polygons.

``PlanDrawer(connection).draw(record, t_s)`` takes a plan record (the dict the swarm writes to
``plans.jsonl``) and places polygons through traci's ``polygon`` domain, above the road: the grid
of cells as outlines, and for each CAV the cell of the behaving step it is driving into, filled in
its role's colour (orange: assigned to block an HV, blue: the others). The grid moves with the
traffic, so call :meth:`PlanDrawer.update` between plans (every few steps) to move the polygons
along. A record without a valid plan (a failed solve) leaves the last plan shown, as the swarm
keeps following it until its last step; :meth:`PlanDrawer.clear` removes the polygons (call it
when the overtake ends).

Works on any connection with traci's API: a traci connection to sumo-gui, or plain ``sumo``
(the polygons exist and can be read back, they are just not shown).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from typing import Any

import numpy as np

from sumo_swarm.sim.routeshape import PlanRecord, RouteGeometry, route_from_connection

log = logging.getLogger(__name__)

POLYGON_PREFIX = "sumo_swarm.plan"
GRID_LAYER = 10.0  # above the road (lanes are drawn at layer 0)
CELL_LAYER = 11.0  # the planned cells above the grid
GRID_RGBA = (90, 90, 90, 255)
BLOCKER_RGBA = (255, 127, 14, 110)  # the colours of the replay, translucent
CAV_RGBA = (31, 119, 180, 110)


class PlanDrawer:
    """Draws the current plan of a swarm in a running simulation (see the module's docstring).

    ``route_edges`` is the route the plan's coordinates run along; by default the route of the
    first CAV of the first plan drawn.
    """

    def __init__(self, connection: Any, route_edges: Sequence[str] | None = None) -> None:
        self.conn = connection
        self.route_edges = list(route_edges) if route_edges else None
        self.route: RouteGeometry | None = None
        self.plan: PlanRecord | None = None
        self._shown: set[str] = set()

    def draw(self, record: dict[str, Any], t_s: float) -> None:
        """Show the plan of ``record`` as it stands at simulation time ``t_s`` [s]."""
        if PlanRecord.is_valid(record):
            self.plan = PlanRecord.from_record(record)
        self.update(t_s)

    def update(self, t_s: float) -> None:
        """Move the last plan's polygons to where the grid is at ``t_s`` [s]; clear them once
        the plan's last step is over."""
        plan = self.plan
        if plan is None:
            return
        if t_s >= plan.until_s:
            self.clear()
            return
        route = self._route(plan)
        grid, cells = plan.polygons(route, t_s)
        n_cols = int(plan.grid["n_cols"])
        wanted: dict[str, tuple[np.ndarray, tuple[int, ...], bool, float]] = {}
        for i, quad in enumerate(grid):
            col, row = divmod(i, len(grid) // n_cols)  # the grid comes lane by lane
            wanted[f"{POLYGON_PREFIX}.grid.{row}.{col}"] = (quad, GRID_RGBA, False, GRID_LAYER)
        for cav, quad in cells.items():
            rgba = BLOCKER_RGBA if cav in plan.blockers else CAV_RGBA
            wanted[f"{POLYGON_PREFIX}.cell.{cav}"] = (quad, rgba, True, CELL_LAYER)
        poly = self.conn.polygon
        for pid in self._shown - set(wanted):
            poly.remove(pid)
        for pid, (quad, rgba, fill, layer) in wanted.items():
            shape = [(float(x), float(y)) for x, y in quad]
            if pid in self._shown:
                poly.setShape(pid, shape)
                poly.setColor(pid, rgba)
            else:
                poly.add(pid, shape, rgba, fill=fill, layer=layer, lineWidth=0.15)
        self._shown = set(wanted)

    def clear(self) -> None:
        """Remove every polygon this drawer made."""
        for pid in self._shown:
            self.conn.polygon.remove(pid)
        self._shown = set()
        self.plan = None

    def _route(self, plan: PlanRecord) -> RouteGeometry:
        if self.route is None:
            if self.route_edges is None:
                first = sorted(plan.cells)[0]
                self.route_edges = list(self.conn.vehicle.getRoute(first))
            self.route = route_from_connection(self.conn, self.route_edges)
        return self.route


def attach_plan_drawer(controller: Any, session: Any) -> PlanDrawer | None:
    """Draw ``controller``'s plans in sumo-gui when ``session`` is a traci connection to
    sumo-gui and the controller writes plans (the swarm); None otherwise. A drawer that fails to
    start is logged, never raised: drawing is a convenience."""
    planlog = getattr(controller, "planlog", None)
    api = getattr(session, "api", None)
    if planlog is None or api is None:
        return None
    try:
        api.gui.getIDList()  # only sumo-gui answers
    except Exception:
        return None
    try:
        drawer = PlanDrawer(api, getattr(session, "route_edges", None))
    except Exception:
        log.exception("sumo-gui plan drawing is off")
        return None
    planlog.listeners.append(lambda record: drawer.draw(record, record["time_s"]))
    controller.drawer = drawer
    return drawer
