"""One recording path: ``sumo-swarm run --sumocfg`` and ``attach()`` on the same simulation
record the same trajectories and finish the run with the same outputs."""

from __future__ import annotations

import itertools
import json

import pandas as pd
import pytest

import sumo_swarm
from sumo_swarm.sim.bridge import sumo_binary
from sumo_swarm.sim.netbuild import HighwaySpec
from sumo_swarm.sim.recorder import RECORD_COLUMNS
from sumo_swarm.sim.runner import run_sumocfg
from tests.usercases import write_user_case

pytestmark = pytest.mark.sumo

END_S = 20.0


def test_runner_and_plugin_record_the_same_run(tmp_path):
    import libsumo

    cfg = write_user_case(tmp_path / "net", HighwaySpec(length_m=1500, lanes=3), end_s=END_S)
    ran = run_sumocfg(cfg, "cav", "cacc", tmp_path / "run", progress=False, notify=lambda m: None)
    # the options run_sumocfg adds, so that SUMO runs the same simulation
    options = {
        "--lateral-resolution": "0.5",
        "--collision.mingap-factor": "0",
        "--collision.action": "warn",
        "--no-step-log": "true",
    }
    libsumo.start([sumo_binary(), "-c", str(cfg), *(a for kv in options.items() for a in kv)])
    try:
        handle = sumo_swarm.attach(
            libsumo, cav_type="cav", controller="cacc", out_dir=tmp_path / "attach"
        )
        while libsumo.simulation.getTime() < END_S:
            libsumo.simulation.step()
        live = handle.summary()
        handle.detach()
    finally:
        libsumo.close()

    run_df = pd.read_parquet(tmp_path / "run" / "trajectories.parquet")
    attach_df = pd.read_parquet(tmp_path / "attach" / "trajectories.parquet")
    assert list(run_df.columns) == list(RECORD_COLUMNS)
    assert run_df["time_s"].max() == END_S and run_df["vehicle"].nunique() > 6
    pd.testing.assert_frame_equal(run_df, attach_df)

    written = json.loads((tmp_path / "attach" / "summary.json").read_text())
    for block in ("cav", "safety", "overtake", "upstream"):
        assert written[block] == live[block] == ran[block], block
    assert written["controller"] == ran["controller"] == "cacc"
    assert written["timing"]["wall_s"] > 0
    assert (tmp_path / "attach" / "events.jsonl").is_file()


class _Road:
    """A stand-in for SumoSession with what RunRecorder reads: vehicles that come and go."""

    step_length_s = 0.5

    def __init__(self) -> None:
        from sumo_swarm.sim.bridge import StepColumns

        self.time_s = 0.0
        self.columns = StepColumns()
        # as a session registers them when each vehicle departs: they do not change
        names = [f"v{j}" for j in range(10)]
        self.kinds = {v: "cav" for v in ("v0", "v3")}  # the others are HVs by default
        self.lengths = {v: 4.0 + 0.5 * j for j, v in enumerate(names)}
        self.widths = {v: 1.8 for v in names if v != "v1"}  # v1's: unknown (NaN)

    def advance(self, k: int) -> None:
        from sumo_swarm.sim.bridge import StepColumns

        self.time_s = k * self.step_length_s
        ids = [f"v{j}" for j in range(k % 5, k % 5 + 3 + k % 4)]  # 3 to 6, a changing set
        js = range(len(ids))
        edges = ["ab"[(k + j) % 2] for j in js]
        lanes = [j % 3 for j in js]
        widen = {"a": 0.0, "b": 0.2}
        lane_widths = [3.0 + 0.1 * lane + widen[e] for lane, e in zip(lanes, edges, strict=True)]
        self.columns = StepColumns(
            self.time_s, ids, edges, lanes,
            [float("nan")] + [1.0 * k] * (len(ids) - 1),  # the first's: unknown (NaN)
            [10.0 * k + j for j in js], [0.1 * j for j in js], [20.0 + j for j in js],
            [-0.5 * j for j in js], [(float(k), float(j)) for j in js],
            lane_widths,
        )  # fmt: skip


