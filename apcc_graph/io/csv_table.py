"""Numeric CSV tables with a header, read fast and checked with errors that name file and line.

The fast path hands the whole file to ``numpy.loadtxt`` (its C parser; about 1 s per million rows
of four full-precision numbers on this project's machines). Only when that fails does a slow
line-by-line pass run, to say exactly which line and column is wrong. Line numbers are 1-based and
count the header, as an editor shows them. Blank lines are refused (they would shift the mapping
from rows to lines) except at the end of the file.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from apcc_graph.model.arrays import FloatArray


class CsvTable:
    """A parsed table: ``values[i, j]`` is row i (file line ``i + 2``) of column ``names[j]``."""

    def __init__(self, path: Path, names: list[str], values: FloatArray) -> None:
        self.path = path
        self.names = names
        self.values = values

    def __len__(self) -> int:
        return len(self.values)

    def column(self, name: str) -> FloatArray:
        """The values of a column."""
        return self.values[:, self.names.index(name)]

    def line(self, row: int) -> int:
        """The 1-based file line of a data row."""
        return int(row) + 2

    def error(self, row: int, column: str | None, message: str) -> ValueError:
        """A ``ValueError`` naming the file, the line and the column."""
        where = f"line {self.line(row)}" + (f", column '{column}'" if column else "")
        return ValueError(f"{self.path}: {where}: {message}")

    def require_finite(self) -> None:
        """Refuse NaN and infinite values."""
        bad = ~np.isfinite(self.values)
        if bad.any():
            row, col = np.argwhere(bad)[0]
            raise self.error(row, self.names[col],
                             f"expected a finite number, got {float(self.values[row, col])!r}")

    def integers(self, name: str, minimum: int = 0) -> NDArray[np.int64]:
        """A column of integers ``>= minimum`` (as written: no fraction)."""
        col = self.column(name)
        bad = (col != np.round(col)) | (col < minimum) | (np.abs(col) > 2**53)
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise self.error(row, name,
                             f"expected an integer >= {minimum}, got {float(col[row])!r}")
        return col.astype(np.int64)


def read_header(path: Path) -> list[str]:
    """The column names of the first line (stripped); a missing or empty file is an error."""
    try:
        with path.open("r", encoding="utf-8", newline="") as fh:
            first = fh.readline()
    except FileNotFoundError:
        raise ValueError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ValueError(f"{path}: is a folder, expected a CSV file") from None
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text: {exc}") from None
    if not first.strip():
        raise ValueError(f"{path}: line 1: expected a header line, the file is empty")
    return [name.strip() for name in first.rstrip("\r\n").split(",")]


def read_table(path: Path, expected: Sequence[str]) -> CsvTable:
    """Read a CSV file whose header must be exactly ``expected``.

    Args:
        path: the file.
        expected: the column names, in order.

    Returns:
        The table (possibly with zero rows).

    Raises:
        ValueError: wrong header, a row with the wrong number of fields, a field that is not a
            number, a blank line; the message names the file and the line.
    """
    names = read_header(path)
    expected = list(expected)
    if names != expected:
        raise ValueError(_header_message(path, names, expected))
    raw = path.read_bytes()
    body_start = raw.find(b"\n") + 1 if b"\n" in raw else len(raw)
    body = raw[body_start:].rstrip(b"\r\n")
    if not body:
        return CsvTable(path, names, np.zeros((0, len(names))))
    blank = _first_blank_line(body)
    if blank is not None:
        raise ValueError(f"{path}: line {blank + 1}: blank line; expected "
                         f"{len(names)} fields ({','.join(names)})")
    try:
        values = np.loadtxt(path, delimiter=",", skiprows=1, comments=None, ndmin=2,
                            dtype=np.float64, encoding="utf-8")
    except ValueError:
        _diagnose(path, names)
        raise  # pragma: no cover - _diagnose always raises when loadtxt does
    if values.shape[1] != len(names):  # pragma: no cover - loadtxt checks this itself
        _diagnose(path, names)
    return CsvTable(path, names, values)


def _header_message(path: Path, names: list[str], expected: list[str]) -> str:
    for i, (got, want) in enumerate(zip(names, expected, strict=False)):
        if got != want:
            return (f"{path}: line 1: column {i + 1} is '{got}', expected '{want}' "
                    f"(header: {','.join(expected)})")
    if len(names) < len(expected):
        return (f"{path}: line 1: missing column '{expected[len(names)]}' "
                f"(header: {','.join(expected)})")
    return (f"{path}: line 1: unexpected extra column '{names[len(expected)]}' "
            f"(header: {','.join(expected)})")


def _first_blank_line(body: bytes) -> int | None:
    """1-based line (within ``body``, whose line 1 is file line 2) of the first blank line."""
    if body.startswith((b"\n", b"\r\n")):
        return 1
    found = [pos for pos in (body.find(b"\n\n"), body.find(b"\n\r\n")) if pos >= 0]
    if not found:
        return None
    return body.count(b"\n", 0, min(found) + 1) + 1


_NUMBER = re.compile(
    r"\s*[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|nan|inf|infinity)\s*", re.IGNORECASE
)
"""What numpy.loadtxt reads as a float (ASCII digits, no underscores)."""


def _diagnose(path: Path, names: list[str]) -> None:
    """Find the first bad line the slow way and raise a precise error."""
    with path.open("r", encoding="utf-8") as fh:
        next(fh)
        for number, line in enumerate(fh, start=2):
            fields = line.rstrip("\r\n").split(",")
            if len(fields) != len(names):
                raise ValueError(f"{path}: line {number}: expected {len(names)} fields "
                                 f"({','.join(names)}), got {len(fields)}")
            for name, field in zip(names, fields, strict=True):
                if _NUMBER.fullmatch(field) is None:
                    raise ValueError(f"{path}: line {number}, column '{name}': "
                                     f"{field.strip()!r} is not a number")
    raise ValueError(f"{path}: could not be read as a numeric CSV table")


def format_number(value: float) -> str:
    """Shortest text that reads back as exactly ``value`` (Python's repr)."""
    return repr(float(value)) if math.isfinite(value) else str(value)
