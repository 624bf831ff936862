"""The swarm in traffic it was not tuned for (issue 12), through real SUMO: a target that leaves
the platoon's lane, side lanes as slow as the target, and a user's road whose CAVs are faster
than the paper's 20 m/s. Each swarm run is compared with a baseline on the same scene."""

from __future__ import annotations

import copy
import dataclasses
import json
from pathlib import Path

import pandas as pd
import pytest

import sumo_swarm
from sumo_swarm.sim.bridge import sumo_binary
from sumo_swarm.sim.netbuild import HighwaySpec
from sumo_swarm.sim.runner import run_scenario, run_sumocfg
from sumo_swarm.sim.summary import pass_times_s
from sumo_swarm.study.batch import load_sweep
from tests.toolload import load_tool
from tests.usercases import write_exit_case, write_user_case

pytestmark = pytest.mark.sumo
ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture(autouse=True)
def _paper_trigger(monkeypatch):
    """Every swarm of this module decides by the paper's trigger and its rules for targets that
    keep right, catch up or leave (``[swarm] decide = "paper"``): these scenes pin those rules,
    which stay reachable by that setting. The weighing of the default is judged on the corridor
    checks (tools/corridor_checks.py) and tests/test_arbiter.py."""
    from sumo_swarm.config import SwarmSettings

    original = SwarmSettings.__init__

    def init(self, *args, decide="paper", **kwargs):
        original(self, *args, decide=decide, **kwargs)

    monkeypatch.setattr(SwarmSettings, "__init__", init)


def _events(run_dir: Path) -> list[dict]:
    lines = (run_dir / "events.jsonl").read_text(encoding="utf-8").splitlines()
    return [json.loads(line) for line in lines if line.strip()]


def _cav_lanes_at_end(run_dir: Path) -> set[int]:
    df = pd.read_parquet(run_dir / "trajectories.parquet")
    cav = df[df["kind"] == "cav"]
    return set(cav[cav["time_s"] == cav["time_s"].max()]["lane"])


def _no_keep_right_wait(scenario):
    """The scenario with the swarm starting whatever the target may do (``[swarm]
    keep_right_wait_s = 0``): what follows a target leaving mid-manoeuvre is the point."""
    return dataclasses.replace(
        scenario, swarm=dataclasses.replace(scenario.swarm, keep_right_wait_s=0.0)
    )


# The variant tests below were written against the paper's 80 s run (window 0-60 s); the sweep
# now runs 150 s (tools/make_variants.py). Their stories and thresholds are those of 80 s: a
# longer run dilutes a gain made in the first minute with cruising (variant 23: +1.53 m/s over
# cacc in 150 s, +2 or more in 80 s), and 80 s keeps them quick.
VARIANT_TEST_WINDOW = {"duration_s": 80.0, "end_s": 60.0}


def _variant_spec(cavs: int, truck_mps: float):
    """The swarm run of the scenarios/variants.toml case with ``cavs`` CAVs and that truck,
    over the paper's 80 s (``VARIANT_TEST_WINDOW``)."""
    sweep = load_sweep(ROOT / "scenarios" / "variants.toml")
    spec = next(
        r for r in sweep.runs
        if r.controller == "swarm" and r.params["cav.count"] == cavs
        and r.params["scene.hv.hv_target.speed_mps"] == pytest.approx(truck_mps)
    )  # fmt: skip
    overrides = copy.deepcopy(spec.overrides)
    overrides.setdefault("simulation", {})["duration_s"] = VARIANT_TEST_WINDOW["duration_s"]
    overrides.setdefault("evaluation", {})["end_s"] = VARIANT_TEST_WINDOW["end_s"]
    return dataclasses.replace(spec, overrides=overrides)


def test_platoon_reforms_in_one_lane_when_the_target_leaves_its_lane(tmp_path):
    # Variant 10 of scenarios/variants.toml: 11 CAVs, a 16.5 m/s truck that changes to the
    # right lane at about 8 s, while the swarm is spread over all three lanes.
    spec = _variant_spec(11, 16.51)
    scenario = _no_keep_right_wait(spec.scenario())
    swarm = run_scenario(scenario, "swarm", tmp_path / "swarm", seed=spec.seed, progress=False)
    cacc = run_scenario(scenario, "cacc", tmp_path / "cacc", seed=spec.seed, progress=False)
    ends = [e for e in _events(tmp_path / "swarm") if e["event"] == "overtake_end"]
    assert ends and ends[0]["reason"] == "target_changed_lane"
    assert any(e["event"] == "reform_lane" for e in _events(tmp_path / "swarm"))
    assert len(_cav_lanes_at_end(tmp_path / "swarm")) == 1  # one platoon again
    assert swarm["safety"]["collisions"] == 0 and swarm["safety"]["hard_brakes_cav"] == 0
    assert swarm["cav"]["gap_min_m"] >= 5.0
    assert swarm["cav"]["mean_speed_mps"] > cacc["cav"]["mean_speed_mps"]


def test_a_queue_behind_a_truck_slower_than_the_grid_is_planned_at_the_trucks_speed(tmp_path):
    # Variant 17 of scenarios/variants.toml: 11 CAVs, a 13.4 m/s truck, both side lanes full
    # of 17.5 m/s HVs. At 36 s six CAVs are past and five queue behind the truck, which has
    # slowed to 12.6 m/s behind the CAVs ahead of it; the grid, held at 13.4 m/s by those CAVs,
    # leaves the truck behind, the queue has to fall back row by row and the tail CAV is in
    # row 0: no plan, and the swarm gave up with no_feasible_plan. Now it plans again at the
    # truck's own speed (plans.jsonl: grid_speed_rule "target"), and the CAV following the
    # truck closer than the cells' margin may follow on.
    spec = _variant_spec(11, 13.4)
    swarm = run_scenario(spec.scenario(), "swarm", tmp_path, seed=spec.seed, progress=False)
    plans = [json.loads(line) for line in (tmp_path / "plans.jsonl").read_text().splitlines()]
    retried = [p for p in plans if p.get("grid_speed_rule") == "target"]
    assert retried and retried[0]["status"] in ("optimal", "feasible")
    assert retried[0]["grid_speed_mps"] < plans[0]["grid_speed_mps"] - 0.5
    assert swarm["planner"]["grid_retries"]["planned"] >= 1
    assert swarm["planner"]["grid_retries"]["tried"] == len(retried)
    ends = [e for e in _events(tmp_path) if e["event"] == "overtake_end"]
    assert ends and ends[0]["reason"] != "no_feasible_plan"
    assert swarm["safety"]["collisions"] == 0 and swarm["safety"]["hard_brakes_cav"] == 0
    assert swarm["cav"]["gap_min_m"] >= 5.0


