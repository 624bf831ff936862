"""Bad input: exit status 2 and one line naming the problem and where it is, no traceback."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time

import pytest

from sumo_swarm.sim.netbuild import HighwaySpec, build_highway
from sumo_swarm.userfiles import MAX_TEXT_BYTES
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


# ------------------------------------------------------------------------------------------
# Paths with spaces and non-ASCII letters, everywhere a user names one

SPACED = "my road ü é"  # a space, non-ASCII letters


def _short_scenario(folder, net: str = "../net/highway3.net.xml", *, duration_s: float = 2.0):
    """The paper's scenario, ``duration_s`` long, its network relative to the file."""
    from tests.conftest import PAPER, ROOT

    (folder / "net").mkdir(parents=True, exist_ok=True)
    (folder / "net" / "highway3.net.xml").write_bytes(
        (ROOT / "networks" / "highway3.net.xml").read_bytes()
    )
    (folder / "scen").mkdir(exist_ok=True)
    text = PAPER.read_text(encoding="utf-8")
    text = text.replace('network = "../networks/highway3.net.xml"', f'network = "{net}"')
    text = text.replace("duration_s = 80.0", f"duration_s = {duration_s}")
    text = text.replace("end_s = 60.0", f"end_s = {duration_s}")
    path = folder / "scen" / "paper é.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.sumo
