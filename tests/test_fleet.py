"""Many swarms in one simulation (controllers.fleet): the grouping on hand-made cases, and real
SUMO runs: a user's flow with CAVs inside a vTypeDistribution forms several swarms; CAVs form
one only where a slow vehicle holds them; a platoon for which nothing together pays goes back
to SUMO without a hard brake; two platoons that meet merge; two swarms that overtake near each
other never plan into the same space."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import pandas as pd
import pytest

from sumo_swarm.config import PlatoonSettings
from sumo_swarm.controllers.fleet import (
    VIEW_M,
    Fleet,
    Placed,
    in_lane_neighbours,
    opening_accel,
    strung_out,
)
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.core.neighbours import snapshot_of
from sumo_swarm.errors import ConfigError
from sumo_swarm.sim.netbuild import HighwaySpec, MotorwaySpec, build_highway, build_motorway
from sumo_swarm.sim.runner import run_sumocfg
from sumo_swarm.sim.userroads import write_road
from tests.fakes import FakeSession, run_context

# --------------------------------------------------------------------------- pure parts


def test_in_lane_neighbours_pairs_only_vehicles_directly_behind_one_another():
    cars = [
        Placed("a", 100.0, 5.0, 1),
        Placed("b", 80.0, 5.0, 1),  # 15 m behind a
        Placed("c", 40.0, 5.0, 1),  # 35 m behind b
        Placed("d", 90.0, 5.0, 0),  # another lane: nobody's neighbour
    ]
    pairs = sorted(in_lane_neighbours(cars))
    assert pairs == [("b", "a", 15.0), ("c", "b", 35.0)]


def _state(vid: str, s: float, lane: int = 1, cav: bool = True) -> VehicleState:
    return VehicleState(vid, s, lane, 0.0, 20.0, 5.0, is_cav=cav)


def test_a_parted_cav_drops_back_gently_unless_it_must_brake_harder():
    # 1.5 m/s below the car ahead, braking at most 2 m/s^2 for that...
    assert opening_accel(20.0, 30.0, (20.0, 10.0), 2.0) == pytest.approx(-1.5)
    assert opening_accel(23.0, 30.0, (15.0, 44.0), 2.0) == pytest.approx(-2.0)
    # ...harder where it must not close in below the minimum gap: 5 m/s faster, 1 m of room
    assert opening_accel(25.0, 30.0, (20.0, 3.0), 2.0) == pytest.approx(-12.5)
    # slower than the car ahead already: the gap opens by itself
    assert opening_accel(15.0, 30.0, (20.0, 10.0), 2.0) == 0.0
    # above the speed SUMO will drive it at: a second's worth of the difference, at most 2
    assert opening_accel(29.0, 28.2, None, 2.0) == pytest.approx(-0.8)
    assert opening_accel(33.0, 28.0, None, 2.0) == pytest.approx(-2.0)
    assert opening_accel(20.0, 28.0, None, 2.0) == 0.0  # SUMO speeds it up itself


def test_strung_out_cuts_at_long_gaps_and_at_the_largest_size():
    states = {v: _state(v, s) for v, s in [("a", 500), ("b", 485), ("c", 470), ("d", 300)]}
    # d is 165 m behind c's rear bumper: beyond 150 m
    assert strung_out(["d", "b", "a", "c"], states, 150.0, 8) == [["a", "b", "c"], ["d"]]
    assert strung_out(["d", "b", "a", "c"], states, 200.0, 8) == [["a", "b", "c", "d"]]
    assert strung_out(["d", "b", "a", "c"], states, 200.0, 3) == [["a", "b", "c"], ["d"]]


def test_each_swarm_sees_the_other_swarms_cavs_as_vehicles():
    states = {"a": _state("a", 100), "b": _state("b", 80), "h": _state("h", 60, cav=False)}
    fleet = Fleet(lambda: None, name="x")
    fleet.ctx = run_context(FakeSession(states))
    view = fleet.view(frozenset({"a"}))
    assert view["a"].is_cav and not view["b"].is_cav and not view["h"].is_cav
    assert view["b"].s_m == 80 and states["b"].is_cav  # the session's states untouched
    assert fleet.view(frozenset({"a"})) is view  # once per step and platoon
    assert fleet.view(frozenset({"a", "b"})) is fleet.ctx.session.states  # none foreign: no copy


def test_a_swarm_sees_the_vehicles_within_its_view_only():
    far = VIEW_M + 50.0
    states = {
        "a": _state("a", 2000.0),
        "b": _state("b", 2000.0 + far),  # another swarm's CAV, beyond the view
        "c": _state("c", 1990.0),  # another swarm's CAV, near
        "h": _state("h", 2000.0 - far, cav=False),
        "k": _state("k", 2000.0 - VIEW_M, cav=False),  # exactly at the view's end: in it
    }
    fleet = Fleet(lambda: None, name="x")
    fleet.ctx = run_context(FakeSession(states))
    view = fleet.view(frozenset({"a"}))
    assert list(view) == ["a", "c", "k"]  # the session's order
    assert view["a"] is states["a"] and view["k"] is states["k"] and not view["c"].is_cav
    assert [v.vehicle_id for v in snapshot_of(view, RoadSection((3.2, 3.2, 3.2)))] == [
        "k", "c", "a"
    ]  # fmt: skip


def test_a_parted_cav_straddling_two_lanes_follows_the_leaders_of_both():
    # The users' road 3-lane-cav-flow at 0.5 s steps, SUMO's seed 3 (the SUMO run below): SUMO
    # moved a parted CAV half into the next lane, where a faster car was 11 m ahead, while it
    # still followed a 15 m/s truck 37 m ahead in its own lane. Judged against the nearest alone
    # it was handed to SUMO at 21 m/s, and SUMO braked it at 4.4 m/s^2: the hand-over waits for
    # the gap behind each vehicle SUMO has it follow.
    road = RoadSection((3.2, 3.2, 3.2))
    cav = VehicleState("c", 100.0, 0, 1.5, 21.0, 5.0, is_cav=True)  # 1.5 m left of lane 0
    states = {
        "c": cav,
        "car": VehicleState("car", 116.0, 1, 0.0, 25.0, 5.0, is_cav=False),  # 11 m ahead
        "truck": VehicleState("truck", 153.5, 0, 0.0, 15.0, 16.5, is_cav=False),  # 37 m
        "far": VehicleState("far", 400.0, 0, 0.0, 15.0, 5.0, is_cav=False),  # beyond reach
        "right": VehicleState("right", 120.0, 2, 0.0, 25.0, 5.0, is_cav=False),  # lane 2
    }
    fleet = Fleet(lambda: None, name="x")
    fleet.ctx = run_context(FakeSession(states), road=road)
    leaders = {lead.vehicle_id: gap for lead, gap in fleet._leaders("c", cav, states, road)}
    assert leaders == pytest.approx({"car": 11.0, "truck": 37.0})


def _opening(states, vid, *, edges, road=None, **answers):
    """One step of the fleet opening parted CAV ``vid``'s gap (``Fleet._open_gaps``) on a fake
    session whose SUMO wants a 30 m gap at a 30 m/s desired speed; ``(fleet, handed over, speeds
    commanded)``."""
    handed, speeds = [], {}
    session = FakeSession(
        states, edges=edges, speed_limits=lambda v: (30.0, 30.0),
        alone_gap_m=lambda v, speed, lead, lead_id=None: 30.0, drive_alone=handed.append,
        release_speed=lambda v: None, set_speed=speeds.__setitem__, **answers,
    )  # fmt: skip
    fleet = Fleet(lambda: None, name="x")
    fleet.ctx = run_context(session, road=road)
    fleet._opening.add(vid)
    fleet._open_gaps(states)
    return fleet, handed, speeds


def test_a_parted_cav_is_handed_over_clear_of_a_leader_whose_lanes_are_numbered_afresh():
    # The 5-lane OSM road at 20 %, SUMO's seed 1: a platoon parted before an on-ramp; its front
    # CAV crossed onto the edge where the ramp's lane is added on the right, so the lane both
    # drive in is lane 1 there and lane 0 behind. Compared by its own edge's index, the CAV 6.7 m
    # ahead was in the next lane: the rear CAV was handed to SUMO, which braked it at 9 m/s^2.
    # Counted as on the rear CAV's edge (the session's states_in_lanes_of), it is its leader.
    rear = VehicleState("rear", 889.4, 0, 0.0, 16.3, 5.0, is_cav=True)
    mate = VehicleState("mate", 901.1, 1, 0.0, 14.3, 5.0, -4.0, is_cav=True)  # its own edge's
    states = {"rear": rear, "mate": mate}
    as_on_rear = {"rear": rear, "mate": replace(mate, lane=0)}
    fleet, handed, speeds = _opening(
        states, "rear", edges={"rear": "101", "mate": "102-AddedOnRampEdge"},
        road=RoadSection((3.2,) * 5), step_length_s=0.2,
        states_in_lanes_of=lambda vid: as_on_rear,
    )  # fmt: skip
    assert handed == [] and "rear" in fleet._opening
    assert speeds["rear"] < rear.speed_mps  # still dropping back, under the fleet's command


@pytest.mark.parametrize("speed, handed_over", [(12.0, False), (0.0, True)])
def test_a_parted_cav_on_a_junction_is_handed_over_only_once_beyond_it_or_standing(
    speed, handed_over
):
    # Driving across a junction it opens its gap on (its lane there is the junction's); one
    # that stands there is handed over, else, commanded never to speed up, it would stand on.
    cav = VehicleState("c", 500.0, 0, 0.0, speed, 5.0, is_cav=True)
    fleet, handed, _ = _opening({"c": cav}, "c", edges={"c": ":J1_0"})
    assert (handed == ["c"]) is handed_over
    assert ("c" in fleet._opening) is not handed_over


def _watching(states, cav_edge: str = "e0"):
    """One step of the fleet watching CAV "c", which SUMO drives alone (``Fleet._watch_alone``),
    on a 3-lane road of a fake session whose route frame is edge e0, in 0.5 s steps, SUMO's gap
    a 1 s headway and nothing else; the fleet."""
    session = FakeSession(
        states, edges={"c": cav_edge, "car": "e0"},
        frame=SimpleNamespace(edge_offset_m={"e0": 0.0}), step_length_s=0.5,
        alone_gap_m=lambda v, speed, lead, lead_id=None: speed,
    )  # fmt: skip
    fleet = Fleet(lambda: None, name="x")
    fleet.ctx = run_context(session, road=RoadSection((3.2, 3.2, 3.2)))
    fleet._to_sumo.add("c")
    fleet._watch_alone(states)
    return fleet


@pytest.mark.parametrize(
    "accel, car_lane, car_lat, gap, taken",
    [
        (-4.0, 2, -0.75, 7.6, True),  # moving into its lane, SUMO braking at the line
        (-1.0, 2, -0.75, 7.6, False),  # ... SUMO braking less
        (-4.0, 2, 0.0, 7.6, False),  # keeping to its lane
        (-4.0, 2, 0.75, 7.6, False),  # moving away
        (-4.0, 1, 0.0, 7.6, True),  # in its lane already
        # closer than SUMO's gap at the CAV's 31 m/s (31 m), not at the 29 m/s a step at the
        # line leaves it (29 m): SUMO follows it braking no harder than the line
        (-4.0, 2, -0.75, 30.0, False),
        (-4.0, 2, -0.75, 28.0, True),
        (-3.99, 2, -0.75, 7.6, False),  # just inside the line
    ],
)
def test_a_cav_sumo_drives_at_its_decel_behind_a_car_cutting_in_is_the_fleets_again(
    accel, car_lane, car_lat, gap, taken
):
    # The users' road cav-flow-1800 at 0.5 s steps (SUMO's seed 1): SUMO drove cav.3 alone at
    # 31 m/s, a car in the lane to its left moving over into its lane 7.6 m ahead; SUMO let it
    # in by braking at the CAV's decel every other step and, once the car overlapped it, braked
    # at 4.47 m/s^2. Braking at the line behind a vehicle so close that SUMO following it would
    # brake beyond the line, the CAV is the fleet's again until it has opened SUMO's gap; not
    # while it brakes less, nor behind a car that keeps to its lane or moves away.
    cav = VehicleState("c", 100.0, 1, 0.0, 31.0, 5.0, accel, is_cav=False)  # SUMO drives it
    car = VehicleState("car", 105.0 + gap, car_lane, car_lat, 31.7, 5.0, 0.0, is_cav=False)
    fleet = _watching({"c": cav, "car": car})
    assert ("c" in fleet._opening) is taken
    assert ("c" in fleet._to_sumo) is not taken
    taken_back = [e for e in fleet.ctx.events if e["event"] == "cav_taken_back"]
    assert [(e["vehicle"], e["leader"]) for e in taken_back] == ([("c", "car")] if taken else [])


def test_a_cav_sumo_drives_off_the_route_frame_is_not_watched_and_one_a_platoon_claims_is_dropped():
    # Off the route frame (a ramp, a junction) its lanes are not the road's: not watched there.
    cav = VehicleState("c", 100.0, 1, 0.0, 31.0, 5.0, -4.0, is_cav=False)
    car = VehicleState("car", 112.6, 1, 0.0, 31.7, 5.0, 0.0, is_cav=False)
    fleet = _watching({"c": cav, "car": car}, cav_edge=":J1_0")
    assert "c" in fleet._to_sumo and "c" not in fleet._opening
    # a platoon taking it in claims it: SUMO no longer drives it alone
    fleet._claim("c")
    assert "c" not in fleet._to_sumo


@pytest.mark.sumo
@pytest.mark.parametrize("road, seed, end_s", [("3-lane-truck-left", 3, 20.0)])
def test_a_cav_sumo_drives_is_not_braked_beyond_the_line_by_a_vehicle_cutting_in(
    tmp_path, road, seed, end_s
):
    # The users' road 3-lane-truck-left at 0.5 s steps (SUMO's seed 3): the platoon parted,
    # SUMO drove c0 11 m behind the truck moving over into its lane, and braked it at 4.56
    # m/s^2 when the truck came in at 18 s.
    cfg = write_road(road, tmp_path / "road", end_s=end_s, step_length_s=0.5)
    out, events = _swarm_run(cfg, tmp_path / "swarm", seed=seed)
    assert any(e["event"] == "platoon_apart" for e in events), [e["event"] for e in events]
    taken = [e for e in events if e["event"] == "cav_taken_back"]
    assert "c0" in {e["vehicle"] for e in taken}, taken  # behind the truck moving over
    rows = pd.read_parquet(tmp_path / "swarm" / "trajectories.parquet")
    assert rows[rows.kind == "cav"].accel_mps2.min() >= -4.0 - 1e-6
    assert out["safety"]["collisions"] == 0
    assert out["safety"]["hard_brakes_cav"] == 0


def test_an_error_handing_a_parted_cav_to_sumo_is_not_swallowed():
    # The session's hand-over calls leave a vanished vehicle alone without an error; anything
    # else they raise is a defect and must reach the run loop (which stands the swarm down and
    # says so), not vanish in a guard: one such guard hid a NameError for a whole run.
    cav = VehicleState("c", 500.0, 0, 0.0, 20.0, 5.0, is_cav=True)

    def broken(vid):
        raise RuntimeError("a defect")

    session = FakeSession(
        {"c": cav}, edges={"c": "e"}, speed_limits=lambda v: (30.0, 30.0),
        alone_gap_m=lambda v, speed, lead, lead_id=None: 30.0, drive_alone=broken,
    )  # fmt: skip
    fleet = Fleet(lambda: None, name="x")
    fleet.ctx = run_context(session)
    fleet._opening.add("c")
    with pytest.raises(RuntimeError, match="a defect"):
        fleet._open_gaps({"c": cav})


@pytest.mark.parametrize(
    "key, value, fragment",
    [
        ("max_size", 0, "max_size"),
        ("join_gap_m", -1.0, "join_gap_m"),
        ("split_gap_m", 10.0, "split_gap_m"),
    ],
)
def test_platoon_settings_refuse_impossible_values(key, value, fragment):
    with pytest.raises(ConfigError, match=fragment):
        PlatoonSettings(**{key: value})


# --------------------------------------------------------------------------- SUMO runs


def _lines(path: Path) -> list[dict]:
    """A run's events.jsonl or plans.jsonl, one object per line."""
    with path.open(encoding="utf-8") as f:
        return [json.loads(line) for line in f]