def test_rows_packed_in_chunks_make_the_table_one_list_would(monkeypatch):
    import sumo_swarm.sim.recorder as recorder

    def run(chunk_rows: int) -> tuple[pd.DataFrame, int]:
        monkeypatch.setattr(recorder, "CHUNK_ROWS", chunk_rows)
        road = _Road()
        rec = recorder.RunRecorder(road, controller=None, controller_name="none", scene=None)
        for k in range(1, 40):
            road.advance(k)
            rec.record()
        packed_before = len(rec._chunks)
        return rec.frame(), packed_before

    whole, _ = run(10**9)
    packed, chunks = run(7)
    assert len(whole) > 150 and chunks > 10  # packed in many chunks, then joined into one
    pd.testing.assert_frame_equal(packed, whole)
    assert list(whole["vehicle"].cat.categories) == sorted(whole["vehicle"].unique())
    assert whole["lane_pos_m"].isna().sum() == 39  # each step's first, unknown
    assert set(whole.loc[whole["width_m"].isna(), "vehicle"]) == {"v1"}
    assert set(whole.loc[whole["kind"] == "cav", "vehicle"]) == {"v0", "v3"}
    assert (whole["length_m"] == 4.0 + 0.5 * whole["vehicle"].str[1:].astype(int)).all()


def test_rows_on_disk_read_back_as_the_table_in_memory(monkeypatch, tmp_path):
    # Past outputs.memory_rows the chunks go to disk; frame() reads them back, the same table
    # (each chunk with its own vehicle names, read back on one sorted vocabulary).
    import sumo_swarm.sim.recorder as recorder
    from sumo_swarm.config import OutputSettings

    monkeypatch.setattr(recorder, "CHUNK_ROWS", 7)

    def run(out_dir, memory_rows: int) -> recorder.RunRecorder:
        road = _Road()
        outputs = OutputSettings(memory_rows=memory_rows)
        rec = recorder.RunRecorder(road, None, "none", None, outputs, out_dir=out_dir)
        for k in range(1, 40):
            road.advance(k)
            rec.record()
        return rec

    held = run(None, 10)  # no folder: everything stays in memory
    disk = run(tmp_path, 10)
    assert not held.on_disk and disk.on_disk and disk._file.rows > 100
    assert len(disk._chunks) <= 1  # at most the chunk that has not reached the file yet
    pd.testing.assert_frame_equal(disk.frame(), held.frame())
    slices = list(disk._slices())
    assert [s.index[0] for s in slices[1:]] == list(itertools.accumulate(map(len, slices[:-1])))
    assert all(s["time_s"].nunique() * 3 <= len(s) for s in slices)  # whole steps each
    disk._pack()
    disk._spill()
    disk._file.close()
    written = pd.read_parquet(tmp_path / "trajectories.parquet")
    pd.testing.assert_frame_equal(written, held.frame(), check_categorical=False)
    assert [p.name for p in tmp_path.iterdir()] == ["trajectories.parquet"]  # no parts left


@pytest.mark.parametrize("controller", ["swarm", "sumo-cacc"])
def test_a_run_on_disk_has_the_summary_of_the_run_in_memory(
    monkeypatch, tmp_path, paper_path, controller
):
    # The paper's scene, the summary taken slice by slice from the file (sim/streamed.py)
    # against the whole table in memory: the same numbers (timing aside), the overtake's
    # times and regrouping, the upstream block and the speed field included. Under sumo-cacc
    # SUMO records the steps (sim/fcd.py): its rows go to disk as they are converted.
    import dataclasses

    import sumo_swarm.sim.recorder as recorder
    from sumo_swarm.config import load_scenario
    from sumo_swarm.sim.runner import run_scenario

    sc = load_scenario(paper_path)
    sc = dataclasses.replace(sc, simulation=dataclasses.replace(sc.simulation, duration_s=50.0))
    sc = dataclasses.replace(sc, evaluation=dataclasses.replace(sc.evaluation, end_s=50.0))
    held = run_scenario(sc, controller, tmp_path / "held", progress=False)
    monkeypatch.setattr(recorder, "CHUNK_ROWS", 600)
    small = dataclasses.replace(sc, outputs=dataclasses.replace(sc.outputs, memory_rows=1000))
    disk = run_scenario(small, controller, tmp_path / "disk", progress=False)
    assert held["overtake"]["completed"] == (controller == "swarm")
    assert len(held["upstream"]) > 5
    timed = {"timing", "planner", "tracking"}  # wall and solve times differ run to run
    assert {k: v for k, v in disk.items() if k not in timed} == {
        k: v for k, v in held.items() if k not in timed
    }
    assert disk["planner"]["statuses"] == held["planner"]["statuses"]
    for name in ("trajectories.parquet", "network_speed_field.parquet"):
        pd.testing.assert_frame_equal(
            pd.read_parquet(tmp_path / "disk" / name),
            pd.read_parquet(tmp_path / "held" / name),
            check_categorical=False,
        )
    rows = len(pd.read_parquet(tmp_path / "disk" / "trajectories.parquet"))
    assert rows > 5 * 600  # many slices
    assert sorted(p.name for p in (tmp_path / "disk").iterdir() if p.name.startswith(".")) == []