def test_after_a_give_up_the_cavs_past_the_truck_wait_for_the_one_behind_it(tmp_path):
    # Variant 24 of scenarios/variants.toml: 5 CAVs, a 14.9 m/s truck, side lanes of 20 and
    # 23 m/s. At 30 s four CAVs are past and the swarm gives up (no way past for the fifth).
    # The four drove on at 20 m/s: the fifth got by at 58 s, 190 m behind them, and the
    # platoon was still in two lanes at 80 s. Now they wait in the truck's lane ahead of it.
    spec = _variant_spec(5, 14.87)
    swarm = run_scenario(spec.scenario(), "swarm", tmp_path, seed=spec.seed, progress=False)
    events = _events(tmp_path)
    starts = [e for e in events if e["event"] == "wait_start"]
    assert [(e["slow"], e["past"], e["behind"]) for e in starts] == [("hv_target", 4, 1)]
    assert swarm["overtake"]["waits_ahead"] == {"started": 1, "ended": {"rejoined": 1}}
    # Two manoeuvres: the cells given up with four CAVs past, then the wait, which regroups
    give_up, wait = swarm["manoeuvres"]
    assert (give_up["kind"], give_up["cavs_past"]) == ("cells", 4)
    assert give_up["outcome"].startswith("aborted:") and not swarm["overtake"]["completed"]
    assert (wait["kind"], wait["outcome"], wait["cavs_past"]) == ("wait", "completed", 5)
    assert wait["regrouped"] is True
    assert len(_cav_lanes_at_end(tmp_path)) == 1
    assert swarm["safety"]["collisions"] == 0 and swarm["safety"]["hard_brakes_cav"] == 0
    assert swarm["cav"]["gap_min_cav_m"] >= 5.0


def test_after_a_give_up_the_cavs_behind_the_truck_keep_their_lanes(tmp_path):
    # Variant 39: 11 CAVs, a 15.0 m/s truck; at 36 s two CAVs are past it and nine behind, in
    # two lanes, and the planner finds no plan. The nine merged into one lane behind the
    # truck and hv_right, slowing to 3 m/s, the HVs behind them to 4 m/s. Now they keep their
    # lanes and pass it from there, while the two wait ahead of it.
    spec = _variant_spec(11, 15.01)
    swarm = run_scenario(spec.scenario(), "swarm", tmp_path, seed=spec.seed, progress=False)
    starts = [e for e in _events(tmp_path) if e["event"] == "wait_start"]
    assert starts and starts[0]["slow"] == "hv_target" and starts[0]["behind"] == 9
    df = pd.read_parquet(tmp_path / "trajectories.parquet")
    late = df[df["time_s"] > starts[0]["time_s"]]
    assert late["speed_mps"].min() > 10.0  # no CAV and no HV crawls behind the truck
    assert swarm["safety"]["collisions"] == 0 and swarm["safety"]["hard_brakes"] == 0
    assert swarm["cav"]["gap_min_cav_m"] >= 5.0


def test_cavs_passing_on_their_own_do_not_pass_into_the_trucks_lane_just_behind_it(tmp_path):
    # Variant 23: 12 CAVs, a 12.4 m/s truck that moves into the lane on its right at 16 s. The
    # last CAVs, passing queued cars there on their own, judged that lane free over 60 m with
    # the truck 94 m ahead in it: three ended behind the truck for 20 s and the platoon never
    # regrouped. The lanes beside are judged over the pass's reach now (reform.PASS_REACH_S).
    spec = _variant_spec(12, 12.38)
    swarm = run_scenario(spec.scenario(), "swarm", tmp_path / "swarm", seed=spec.seed,
                         progress=False)  # fmt: skip
    cacc = run_scenario(spec.scenario(), "cacc", tmp_path / "cacc", seed=spec.seed,
                        progress=False)  # fmt: skip
    # The truck left the lane: the overtake ended there (target_changed_lane), and the swarm
    # drove past it as a platoon; every CAV ends ahead of it, in one lane.
    assert swarm["manoeuvres"][0]["outcome"] == "aborted:target_changed_lane"
    df = pd.read_parquet(tmp_path / "swarm" / "trajectories.parquet")
    cavs = tuple(df.loc[df["kind"] == "cav", "vehicle"].astype(str).unique())
    assert None not in pass_times_s(df, cavs, "hv_target").values()
    assert len(_cav_lanes_at_end(tmp_path / "swarm")) == 1
    assert swarm["cav"]["mean_speed_mps"] > cacc["cav"]["mean_speed_mps"] + 2.0
    assert swarm["safety"]["collisions"] == 0 and swarm["safety"]["hard_brakes_cav"] == 0
    assert swarm["safety"]["hard_brakes"] <= cacc["safety"]["hard_brakes"]
    assert swarm["cav"]["gap_min_cav_m"] >= 5.0