def _swarm_run(cfg: Path, folder: Path, seed: int | None = None) -> tuple[dict, list[dict]]:
    """The swarm's run of ``cfg`` into ``folder``: its summary and its events."""
    out = run_sumocfg(cfg, "cav", "swarm", folder, seed=seed, progress=False, notify=print)
    return out, _lines(folder / "events.jsonl")


def _cavs(ids, lane, first_pos, speed, spacing=15.0):
    """``<vehicle>`` lines of CAVs ``ids`` in ``lane``, the first at ``first_pos`` [m], the
    others ``spacing`` [m] apart behind it."""
    return "\n".join(
        f'  <vehicle id="{vid}" type="cav" route="r" depart="0" departLane="{lane}" '
        f'departPos="{first_pos - spacing * i:g}" departSpeed="{speed:g}"/>'
        for i, vid in enumerate(ids)
    )


def _config(folder: Path, spec: HighwaySpec | MotorwaySpec, routes: str, end_s: float) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    if isinstance(spec, MotorwaySpec):
        build_motorway(spec, folder, "road")
    else:
        build_highway(spec, folder, "road")
    (folder / "user.rou.xml").write_text(routes, encoding="utf-8")
    cfg = folder / "user.sumocfg"
    cfg.write_text(
        "<configuration>\n"
        '  <input><net-file value="road.net.xml"/><route-files value="user.rou.xml"/></input>\n'
        f'  <time><begin value="0"/><end value="{end_s:g}"/>'
        '<step-length value="0.1"/></time>\n'
        "</configuration>\n",
        encoding="utf-8",
    )
    return cfg


