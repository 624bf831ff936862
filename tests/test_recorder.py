"""One recording path: ``sumo-swarm run --sumocfg`` and ``attach()`` on the same simulation
record the same trajectories and finish the run with the same outputs."""

from __future__ import annotations

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
        self.time_s = 0.0
        self.states, self.positions, self.edges = {}, {}, {}
        self.kinds, self.lane_positions, self.widths = {}, {}, {}

    def lane_width_m(self, edge: str, lane: int) -> float:
        return 3.0 + 0.1 * lane + (0.2 if edge == "b" else 0.0)

    def advance(self, k: int) -> None:
        from sumo_swarm.core.model import VehicleState

        self.time_s = k * self.step_length_s
        ids = [f"v{j}" for j in range(k % 5, k % 5 + 3 + k % 4)]  # 3 to 6, a changing set
        self.states = {
            v: VehicleState(v, 10.0 * k + j, j % 3, 0.1 * j, 20.0 + j, 4.5, -0.5 * j)
            for j, v in enumerate(ids)
        }
        self.positions = {v: (float(k), float(j)) for j, v in enumerate(ids)}
        self.edges = {v: "ab"[(k + j) % 2] for j, v in enumerate(ids)}
        self.kinds = {v: "cav" for v in ids[:1]}  # the others are HVs by default
        self.lane_positions = {v: 1.0 * k for v in ids[1:]}  # the first: unknown (NaN)
        self.widths = {v: 1.8 for v in ids}


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
    assert whole["lane_pos_m"].isna().sum() == 39  # the CAV's, unknown
    assert set(whole.loc[whole["kind"] == "cav", "vehicle"]) == {f"v{j}" for j in range(5)}
