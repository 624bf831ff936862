"""Injected faults on the paper scene, through real SUMO: no crash, no collision, no CAV
braking beyond -4 m/s^2, and every fault leaves a trace in the run's outputs."""

from __future__ import annotations

import json
import logging
import os
import signal
from collections.abc import Callable
from dataclasses import replace

import numpy as np
import pandas as pd
import pytest

from sumo_swarm.config import HvPlacement, load_scenario
from sumo_swarm.controllers.base import RunContext
from sumo_swarm.controllers.swarm import SwarmController
from sumo_swarm.core.model import VehicleState
from sumo_swarm.errors import RunInterrupted, SimulationError
from sumo_swarm.sim.metrics import hard_brake_events
from sumo_swarm.sim.runfolder import StopRequest
from sumo_swarm.sim.runner import run_scenario
from tests.conftest import PAPER

pytestmark = pytest.mark.sumo


class Injector:
    """Wraps a controller; at ``at_s`` runs ``action(ctx)`` once, then carries on."""

    def __init__(self, inner, at_s: float, action: Callable[[RunContext], None]) -> None:
        self.inner = inner
        self.name = inner.name
        self.at_s = at_s
        self.action = action
        self.done = False

    def attach(self, ctx: RunContext) -> None:
        self.ctx = ctx
        self.inner.attach(ctx)

    def control(self, t_s: float) -> None:
        if not self.done and t_s >= self.at_s:
            self.done = True
            self.action(self.ctx)
        self.inner.control(t_s)

    def summary(self):
        return self.inner.summary()


def paper(duration_s: float = 60.0, **scene_changes):
    sc = load_scenario(PAPER)
    sc = replace(
        sc,
        simulation=replace(sc.simulation, duration_s=duration_s),
        evaluation=replace(sc.evaluation, end_s=duration_s),
    )
    if scene_changes:
        sc = replace(sc, scene=replace(sc.scene, **scene_changes))
    return sc


def assert_safe(summary: dict, out, allow_hv_braking: tuple[str, ...] = ()) -> None:
    assert summary["safety"]["collisions"] == 0
    assert summary["safety"]["teleports"] == 0
    df = pd.read_parquet(out / "trajectories.parquet")
    brakes = hard_brake_events(df)
    assert brakes[brakes["kind"] == "cav"].empty, brakes
    others = brakes[~brakes["vehicle"].isin(allow_hv_braking)]
    assert others.empty, others


