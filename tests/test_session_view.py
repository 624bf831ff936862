"""The controllers' view of SUMO is one declared interface (controllers.session.SessionView):
the bridge's session and a swarm's view of it answer every declared name, nothing is
forwarded by ``__getattr__``, and the speeds that follow the world are the context's state,
not a changed scenario."""

from __future__ import annotations

import dataclasses
import inspect

import pytest

from sumo_swarm.config import Scenario
from sumo_swarm.controllers.base import Controller, RunContext
from sumo_swarm.controllers.fleet import Fleet, PlatoonSession, SwarmMember
from sumo_swarm.controllers.reform import Reformer
from sumo_swarm.controllers.session import (
    SESSION_DATA,
    SESSION_METHODS,
    SessionBase,
    SessionView,
)
from sumo_swarm.controllers.swarm import SwarmController
from sumo_swarm.core.hvmodel import DriverModel
from sumo_swarm.core.model import RoadSection, VehicleState
from sumo_swarm.sim.bridge import SumoSession
from tests.fakes import FakeSession, run_context


def test_the_interface_declares_what_the_controllers_use():
    assert {"states", "edges", "kinds", "released", "frame", "time_s"} <= set(SESSION_DATA)
    assert {"speed_limits", "lane_wish", "keeps_right", "keep_right_due_s", "lanes_ending",
            "near_lane_shift", "states_in_lanes_of", "reclaim", "miss_exit",
            "set_speed", "configure_cav", "restore_gaps"} <= set(SESSION_METHODS)  # fmt: skip
    assert not set(SESSION_DATA) & set(SESSION_METHODS)
    # No way around it: the vType commands a controller gives go through declared names too.
    assert "api" not in SESSION_DATA and not hasattr(PlatoonSession, "api")


def test_the_sumo_session_answers_every_declared_name_itself():
    session = SumoSession([])  # not started: its tables are empty
    assert isinstance(session, SessionView)
    for name in SESSION_DATA:
        assert hasattr(session, name), name
    for name in SESSION_METHODS:
        assert callable(getattr(session, name)), name
        # its own answer, not the base's "SUMO cannot tell"
        assert getattr(SumoSession, name) is not getattr(SessionBase, name), name


def test_a_platoons_view_passes_every_declared_name_on_but_the_states():
    commands = []
    cars = {"a": VehicleState("a", 100.0, 1, 0.0, 20.0, 5.0, 0.0, True),
            "b": VehicleState("b", 80.0, 1, 0.0, 20.0, 5.0, 0.0, True)}  # fmt: skip
    session = FakeSession(cars, edges={"a": "e"}, set_speed=lambda v, x: commands.append((v, x)))
    fleet = Fleet(lambda: None, name="x")
    fleet.ctx = run_context(session)
    view = PlatoonSession(session, fleet, frozenset({"a"}))
    assert isinstance(view, SessionView)
    assert "__getattr__" not in vars(PlatoonSession)
    for name in (*SESSION_DATA, *SESSION_METHODS):
        assert name in dir(PlatoonSession), name  # declared on the class, not looked up
        if name not in ("states", "states_in_lanes_of"):
            assert getattr(view, name) == getattr(session, name), name
    view.set_speed("a", 21.0)
    assert commands == [("a", 21.0)]
    assert view.edges is session.edges and view.released is session.released
    assert view.states["a"].is_cav and not view.states["b"].is_cav  # another swarm's CAV
    assert not view.states_in_lanes_of("a")["b"].is_cav
    with pytest.raises(AttributeError):
        view.no_such_name  # noqa: B018  (nothing is forwarded that is not declared)


def test_the_check_of_the_interface_can_fail():
    assert not isinstance(object(), SessionView)
    names = {n: None for n in (*SESSION_DATA, *SESSION_METHODS) if n != "lane_wish"}
    assert not isinstance(type("NoWish", (), names)(), SessionView)
    with pytest.raises(TypeError, match="declares no 'lane_wishes'"):
        FakeSession(lane_wishes=lambda vid: (1, False))  # a misspelt stand-in is refused


def test_a_session_that_cannot_tell_gives_the_answers_of_no_sumo():
    s = SessionBase()
    assert s.speed_limits("x") is None and s.lane_wish("x") == (0, False)
    assert not s.keeps_right("x") and s.keep_right_due_s("x") is None
    assert s.lanes_ending("e", 0.0, 1e4) == [] and not s.near_lane_shift(0.0, 100.0)
    assert s.driver_model("x") == DriverModel(model="unknown")
    assert s.set_modes("x", 31, 0) is False and s.route_of("x") is None


