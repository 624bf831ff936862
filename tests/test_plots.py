"""What the figures draw (matplotlib objects, checked on a real swarm run of the paper scene):
Fig. 8(b) to scale with named lanes, Fig. 12's speed axes and off-scale note, event labels
clear of the curves."""

from __future__ import annotations

import json

import numpy as np
import pytest
from matplotlib.text import Annotation

from sumo_swarm.config import load_scenario
from sumo_swarm.core.model import RoadSection
from sumo_swarm.sim.runner import run_scenario
from sumo_swarm.sim.scene import build_scene
from sumo_swarm.study import plots
from tests.conftest import PAPER

# The paper scene to 40 s: decision, all CAVs past and regrouped all happen (at about 3, 27, 36 s).
UNTIL_REGROUPED = {"simulation": {"duration_s": 45.0}, "evaluation": {"end_s": 45.0}}


@pytest.fixture(scope="module")
def paper_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("swarm")
    scenario = load_scenario(PAPER, overrides=UNTIL_REGROUPED)
    run_scenario(scenario, "swarm", out)
    summary = json.loads((out / "summary.json").read_text())
    return scenario, plots.RunData("swarm", out, summary)


# ------------------------------------------------------------------------------ pure helpers


@pytest.mark.parametrize(
    ("data", "expected"),
    [
        ((17.40, 17.81), (15.5, 19.5)),  # sub-1 % changes: 4 m/s around the data
        ((17.3, 21.9), (17.0, 23.0)),  # wide data: whole m/s with a margin
        ((0.5, 1.0), (0.0, 4.0)),  # near standstill: not below 0
    ],
)
def test_speed_limits(data, expected):
    assert plots.speed_limits(*data) == expected


def test_largest_gap():
    assert plots._largest_gap([(0.1, 0.3), (0.5, 0.6)], pad=0.0) == (0.6, 1.0)
    assert plots._largest_gap([(0.0, 0.2), (0.7, 1.0)], pad=0.0) == (0.2, 0.7)
    low, high = plots._largest_gap([(0.0, 1.0)], pad=0.0)
    assert high - low == 0.0


# ------------------------------------------------------------------------------ a real run


def road_of(scenario) -> RoadSection:
    return RoadSection(plots.lane_widths_m(scenario))


@pytest.mark.sumo
def test_fig8_snapshots_are_to_scale_with_named_lanes(paper_run):
    scenario, run = paper_run
    widths = {"cav": scenario.cav.width_m, "hv": scenario.hv.width_m}
    fig = plots.draw_trajectories(run.df, run.summary, road_of(scenario), widths)
    fig.canvas.draw()
    snapshots = fig.axes[1:]
    # decision, +3 s, +9 s, all CAVs past (and regrouped, when that is within the run)
    end_s = UNTIL_REGROUPED["simulation"]["duration_s"]
    assert len(snapshots) == len(plots.snapshot_times(run.summary, end_s)) >= 4
    for ax in snapshots:
        assert ax.get_ylabel() == "lane"
        assert [t.get_text() for t in ax.get_yticklabels()] == ["right", "middle", "left"]
        # to scale: a metre along the road is as long on the page as a metre across it
        (x0, y0), (x1, _), (_, y1) = ax.transData.transform([(0, 0), (10, 0), (0, 10)])
        assert abs(x1 - x0) == pytest.approx(abs(y1 - y0), rel=0.01)
        cars = [p for p in ax.patches if p.get_facecolor()[:3] != (1.0, 1.0, 1.0)]
        assert {(round(p.get_width(), 6), round(p.get_height(), 6)) for p in cars} == {(5.0, 1.8)}
        # the six CAVs and the slow HV are all in the window
        lo, hi = ax.get_xlim()
        colours = [p.get_facecolor()[:3] for p in cars if lo <= p.get_x() <= hi - p.get_width()]
        target = tuple(int(plots.TARGET_COLOUR[i : i + 2], 16) / 255 for i in (1, 3, 5))
        assert sum(np.allclose(c, target) for c in colours) == 1
        cav_colours = {
            tuple(int(c[i : i + 2], 16) / 255 for i in (1, 3, 5)) for c in plots.CAV_COLOURS[:6]
        }
        assert sum(any(np.allclose(c, k) for k in cav_colours) for c in colours) == 6


def fig12(scenario, run):
    adjacent: dict[int, list[str]] = {}
    for v in build_scene(scenario).vehicles:
        if v.role == "adjacent":
            adjacent.setdefault(v.lane, []).append(v.id)
    return plots.draw_upstream(
        run.df,
        run.summary,
        adjacent,
        3,
        scenario.hv.headway_s,
        scenario.scene.upstream_speed_mps,
    )