def test_a_sumocfg_in_a_folder_with_spaces_and_non_ascii_letters_runs(tmp_path):
    # SUMO's saved configuration writes such a path percent-encoded (my%20road%20ü): read back
    # as it was, it named a file that does not exist.
    folder = tmp_path / SPACED
    cfg = write_user_case(folder, HighwaySpec(length_m=800, lanes=3), end_s=3.0)
    out = tmp_path / "out ä"
    proc = sumo_swarm(
        "run", "--sumocfg", str(cfg), "--cav-type", "cav", "--controller", "cacc",
        "--out", str(out),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr
    assert (out / "summary.json").is_file()
    # replay reads the network from the configuration SUMO saved, its paths percent-encoded
    proc = sumo_swarm("replay", str(out), "--to", "1", "--fps", "2", "--out", str(out / "r ü.gif"))
    assert proc.returncode == 0, proc.stderr


@pytest.mark.sumo
def test_scenario_batch_replay_and_impact_in_folders_with_spaces(tmp_path):
    folder = tmp_path / SPACED
    scenario_path = _short_scenario(folder)
    run_dir = folder / "run é"
    proc = sumo_swarm("run", str(scenario_path), "--controller", "cacc", "--out", str(run_dir))
    assert proc.returncode == 0, proc.stderr
    movie = run_dir / "replay ü.gif"
    proc = sumo_swarm("replay", str(run_dir), "--out", str(movie), "--to", "1", "--fps", "2")
    assert proc.returncode == 0, proc.stderr
    assert movie.stat().st_size > 0
    sweep = folder / "scen" / "sweep ü.toml"
    sweep.write_text(
        f'base = "{scenario_path.name}"\ncontrollers = ["cacc"]\nseeds = [1]\n', encoding="utf-8"
    )
    batch_dir = folder / "batch é"
    proc = sumo_swarm("batch", str(sweep), "--out", str(batch_dir), "--workers", "1")
    assert proc.returncode == 0, proc.stderr
    proc = sumo_swarm("impact", str(batch_dir))
    assert proc.returncode == 0, proc.stderr
    assert (batch_dir / "impact" / "impact.md").is_file()


# ------------------------------------------------------------------------------------------
# Every file a user names: a regular file of bounded size, checked before it is read


def _special(tmp_path, kind: str):
    """A path that is no regular file: a FIFO (a reader would wait for ever), a character
    device (endless), a folder; or a regular file larger than any scenario may be (sparse)."""
    path = tmp_path / f"special-{kind}"
    if kind == "fifo":
        os.mkfifo(path)
    elif kind == "device":
        path.symlink_to("/dev/zero")
    elif kind == "folder":
        path.mkdir()
    else:
        with path.open("wb") as fh:
            fh.truncate(MAX_TEXT_BYTES + 1)
    return path


SPECIAL = {
    "fifo": "not a regular file (a FIFO)",
    "device": "not a regular file (a character device)",
    "folder": "a folder, not a file",
    "huge": "more than the 64 MiB",
}


@pytest.mark.parametrize("kind", sorted(SPECIAL))
@pytest.mark.parametrize("role", ["scenario", "sumocfg", "config", "sweep"])
def test_a_special_or_huge_file_is_refused_at_once(tmp_path, kind, role):
    path = _special(tmp_path, kind)
    cfg = write_user_case(tmp_path / "case", HighwaySpec(length_m=500, lanes=3), end_s=2.0)
    args = {
        "scenario": ["run", str(path)],
        "sumocfg": ["run", "--sumocfg", str(path), "--cav-type", "cav"],
        "config": ["run", "--sumocfg", str(cfg), "--cav-type", "cav", "--config", str(path)],
        "sweep": ["batch", str(path), "--out", str(tmp_path / "b")],
    }[role]
    proc = sumo_swarm(*args, "--out", str(tmp_path / "o")) if role != "sweep" else sumo_swarm(*args)
    assert_bad_input(proc, SPECIAL[kind], str(path))


@pytest.mark.parametrize("kind", ["fifo", "device"])
@pytest.mark.parametrize("named", ["route-files", "net-file"])
def test_a_special_file_a_sumocfg_names_is_refused(tmp_path, kind, named):
    cfg = write_user_case(tmp_path, HighwaySpec(length_m=500, lanes=3), end_s=2.0)
    target = tmp_path / ("routes.rou.xml" if named == "route-files" else "highway.net.xml")
    target.unlink()
    special = _special(tmp_path, kind)
    special.rename(target)
    proc = sumo_swarm(
        "run", "--sumocfg", str(cfg), "--cav-type", "cav", "--out", str(tmp_path / "o")
    )
    assert_bad_input(proc, named, SPECIAL[kind], str(target), str(cfg))


@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_a_special_file_as_the_scenario_network_is_refused(tmp_path, scenario_file, kind):
    special = _special(tmp_path, kind)
    path = scenario_file(f'[simulation]\nnetwork = "{special.as_posix()}"\n')
    # the network's path is resolved: the device a link points to is named
    assert_bad_input(sumo_swarm("run", str(path)), SPECIAL[kind], str(special.resolve()), str(path))


# ------------------------------------------------------------------------------------------
# A mistyped key, section, option or type: the nearest one suggested


@pytest.mark.parametrize(
    ("body", "fragment"),
    [
        ("[cav]\nlenght_m = 4.0\n", "unknown key 'cav.lenght_m': did you mean 'cav.length_m'?"),
        ("[simulaton]\n", "unknown section '[simulaton]': did you mean '[simulation]'?"),
        ("[planner.weights]\nw_tarr = 1.0\n", "did you mean 'planner.weights.w_tar'?"),
        (
            "[[scene.hv]]\nid='a'\nlane=0\nfront_m=30.0\nspeedmps=3.0\n",
            "did you mean 'scene.hv[0].speed_mps'?",
        ),
    ],
)
def test_a_mistyped_key_in_a_scenario_suggests_the_nearest(scenario_file, body, fragment):
    path = scenario(scenario_file, body)
    assert_bad_input(sumo_swarm("run", str(path)), fragment, str(path))


@pytest.mark.parametrize(
    ("body", "fragment"),
    [
        ('controler = ["cacc"]\n', "unknown key 'controler': did you mean 'controllers'?"),
        ('controllers = ["cac"]\n', "unknown controller 'cac': did you mean 'cacc'?"),
        ('[grid]\n"cav.cuont" = [4, 6]\n', "unknown key 'cav.cuont': did you mean 'cav.count'?"),
        ('[fixed]\n"simulaton.duration_s" = 5.0\n', "did you mean 'simulation'?"),
    ],
)
def test_a_mistyped_key_in_a_sweep_suggests_the_nearest(tmp_path, paper_path, body, fragment):
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(f'base = "{paper_path.as_posix()}"\n{body}', encoding="utf-8")
    proc = sumo_swarm("batch", str(sweep), "--out", str(tmp_path / "b"))
    assert_bad_input(proc, fragment, str(sweep))


def test_a_mistyped_key_in_a_config_file_suggests_the_nearest(tmp_path):
    cfg = write_user_case(tmp_path, HighwaySpec(length_m=500, lanes=3), end_s=2.0)
    settings = tmp_path / "swarm settings.toml"
    settings.write_text("[swarm]\nkeep_rigth_wait_s = 2.0\n", encoding="utf-8")
    proc = sumo_swarm(
        "run", "--sumocfg", str(cfg), "--cav-type", "cav", "--config", str(settings),
        "--out", str(tmp_path / "o"),
    )  # fmt: skip
    assert_bad_input(proc, "did you mean 'swarm.keep_right_wait_s'?", str(settings))


def test_a_sweep_given_to_run_says_it_is_a_sweep(tmp_path, paper_path):
    sweep = tmp_path / "sweep.toml"
    sweep.write_text(f'base = "{paper_path.as_posix()}"\n', encoding="utf-8")
    assert_bad_input(sumo_swarm("run", str(sweep)), "this is a sweep file", "batch", str(sweep))


@pytest.mark.sumo
def test_a_wrong_cav_type_lists_the_types_present(tmp_path):
    cfg = write_user_case(tmp_path, HighwaySpec(length_m=500, lanes=3), end_s=2.0)
    proc = sumo_swarm(
        "run", "--sumocfg", str(cfg), "--cav-type", "CAV_", "--out", str(tmp_path / "o")
    )
    assert_bad_input(
        proc, "unknown vType 'CAV_': did you mean 'cav'?", "(vTypes in the simulation: car, cav, "
        "truck)", str(cfg),
    )  # fmt: skip


# ------------------------------------------------------------------------------------------
# --gui where no window can open


@pytest.mark.parametrize(
    ("display", "fragment"),
    [(None, "DISPLAY is not set"), (":97", "no X server answers at DISPLAY=:97")],
)
def test_gui_without_a_display_fails_at_once(tmp_path, scenario_file, display, fragment):
    path = scenario_file('[simulation]\nnetwork = "@NET@"\n')
    env = {k: v for k, v in os.environ.items() if k != "DISPLAY"}
    if display is not None:
        env["DISPLAY"] = display
    t0 = time.monotonic()
    proc = subprocess.run(
        [sys.executable, "-m", "sumo_swarm", "run", str(path), "--gui", "--out",
         str(tmp_path / "o")],
        capture_output=True, text=True, env=env, timeout=120,
    )  # fmt: skip
    assert_bad_input(proc, "--gui", fragment)
    assert time.monotonic() - t0 < 20.0  # traci retried for about a minute
    assert not (tmp_path / "o").exists()  # refused before anything was written


# ------------------------------------------------------------------------------------------
# Geometry and counts against the road, before SUMO starts (or anything is allocated)


@pytest.mark.parametrize(
    ("body", "fragments"),
    [
        ("[scene]\nleader_front_m = 5000.0\n", ["scene.leader_front_m = 5000", "beyond the end"]),
        ("[scene]\nleader_front_m = 2995.0\n", ["the slow HV placed ahead", "beyond the end"]),
        ("[cav]\ncount = 1000\n", ["cav.count = 1000", "20 fit"]),
        ("[cav]\ncount = 100000000000\n", ["count must be >= 1 and <= 10000"]),
        ("[planner]\nn_steps = 1000000000\n", ["n_steps must be an integer >= 2 and <= 1000"]),
        ("[grid]\nrows_ahead = 1000000000\n", ["rows_ahead must be an integer >= 0 and <= 1000"]),
        ("[cav]\nlength_m = 5000.0\n", ["cav.length_m = 5000", "longer than lane 1"]),
        (
            "[[scene.hv]]\nid = 'x'\nlane = 1\nfront_m = 280.0\n",
            ["scene.hv 'x'.front_m", "overlap in lane 1"],
        ),
        (
            "[[scene.hv]]\nid = 'x'\nlane = 0\nfront_m = 3.0\n",
            ["scene.hv 'x'.front_m = 3", "before the start"],
        ),
        (
            "[[scene.hv]]\nid = 'x'\nlane = 2\nfront_m = 3300.0\n",
            ["scene.hv 'x'.front_m = 3300", "beyond the end of lane 2"],
        ),
        (
            "[[scene.hv]]\nid = 'x'\nlane = 0\nfront_m = 30.0\n"
            "[[scene.hv]]\nid = 'y'\nlane = 0\nfront_m = 33.0\n",
            ["'x' (25-30 m) and 'y' (28-33 m) overlap in lane 0"],
        ),
    ],
)
def test_geometry_and_counts_are_checked_against_the_road(scenario_file, tmp_path, body, fragments):
    path = scenario(scenario_file, body)
    t0 = time.monotonic()
    proc = sumo_swarm("run", str(path), "--out", str(tmp_path / "o"))
    assert_bad_input(proc, *fragments, str(path))
    assert time.monotonic() - t0 < 30.0


# ------------------------------------------------------------------------------------------
# SUMO refusing the user's files: exit 2, one line, the file named


def _break(tmp_path, case: str):
    cfg = write_user_case(tmp_path, HighwaySpec(length_m=800, lanes=3), end_s=3.0)
    routes, net = tmp_path / "routes.rou.xml", tmp_path / "highway.net.xml"
    if case == "no lane for its vClass":
        net.write_text(net.read_text().replace("<lane id=", '<lane allow="passenger truck" id='))
        routes.write_text(
            routes.read_text().replace('<vType id="cav" ', '<vType id="cav" vClass="bus" ')
        )
    elif case == "route over an unknown edge":
        routes.write_text(routes.read_text().replace('edges="e0"', 'edges="e0 nowhere"'))
    else:
        routes.write_text(
            routes.read_text().replace(
                'id="cav" length="5" maxSpeed="20"', 'id="cav" length="5" maxSpeed="0"'
            )
        )
    return cfg, routes


@pytest.mark.sumo
@pytest.mark.parametrize(
    ("case", "fragment"),
    [
        ("no lane for its vClass", "Invalid departLane definition for vehicle 'c0'"),
        ("route over an unknown edge", "The edge 'nowhere' within the route 'r' is not known."),
        ("vType maxSpeed 0", "maxSpeed must be greater than 0"),
    ],
)
def test_sumo_refusing_a_users_file_names_the_file(tmp_path, case, fragment):
    cfg, routes = _break(tmp_path, case)
    proc = sumo_swarm(
        "run", "--sumocfg", str(cfg), "--cav-type", "cav", "--out", str(tmp_path / "o")
    )
    assert_bad_input(proc, f"{routes}: SUMO refuses it: {fragment}", str(cfg))


# ------------------------------------------------------------------------------------------
# Corrupt outputs read back: exit 2 in replay and impact alike


@pytest.mark.sumo
def test_corrupt_files_exit_2_in_replay_and_impact_alike(tmp_path):
    folder = tmp_path / "case"
    scenario_path = _short_scenario(folder)
    sweep = folder / "scen" / "sweep.toml"
    sweep.write_text(f'base = "{scenario_path.name}"\ncontrollers = ["cacc"]\nseeds = [1]\n')
    batch_dir = tmp_path / "batch"
    assert (
        sumo_swarm("batch", str(sweep), "--out", str(batch_dir), "--workers", "1").returncode == 0
    )
    run_dir = next((batch_dir / "runs").iterdir())
    garbage = b"PAR1 not parquet at all"
    for name, command in [
        ("trajectories.parquet", ["replay", str(run_dir)]),
        ("summary.json", ["replay", str(run_dir)]),
        ("events.jsonl", ["replay", str(run_dir)]),
        ("results.parquet", ["impact", str(batch_dir)]),
        ("sweep.json", ["impact", str(batch_dir)]),
    ]:
        path = (batch_dir if command[0] == "impact" else run_dir) / name
        kept = path.read_bytes()
        path.write_bytes(garbage if name.endswith("parquet") else b"[1, 2")
        assert_bad_input(sumo_swarm(*command), str(path))
        path.write_bytes(b"[1]\n" if name == "events.jsonl" else b"[]")  # JSON, wrong shape
        if not name.endswith("parquet"):
            assert_bad_input(sumo_swarm(*command), str(path))
        path.write_bytes(kept)


# ------------------------------------------------------------------------------------------
# attach(): its arguments checked as the command line checks them, with typed exceptions


@pytest.fixture
def running(tmp_path):
    """libsumo running a user's case with the sublane model; closed after the test."""
    import libsumo

    from sumo_swarm.sim.bridge import sumo_binary

    def start(*extra: str):
        cfg = write_user_case(tmp_path / "case", HighwaySpec(length_m=800, lanes=3), end_s=20.0)
        libsumo.start([sumo_binary(), "-c", str(cfg), "--no-step-log", "true", *extra])
        return libsumo

    yield start
    libsumo_module = sys.modules.get("libsumo")
    if libsumo_module is not None and libsumo_module.simulation.isLoaded():
        libsumo_module.close()


def test_attach_before_any_simulation_runs():
    import libsumo

    import sumo_swarm

    with pytest.raises(sumo_swarm.SessionError, match="no simulation is running: start SUMO"):
        sumo_swarm.attach(libsumo, cav_type="cav")
    with pytest.raises(RuntimeError):  # a SessionError is a RuntimeError
        sumo_swarm.attach(libsumo, cav_type="cav")


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"cav_ids": "c0"}, "cav_ids must be a list of vehicle ids, got str 'c0'"),
        ({"cav_ids": 7}, "cav_ids must be a list of vehicle ids, got int"),
        ({"cav_ids": []}, "cav_ids is empty"),
        ({"cav_ids": ["c0", 3]}, "a vehicle id must be a non-empty string, got 3"),
        ({"cav_type": ""}, "cav_type must be a vType id"),
        ({"cav_type": "cav", "controller": "swam"}, "did you mean 'swarm'?"),
        ({"cav_type": "cav", "controller": object()}, "controller must be a name"),
        ({"cav_type": "cav", "config": 3}, "config must be a settings file or a Scenario"),
        ({"cav_type": "cav", "out_dir": 3}, "out_dir must be a folder path"),
    ],
)
def test_attach_refuses_bad_arguments(running, kwargs, message):
    import sumo_swarm

    api = running("--lateral-resolution", "0.5")
    with pytest.raises(sumo_swarm.ConfigError, match=re.escape(message)):
        sumo_swarm.attach(api, **kwargs)
    assert api.simulation.isLoaded()


