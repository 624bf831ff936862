"""tools/oldest_deps.py: the pins of the oldest releases pyproject.toml allows."""

from __future__ import annotations

import tomllib

from tests.toolload import ROOT, load_tool

oldest = load_tool("oldest_deps")


def test_a_floor_becomes_the_release_line_of_the_floor():
    assert oldest.floor_pin("pandas>=2.1") == "pandas==2.1.*"
    assert oldest.floor_pin("pyarrow>=15,<24") == "pyarrow==15.*"  # the floor lies below the cap
    assert oldest.floor_pin("imageio-ffmpeg>=0.4.9") == "imageio-ffmpeg==0.4.9.*"
    assert oldest.floor_pin("mkdocstrings[python]>=0.26") == "mkdocstrings[python]==0.26.*"
    assert oldest.floor_pin("anything") == "anything"  # no floor: as it is


def test_every_dependency_and_test_tool_is_pinned_to_its_floor():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    wanted = [*project["dependencies"], *project["optional-dependencies"]["test"]]
    pins = oldest.pins()
    assert all("==" in p and p.endswith(".*") for p in pins), pins
    names = {p.split("==")[0] for p in pins}
    for requirement in wanted:
        name = requirement.split(">=")[0].split("[")[0].strip()
        assert name in names or name in oldest.NOT_NEEDED, name
    assert "pandas==2.1.*" in pins and "numpy==1.26.*" in pins