MIXED_FLOW = """<routes>
  <vTypeDistribution id="traffic">
    <vType id="car" probability="0.7"/>
    <vType id="cav" sigma="0" color="0,160,255" probability="0.25"/>
    <vType id="truck" vClass="truck" maxSpeed="22" probability="0.05"/>
  </vTypeDistribution>
  <route id="r" edges="e0 e1"/>
  <flow id="f" type="traffic" route="r" begin="0" end="150" vehsPerHour="3000"
        departLane="best" departSpeed="max"/>
  <vehicle id="slow" type="truck" route="r" depart="0" departLane="0" departPos="200"
           departSpeed="15"/>
</routes>
"""


@pytest.mark.sumo
def test_a_users_flow_with_cavs_in_a_type_distribution_forms_several_swarms(tmp_path):
    cfg = _config(tmp_path / "net", HighwaySpec(length_m=3000, lanes=3, edges=2), MIXED_FLOW, 200)
    swarm = run_sumocfg(cfg, "cav", "swarm", tmp_path / "swarm", progress=False, notify=print)
    cacc = run_sumocfg(cfg, "cav", "cacc", tmp_path / "cacc", progress=False, notify=print)
    blocks = swarm["swarms"]
    # A CAV alone is no swarm (SUMO drives it): every swarm had two CAVs.
    assert blocks["platoons_formed"] >= 2 and blocks["swarms"] == blocks["platoons_formed"]
    assert swarm["safety"]["collisions"] == 0
    assert swarm["safety"]["hard_brakes_cav"] == 0
    # Did it help, and harm nobody: CAVs faster than as a plain CACC platoon, the other
    # vehicles braked hard no more often than among the plain platoons.
    assert swarm["cav"]["mean_speed_mps"] > cacc["cav"]["mean_speed_mps"]
    assert swarm["safety"]["hard_brakes_hv"] <= cacc["safety"]["hard_brakes_hv"] + 10
    events = _lines(tmp_path / "swarm" / "events.jsonl")
    formed = [e for e in events if e["event"] == "platoon_formed"]
    assert formed and all(len(e["cavs"]) >= 2 for e in formed)
    weighed = [e for e in events if e["event"] == "overtake_weighed"]
    assert all("follow" in e["scores_m"] for e in weighed)
    plans = _lines(tmp_path / "swarm" / "plans.jsonl")
    assert all("platoon" in p for p in plans)
    # Every swarm's plans and tracking in the summary (they were the first swarm's alone).
    assert swarm["planner"]["solves"] == len(plans)
    if any(p.get("cells") for p in plans):
        assert swarm["tracking"]["solve_ms_per_cav_median"] is not None
        assert swarm["cav"]["lat_error_rms_m"] is not None