def test_attach_with_a_wrong_cav_type_lists_the_types_present(running):
    import sumo_swarm

    api = running("--lateral-resolution", "0.5")
    with pytest.raises(ValueError, match=re.escape(
        "unknown vType 'cva': did you mean 'cav'? (vTypes in the simulation: car, cav, truck)"
    )):  # fmt: skip
        sumo_swarm.attach(api, cav_type="cva")


def test_attach_without_the_sublane_model_raises_at_once_with_the_fix(running):
    import sumo_swarm

    api = running()  # no --lateral-resolution: every sublane move of the swarm would fail
    with pytest.raises(sumo_swarm.ConfigError, match=re.escape("--lateral-resolution 0.5")):
        sumo_swarm.attach(api, cav_type="cav")
    sumo_swarm.attach(api, cav_type="cav", controller="sumo-lc").detach()  # SUMO changes lanes


def test_attach_to_an_unwritable_out_dir(running, tmp_path):
    import sumo_swarm

    api = running("--lateral-resolution", "0.5")
    blocker = tmp_path / "a file"
    blocker.write_text("")
    with pytest.raises(sumo_swarm.ConfigError, match="cannot be written"):
        sumo_swarm.attach(api, cav_type="cav", out_dir=blocker / "out")


def test_attach_twice_to_one_simulation(running):
    import sumo_swarm

    api = running("--lateral-resolution", "0.5")
    first = sumo_swarm.attach(api, cav_type="cav", controller="cacc")
    api.simulation.step()
    with pytest.raises(sumo_swarm.SessionError, match=r"already \(since t = 0 s\)"):
        sumo_swarm.attach(api, cav_ids=["c0"], controller="cacc")
    first.detach()
    again = sumo_swarm.attach(api, cav_type="cav", controller="cacc")  # after detach: fine
    api.close()
    api = running("--lateral-resolution", "0.5")  # a new simulation: the old swarm is gone
    sumo_swarm.attach(api, cav_type="cav", controller="cacc").detach()
    again.detach()