def test_a_collision_is_an_event_naming_who_hit_whom(tmp_path):
    # A counted collision must be findable: events.jsonl gets SUMO's collisions, in time order.
    import libsumo

    cfg = write_user_case(tmp_path / "net", HighwaySpec(length_m=1500, lanes=3), end_s=END_S)
    options = ["--lateral-resolution", "0.5", "--collision.mingap-factor", "0",
               "--collision.action", "warn", "--time-to-teleport", "-1"]  # fmt: skip
    libsumo.start([sumo_binary(), "-c", str(cfg), *options])
    try:
        handle = sumo_swarm.attach(
            libsumo, cav_type="cav", controller="cacc", out_dir=tmp_path / "attach"
        )
        while len(handle.session.cav_ids) < 2:
            libsumo.simulation.step()
        # the last CAV drives into the one ahead of it: SUMO's safety checks off
        cavs = sorted(handle.session.cav_ids, key=lambda v: libsumo.vehicle.getLanePosition(v))
        rear, front = cavs[0], cavs[1]
        while libsumo.simulation.getTime() < END_S:
            libsumo.vehicle.setSpeedMode(rear, 0)
            libsumo.vehicle.setSpeed(rear, 30.0)
            libsumo.simulation.step()
        summary = handle.summary()
        handle.detach()
    finally:
        libsumo.close()
    events = [json.loads(line) for line in (tmp_path / "attach" / "events.jsonl").open()]
    hits = [e for e in events if e["event"] == "collision"]
    assert summary["safety"]["collisions"] >= 1 and hits
    assert (hits[0]["collider"], hits[0]["victim"]) == (rear, front)
    assert len({(e["collider"], e["victim"]) for e in hits}) == len(hits)  # once per pair
    assert hits[0]["type"] == "collision"
    times = [e["time_s"] for e in events]
    assert times == sorted(times)


class _Queue(_Road):
    """_Road's vehicles in one lane of one edge, 8 m apart, each 3 m/s faster than the one
    ahead: time to collision 0.3-1.2 s, pairs that come and go."""

    def advance(self, k: int) -> None:
        super().advance(k)
        c = self.columns
        n = len(c.ids)
        c.edge, c.lane = ["a"] * n, [0] * n
        c.s_m = [10.0 * k + 8.0 * j for j in range(n)]
        c.speed_mps = [30.0 - 3.0 * j for j in range(n)]


def test_conflicts_are_counted_of_every_vehicle_whatever_is_recorded(monkeypatch):
    # The counter pairs the packed rows when every vehicle of a step is recorded, the steps as
    # read otherwise (CAVs only, steps outside the record window): the same count, in chunks
    # or whole, as the pairs of the whole table taken at once.
    import sumo_swarm.sim.recorder as recorder
    from sumo_swarm.config import OutputSettings
    from sumo_swarm.sim.conflicts import TtcConflictCounter
    from sumo_swarm.sim.metrics import gaps

    def count(chunk_rows: int, **outputs) -> tuple[int, int]:
        monkeypatch.setattr(recorder, "CHUNK_ROWS", chunk_rows)
        road = _Queue()
        settings = OutputSettings(**outputs)
        rec = recorder.RunRecorder(road, None, "none", None, settings, count_conflicts=True)
        for k in range(1, 40):
            road.advance(k)
            rec.record()
        rec._pack()
        rec._count_conflicts()
        return rec.conflicts.events, len(rec.frame())

    whole, rows = count(10**9)
    road, table = _Queue(), []
    for k in range(1, 40):
        road.advance(k)
        table.append(recorder._Steps())
        c = road.columns
        table[-1].add(road.time_s, [c.ids, c.edge, c.lane, c.xy, c.s_m, c.lat_m, c.speed_mps,
                                    c.accel_mps2, c.lane_pos_m, c.lane_width_m])  # fmt: skip
    info = recorder.RunRecorder(road, None, "none", None)._vehicle_info
    at_once = TtcConflictCounter()
    at_once.add(gaps(pd.concat([t.table(info) for t in table], ignore_index=True)))
    assert whole == at_once.events > 3
    assert count(7) == (whole, rows)
    assert count(7, trajectories="cavs")[0] == whole
    for chunk_rows in (7, 10**9):
        windowed = count(chunk_rows, record_from_s=5.0, record_to_s=12.0)
        assert windowed[0] == whole and windowed[1] < rows / 2