HELD_AND_FREE = f"""<routes>
  <vType id="cav" sigma="0" maxSpeed="30"/>
  <vType id="truck" vClass="truck" maxSpeed="15"/>
  <route id="r" edges="e0"/>
  <vehicle id="slow" type="truck" route="r" depart="0" departLane="0" departPos="330"
           departSpeed="15"/>
{_cavs(["a0", "a1"], 0, 300, 15, spacing=20)}
{_cavs(["b0", "b1"], 2, 300, 28, spacing=40)}
</routes>
"""


@pytest.mark.sumo
def test_cavs_form_a_swarm_only_where_a_slow_vehicle_holds_them(tmp_path):
    # a0, a1 behind a 15 m/s truck; b0, b1 in a free lane at their 28 m/s: only the held
    # pair has something to decide together.
    cfg = _config(tmp_path / "net", HighwaySpec(length_m=3000, lanes=3), HELD_AND_FREE, 12)
    out, events = _swarm_run(cfg, tmp_path / "swarm")
    formed = [e for e in events if e["event"] == "platoon_formed"]
    assert [sorted(e["cavs"]) for e in formed] == [["a0", "a1"]]
    assert out["safety"]["collisions"] == 0 and out["safety"]["hard_brakes_cav"] == 0


@pytest.mark.sumo
def test_a_platoon_for_which_nothing_together_pays_goes_back_to_sumo_gently(tmp_path):
    # A user's road (SUMO's seed 4): the CAVs close in on a 15 m/s truck at 23-32 m/s; the
    # swarm weighs moving over apart best, parts, and each CAV drops back to the gap SUMO
    # wants before SUMO drives it. Handed over at once, SUMO braked three CAVs at 4.7 m/s^2.
    cfg = write_road("3-lane-cav-flow", tmp_path / "road", end_s=25.0)
    out, events = _swarm_run(cfg, tmp_path / "swarm", seed=4)
    parted = [e for e in events if e["event"] == "platoon_apart"]
    assert parted, [e["event"] for e in events]
    weighed = [e for e in events if e["event"] == "overtake_weighed"]
    assert weighed[-1]["chosen"] in ("apart", "follow")
    assert out["safety"]["collisions"] == 0
    assert out["safety"]["hard_brakes_cav"] == 0
    # ...and then SUMO drives them: none of them in a platoon at the end
    assert out["swarms"]["platoons_now"] == 0