@pytest.mark.sumo
def test_sumo_refusing_a_scenarios_road_names_the_scenario(tmp_path):
    # The network lets no passenger car drive: SUMO refuses the scene written from the file.
    from tests.conftest import ROOT

    net = tmp_path / "trucks only.net.xml"
    text = (ROOT / "networks" / "highway3.net.xml").read_text(encoding="utf-8")
    net.write_text(text.replace("<lane id=", '<lane allow="truck" id='), encoding="utf-8")
    path = tmp_path / "s.toml"
    path.write_text(
        f'[simulation]\nnetwork = "{net.name}"\nduration_s = 2.0\n[evaluation]\nend_s = 2.0\n'
    )
    proc = sumo_swarm("run", str(path), "--controller", "cacc", "--out", str(tmp_path / "o"))
    assert_bad_input(proc, f"{path}: SUMO stopped: Invalid departLane")


@pytest.mark.sumo
def test_a_special_file_as_a_sumocfg_weight_file_is_refused(tmp_path):
    cfg = write_user_case(tmp_path, HighwaySpec(length_m=500, lanes=3), end_s=2.0)
    weights = _special(tmp_path, "fifo")
    text = cfg.read_text(encoding="utf-8")
    cfg.write_text(text.replace("</input>", f'<weight-files value="{weights.name}"/></input>'))
    proc = sumo_swarm(
        "run", "--sumocfg", str(cfg), "--cav-type", "cav", "--out", str(tmp_path / "o")
    )
    assert_bad_input(proc, "weight-files", SPECIAL["fifo"], str(weights))


