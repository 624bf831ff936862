"""tools/study_headline.py: the penetration study's headline table, on hand-made results with
known means (two seeds of one sweep, given as one batch or as two)."""

from __future__ import annotations

import pandas as pd
import pytest

from tests.toolload import load_tool

sh = load_tool("study_headline")


def _runs(seed: int, cav_delay: dict[str, float]) -> pd.DataFrame:
    rows = [
        {sh.SHARE: 0.0, sh.DEMAND: 1500.0, "controller": c, "seed": seed, "status": "ok",
         "network.delay_s.hv": 30.0 + seed, "network.throughput_vph": 3000.0}
        for c in sh.ORDER
    ]  # fmt: skip
    rows += [
        {sh.SHARE: 0.2, sh.DEMAND: 1500.0, "controller": c, "seed": seed, "status": "ok",
         "network.delay_s.cav": d, "network.delay_s.hv": 20.0, "network.throughput_vph": 3600.0,
         "swarms.platoons_formed": 5.0 if c == "swarm" else float("nan")}
        for c, d in cav_delay.items()
    ]  # fmt: skip
    rows.append({sh.SHARE: 0.2, sh.DEMAND: 1000.0, "controller": "swarm", "seed": seed,
                 "status": "ok", "network.delay_s.cav": 999.0})  # fmt: skip
    rows.append({sh.SHARE: 0.2, sh.DEMAND: 1500.0, "controller": "cacc", "seed": seed,
                 "status": "failed", "network.delay_s.cav": 999.0})  # fmt: skip
    return pd.DataFrame(rows)


def test_each_row_is_the_mean_over_the_seeds_of_one_demand():
    results = pd.concat([_runs(1, {"swarm": 10.0, "sumo-lc": 12.0}),
                         _runs(3, {"swarm": 14.0, "sumo-lc": 12.0})])  # fmt: skip
    table = sh.headline(results, 1500.0).set_index("controller")
    assert list(table.index) == ["(no CAV)", "swarm", "sumo-lc"]  # no cacc: its runs failed
    assert table.loc["swarm", "CAV delay [s]"] == pytest.approx(12.0)
    assert table.loc["swarm", "runs"] == 2 and table.loc["(no CAV)", "runs"] == 2
    assert table.loc["(no CAV)", "car delay [s]"] == pytest.approx(32.0)  # seeds 1 and 3
    assert table.loc["swarm", "platoons formed"] == 5.0
    assert pd.isna(table.loc["sumo-lc", "platoons formed"])


def test_batches_of_other_seeds_are_averaged_together(tmp_path, capsys):
    for seed, swarm in ((1, 10.0), (3, 14.0)):
        folder = tmp_path / f"seed{seed}"
        folder.mkdir()
        _runs(seed, {"swarm": swarm, "sumo-lc": 12.0}).to_parquet(folder / "results.parquet")
    out = tmp_path / "head"
    assert sh.main([str(tmp_path / "seed1"), str(tmp_path / "seed3"), "--out", str(out)]) == 0
    table = pd.read_csv(out.with_suffix(".csv")).set_index("controller")
    assert table.loc["swarm", "CAV delay [s]"] == pytest.approx(12.0)
    assert table.loc["swarm", "runs"] == 2
    command = out.with_suffix(".md").read_text(encoding="utf-8").splitlines()[0]
    assert "seed1 " in command and "seed3 --demand 1500" in command
    assert "| swarm " in capsys.readouterr().out