@pytest.mark.sumo
def test_a_parted_cav_that_sumo_moves_over_is_handed_over_clear_of_both_lanes_leaders(tmp_path):
    # The same road at 0.5 s steps (SUMO's seed 3): the platoon parts behind the truck and SUMO
    # at once moves cav.1 towards the next lane, where a faster car is 11 m ahead. Straddling,
    # it still follows the truck in its own lane: judged against the car alone it was handed
    # to SUMO 37 m behind the truck at 21 m/s, and SUMO braked it at 4.4 m/s^2.
    cfg = write_road("3-lane-cav-flow", tmp_path / "road", end_s=15.0, step_length_s=0.5)
    out, events = _swarm_run(cfg, tmp_path / "swarm", seed=3)
    assert any(e["event"] == "platoon_apart" for e in events), [e["event"] for e in events]
    assert out["safety"]["collisions"] == 0
    assert out["safety"]["hard_brakes_cav"] == 0


@pytest.mark.sumo
def test_a_platoon_parting_before_an_on_ramps_junction_hands_its_cavs_over_gently(tmp_path):
    # The motorway road with ramps at 0.5 s steps (SUMO's seed 6): the platoon parts at 33 m/s
    # with 10 m gaps just before the on-ramp's junction, where the through lanes are numbered
    # one higher on the next edge. On the junction a CAV's lane is the junction's: its leader,
    # already on the next edge, was one lane off, the CAV was handed to SUMO 10 m behind it at
    # 31 m/s, and SUMO braked it at 4.5 m/s^2 (the CAV behind it at 7.1).
    cfg = write_road("motorway-ramps", tmp_path / "road", end_s=25.0, step_length_s=0.5)
    out, events = _swarm_run(cfg, tmp_path / "swarm", seed=6)
    assert any(e["event"] == "platoon_apart" for e in events), [e["event"] for e in events]
    rows = pd.read_parquet(tmp_path / "swarm" / "trajectories.parquet")
    crossed = rows[(rows.kind == "cav") & rows.edge.astype(str).str.startswith(":")]
    assert (crossed.time_s > 20.0).any()  # parted CAVs crossed the junction
    assert out["safety"]["collisions"] == 0
    assert out["safety"]["hard_brakes_cav"] == 0