@pytest.mark.parametrize("where", ["sumocfg", "out", "batch"])
def test_a_path_sumo_would_read_as_escaped_is_refused_in_one_line(tmp_path, paper_path, where):
    # SUMO reads "%41" in a path as "A" (plain SUMO fails on it too): refused, not a
    # "Process Error" after SUMO's own line.
    folder = tmp_path / ("odd%41name" if where == "sumocfg" else "case")
    cfg = write_user_case(folder, HighwaySpec(length_m=500, lanes=3), end_s=2.0)
    out = tmp_path / ("o%41x" if where != "sumocfg" else "o")
    if where == "batch":
        sweep = tmp_path / "sweep.toml"
        sweep.write_text(f'base = "{paper_path.as_posix()}"\ncontrollers = ["cacc"]\n')
        proc = sumo_swarm("batch", str(sweep), "--out", str(out))
    else:
        proc = sumo_swarm("run", "--sumocfg", str(cfg), "--cav-type", "cav", "--out", str(out))
    assert_bad_input(proc, "SUMO reads '%41' in a path as an escaped character", "%41")


@pytest.mark.sumo
def test_sumo_printing_its_own_errors_at_the_start_is_still_one_line(tmp_path, scenario_file):
    # A network SUMO cannot build: SUMO prints four "Error:" lines itself and libsumo raises
    # only "Process Error". One line, SUMO's first reason, on the network file.
    from tests.conftest import ROOT

    text = (ROOT / "networks" / "highway3.net.xml").read_text(encoding="utf-8")
    net = tmp_path / "no shapes.net.xml"
    net.write_text(re.sub(r' shape="[^"]*"', "", text), encoding="utf-8")
    path = scenario_file(f'[simulation]\nnetwork = "{net.as_posix()}"\n')
    proc = sumo_swarm("run", str(path), "--controller", "cacc", "--out", str(tmp_path / "o"))
    assert_bad_input(
        proc, f"{net}: SUMO refuses it: Attribute 'shape' is missing in definition of lane",
        str(path),
    )  # fmt: skip