def test_cav_removed_mid_manoeuvre(tmp_path):
    def remove(ctx):
        ctx.session.remove_vehicle("cav2")

    summary = run_scenario(paper(), "swarm", tmp_path, progress=False,
                           controller=Injector(SwarmController(), 12.0, remove))  # fmt: skip
    assert_safe(summary, tmp_path)
    events = [json.loads(x) for x in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert any(e["event"] == "cav_set_changed" for e in events)
    plans = [json.loads(x) for x in (tmp_path / "plans.jsonl").read_text().splitlines()]
    assert any(p["trigger"] == "cav_set_changed" and "cav2" not in (p["cells"] or {})
               for p in plans)  # fmt: skip
    df = pd.read_parquet(tmp_path / "trajectories.parquet")
    end = df[df["time_s"] == df["time_s"].max()]
    assert set(end[end["kind"] == "cav"]["vehicle"]) == {"cav0", "cav1", "cav3", "cav4", "cav5"}


def test_hv_braking_hard_in_front_of_a_blocker(tmp_path):
    # An HV drives in the left lane ahead of where the leader blocks; at 8 s it brakes at
    # -4 m/s^2 for 2 s (17.5 -> 9.5 m/s), then drives on at 9.5 m/s.
    sc = load_scenario(PAPER)
    ahead = HvPlacement(id="hv_ahead", lane=2, front_m=345.0, speed_mps=17.5,
                        desired_speed_mps=17.5)  # fmt: skip
    sc = paper(hv=(*sc.scene.hv, ahead))

    def brake(ctx):
        ctx.session.api.vehicle.slowDown("hv_ahead", 9.5, 2.0)

    summary = run_scenario(sc, "swarm", tmp_path, progress=False,
                           controller=Injector(SwarmController(), 8.0, brake))  # fmt: skip
    assert_safe(summary, tmp_path, allow_hv_braking=("hv_ahead",))
    assert summary["cav"]["gap_min_m"] > 0.0


@pytest.mark.parametrize(("vehicle", "speed_mps"), [("hv_left", 21.0), ("hv_target", 15.0)])
def test_hv_faster_or_slower_than_predicted(tmp_path, vehicle, speed_mps):
    # From 6 s on the HV heads for another speed than the constant one the planner predicts,
    # changing speed at 1 m/s^2 (a new maxSpeed alone would make SUMO jump to it in one step).
    def change(ctx):
        api = ctx.session.api
        if speed_mps < api.vehicle.getSpeed(vehicle):
            api.vehicle.slowDown(vehicle, speed_mps, 17.5 - speed_mps)
        api.vehicle.setMaxSpeed(vehicle, max(speed_mps, api.vehicle.getSpeed(vehicle)))

    summary = run_scenario(paper(), "swarm", tmp_path, progress=False,
                           controller=Injector(SwarmController(), 6.0, change))  # fmt: skip
    assert_safe(summary, tmp_path)
    assert summary["cav"]["gap_min_m"] > 0.0


class NoisySwarm(SwarmController):
    """The swarm reading noisy states: position sigma 0.3 m, speed 0.2 m/s, lateral 0.05 m."""

    rng = np.random.default_rng(7)

    def control(self, t_s: float) -> None:
        session = self.ctx.session
        true_states = session.states
        noisy = {}
        for vid, st in true_states.items():
            e = self.rng.normal(size=3)
            noisy[vid] = VehicleState(
                vid, st.s_m + 0.3 * e[0], st.lane, st.lat_m + 0.05 * e[1],
                max(0.0, st.speed_mps + 0.2 * e[2]), st.length_m, st.accel_mps2, st.is_cav,
            )  # fmt: skip
        session.states = noisy
        try:
            super().control(t_s)
        finally:
            session.states = true_states


def test_noise_on_the_states_read(tmp_path):
    summary = run_scenario(paper(), "swarm", tmp_path, progress=False, controller=NoisySwarm())
    assert_safe(summary, tmp_path)
    assert summary["overtake"]["completed"]
    assert summary["cav"]["gap_min_m"] >= 4.0


def test_sumo_exiting_mid_run_keeps_the_outputs(tmp_path):
    def kill(ctx):
        ctx.session.api.close()

    with pytest.raises(SimulationError, match="outputs so far kept"):
        run_scenario(paper(), "cacc", tmp_path, progress=False,
                     controller=Injector(SwarmController(), 5.0, kill))  # fmt: skip
    df = pd.read_parquet(tmp_path / "trajectories.parquet")
    assert df["time_s"].max() == pytest.approx(5.0, abs=0.05)
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["sim_end_s"] == pytest.approx(5.0, abs=0.05)
    events = (tmp_path / "events.jsonl").read_text()
    assert "sumo_failed" in events or "run_failed" in events
    assert summary["complete"] is False and summary["incomplete_reason"]
    assert json.loads((tmp_path / "run.json").read_text())["state"] == "incomplete"


def test_a_run_that_records_nothing_still_writes_its_outputs(tmp_path):
    # Every step before record_from_s: no row at all. The run ends as any other: an empty
    # trajectory table with the usual columns and a summary.
    from sumo_swarm.sim.recorder import RECORD_COLUMNS

    sc = paper(5.0)
    sc = replace(sc, outputs=replace(sc.outputs, record_from_s=100.0))
    summary = run_scenario(sc, "cacc", tmp_path, progress=False)
    df = pd.read_parquet(tmp_path / "trajectories.parquet")
    assert df.empty and list(df.columns) == list(RECORD_COLUMNS)
    assert summary["safety"]["collisions"] == 0
    assert json.loads((tmp_path / "summary.json").read_text())["controller"] == "cacc"


# --------------------------------------------------------------------------- ends before the end


def read_folder(out) -> tuple[dict, dict, pd.DataFrame, list[dict]]:
    """run.json, summary.json, the trajectories and the events of a run folder."""
    manifest = json.loads((out / "run.json").read_text())
    summary = json.loads((out / "summary.json").read_text())
    df = pd.read_parquet(out / "trajectories.parquet")
    events = [json.loads(x) for x in (out / "events.jsonl").read_text().splitlines()]
    return manifest, summary, df, events


def no_staging_left(out) -> bool:
    return not [p for p in out.parent.iterdir() if p.name.startswith(f"{out.name}.partial-")]


def send(sig: signal.Signals, times: int = 1) -> Callable[[RunContext], None]:
    def action(ctx: RunContext) -> None:
        for _ in range(times):
            os.kill(os.getpid(), sig)

    return action


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_signal_mid_run_writes_what_was_gathered_marked_incomplete(tmp_path, sig):
    out = tmp_path / "run"
    with pytest.raises(RunInterrupted) as stopped:
        run_scenario(paper(), "swarm", out, progress=False,
                     controller=Injector(SwarmController(), 5.0, send(sig, times=2)))  # fmt: skip
    assert stopped.value.exit_status == 128 + sig
    assert f"interrupted by {sig.name} at t = 5.0" in stopped.value.message
    assert str(out) in stopped.value.message and "\n" not in stopped.value.message
    manifest, summary, df, events = read_folder(out)
    assert manifest["state"] == "incomplete" and sig.name in manifest["reason"]
    assert summary["complete"] is False
    assert summary["incomplete_reason"] == manifest["reason"]
    assert list(summary)[4:6] == ["complete", "incomplete_reason"]  # the contract's place
    # the steps up to the signal (the step under way ends first), nothing after
    assert df["time_s"].max() == pytest.approx(5.0, abs=0.05)
    assert summary["sim_end_s"] == pytest.approx(df["time_s"].max())
    assert events[-1]["event"] == "interrupted" and events[-1]["signal"] == sig.name
    assert (out / "plans.jsonl").read_text().strip()  # the swarm's plans so far
    assert no_staging_left(out)


def test_a_signal_before_the_first_step_leaves_an_empty_incomplete_run(tmp_path):
    class SignalOnAttach(Injector):
        def attach(self, ctx: RunContext) -> None:  # SUMO has started, no step made yet
            super().attach(ctx)
            os.kill(os.getpid(), signal.SIGTERM)

    out = tmp_path / "run"
    controller = SignalOnAttach(SwarmController(), 1e9, send(signal.SIGTERM))
    with pytest.raises(RunInterrupted, match=r"at t = 0\.00 s"):
        run_scenario(paper(5.0), "cacc", out, progress=False, controller=controller)
    manifest, summary, df, _ = read_folder(out)
    assert manifest["state"] == "incomplete" and summary["complete"] is False
    assert df.empty


def test_a_stop_asked_before_sumo_starts_writes_nothing(tmp_path):
    stop = StopRequest()
    stop.request(signal.SIGINT)
    out = tmp_path / "run"
    with pytest.raises(RunInterrupted, match="nothing written"):
        run_scenario(paper(5.0), "cacc", out, progress=False, stop=stop)
    assert not out.exists() and no_staging_left(out)


def test_signals_while_the_outputs_are_written_leave_the_run_complete(tmp_path):
    class SignalAtSummary(Injector):
        def summary(self):  # asked for when the run's outputs are being written
            send(signal.SIGTERM, times=2)(self.ctx)
            return super().summary()

    out = tmp_path / "run"
    controller = SignalAtSummary(SwarmController(), 1e9, send(signal.SIGTERM))
    with pytest.raises(RunInterrupted, match="after the last step: the run is complete"):
        run_scenario(paper(5.0), "swarm", out, progress=False, controller=controller)
    manifest, summary, df, _ = read_folder(out)
    assert manifest["state"] == "complete" and summary["complete"] is True
    assert summary["incomplete_reason"] is None
    assert df["time_s"].max() == pytest.approx(5.0, abs=0.05)
    assert no_staging_left(out)


def test_a_failure_mid_run_is_written_marked_incomplete(tmp_path):
    # A failure outside the controller: reading SUMO breaks. (A controller's own error stands
    # the swarm down and the run goes on: the tests of StandDown below.)
    def fail(ctx):
        def broken() -> None:
            raise RuntimeError("the reading broke")

        ctx.session.refresh = broken

    out = tmp_path / "run"
    with pytest.raises(SimulationError, match="the reading broke") as failed:
        run_scenario(paper(), "swarm", out, progress=False,
                     controller=Injector(SwarmController(), 4.0, fail))  # fmt: skip
    assert str(out) in str(failed.value)
    manifest, summary, df, events = read_folder(out)
    assert summary["complete"] is False
    assert summary["incomplete_reason"].startswith("RuntimeError at t = 4.0")
    assert manifest["state"] == "incomplete"
    assert df["time_s"].max() == pytest.approx(4.0, abs=0.05)
    assert events[-1]["event"] == "run_failed"


def test_a_complete_run_says_so(tmp_path):
    summary = run_scenario(paper(3.0), "cacc", tmp_path, progress=False)
    assert summary["complete"] is True and summary["incomplete_reason"] is None
    manifest = json.loads((tmp_path / "run.json").read_text())
    assert manifest["state"] == "complete" and manifest["reason"] is None
    assert "summary.json" in manifest["files"] and "trajectories.parquet" in manifest["files"]


def test_a_failure_while_the_outputs_are_written_leaves_them_marked_incomplete(tmp_path):
    class BrokenSummary(Injector):
        def summary(self):
            raise ValueError("no summary today")

    out = tmp_path / "run"
    controller = BrokenSummary(SwarmController(), 1e9, send(signal.SIGTERM))
    with pytest.raises(ValueError, match="no summary today"):
        run_scenario(paper(3.0), "swarm", out, progress=False, controller=controller)
    manifest = json.loads((out / "run.json").read_text())
    assert manifest["state"] == "incomplete"
    assert manifest["reason"].endswith("could not all be written: ValueError: no summary today")
    assert (out / "trajectories.parquet").is_file() and not (out / "summary.json").exists()
    assert no_staging_left(out)


def test_bad_input_found_once_sumo_runs_leaves_the_folder_as_it_was(tmp_path):
    from sumo_swarm.errors import ConfigError

    class BadAttach(Injector):
        def attach(self, ctx: RunContext) -> None:
            raise ConfigError("a setting the controller refuses")

    first = run_scenario(paper(2.0), "cacc", tmp_path / "run", progress=False)
    before = (tmp_path / "run" / "summary.json").read_text()
    controller = BadAttach(SwarmController(), 1e9, send(signal.SIGTERM))
    with pytest.raises(ConfigError):
        run_scenario(paper(2.0), "swarm", tmp_path / "run", progress=False, force=True,
                     controller=controller)  # fmt: skip
    assert (tmp_path / "run" / "summary.json").read_text() == before
    assert first["controller"] == "cacc" and no_staging_left(tmp_path / "run")


def test_a_signal_ignored_before_the_run_stays_ignored(tmp_path):
    # nohup ignores SIGHUP: a run under it goes on when the terminal closes
    controller = Injector(SwarmController(), 1.0, send(signal.SIGHUP))
    previous = signal.signal(signal.SIGHUP, signal.SIG_IGN)
    try:
        summary = run_scenario(paper(3.0), "cacc", tmp_path / "run", progress=False,
                               controller=controller)  # fmt: skip
        assert signal.getsignal(signal.SIGHUP) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGHUP, previous)
    assert summary["complete"] is True and summary["sim_end_s"] == pytest.approx(3.0)


