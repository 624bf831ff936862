"""The one account of manoeuvres (core/swarming/account.py): the book's events, the list folded
from them, the blocks derived from it; the rules that summary and events agree
(tests/contract.py), shown to fail on a pair that disagrees; and a lane pass on a user's road,
with real SUMO, said to be one: every CAV past, regrouped."""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from sumo_swarm.core.model import VehicleState
from sumo_swarm.core.swarming.account import (
    ManoeuvreBook,
    manoeuvres_from_events,
    overtake_counts,
    overtake_outcome,
)
from sumo_swarm.sim.summary import manoeuvre_line
from sumo_swarm.sim.userroads import CAV_COUNT, write_road
from tests.conftest import run_problems
from tests.contract import manoeuvre_problems

ROOT = Path(__file__).resolve().parent.parent


class Log:
    """Events as RunContext.event writes them, stamped with the clock's time [s]."""

    def __init__(self) -> None:
        self.events: list[dict] = []
        self.t_s = 0.0

    def __call__(self, name: str, /, **data) -> None:
        self.events.append({"time_s": self.t_s, "event": name, "platoon": 0, **data})


def car(vid: str, s_m: float, lane: int = 1, length_m: float = 5.0) -> VehicleState:
    return VehicleState(vid, s_m, lane, 0.0, 20.0, length_m)


def test_a_give_up_then_one_by_one_is_two_manoeuvres_with_their_passes():
    log = Log()
    book = ManoeuvreBook(log, min_gap_m=1.0)
    truck = car("truck", 100.0, lane=0, length_m=12.0)
    log.t_s = 3.0
    book.start(3.0, "cells", "truck", ["c0", "c1"])
    log.t_s = 10.0  # c0's rear 1.5 m ahead of the truck's front: past; c1 behind
    book.watch(10.0, {"truck": truck, "c0": car("c0", 106.5), "c1": car("c1", 80.0)})
    book.end(10.0, book.current("cells"), completed=False, reason="no_way_past")
    book.start(10.0, "one_by_one", "truck", ["c0", "c1"], watched=True, until_s=40.0)
    log.t_s = 20.0  # c1's rear exactly at the truck's front + 0.5 m: not past yet (min gap 1)
    book.watch(20.0, {"truck": truck, "c0": car("c0", 130.0), "c1": car("c1", 105.5)})
    assert book.current() is not None
    log.t_s = 21.0
    book.watch(21.0, {"truck": truck, "c0": car("c0", 131.0), "c1": car("c1", 106.0)})
    assert book.current() is None  # every CAV past: the book ended it
    listed = manoeuvres_from_events(log.events)
    assert [(m["kind"], m["outcome"], m["cavs_past"], m["t_end_s"]) for m in listed] == [
        ("cells", "aborted:no_way_past", 1, 10.0),
        ("one_by_one", "completed", 2, 21.0),
    ]
    assert overtake_counts(listed) == {
        "overtakes_started": 2, "overtakes_completed": 1,
        "overtakes_aborted": 1, "overtakes_running": 0,
    }  # fmt: skip
    ot = overtake_outcome(listed, 3.0)
    assert ot["triggered"] and not ot["completed"] and ot["t_end_s"] is None
    assert ot["abort_reasons"] == {"no_way_past": 1} and ot["behaving_steps"] is None


def test_a_watched_manoeuvre_times_out_and_one_under_way_at_the_end_is_running():
    log = Log()
    book = ManoeuvreBook(log, min_gap_m=1.0)
    states = {"truck": car("truck", 100.0, lane=0), "c0": car("c0", 50.0)}
    book.start(0.0, "one_by_one", "truck", ["c0"], watched=True, until_s=5.0)
    log.t_s = 5.1
    book.watch(5.1, states)
    log.t_s = 6.0
    book.start(6.0, "lane_pass", "truck", ["c0"])
    listed = manoeuvres_from_events(log.events)
    assert [m["outcome"] for m in listed] == ["aborted:timeout", "running"]
    assert listed[1]["t_end_s"] is None
    with pytest.raises(ValueError, match="unknown manoeuvre kind"):
        book.start(7.0, "teleport", "truck", ["c0"])


def consistent_pair() -> tuple[dict, list[dict]]:
    """A lane pass that completed and regrouped, as a run writes it."""
    log = Log()
    book = ManoeuvreBook(log, min_gap_m=1.0)
    log.t_s = 5.0
    book.start(5.0, "lane_pass", "truck", ["c0", "c1"])
    log.t_s = 20.0
    states = {"truck": car("truck", 100.0), "c0": car("c0", 140.0), "c1": car("c1", 120.0)}
    book.end(20.0, book.current(), completed=True, states=states)
    listed = manoeuvres_from_events(log.events)
    listed[0].update(regrouped=True, t_regrouped_s=30.0, t_past_s=19.0)
    summary = {
        "schema": "sumo-swarm/summary/1",
        "manoeuvres": listed,
        "overtake": {**overtake_outcome(listed, 3.0), "lateral_holds": 0},
        "swarms": {"platoons_formed": 1, "max_concurrent": 1, **overtake_counts(listed)},
    }
    return summary, log.events