BESIDE_THE_RAMP = f"""<routes>
  <vType id="cav" sigma="0" maxSpeed="30"/>
  <vType id="car" sigma="0" maxSpeed="30"/>
  <route id="r" edges="up acc mid dec down"/>
  <route id="ramp" edges="acc mid dec down"/>
  <vehicle id="merging" type="car" route="ramp" depart="0" departLane="0" departPos="20"
           departSpeed="0"/>
{_cavs(["a0", "a1"], 0, 770, 8, spacing=18)}
</routes>
"""


@pytest.mark.sumo
def test_cavs_beside_an_acceleration_lane_are_not_held_by_a_car_standing_in_it(tmp_path):
    # Two CAVs at 8 m/s in the rightmost through lane, 30 m before an on-ramp's acceleration
    # lane where a car starts from a standstill. Counted in its own edge's numbering the car
    # was in their lane (lane 0 of each edge), a slow vehicle holding them: they formed a
    # platoon to get past it. Counted as the CAVs' edge numbers lanes, it is beside them.
    cfg = _config(tmp_path / "net", MotorwaySpec(), BESIDE_THE_RAMP, 10.0)
    out, events = _swarm_run(cfg, tmp_path / "swarm")
    assert [e for e in events if e["event"] == "platoon_formed"] == []
    assert out["safety"]["collisions"] == 0 and out["safety"]["hard_brakes_cav"] == 0


MERGE = f"""<routes>
  <vType id="cav" sigma="0" maxSpeed="30"/>
  <vType id="truck" vClass="truck" maxSpeed="15"/>
  <route id="r" edges="e0"/>
  <vehicle id="slow" type="truck" route="r" depart="0" departLane="0" departPos="420"
           departSpeed="15"/>
{_cavs(["a0", "a1", "a2"], 0, 400, 15)}
{_cavs(["b0", "b1", "b2"], 0, 160, 25)}
</routes>
"""