@pytest.mark.parametrize("scene", [155, 181])
def test_target_moving_into_the_front_cavs_lane_is_not_overtaken_again(tmp_path, scene):
    # Stress v2 scenes (scenarios/stress2.toml): the truck moves right at about 8 s, into the
    # lane where the plan had put the front CAV, behind it. The swarm took that CAV as its
    # leader and overtook the same truck again in a lane full of traffic: 16.48 m/s (155) and
    # 15.87 m/s (181) against cacc's 19.13 and 17.93, whose platoon simply drove on.
    sweep = load_sweep(ROOT / "scenarios" / "stress2.toml")
    spec = _stress_spec(sweep, scene)
    scenario = _no_keep_right_wait(spec.scenario())
    swarm = run_scenario(scenario, "swarm", tmp_path / "swarm", seed=spec.seed, progress=False)
    cacc = run_scenario(scenario, "cacc", tmp_path / "cacc", seed=spec.seed, progress=False)
    starts = [e for e in _events(tmp_path / "swarm") if e["event"] == "overtake_start"]
    ends = [e for e in _events(tmp_path / "swarm") if e["event"] == "overtake_end"]
    assert ends and ends[0]["reason"] == "target_changed_lane"
    assert len(starts) == 1  # not the same truck again from the lane it moved into
    assert swarm["safety"]["collisions"] == 0 and swarm["safety"]["hard_brakes_cav"] == 0
    assert swarm["cav"]["gap_min_cav_m"] >= 5.0
    assert swarm["cav"]["mean_speed_mps"] >= 0.97 * cacc["cav"]["mean_speed_mps"]


@pytest.mark.parametrize("scene", [37])
def test_the_swarm_waits_for_a_target_about_to_keep_right(tmp_path, scene):
    # Stress v2 scene: a truck in the leftmost lane with SUMO's keep-right drivers and a free
    # lane on its right moves over at about 8 s. Started at 3 s, the swarm's front CAV passed
    # on the right; the truck moved in front of it and re-forming cost the platoon 2.3 %
    # against cacc. The swarm now waits for such a target (up to [swarm] keep_right_wait_s).
    sweep = load_sweep(ROOT / "scenarios" / "stress2.toml")
    spec = _stress_spec(sweep, scene)
    scenario = spec.scenario()
    swarm = run_scenario(scenario, "swarm", tmp_path / "swarm", seed=spec.seed, progress=False)
    cacc = run_scenario(scenario, "cacc", tmp_path / "cacc", seed=spec.seed, progress=False)
    events = _events(tmp_path / "swarm")
    waits = [e for e in events if e["event"] == "target_may_keep_right"]
    assert waits and waits[0]["target"] == "hv_target"
    assert not [e for e in events if e["event"] == "overtake_start"]  # it moved over first
    assert swarm["safety"]["collisions"] == 0 and swarm["safety"]["hard_brakes_cav"] == 0
    assert swarm["cav"]["mean_speed_mps"] >= 0.99 * cacc["cav"]["mean_speed_mps"]


def test_a_middle_lane_target_about_to_keep_right_is_passed_on_its_left(tmp_path):
    # Stress v2 scene 182: the truck in the middle lane keeps right and moves over at about
    # 8 s. Started on either side, the plan put the front CAV in its right lane and the truck
    # cut it off (3.2 % slower than cacc); waiting for it tied cacc exactly. With [swarm]
    # keep_right_middle = "left" the swarm starts at once with that lane closed to the plan.
    sweep = load_sweep(ROOT / "scenarios" / "stress2.toml")
    spec = _stress_spec(sweep, 182)
    scenario = spec.scenario()
    swarm = run_scenario(scenario, "swarm", tmp_path / "swarm", seed=spec.seed, progress=False)
    cacc = run_scenario(scenario, "cacc", tmp_path / "cacc", seed=spec.seed, progress=False)
    events = _events(tmp_path / "swarm")
    assert [e["target"] for e in events if e["event"] == "overtake_start"][:1] == ["hv_target"]
    assert not [e for e in events if e["event"] == "target_may_keep_right"]  # did not wait
    tr = pd.read_parquet(tmp_path / "swarm" / "trajectories.parquet")
    truck = tr[tr["vehicle"] == "hv_target"]
    moved_s = truck[truck["lane"] != truck["lane"].iloc[0]]["time_s"].min()
    assert 3.0 < moved_s < 20.0  # it did keep right, after the swarm had started
    before = tr[(tr["kind"] == "cav") & (tr["time_s"] < moved_s)]
    assert not (before["lane"] == truck["lane"].iloc[0] - 1).any()  # none in its right lane
    assert swarm["safety"]["collisions"] == 0 and swarm["safety"]["hard_brakes_cav"] == 0
    assert swarm["cav"]["gap_min_cav_m"] >= 5.0
    assert swarm["cav"]["mean_speed_mps"] > cacc["cav"]["mean_speed_mps"]


def _stress_spec(sweep, scene: int):
    """The swarm run of case ``scene`` (0-based, in the file's order) of a sweep."""
    import tomllib

    data = tomllib.loads((ROOT / "scenarios" / "stress2.toml").read_text(encoding="utf-8"))
    want = data["cases"][scene]
    return next(
        r for r in sweep.runs
        if r.controller == "swarm"
        and all(r.params[k] == pytest.approx(v) if isinstance(v, float) else r.params[k] == v
                for k, v in want.items())
    )  # fmt: skip


def _slow_side_lanes(folder: Path) -> Path:
    """The user case with a car ahead in each side lane as slow as the truck."""
    cfg = write_user_case(folder, HighwaySpec(length_m=2500, lanes=3), platoon_lane=1)
    routes = folder / "routes.rou.xml"
    slow = [
        f'  <vehicle id="slow{lane}" type="car" route="r" depart="0" departLane="{lane}" '
        f'departPos="{330 + 20 * lane}" departSpeed="16"/>'
        for lane in (0, 2)
    ]
    text = routes.read_text(encoding="utf-8").replace("</routes>", "\n".join(slow) + "\n</routes>")
    routes.write_text(text, encoding="utf-8")
    return cfg