def test_the_fleet_forwards_nothing_and_names_its_lead_swarm():
    fleet = Fleet(lambda: None, name="x")
    assert "__getattr__" not in vars(Fleet)
    assert fleet.lead is None and fleet.target_id is None
    with pytest.raises(AttributeError):
        fleet.mode  # noqa: B018  (a single swarm's mode is its lead's: fleet.lead.mode)


def test_speeds_that_follow_the_world_leave_the_scenario_as_configured():
    default = Scenario(name="t", path=None)
    world = dataclasses.replace(default, cav=dataclasses.replace(default.cav, speeds="world"))
    limits = {"c0": (40.0, 27.5), "c1": (26.0, 30.0)}

    def speed_limits(vid):
        if vid == "defect":
            raise KeyError(vid)  # not a vehicle that vanished (that is None): a defect
        return limits.get(vid)  # None: vanished, or SUMO cannot tell

    ctx = run_context(FakeSession(speed_limits=speed_limits), world)
    reformer = Reformer(world, lambda vid: DriverModel(), speeds=ctx.speeds)
    configured = world.cav
    ctx.follow_world_speeds(["c0", "gone", "nobody"])
    with pytest.raises(KeyError):  # a defect is not taken for a vehicle that left
        ctx.follow_world_speeds(["c0", "defect"])
    assert ctx.scenario is world and world.cav is configured  # never replaced
    assert ctx.cav.cruising_speed_mps == ctx.cav.max_speed_mps == 27.5
    assert reformer.cav is ctx.cav  # the reformer reads the same speeds
    assert ctx.speeds_block()["cruising_speed_mps"] == 27.5
    ctx.follow_world_speeds(["c0", "c1"])  # the lowest: c1's vType maxSpeed
    assert ctx.cav.cruising_speed_mps == 26.0 and reformer.cav.max_speed_mps == 26.0
    assert [e["event"] for e in ctx.events] == ["world_speeds"]  # said once
    assert ctx.events[0]["cruising_speed_mps"] == 27.5
    # Within the tolerance nothing changes; speeds = "config" never follows the world.
    limits["c1"] = (26.03, 30.0)
    ctx.follow_world_speeds(["c1"])
    assert ctx.cav.cruising_speed_mps == 26.0
    fixed = run_context(FakeSession(speed_limits=speed_limits), default)
    fixed.follow_world_speeds(["c0"])
    assert fixed.cav is default.cav and fixed.events == []


def test_one_swarms_context_may_always_start_and_knows_no_other_plans():
    ctx = RunContext(SessionBase(), Scenario(name="t", path=None), (), RoadSection((3.2,)))
    assert ctx.may_start(0.0, 0.0, 100.0, "truck") is True
    assert ctx.planned_paths() == {} and ctx.platoon_id is None


def test_the_swarm_controller_offers_the_fleet_every_declared_name():
    swarm = SwarmController()  # before attach, as the fleet's pattern (Fleet._kind)
    declared = [vars(Controller), vars(SwarmMember)]
    for names in declared:
        for name, value in names.items():
            if name.startswith("_"):
                continue
            assert hasattr(swarm, name), name
            if inspect.isfunction(value):
                assert callable(getattr(swarm, name)), name
    for name in (*Controller.__annotations__, *SwarmMember.__annotations__):
        assert hasattr(swarm, name), name
    assert swarm.idle() and swarm.planned_paths() == {} and swarm.manoeuvre_region(0.0) is None


@pytest.mark.parametrize(
    ("step_s", "predicted_s"), [(0.03, 0.25), (0.25, 0.25), (0.5, 0.5), (1.0, 1.0)]
)
def test_the_swarm_predicts_the_hvs_on_sumos_clock_where_it_is_coarser(
    tmp_path, step_s, predicted_s
):
    # SUMO moves its drivers once a step: at 1 s, predicted in 0.25 s steps, they were off
    # their predictions six times as often as at 0.5 s (a replan each time).
    ctx = RunContext(SessionBase(step_length_s=step_s), Scenario(name="t", path=None), (),
                     RoadSection((3.2, 3.2, 3.2)))  # fmt: skip
    ctx.out_dir = tmp_path
    swarm = SwarmController()
    swarm.attach(ctx)
    assert swarm.replanner.manoeuvre.settings.prediction_dt_s == predicted_s
    assert ctx.scenario.hvmodel.prediction_dt_s == 0.25  # the setting as given
    swarm.close()
