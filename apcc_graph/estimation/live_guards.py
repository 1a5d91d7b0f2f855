"""What keeps a live run honest and its outputs whole (:mod:`apcc_graph.estimation.live`).

- :class:`LimitGuard`: an angle beyond its segment's ``theta_max`` is never passed on as it
  is: it is clamped to the limit, flagged, and a :class:`LiveWarning` names the segment and
  the frame (once per segment).
- :class:`RateMonitor`: when the frames smoothed per second of the recording fall below the
  frames arriving by more than :data:`RATE_MARGIN` over :data:`RATE_WINDOW` seconds, a
  :class:`LiveWarning` says both rates, as soon as the first window has passed.
- :func:`deferred_interrupts`: Ctrl-C (SIGINT) only sets a flag while the loop runs, so it
  never lands inside a gtsam update (which would leave iSAM2 inconsistent and lose the window);
  the loop stops at the next frame boundary. A second Ctrl-C raises at once.
"""

from __future__ import annotations

import math
import signal
import threading
import warnings
from collections import deque
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from apcc_graph.model.arrays import FloatArray

RATE_WINDOW = 1.0
"""Seconds of the recording over which the smoothed rate is compared with the input rate."""
RATE_MARGIN = 0.2
"""The overload warning comes when fewer than ``1 - RATE_MARGIN`` of the frames that arrived
over the last :data:`RATE_WINDOW` were smoothed."""
LIMIT_TOLERANCE = math.radians(0.01)
"""An angle this close beyond its limit counts as at the limit (radians)."""


class LiveWarning(UserWarning):
    """The live loop falls behind the recording, or an estimate left its joint limits."""


class LimitGuard:
    """Clamps angles to ``[-theta_max, theta_max]`` per segment and warns (once per segment).

    Args:
        theta_max: ``(S,)`` each segment's limit (radians).
    """

    def __init__(self, theta_max: FloatArray) -> None:
        self.theta_max = np.asarray(theta_max, dtype=float)
        self.warned = np.zeros(len(self.theta_max), dtype=bool)
        self.rows = 0  # final rows clamped so far

    def clamp(self, frame: int, thetas: FloatArray, final: bool
              ) -> tuple[FloatArray, NDArray[np.bool_]]:
        """``(angles clamped, which segments were)``; a final row clamped is counted and, the
        first time for its segment, warned about."""
        thetas = np.asarray(thetas, dtype=float)
        beyond = np.abs(thetas) > self.theta_max + LIMIT_TOLERANCE
        if not beyond.any():
            return thetas, beyond
        clamped = np.clip(thetas, -self.theta_max, self.theta_max)
        if final:
            self.rows += 1
            for j in np.flatnonzero(beyond & ~self.warned):
                self.warned[j] = True
                warnings.warn(
                    f"live: frame {frame}: segment {j + 1}'s estimate "
                    f"{math.degrees(thetas[j]):.1f} deg is beyond its limit of "
                    f"{math.degrees(self.theta_max[j]):.1f} deg (theta_max): written as "
                    f"{math.degrees(clamped[j]):.1f} deg and flagged (clamped_{j + 1} = 1 in "
                    "theta.csv); the estimate has left the robot's range there and cannot be "
                    "trusted", LiveWarning, stacklevel=3)
        return clamped, beyond


@dataclass
class RateMonitor:
    """Frames arrived and smoothed, by the recording's time; one warning when smoothing falls
    behind (module docstring)."""

    window: float = RATE_WINDOW
    margin: float = RATE_MARGIN
    warned: bool = False

    def __post_init__(self) -> None:
        self.restart()

    def restart(self) -> None:
        """Forget the frames so far (after a pause the loop chose, e.g. the start search)."""
        self._seen: deque[tuple[float, bool]] = deque()  # (timestamp, smoothed)
        self._first: float | None = None

    def arrived(self, t: float, index: int) -> None:
        """Frame ``index`` of the source arrived at ``t`` (smoothed or not, it is not known
        yet); warns once when, over the last window before it, too few were smoothed."""
        self._first = t if self._first is None else self._first
        if not self.warned and self._seen and len(self._seen) >= 5 and (
                self._seen[-1][0] - self._first >= self.window):
            self._check(index)
        self._seen.append((t, False))
        while self._seen and self._seen[0][0] <= t - self.window:
            self._seen.popleft()

    def smoothed(self, t: float) -> None:
        """The frame at ``t`` is smoothed."""
        for k in range(len(self._seen) - 1, -1, -1):
            if self._seen[k][0] == t:
                self._seen[k] = (t, True)
                break

    def _check(self, index: int) -> None:
        arrived = len(self._seen)
        done = sum(1 for _, s in self._seen if s)
        if done < (1.0 - self.margin) * arrived:
            self.warned = True
            span = max(self._seen[-1][0] - self._seen[0][0], 1e-9) * arrived / max(arrived - 1, 1)
            warnings.warn(
                f"live: by frame {index} {done / span:.1f} frames per second of the recording "
                f"are smoothed of the {arrived / span:.1f} arriving (over the last "
                f"{self.window:.1f} s): this machine does not keep up, the others are dropped "
                "and the estimate can run far off; --no-realtime estimates every frame",
                LiveWarning, stacklevel=4)


@contextmanager
def deferred_interrupts() -> Iterator[threading.Event]:
    """While inside, SIGINT (Ctrl-C) sets the yielded event instead of raising
    ``KeyboardInterrupt``; the caller stops at a safe point. A second Ctrl-C raises at once (a
    source that hangs can still be left). Outside the main thread (where signal handlers
    cannot be set) the event is never set and Ctrl-C behaves as usual."""
    event = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield event
        return

    def on_sigint(signum: int, frame: object) -> None:
        if event.is_set():
            raise KeyboardInterrupt
        event.set()

    previous = signal.signal(signal.SIGINT, on_sigint)
    try:
        yield event
    finally:
        signal.signal(signal.SIGINT, previous)
