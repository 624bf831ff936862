"""The command line: exit status 2 and one line for bad input, no traceback."""

from __future__ import annotations

import argparse
import json
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
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
    # written in a staging folder, then moved: the outputs named where they are now
    assert options["tripinfo-output"] == str((out / "sumo" / "tripinfo.xml").resolve())
    for name in ("scenario.sumocfg", "network.add.xml"):
        assert ".partial-" not in (out / "sumo" / name).read_text()


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


# --------------------------------------------------------------------------- the output folder


def paper_variant(tmp_path: Path, paper_path: Path, duration_s: float) -> Path:
    """The paper scenario lasting ``duration_s``, its network by absolute path."""
    text = paper_path.read_text(encoding="utf-8")
    net = (paper_path.parent.parent / "networks" / "highway3.net.xml").as_posix()
    text = text.replace('"../networks/highway3.net.xml"', f'"{net}"')
    text = text.replace("duration_s = 80.0", f"duration_s = {duration_s}")
    text = text.replace("end_s = 60.0", f"end_s = {duration_s}")
    path = tmp_path / f"paper{duration_s:g}.toml"
    path.write_text(text, encoding="utf-8")
    return path


def one_line_on_stderr(proc: subprocess.CompletedProcess, *fragments: str) -> str:
    # reproduce and batch draw their progress bars on stderr
    bars = ("reproduce:", "batch ")
    lines = [x for x in proc.stderr.strip().splitlines() if not x.startswith(bars)]
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    for fragment in fragments:
        assert fragment in lines[0], lines[0]
    return lines[0]


def folder_says(out: Path) -> tuple[dict, dict]:
    """run.json and summary.json of a run folder; they agree on whether it is complete."""
    manifest = json.loads((out / "run.json").read_text())
    summary = json.loads((out / "summary.json").read_text())
    assert summary["complete"] is (manifest["state"] == "complete")
    assert summary["incomplete_reason"] == manifest["reason"]
    assert set(manifest["files"]) == {p.name for p in out.iterdir()} - {"run.json"}
    return manifest, summary


def staged(out: Path) -> list[Path]:
    return sorted(out.parent.glob(f"{out.name}.partial-*"))


@pytest.mark.sumo
def test_out_holding_a_run_is_refused_unless_forced(paper_path, tmp_path):
    scenario = paper_variant(tmp_path, paper_path, 5.0)
    out = tmp_path / "o"
    first = sumo_swarm("run", str(scenario), "--controller", "swarm", "--out", str(out))
    assert first.returncode == 0, first.stderr
    assert (out / "plans.jsonl").is_file()
    (out / "replay.mp4").write_bytes(b"an earlier replay")
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}

    again = sumo_swarm("run", str(scenario), "--controller", "cacc", "--out", str(out))
    assert_bad_input(again, str(out), "holds an earlier run", "--force")
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before  # untouched

    forced = sumo_swarm("run", str(scenario), "--controller", "cacc", "--out", str(out), "--force")
    assert forced.returncode == 0, forced.stderr
    manifest, summary = folder_says(out)
    assert summary["controller"] == "cacc" and manifest["state"] == "complete"
    # nothing of the swarm run is left beside the cacc run's files
    assert not (out / "plans.jsonl").exists() and not (out / "replay.mp4").exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o", scenario.name]


