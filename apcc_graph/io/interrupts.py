"""Ctrl-C that is never lost: while :func:`catching_interrupts` is active, SIGINT sets a flag
and raises ``KeyboardInterrupt``; where that exception is swallowed (Python cannot raise it out
of a C callback, e.g. while numba compiles a kernel, which would print "Exception ignored" and
go on), it is raised again a moment later, from a timer thread, so that it reaches the
command's own code.
Writers check :func:`check_interrupted` before they move a finished output into place, so an
interrupted command never publishes its output."""

from __future__ import annotations

import _thread
import signal
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

INTERRUPTED = threading.Event()
"""Set by the first Ctrl-C while :func:`catching_interrupts` is active."""


def check_interrupted() -> None:
    """Raise ``KeyboardInterrupt`` if Ctrl-C was pressed (even where it was swallowed)."""
    if INTERRUPTED.is_set():
        raise KeyboardInterrupt


def _on_sigint(signum: int, frame: FrameType | None) -> None:
    INTERRUPTED.set()
    raise KeyboardInterrupt


@contextmanager
def catching_interrupts() -> Iterator[None]:
    """Within the block, Ctrl-C is recorded in :data:`INTERRUPTED` and a ``KeyboardInterrupt``
    swallowed by a C callback is raised again; both are undone after it. Only the main thread
    can install a signal handler: elsewhere the block changes nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    INTERRUPTED.clear()
    previous_handler = signal.signal(signal.SIGINT, _on_sigint)
    previous_hook = sys.unraisablehook

    def hook(unraisable: Any) -> None:
        if isinstance(unraisable.exc_value, KeyboardInterrupt):
            # again, a moment later: from here it would only be swallowed once more
            threading.Timer(0.05, _thread.interrupt_main).start()
            return
        previous_hook(unraisable)

    sys.unraisablehook = hook
    try:
        yield
    finally:
        sys.unraisablehook = previous_hook
        signal.signal(signal.SIGINT, previous_handler)
