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
import time
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType
from typing import Any

INTERRUPTED = threading.Event()
"""Set by Ctrl-C while :func:`catching_interrupts` is active (cleared when it ends)."""


def check_interrupted() -> None:
    """Raise ``KeyboardInterrupt`` if Ctrl-C was pressed (even where it was swallowed)."""
    if INTERRUPTED.is_set():
        _raised[0] += 1  # delivered: a pending re-raise is no longer needed
        raise KeyboardInterrupt


_raised = [0]  # KeyboardInterrupts raised by the handler so far
_active = threading.Event()  # inside catching_interrupts
_early = threading.Event()  # Ctrl-C before catching_interrupts, noted by record_early_interrupt


def record_early_interrupt(signum: int, frame: FrameType | None) -> None:
    """A SIGINT handler for a command line's start, until :func:`catching_interrupts` installs
    its own: Ctrl-C is only noted, and the block raises it as soon as it begins (no traceback
    from whatever code ran at that moment)."""
    _early.set()


def _on_sigint(signum: int, frame: FrameType | None) -> None:
    INTERRUPTED.set()
    _raised[0] += 1
    raise KeyboardInterrupt


def _raise_again(count: int) -> None:
    """Interrupt the main thread again, unless an interruption was raised since the one
    that was swallowed (it was delivered, or was swallowed and scheduled its own), or the
    command is over."""
    if _active.is_set() and _raised[0] == count:
        _thread.interrupt_main()


@contextmanager
def catching_interrupts(final: bool = False) -> Iterator[None]:
    """Within the block, Ctrl-C is recorded in :data:`INTERRUPTED` and a ``KeyboardInterrupt``
    swallowed by a C callback is raised again; both are undone after it. ``final``: the block
    is the process's last work (the command line's entry point): after an interruption Ctrl-C
    is then ignored, so that a late second delivery cannot turn the exit code 130 into death
    by SIGINT. Only the main thread can install a signal handler: elsewhere the block changes
    nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    INTERRUPTED.clear()
    previous_handler = signal.signal(signal.SIGINT, _on_sigint)
    previous_hook = sys.unraisablehook
    timers: list[threading.Timer] = []

    def hook(unraisable: Any) -> None:
        if isinstance(unraisable.exc_value, KeyboardInterrupt):
            # again, a moment later: from here it would only be swallowed once more
            timer = threading.Timer(0.05, _raise_again, (_raised[0],))
            timers.append(timer)
            timer.start()
            return
        previous_hook(unraisable)

    sys.unraisablehook = hook
    _active.set()
    interrupted = False
    try:
        if _early.is_set():  # Ctrl-C while the command started: acted on now
            _early.clear()
            INTERRUPTED.set()
            raise KeyboardInterrupt
        yield
    except KeyboardInterrupt:
        interrupted = True
        raise
    finally:
        interrupted = interrupted or INTERRUPTED.is_set()
        _active.clear()
        INTERRUPTED.clear()  # it speaks of this block only
        for timer in timers:
            timer.cancel()
            timer.join()
        # a re-raise already on its way is taken by a handler that does nothing, not by the
        # previous one (which would raise outside the command)
        signal.signal(signal.SIGINT, lambda signum, frame: None)
        _drain()
        sys.unraisablehook = previous_hook
        signal.signal(signal.SIGINT, signal.SIG_IGN if final and interrupted
                      else previous_handler)


def _drain() -> None:
    """A few calls: the interpreter runs a pending signal handler at such points."""
    for _ in range(3):
        time.sleep(0)


@contextmanager
def deferring_interrupts() -> Iterator[None]:
    """Ctrl-C held back for the block: a SIGINT that arrives within it is only recorded (in
    :data:`INTERRUPTED` too, when :func:`catching_interrupts` is active) and raised as
    ``KeyboardInterrupt`` once the block is over, so that steps which must happen together
    (two renames) all happen. A Python-level handler, unlike a blocked signal mask, also holds
    back the SIGINT that the kernel hands to another thread (a BLAS thread, say). Only the main
    thread can install a handler: elsewhere the block changes nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def record(signum: int, frame: FrameType | None) -> None:
        received.append(signum)
        if _active.is_set():
            INTERRUPTED.set()
            _raised[0] += 1  # a swallowed interruption's re-raise lands here: no more needed

    previous = signal.signal(signal.SIGINT, record)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if received:
            raise KeyboardInterrupt