# ------------------------------------------------------------------------------------------
# The hostile-input probe of items 4 and 5: each a class of input, refused in one line


@pytest.mark.parametrize("text", ["", "\n\n", "# only a comment\n"])
@pytest.mark.parametrize("role", ["scenario", "config", "sweep"])
def test_an_empty_toml_file_is_refused_not_run_with_every_default(tmp_path, text, role):
    path = tmp_path / "empty.toml"
    path.write_text(text, encoding="utf-8")
    cfg = write_user_case(tmp_path / "case", HighwaySpec(length_m=500, lanes=3), end_s=5.0)
    args = {
        "scenario": ["run", str(path)],
        "config": ["run", "--sumocfg", str(cfg), "--cav-type", "cav", "--config", str(path)],
        "sweep": ["batch", str(path)],
    }[role]
    out = tmp_path / "o"
    assert_bad_input(sumo_swarm(*args, "--out", str(out)), str(path), "is empty")
    assert not out.exists()


@pytest.mark.parametrize(
    ("option", "names"),
    [
        ("additional-files", "user.sumocfg"),  # the configuration itself
        ("route-files", "user.sumocfg"),
        ("additional-files", "other.sumocfg"),  # another configuration
        ("route-files", "routes.rou.xml,other.sumocfg"),
    ],
)
def test_a_sumocfg_named_where_an_input_file_belongs_is_refused(tmp_path, option, names):
    cfg = write_user_case(tmp_path, HighwaySpec(length_m=500, lanes=3), end_s=5.0)
    (tmp_path / "other.sumocfg").write_text(
        '<?xml version="1.0"?>\n<!-- a comment -->\n<sumoConfiguration/>\n', encoding="utf-8"
    )
    text = cfg.read_text(encoding="utf-8")
    text = text.replace('<route-files value="routes.rou.xml"/>', "")
    extra = f'<{option} value="{names}"/>'
    if option != "route-files":
        extra += '<route-files value="routes.rou.xml"/>'
    cfg.write_text(text.replace("<input>", "<input>" + extra), encoding="utf-8")
    which = "the configuration itself" if "user" in names else "a SUMO configuration"
    assert_bad_input(
        sumo_swarm("run", "--sumocfg", str(cfg), "--cav-type", "cav", "--out", str(tmp_path / "o")),
        str(cfg),
        f"{option}:",
        which,
    )


