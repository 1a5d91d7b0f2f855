"""What every text file the project reads shares: the byte-order mark and the size limits.

A UTF-8 byte-order mark (as some editors and spreadsheet programs write) is read and ignored; a
UTF-16 or UTF-32 one names the encoding the file was saved in (the files are UTF-8). A line longer
than :data:`MAX_LINE_BYTES` is refused while the file is scanned in chunks, so a huge file that is
one "line" costs neither the memory nor the time of reading it whole, and an error never quotes
more than :data:`QUOTE_CHARS` characters of what the user wrote.
"""

from __future__ import annotations

import codecs
from pathlib import Path

MAX_LINE_BYTES = 65536
"""Longest line of a CSV file (the widest row any format here has, a spatial 64-segment
``theta.csv``, is about 6 KB)."""

MAX_TOML_BYTES = 16 * 1024 * 1024
"""Largest TOML file read (a robot or calibration file is a few KB; a calibration with a pose per
photo of a long sweep stays far below)."""

QUOTE_CHARS = 60
"""At most this much of the user's text is quoted in a message."""

_OTHER_BOMS = (  # UTF-32 first: its little-endian mark starts with UTF-16's
    (codecs.BOM_UTF32_LE, "UTF-32 (little-endian)"),
    (codecs.BOM_UTF32_BE, "UTF-32 (big-endian)"),
    (codecs.BOM_UTF16_LE, "UTF-16 (little-endian)"),
    (codecs.BOM_UTF16_BE, "UTF-16 (big-endian)"),
)


def bom_length(head: bytes, path: str | Path) -> int:
    """How many bytes of a UTF-8 byte-order mark start a file whose first bytes are ``head``
    (0 or 3).

    Raises:
        ValueError: the file starts with a UTF-16 or UTF-32 byte-order mark; the message names
            the file and the encoding and asks for UTF-8.
    """
    if head.startswith(codecs.BOM_UTF8):
        return len(codecs.BOM_UTF8)
    for mark, name in _OTHER_BOMS:
        if head.startswith(mark):
            raise ValueError(f"{path}: the file is {name} text (it starts with that byte-order "
                             "mark); expected UTF-8: save it as UTF-8")
    return 0


def read_start(path: Path, size: int, what: str, line: bool = False) -> bytes:
    """The first ``size`` bytes of the file ``path`` (with ``line``, of its first line), read
    without ever reading more.

    Raises:
        ValueError: no such file, a folder, or unreadable; the message names the file and says
            it should be ``what``.
    """
    try:
        with path.open("rb") as fh:
            return fh.readline(size) if line else fh.read(size)
    except FileNotFoundError:
        raise ValueError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ValueError(f"{path}: is a folder, expected {what}") from None
    except OSError as exc:
        raise ValueError(f"{path}: cannot read it ({exc.strerror or exc})") from None


def quote(text: str | bytes) -> str:
    """``text`` for a message: ``repr`` of at most :data:`QUOTE_CHARS` characters (control
    characters and undecodable bytes shown as ``?``), with ``...`` when cut."""
    if isinstance(text, bytes):
        text = text[:QUOTE_CHARS * 4].decode("utf-8", errors="replace")
    text = "".join(c if c.isprintable() else "?" for c in text[:QUOTE_CHARS + 1])
    if len(text) <= QUOTE_CHARS:
        return repr(text)
    return repr(text[:QUOTE_CHARS]) + "..."


def read_small_text(path: str | Path, limit: int, what: str) -> str:
    """The UTF-8 text of a file of at most ``limit`` bytes (a UTF-8 byte-order mark dropped).

    Args:
        path: the file.
        limit: the largest size accepted, bytes.
        what: what the file should be, for messages (e.g. ``"a TOML file"``).

    Raises:
        ValueError: no such file, a folder, larger than ``limit``, another encoding's
            byte-order mark or text that is not UTF-8; the message names the file.
    """
    path = Path(path)
    raw = read_start(path, limit + 1, what)
    if len(raw) > limit:
        raise ValueError(f"{path}: larger than {limit // (1024 * 1024)} MB; expected {what} "
                         "(a few KB)")
    body = raw[bom_length(raw[:4], path):]
    try:
        return body.decode("utf-8")
    except UnicodeDecodeError as exc:
        line = body[:exc.start].count(b"\n") + 1
        raise ValueError(f"{path}: not UTF-8 text (line {line}: byte "
                         f"0x{body[exc.start]:02x}); save it as UTF-8") from None
