"""Every kind of configuration error is refused with the key and the file named."""

from __future__ import annotations

import subprocess
import sys

import pytest

from sumo_swarm.config import load_scenario
from sumo_swarm.errors import ConfigError
from tests.conftest import ROOT


def test_paper_scenario_holds_section_iv_c(paper_path):
    sc = load_scenario(paper_path)
    assert sc.name == "paper"
    assert sc.cav.count == 6
    assert sc.cav.length_m == 5.0
    assert sc.cav.cruising_speed_mps == 20.0
    assert sc.cav.min_gap_m == 5.0 and sc.cav.desired_gap_m == 10.0
    assert (sc.cav.accel_min_mps2, sc.cav.accel_max_mps2) == (-4.0, 3.0)
    assert sc.simulation.step_length_s == 0.03
    assert sc.planner.behaving_interval_s == 3.0
    assert sc.scene.upstream_gap_m == 25.0
    assert sc.hv.headway_s == 1.2
    # l_CAV + desired safety distance (paper II-B-1), not IV-C's 5 m: see scenarios/paper.toml
    assert sc.cell_length_m == 15.0
    assert sc.network_path.is_file()


@pytest.mark.parametrize(
    ("body", "expected"),
    [
        ('[cav]\ncount = 6\ncolour = "red"\n', "unknown key 'cav.colour'"),
        ("[cav]\ncount = 6.5\n", "cav.count: expected an integer"),
        ('[cav]\nlength_m = "long"\n', "cav.length_m: expected a number"),
        ("[cav]\nlength_m = -5.0\n", "length_m must be > 0"),
        ("[cav]\ncount = 0\n", "count must be >= 1"),
        ("[simulation]\nstep_length_s = 0.0\n", "step_length_s must be > 0"),
        ("[cav]\nmin_gap_m = 12.0\n", "desired_gap_m (10.0) must be >= min_gap_m"),
        ("[hv]\nlane_changes = 1\n", "hv.lane_changes: expected true or false"),
        ('[cell]\nrule = "tiny"\n', "cell.rule: must be one of"),
        (
            "[grid]\ncell_length_m = 9.0\n",
            "grid.cell_length_m is not set here: it comes from [cell]",
        ),
        ("[lateral]\nwheelbase_m = 3.0\n", "lateral.wheelbase_m is not set here"),
        ("[hvmodel]\nplanner_share = 1.5\n", "planner_share must be <= 1"),
        ("[swarm]\ncontrol_interval_s = 0.0\n", "control_interval_s must be > 0"),
        ("[planner]\nregroup_lane = -1\n", "regroup_lane must be an integer >= 0"),
        ("[guards]\nclearing_mps = -0.5\n", "clearing_mps must be >= 0"),
        ("[swarm]\nkeep_right_wait_s = -1\n", "keep_right_wait_s"),
        ("[swarm]\npass_open_side_s = 1.0\n", "unknown key 'swarm.pass_open_side_s'"),
        ('[cell]\nrule = "fixed"\ncell_length_m = 2.0\n', "must be at least as long as a CAV"),
        ("[bogus]\nx = 1\n", "unknown section '[bogus]'"),
        ("[evaluation]\nend_s = 500.0\n", "is after simulation.duration_s"),
        ("[planner]\nbehaving_interval_s = 0.1\n", "whole number of"),
        ("[planner]\nn_steps = 1\n", "n_steps"),
        ('[simulation]\nnetwork = "nowhere.net.xml"\n', "simulation.network: file not found"),
        ('[[scene.hv]]\nid = "a"\nlane = 1\nfront_m = 10.0\nspeed = 3.0\n', "unknown key"),
    ],
)
def test_bad_values_are_refused_naming_key_and_file(scenario_file, body, expected):
    head = '[simulation]\nnetwork = "@NET@"\n' if "[simulation]" not in body else ""
    text = head + body
    if "[simulation]" in body and "network" not in body:
        text = body.replace("[simulation]\n", '[simulation]\nnetwork = "@NET@"\n')
    path = scenario_file(text)
    with pytest.raises(ConfigError) as err:
        load_scenario(path)
    message = str(err.value)
    assert expected in message
    assert str(path) in message


# [swarm] keys deleted in issue 51: switches whose alternative lost (the default stays),
# tuning numbers no scenario set (now constants beside their code) and regroup_lane, the
# [planner] key of the same name spelt twice. A file that still sets one is refused like any
# unknown key, not silently ignored.
REMOVED_SWARM_KEYS = (
    "regroup_lane",
    "regroup_by", "regroup_anywhere", "regroup_grid_speed", "catch_up_across_lanes",
    "pass_in_train", "control_interval_steps", "replan_min_interval_s", "max_pass_s",
    "pass_switch_s", "pass_open_side_s", "drop_behind_s", "pass_intruder_mps", "pass_reach_s",
    "run_up_gap_m", "run_up_after_s", "run_up_commit_s", "run_up_drop_mps", "entry_accel_mps2",
    "pull_away_after_s", "pull_away_mps", "reform_switch_s", "block_assist_after_s",
    "block_assist_mps", "max_block_s", "wait_ahead_s", "wait_lead_m", "max_leader_ease_mps",
    "regroup_ease_mps", "drift_rows", "retry_after_s", "replan_every_intervals",
    "prediction_error_m", "give_up_no_progress_intervals", "give_up_partial_intervals",
    "give_up_stranded_plans", "give_up_waiting_plans", "give_up_waiting_s", "give_up_no_plan_s",
    "progress_step_m", "match_lookahead_s", "hold_episode_s", "lane_end_hold_s",
    "lane_end_escape_s", "lane_end_min_m", "lane_shift_hold_m", "cap_decel_mps2",
)  # fmt: skip