def test_no_overtake_when_the_side_lanes_are_as_slow_as_the_target(tmp_path):
    cfg = _slow_side_lanes(tmp_path / "net")
    swarm = run_sumocfg(cfg, "cav", "swarm", tmp_path / "swarm", progress=False, notify=print)
    cacc = run_sumocfg(cfg, "cav", "cacc", tmp_path / "cacc", progress=False, notify=print)
    assert not swarm["overtake"]["triggered"]
    worth = [e for e in _events(tmp_path / "swarm") if e["event"] == "overtake_not_worth"]
    assert worth and worth[0]["target"] == "truck"
    assert swarm["safety"]["collisions"] == 0
    assert swarm["cav"]["mean_speed_mps"] >= 0.99 * cacc["cav"]["mean_speed_mps"]


def test_cavs_drive_at_the_speed_of_the_users_world(tmp_path):
    # The user's CAVs may drive 40 m/s on a 33.33 m/s road: SUMO's desired speed for them is
    # min(maxSpeed, limit * speedFactor), never the paper's 20 m/s.
    cfg = write_user_case(tmp_path / "net", HighwaySpec(length_m=2500, lanes=3), end_s=40.0)
    routes = tmp_path / "net" / "routes.rou.xml"
    routes.write_text(
        routes.read_text(encoding="utf-8").replace(
            'maxSpeed="20" accel="3"', 'maxSpeed="40" accel="3"'
        ),
        encoding="utf-8",
    )
    out = run_sumocfg(cfg, "cav", "cacc", tmp_path / "cacc", progress=False, notify=print)
    speeds = out["speeds"]
    assert speeds["source"].startswith("SUMO") and "vType's speedFactor" in speeds["source"]
    # Every CAV got its vType's speedFactor (1.0, SUMO's mean): the lane limit exactly, not the
    # lowest of five draws with SUMO's default speedDev 0.1.
    assert speeds["cruising_speed_mps"] == pytest.approx(33.33, abs=0.01)
    assert out["cav"]["max_speed_mps"] <= speeds["max_speed_mps"] + 0.1
    drawn = tmp_path / "drawn.toml"
    drawn.write_text('[cav]\nspeed_factor = "vehicle"\n', encoding="utf-8")
    own = run_sumocfg(cfg, "cav", "cacc", tmp_path / "drawn", config=drawn, progress=False,
                      notify=print)  # fmt: skip
    assert "vType's" not in own["speeds"]["source"]
    assert 25.0 < own["speeds"]["cruising_speed_mps"] <= 40.0  # 33.33 x the lowest draw
    assert own["speeds"]["cruising_speed_mps"] != pytest.approx(33.33, abs=0.01)
    # A config that sets the speeds keeps them.
    config = tmp_path / "mine.toml"
    config.write_text("[cav]\ncruising_speed_mps = 18.0\nmax_speed_mps = 22.0\n", encoding="utf-8")
    mine = run_sumocfg(cfg, "cav", "cacc", tmp_path / "mine", config=config, progress=False,
                       notify=print)  # fmt: skip
    assert mine["speeds"]["source"] == "config [cav]"
    assert mine["speeds"]["cruising_speed_mps"] == 18.0
    assert mine["cav"]["max_speed_mps"] <= 22.1


def test_cavs_change_lanes_at_the_lateral_speed_their_plans_assume(tmp_path):
    # A user's CAV vType at SUMO's default maxSpeedLat (1 m/s): the controller plans lane
    # changes at [cav] max_lateral_speed_mps (2 m/s), and SUMO capped them at half of it.
    import libsumo

    cfg = write_exit_case(tmp_path, exiting=(), end_s=20.0)
    libsumo.start(
        [sumo_binary(), "-c", str(cfg), "--lateral-resolution", "0.5", "--no-step-log", "true",
         "--time-to-teleport", "-1", "--collision.action", "warn"]
    )  # fmt: skip
    try:
        assert libsumo.vehicletype.getMaxSpeedLat("cav") == pytest.approx(1.0)
        handle = sumo_swarm.attach(libsumo, cav_type="cav")
        while libsumo.simulation.getTime() < 2.0:
            libsumo.simulation.step()
        lateral = {v: libsumo.vehicle.getMaxSpeedLat(v) for v in ("c0", "c3")}
        factors = {v: libsumo.vehicle.getSpeedFactor(v) for v in ("c0", "c3")}
        truck_factor = libsumo.vehicle.getSpeedFactor("truck")
        handle.detach()
    finally:
        libsumo.close()
    assert lateral == {"c0": pytest.approx(2.0), "c3": pytest.approx(2.0)}
    assert factors == {"c0": pytest.approx(1.0), "c3": pytest.approx(1.0)}
    assert truck_factor != pytest.approx(1.0)  # an HV keeps SUMO's draw


