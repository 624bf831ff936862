"""What the bridge reads of every vehicle each step, against SUMO's own answers (real SUMO).

The bridge subscribes fewer variables than it gives (sim/bridge.py, SumoSession.VARS): the edge
and lane index come from the lane id, the acceleration from the speeds one step apart. Both
must be SUMO's own values to the last bit, on a road of SUMO's defaults with flows entering
(``departLane="best"``), lane changes, a lane drop and a vehicle that SUMO is stepped past.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from sumo_swarm.sim.bridge import SumoSession
from sumo_swarm.sim.userroads import write_osm_road, write_road

OSM_DIR = Path(__file__).resolve().parent.parent / "networks" / "osm"


def _session(tmp_path: Path, road: str = "lane-drop") -> SumoSession:
    cfg = write_road(road, tmp_path / "road", end_s=60.0)
    args = ["-c", str(cfg), "--lateral-resolution", "0.5", "--no-step-log", "true",
            "--collision.action", "warn"]  # fmt: skip
    return SumoSession(args, is_cav=lambda vid, type_id: type_id.startswith("cav"))


def _check_step(sumo: SumoSession, every_vehicle: bool) -> int:
    veh = sumo.api.vehicle
    # Before any view is made: who is there comes from the read itself.
    if every_vehicle:
        assert all(sumo.exists(vid) for vid in veh.getIDList())
    assert not sumo.exists("nobody")
    # The columns the recorder takes as they are, and the views made from them.
    c = sumo.columns
    assert c.time_s == sumo.time_s and list(sumo.states) == c.ids
    for i, vid in enumerate(c.ids):
        assert c.xy[i] == veh.getPosition(vid), (sumo.time_s, vid)
        assert c.speed_mps[i] == veh.getSpeed(vid), (sumo.time_s, vid)
        assert c.lat_m[i] == veh.getLateralLanePosition(vid), (sumo.time_s, vid)
        assert c.lane_width_m[i] == sumo.api.lane.getWidth(veh.getLaneID(vid)), (sumo.time_s, vid)
        assert sumo.positions[vid] == c.xy[i]
    for vid, st in sumo.states.items():
        assert st.accel_mps2 == veh.getAcceleration(vid), (sumo.time_s, vid)
        assert st.lane == veh.getLaneIndex(vid), (sumo.time_s, vid)
        assert sumo.edges[vid] == veh.getRoadID(vid), (sumo.time_s, vid)
        assert sumo.lane_positions[vid] == veh.getLanePosition(vid), (sumo.time_s, vid)
    if every_vehicle:  # (a vehicle that departs in a step not read is not known to the session)
        assert set(sumo.states) == set(veh.getIDList())
    return len(sumo.states)


def test_lanes_and_accelerations_read_are_sumos_own(tmp_path):
    seen, junction, braking, skipped = 0, 0, 0, False
    with _session(tmp_path) as sumo:
        while sumo.time_s < 60.0 - 1e-6:
            if not skipped and sumo.time_s >= 30.0:  # a step the session did not read
                sumo.api.simulation.step()
                skipped = True
            sumo.step()
            seen += _check_step(sumo, every_vehicle=not skipped)
            junction += sum(1 for e in sumo.edges.values() if e.startswith(":"))
            braking += sum(1 for st in sumo.states.values() if st.accel_mps2 < -0.5)
    assert skipped and seen > 2000  # vehicle-steps compared
    assert junction > 0 and braking > 0  # internal lanes and real braking among them


def test_a_vehicle_taken_out_of_the_states_is_gone_until_the_next_read(tmp_path):
    # As a command to a vehicle SUMO no longer knows does (SumoSession._command): the
    # controllers stop commanding it in this step; the next read has it again if it is there.
    with _session(tmp_path) as sumo:
        while not sumo.columns.ids:
            sumo.step()
        vid = sumo.columns.ids[0]
        assert sumo.exists(vid)
        sumo.states.pop(vid)
        assert not sumo.exists(vid) and vid in sumo.columns.ids  # the read itself is kept
        sumo.step()
        assert sumo.exists(vid) and vid in sumo.states


def test_a_vehicle_that_left_is_answered_as_absent_and_a_defect_is_not(tmp_path):
    # What the controllers ask of a vehicle that arrived in the step: the session's answers
    # for a vehicle it does not know, no error. Only SUMO's "not known" is taken so: an id
    # that is no id at all (a defect of the caller) raises.
    from sumo_swarm.core.hvmodel import DriverModel

    with _session(tmp_path) as sumo:
        while not sumo.arrived and sumo.time_s < 60.0 - 1e-6:
            sumo.step()
        assert sumo.arrived, "no vehicle arrived within the road's minute"
        gone = sumo.arrived[0]
        assert gone not in sumo.api.vehicle.getIDList()
        assert sumo.speed_limits(gone) is None
        assert sumo.driver_model(gone) == DriverModel(model="unknown")
        assert sumo.keeps_right(gone) is False and sumo.wants_right(gone) is False
        assert sumo.route_of(gone) is None and sumo.lane_change_need(gone) is None
        assert sumo.lane_wish(gone) == (0, False)
        sumo.drive_alone(gone)
        sumo.release(gone)
        sumo.restore_gaps(gone, tau=True)
        sumo.configure_cav(gone, lane_change_mode=0)
        here = next(iter(sumo.states))
        assert sumo.speed_limits(here) is not None and sumo.keeps_right(here) is True
        with pytest.raises(TypeError):
            sumo.speed_limits(7)  # type: ignore[arg-type]
        with pytest.raises(TypeError):
            sumo.keeps_right(None)  # type: ignore[arg-type]


def test_a_vehicle_removed_and_added_again_starts_afresh(tmp_path):
    # TraCI can add a vehicle of an id that left. The new one's first acceleration is SUMO's
    # own (not a speed difference with the old one's last speed), and its rows get its own
    # length when the recorder packs them: the old one's rows are packed before the new values
    # come.
    from sumo_swarm.sim.recorder import RunRecorder

    with _session(tmp_path) as sumo:
        rec = RunRecorder(sumo, None, "none", None)
        while sumo.time_s < 2.0 or not sumo.columns.ids:
            sumo.step()
            rec.record()
        vid = sumo.columns.ids[0]
        assert sumo.states[vid].speed_mps > 5.0
        route = sumo.api.vehicle.getRouteID(vid)
        sumo.remove_vehicle(vid)  # and added again before the next step, ahead of the others
        assert not sumo.exists(vid)
        sumo.api.vehicle.add(vid, route, typeID="DEFAULT_VEHTYPE", departSpeed="0",
                             departPos="300", departLane="free")  # fmt: skip
        sumo.api.vehicle.setLength(vid, 9.5)
        sumo.step()
        rec.record()
        i = sumo.columns.ids.index(vid)  # in the very next read
        assert sumo.columns.lane_pos_m[i] == 300.0
        assert sumo.columns.accel_mps2[i] == sumo.api.vehicle.getAcceleration(vid) == 0.0
        for _ in range(5):
            sumo.step()
            rec.record()
        rows = rec.frame()
        mine = rows[rows["vehicle"] == vid]
        assert (mine.loc[mine["time_s"] < 2.0, "length_m"] == 5.0).all()
        assert (mine.loc[mine["time_s"] > sumo.time_s - 0.6, "length_m"] == 9.5).all()


def test_a_sideways_move_stops_when_the_next_command_is_no_move(tmp_path):
    # SUMO carries a sublane command on, over the next steps, until the whole distance is
    # covered: a CAV commanded across a lane and then held (the guard refused the rest) went on
    # moving into a car alongside. No move after a move must stop it where it is.
    with _session(tmp_path) as sumo:
        veh = sumo.api.vehicle
        while not sumo.columns.ids:
            sumo.step()
        vid = sumo.columns.ids[0]
        veh.setLaneChangeMode(vid, 0)
        veh.setMaxSpeedLat(vid, 1.0)
        veh.setParameter(vid, "laneChangeModel.lcAccelLat", "40")  # as configure_cav
        lane = veh.getLaneIndex(vid)
        sumo.change_sublane(vid, 2.5 if lane == 0 else -2.5)  # 2.5 s of moving
        sumo.step()
        moved = veh.getLateralLanePosition(vid)
        assert abs(moved) > 0.05  # it started moving
        for _ in range(5):
            sumo.change_sublane(vid, 0.0)
            sumo.step()
            assert veh.getLateralLanePosition(vid) == moved and veh.getLaneIndex(vid) == lane


def test_a_vehicle_in_an_acceleration_lane_is_beside_the_through_lanes_as_the_next_edge_counts(
    tmp_path,
):
    # Seen from the edge after an on-ramp (its rightmost lane is the acceleration edge's lane
    # 1), a vehicle in the acceleration lane (lane 0 of ``acc``, which ends) is in lane -1: to
    # the right of lane 0, not in it. Counted as lane 0, a vehicle standing at the lane's end
    # was taken to be ahead of a CAV in the through lane beside it, which braked to 1.4 m/s.
    seen = 0
    with _session(tmp_path, "motorway-ramps") as sumo:
        while sumo.time_s < 60.0 - 1e-6 and seen < 20:
            sumo.step()
            on_mid = [v for v, e in sumo.edges.items() if e == "mid"]
            in_acc = {v: st for v, st in sumo.states.items() if sumo.edges[v] == "acc"}
            if not on_mid or not any(st.lane == 0 for st in in_acc.values()):
                continue
            view = sumo.states_in_lanes_of(on_mid[0])
            for vid, st in in_acc.items():
                assert view[vid].lane == st.lane - 1, (sumo.time_s, vid, st.lane)
                seen += st.lane == 0
    assert seen >= 20  # acceleration-lane vehicles checked


def test_every_vehicle_is_renumbered_as_the_route_frame_maps_its_lane(tmp_path):
    # The view is built edge by edge (one shift per edge, a junction edge's per lane); it must
    # give each vehicle what RouteFrame.lane_as_on gives it alone, from every edge's side, and
    # leave the rest of each state as it is. On an OpenStreetMap motorway netconverted with
    # guessed ramps, a junction lane before an added deceleration lane fans out: its own
    # offset differs from its edge's.
    cfg = write_osm_road("osm-3-lane-drop", OSM_DIR, tmp_path, end_s=120.0)
    args = ["-c", str(cfg), "--lateral-resolution", "0.5", "--no-step-log", "true",
            "--collision.action", "warn"]  # fmt: skip
    checked = fanned = shared = 0
    with SumoSession(args, is_cav=lambda vid, type_id: type_id.startswith("cav")) as sumo:
        frame = sumo.frame
        while sumo.time_s < 120.0 - 1e-6:
            sumo.step()
            askers = {}
            for vid, edge in sumo.edges.items():
                askers.setdefault(frame.route_edge(edge), vid)
            tables: dict[int | None, list[int]] = {}  # lane numbering -> its askers' tables
            for reference, asker in askers.items():
                view = sumo.states_in_lanes_of(asker)
                tables.setdefault(frame.lane_offset.get(reference), []).append(id(view))
                assert list(view) == list(sumo.states)
                for vid, st in sumo.states.items():
                    edge = sumo.edges[vid]
                    lane = frame.lane_as_on(st.lane, edge, reference)
                    expected = st.lane if lane is None or edge == reference else lane
                    seen = view[vid]
                    assert seen.lane == expected, (sumo.time_s, vid, edge, reference)
                    assert (seen.s_m, seen.lat_m, seen.speed_mps) == (
                        st.s_m, st.lat_m, st.speed_mps,
                    )  # fmt: skip
                    checked += expected != st.lane
                    own = frame.via_lane_offset.get(f"{edge}_{st.lane}")
                    fanned += own is not None and own != frame.lane_offset.get(edge)
            # edges that number their lanes alike share one table in a step
            assert all(len(set(ids)) == 1 for ids in tables.values()), (sumo.time_s, tables)
            shared += any(len(ids) > 1 for ids in tables.values())
    assert checked > 100 and fanned > 0  # renumbered vehicles, some on a fanning junction lane
    assert shared > 0  # steps where two edges of one numbering asked


def test_a_vehicle_that_vanishes_mid_step_leaves_every_renumbered_table_made_after():
    # Lanes shift from a to b (a's lane 0 ends) and again on c (b's lane 0 ends): three lane
    # numberings. A
    # vehicle SUMO no longer knows is forgotten during the controllers' step (SumoSession's
    # commands do so); a table asked for afterwards, of the numbering already made or of
    # another, neither holds it nor fails over it (the vehicles of each edge, gathered once per
    # step, still named it: a KeyError).
    from sumo_swarm.core.model import VehicleState
    from sumo_swarm.core.routeframe import RouteFrame
    from tests.test_routeframe import A_DROPS_INTO_B, STRAIGHT, TableNetwork

    lanes = {
        **A_DROPS_INTO_B,
        "b_0": (100.0, 3.2, STRAIGHT, []),
        "b_1": (100.0, 3.2, STRAIGHT, [("c_0", ":j2_0_0")]),
        ":j2_0_0": (5.0, 3.2, STRAIGHT, [("c_0", "")]),
        "c_0": (100.0, 3.2, STRAIGHT, []),
    }
    session = SumoSession([])  # not started: its views over hand-made states
    session.frame = RouteFrame(TableNetwork(lanes), ["a", "b", "c"])
    where = {"va": ("a", 2), "vb": ("b", 1), "vc": ("c", 0)}
    session.states = {
        vid: VehicleState(vid, 100.0 * i, lane, 0.0, 20.0, 5.0, 0.0, False, 1.8)
        for i, (vid, (_, lane)) in enumerate(where.items())
    }
    session._edges = {vid: edge for vid, (edge, _) in where.items()}
    frame = session.frame
    assert len({frame.lane_offset[e] for e in "abc"}) == 3  # three numberings
    assert session.states_in_lanes_of("vb")["va"].lane == 1  # a's lane 2 is b's lane 1
    session._forget("va")
    for asker in ("vb", "vc"):
        table = session.states_in_lanes_of(asker)
        assert "va" not in table and list(table) == ["vb", "vc"], asker
    assert session.states_in_lanes_of("vb")["vc"].lane == 1  # c's lane 0 is b's lane 1