@pytest.mark.parametrize("key", REMOVED_SWARM_KEYS)
def test_a_removed_swarm_key_is_an_unknown_key(scenario_file, key):
    path = scenario_file(f'[simulation]\nnetwork = "@NET@"\n[swarm]\n{key} = 1\n')
    with pytest.raises(ConfigError, match=f"unknown key 'swarm.{key}'"):
        load_scenario(path)


def test_a_removed_swarm_key_in_a_run_exits_2_with_one_line(tmp_path, paper_path):
    scenario = tmp_path / "old.toml"
    text = paper_path.read_text(encoding="utf-8").replace(
        'network = "', f'network = "{paper_path.parent.as_posix()}/', 1
    )
    scenario.write_text(text + '\n[swarm]\nregroup_by = "planner"\n', encoding="utf-8")
    proc = subprocess.run(
        [sys.executable, "-m", "sumo_swarm", "run", str(scenario), "--out", str(tmp_path / "o")],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "unknown key 'swarm.regroup_by'" in lines[0]
    assert str(scenario) in lines[0] and not (tmp_path / "o").exists()


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="scenario file not found"):
        load_scenario(tmp_path / "nope.toml")


def test_malformed_toml(scenario_file):
    path = scenario_file("[cav\ncount = 3\n")
    with pytest.raises(ConfigError, match="malformed TOML"):
        load_scenario(path)


def test_overrides_are_validated_too(paper_path):
    sc = load_scenario(paper_path, overrides={"cav": {"count": 4}})
    assert sc.cav.count == 4
    with pytest.raises(ConfigError, match=r"unknown key 'cav\.cnt'"):
        load_scenario(paper_path, overrides={"cav": {"cnt": 4}})


def test_one_source_for_each_physical_quantity(tmp_path, paper_path):
    """The grid and the lateral MPC take the cell length, CAV length, wheelbase and steering
    range from [cell] and [cav]; keys nothing reads are refused instead of ignored."""
    import math

    text = paper_path.read_text().replace(
        'network = "../networks/', f'network = "{paper_path.parent.parent}/networks/'
    )
    text += "\n[cav]\n" if "[cav]" not in text else ""
    text = text.replace("steering_ratio = 15.0", "steering_ratio = 10.0")
    path = tmp_path / "s.toml"
    path.write_text(text)
    sc = load_scenario(path)
    assert sc.grid.cell_length_m == sc.cell_length_m == 15.0
    assert sc.grid.cav_length_m == sc.cav.length_m
    assert sc.lateral.wheelbase_m == sc.cav.wheelbase_m
    assert sc.lateral.delta_max == pytest.approx(math.radians(450.0 / 10.0))
    assert sc.lateral.delta_min == -sc.lateral.delta_max


def test_a_settings_file_for_a_sumocfg_is_not_held_to_the_papers_step(tmp_path):
    # The swarm's settings for a user's sumocfg (run --config, attach(config=...)) run at the
    # sumocfg's step (0.1 s, 1 s, ...); the 0.03 s default step of a scenario file does not apply.
    from sumo_swarm.sim.scene import default_settings

    path = tmp_path / "mine.toml"
    path.write_text("[planner]\nbehaving_interval_s = 2.0\n", encoding="utf-8")
    assert default_settings(path).planner.behaving_interval_s == 2.0
    # A file that names its step is still checked against it.
    path.write_text(
        "[simulation]\nstep_length_s = 0.3\n[planner]\nbehaving_interval_s = 2.0\n",
        encoding="utf-8",
    )
    with pytest.raises(ConfigError, match="whole number of"):
        default_settings(path)


def test_a_copied_scenario_finds_its_network_by_name(tmp_path):
    """A copy of the paper's scenario runs wherever it is: a network path that does not resolve
    beside the copy falls back to the built-in network of that file name."""
    import shutil

    from sumo_swarm.config import BUILT_IN_NETWORKS

    for source in (ROOT / "scenarios" / "paper.toml", BUILT_IN_NETWORKS / "paper.toml"):
        copy = tmp_path / source.parent.name / "my.toml"
        copy.parent.mkdir()
        shutil.copy(source, copy)
        sc = load_scenario(copy)
        assert sc.network_path == BUILT_IN_NETWORKS / "highway3.net.xml"
    # a network beside the copy is the one used
    (tmp_path / "data" / "highway3.net.xml").write_bytes(
        (BUILT_IN_NETWORKS / "highway3.net.xml").read_bytes()
    )
    assert (
        load_scenario(tmp_path / "data" / "my.toml").network_path
        == (tmp_path / "data" / "highway3.net.xml").resolve()
    )
    # a name that is not built in is still refused, naming the file
    text = (tmp_path / "data" / "my.toml").read_text().replace("highway3.net.xml", "mine.net.xml")
    (tmp_path / "data" / "bad.toml").write_text(text)
    with pytest.raises(ConfigError, match=r"bad.toml: simulation.network: file not found"):
        load_scenario(tmp_path / "data" / "bad.toml")