def test_cavs_cut_off_by_a_slow_vehicle_pass_it_and_rejoin(tmp_path):
    # A platoon whose leader is free but whose last two CAVs are stuck behind a slow car that
    # drives between them (as after a give-up, or a cut-in): they pass it one by one in the
    # faster lane beside and come back to the platoon's lane, where cacc would stay behind.
    cfg = write_user_case(tmp_path / "net", HighwaySpec(length_m=2500, lanes=3), cav_count=0,
                          end_s=70.0)  # fmt: skip
    routes = tmp_path / "net" / "routes.rou.xml"
    text = routes.read_text(encoding="utf-8")
    truck = 'departPos="322.0" departSpeed="16.0"'
    assert truck in text
    text = text.replace(truck, 'departPos="2400" departSpeed="16.0"')  # far away
    text = text.replace(
        '<vType id="car"', '<vType id="slowcar" maxSpeed="12" carFollowModel="IDM" speedDev="0" '
        'lcSpeedGain="0" lcKeepRight="0"/>\n  <vType id="car"'
    )  # fmt: skip
    cars = [
        '  <vehicle id="c0" type="cav" route="r" depart="0" departLane="1" departPos="300" '
        'departSpeed="16"/>',
        '  <vehicle id="slow" type="slowcar" route="r" depart="0" departLane="1" departPos="280" '
        'departSpeed="12"/>',
        '  <vehicle id="c1" type="cav" route="r" depart="0" departLane="1" departPos="260" '
        'departSpeed="12"/>',
        '  <vehicle id="c2" type="cav" route="r" depart="0" departLane="1" departPos="245" '
        'departSpeed="12"/>',
    ]
    routes.write_text(text.replace("</routes>", "\n".join(cars) + "\n</routes>"), encoding="utf-8")
    # One swarm of the three CAVs (the cut-off pair passes one by one); with many swarms
    # (the default) the pair is a swarm of its own that overtakes the slow car as well.
    one = tmp_path / "one.toml"
    one.write_text('[platoons]\ngrouping = "one"\n', encoding="utf-8")
    swarm = run_sumocfg(
        cfg, "cav", "swarm", tmp_path / "swarm", config=one, progress=False, notify=print
    )
    cacc = run_sumocfg(cfg, "cav", "cacc", tmp_path / "cacc", progress=False, notify=print)
    events = _events(tmp_path / "swarm")
    assert {e["vehicle"] for e in events if e["event"] == "passing_start"} == {"c1", "c2"}
    assert {e["vehicle"] for e in events if e["event"] == "passing_end" and e["past"]} == {
        "c1",
        "c2",
    }
    many = run_sumocfg(cfg, "cav", "swarm", tmp_path / "many", progress=False, notify=print)
    # (each platoon a swarm; a CAV alone is SUMO's, no swarm): the pair weighs passing together
    # against passing apart, SUMO's drivers each, and does what pays; either way it gets past
    assert many["swarms"]["swarms"] >= 1
    parted = [e for e in _events(tmp_path / "many") if e["event"] == "platoon_apart"]
    assert many["swarms"]["overtakes_completed"] >= 1 or parted
    last = pd.read_parquet(tmp_path / "many" / "trajectories.parquet")
    last = last[last["time_s"] == last["time_s"].max()].set_index("vehicle")
    assert (last.loc[["c1", "c2"], "s_m"] > last.loc["slow", "s_m"]).all()
    assert many["safety"]["collisions"] == 0 and many["safety"]["hard_brakes_cav"] == 0
    assert many["cav"]["mean_speed_mps"] > cacc["cav"]["mean_speed_mps"]
    df = pd.read_parquet(tmp_path / "swarm" / "trajectories.parquet")
    last = df[df["time_s"] == df["time_s"].max()].set_index("vehicle")
    assert len(set(last.loc[["c0", "c1", "c2"], "lane"])) == 1
    assert (last.loc[["c1", "c2"], "s_m"] > last.loc["slow", "s_m"]).all()
    assert swarm["safety"]["collisions"] == 0 and swarm["safety"]["hard_brakes_cav"] == 0
    assert swarm["cav"]["mean_speed_mps"] > cacc["cav"]["mean_speed_mps"]


def test_cavs_whose_routes_part_take_their_exit_and_none_enters_a_lane_that_ends(tmp_path):
    # A 3-lane motorway with an on-ramp (acceleration lane) and an off-ramp, SUMO's default
    # cars at 600 veh/h/lane: c1 and c3 take the off-ramp, the others drive through. The
    # controllers' lane-change mode lets SUMO change no lane, so an exiting CAV kept in the
    # platoon would stop at the end of its lane; and a CAV the plan's columns sent into the
    # acceleration lane stopped at its end (0 m/s from 44 s on).
    cfg = write_exit_case(tmp_path / "case")
    swarm = run_sumocfg(cfg, "cav", "swarm", tmp_path / "swarm", progress=False)
    cacc = run_sumocfg(cfg, "cav", "cacc", tmp_path / "cacc", progress=False)
    leaves = [e for e in _events(tmp_path / "swarm") if e["event"] == "cav_leaves"]
    # the exiting CAVs, and only they, leave their platoons (once per platoon they were in)
    assert sorted({e["vehicle"] for e in leaves}) == ["c1", "c3"]
    df = pd.read_parquet(tmp_path / "swarm" / "trajectories.parquet")
    cav = df[df["kind"] == "cav"]
    edges = cav.groupby("vehicle", observed=True)["edge"].agg(lambda e: set(e.astype(str)))
    assert "off" in edges["c1"] and "off" in edges["c3"]
    last = cav.sort_values("time_s").groupby("vehicle", observed=True).tail(1).set_index("vehicle")
    for through in ("c0", "c2", "c4"):  # past the on-ramp, at speed, never on the off-ramp
        assert "off" not in edges[through]
        assert str(last.loc[through, "edge"]) in ("dec", "down")
        assert last.loc[through, "speed_mps"] > 20.0
    on_acceleration_lane = cav[(cav["edge"] == "acc") & (cav["lane"] == 0)]
    assert on_acceleration_lane.empty
    assert swarm["safety"]["collisions"] == 0 and swarm["safety"]["hard_brakes_cav"] == 0
    assert swarm["cav"]["mean_speed_mps"] > cacc["cav"]["mean_speed_mps"]