# ------------------------------------------------------------------------------------------
# A controller's error mid-run: one event, one warning, the swarm stands down


class _Broken:
    """A controller whose every step fails; with ``fallback``, its fallback fails too."""

    name = "broken"

    def __init__(self, fallback: bool = False) -> None:
        self.steps = 0
        if fallback:
            self.fallback = self._fallback
        self.fallbacks = 0

    def attach(self, ctx: RunContext) -> None:
        self.ctx = ctx

    def control(self, t_s: float) -> None:
        self.steps += 1
        raise KeyError("a bug")

    def _fallback(self, t_s: float) -> None:
        self.fallbacks += 1
        raise ZeroDivisionError("the fallback too")

    def summary(self):
        return {}


def _events(folder) -> list[dict]:
    return [json.loads(line) for line in (folder / "events.jsonl").read_text().splitlines()]


def test_a_controller_error_is_one_warning_and_one_event_and_the_swarm_stands_down(
    tmp_path, caplog
):
    from tests.test_swarm_sumo import _BrokenTracker

    with caplog.at_level(logging.DEBUG, logger="sumo_swarm"):
        summary = run_scenario(paper(12.0), "swarm", tmp_path, progress=False,
                               controller=SwarmController(tracker=_BrokenTracker()))  # fmt: skip
    warnings = [r for r in caplog.records if r.levelno >= logging.WARNING]
    assert len(warnings) == 1, [r.getMessage() for r in warnings]
    assert (
        "stood down" in warnings[0].getMessage() and "ZeroDivisionError" in warnings[0].getMessage()
    )
    assert not any(r.exc_info for r in caplog.records if r.levelno >= logging.INFO)
    errors = [e for e in _events(tmp_path) if e["event"] == "controller_error"]
    assert len(errors) == 1 and errors[0]["action"] == "stood_down"
    # where in our code: the bug report's first line (the broken tracker is the test's)
    assert errors[0]["where"].startswith(("controllers/", "core/")), errors[0]["where"]
    stood = summary["stood_down"]
    assert stood["t_s"] == pytest.approx(errors[0]["time_s"]) and stood["then"] == "fallback"
    assert "ZeroDivisionError: a bug" in stood["reason"]
    assert json.loads((tmp_path / "summary.json").read_text())["stood_down"] == stood
    assert summary["overtake"]["abort_reasons"] == {"controller_error": 1}
    assert_safe(summary, tmp_path)  # the CAVs drove on as a CACC platoon, to the end
    assert summary["sim_end_s"] == pytest.approx(12.0, abs=0.05)


