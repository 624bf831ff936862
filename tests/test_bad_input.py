"""Bad input: exit status 2 and one line naming the problem and where it is, no traceback."""

from __future__ import annotations

import pytest

from sumo_swarm.sim.netbuild import HighwaySpec, build_highway
from tests.test_cli import assert_bad_input, sumo_swarm
from tests.usercases import write_user_case


def scenario(scenario_file, body: str):
    return scenario_file('[simulation]\nnetwork = "@NET@"\n' + body)


@pytest.mark.parametrize(
    ("body", "fragment"),
    [
        ("[cav]\nlength_m = -5.0\n", "cav: length_m must be > 0"),
        ("[cav]\ncruising_speed_mps = 0.0\n", "cruising_speed_mps must be > 0"),
        ("[hv]\nlength_m = 0.0\n", "hv: length_m must be > 0"),
        ("[cav]\ncount = 0\n", "count must be >= 1"),
        ("[cav]\ncount = 'six'\n", "cav.count: expected an integer"),
        ("[cav]\ncolor = 'red'\n", "unknown key 'cav.color'"),
        ("[cell]\nrule = 'fixed'\ncell_length_m = 3.0\n", "must be at least as long as a CAV"),
        ("[scene]\nplatoon_lane = 3\n", "scene.platoon_lane = 3, but the road has lanes 0..2"),
        ("[planner]\ntime_limit_s = -1.0\n", "time_limit_s"),
        ("[evaluation]\nstart_s = 50.0\nend_s = 10.0\n", "must be after start_s"),
        ("[cav]\naccel_min_mps2 = nan\n", "cav.accel_min_mps2: expected a finite number"),
        ("[planner.weights]\nw_tar = inf\n", "planner.weights.w_tar: expected a finite number"),
    ],
)
def test_bad_scenario_values(scenario_file, body, fragment):
    path = scenario(scenario_file, body)
    assert_bad_input(sumo_swarm("run", str(path)), fragment, str(path))


def test_step_length_zero(scenario_file):
    path = scenario_file('[simulation]\nnetwork = "@NET@"\nstep_length_s = 0.0\n')
    assert_bad_input(sumo_swarm("run", str(path)), "step_length_s must be > 0", str(path))


def test_negative_seed_in_the_file(scenario_file):
    path = scenario_file('[simulation]\nnetwork = "@NET@"\nseed = -5\n')
    assert_bad_input(sumo_swarm("run", str(path)), "seed must be an integer >= 0", str(path))


def test_unreadable_scenario(tmp_path):
    folder = tmp_path / "a-folder.toml"
    folder.mkdir()  # a folder where a file should be: unreadable as a file, even for root
    assert_bad_input(sumo_swarm("run", str(folder)), "cannot read", str(folder))


def test_malformed_toml(scenario_file):
    path = scenario_file("[cav\n")
    assert_bad_input(sumo_swarm("run", str(path)), "malformed TOML", str(path))


def test_one_lane_road(tmp_path, scenario_file):
    net = build_highway(HighwaySpec(length_m=1000, lanes=1), tmp_path / "one")
    path = scenario_file(
        f'[simulation]\nnetwork = "{net.as_posix()}"\nroute_edges = ["e0"]\n'
        "[scene]\nplatoon_lane = 0\nhv = []\n"
    )
    assert_bad_input(sumo_swarm("run", str(path)), "needs at least 2", str(path))


def test_unknown_route_edge(scenario_file):
    path = scenario_file('[simulation]\nnetwork = "@NET@"\nroute_edges = ["nope"]\n')
    assert_bad_input(sumo_swarm("run", str(path)), "no edge 'nope'", str(path))


def test_malformed_network(tmp_path, scenario_file):
    bad = tmp_path / "bad.net.xml"
    bad.write_text("<net><edge id='hwy'>")
    path = scenario_file(f'[simulation]\nnetwork = "{bad.as_posix()}"\n')
    assert_bad_input(sumo_swarm("run", str(path)), "malformed SUMO network", str(bad))


def test_malformed_sumocfg(tmp_path):
    cfg = tmp_path / "broken.sumocfg"
    cfg.write_text("<configuration><input>")
    assert_bad_input(
        sumo_swarm("run", "--sumocfg", str(cfg), "--cav-type", "cav"),
        "malformed SUMO configuration",
        str(cfg),
    )