def test_the_rules_hold_for_a_consistent_pair_and_catch_each_disagreement():
    summary, events = consistent_pair()
    assert manoeuvre_problems(summary, events) == []
    assert summary["overtake"]["t_end_s"] == 19.0 and summary["overtake"]["completed"]
    broken = [
        ("overtake", "completed", False, "overtake.completed"),
        ("overtake", "regrouped", False, "overtake.regrouped"),
        ("swarms", "overtakes_completed", 0, "swarms.overtakes_completed"),
        ("swarms", "overtakes_aborted", 1, "swarms.overtakes_aborted"),
    ]
    for block, key, value, said in broken:
        bad = json.loads(json.dumps(summary))
        bad[block][key] = value
        assert any(said in p for p in manoeuvre_problems(bad, events)), (block, key)
    # the case: completed in the summary, not so in the event
    ev = [dict(e) for e in events]
    end = next(e for e in ev if e["event"] == "overtake_end")
    end.update(completed=False, reason="no_feasible_plan")
    assert any("its event says" in p for p in manoeuvre_problems(summary, ev))
    # a manoeuvre the events have and the list lacks
    extra = [*events, {**events[0], "time_s": 40.0, "manoeuvre": 9}]
    assert any("overtake_start events" in p for p in manoeuvre_problems(summary, extra))
    # regrouped after a manoeuvre that did not complete
    bad = json.loads(json.dumps(summary))
    bad["manoeuvres"][0]["outcome"] = "aborted:x"
    assert any("regrouped after" in p for p in manoeuvre_problems(bad, events))


def test_the_check_after_each_test_reads_a_run_folder_and_fails_an_inconsistent_one():
    summary, events = consistent_pair()
    # outside the session's temporary folders, which the check after this test reads
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        (folder / "events.jsonl").write_text("".join(json.dumps(e) + "\n" for e in events))
        (folder / "summary.json").write_text(json.dumps(summary))
        assert run_problems(folder) == []
        summary["swarms"]["overtakes_completed"] = 0
        (folder / "summary.json").write_text(json.dumps(summary))
        problems = run_problems(folder)
        assert len(problems) == 1 and "overtakes_completed" in problems[0], problems


def test_the_printed_line_says_how_far_the_first_manoeuvre_got_and_why_it_stopped():
    summary, _ = consistent_pair()
    assert manoeuvre_line(summary) == (
        "overtake of truck (lane pass from 5.0 s: 2 of 2 CAVs past, regrouped at 30.0 s)"
    )
    first = summary["manoeuvres"][0]
    first.update(outcome="aborted:target_changed_lane", reason="target_changed_lane",
                 cavs_past=1, regrouped=False)  # fmt: skip
    summary["manoeuvres"].append({**first, "outcome": "running", "kind": "one_by_one"})
    assert manoeuvre_line(summary) == (
        "overtake of truck (lane pass from 5.0 s: 1 of 2 CAVs past, stopped at 20.0 s: "
        "target_changed_lane), then (one by one from 5.0 s: 1 of 2 CAVs past, still under way "
        "at the end), 2 manoeuvres in all (0 completed, 1 stopped, 1 running)"
    )
    summary["overtake"].update(all_past=True, all_past_regrouped=False)
    assert manoeuvre_line(summary).endswith(
        "running); at the end every CAV past truck, not one platoon"
    )
    summary["overtake"]["all_past"] = False
    assert manoeuvre_line(summary).endswith("running); at the end not every CAV past truck")
    baseline = {"manoeuvres": [], "overtake": {"target": "truck", "completed": True}}
    assert manoeuvre_line(baseline) == "no manoeuvre of the controller; every CAV got past truck"


@pytest.mark.sumo
def test_a_lane_pass_on_a_users_road_says_every_cav_passed_and_regrouped(tmp_path):
    """The lane-drop road: the swarm passes the truck in the lane beside it and drives on as
    one platoon to the road's end. The summary said not triggered, not completed, not
    regrouped before (the first swarm's account was lost when its platoon dissolved there)."""
    cfg = write_road("lane-drop", tmp_path / "road", end_s=90.0)
    out = tmp_path / "swarm"
    cmd = [
        sys.executable, "-m", "sumo_swarm", "run", "--sumocfg", str(cfg), "--cav-type", "cav",
        "--controller", "swarm", "--out", str(out),
    ]  # fmt: skip
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    first = summary["manoeuvres"][0]
    assert (first["kind"], first["target"], first["outcome"]) == ("lane_pass", "truck", "completed")
    assert first["cavs"] == first["cavs_past"] == CAV_COUNT and first["regrouped"]
    ot = summary["overtake"]
    assert ot["triggered"] and ot["completed"] and ot["regrouped"] and ot["target"] == "truck"
    assert ot["t_start_s"] < ot["t_end_s"] <= first["t_end_s"] < ot["t_regrouped_s"] < 60.0
    assert summary["swarms"]["overtakes_completed"] == 1
    assert summary["swarms"]["platoons_now"] == 0  # the CAVs left at the road's end
    assert f"{CAV_COUNT} of {CAV_COUNT} CAVs past, regrouped at" in proc.stdout, proc.stdout
    assert summary["safety"]["collisions"] == 0