def test_a_run_without_error_has_not_stood_down(tmp_path):
    summary = run_scenario(paper(2.0), "cacc", tmp_path, progress=False)
    assert summary["stood_down"] is None


@pytest.mark.parametrize("fallback", [False, True])
def test_without_a_working_fallback_the_cavs_are_handed_back_to_sumo(tmp_path, fallback):
    broken = _Broken(fallback=fallback)
    summary = run_scenario(paper(6.0), "cacc", tmp_path, progress=False, controller=broken)
    assert broken.steps == 1  # called once, never again
    assert broken.fallbacks == (1 if fallback else 0)
    assert summary["stood_down"]["then"] == "sumo"
    assert "KeyError" in summary["stood_down"]["reason"]
    assert len([e for e in _events(tmp_path) if e["event"] == "controller_error"]) == 1
    assert summary["sim_end_s"] == pytest.approx(6.0, abs=0.05)
    assert summary["safety"]["collisions"] == 0
    df = pd.read_parquet(tmp_path / "trajectories.parquet")
    late = df[(df["kind"] == "cav") & (df["time_s"] > 3.0)]
    assert late["speed_mps"].min() > 10.0  # SUMO drove them on; nobody stopped


CLI_WITH_A_BUG = """
import sys
import sumo_swarm.sim.runner as runner
from sumo_swarm.cli import main
from sumo_swarm.controllers.swarm import SwarmController
from tests.test_swarm_sumo import _BrokenTracker

runner.make_controller = lambda name: SwarmController(tracker=_BrokenTracker())
sys.exit(main(sys.argv[1:]))
"""