def test_out_holding_other_files_is_refused_even_forced(paper_path, tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    proc = sumo_swarm("run", str(paper_path), "--out", str(out), "--force")
    assert_bad_input(proc, str(out), "not a sumo-swarm run", "notes.txt")
    assert [p.name for p in out.iterdir()] == ["notes.txt"] and not staged(out)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert_bad_input(sumo_swarm("run", str(paper_path), "--out", str(blocker)), "not a folder")


def start_run(scenario: Path, out: Path, controller: str = "cacc") -> subprocess.Popen:
    """``run`` in a process of its own, writing SUMO's fcd-output (it grows step by step)."""
    cmd = [sys.executable, "-m", "sumo_swarm", "run", str(scenario), "--controller", controller,
           "--out", str(out), "--fcd"]  # fmt: skip
    return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_until(proc: subprocess.Popen, ready, timeout_s: float = 120.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not ready():
        assert proc.poll() is None, "the run ended before the signal"
        assert time.monotonic() < deadline, "the moment never came"
        time.sleep(0.002)


def finished(proc: subprocess.Popen) -> subprocess.CompletedProcess:
    stdout, stderr = proc.communicate(timeout=300)
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)


@pytest.mark.sumo
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_mid_run_keeps_what_was_gathered(paper_path, tmp_path, sig):
    scenario = paper_variant(tmp_path, paper_path, 600.0)  # far longer than the test waits
    out = tmp_path / "o"
    proc = start_run(scenario, out)

    def mid_run() -> bool:  # SUMO has written a few steps of fcd-output
        return any((s / "fcd.xml").is_file() and (s / "fcd.xml").stat().st_size > 200_000
                   for s in staged(out))  # fmt: skip

    wait_until(proc, mid_run)
    proc.send_signal(sig)
    done = finished(proc)
    assert done.returncode == 128 + sig
    one_line_on_stderr(done, f"interrupted by {sig.name} at t = ", str(out), '"complete": false')
    manifest, summary = folder_says(out)
    assert manifest["state"] == "incomplete" and sig.name in summary["incomplete_reason"]
    assert 0.0 < summary["sim_end_s"] < 600.0
    df = pd.read_parquet(out / "trajectories.parquet")
    assert df["time_s"].max() == pytest.approx(summary["sim_end_s"])
    last = json.loads((out / "events.jsonl").read_text().splitlines()[-1])
    assert last["event"] == "interrupted" and last["signal"] == sig.name
    assert not staged(out)


@pytest.mark.sumo
@pytest.mark.parametrize("moment", ["sumo", "finishing"])
def test_a_signal_at_any_moment_leaves_a_folder_that_says_what_it_holds(
    paper_path, tmp_path, moment
):
    # sumo: as soon as the staging folder is there (SUMO's inputs being written, SUMO
    # starting); finishing: two SIGTERMs once the last step is made and the outputs are being
    # written. Whatever the exact moment, the folder is either untouched (nothing written) or
    # one whole run saying whether it is complete.
    duration = 600.0 if moment != "finishing" else 60.0
    scenario = paper_variant(tmp_path, paper_path, duration)
    out = tmp_path / "o"
    proc = start_run(scenario, out)
    if moment == "sumo":
        wait_until(proc, lambda: bool(staged(out)))
    elif moment == "finishing":
        wait_until(proc, lambda: any((s / "events.jsonl").exists() for s in staged(out)))
    proc.send_signal(signal.SIGTERM)
    if moment == "finishing":
        time.sleep(0.005)
        proc.send_signal(signal.SIGTERM)
    done = finished(proc)
    assert done.returncode == 128 + signal.SIGTERM
    line = one_line_on_stderr(done, "interrupted by SIGTERM")
    assert not staged(out)
    if not out.exists():
        assert "nothing written" in line
        assert moment != "finishing"
        return
    _, summary = folder_says(out)
    pd.read_parquet(out / "trajectories.parquet")  # whole, readable
    if moment == "finishing":
        assert summary["complete"] is True and summary["sim_end_s"] == pytest.approx(duration)
        assert "the run is complete" in line
    else:
        assert summary["complete"] is False and '"complete": false' in line


def _finished_runs(out: Path) -> list[Path]:
    """The ``done`` markers of the runs finished in ``out/runs``: in a run's own folder, not in
    the hidden staging folder a worker writes it in before moving it there (``Path.glob``'s
    ``*`` matches hidden names: the signal once came between the two and nothing was kept)."""
    return [p for p in out.glob("runs/*/done") if not p.parent.name.startswith(".")]


@pytest.mark.sumo
@pytest.mark.parametrize("command", ["reproduce", "batch"])
def test_sigterm_during_reproduce_or_batch_says_what_is_kept(paper_path, tmp_path, command):
    scenario = paper_variant(tmp_path, paper_path, 20.0)
    out = tmp_path / "o"
    if command == "reproduce":
        args = ["reproduce", "--scenario", str(scenario), "--out", str(out)]
    else:
        sweep = tmp_path / "sweep.toml"
        sweep.write_text(f'base = "{scenario.as_posix()}"\ncontrollers = ["cacc", "sumo-cacc"]\n'
                         'seeds = [1, 2, 3]\n', encoding="utf-8")  # fmt: skip
        args = ["batch", str(sweep), "--out", str(out), "--workers", "1"]
    proc = subprocess.Popen([sys.executable, "-m", "sumo_swarm", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)  # fmt: skip
    wait_until(proc, lambda: (out / "runs").is_dir() and bool(_finished_runs(out)))
    proc.send_signal(signal.SIGTERM)
    done = finished(proc)
    assert done.returncode == 128 + signal.SIGTERM
    kept = len(_finished_runs(out))
    if command == "reproduce":
        one_line_on_stderr(done, "interrupted by SIGTERM", str(out), '"complete": false')
        report = json.loads((out / "report.json").read_text())
        assert report["complete"] is False
        # A run in its last writes when the signal came may still finish as the workers are
        # stopped, after the report counted: the report never claims more than the disk holds.
        said = re.fullmatch(r"interrupted by SIGTERM: (\d) of 5 runs finished",
                            report["incomplete_reason"])  # fmt: skip
        assert said is not None, report["incomplete_reason"]
        assert 1 <= int(said.group(1)) <= kept
    else:
        one_line_on_stderr(done, "interrupted by SIGTERM", str(out), "again to resume")
        assert len(pd.read_parquet(out / "results.parquet")) == kept < 6


@pytest.mark.sumo
def test_kill_9_mid_run_never_leaves_a_mixed_folder(paper_path, tmp_path):
    out = tmp_path / "o"
    short = paper_variant(tmp_path, paper_path, 3.0)
    assert sumo_swarm("run", str(short), "--controller", "cacc", "--out", str(out)).returncode == 0
    before = {p.name: p.stat().st_mtime_ns for p in out.iterdir()}
    proc = subprocess.Popen(
        [sys.executable, "-m", "sumo_swarm", "run", str(paper_variant(tmp_path, paper_path, 600.0)),
         "--controller", "sumo-cacc", "--out", str(out), "--force", "--fcd"],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip
    wait_until(proc, lambda: any((s / "fcd.xml").is_file() for s in staged(out)))
    proc.kill()
    proc.wait()
    # the earlier run as it was; the killed one aside, saying what it is
    assert {p.name: p.stat().st_mtime_ns for p in out.iterdir()} == before
    (left,) = staged(out)
    manifest = json.loads((left / "run.json").read_text())
    assert manifest["state"] == "running" and manifest["pid"] == proc.pid
    assert manifest["out"] == str(out.resolve()) and not (left / "summary.json").exists()
    forced = sumo_swarm("run", str(short), "--controller", "sumo-lc", "--out", str(out), "--force")
    assert forced.returncode == 0, forced.stderr
    assert json.loads((out / "summary.json").read_text())["controller"] == "sumo-lc"


def test_an_interrupted_command_says_what_it_kept_in_one_line():
    from sumo_swarm.cli import _interrupted_line, _Signalled
    from sumo_swarm.errors import RunInterrupted

    out = Path("o")
    term = _Signalled("interrupted by SIGTERM", 143)
    assert _interrupted_line(term, "run", out) == "interrupted by SIGTERM: nothing written to o"
    assert _interrupted_line(KeyboardInterrupt(), "batch", out) == (
        "interrupted by SIGINT: finished runs are kept in o; run the same command again to resume"
    )
    assert "report.json" in _interrupted_line(term, "reproduce", out)
    kept = RunInterrupted("interrupted by SIGINT at t = 3.00 s:\nkept in o", 130)
    assert _interrupted_line(kept, "run", out) == "interrupted by SIGINT at t = 3.00 s: kept in o"


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [
        (["run", "x.toml", "--controller", "swam"], "did you mean 'swarm'?"),
        (["run", "x.toml", "--sumcfg", "a.sumocfg"], "did you mean '--sumocfg'?"),
        (["run", "x.toml", "--cav_type", "cav"], "did you mean '--cav-type'?"),
        (["bach", "sweep.toml"], "did you mean 'batch'?"),
        (["batch", "s.toml", "--out", "o", "--wrokers", "2"], "did you mean '--workers'?"),
    ],
)
def test_a_mistyped_command_option_or_choice_suggests_the_nearest(argv, fragment, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and fragment in err[0], err


def test_an_unknown_option_far_from_any_gets_no_suggestion(capsys):
    assert main(["run", "x.toml", "--zzzzzz"]) == 2
    err = capsys.readouterr().err
    assert "unrecognized arguments: --zzzzzz" in err and "did you mean" not in err