@pytest.mark.sumo
def test_fig12_speed_axes_do_not_magnify_small_changes(paper_run):
    fig = fig12(*paper_run)
    speed_axes = fig.axes[:3]  # the top row: left, middle, right lane
    limits = {ax.get_ylim() for ax in speed_axes}
    assert len(limits) == 1  # shared, so the lanes compare at a glance
    low, high = limits.pop()
    assert high - low >= plots.MIN_SPEED_SPAN_MPS
    assert low == int(low) or low * 2 == int(low * 2)  # ends on whole or half m/s
    for ax in speed_axes:  # and every curve fits
        for line in ax.get_lines():
            if line.get_gid() != plots.EVENT_GID:
                y = np.asarray(line.get_ydata(), dtype=float)
                assert np.nanmin(y) >= low and np.nanmax(y) <= high


@pytest.mark.sumo
def test_fig12_off_scale_vehicle_is_a_note_not_a_fragment(paper_run):
    fig = fig12(*paper_run)
    gap_axes = fig.axes[3:]
    notes = [
        (ax, t.get_text()) for ax in gap_axes for t in ax.texts if "off the scale" in t.get_text()
    ]
    assert notes, "the blocked HVs' gaps grow off the scale in the paper scene"
    for ax, note in notes:
        vehicle = note.split(" ")[0]
        drawn = [line.get_label() for line in ax.get_lines()]
        assert not [label for label in drawn if vehicle in label]
        # still in the lane's legend (its speed is drawn above)
        assert any(vehicle in t.get_text() for t in ax.get_legend().get_texts())
        # every gap drawn stays within the axis
        high = ax.get_ylim()[1]
        for line in ax.get_lines():
            y = np.asarray(line.get_ydata(), dtype=float)
            if line.get_gid() != plots.EVENT_GID and len(y) > 2:
                assert np.nanmax(y) <= high


def labels_clear_of_curves(fig) -> int:
    """Check every event label against the curves of its axes (drawn, in pixels); return the
    number of labels checked."""
    renderer = fig.canvas.get_renderer()
    fig.canvas.draw()
    checked = 0
    for ax in fig.axes:
        for text in ax.texts:
            if not isinstance(text, Annotation) or text.get_rotation() != 90:
                continue
            box = text.get_window_extent(renderer)
            xs = np.linspace(box.x0, box.x1, 12)
            for line in ax.get_lines():
                if line.get_gid() == plots.EVENT_GID:
                    continue
                pts = line.get_transform().transform(line.get_xydata())
                pts = pts[np.isfinite(pts).all(axis=1)]
                if len(pts) < 2 or not (np.diff(pts[:, 0]) >= 0).all():
                    continue
                inside = (pts[:, 0] >= xs[0]) & (pts[:, 0] <= xs[-1])
                ys = np.concatenate(
                    [pts[inside, 1], np.interp(xs, pts[:, 0], pts[:, 1], left=np.nan, right=np.nan)]
                )
                ys = ys[np.isfinite(ys)]
                hits = (ys > box.y0 + 1) & (ys < box.y1 - 1)
                assert not hits.any(), f"'{text.get_text()}' sits on {line.get_label()}"
            checked += 1
    return checked


@pytest.mark.sumo
def test_event_labels_do_not_sit_on_the_curves(paper_run):
    scenario, run = paper_run
    assert labels_clear_of_curves(fig12(scenario, run)) == 3
    fig9 = plots.draw_speeds({"swarm": run}, "swarm", (0.0, 40.0), {"swarm": 20.0})
    assert labels_clear_of_curves(fig9) == 3
    fig10 = plots.draw_gaps(run.df, run.summary, 2.0, 10.0, (0.0, 40.0))
    assert labels_clear_of_curves(fig10) == 3


def test_event_label_finds_the_free_stretch():
    # curves hug the top and the bottom: the label goes between them, not at the top
    fig = plots._new_figure(6.0, 3.0)
    ax = fig.subplots()
    ax.plot([0.0, 10.0], [9.4, 9.6])
    ax.plot([0.0, 10.0], [1.0, 1.0])
    ax.axhline(5.0)  # a reference line across the middle: the label avoids it too
    ax.set_xlim(0.0, 10.0)
    ax.set_ylim(0.0, 10.0)
    summary = {"overtake": {"t_start_s": 3.0}}
    plots._mark_events(ax, summary)
    plots._label_events(ax, summary)
    assert labels_clear_of_curves(fig) == 1
    (label,) = [t for t in ax.texts if t.get_text() == "decision"]
    assert 0.5 < label.xy[1] < 0.94  # in the upper free stretch, between 5 and 9.4
