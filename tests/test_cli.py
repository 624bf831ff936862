"""The command line: exit status 2 and one line for bad input, no traceback."""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import pytest

from sumo_swarm.cli import build_parser, main


def sumo_swarm(*args: str, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "sumo_swarm", *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=300,
    )


def assert_bad_input(proc: subprocess.CompletedProcess, *fragments: str) -> None:
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    for fragment in fragments:
        assert fragment in lines[0]


def _parsers() -> dict[str, argparse.ArgumentParser]:
    """The top-level parser and every command's, by name ("" for the top level)."""
    top = build_parser()
    parsers = {"": top}
    for action in top._actions:
        if isinstance(action, argparse._SubParsersAction):
            parsers.update(action.choices)
    return parsers


def test_every_command_is_covered():
    assert {"", "run", "reproduce", "batch", "impact"} <= set(_parsers())


@pytest.mark.parametrize("command", sorted(_parsers()))
def test_help_explains_every_option_and_its_default(command, capsys):
    parser = _parsers()[command]
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction | argparse._VersionAction):
            continue
        if isinstance(action, argparse._SubParsersAction):
            assert all(a.help for a in action._choices_actions), command
            continue
        name = "/".join(action.option_strings) or action.dest
        assert action.help, f"{command} {name} has no help"
        if action.option_strings:  # an option says its default, or when it is required
            said = "default" in action.help or "required" in action.help
            assert said, f"{command} {name} says neither its default nor that it is required"
    with pytest.raises(SystemExit) as done:
        main([*([command] if command else []), "--help"])
    assert done.value.code == 0
    text = capsys.readouterr().out
    assert "``" not in text and ":mod:" not in text  # no reStructuredText markup
    # an installed user has no docs/ folder (the package's own path, printed by run --help,
    # may contain one: a checkout in a folder called docs)
    import sumo_swarm

    assert "docs/" not in text.replace(str(Path(sumo_swarm.__file__).parent), "")


def test_help_says_where_the_scenario_format_is(capsys):
    with pytest.raises(SystemExit):
        main(["run", "--help"])
    text = capsys.readouterr().out
    shipped = next(w for w in text.split() if w.endswith("paper.toml"))
    assert Path(shipped).is_absolute()
    assert Path(shipped).read_text(encoding="utf-8").count("[cav]") == 1


def test_batch_help_has_the_sweep_format(capsys):
    with pytest.raises(SystemExit):
        main(["batch", "--help"])
    text = capsys.readouterr().out
    for fragment in ('base = "paper.toml"', "[grid]", "[[cases]]", "results.parquet"):
        assert fragment in text


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--seed", "-5"], "--seed: must be >= 0"),
        (["--seed", "1.5"], "--seed: expected an integer"),
        (["--seed", str(2**31)], "--seed: must be >= 0 and <= 2147483647"),
    ],
)
def test_bad_seed(paper_path, args, fragment):
    assert_bad_input(sumo_swarm("run", str(paper_path), *args), fragment)


def test_bad_workers(paper_path, tmp_path):
    out = tmp_path / "o"
    proc = sumo_swarm("batch", str(paper_path), "--out", str(out), "--workers", "0")
    assert_bad_input(proc, "--workers: must be >= 1")
    assert not out.exists()


def test_missing_scenario_file(tmp_path):
    missing = tmp_path / "nope.toml"
    assert_bad_input(sumo_swarm("run", str(missing)), "not found", str(missing))


def test_unknown_key(tmp_path, scenario_file):
    path = scenario_file('[simulation]\nnetwork = "@NET@"\nstep_lenght_s = 0.1\n')
    assert_bad_input(sumo_swarm("run", str(path)), "simulation.step_lenght_s", str(path))


def test_unknown_controller(paper_path):
    assert_bad_input(sumo_swarm("run", str(paper_path), "--controller", "magic"), "magic")


def test_unwritable_output_folder(paper_path, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert_bad_input(
        sumo_swarm("run", str(paper_path), "--out", str(blocker / "sub")), "cannot be written"
    )


@pytest.mark.sumo
def test_run_writes_summary(paper_path, tmp_path):
    proc = sumo_swarm("run", str(paper_path), "--controller", "cacc", "--out", str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["safety"]["collisions"] == 0
    assert "paper/cacc" in proc.stdout


@pytest.mark.sumo
def test_run_sumocfg_records_the_sumo_configuration_as_run(tmp_path):
    from sumo_swarm.sim.netbuild import HighwaySpec
    from sumo_swarm.sim.runner import read_sumocfg_options
    from tests.usercases import write_user_case

    cfg = write_user_case(tmp_path / "case", HighwaySpec(length_m=500, lanes=3), end_s=3.0)
    out = tmp_path / "o"
    proc = sumo_swarm(
        "run",
        "--sumocfg",
        str(cfg),
        "--cav-type",
        "cav",
        "--controller",
        "cacc",
        "--seed",
        "7",
        "--out",
        str(out),
    )
    assert proc.returncode == 0, proc.stderr
    options = read_sumocfg_options(out / "sumo" / "scenario.sumocfg")
    assert options["net-file"] == str((cfg.parent / "highway.net.xml").resolve())
    assert options["route-files"] == str((cfg.parent / "routes.rou.xml").resolve())
    assert options["lateral-resolution"] == "0.5"  # added: the configuration lacks it
    assert options["collision.action"] == "warn" and options["seed"] == "7"
    assert options["step-length"] == "0.1" and "fcd-output" not in options


@pytest.mark.parametrize(
    ("argv", "module", "name", "where"),
    [
        (["reproduce", "--out", "{tmp}/rep"], "sumo_swarm.study.reproduce", "reproduce",
         "{tmp}/rep/report.md"),
        (["impact", "{tmp}/batch"], "sumo_swarm.study.impact", "impact", "{tmp}/batch/impact"),
    ],
)  # fmt: skip
def test_commands_that_write_outputs_end_by_saying_where(
    argv, module, name, where, tmp_path, monkeypatch, capsys
):
    """The last line a command prints names where its outputs are (the study itself is
    replaced: this checks the command's wiring, tests/test_reproduce.py and test_batch.py the
    studies)."""
    import importlib

    monkeypatch.setattr(importlib.import_module(module), name, lambda *a, **k: "table")
    assert main([a.format(tmp=tmp_path) for a in argv]) == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert where.format(tmp=tmp_path) in last
