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
