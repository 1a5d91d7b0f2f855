"""Reading versioned TOML files with errors that name the file and the key.

Every error raised here is a ``ValueError`` whose message starts with ``<file>: <key>:`` so that a
user can find and fix the entry. Keys are written in dotted form with list indices, e.g.
``segments[1].camera.fx`` (indices are 0-based, as TOML arrays are read).
"""

from __future__ import annotations

import math
import sys
import warnings
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from apcc_graph.io.text_files import MAX_TOML_BYTES, read_small_text
from apcc_graph.io.units import PLAUSIBLE_LENGTH_M, UnitsWarning

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib


def read_toml(path: str | Path) -> dict[str, Any]:
    """Parse a TOML file; a missing file or a syntax error raises ``ValueError`` naming the file.

    A UTF-8 byte-order mark is read and ignored; another encoding's is named, and a file larger
    than :data:`~apcc_graph.io.text_files.MAX_TOML_BYTES` is refused unread.
    """
    path = Path(path)
    text = read_small_text(path, MAX_TOML_BYTES, "a TOML file")
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML: {exc}") from None


class TomlTable:
    """A table of a TOML file with typed, checked accessors.

    Args:
        path: the file, for messages.
        prefix: the dotted key of this table (``""`` at the top level).
        data: the parsed table.
    """

    def __init__(self, path: str | Path, prefix: str, data: Any) -> None:
        self.path = Path(path)
        self.prefix = prefix
        if not isinstance(data, Mapping):
            raise ValueError(f"{self.path}: {prefix or 'file'}: expected a table")
        self.data = data

    def key(self, name: str) -> str:
        """The dotted key of ``name`` in this table."""
        return f"{self.prefix}.{name}" if self.prefix else name

    def error(self, name: str, message: str) -> ValueError:
        """A ``ValueError`` naming the file and the key."""
        return ValueError(f"{self.path}: {self.key(name)}: {message}")

    def check_keys(self, allowed: Iterable[str], required: Iterable[str] = ()) -> None:
        """Reject unknown keys and report missing required ones."""
        allowed = set(allowed)
        for name in self.data:
            if name not in allowed:
                raise self.error(name, f"unknown key; expected one of {', '.join(sorted(allowed))}")
        for name in required:
            if name not in self.data:
                raise self.error(name, "missing required key")

    def has(self, name: str) -> bool:
        """Whether the key is present."""
        return name in self.data

    def number(self, name: str, default: float | None = None) -> float:
        """A finite real number (integers are accepted)."""
        if name not in self.data:
            if default is None:
                raise self.error(name, "missing required key")
            return default
        value = self.data[name]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.error(name, f"expected a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise self.error(name, f"expected a finite number, got {value!r}")
        return value

    def metres(self, name: str, what: str = "a continuum-robot segment") -> float:
        """A finite length in metres; one beyond :data:`PLAUSIBLE_LENGTH_M` is read as written
        with a :class:`UnitsWarning` naming the file and the key (millimetres, perhaps)."""
        value = self.number(name)
        if abs(value) > PLAUSIBLE_LENGTH_M:
            warnings.warn(f"{self.path}: {self.key(name)} = {self.data[name]!r} m: {what} "
                          f"of more than {PLAUSIBLE_LENGTH_M:g} m is implausible; lengths are "
                          f"in metres (if this is millimetres, write {value / 1000.0:g})",
                          UnitsWarning, stacklevel=3)
        return value

    def integer(self, name: str) -> int:
        """An integer."""
        if name not in self.data:
            raise self.error(name, "missing required key")
        value = self.data[name]
        if isinstance(value, bool) or not isinstance(value, int):
            raise self.error(name, f"expected an integer, got {value!r}")
        return value

    def string(self, name: str) -> str:
        """A string."""
        if name not in self.data:
            raise self.error(name, "missing required key")
        value = self.data[name]
        if not isinstance(value, str):
            raise self.error(name, f"expected a string, got {value!r}")
        return value

    def numbers(
        self, name: str, length: int | None = None, default: list[float] | None = None
    ) -> list[float]:
        """A list of finite numbers, optionally of a fixed length."""
        if name not in self.data:
            if default is None:
                raise self.error(name, "missing required key")
            return list(default)
        value = self.data[name]
        if not isinstance(value, list):
            raise self.error(name, f"expected a list of numbers, got {value!r}")
        out = []
        for i, item in enumerate(value):
            if (
                isinstance(item, bool)
                or not isinstance(item, (int, float))
                or not math.isfinite(float(item))
            ):
                raise self.error(f"{name}[{i}]", f"expected a finite number, got {item!r}")
            out.append(float(item))
        if length is not None and len(out) != length:
            raise self.error(name, f"expected {length} numbers, got {len(out)}")
        return out

    def table(self, name: str) -> TomlTable:
        """A sub-table."""
        if name not in self.data:
            raise self.error(name, "missing required table")
        return TomlTable(self.path, self.key(name), self.data[name])

    def tables(self, name: str) -> list[TomlTable]:
        """An array of tables (``[[name]]``)."""
        if name not in self.data:
            raise self.error(name, "missing required array of tables")
        value = self.data[name]
        if not isinstance(value, list) or not value:
            raise self.error(name, f"expected a non-empty array of tables ([[{name}]])")
        return [
            TomlTable(self.path, f"{self.key(name)}[{i}]", item) for i, item in enumerate(value)
        ]

    def check_format(self, expected: str) -> None:
        """Require ``format = expected`` (the file's format name and version)."""
        value = self.string("format")
        if value != expected:
            raise self.error("format", f"expected {expected!r}, got {value!r}")

    def wrap(self, name: str, exc: ValueError) -> ValueError:
        """Re-raise a model validation error (e.g. from ``Segment``) naming the file and key."""
        return ValueError(f"{self.path}: {self.key(name)}: {exc}")
