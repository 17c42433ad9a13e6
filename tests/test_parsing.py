"""riskplan.parsing: the one convention for comma-separated numbers (options and table files)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from typer.testing import CliRunner

from riskplan.errors import DataFormatError, InvalidInputError
from riskplan.parsing import parse_numbers, parse_rows, read_table
from tests.properties import PROPERTY, finite_float

spaces = st.sampled_from(["", " ", "  ", "\t"])


def _join(values, pads) -> str:
    return ",".join(f"{a}{v!r}{b}" for v, (a, b) in zip(values, pads))


@PROPERTY
@given(st.data(), st.lists(finite_float, min_size=1, max_size=8))
def test_numbers_round_trip(data, values):
    # repr() of a float reads back to the same float; spaces around a field are ignored
    pads = data.draw(
        st.lists(st.tuples(spaces, spaces), min_size=len(values), max_size=len(values))
    )
    assert parse_numbers(_join(values, pads), "--x") == values


@PROPERTY
@given(st.lists(st.integers(-(10**6), 10**6), min_size=1, max_size=6))
def test_integers_round_trip(values):
    got = parse_numbers(",".join(map(str, values)), "--w", integers=True)
    assert got == values and all(type(v) is int for v in got)


@PROPERTY
@given(st.integers(1, 4), st.integers(1, 3), st.data())
def test_rows_round_trip(n_rows, n_cols, data):
    rows = data.draw(
        st.lists(
            st.lists(finite_float, min_size=n_cols, max_size=n_cols),
            min_size=n_rows,
            max_size=n_rows,
        )
    )
    text = ";".join(", ".join(repr(v) for v in r) for r in rows)
    got = parse_rows(text, "-d", columns=n_cols)
    assert got.dtype == np.float64 and got.shape == (n_rows, n_cols)
    assert got.tolist() == rows


@PROPERTY
@given(st.text(max_size=30))
def test_any_text_parses_to_finite_numbers_or_a_named_error(text):
    for fn in (
        lambda: parse_numbers(text, "--opt"),
        lambda: parse_numbers(text, "--opt", integers=True, allow_empty=True),
        lambda: parse_rows(text, "--opt"),
    ):
        try:
            out = fn()
        except InvalidInputError as exc:
            assert str(exc).startswith("--opt: ")
        else:
            assert np.all(np.isfinite(np.asarray(out, dtype=np.float64)))


@pytest.mark.parametrize(
    "text, match",
    [
        ("0.1;0.2", "';' separates rows"),
        ("0.1,,0.2", "empty field"),
        ("0.1,0.2,", "empty field"),
        ("0.1,abc", "'abc' is not a number"),
        ("0.1,nan", "not a finite number"),
        ("inf", "not a finite number"),
        ("", "expected comma-separated numbers"),
        ("  ", "expected comma-separated numbers"),
    ],
)
def test_bad_numbers_name_the_option(text, match):
    with pytest.raises(InvalidInputError, match=match) as info:
        parse_numbers(text, "--goal")
    assert str(info.value).startswith("--goal: ")


def test_count_integers_and_empty():
    with pytest.raises(InvalidInputError, match="--goal-tip: expected 3 comma-separated numbers"):
        parse_numbers("0,0", "--goal-tip", count=3)
    with pytest.raises(InvalidInputError, match=r"'64\.0' is not an integer"):
        parse_numbers("64,64.0", "--hidden", integers=True)
    assert parse_numbers("", "--head-hidden", integers=True, allow_empty=True) == []
    assert parse_numbers(" 8 , 16 ", "--hidden", integers=True) == [8, 16]


def test_rows():
    np.testing.assert_array_equal(parse_rows("0,0.5;1,2", "-d"), [[0.0, 0.5], [1.0, 2.0]])
    assert parse_rows("1,2,3", "-d").shape == (1, 3)
    with pytest.raises(InvalidInputError, match="equal length"):
        parse_rows("0,0,0,0;0,0", "-d")
    with pytest.raises(InvalidInputError, match=r"row 2 .* empty field"):
        parse_rows("0,0;", "-d")
    with pytest.raises(InvalidInputError, match="expected 4 comma-separated numbers per row"):
        parse_rows("0,0;1,1", "-d", columns=4)


def test_read_table_formats(tmp_path):
    want = [[0.1, 0.2], [0.3, 0.4]]
    csv = tmp_path / "a.csv"
    csv.write_text("# comment\nv, phi\n0.1, 0.2\n\n0.3,0.4\n")
    np.testing.assert_array_equal(read_table(csv, "controls"), want)
    js = tmp_path / "b.json"
    js.write_text(json.dumps({"controls": want}))
    np.testing.assert_array_equal(read_table(js, "controls", key="controls"), want)
    with pytest.raises(DataFormatError, match="object"):
        read_table(js, "controls")
    js.write_text(json.dumps([0.1, 0.2]))
    assert read_table(js, "x").shape == (2,)  # one row, as stored
    npy = tmp_path / "c.npy"
    np.save(npy, np.array(want))
    np.testing.assert_array_equal(read_table(npy, "x"), want)


def test_read_table_reads_a_byte_order_mark(tmp_path):
    # spreadsheet exports often start a UTF-8 file with a BOM
    path = tmp_path / "bom.csv"
    path.write_bytes("\ufeff0.1,0.2\n0.3,0.4\n".encode())
    np.testing.assert_array_equal(read_table(path, "controls"), [[0.1, 0.2], [0.3, 0.4]])


@pytest.mark.parametrize(
    "name, content, match",
    [
        ("a.csv", "0.1,0.2\n0.3\n", "line 2 has 1 numbers, the first row 2"),
        ("b.csv", "0.1,nan\n", "line 1 .* not a finite number"),
        ("c.csv", "v,phi\n0.1,0.2\nw,x\n", "line 3"),  # only one header line, before the data
        ("d.csv", "0.1;0.2\n", "one row per line"),
        ("e.csv", "v,phi\n", "non-empty"),
        ("f.json", "[[1, null]]", "NaN or inf"),
        ("g.dat", "0.1,0.2\n", "expected a file ending in"),
    ],
)
def test_read_table_errors_name_the_file(tmp_path, name, content, match):
    path = tmp_path / name
    path.write_text(content)
    with pytest.raises(DataFormatError, match=match) as info:
        read_table(path, "controls")
    assert str(info.value).startswith("controls: ") and name in str(info.value)
    with pytest.raises(DataFormatError, match="no such file"):
        read_table(tmp_path / "missing.csv", "controls")


def test_cli_options_follow_the_convention():
    from riskplan.cli import app

    runner = CliRunner()
    res = runner.invoke(app, ["robot", "shape", "-d", "0.01;0;0;0"])
    assert isinstance(res.exception, InvalidInputError)
    assert "--displacements" in str(res.exception) and "';' separates rows" in str(res.exception)
    res = runner.invoke(app, ["robot", "shape", "-t", "1,0,0"])
    assert isinstance(res.exception, InvalidInputError)
    assert "--tensions: expected 4 comma-separated numbers" in str(res.exception)
    res = runner.invoke(app, ["collision", "probability", "--arc", "8,0,1"])
    assert isinstance(res.exception, InvalidInputError) and "--arc: expected 2" in str(
        res.exception
    )
