"""The pure parts behind the bad-input answers: reading a user's file, the nearest known name,
SUMO's saved paths, and which file a SUMO error is about (hand-made cases, known answers)."""

from __future__ import annotations

import os
import threading

import pytest

from sumo_swarm.checks import did_you_mean, unknown_name
from sumo_swarm.errors import ConfigError
from sumo_swarm.sim.bridge import require_display, unknown_vtype
from sumo_swarm.sim.sumoerrors import blame, input_error
from sumo_swarm.userfiles import (
    check_sumo_path,
    read_user_bytes,
    read_user_json,
    read_user_text,
    sumo_saved_path,
    xml_root_name,
)


def test_a_regular_file_is_read(tmp_path):
    path = tmp_path / "ü é.toml"
    path.write_text("a = 1\n", encoding="utf-8")
    assert read_user_text(path, "scenario file") == "a = 1\n"


def test_a_fifo_is_refused_without_waiting_for_a_writer(tmp_path):
    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    result: list[BaseException] = []
    reader = threading.Thread(target=lambda: _catch(result, read_user_bytes, fifo, "file"))
    reader.start()
    reader.join(timeout=5.0)
    assert not reader.is_alive(), "reading a FIFO hangs"
    assert "not a regular file (a FIFO)" in str(result[0])


def _catch(into: list, fn, *args) -> None:
    try:
        fn(*args)
    except ConfigError as exc:
        into.append(exc)


def test_a_file_larger_than_its_bound_is_refused_before_it_is_read(tmp_path):
    path = tmp_path / "big"
    path.write_bytes(b"x" * 101)
    with pytest.raises(ConfigError, match=r"101 bytes, more than the 9.53674e-05 MiB"):
        read_user_bytes(path, "file", max_bytes=100)
    assert read_user_bytes(path, "file", max_bytes=101) == b"x" * 101


def test_an_endless_file_that_says_it_is_empty_is_cut_at_the_bound():
    # /proc files are regular and report size 0, however much they hold
    data = read_user_bytes("/proc/self/status", "file", max_bytes=1 << 20)
    assert b"Pid:" in data
    with pytest.raises(ConfigError, match="more than"):
        read_user_bytes("/proc/self/status", "file", max_bytes=10)


@pytest.mark.parametrize(("text", "fragment"), [(b"\xff\xfe", "not UTF-8"), (b"[1,", "malformed")])
def test_bad_text_and_json_name_the_file(tmp_path, text, fragment):
    path = tmp_path / "r.json"
    path.write_bytes(text)
    with pytest.raises(ConfigError, match=fragment) as caught:
        read_user_json(path, "record")
    assert str(path) in str(caught.value)


@pytest.mark.parametrize(
    ("name", "known", "nearest"),
    [
        ("lenght_m", ["count", "length_m"], "length_m"),
        ("cva", ["car", "cav", "truck"], "cav"),
        ("Swarm", ["swarm", "cacc"], "swarm"),
        ("base", ["scene", "cav", "grid"], None),  # nothing near: no guess
        ("zzzz", [], None),
    ],
)
def test_did_you_mean(name, known, nearest):
    assert did_you_mean(name, known) == nearest


def test_unknown_name_message():
    text = unknown_name("key", "lenght_m", ["count", "length_m"], prefix="cav.")
    assert (
        text == "unknown key 'cav.lenght_m': did you mean 'cav.length_m'? (known: count, length_m)"
    )
    assert (
        unknown_name("section", "x", ["cav"], shown="[{}]")
        == "unknown section '[x]' (known: [cav])"
    )


def test_unknown_vtype_lists_the_users_types_only():
    present = ["DEFAULT_VEHTYPE", "DEFAULT_PEDTYPE", "car", "cav", "cav@c0", "truck"]
    assert unknown_vtype("cav", present) is None
    assert unknown_vtype("DEFAULT_VEHTYPE", present) is None  # accepted, just not listed
    message = unknown_vtype("CAV", present)
    assert message == (
        "unknown vType 'CAV': did you mean 'cav'? (vTypes in the simulation: car, cav, truck)"
    )


@pytest.mark.parametrize(
    ("saved", "path"),
    [
        ("/a/my%20road%20%C3%BC/x.net.xml", "/a/my road ü/x.net.xml"),
        ("/a/my%20road%20ü/x.net.xml", "/a/my road ü/x.net.xml"),  # SUMO keeps UTF-8 as is
        ("/a/p%2541q/x.xml", "/a/p%41q/x.xml"),
        ("/a/s%3bc/x.xml", "/a/s;c/x.xml"),
        ("rel/my road/x.xml", "rel/my road/x.xml"),  # a relative one is written as it is
    ],
)
def test_sumo_saved_paths_are_decoded(saved, path):
    assert sumo_saved_path(saved) == path


