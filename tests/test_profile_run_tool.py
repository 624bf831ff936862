"""tools/profile_run.py: every part names a function that exists, and a profile's times are
summed per part (a hand-made profile with known times)."""

from __future__ import annotations

from types import SimpleNamespace

from tests.toolload import load_tool

prof = load_tool("profile_run")


def test_every_part_names_a_function_of_the_code():
    # A function renamed or moved would leave its part at 0 s without a word: it fails here.
    for name, functions in prof.PARTS:
        for spec in functions:
            file, line, function = prof._key(spec)
            assert file.endswith(".py") and line > 0, (name, spec)
            assert function.isidentifier(), (name, spec)


def test_parts_take_their_functions_cumulative_time_and_the_outermost_import():
    step = prof._key("libsumo.libsumo:simulation.step")
    review = prof._key("sumo_swarm.controllers.fleet:Fleet._review")
    table = {
        step: (1500, 1500, 3.0, 3.5, {}),
        review: (400, 400, 0.2, 1.25, {}),
        ("<frozen importlib._bootstrap>", 1165, "_find_and_load"): (700, 20, 0.1, 0.75, {}),
        ("elsewhere.py", 1, "step"): (1, 1, 9.0, 9.0, {}),  # another "step": not SUMO's
    }
    times = dict(prof.part_times(SimpleNamespace(stats=table)))
    assert times["SUMO's steps"] == 3.5
    assert times["controllers: membership reviews"] == 1.25
    assert times["imports"] == 0.75
    assert times["recording"] == 0.0  # not in the profile
    assert list(times) == [name for name, _ in prof.PARTS] + ["imports"]


def test_without_the_runs_arguments_it_says_how_to_give_them(capsys):
    assert prof.main(["--out", "x"]) == 2
    assert "after --" in capsys.readouterr().err