@pytest.mark.sumo
def test_two_platoons_that_meet_in_a_lane_merge(tmp_path):
    # One lane: the front platoon stays behind the slow truck, the one behind catches up.
    cfg = _config(tmp_path / "net", HighwaySpec(length_m=3000, lanes=1), MERGE, 60)
    out, events = _swarm_run(cfg, tmp_path / "swarm")
    formed = [e for e in events if e["event"] == "platoon_formed"]
    merges = [e for e in events if e["event"] == "platoon_merge"]
    # a0-a2, held by the truck, form a platoon at once; b0-b2, free until they reach it, only
    # then (at 10 m/s more, 200 m back), and the two merge
    assert sorted(formed[0]["cavs"]) == ["a0", "a1"] and formed[0]["time_s"] <= 1.0
    assert len(formed) == 2 and set(formed[1]["cavs"]) <= {"b0", "b1", "b2"}
    assert formed[1]["time_s"] > 10.0
    assert len(merges) == 1 and set(merges[0]["cavs"]) == {"a0", "a1", "a2", "b0", "b1", "b2"}
    assert out["swarms"]["merges"] == 1 and out["swarms"]["platoons_now"] == 1
    assert out["safety"]["collisions"] == 0 and out["safety"]["hard_brakes"] == 0


NEAR = f"""<routes>
  <vType id="car"/>
  <vType id="cav" sigma="0" maxSpeed="30"/>
  <vType id="truck" vClass="truck" maxSpeed="16"/>
  <route id="r" edges="e0 e1"/>
  <vehicle id="t1" type="truck" route="r" depart="0" departLane="0" departPos="660"
           departSpeed="16"/>
  <vehicle id="t2" type="truck" route="r" depart="0" departLane="0" departPos="360"
           departSpeed="16"/>
{_cavs(["a0", "a1", "a2"], 0, 640, 16)}
{_cavs(["b0", "b1", "b2"], 0, 340, 16)}
  <flow id="f" type="car" route="r" begin="0" end="90" vehsPerHour="2400" departLane="best"
        departSpeed="max"/>
</routes>
"""


def _footprints(plan: dict) -> list[tuple[float, float, float, float, int]]:
    """Each planned cell of ``plan`` as (t_from, t_to, s_from, s_to, lane)."""
    grid = plan["grid"]
    dt = plan["behaving_interval_s"]
    out = []
    for cells in plan["cells"].values():
        for k, (row, col) in enumerate(cells):
            t = grid["t0_s"] + k * dt
            s = grid["origin_s_m"] + grid["speed_mps"] * (t - grid["t0_s"])
            s += row * grid["cell_length_m"]
            out.append((t, t + dt, s, s + grid["cell_length_m"], col))
    return out


@pytest.mark.sumo
def test_two_swarms_overtaking_near_each_other_never_plan_into_the_same_space(tmp_path):
    cfg = _config(tmp_path / "net", HighwaySpec(length_m=4000, lanes=3, edges=2), NEAR, 90)
    # Through the cells every time (no passing in a free lane as a unit): plans to compare.
    settings = tmp_path / "swarm.toml"
    # The cells' plans are what is compared: the paper's trigger starts them.
    settings.write_text('[swarm]\nlane_pass = false\ndecide = "paper"\n', encoding="utf-8")
    out = run_sumocfg(
        cfg, "cav", "swarm", tmp_path / "swarm", config=settings, progress=False, notify=print
    )
    assert out["safety"]["collisions"] == 0 and out["safety"]["hard_brakes_cav"] == 0
    # Both platoons got past their trucks
    df = pd.read_parquet(tmp_path / "swarm" / "trajectories.parquet")
    last = df[df["time_s"] == df["time_s"].max()].set_index("vehicle")["s_m"]
    assert all(last[c] > last["t1"] for c in ("a0", "a1", "a2"))
    assert all(last[c] > last["t2"] for c in ("b0", "b1", "b2"))
    events = _lines(tmp_path / "swarm" / "events.jsonl")
    targets = {e["platoon"]: e["target"] for e in events if e["event"] == "overtake_start"}
    assert len(targets) >= 2
    plans = _lines(tmp_path / "swarm" / "plans.jsonl")
    # The summary's planner block counts every swarm's plans (it counted the first swarm's).
    assert sum(out["planner"]["statuses"].values()) == len(plans)
    assert out["planner"]["solves"] == len(plans)
    plans = [p for p in plans if p.get("cells")]
    assert len({p["platoon"] for p in plans}) >= 2
    # No cell of one swarm's plan overlaps a cell of another swarm's plan at the same time.
    for i, a in enumerate(plans):
        for b in plans[i + 1 :]:
            if a["platoon"] == b["platoon"]:
                continue
            for ta0, ta1, sa0, sa1, la in _footprints(a):
                for tb0, tb1, sb0, sb1, lb in _footprints(b):
                    overlap = la == lb and ta0 < tb1 and tb0 < ta1 and sa0 < sb1 and sb0 < sa1
                    assert not overlap, (a["platoon"], b["platoon"], ta0, sa0, la)


