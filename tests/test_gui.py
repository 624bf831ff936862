"""Route geometry (route coordinates -> map) and the live plan drawing in sumo-gui.

The drawing is tested through plain ``sumo`` over traci: the polygons sumo-gui would show are
created, read back and moved exactly as they would be in the GUI.
"""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest
import traci

from sumo_swarm.sim.bridge import sumo_binary
from sumo_swarm.sim.gui import POLYGON_PREFIX, PlanDrawer
from sumo_swarm.sim.routeshape import (
    DEFAULT_INTERVAL_S,
    LaneGeometry,
    PlanRecord,
    RouteEdge,
    RouteGeometry,
    route_from_connection,
    route_from_net,
)
from tests.conftest import ROOT

NET = (
    ROOT / "networks" / "highway3.net.xml"
)  # straight, along +x; lanes 3 m wide at y -7.5/-4.5/-1.5
_labels = itertools.count()


def corner_set(quad) -> set[tuple[float, float]]:
    return {(round(float(x), 6), round(float(y), 6)) for x, y in quad}


# ------------------------------------------------------------------------------ geometry (pure)


def bent_route() -> RouteGeometry:
    """Edge a: 100 m east along y = 0; a 10 m junction; edge b: 50 m north from (110, 0)."""
    a = LaneGeometry(np.array([[0.0, 0.0], [100.0, 0.0]]), 3.0, 100.0)
    b = LaneGeometry(np.array([[110.0, 0.0], [110.0, 50.0]]), 3.0, 50.0)
    return RouteGeometry([RouteEdge("a", 0.0, (a,)), RouteEdge("b", 110.0, (b,))])


def test_points_on_straight_and_turned_edges():
    route = bent_route()
    x, y, h = route.xy([40.0, 130.0], 0)
    assert np.allclose(x, [40.0, 110.0]) and np.allclose(y, [0.0, 20.0])
    assert np.allclose(h, [0.0, np.pi / 2])
    # left of an east-bound lane is +y, left of a north-bound lane is -x
    x, y, _ = route.xy([40.0, 130.0], 0, 1.0)
    assert np.allclose(x, [40.0, 109.0]) and np.allclose(y, [1.0, 20.0])


def test_junction_gap_is_blended_and_missing_lanes_placed_beside():
    route = bent_route()
    x, y, h = route.xy(105.0, 0)  # half-way from (100, 0) to (110, 0)
    assert (float(x), float(y), float(h)) == pytest.approx((105.0, 0.0, 0.0))
    x, y, _ = route.xy(40.0, 2)  # lane 2 on a one-lane edge: two lane widths to the left
    assert (float(x), float(y)) == pytest.approx((40.0, 6.0))


def test_lane_position_is_scaled_onto_the_drawn_shape():
    # SUMO length 50 m drawn over a 100 m shape: position 25 is the middle of the shape
    lane = LaneGeometry(np.array([[0.0, 0.0], [100.0, 0.0]]), 3.2, 50.0)
    x, _, _ = RouteGeometry([RouteEdge("e", 0.0, (lane,))]).xy(25.0, 0)
    assert float(x) == pytest.approx(50.0)


def test_cells_cover_the_lane_between_row_edges():
    route = route_from_net(NET, ["hwy"])
    quads = route.cells(np.array([100.0, 115.0, 130.0]), 1)
    assert quads.shape == (2, 4, 2)
    assert corner_set(quads[1]) == {(115, -3), (130, -3), (130, -6), (115, -6)}


RECORD = {
    "time_s": 0.0,
    "status": "optimal",
    "violations": [],
    "blockers": {"cav0": "hv_left"},
    "cells": {"cav0": [[0, 1], [1, 2], [2, 2]], "cav1": [[0, 0], [0, 0], [5, 0]]},
    "grid": {
        "origin_s_m": 100.0,
        "t0_s": 0.0,
        "speed_mps": 10.0,
        "cell_length_m": 15.0,
        "n_rows": 4,
        "n_cols": 3,
    },
}


def test_plan_record_steps_and_cells_at_a_time():
    plan = PlanRecord.from_record(RECORD)
    assert plan.until_s == pytest.approx(3 * DEFAULT_INTERVAL_S)
    assert [plan.step_at(t) for t in (0.0, 2.9, 3.0, 6.5, 30.0)] == [1, 1, 2, 2, 2]
    grid, cells = plan.polygons(route_from_net(NET, ["hwy"]), 1.5)  # grid moved 15 m
    assert grid.shape == (12, 4, 2)
    # cav0 drives into row 1 of the left lane: s 130-145 at t = 1.5 s, y -3 to 0
    assert corner_set(cells["cav0"]) == {(130, 0), (145, 0), (145, -3), (130, -3)}
    assert "cav1" in cells
    # at step 2 cav1's cell (row 5) is off the 4-row grid: not drawn
    _, cells = plan.polygons(route_from_net(NET, ["hwy"]), 4.0)
    assert set(cells) == {"cav0"}


