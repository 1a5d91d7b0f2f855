"""Numeric CSV tables with a header, read fast and checked with errors that name file and line.

The fast path hands the whole file to ``numpy.loadtxt`` (its C parser; about 1 s per million rows
of four full-precision numbers on this project's machines). Only when that fails does a slow
line-by-line pass run, to say exactly which line and column is wrong. Line numbers are 1-based and
count the header, as an editor shows them. Blank lines are refused (they would shift the mapping
from rows to lines) except at the end of the file. A UTF-8 byte-order mark is read; a line longer
than 64 KB is refused after reading the file in 1 MB chunks, before any parsing
(:mod:`~apcc_graph.io.text_files`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from apcc_graph.io.text_files import MAX_LINE_BYTES, QUOTE_CHARS, bom_length, quote, read_start
from apcc_graph.model.arrays import FloatArray

_CHUNK = 1 << 20
_QUOTE_BYTES = QUOTE_CHARS * 4


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
    """The column names of the first line (stripped); a missing or empty file is an error.

    A UTF-8 byte-order mark is dropped; a UTF-16/32 one, or a first line longer than
    :data:`~apcc_graph.io.text_files.MAX_LINE_BYTES`, is refused (only that much is read).
    """
    raw = read_start(path, MAX_LINE_BYTES + 1, "a CSV file", line=True)
    raw = raw[bom_length(raw[:4], path):]
    if len(raw) > MAX_LINE_BYTES and not raw.endswith(b"\n"):
        raise _long_line(path, 1, raw)
    try:
        first = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ValueError(f"{path}: not UTF-8 text (line 1: byte 0x{raw[exc.start]:02x}); save "
                         "it as UTF-8") from None
    if not first.strip():
        raise ValueError(f"{path}: line 1: expected a header line, the file is empty")
    return [name.strip() for name in first.rstrip("\r\n").split(",")]


def _long_line(path: Path, line: int, start: bytes) -> ValueError:
    return ValueError(f"{path}: line {line}: longer than {MAX_LINE_BYTES} bytes (starts "
                      f"{quote(start)}); expected one row of comma-separated numbers per line")


def _scan_lines(path: Path) -> tuple[bool, int | None]:
    """Read the file in chunks once: whether it has a data row after the header, and the
    1-based line of the first blank line that is followed by a non-blank one.

    Raises:
        ValueError: a line longer than ``MAX_LINE_BYTES`` (found without holding more than a
            chunk in memory).
    """
    line = 1  # the line the next byte belongs to
    length = 0  # bytes of that line seen so far
    ends_cr = False  # whether the bytes of that line seen so far end in a carriage return
    first_blank: int | None = None
    last_full = 0  # last line that is not blank
    head = b""
    with path.open("rb") as fh:
        while chunk := fh.read(_CHUNK):
            buf = np.frombuffer(chunk, dtype=np.uint8)
            ends = np.flatnonzero(buf == 10)
            starts = np.concatenate([[0], ends + 1])
            lengths = np.append(ends, len(buf)) - starts  # bytes before each newline / chunk end
            lengths[0] += length
            head = (head + chunk[:_QUOTE_BYTES])[:_QUOTE_BYTES]  # of the line going on
            too_long = np.flatnonzero(lengths > MAX_LINE_BYTES)
            if len(too_long):
                k = int(too_long[0])
                start = head if k == 0 else chunk[starts[k]:starts[k] + _QUOTE_BYTES]
                raise _long_line(path, line + k, start)
            # a line is blank when it is empty or only a carriage return
            cr_end = np.zeros(len(ends), dtype=bool)
            inner = ends > 0
            cr_end[inner] = buf[ends[inner] - 1] == 13
            if len(ends) and ends[0] == 0:
                cr_end[0] = ends_cr
            blank = (lengths[:-1] == 0) | ((lengths[:-1] == 1) & cr_end)
            numbers = line + np.arange(len(ends))
            if first_blank is None and blank[numbers > 1].any():
                first_blank = int(numbers[(numbers > 1) & blank][0])
            if (~blank).any():
                last_full = max(last_full, int(numbers[~blank][-1]))
            line += len(ends)
            length = int(lengths[-1])
            if len(ends):
                head = chunk[starts[-1]:starts[-1] + _QUOTE_BYTES]
            if length:
                ends_cr = bool(buf[-1] == 13)
            if length and not (length == 1 and ends_cr):
                last_full = max(last_full, line)
    blank_inside = first_blank if first_blank is not None and first_blank < last_full else None
    return last_full > 1, blank_inside


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
    has_rows, blank = _scan_lines(path)
    if not has_rows:
        return CsvTable(path, names, np.zeros((0, len(names))))
    if blank is not None:
        raise ValueError(f"{path}: line {blank}: blank line; expected "
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


_NUMBER = re.compile(
    r"\s*[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|nan|inf|infinity)\s*", re.IGNORECASE
)
"""What numpy.loadtxt reads as a float (ASCII digits, no underscores)."""


def _diagnose(path: Path, names: list[str]) -> None:
    """Find the first bad line the slow way and raise a precise error."""
    with path.open("r", encoding="utf-8-sig", errors="replace") as fh:
        next(fh)
        for number, line in enumerate(fh, start=2):
            fields = line.rstrip("\r\n").split(",")
            if len(fields) != len(names):
                raise ValueError(f"{path}: line {number}: expected {len(names)} fields "
                                 f"({','.join(names)}), got {len(fields)}")
            for name, field in zip(names, fields, strict=True):
                if _NUMBER.fullmatch(field) is None:
                    raise ValueError(f"{path}: line {number}, column '{name}': "
                                     f"{quote(field.strip())} is not a number")
    raise ValueError(f"{path}: could not be read as a numeric CSV table")


def format_number(value: float) -> str:
    """Shortest text that reads back as exactly ``value`` (Python's repr)."""
    return repr(float(value)) if math.isfinite(value) else str(value)