def test_a_controller_error_in_the_command_line_run_is_one_line_and_exit_1(tmp_path):
    import subprocess
    import sys

    from tests.conftest import ROOT

    scenario = tmp_path / "short.toml"
    scenario.write_text(
        PAPER.read_text().replace("duration_s = 80.0", "duration_s = 6.0")
        .replace("end_s = 60.0", "end_s = 6.0")
        .replace('"../networks/', f'"{(ROOT / "networks").as_posix()}/')
    )  # fmt: skip
    proc = subprocess.run(
        [sys.executable, "-c", CLI_WITH_A_BUG, "run", str(scenario), "--out", str(tmp_path / "o")],
        capture_output=True, text=True, timeout=300, cwd=ROOT,
    )  # fmt: skip
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "the swarm controller failed at t = " in lines[0] and "stood down" in lines[0]
    summary = json.loads((tmp_path / "o" / "summary.json").read_text())
    assert summary["stood_down"]["reason"] == "ZeroDivisionError: a bug"


def test_attach_a_controller_error_is_one_warning_not_one_per_step(tmp_path, caplog, capfd):
    import libsumo

    import sumo_swarm
    from sumo_swarm.sim.bridge import sumo_binary
    from sumo_swarm.sim.netbuild import HighwaySpec
    from tests.test_swarm_sumo import _BrokenTracker
    from tests.usercases import write_user_case

    cfg = write_user_case(tmp_path, HighwaySpec(length_m=1500, lanes=3), end_s=30.0)
    libsumo.start([sumo_binary(), "-c", str(cfg), "--lateral-resolution", "0.5",
                   "--no-step-log", "true", "--collision.action", "warn"])  # fmt: skip
    try:
        with caplog.at_level(logging.DEBUG, logger="sumo_swarm"):
            handle = sumo_swarm.attach(
                libsumo, cav_type="cav", controller=SwarmController(tracker=_BrokenTracker()),
                out_dir=tmp_path / "out",
            )  # fmt: skip
            while libsumo.simulation.getTime() < 30.0:
                libsumo.simulation.step()
            summary = handle.summary()
            handle.detach()
    finally:
        libsumo.close()
    warnings = [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]
    warnings = [w for w in warnings if "teleports" not in w]  # SUMO's jam teleports: 300 s
    assert len(warnings) == 1 and "stood down" in warnings[0], warnings
    assert "Traceback" not in capfd.readouterr().err
    assert summary["stood_down"]["then"] == "fallback"
    assert 0.0 < summary["stood_down"]["t_s"] < 30.0
    errors = [e for e in _events(tmp_path / "out") if e["event"] == "controller_error"]
    assert len(errors) == 1
    assert json.loads((tmp_path / "out" / "summary.json").read_text())["stood_down"] is not None
    assert summary["safety"]["collisions"] == 0
