"""tools/swarm_ab.py: the copy of a batch without its swarm runs, and the scene-by-scene
comparison of two report tables, on hand-made folders and tables."""

from __future__ import annotations

import pandas as pd
import pytest

from tests.toolload import load_tool

ab = load_tool("swarm_ab")


def test_the_copy_keeps_the_baselines_and_leaves_out_the_swarm_runs_and_reports(tmp_path):
    before = tmp_path / "before"
    for run in ("swarm-s42-a", "swarm-s42-b", "cacc-s42-a", "sumo-lc-s42-a"):
        (before / "runs" / run).mkdir(parents=True)
        (before / "runs" / run / "done").write_text("", encoding="utf-8")
    for name in ("results.parquet", "sweep.json", "variants.md", "variants.csv"):
        (before / name).write_text("x", encoding="utf-8")
    (before / "impact").mkdir()
    out = tmp_path / "after"
    assert ab.prepare(before, out) == 2
    assert sorted(p.name for p in (out / "runs").iterdir()) == ["cacc-s42-a", "sumo-lc-s42-a"]
    assert (out / "runs" / "cacc-s42-a" / "done").is_file()
    assert sorted(p.name for p in out.iterdir()) == ["results.parquet", "runs", "sweep.json"]
    with pytest.raises(ValueError, match="exists already"):
        ab.prepare(before, out)
    with pytest.raises(ValueError, match="not a batch folder"):
        ab.prepare(tmp_path / "nothing", tmp_path / "other")


def test_changed_scenes_are_the_flipped_verdicts_and_the_speeds_that_moved():
    before = pd.DataFrame(
        {"scene": [0, 1, 2, 3], "all": ["pass", "pass", "FAIL", "pass"],
         "mean_speed_mps": [19.0, 18.0, 17.0, 16.0]}
    )  # fmt: skip
    after = pd.DataFrame(
        {"scene": [0, 1, 2, 3], "all": ["pass", "FAIL", "pass", "pass"],
         "mean_speed_mps": [19.004, 17.999, 17.2, 15.9]}
    )  # fmt: skip
    figures, changed = ab.compare(before, after)
    # 0 moved by less than the tolerance; 1 flipped by 0.001 m/s; 2 flipped; 3 moved 0.1 m/s
    assert changed["scene"].tolist() == [1, 2, 3]
    assert changed["change_mps"].tolist() == pytest.approx([-0.001, 0.2, -0.1])
    assert figures["passing_before"] == 3 and figures["passing_after"] == 3
    assert figures["mean_speed_after_mps"] == pytest.approx((19.004 + 17.999 + 17.2 + 15.9) / 4)


def test_a_stress_table_is_compared_by_its_row_order_and_its_own_verdict():
    before = pd.DataFrame(
        {"passes_where_sumo_lc_passes": [True, False], "mean_speed_mps": [15.0, 14.0]}
    )
    after = pd.DataFrame(
        {"passes_where_sumo_lc_passes": [True, True], "mean_speed_mps": [15.0, 14.5]}
    )
    figures, changed = ab.compare(before, after)
    assert changed["scene"].tolist() == [1]
    assert (figures["passing_before"], figures["passing_after"]) == (1, 2)
    with pytest.raises(ValueError, match="no verdict column"):
        ab.verdict_column(pd.DataFrame({"mean_speed_mps": [1.0]}))


def test_bad_input_exits_2_with_one_line(tmp_path, capsys):
    assert ab.main([str(tmp_path / "none.toml"), "--before", "b", "--out", "o"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "none.toml" in err[0]
    sweep = tmp_path / "sweep.toml"
    sweep.write_text("", encoding="utf-8")
    args = [str(sweep), "--before", str(tmp_path / "nothing"), "--out", str(tmp_path / "o")]
    assert ab.main(args) == 2
    assert "not a batch folder" in capsys.readouterr().err


def test_the_batch_runs_the_trees_package_from_the_tree(tmp_path, monkeypatch, capsys):
    # "python -m" puts the working folder first on the path, before PYTHONPATH: run from
    # another checkout, the batch ran that checkout's package and every scene came out the
    # same. The batch runs from the tree, with the tree first on PYTHONPATH.
    import subprocess

    tree = tmp_path / "tree"
    (tree / "sumo_swarm").mkdir(parents=True)
    before = tmp_path / "before"
    (before / "runs" / "cacc-s42-a").mkdir(parents=True)
    sweep = tmp_path / "variants.toml"
    sweep.write_text("", encoding="utf-8")
    table = pd.DataFrame({"scene": [0], "all": ["pass"], "mean_speed_mps": [19.0]})
    table.to_csv(before / "variants.csv", index=False)
    calls = []

    def run(cmd, **kwargs):
        calls.append((cmd, kwargs))
        return subprocess.CompletedProcess(cmd, 0)

    monkeypatch.setattr(ab.subprocess, "run", run)
    monkeypatch.setattr(ab, "_report", lambda name, folder, env: before / "variants.csv")
    out = tmp_path / "after"
    assert (
        ab.main([str(sweep), "--before", str(before), "--out", str(out), "--tree", str(tree)]) == 0
    )
    cmd, kwargs = calls[0]
    assert cmd[1:5] == ["-m", "sumo_swarm.cli", "batch", str(sweep.resolve())]
    assert kwargs["cwd"] == tree.resolve()
    assert kwargs["env"]["PYTHONPATH"].split(ab.os.pathsep)[0] == str(tree.resolve())
    assert "0 scenes changed" in capsys.readouterr().out