def test_a_sumocfg_in_a_folder_whose_path_holds_a_comma_says_so(tmp_path):
    # SUMO splits its file lists at commas, the folder's name included
    cfg = write_user_case(tmp_path / "roads, v2", HighwaySpec(length_m=500, lanes=3), end_s=5.0)
    assert_bad_input(
        sumo_swarm("run", "--sumocfg", str(cfg), "--cav-type", "cav", "--out", str(tmp_path / "o")),
        str(cfg),
        "holds a comma",
    )


def test_a_sweep_of_a_million_runs_is_refused_before_any_is_built(tmp_path, paper_path):
    sweep = tmp_path / "huge.toml"
    gaps = ", ".join(f"{20.0 + i * 0.001:.3f}" for i in range(1000))
    seeds = ", ".join(str(i) for i in range(1000))
    sweep.write_text(
        f'base = "{paper_path.as_posix()}"\ncontrollers = ["cacc"]\nseeds = [{seeds}]\n'
        f'[grid]\n"scene.upstream_gap_m" = [{gaps}]\n',
        encoding="utf-8",
    )
    t0 = time.perf_counter()
    proc = sumo_swarm("batch", str(sweep), "--out", str(tmp_path / "o"))
    assert_bad_input(proc, str(sweep), "1000000 runs", "more than the 100000")
    assert time.perf_counter() - t0 < 20.0  # built one by one, it took minutes
    assert not (tmp_path / "o").exists()