def test_sumocfg_with_entities_is_refused(tmp_path):
    cfg = tmp_path / "laughs.sumocfg"
    cfg.write_text(
        '<?xml version="1.0"?>\n<!DOCTYPE lolz [<!ENTITY lol "lol">'
        '<!ENTITY lol2 "&lol;&lol;&lol;&lol;">]>\n<configuration>&lol2;</configuration>\n'
    )
    assert_bad_input(
        sumo_swarm("run", "--sumocfg", str(cfg), "--cav-type", "cav"), "unsafe XML", str(cfg)
    )


def test_utf16_sumocfg_with_an_entity_bomb_is_refused(tmp_path):
    # In UTF-16 the bytes "<!DOCTYPE" never occur, so only a parser that sees the decoded text
    # (defusedxml) finds the DTD; expanded, lol9 would be 10**9 "lol"s.
    entities = ['<!ENTITY lol0 "lol">']
    entities += [f'<!ENTITY lol{i} "{f"&lol{i - 1};" * 10}">' for i in range(1, 10)]
    text = (
        '<?xml version="1.0" encoding="UTF-16"?>\n'
        f"<!DOCTYPE lolz [{''.join(entities)}]>\n"
        "<configuration><input><net-file value='&lol9;'/></input></configuration>\n"
    )
    cfg = tmp_path / "bomb.sumocfg"
    cfg.write_bytes(text.encode("utf-16"))
    assert b"<!DOCTYPE" not in cfg.read_bytes()
    assert_bad_input(
        sumo_swarm("run", "--sumocfg", str(cfg), "--cav-type", "cav"), "unsafe XML", str(cfg)
    )


def test_missing_sumocfg(tmp_path):
    cfg = tmp_path / "none.sumocfg"
    assert_bad_input(
        sumo_swarm("run", "--sumocfg", str(cfg), "--cav-type", "cav"), "not found", str(cfg)
    )


@pytest.mark.parametrize("missing", ["highway.net.xml", "routes.rou.xml"])
def test_sumocfg_input_file_missing(tmp_path, missing):
    cfg = write_user_case(tmp_path, HighwaySpec(length_m=500, lanes=3), end_s=5.0)
    (tmp_path / missing).unlink()
    assert_bad_input(
        sumo_swarm("run", "--sumocfg", str(cfg), "--cav-type", "cav", "--out", str(tmp_path / "o")),
        "file not found",
        str(tmp_path / missing),
        str(cfg),
    )


@pytest.mark.parametrize(
    ("old", "new", "fragment"),
    [
        ('<end value="5.0"/>', '<end value="soon"/>', "end: expected a time in seconds"),
        ('<end value="5.0"/>', '<end value="nan"/>', "end must be a finite number"),
        ('<step-length value="0.1"/>', '<step-length value="0"/>', "step-length must be > 0"),
        ('<end value="5.0"/>', '<end value="5.0"/><no-such-thing value="1"/>', "SUMO refuses"),
    ],
)
def test_sumocfg_bad_option(tmp_path, old, new, fragment):
    cfg = write_user_case(tmp_path, HighwaySpec(length_m=500, lanes=3), end_s=5.0)
    text = cfg.read_text(encoding="utf-8")
    assert old in text
    cfg.write_text(text.replace(old, new), encoding="utf-8")
    assert_bad_input(
        sumo_swarm("run", "--sumocfg", str(cfg), "--cav-type", "cav", "--out", str(tmp_path / "o")),
        fragment,
        str(cfg),
    )


def test_sumocfg_without_cav_type(tmp_path):
    cfg = tmp_path / "x.sumocfg"
    cfg.write_text("<configuration/>")
    assert_bad_input(sumo_swarm("run", "--sumocfg", str(cfg)), "--cav-type")


@pytest.mark.sumo
def test_cav_type_no_vehicle_has(tmp_path):
    cfg = write_user_case(tmp_path, HighwaySpec(length_m=1000, lanes=3), end_s=5.0)
    assert_bad_input(
        sumo_swarm(
            "run", "--sumocfg", str(cfg), "--cav-type", "robotaxi", "--out", str(tmp_path / "o")
        ),
        "robotaxi",
        str(cfg),
    )
