"""tools/user_roads.py: its measures on hand-made trajectories, and a run the CLI refuses
(exit 2) recorded as refused."""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import pytest

from tests.toolload import load_tool

ROOT = Path(__file__).resolve().parent.parent


ur = load_tool("user_roads")


def _rows(samples: list[tuple[float, str, str, float]]) -> pd.DataFrame:
    return pd.DataFrame(samples, columns=["time_s", "vehicle", "kind", "s_m"])


def test_cavs_past_truck_counts_ever_and_at_the_end():
    df = _rows(
        [
            # a passes the truck at t = 2 and stays ahead
            (0.0, "truck", "hv", 100.0), (0.0, "a", "cav", 80.0), (0.0, "b", "cav", 60.0),
            (1.0, "truck", "hv", 110.0), (1.0, "a", "cav", 105.0), (1.0, "b", "cav", 115.0),
            (2.0, "truck", "hv", 120.0), (2.0, "a", "cav", 130.0), (2.0, "b", "cav", 118.0),
            # c is never beside the truck in time: it does not count
            (3.0, "c", "cav", 500.0),
        ]
    )  # fmt: skip
    # a: ahead at the end; b: ahead at t = 1 only; c: never seen with the truck
    assert ur.cavs_past_truck(df) == (2, 1)
    assert ur.cavs_past_truck(df[df["vehicle"] != "truck"]) == (0, 0)


def test_ratios_of_speed_and_wall_time():
    rows = pd.DataFrame(
        {
            "controller": ["swarm", "sumo-cacc", "sumo-lc", "cacc"],
            "status": ["ok", "ok", "ok", "refused"],
            "cav_mean_speed_mps": [20.0, 16.0, 25.0, math.nan],
            "wall_s": [9.0, 3.0, 2.0, math.nan],
        }
    )
    assert ur.ratios(rows) == {
        "speed swarm/sumo-cacc": pytest.approx(1.25),
        "speed swarm/sumo-lc": pytest.approx(0.8),
        "wall swarm/sumo-cacc": pytest.approx(3.0),
    }
    refused = rows.assign(status=["refused", "ok", "ok", "ok"])
    assert all(math.isnan(v) for v in ur.ratios(refused).values())


def test_brake_lines_one_per_vehicle():
    episodes = pd.DataFrame(
        {
            "vehicle": ["c0", "c1", "c0"],
            "start_s": [1.0, 2.0, 5.0],
            "end_s": [1.2, 2.0, 5.5],
            "min_accel_mps2": [-4.2, -4.5, -4.8],
        }
    )
    assert ur.brake_lines(episodes) == [
        "c0: 2 episode(s), 1.0-5.5 s, strongest -4.80 m/s^2",
        "c1: 1 episode(s), 2.0-2.0 s, strongest -4.50 m/s^2",
    ]


def test_a_run_the_cli_refuses_is_recorded_as_refused(tmp_path):
    cfg = tmp_path / "user.sumocfg"
    cfg.write_text('<configuration><input><net-file value="missing.net.xml"/></input>'
                   "</configuration>\n")  # fmt: skip
    row = ur.run_job(ur.Job("r", "0.1", "swarm", cfg, tmp_path / "out"), timeout_s=120)
    assert row["status"] == "refused"
    assert "missing.net.xml" in row["message"]


def test_over_seeds_sums_up_each_road_and_step():
    def run(seed, controller, speed, **kw):
        row = {"road": "3-lane-900", "step_s": "0.1", "seed": seed, "controller": controller,
               "status": "ok", "cav_mean_speed_mps": speed, "wall_s": 1.0}  # fmt: skip
        return {**row, **kw}

    swarm = dict(cav_count=5, collisions=0, hard_brakes_cav=0)
    df = pd.DataFrame([
        run("1", "swarm", 27.0, cavs_passed_truck=5, regrouped=True, **swarm),
        run("1", "sumo-lc", 30.0), run("1", "sumo-cacc", 15.0),
        run("2", "swarm", 24.0, cavs_passed_truck=4, regrouped=True, **swarm),
        run("2", "sumo-lc", 30.0), run("2", "sumo-cacc", 16.0),
    ])  # fmt: skip
    (row,) = ur.over_seeds(df).to_dict("records")
    assert row["seeds"] == 2
    assert row["swarm/sumo-lc mean"] == pytest.approx(0.85)  # (0.9 + 0.8) / 2
    assert row["swarm/sumo-lc min"] == pytest.approx(0.8)
    assert row["runs >= 0.9x sumo-lc"] == 1
    assert row["swarm/sumo-cacc min"] == pytest.approx(1.5)  # 24 / 16
    assert row["all past and regrouped"] == 1  # seed 2 left a CAV behind the truck
    assert row["collisions"] == 0 and row["CAV hard brakes"] == 0
    assert "## Over the seeds" in ur.markdown(df.assign(commit="abc"), "cmd", 90.0)
    assert "## Over the seeds" not in ur.markdown(
        df[df["seed"] == "1"].assign(commit="abc"), "cmd", 90.0
    )


def test_table_files_keep_a_dot_in_the_name():
    # --table /work/runs/cost0.5 wrote cost0.md and cost0.csv (Path.with_suffix), and the
    # table of the next step's run (cost0.2) overwrote them.
    assert ur.table_file(Path("runs/cost0.5"), ".md") == Path("runs/cost0.5.md")
    assert ur.table_file(Path("runs/cost0.5"), ".runs.csv") == Path("runs/cost0.5.runs.csv")
    assert ur.table_file(Path("docs/bench/user_roads"), ".csv") == Path("docs/bench/user_roads.csv")
    assert ur.table_file(Path("t.md"), ".csv") == Path("t.csv")  # an extension given: replaced