def _small_sweep(tmp_path, paper_path):
    sweep = tmp_path / "small.toml"
    sweep.write_text(
        f'base = "{paper_path.as_posix()}"\ncontrollers = ["cacc"]\nseeds = [1]\n'
        '[fixed]\n"simulation.duration_s" = 2.0\n"evaluation.end_s" = 2.0\n',
        encoding="utf-8",
    )
    return sweep


@pytest.mark.parametrize(
    ("layout", "fragments"),
    [
        ({"notes.txt": "mine"}, ["holds files that are not a sumo-swarm batch's", "notes.txt"]),
        (
            {"sweep.json": '{"sweep_file": "/elsewhere/other.toml", "runs": ["cacc-s9-x"]}'},
            ["holds the batch of another sweep", "/elsewhere/other.toml"],
        ),
        ({"results.parquet/": None}, ["results.parquet: a folder, where a file"]),
        ({"runs": "a file"}, ["runs: not a folder, where the folder of the runs"]),
    ],
)
def test_a_batch_folder_that_is_not_this_sweeps_is_refused(tmp_path, paper_path, layout, fragments):
    out = tmp_path / "o"
    out.mkdir()
    for name, text in layout.items():
        if name.endswith("/"):
            (out / name).mkdir()
        else:
            (out / name).write_text(text, encoding="utf-8")
    before = sorted(p.name for p in out.iterdir())
    sweep = _small_sweep(tmp_path, paper_path)
    assert_bad_input(sumo_swarm("batch", str(sweep), "--out", str(out)), str(out), *fragments)
    assert sorted(p.name for p in out.iterdir()) == before  # nothing written, nothing removed


@pytest.mark.parametrize("option", [["--config", "x.toml"], ["--cav-type", "cav"]])
def test_a_sumocfg_option_without_sumocfg_is_refused_not_dropped(tmp_path, paper_path, option):
    assert_bad_input(
        sumo_swarm("run", str(paper_path), *option, "--out", str(tmp_path / "o")),
        f"{option[0]} go with --sumocfg",
    )
    assert not (tmp_path / "o").exists()


def test_attach_out_dir_empty_or_a_folder_of_other_files(running, tmp_path):
    import sumo_swarm

    api = running("--lateral-resolution", "0.5")
    with pytest.raises(sumo_swarm.ConfigError, match="out_dir is empty"):
        sumo_swarm.attach(api, cav_type="cav", out_dir="")  # "" would be the working folder
    mine = tmp_path / "project"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine", encoding="utf-8")
    with pytest.raises(sumo_swarm.ConfigError, match="holds files that are not a sumo-swarm run"):
        sumo_swarm.attach(api, cav_type="cav", out_dir=mine)
    assert sorted(p.name for p in mine.iterdir()) == ["notes.txt"]
    sumo_swarm.attach(api, cav_type="cav", out_dir=tmp_path / "new").detach()  # still fine