@pytest.mark.parametrize(
    ("settings", "hand_over"),
    [
        ("[swarm]\nlane_pass = false\nhand_over_in_lane = true\n", True),
        ("[swarm]\nlane_pass = false\nhand_over_in_lane = false\n", False),
        # A cruise 1 m/s above the plan's pace beside the truck: the plan passes faster.
        ("[swarm]\nlane_pass = false\n[cav]\ncruising_speed_mps = 21.0\n", False),
    ],
    ids=["hand-over", "off", "cruise-barely-faster"],
)
def test_the_swarm_passes_at_the_lanes_pace_once_in_one_faster_lane(tmp_path, settings, hand_over):
    """A user's 3-lane road at 900 veh/h/lane, a 15 m/s truck ahead of five CAVs whose lanes
    allow 33 m/s, the cells asked to pass it (``lane_pass = false``; with it the platoon
    moves over as a unit first): the plan moves all five into the middle lane, where they are
    one platoon beside the truck. With the hand-over the cruise takes them past at that
    lane's pace (the plan's one cell per behaving interval is 5 m/s above the truck), not
    counted as a give-up; without it (``[swarm] hand_over_in_lane = false``), or with a
    cruise that does not beat the plan's pace by ``min_speed_gain_mps``, the plan leads them
    past."""
    from sumo_swarm.sim.userroads import write_road

    cfg = write_road("3-lane-900", tmp_path / "road", end_s=40.0)
    config = tmp_path / "swarm.toml"
    config.write_text(settings)
    out = tmp_path / "swarm"
    summary = run_sumocfg(cfg, "cav", "swarm", out, config=config, progress=False,
                          notify=lambda _: None)  # fmt: skip
    assert summary["safety"]["collisions"] == 0
    assert summary["cav"]["gap_min_m"] >= 5.0
    handed = [e for e in _events(out) if e["event"] == "overtake_handover"]
    assert bool(handed) == hand_over, handed
    # the manoeuvre goes on past the hand-over, until every CAV is past the truck
    assert summary["manoeuvres"][0]["outcome"] == "completed"
    df = pd.read_parquet(out / "trajectories.parquet")
    truck = df[df["vehicle"] == "truck"].set_index("time_s")["speed_mps"]
    cav = df[df["kind"] == "cav"]
    if hand_over:
        assert summary["overtake"]["aborted"] == 0
        t0 = handed[0]["time_s"]
        later = cav[(cav["time_s"] > t0 + 5.0) & (cav["time_s"] < t0 + 10.0)]
        # Well above the plan's pace beside the truck, every CAV
        assert later.groupby("vehicle", observed=True)["speed_mps"].min().min() > (
            truck.max() + 8.0
        )
    else:
        start = next(e["time_s"] for e in _events(out) if e["event"] == "overtake_start")
        during = cav[(cav["time_s"] > start) & (cav["time_s"] < start + 15.0)]
        # The plan's pace: about one cell per 3 s above the truck, far below the lanes' 33 m/s
        assert during["speed_mps"].max() < truck.max() + 10.0


@pytest.fixture(scope="module")
def two_lane_runs(tmp_path_factory):
    """The user's 2-lane road with a 900 veh/h flow in the passing lane (33 m/s), a 15 m/s
    truck ahead of five CAVs: the swarm with and without ``[swarm] lane_pass``."""
    from sumo_swarm.sim.userroads import write_road

    base = tmp_path_factory.mktemp("lane_pass")
    cfg = write_road("2-lane-passing-flow", base / "road", end_s=90.0)
    runs = {}
    for lane_pass in (True, False):
        config = base / f"swarm-{lane_pass}.toml"
        # (a module's fixture: the paper's trigger written out, the autouse pin is per test)
        config.write_text(f'[swarm]\nlane_pass = {str(lane_pass).lower()}\ndecide = "paper"\n')
        out = base / f"swarm-{lane_pass}"
        summary = run_sumocfg(cfg, "cav", "swarm", out, config=config, progress=False,
                              notify=lambda _: None)  # fmt: skip
        runs[lane_pass] = (summary, out)
    return runs


def test_the_platoon_moves_over_to_a_faster_lane_and_passes_there(two_lane_runs):
    """Beside a passing lane 18 m/s faster than the truck (the cells would pass at 5 m/s above
    it, entering at that speed in front of 33 m/s drivers, which the guard refuses), the
    platoon moves over as a unit, each CAV entering speeding up, passes the truck at the
    lane's pace and re-forms there: faster than with the cells alone, safe, and regrouped."""
    summary, out = two_lane_runs[True]
    starts = [e for e in _events(out) if e["event"] == "overtake_start"]
    assert starts and starts[0].get("how") == "lane" and starts[0]["lane"] == 1
    assert summary["safety"]["collisions"] == 0
    assert summary["safety"]["hard_brakes_cav"] == 0
    assert summary["cav"]["gap_min_m"] >= 5.0
    assert summary["overtake"]["completed"] and summary["overtake"]["regrouped"]
    cells, _ = two_lane_runs[False]
    assert summary["cav"]["mean_speed_mps"] > cells["cav"]["mean_speed_mps"] + 3.0
    # The HV drivers of the passing lane are not braked harder than by the cells' swarm.
    assert summary["safety"]["hard_brakes"] <= max(cells["safety"]["hard_brakes"], 1)


def test_a_lane_pass_that_stalls_is_weighed_again_and_the_cells_take_the_target(tmp_path):
    """Stress v2 scene 59 (2 lanes, a 12.7 m/s truck ahead of three CAVs, the cruise 20 m/s):
    the passing lane looks free enough at the decision, the platoon starts to move over,
    but no CAV gets out of the truck's lane for lane_pass_stall_s; the swarm weighs again at
    once, with no lane pass on that truck, takes the cells (blocking), and all CAVs get past
    it, safely."""
    sweep = load_sweep(ROOT / "scenarios" / "stress2.toml")
    spec = [r for r in sweep.runs if r.controller == "swarm"][59]
    summary = run_scenario(spec.scenario(), "swarm", tmp_path, seed=spec.seed, progress=False)
    ends = {e["event"] + ":" + str(e.get("reason", e.get("how")))
            for e in _events(tmp_path) if e["event"].startswith("overtake_")}  # fmt: skip
    assert "overtake_start:lane" in ends and "overtake_end:lane_pass_stalled" in ends
    starts = [e for e in _events(tmp_path) if e["event"] == "overtake_start"]
    assert [e.get("how", "cells") for e in starts[:2]] == ["lane", "cells"]
    stalled, cells = summary["manoeuvres"][:2]
    assert (stalled["kind"], stalled["outcome"]) == ("lane_pass", "aborted:lane_pass_stalled")
    assert (cells["kind"], cells["outcome"], cells["cavs_past"]) == ("cells", "completed", 3)
    assert not summary["overtake"]["completed"]  # the first manoeuvre's, the lane pass's
    assert summary["safety"]["collisions"] == 0 and summary["safety"]["hard_brakes_cav"] == 0
    assert summary["cav"]["gap_min_m"] >= 5.0