def test_invalid_records_are_not_plans():
    assert not PlanRecord.is_valid({**RECORD, "cells": None})
    assert not PlanRecord.is_valid({**RECORD, "violations": ["cav0 collides"]})
    assert PlanRecord.is_valid(RECORD)


# ------------------------------------------------------------------------------ real SUMO


@pytest.fixture
def connection():
    label = f"gui-test-{next(_labels)}"
    traci.start([sumo_binary(), "-n", str(NET), "--end", "30", "--no-step-log"], label=label)
    conn = traci.getConnection(label)
    yield conn
    conn.close()


@pytest.mark.sumo
def test_route_from_connection_matches_the_network_file(connection):
    live = route_from_connection(connection, ["hwy"])
    net = route_from_net(NET, ["hwy"])
    s = np.linspace(0.0, 2900.0, 7)
    for lane in range(3):
        assert np.allclose(live.xy(s, lane, 0.4)[:2], net.xy(s, lane, 0.4)[:2])


@pytest.mark.sumo
def test_plan_polygons_are_made_moved_and_removed(connection):
    drawer = PlanDrawer(connection, route_edges=["hwy"])
    drawer.draw(RECORD, 0.0)
    ids = {p for p in connection.polygon.getIDList() if p.startswith(POLYGON_PREFIX)}
    assert len(ids) == 4 * 3 + 2  # the grid and one cell per CAV
    cell = f"{POLYGON_PREFIX}.cell.cav0"
    # step 1 at t = 0: row 1 of the left lane, s 115-130
    assert corner_set(connection.polygon.getShape(cell)) == {
        (115, 0),
        (130, 0),
        (130, -3),
        (115, -3),
    }
    assert connection.polygon.getFilled(cell)
    assert connection.polygon.getColor(cell)[:3] == (255, 127, 14)  # a blocker: orange
    grid00 = f"{POLYGON_PREFIX}.grid.0.0"
    assert corner_set(connection.polygon.getShape(grid00)) == {
        (100, -6),
        (115, -6),
        (115, -9),
        (100, -9),
    }
    assert not connection.polygon.getFilled(grid00)

    drawer.update(3.0)  # the grid moved 30 m; step 2 is row 2
    assert corner_set(connection.polygon.getShape(cell)) == {
        (160, 0),
        (175, 0),
        (175, -3),
        (160, -3),
    }
    assert f"{POLYGON_PREFIX}.cell.cav1" not in connection.polygon.getIDList()  # off the grid

    drawer.draw({**RECORD, "cells": None, "status": "infeasible"}, 3.5)  # a failed replan
    assert cell in connection.polygon.getIDList()  # the swarm keeps following the last plan
    drawer.update(9.0)  # the plan's last step is over
    assert not [p for p in connection.polygon.getIDList() if p.startswith(POLYGON_PREFIX)]


@pytest.mark.sumo
def test_route_is_read_from_the_first_cav(connection):
    connection.route.add("r", ["hwy"])
    connection.vehicle.add("cav0", "r", departPos="120")
    connection.vehicle.add("cav1", "r", departPos="100")
    connection.simulationStep()
    drawer = PlanDrawer(connection)
    drawer.draw(RECORD, 0.0)
    assert drawer.route_edges == ["hwy"]
    drawer.clear()
    assert not [p for p in connection.polygon.getIDList() if p.startswith(POLYGON_PREFIX)]


@pytest.mark.sumo
def test_route_coordinates_land_where_sumo_put_the_vehicles(tmp_path):
    """A curved road of four edges with a lane drop: every recorded (s, lane, lat) maps back to
    the position SUMO reported. Exactly on the edges; on junction lanes (a few steps each) the
    bridge's lane index is the internal lane's and the route blends across, so within a lane."""
    from sumo_swarm.sim.netbuild import HighwaySpec, edge_ids
    from sumo_swarm.sim.runner import run_sumocfg
    from tests.usercases import write_user_case

    spec = HighwaySpec(length_m=1600, lanes=(3, 3, 2, 2), edges=4, radius_m=500)
    cfg = write_user_case(tmp_path, spec, platoon_lane=1, end_s=70.0)
    run_sumocfg(cfg, "cav", "swarm", tmp_path / "run")
    df = pd.read_parquet(tmp_path / "run" / "trajectories.parquet")
    route = route_from_net(tmp_path / "highway.net.xml", edge_ids(spec))
    x, y, _ = route.xy(df["s_m"].to_numpy(), df["lane"].to_numpy(), df["lat_m"].to_numpy())
    error_m = np.hypot(x - df["x_m"].to_numpy(), y - df["y_m"].to_numpy())
    on_junction = df["edge"].astype(str).str.startswith(":").to_numpy()
    assert set(df.loc[~on_junction, "edge"].astype(str)) >= {"e0", "e1", "e2"}  # past the drop
    assert error_m[~on_junction].max() < 0.01
    assert on_junction.any() and error_m[on_junction].max() < spec.lane_width_m + 0.1
