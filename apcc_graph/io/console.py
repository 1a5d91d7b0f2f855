"""What the command line shows on stderr while it works: progress bars, the live status line,
and warnings, each on its own line.

- :func:`progress_bar` is ``tqdm`` drawn only on a terminal: in a log (stderr a file or a pipe)
  nothing at all is drawn (no ``\\r`` updates), nor with ``--quiet`` (:func:`set_quiet`).
- :class:`StatusLine` is one line redrawn in place (``apcc-graph live``), on a terminal only.
- :func:`print_line` prints a line (a warning) above whatever is being redrawn: a progress bar
  or the status line is cleared, the line printed, and the bar or status line drawn again.
"""

from __future__ import annotations

import sys
from collections.abc import Iterable
from typing import Any, TextIO

from tqdm import tqdm

_quiet = False
_status: StatusLine | None = None


def set_quiet(quiet: bool) -> None:
    """``--quiet``: no progress bar and no status line, whatever stderr is."""
    global _quiet
    _quiet = bool(quiet)


def on_terminal(stream: TextIO | None = None) -> bool:
    """Whether ``stream`` (stderr by default) is a terminal and ``--quiet`` was not given."""
    stream = sys.stderr if stream is None else stream
    try:
        return not _quiet and bool(stream.isatty())
    except (AttributeError, ValueError):  # no isatty, or closed
        return False


def progress_bar(iterable: Iterable[Any] | None = None, *, progress: bool = True,
                 **kwargs: Any) -> tqdm:
    """A ``tqdm`` bar on stderr when ``progress`` and stderr is a terminal (and not
    ``--quiet``); otherwise a disabled one, which draws nothing but still counts."""
    return tqdm(iterable, disable=not (progress and on_terminal()), file=sys.stderr, **kwargs)


class StatusLine:
    """One line on stderr redrawn in place (``\\r``), drawn only on a terminal; a no-op in a
    log. While it is shown, :func:`print_line` prints above it."""

    def __init__(self, stream: TextIO | None = None) -> None:
        self.stream = sys.stderr if stream is None else stream
        self.active = on_terminal(self.stream)
        self.text = ""

    def show(self, text: str) -> None:
        """Replace the line's text."""
        if not self.active:
            return
        global _status
        _status = self
        self.text = text
        self.stream.write("\r\033[K" + text)
        self.stream.flush()

    def clear(self) -> None:
        """Erase the line (the cursor back at its start)."""
        if self.active and self.text:
            self.stream.write("\r\033[K")
            self.stream.flush()

    def close(self) -> None:
        """Erase the line for good."""
        global _status
        self.clear()
        self.text = ""
        if _status is self:
            _status = None


def print_line(text: str, stream: TextIO | None = None) -> None:
    """Print ``text`` as a line of its own on stderr: above the live status line or the
    progress bars when one is drawn."""
    stream = sys.stderr if stream is None else stream
    if _status is not None and _status.active and _status.text and _status.stream is stream:
        _status.clear()
        stream.write(text + "\n")
        stream.write(_status.text)
        stream.flush()
    elif any(not getattr(bar, "disable", True) for bar in list(getattr(tqdm, "_instances", ()))):
        tqdm.write(text, file=stream)
    else:
        print(text, file=stream, flush=True)