def test_no_cav_side_swipes_an_hv_straddling_a_lane_boundary(tmp_path):
    """The user's 3-lane road at 900 veh/h/lane with 30 m cells (a cell length the config
    accepts): at 74-76 s an HV of lane 1 stood half-way through a lane change into lane 0, its
    side 0.25 m into it, and two CAVs of lane 0 moving left within their own lane (no lane
    guard looks at the next lane before the CAV's side nears it) hit it: 2 side collisions
    before the side clearance check (``[guards] side_clearance_m``)."""
    from sumo_swarm.sim.userroads import write_road

    cfg = write_road("3-lane-900", tmp_path / "road", end_s=80.0)
    config = tmp_path / "swarm.toml"
    config.write_text('[cell]\nrule = "fixed"\ncell_length_m = 30.0\n[swarm]\nlane_pass = false\n')
    summary = run_sumocfg(cfg, "cav", "swarm", tmp_path / "swarm", config=config,
                          progress=False, notify=lambda _: None)  # fmt: skip
    assert summary["safety"]["collisions"] == 0
    assert summary["safety"]["hard_brakes_cav"] == 0


def test_no_overtake_of_a_car_that_is_only_catching_up(tmp_path):
    # The paper's swarm cruises at 20 m/s (trigger below 0.95 x 20 = 19 m/s). The slow vehicle
    # drives 17 m/s but wants 19.6 and has a free road ahead: with the paper's HV accel of
    # 0.73 m/s^2 it gets there slowly (0.3 m/s^2 at 17 m/s, below the "speeding up" line),
    # so it looks slow for seconds. It is catching up, not persistently slower: no overtake.
    from sumo_swarm.config import load_scenario

    truck = {"speed_mps": 17.0, "desired_speed_mps": 19.6}
    sc = load_scenario(
        ROOT / "scenarios" / "paper.toml",
        overrides={"simulation": {"duration_s": 20.0}, "evaluation": {"end_s": 20.0}},
    )
    hvs = [dataclasses.replace(h, **truck) if h.id == "hv_target" else h for h in sc.scene.hv]
    sc = dataclasses.replace(sc, scene=dataclasses.replace(sc.scene, hv=tuple(hvs)))
    swarm = run_scenario(sc, "swarm", tmp_path / "swarm", progress=False)
    assert not swarm["overtake"]["triggered"]
    worth = [e for e in _events(tmp_path / "swarm") if e["event"] == "overtake_not_worth"]
    assert worth and worth[0]["reason"] == "catching_up" and worth[0]["target"] == "hv_target"
    assert swarm["safety"]["collisions"] == 0


# A paper-scene variant drawn like those of scenarios/variants.toml (another seed): 2 CAVs
# behind a 12 m truck at 12.6 m/s in the middle lane, HV lane changes on, seven HVs per lane
# upstream whose right-lane stream (up to 21 m/s) passes the truck for some 45 s; 150 s.
STREAM_CASE = {
    "cav.count": 2, "scene.initial_speed_mps": 12.61, "scene.upstream_speed_mps": 12.61,
    "scene.hv.hv_target.front_m": 322.0, "scene.hv.hv_target.length_m": 12.0,
    "scene.hv.hv_target.speed_mps": 12.61, "scene.hv.hv_target.desired_speed_mps": 12.61,
    "scene.hv.hv_left.desired_speed_mps": 19.95, "scene.hv.hv_right.desired_speed_mps": 20.99,
    "scene.upstream_gap_m": 22.7, "scene.upstream_per_lane": 7, "hv.lane_changes": True,
}  # fmt: skip


def _stream_spec(tmp_path: Path, **swarm):
    """The runs of STREAM_CASE (``swarm``: ``[swarm]`` keys), by controller, from a sweep file
    written by tools/make_variants.py."""
    case = {**STREAM_CASE, **{f"swarm.{k}": v for k, v in swarm.items()}}
    path = tmp_path / "stream.toml"
    base = (ROOT / "scenarios" / "paper.toml").as_posix()
    path.write_text(load_tool("make_variants").render([case], seed=0, base=base), encoding="utf-8")
    return {run.controller: run for run in load_sweep(path).runs}


def test_a_truck_that_wants_to_keep_right_behind_a_stream_is_not_passed_on_its_right(tmp_path):
    # Its driver wants to move right from about 5 s on (SUMO's lane-change state) and moves
    # over once the stream has passed. Passed on that side right after the stream, the CAV
    # there kept it from moving, and the swarm was 0.08 m/s slower than cacc; with the lane
    # closed to the plan while the wish lasts and the lane opens within keep_right_soon_s, the
    # swarm passes it on its left and is faster than cacc.
    runs = _stream_spec(tmp_path)
    results = {}
    for controller in ("swarm", "cacc"):
        spec = runs[controller]
        out = tmp_path / controller
        results[controller] = run_scenario(spec.scenario(), controller, out, seed=spec.seed,
                                           progress=False)  # fmt: skip
    swarm, cacc = results["swarm"], results["cacc"]
    plans = [json.loads(line) for line in (tmp_path / "swarm" / "plans.jsonl").read_text(
        encoding="utf-8").splitlines() if line.strip()]  # fmt: skip
    assert any(p.get("closed_lane") == 0 for p in plans)
    assert swarm["safety"]["collisions"] == 0 and swarm["safety"]["hard_brakes_cav"] == 0
    assert swarm["cav"]["gap_min_cav_m"] >= 5.0
    assert swarm["cav"]["mean_speed_mps"] > cacc["cav"]["mean_speed_mps"] + 0.05
    # The former rule (closed only while free): slower than cacc on this scene.
    old = _stream_spec(tmp_path, keep_right_wish=False)["swarm"]
    former = run_scenario(old.scenario(), "swarm", tmp_path / "former", seed=old.seed,
                          progress=False)  # fmt: skip
    assert former["cav"]["mean_speed_mps"] < cacc["cav"]["mean_speed_mps"]


