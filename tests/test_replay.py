"""`sumo-swarm replay`: what the frames draw, the files written, and bad input (real SUMO run)."""

from __future__ import annotations

import math
import re
import shutil
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
from matplotlib.colors import to_rgba
from PIL import Image

from sumo_swarm.cli import main
from sumo_swarm.config import load_scenario
from sumo_swarm.sim.runner import run_scenario
from sumo_swarm.study.replay import (
    FRAME_PX,
    ROLE_COLOURS,
    Renderer,
    TextStamps,
    _view_length,
    frame_times,
    load_run,
    vehicle_polygons,
)
from tests.conftest import PAPER

# The paper scene cut to 16 s: the first plan (t = 3.03 s, two blockers) and the replan after it.
SHORT = {"simulation": {"duration_s": 16.0}, "evaluation": {"end_s": 16.0}}


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("run")
    run_scenario(load_scenario(PAPER, overrides=SHORT), "swarm", out)
    return out


@pytest.fixture(scope="module")
def run(run_dir):
    return load_run(run_dir)


# ------------------------------------------------------------------------------ pure parts


def test_vehicle_polygons_from_the_front_bumper():
    # east-bound: front at (10, 0), 5 m long, 2 m wide
    quad = vehicle_polygons(*(np.array([v]) for v in (10.0, 0.0, 0.0, 5.0, 2.0)))[0]
    assert np.allclose(quad, [[10, 1], [10, -1], [5, -1], [5, 1]])
    # north-bound: the body hangs south of the front bumper, its left side is -x
    quad = vehicle_polygons(*(np.array([v]) for v in (0.0, 10.0, math.pi / 2, 5.0, 2.0)))[0]
    assert np.allclose(quad, [[-1, 10], [1, 10], [1, 5], [-1, 5]])


def test_text_stamps_draw_where_asked():
    stamps = TextStamps(12.0)
    image = np.zeros((60, 120, 4), np.uint8)
    stamps.stamp(image, "17.5", 60.0, 30.0, (255, 255, 255), centred=True)
    rows, cols = np.nonzero(image[..., 0] > 128)
    assert len(rows) > 20  # the digits are there, in white
    assert abs(cols.mean() - 60.0) < 3.0 and abs(rows.mean() - 30.0) < 3.0
    assert cols.max() - cols.min() == pytest.approx(stamps.width_px("17.5"), abs=3.0)
    assert len(stamps.glyphs) == 4  # one glyph per character...
    stamps.stamp(image, "5.1", -3.0, 55.0, (255, 0, 0))  # ...reused; clipped at the corner
    assert len(stamps.glyphs) == 4
    assert (image[50:, :8, 0] > 128).any()
    assert (image[..., 3] == 0).all()  # the alpha channel is left alone


# ------------------------------------------------------------------------------ a real run


def colours_of(collection) -> list[tuple[float, ...]]:
    return [tuple(np.round(c, 3)) for c in collection.get_facecolors()]


def rgba(role: str) -> tuple[float, ...]:
    return tuple(np.round(to_rgba(ROLE_COLOURS[role]), 3))


@pytest.mark.sumo
def test_run_inputs_are_read(run):
    assert run.target == "hv_target"
    assert run.plans and run.plans[0].blockers == {"cav0": "hv_left", "cav1": "hv_right"}
    assert run.plans[0].until_s <= (run.plans[1].time_s if len(run.plans) > 1 else math.inf)
    assert set(run.df["width_m"]) == {1.8}  # from the vTypes of sumo/routes.rou.xml
    # headings follow the motion: 0 on a straight lane, a few degrees while changing lanes
    cav = run.df[run.df["kind"] == "cav"]
    assert 1.0 < np.degrees(np.abs(cav["heading_rad"])).max() < 15.0
    assert np.abs(run.df.loc[run.df["vehicle"] == "hv_target", "heading_rad"]).max() < 1e-6


