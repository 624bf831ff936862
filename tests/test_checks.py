"""The one range check, finite-or-None and the atomic write: hand-made cases, known answers."""

from __future__ import annotations

import json
import math

import pandas as pd
import pytest

from sumo_swarm.checks import check_fields, finite_or_none, is_number, require_number
from sumo_swarm.errors import ConfigError
from sumo_swarm.files import write_atomic, write_json_atomic, write_parquet_atomic


@pytest.mark.parametrize(
    ("value", "bounds", "message"),
    [
        (-5.0, {"gt": 0.0}, "x must be > 0, got -5.0"),
        (0, {"gt": 0.0}, "x must be > 0, got 0"),
        (math.nan, {"gt": 0.0}, "x must be a finite number > 0, got nan"),
        (math.inf, {}, "x must be a finite number, got inf"),
        (-math.inf, {"lt": 0.0}, "x must be a finite number < 0, got -inf"),
        (True, {}, "x must be a finite number, got True"),
        ("3", {}, "x must be a finite number, got '3'"),
        (1.5, {"integer": True}, "x must be an integer, got 1.5"),
        (0, {"ge": 1, "integer": True}, "x must be an integer >= 1, got 0"),
        (2.0, {"gt": 0.0, "le": 1.0}, "x must be > 0 and <= 1, got 2.0"),
        (1.0, {"lt": 1.0}, "x must be < 1, got 1.0"),
    ],
)
def test_require_number_refuses(value, bounds, message):
    with pytest.raises(ConfigError) as err:
        require_number("x", value, **bounds)
    assert str(err.value) == message


@pytest.mark.parametrize(
    ("value", "bounds"),
    [(1e-9, {"gt": 0.0}), (0.0, {"ge": 0.0}), (1.0, {"le": 1.0}), (7, {"integer": True}), (-3, {})],
)
def test_require_number_accepts(value, bounds):
    require_number("x", value, **bounds)


def test_check_fields_skips_none_and_names_the_field():
    class Owner:
        a_m = 2.0
        b_m = None
        c_m = -1.0

    check_fields(Owner(), "a_m", "b_m", gt=0.0)
    with pytest.raises(ConfigError, match=r"^c_m must be >= 0, got -1.0$"):
        check_fields(Owner(), "a_m", "c_m", ge=0.0)


def test_finite_or_none():
    assert finite_or_none(None) is None
    assert finite_or_none(math.nan) is None
    assert finite_or_none(-math.inf) is None
    assert finite_or_none(3) == 3.0 and isinstance(finite_or_none(3), float)
    assert is_number(2) and not is_number(False) and not is_number(math.nan)


def test_atomic_writes_replace_the_file_and_leave_no_temporary(tmp_path):
    path = tmp_path / "a.json"
    write_json_atomic(path, {"x": 1})
    write_json_atomic(path, {"x": 2})
    assert json.loads(path.read_text()) == {"x": 2}
    table = tmp_path / "t.parquet"
    write_parquet_atomic(table, pd.DataFrame({"v": [1.5, 2.5]}))
    assert pd.read_parquet(table)["v"].tolist() == [1.5, 2.5]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.json", "t.parquet"]


def test_a_failed_write_keeps_the_old_file(tmp_path):
    path = tmp_path / "a.json"
    write_json_atomic(path, {"x": 1})
    with pytest.raises(ValueError):  # NaN is not JSON: refused before anything is replaced
        write_json_atomic(path, {"x": math.nan})

    def half_then_crash(tmp):
        tmp.write_text('{"x": ', encoding="utf-8")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_atomic(path, half_then_crash)
    assert json.loads(path.read_text()) == {"x": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


def test_parquet_dictionaries_for_names_and_integers_plain_floats(tmp_path):
    import pyarrow.parquet as pq

    df = pd.DataFrame(
        {
            "vehicle": pd.Categorical(["a", "b", "a", "c"]),
            "lane": pd.array([0, 1, 0, 2], dtype="int16"),
            "speed": [10.0, 11.5, 10.0, 9.25],
        }
    )
    path = tmp_path / "t.parquet"
    write_parquet_atomic(path, df)
    pd.testing.assert_frame_equal(pd.read_parquet(path), df)
    meta = pq.ParquetFile(path).metadata.row_group(0)
    encodings = {meta.column(i).path_in_schema: meta.column(i).encodings for i in range(3)}
    assert any("DICTIONARY" in e for e in encodings["vehicle"])
    assert any("DICTIONARY" in e for e in encodings["lane"])
    assert not any("DICTIONARY" in e for e in encodings["speed"])