def test_a_truck_about_to_keep_right_is_passed_on_its_left_when_sumo_says_it_will_move(tmp_path):
    # A fresh variant of seed 23 (python tools/make_variants.py --seed 23, scene 28): a keep-
    # right truck at 14.97 m/s in the middle lane, a car at 17.5-18.5 m/s on its right 70 m
    # behind it. Under cacc the truck moves right at 7 s. Judged 5 s ahead, its right lane was
    # not free for it at the start (3 s); the plan sent a blocker into that lane and the truck
    # stayed in the platoon's way until 17 s (19.45 m/s against cacc's 19.65). Read from SUMO,
    # its wish was 2 s away: the lane is closed to the plan, the swarm passes on its left and
    # the truck moves over as under cacc.
    scenario = _paper_variant(
        tmp_path, cavs=9, truck=(315.9, 5.9, 14.97), left=22.41, right=18.54,
        upstream=(37.0, 3),
    )  # fmt: skip
    swarm = run_scenario(scenario, "swarm", tmp_path / "swarm", seed=42, progress=False)
    cacc = run_scenario(scenario, "cacc", tmp_path / "cacc", seed=42, progress=False)
    tr = pd.read_parquet(tmp_path / "swarm" / "trajectories.parquet")
    truck = tr[tr["vehicle"] == "hv_target"]
    moved_s = truck[truck["lane"] != truck["lane"].iloc[0]]["time_s"].min()
    assert moved_s < 9.0  # as under cacc (7 s), not held up by a CAV in its right lane
    before = tr[(tr["kind"] == "cav") & (tr["time_s"] < moved_s)]
    assert not (before["lane"] == truck["lane"].iloc[0] - 1).any()  # none in its right lane
    assert swarm["safety"]["collisions"] == 0 and swarm["safety"]["hard_brakes_cav"] == 0
    assert swarm["cav"]["gap_min_cav_m"] >= 5.0
    assert swarm["cav"]["mean_speed_mps"] > cacc["cav"]["mean_speed_mps"]
    # Judged the former way (keep_right_move_s from now): the truck is held up.
    old = dataclasses.replace(
        scenario, swarm=dataclasses.replace(scenario.swarm, keep_right_due=False)
    )
    run_scenario(old, "swarm", tmp_path / "old", seed=42, progress=False)
    tr = pd.read_parquet(tmp_path / "old" / "trajectories.parquet")
    truck = tr[tr["vehicle"] == "hv_target"]
    assert truck[truck["lane"] != truck["lane"].iloc[0]]["time_s"].min() > 12.0


def _paper_variant(tmp_path, *, cavs, truck, left, right, upstream, duration_s=80.0):
    """A paper-scene variant as tools/make_variants.py draws them, HV lane changes on:
    ``cavs`` CAVs, the truck's (front [m], length [m], speed [m/s]), the side HVs' desired
    speeds [m/s], the upstream (gap [m], HVs per lane); run for ``duration_s``."""
    front, length, speed = truck
    gap, per_lane = upstream
    paper = (ROOT / "scenarios" / "paper.toml").as_posix()
    sweep_file = tmp_path / "case.toml"
    sweep_file.write_text(
        f"""name = "variant"
base = "{paper}"
controllers = ["swarm"]
seeds = [42]

[fixed]
"simulation.duration_s" = {duration_s}
"evaluation.end_s" = {min(duration_s, 60.0)}

[[cases]]
"cav.count" = {cavs}
"scene.leader_front_m" = 300.0
"scene.initial_speed_mps" = {speed}
"scene.hv.hv_target.front_m" = {front}
"scene.hv.hv_target.length_m" = {length}
"scene.hv.hv_target.speed_mps" = {speed}
"scene.hv.hv_target.desired_speed_mps" = {speed}
"scene.hv.hv_left.front_m" = 255.0
"scene.hv.hv_left.speed_mps" = 17.5
"scene.hv.hv_left.desired_speed_mps" = {left}
"scene.hv.hv_right.front_m" = 240.0
"scene.hv.hv_right.speed_mps" = 17.5
"scene.hv.hv_right.desired_speed_mps" = {right}
"scene.upstream_gap_m" = {gap}
"scene.upstream_per_lane" = {per_lane}
"scene.upstream_speed_mps" = {speed}
"hv.lane_changes" = true
""",
        encoding="utf-8",
    )
    return load_sweep(sweep_file).runs[0].scenario()


def test_after_a_give_up_the_leader_passes_a_truck_about_to_keep_right_on_its_left(tmp_path):
    # A fresh variant of seed 31 (scene 27): 2 CAVs behind a keep-right truck at 15.83 m/s in
    # the middle lane, which moves right at 7 s under cacc. The plan keeps its right lane
    # closed (it will be free for the truck when its wish shows) and finds no way past on the
    # left: the swarm gives up 3 s in and the leader passes on its own. It passed in the lane
    # the plan had kept free for the truck; now it keeps out of it as the plan does.
    scenario = _paper_variant(
        tmp_path, cavs=2, truck=(318.9, 8.9, 15.83), left=22.35, right=19.41,
        upstream=(23.6, 3), duration_s=30.0,
    )  # fmt: skip
    swarm = run_scenario(scenario, "swarm", tmp_path / "swarm", seed=42, progress=False)
    events = _events(tmp_path / "swarm")
    ends = [e for e in events if e["event"] == "overtake_end"]
    assert ends and ends[0]["reason"] == "no_way_past"
    passes = [e for e in events if e["event"] == "passing_start"]
    assert passes and all(e["lane"] == 2 for e in passes)  # on its left, never in lane 0
    tr = pd.read_parquet(tmp_path / "swarm" / "trajectories.parquet")
    truck = tr[tr["vehicle"] == "hv_target"]
    assert truck[truck["lane"] != 1]["time_s"].min() < 9.0  # it moved over as under cacc
    assert swarm["safety"]["collisions"] == 0 and swarm["safety"]["hard_brakes_cav"] == 0