@pytest.mark.sumo
def test_frame_draws_lanes_vehicles_roles_and_the_plan(run):
    r = Renderer(run, None, _view_length(run, None))
    # highway3: lanes 3 m wide, centres at y -7.5, -4.5, -1.5 -> edges at -9 and 0, marks -6, -3
    outer, marks = (c.get_segments() for c in r.animated[1:3][::-1])
    assert sorted(round(float(seg[0][1]), 6) for seg in marks) == [-6.0, -3.0]
    assert sorted(round(float(seg[0][1]), 6) for seg in outer) == [-9.0, 0.0]

    r.frame(1.0)  # before the decision: no plan, no roles but the target
    faces = colours_of(r.vehicles)
    assert faces.count(rgba("target")) == 1
    assert faces.count(rgba("blocker")) == 0 and faces.count(rgba("blocked")) == 0
    assert len(r.plan_cells.get_paths()) == 0 and len(r.grid_cells.get_paths()) == 0
    assert r.plan_line.get_text() == "no plan in force"

    frame = r.frame(6.0)  # the first plan: cav0 and cav1 block hv_left and hv_right
    assert frame.shape == (FRAME_PX[1], FRAME_PX[0], 4)
    faces = colours_of(r.vehicles)
    assert faces.count(rgba("blocker")) == 2 and faces.count(rgba("blocked")) == 2
    assert faces.count(rgba("cav")) == 4
    plan = run.plans[0]
    assert len(r.grid_cells.get_paths()) == plan.grid["n_rows"] * plan.grid["n_cols"]
    assert len(r.plan_cells.get_paths()) == 6  # one cell per CAV
    assert "cav0 blocks hv_left" in r.plan_line.get_text()
    assert "t =   6.00 s" in r.header_text
    # speeds written on the CAVs, the target and the blocked HVs, each on its vehicle
    assert len(r.labels) == 9
    to_px = (r.camera + r.ax.transData).transform
    assert all(re.fullmatch(r"\d+\.\d", text) for text, _, _ in r.labels)
    centres_px = to_px(np.array([p.vertices[:4].mean(axis=0) for p in r.vehicles.get_paths()]))
    for _, x_px, y_px in r.labels:
        d = np.hypot(centres_px[:, 0] - x_px, centres_px[:, 1] - (FRAME_PX[1] - y_px))
        assert d.min() < 0.5
    # every vehicle to scale: 5 m x 1.8 m
    for path in r.vehicles.get_paths():
        sides = np.hypot(*np.diff(path.vertices[:5], axis=0).T)
        assert sorted(np.round(sides, 6))[::2] == [1.8, 5.0]
    # the camera is on the swarm: the middle of the CAVs, between the road's edges
    rows = run.rows_at(6.0)
    s_cav = run.col["s_m"][rows][run.is_cav[rows]]
    cx, cy, heading = r.camera_at(rows)
    assert cx == pytest.approx(0.5 * (s_cav.min() + s_cav.max()))
    assert cy == pytest.approx(-4.5) and heading == pytest.approx(0.0)


@pytest.mark.sumo
def test_follow_puts_the_vehicle_in_the_middle(run):
    r = Renderer(run, "hv_right", _view_length(run, "hv_right"))
    rows = run.rows_at(10.0)
    i = rows.start + int(np.flatnonzero(run.vehicle[rows] == "hv_right")[0])
    cx, cy, _ = r.camera_at(rows)
    assert cx == pytest.approx(run.col["x_m"][i] - 2.5)  # its centre, 2.5 m behind the front
    assert cy == pytest.approx(-7.5)


@pytest.mark.sumo
def test_frame_times(run):
    times = frame_times(run, 2.0, 4.0, 5.0)
    assert np.allclose(times, [2.0, 2.2, 2.4, 2.6, 2.8, 3.0, 3.2, 3.4, 3.6, 3.8, 4.0])
    whole = frame_times(run, None, None, 10.0)
    assert whole[0] == pytest.approx(run.times_s[0]) and whole[-1] <= run.times_s[-1]


@pytest.mark.sumo
def test_mp4_and_gif_are_written(run_dir, tmp_path, capsys):
    mp4 = tmp_path / "r.mp4"
    assert (
        main(["replay", str(run_dir), "--out", str(mp4), "--from", "5", "--to", "7", "--fps", "5"])
        == 0
    )
    assert "11 frames" in capsys.readouterr().out
    frames = iio.imread(mp4, plugin="FFMPEG", index=None)  # imageio over imageio-ffmpeg
    assert len(frames) == 11 and frames[0].shape[:2] == (FRAME_PX[1], FRAME_PX[0])
    # the target's red is in the picture (video compression shifts colours a little)
    red = np.array([214, 39, 40])
    assert (np.abs(frames[5][..., :3].astype(int) - red).sum(axis=-1) < 60).sum() > 100

    gif = tmp_path / "r.gif"
    assert (
        main(["replay", str(run_dir), "--out", str(gif), "--from", "5", "--to", "6", "--fps", "4"])
        == 0
    )
    with Image.open(gif) as im:
        assert im.n_frames == 5 and im.size == FRAME_PX
        assert im.info["duration"] == 250 and im.info["loop"] == 0
        im.seek(2)
        pixels = np.asarray(im.convert("RGB")).reshape(-1, 3).astype(int)
        assert (np.abs(pixels - red).sum(axis=-1) < 30).sum() > 100
    assert not list(tmp_path.glob("*.tmp.*"))  # no half-written file left