def test_a_cav_joins_the_one_ahead_only_where_it_can_follow_it():
    from sumo_swarm.controllers.fleet import can_follow

    # 25 m/s onto a CAV standing 40 m ahead: it needs 25^2 / 6 = 104 m to stop at 3 m/s^2
    assert not can_follow(25.0, 0.0, 40.0)
    assert can_follow(25.0, 0.0, 110.0)
    # the same speeds: a 2 m gap is enough, 1 m is not
    assert can_follow(25.0, 25.0, 2.0) and not can_follow(25.0, 25.0, 1.0)
    # a slower CAV behind a faster one: always, at the minimum gap
    assert can_follow(10.0, 20.0, 2.0)


def test_a_platoon_takes_over_no_cav_with_a_straddler_ahead_it_cannot_follow():
    from sumo_swarm.controllers.fleet import straddled
    from sumo_swarm.core.model import RoadSection, VehicleState

    road = RoadSection(lane_widths_m=(3.5, 3.5, 3.5))
    ego = VehicleState("c", 100.0, 1, 0.15, 29.0, 5.0, 0.0, True)
    # a CAV of lane 0 on the line to lane 1 (0.85 m into it), 3 m ahead, 10 m/s slower
    line = VehicleState("s", 108.0, 0, 1.7, 19.0, 5.0, 0.0, True)
    assert straddled(ego, [ego, line], road)
    # in the middle of lane 0: nothing reaches into ego's lane
    assert not straddled(ego, [ego, VehicleState("s", 108.0, 0, 0.0, 19.0, 5.0)], road)
    # on the line 120 m ahead: ego brakes for it within 3 m/s^2
    assert not straddled(ego, [ego, VehicleState("s", 225.0, 0, 1.7, 19.0, 5.0)], road)
    # a slow vehicle in ego's own lane is the platoon's to follow, not a straddler
    assert not straddled(ego, [ego, VehicleState("s", 108.0, 1, 0.0, 19.0, 5.0)], road)


def test_a_cav_off_centre_in_its_lane_joins_nobody():
    from sumo_swarm.controllers.fleet import may_join
    from sumo_swarm.core.model import VehicleState

    def cav(s, lat, v=25.0):
        return VehicleState(f"c{s}", s, 0, lat, v, 5.0, 0.0, True)

    assert may_join(cav(0.0, 0.0), cav(30.0, 0.1), 25.0)
    # SUMO has the front one 0.4 m right of centre, passing a truck across the lane line
    assert not may_join(cav(0.0, 0.0), cav(30.0, -0.4), 25.0)
    assert not may_join(cav(0.0, 0.3), cav(30.0, 0.0), 25.0)
    assert not may_join(cav(0.0, 0.0, v=25.0), cav(30.0, 0.0, v=0.0), 25.0)  # cannot follow


def test_plan_stats_add_up_across_swarms():
    from collections import Counter

    from sumo_swarm.controllers.replanner import PlanStats

    a = PlanStats([10.0, 30.0], [9.0, 29.0], Counter(optimal=2), Counter(initial=2), 0,
                  Counter(), Counter(tried=1))  # fmt: skip
    b = PlanStats([20.0], [19.0], Counter(infeasible=1), Counter(prediction=1), 1,
                  Counter(guard=1), Counter(tried=1, planned=1))  # fmt: skip
    total = PlanStats()
    total.add(a)
    total.add(b)
    block = total.block()
    assert (
        block["solves"] == 3 and block["solve_ms_median"] == 20.0 and block["solve_ms_max"] == 30.0
    )
    assert block["statuses"] == {"optimal": 2, "infeasible": 1}
    assert block["triggers"] == {"initial": 2, "prediction": 1}
    assert block["fallbacks"] == 1 and block["relaxations"] == {"guard": 1}
    assert block["grid_retries"] == {"tried": 2, "planned": 1}
    assert a.solve_ms == [10.0, 30.0]  # the swarms' own stats are left as they were
