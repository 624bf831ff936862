"""Trajectories SUMO records itself (sim/fcd.py): hand-made FCD files with known answers, and
real runs of the baselines recorded by SUMO against the same runs read step by step."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from sumo_swarm.config import load_scenario
from sumo_swarm.sim.fcd import FCD_FILE, FcdReading, fcd_chunks
from sumo_swarm.sim.metrics import HardBrakeCounter
from sumo_swarm.sim.recorder import RECORD_COLUMNS
from sumo_swarm.sim.runner import run_scenario

STEP_S = 0.5
# lane id -> edge, index, width [m]
LANES = {
    "a_0": ("a", 0, 3.2),
    "a_1": ("a", 1, 3.5),
    ":j_0_0": (":j_0", 0, 3.2),  # the junction lane from a into b (on the route)
    ":k_0_0": (":k_0", 0, 3.0),  # a junction lane off the route
    "b_0": ("b", 0, 3.2),
}
OFFSETS = {"a": 0.0, "b": 110.0}  # edge a is 100 m long, the junction lane 10 m
INFO = {"car": ("hv", 4.5, 1.8), "cav": ("cav", 5.0, 1.9)}


class Frame:
    """The route coordinate of edges a, then the junction lane :j_0_0 (10 m), then b."""

    edge_offset_m = OFFSETS

    def route_s(self, edge: str, lane: int, pos_m: float) -> float | None:
        if edge in OFFSETS:
            return OFFSETS[edge] + pos_m
        if edge == ":j_0":
            return 110.0 - (10.0 - pos_m)
        return None


READING = FcdReading(LANES, Frame(), INFO.__getitem__, STEP_S, RECORD_COLUMNS)


def write_fcd(path, rows) -> None:
    """SUMO's FCD Parquet (its column names and types) of ``rows``: (time, id, x, y, speed,
    pos, lane, accel, posLat); an id of None is a step with no vehicle."""
    names = ["timestep_time", "vehicle_id", "vehicle_x", "vehicle_y", "vehicle_speed",
             "vehicle_pos", "vehicle_lane", "vehicle_acceleration", "vehicle_posLat"]  # fmt: skip
    types = [pa.float64(), pa.string(), pa.float64(), pa.float64(), pa.float32(), pa.float32(),
             pa.string(), pa.float32(), pa.float32()]  # fmt: skip
    columns = list(zip(*rows, strict=True))
    table = pa.table(
        [pa.array(c, type=t) for c, t in zip(columns, types, strict=True)],
        schema=pa.schema(list(zip(names, types, strict=True))),
    )
    pq.write_table(table, path)


def chunks(path, rows=50_000) -> list[pd.DataFrame]:
    return list(fcd_chunks(path, READING, rows))


def test_a_step_is_read_as_the_run_reads_it_after_the_step(tmp_path):
    path = tmp_path / FCD_FILE
    write_fcd(path, [
        (0.0, None, None, None, None, None, None, None, None),  # nobody yet
        (0.5, "cav", 10.0, -1.6, 20.0, 10.0, "a_0", 1.0, 0.25),
        (0.5, "car", 40.0, -4.95, 25.0, 40.0, "a_1", -4.5, -0.5),
        (1.0, "cav", 20.0, -1.6, 20.5, 20.25, "a_0", 1.0, 0.25),
    ])  # fmt: skip
    [df] = chunks(path)
    assert list(df.columns) == list(RECORD_COLUMNS)
    # SUMO writes a step under the time it began; the run reads it when the step has ended
    assert df["time_s"].tolist() == [1.0, 1.0, 1.5]
    assert df["vehicle"].tolist() == ["cav", "car", "cav"]
    assert df["kind"].tolist() == ["cav", "hv", "cav"]
    assert df["edge"].tolist() == ["a", "a", "a"] and df["lane"].tolist() == [0, 1, 0]
    assert df["lane"].dtype == np.int16
    assert df["s_m"].tolist() == [10.0, 40.0, 20.25]
    assert df["lane_pos_m"].tolist() == [10.0, 40.0, 20.25]
    assert df["lane_width_m"].tolist() == [3.2, 3.5, 3.2]
    assert df["length_m"].tolist() == [5.0, 4.5, 5.0]
    assert df["width_m"].tolist() == [1.9, 1.8, 1.9]
    assert df["accel_mps2"].tolist() == [1.0, -4.5, 1.0]
    assert df["lat_m"].tolist() == [0.25, -0.5, 0.25]
    assert df["x_m"].tolist() == [10.0, 40.0, 20.0]
    for name in ("vehicle", "kind", "edge"):
        assert isinstance(df[name].dtype, pd.CategoricalDtype)


def test_route_positions_on_junction_lanes_on_and_off_the_route(tmp_path):
    path = tmp_path / FCD_FILE
    write_fcd(path, [
        (0.0, "cav", 0.0, 0.0, 10.0, 4.0, ":j_0_0", 0.0, 0.0),  # 10 m lane ending at b: 104
        (0.0, "car", 0.0, 0.0, 8.0, 2.0, ":k_0_0", 0.0, 0.0),  # off the route, first seen
        (0.5, "car", 0.0, 0.0, 8.0, 5.0, ":k_0_0", 0.0, 0.0),  # one step on: 2 + 8 * 0.5
        (1.0, "car", 0.0, 0.0, 6.0, 7.0, ":k_0_0", 0.0, 0.0),  # 6 + 6 * 0.5
        (1.5, None, None, None, None, None, None, None, None),  # the car out of the file
        (2.0, "car", 0.0, 0.0, 6.0, 1.0, ":k_0_0", 0.0, 0.0),  # back a step later: afresh
    ])  # fmt: skip
    [df] = chunks(path)
    assert df["s_m"].tolist() == [104.0, 2.0, 6.0, 9.0, 1.0]


def test_chunks_hold_whole_steps_and_carry_the_route_position_over(tmp_path):
    path = tmp_path / FCD_FILE
    rows = []
    for k in range(6):  # the car off the route six steps, beside the cav on edge a
        t = k * STEP_S
        rows.append((t, "car", 0.0, 0.0, 4.0, 100.0 + 3 * k, ":k_0_0", 0.0, 0.0))
        rows.append((t, "cav", 0.0, 0.0, 10.0, 5.0 * k, "a_0", 0.0, 0.0))
    write_fcd(path, rows)
    whole = pd.concat(chunks(path), ignore_index=True)
    parts = chunks(path, rows=3)
    assert len(parts) > 1
    for part in parts:  # every step whole in one chunk
        counts = part.groupby("time_s").size()
        assert (counts == 2).all()
    joined = pd.concat(parts, ignore_index=True)
    assert joined["s_m"].tolist() == whole["s_m"].tolist()
    car = joined[joined["vehicle"] == "car"]["s_m"].tolist()
    assert car == [100.0, 102.0, 104.0, 106.0, 108.0, 110.0]  # 100, then + 4 m/s * 0.5 s


def test_a_file_without_a_vehicle_gives_no_rows(tmp_path):
    path = tmp_path / FCD_FILE  # as SUMO writes it when nobody drove: the time column only
    pq.write_table(pa.table({"timestep_time": pa.array([0.0, 0.5, 1.0])}), path)
    assert chunks(path) == []


def test_a_file_that_skips_steps_is_refused(tmp_path):
    path = tmp_path / FCD_FILE  # a device.fcd.period of the configuration: every other step
    write_fcd(path, [(t, "car", 0.0, 0.0, 8.0, 8.0 * t, "a_0", 0.0, 0.0) for t in (0.0, 1.0)])
    with pytest.raises(ValueError, match="skips steps"):
        chunks(path)


def test_a_vehicle_on_no_lane_is_refused(tmp_path):
    path = tmp_path / FCD_FILE
    write_fcd(path, [(0.0, "car", 0.0, 0.0, 8.0, 1.0, None, 0.0, 0.0),
                     (0.0, "cav", 0.0, 0.0, 8.0, 9.0, "a_0", 0.0, 0.0)])  # fmt: skip
    with pytest.raises(ValueError, match="on no lane"):
        chunks(path)


def test_sumo_records_only_what_reads_no_vehicle_and_records_every_row(tmp_path):
    from sumo_swarm.config import OutputSettings
    from sumo_swarm.controllers import make_controller
    from sumo_swarm.sim.runner import _recorded_by_sumo

    every, some = OutputSettings(), OutputSettings(trajectories="cavs")
    late = OutputSettings(record_from_s=10.0)

    def where(controller="sumo-cacc", outputs=every, fcd=False, gui=False, given=None):
        made = make_controller(controller)
        return _recorded_by_sumo(tmp_path, made, outputs, fcd=fcd, gui=gui, given=given)

    assert where() == (tmp_path / "sumo" / FCD_FILE).resolve()
    assert where("sumo-lc") is not None
    assert where("swarm") is None and where("cacc") is None  # they read the vehicles
    assert where(outputs=some) is None and where(outputs=late) is None
    assert where(fcd=True) is None and where(gui=True) is None
    for theirs in ("fcd-output", "device.fcd.probability", "output-prefix"):
        assert where(given={theirs: "x"}) is None
    assert where(given={"tripinfo-output": "trips.xml"}) is not None


def test_hard_brakes_counted_over_whole_steps_as_step_by_step():
    times = np.array([0.5, 0.5, 1.0, 1.0, 1.5, 2.0, 2.0])
    ids = np.array(["a", "b", "a", "b", "b", "a", "b"], dtype=object)
    accels = np.array([-5.0, 0.0, -5.0, -6.0, 0.0, -5.0, -5.0])
    kinds = {"a": "cav", "b": "hv"}
    steps = HardBrakeCounter()
    steps.update_steps(times, ids, accels, kinds)
    one_by_one = HardBrakeCounter()
    for t in (0.5, 1.0, 1.5, 2.0):
        at = times == t
        one_by_one.update(ids[at].tolist(), accels[at].tolist(), kinds)
    # a: one episode (absent at 1.5 s, it keeps its hard sample); b: two
    assert steps.episodes == one_by_one.episodes == 3
    assert steps.vehicles == one_by_one.vehicles == {"a": "cav", "b": "hv"}


@pytest.mark.sumo
@pytest.mark.parametrize(
    ("scenario", "controller", "chunk_rows"),
    [("paper", "sumo-cacc", 50_000), ("paper", "sumo-lc", 50_000), ("corridor", "sumo-cacc", 700)],
)
def test_a_baseline_recorded_by_sumo_is_the_run_read_step_by_step(
    tmp_path, monkeypatch, scenario, controller, chunk_rows
):
    import sumo_swarm.sim.recorder as recorder
    from tests.conftest import ROOT

    # the corridor: ramps, their junctions off the route, in chunks of a few steps
    sc = load_scenario(ROOT / "scenarios" / f"{scenario}.toml")
    sc = replace(sc, simulation=replace(sc.simulation, duration_s=40.0),
                 evaluation=replace(sc.evaluation, start_s=0.0, end_s=40.0))  # fmt: skip
    by_sumo, read = tmp_path / "by_sumo", tmp_path / "read"
    monkeypatch.setattr(recorder, "CHUNK_ROWS", chunk_rows)
    run_scenario(sc, controller, by_sumo, progress=False)
    run_scenario(sc, controller, read, fcd=True, progress=False)  # fcd.xml: the session reads
    assert not (by_sumo / "sumo" / FCD_FILE).exists()  # its rows are in trajectories.parquet
    assert (read / "fcd.xml").is_file()
    keys = ["time_s", "vehicle"]
    a = pd.read_parquet(by_sumo / "trajectories.parquet").sort_values(keys, ignore_index=True)
    b = pd.read_parquet(read / "trajectories.parquet").sort_values(keys, ignore_index=True)
    assert len(a) == len(b) > 0
    if scenario == "corridor":  # the route positions made up of the speed were tested
        assert a["edge"].astype(str).str.match(r"^:n[13]_").any()  # the on-ramps' junctions
        assert len(a) > 5 * chunk_rows
    for name in ("time_s", "vehicle", "kind", "edge", "lane", "x_m", "y_m", "length_m"):
        assert a[name].astype(str).tolist() == b[name].astype(str).tolist(), name
    for name in ("s_m", "lane_pos_m", "lat_m", "speed_mps", "accel_mps2"):  # 32-bit in SUMO's
        np.testing.assert_allclose(a[name], b[name], rtol=1e-6, atol=1e-4, err_msg=name)
    sa = json.loads((by_sumo / "summary.json").read_text())
    sb = json.loads((read / "summary.json").read_text())
    assert sa["cav"]["mean_speed_mps"] == pytest.approx(sb["cav"]["mean_speed_mps"], rel=1e-6)
    assert sa["cav"]["gap_min_m"] == pytest.approx(sb["cav"]["gap_min_m"], abs=1e-4)
    assert sa["safety"] == pytest.approx(sb["safety"], abs=1e-4)
    assert sa["network"]["ttc_below_1_5s_events"] == sb["network"]["ttc_below_1_5s_events"]
    assert sa["network"]["hard_brakes_per_1000_vkm"] == pytest.approx(
        sb["network"]["hard_brakes_per_1000_vkm"], rel=1e-9
    )


@pytest.mark.sumo
def test_an_fcd_file_that_cannot_be_read_costs_the_rows_not_the_run(tmp_path, monkeypatch):
    from tests.conftest import PAPER

    def unreadable(path, *args, **kwargs):
        raise pa.ArrowInvalid("Parquet magic bytes not found in footer")
        yield  # a generator, as fcd_chunks

    monkeypatch.setattr("sumo_swarm.sim.recorder.fcd_chunks", unreadable)
    sc = load_scenario(PAPER)
    sc = replace(sc, simulation=replace(sc.simulation, duration_s=5.0),
                 evaluation=replace(sc.evaluation, end_s=5.0))  # fmt: skip
    summary = run_scenario(sc, "sumo-cacc", tmp_path, progress=False)
    assert summary == json.loads((tmp_path / "summary.json").read_text())
    assert "magic bytes" in summary["errors"]["trajectories"]
    assert summary["complete"] is False and "magic bytes" in summary["incomplete_reason"]
    assert summary["network"]["hard_brakes_per_1000_vkm"] is None  # not counted, not 0
    assert summary["network"]["ttc_below_1_5s_events"] is None
    assert (tmp_path / "sumo" / FCD_FILE).is_file()  # kept, as SUMO left it
    assert summary["network"]["vehicles"] > 0  # the rest of the run stays
    assert pd.read_parquet(tmp_path / "trajectories.parquet").empty


@pytest.mark.sumo
def test_vehicles_left_out_of_sumos_fcd_leave_the_run_incomplete(tmp_path):
    # A user's type without SUMO's FCD device (has.fcd.device false): its vehicles drove but
    # are not in the file; the rows are not the run's, and the summary says so.
    from sumo_swarm.sim.netbuild import HighwaySpec
    from sumo_swarm.sim.runner import run_sumocfg
    from tests.usercases import write_user_case

    cfg = write_user_case(tmp_path / "net", HighwaySpec(length_m=1500, lanes=3), end_s=10.0)
    routes = tmp_path / "net" / "routes.rou.xml"
    quiet = '<vType id="x" length="4.5"><param key="has.fcd.device" value="false"/></vType>'
    text = routes.read_text(encoding="utf-8").replace('type="car"', 'type="x"')
    routes.write_text(text.replace("<routes>", "<routes>\n  " + quiet), encoding="utf-8")
    summary = run_sumocfg(cfg, "cav", "sumo-cacc", tmp_path / "out", progress=False)
    assert summary["complete"] is False
    assert "not in it" in summary["errors"]["trajectories"]
    assert (tmp_path / "out" / "sumo" / FCD_FILE).is_file()


@pytest.mark.parametrize(
    ("version", "parquet"),
    [
        ("SUMO 1.24.0", False),
        ("SUMO 1.25.0", True),
        ("SUMO 1.28.0", True),
        ("SUMO v1_30_0+0421-5c7b0a1", True),
        ("SUMO", False),
    ],
)
def test_sumo_records_with_a_libsumo_that_writes_parquet(monkeypatch, version, parquet):
    import libsumo

    from sumo_swarm.sim import bridge

    monkeypatch.setattr(libsumo, "getVersion", lambda: (22, version))
    bridge.writes_parquet.cache_clear()
    try:
        assert bridge.writes_parquet() is parquet
    finally:
        bridge.writes_parquet.cache_clear()