# ------------------------------------------------------------------------------ bad input


def assert_bad_input(code: int, capsys, *fragments: str) -> None:
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    for fragment in fragments:
        assert fragment in lines[0], lines[0]


def test_missing_run_dir(tmp_path, capsys):
    missing = tmp_path / "nope"
    assert_bad_input(main(["replay", str(missing)]), capsys, "not found", str(missing))


def test_run_dir_without_trajectories(tmp_path, capsys):
    assert_bad_input(main(["replay", str(tmp_path)]), capsys, "trajectories.parquet", str(tmp_path))


@pytest.mark.sumo
def test_unknown_vehicle_extension_and_range(run_dir, tmp_path, capsys):
    code = main(["replay", str(run_dir), "--follow", "ghost", "--out", str(tmp_path / "a.mp4")])
    assert_bad_input(code, capsys, "ghost", "trajectories.parquet")
    code = main(["replay", str(run_dir), "--out", str(tmp_path / "a.avi")])
    assert_bad_input(code, capsys, "a.avi", ".mp4 or .gif")
    code = main(["replay", str(run_dir), "--from", "9", "--to", "3"])
    assert_bad_input(code, capsys, "--from")
    code = main(["replay", str(run_dir), "--fps", "0"])
    assert_bad_input(code, capsys, "--fps")


@pytest.mark.sumo
def test_missing_network(run_dir, tmp_path, capsys):
    copy = tmp_path / "run"
    shutil.copytree(run_dir, copy)
    shutil.rmtree(copy / "sumo")
    assert_bad_input(main(["replay", str(copy)]), capsys, "sumo", str(copy))


# ------------------------------------------------------------------ targets and the first frame


def test_every_manoeuvres_target_is_marked():
    from sumo_swarm.study.replay import manoeuvre_targets

    with_list = {
        "overtake": {"target": "truck", "targets": ["truck"]},
        "manoeuvres": [
            {"kind": "cells", "target": "truck"},
            {"kind": "lane_pass", "target": "bus"},
            {"kind": "wait", "target": None},
            {"kind": "one_by_one", "target": "truck"},
        ],
    }
    assert manoeuvre_targets(with_list) == ("truck", ("truck", "bus"))
    # summaries written before the manoeuvres list: overtake.targets, then overtake.target
    assert manoeuvre_targets({"overtake": {"target": "t", "targets": ["t", "car.1"]}}) == (
        "t",
        ("t", "car.1"),
    )
    assert manoeuvre_targets({"overtake": {"target": "t"}}) == ("t", ("t",))
    assert manoeuvre_targets({}) == (None, ())


def test_replay_starts_where_the_first_cav_appears():
    import pandas as pd

    from sumo_swarm.study.replay import RunRecord

    rows = [  # an HV from 0 s, a CAV from 12 s
        {"time_s": t, "vehicle": v, "kind": k, "x_m": t, "y_m": 0.0, "s_m": t,
         "speed_mps": 10.0, "length_m": 5.0, "width_m": 1.8, "heading_rad": 0.0}
        for t in np.arange(0.0, 20.0, 1.0)
        for v, k in (("hv0", "hv"), ("cav0", "cav"))
        if k == "hv" or t >= 12.0
    ]  # fmt: skip
    df = pd.DataFrame(rows)
    times, starts = np.unique(df["time_s"].to_numpy(), return_index=True)
    run = RunRecord(Path("."), df, times, np.r_[starts, len(df)], "hv0", [], None, [], "", ("bus",))
    assert run.targets == ("hv0", "bus")
    assert frame_times(run, None, None, 1.0)[0] == pytest.approx(12.0)
    assert frame_times(run, 3.0, None, 1.0)[0] == pytest.approx(3.0)  # --from still wins
    r = Renderer.__new__(Renderer)
    r.run = run
    assert r.roles(np.array(["hv0", "bus", "car", "cav0"]), np.array([0, 0, 0, 1], bool), None) == [
        "target",
        "target",
        "hv",
        "cav",
    ]