def test_a_path_sumo_would_read_as_escaped():
    check_sumo_path("/a/my road ü/100% sure/x.xml", "file")  # no hex pair: fine
    with pytest.raises(ConfigError, match="'%41'"):
        check_sumo_path("/a/p%41q/x.xml", "file")


@pytest.fixture
def inputs(tmp_path):
    routes = tmp_path / "routes.rou.xml"
    routes.write_text(
        '<routes>\n  <vType id="cav" maxSpeed="0"/>\n  <route id="r" edges="e0 nowhere"/>\n'
        '  <vehicle id="c0" type="cav" route="r" depart="0"/>\n</routes>\n'
    )
    extra = tmp_path / "extra.add.xml"
    extra.write_text('<additional>\n  <vType id="truck" vClass="truck"/>\n</additional>\n')
    net = tmp_path / "road.net.xml"
    net.write_text('<net>\n  <edge id="e0"><lane id="e0_0" length="100"/></edge>\n</net>\n')
    return routes, extra, net


@pytest.mark.parametrize(
    ("message", "which"),
    [
        ("The edge 'nowhere' within the route 'r' is not known.", 0),  # defines route 'r'
        ("Invalid departLane definition for vehicle 'c0'.", 0),
        ("Unknown vehicle class 'truck' in vType 'truck'.", 1),
        ("maxSpeed must be greater than 0", 0),  # the file that sets maxSpeed
        ("Edge 'e0' has no lanes.", 2),
        ("whitespace expected In file '{extra}' At line/column 5/31.", 1),
        ("Something else entirely.", None),
    ],
)
def test_blame_finds_the_file_a_sumo_error_is_about(inputs, message, which):
    files = list(inputs)
    found = blame(message.format(extra=inputs[1]), files)
    assert found == (None if which is None else files[which])


def test_input_error_is_one_line_naming_the_file(inputs, tmp_path):
    cfg = tmp_path / "user.sumocfg"
    error = input_error(
        "SUMO did not start: The edge 'nowhere' within the route 'r' is not known.\n"
        " The route can not be build.", list(inputs), cfg,
    )  # fmt: skip
    assert str(error) == (
        f"{inputs[0]}: SUMO refuses it: The edge 'nowhere' within the route 'r' is not known. "
        f"The route can not be build. (named in {cfg})"
    )
    assert input_error("SUMO stopped at t = 3.00 s: lost", list(inputs), cfg, strict=True) is None
    generic = input_error("Process Error", list(inputs), cfg)
    assert str(generic) == f"{cfg}: SUMO did not start: Process Error"


def test_an_error_about_a_generated_file_names_the_configuration(tmp_path, inputs):
    ours = tmp_path / "sumo" / "routes.rou.xml"
    ours.parent.mkdir()
    ours.write_text('<routes><vehicle id="cav0"/></routes>')
    scenario = tmp_path / "s.toml"
    error = input_error("Invalid departLane definition for vehicle 'cav0'.", [inputs[2]],
                        scenario, generated=[ours], strict=True)  # fmt: skip
    assert str(error).startswith(f"{scenario}: SUMO stopped: Invalid departLane")


@pytest.mark.parametrize(
    ("env", "platform", "fragment"),
    [
        ({}, "linux", "DISPLAY is not set"),
        ({"DISPLAY": ":93"}, "linux", "no X server answers at DISPLAY=:93"),
        ({"DISPLAY": "127.0.0.1:93"}, "linux", "no X server answers"),
        ({}, "darwin", None),
        ({}, "win32", None),
    ],
)
def test_require_display(env, platform, fragment):
    if fragment is None:
        require_display(env, platform)
    else:
        with pytest.raises(ConfigError, match=fragment):
            require_display(env, platform)


@pytest.mark.parametrize(
    ("data", "root"),
    [
        (b'<?xml version="1.0"?>\n<!-- c <x> -->\n<configuration/>', "configuration"),
        (b"  <routes>\n<vType id='a'/></routes>", "routes"),
        ('<?xml version="1.0" encoding="UTF-16"?><net/>'.encode("utf-16"), "net"),
        (b"not xml at all", None),
        (b"", None),
    ],
)
def test_the_root_element_is_read_from_the_first_bytes(tmp_path, data, root):
    path = tmp_path / "f.xml"
    path.write_bytes(data)
    assert xml_root_name(path) == root
    assert xml_root_name(tmp_path / "missing.xml") is None
