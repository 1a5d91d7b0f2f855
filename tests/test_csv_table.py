"""Tests of apcc_graph.io.csv_table: numeric CSV tables whose errors name file, line and column."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from apcc_graph.io.csv_table import CsvTable, format_number, read_header, read_table

NAMES = ["a", "b", "c"]


def _write(tmp_path: Path, text: str, name: str = "t.csv") -> Path:
    path = tmp_path / name
    path.write_bytes(text.encode("utf-8"))
    return path


def _error(path: Path, names: list[str] = NAMES) -> str:
    with pytest.raises(ValueError) as info:
        read_table(path, names)
    return str(info.value)


# ------------------------------------------------------------------------------------ reading
def test_read_table_values_and_len(tmp_path: Path) -> None:
    path = _write(tmp_path, "a,b,c\n1,2.5,-3\n4e-3,0.1,1e300\n-0.0,7,8\n")
    table = read_table(path, NAMES)
    assert len(table) == 3
    assert table.names == NAMES
    assert table.path == path
    assert table.values.dtype == np.float64
    assert table.values.tolist() == [[1.0, 2.5, -3.0], [4e-3, 0.1, 1e300], [-0.0, 7.0, 8.0]]
    assert math.copysign(1.0, table.values[2, 0]) == -1.0
    assert table.column("b").tolist() == [2.5, 0.1, 7.0]
    assert table.line(0) == 2 and table.line(2) == 4


def test_single_row_and_single_column(tmp_path: Path) -> None:
    one_row = read_table(_write(tmp_path, "a,b,c\n1,2,3\n"), NAMES)
    assert one_row.values.shape == (1, 3)
    one_col = read_table(_write(tmp_path, "x\n1\n2\n", "x.csv"), ["x"])
    assert one_col.values.shape == (2, 1) and one_col.column("x").tolist() == [1.0, 2.0]


@pytest.mark.parametrize("text", ["a,b,c\n", "a,b,c", "a,b,c\r\n", "a,b,c\n\n\n"])
def test_empty_body_gives_zero_rows(tmp_path: Path, text: str) -> None:
    table = read_table(_write(tmp_path, text), NAMES)
    assert len(table) == 0
    assert table.values.shape == (0, 3)
    table.require_finite()
    assert table.integers("a").shape == (0,)


@pytest.mark.parametrize("ending", ["", "\n", "\n\n", "\n\n\n", "\r\n\r\n"])
def test_trailing_newlines_are_fine(tmp_path: Path, ending: str) -> None:
    newline = "\r\n" if ending.startswith("\r") else "\n"
    text = newline.join(["a,b,c", "1,2,3", "4,5,6"]) + ending
    table = read_table(_write(tmp_path, text), NAMES)
    assert table.values.tolist() == [[1, 2, 3], [4, 5, 6]]


def test_crlf_line_endings(tmp_path: Path) -> None:
    path = _write(tmp_path, "a,b,c\r\n1,2,3\r\n4,5,6.25\r\n")
    assert read_header(path) == NAMES
    table = read_table(path, NAMES)
    assert table.values.tolist() == [[1, 2, 3], [4, 5, 6.25]]


def test_crlf_errors_name_the_right_line(tmp_path: Path) -> None:
    path = _write(tmp_path, "a,b,c\r\n1,2,3\r\n4,x,6\r\n")
    assert _error(path) == f"{path}: line 3, column 'b': 'x' is not a number"
    path = _write(tmp_path, "a,b,c\r\n1,2,3\r\n\r\n4,5,6\r\n")
    assert _error(path).startswith(f"{path}: line 3: blank line")


def test_spaces_around_names_and_numbers(tmp_path: Path) -> None:
    table = read_table(_write(tmp_path, "a, b ,c\n 1 , 2 ,3\n"), NAMES)
    assert table.values.tolist() == [[1, 2, 3]]


def test_nan_and_inf_are_read_then_refused_by_require_finite(tmp_path: Path) -> None:
    path = _write(tmp_path, "a,b,c\n1,2,3\n4,5,6\n7,nan,9\n1,2,-inf\n")
    table = read_table(path, NAMES)
    assert np.isnan(table.values[2, 1]) and table.values[3, 2] == -np.inf
    with pytest.raises(ValueError) as info:
        table.require_finite()
    assert str(info.value).startswith(f"{path}: line 4, column 'b': expected a finite number")


@pytest.mark.parametrize(("line", "column", "value"),
                         [(2, "a", "inf"), (3, "c", "-inf"), (4, "b", "nan"), (4, "c", "NaN")])
def test_require_finite_names_line_and_column(tmp_path: Path, line: int, column: str,
                                              value: str) -> None:
    rows = [["1", "2", "3"], ["4", "5", "6"], ["7", "8", "9"]]
    rows[line - 2][NAMES.index(column)] = value
    path = _write(tmp_path, "a,b,c\n" + "".join(",".join(r) + "\n" for r in rows))
    table = read_table(path, NAMES)
    with pytest.raises(ValueError) as info:
        table.require_finite()
    assert str(info.value).startswith(f"{path}: line {line}, column '{column}': "
                                      "expected a finite number")


# ------------------------------------------------------------------------------------- errors
def test_hash_is_not_a_comment(tmp_path: Path) -> None:
    path = _write(tmp_path, "a,b,c\n1,2,3\n4,5#six,6\n")
    assert _error(path) == f"{path}: line 3, column 'b': '5#six' is not a number"
    path = _write(tmp_path, "a,b,c\n1,2,3\n# a comment\n4,5,6\n")
    assert _error(path) == f"{path}: line 3: expected 3 fields (a,b,c), got 1"
    path = _write(tmp_path, "a\n1\n# note\n", "one.csv")
    assert _error(path, ["a"]) == f"{path}: line 3, column 'a': '# note' is not a number"


def test_error_messages(tmp_path: Path) -> None:
    cases = {
        "a,x,c\n1,2,3\n": "line 1: column 2 is 'x', expected 'b' (header: a,b,c)",
        "a,b\n1,2\n": "line 1: missing column 'c' (header: a,b,c)",
        "a,b,c,d\n1,2,3,4\n": "line 1: unexpected extra column 'd' (header: a,b,c)",
        "a,b,c\n1,2,3\n4,5\n": "line 3: expected 3 fields (a,b,c), got 2",
        "a,b,c\n1,2,3\n4,5,6,7\n": "line 3: expected 3 fields (a,b,c), got 4",
        "a,b,c\n1,2,3\n4,5,6,\n": "line 3: expected 3 fields (a,b,c), got 4",
        "a,b,c\n1,2,3\n4,5,6\n7,8,one\n": "line 4, column 'c': 'one' is not a number",
        "a,b,c\n1,,3\n": "line 2, column 'b': '' is not a number",
        "a,b,c\n1,2,3\n\n4,5,6\n": "line 3: blank line; expected 3 fields (a,b,c)",
        "a,b,c\n\n1,2,3\n": "line 2: blank line; expected 3 fields (a,b,c)",
        "a,b,c\n1,2,3\n4,5,6\n\n\n7,8,9\n": "line 4: blank line; expected 3 fields (a,b,c)",
        "a,b,c\n1,2,3\n   \n4,5,6\n": "line 3: expected 3 fields (a,b,c), got 1",
        "": "line 1: expected a header line, the file is empty",
        "\n1,2,3\n": "line 1: expected a header line, the file is empty",
    }
    for text, message in cases.items():
        path = _write(tmp_path, text)
        assert _error(path) == f"{path}: {message}", repr(text)


def test_missing_file_and_folder(tmp_path: Path) -> None:
    missing = tmp_path / "missing.csv"
    assert _error(missing) == f"{missing}: no such file"
    assert _error(tmp_path) == f"{tmp_path}: is a folder, expected a CSV file"


def test_not_utf8(tmp_path: Path) -> None:
    path = tmp_path / "latin1.csv"
    path.write_bytes("é,b,c\n1,2,3\n".encode("latin-1"))
    assert _error(path).startswith(f"{path}: not UTF-8 text")


def test_number_with_underscore_names_the_line(tmp_path: Path) -> None:
    path = _write(tmp_path, "a,b,c\n1,2,3\n1_0,2,3\n")
    assert _error(path).startswith(f"{path}: line 3, column 'a'")


def test_first_blank_line_is_reported_with_mixed_line_endings(tmp_path: Path) -> None:
    path = _write(tmp_path, "a,b,c\n1,2,3\n\r\n4,5,6\n\n7,8,9\n")
    assert _error(path).startswith(f"{path}: line 3: blank line")


# -------------------------------------------------------------------------------- CsvTable
def _table(tmp_path: Path, column: list[str]) -> CsvTable:
    path = _write(tmp_path, "n,x\n" + "".join(f"{v},0\n" for v in column))
    return read_table(path, ["n", "x"])


def test_integers(tmp_path: Path) -> None:
    ints = _table(tmp_path, ["0", "3", "12.0", "1e3", str(2**53)]).integers("n")
    assert ints.dtype == np.int64
    assert ints.tolist() == [0, 3, 12, 1000, 2**53]


@pytest.mark.parametrize(("values", "line", "minimum"), [
    (["0", "1", "2.5"], 4, 0),
    (["0", "-1", "2"], 3, 0),
    (["0.5", "1", "2"], 2, 0),
    (["1", "1.000001", "2"], 3, 0),
    (["2", "1", "3"], 3, 2),
    (["1", "2", str(2**60)], 4, 0),
])
def test_integers_rejects_naming_the_line(tmp_path: Path, values: list[str], line: int,
                                          minimum: int) -> None:
    table = _table(tmp_path, values)
    with pytest.raises(ValueError) as info:
        table.integers("n", minimum=minimum)
    assert str(info.value).startswith(
        f"{table.path}: line {line}, column 'n': expected an integer >= {minimum}, got ")


def test_integer_error_shows_the_value_as_a_plain_number(tmp_path: Path) -> None:
    table = _table(tmp_path, ["0", "1.5"])
    with pytest.raises(ValueError) as info:
        table.integers("n")
    assert str(info.value).endswith("got 1.5")


def test_error_helper(tmp_path: Path) -> None:
    table = _table(tmp_path, ["1", "2"])
    assert str(table.error(1, "x", "bad")) == f"{table.path}: line 3, column 'x': bad"
    assert str(table.error(0, None, "bad")) == f"{table.path}: line 2: bad"


# ----------------------------------------------------------------------------- format_number
@given(st.floats(allow_nan=False, allow_infinity=False))
def test_format_number_round_trips_exactly(x: float) -> None:
    text = format_number(x)
    back = float(text)
    assert back == x
    assert math.copysign(1.0, back) == math.copysign(1.0, x)
    assert "," not in text and " " not in text


def test_format_number_is_shortest_and_reads_back_in_a_table(tmp_path: Path) -> None:
    assert format_number(0.1) == "0.1"
    assert format_number(1.0) == "1.0"
    assert format_number(np.float64(1 / 3)) == repr(1 / 3)
    assert [format_number(v) for v in (math.nan, math.inf, -math.inf)] == ["nan", "inf", "-inf"]
    values = np.random.default_rng(0).normal(size=(50, 3)) * 10.0 ** np.arange(-5, 10, 5)
    text = "a,b,c\n" + "".join(",".join(format_number(v) for v in row) + "\n"
                               for row in values.tolist())
    table = read_table(_write(tmp_path, text), NAMES)
    assert np.array_equal(table.values, values)
