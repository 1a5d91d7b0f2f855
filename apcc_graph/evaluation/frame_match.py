"""Which truth frame each row of an estimate is: matched by frame number AND timestamp.

An estimate's rows are not compared with the truth's by position: a row of frame ``f`` at time
``t`` is compared with the truth's frame ``f``, and only if that frame is at ``t`` too (within
:data:`TIME_TOLERANCE`). An estimate may cover only some of the truth's frames (a live run that
skipped frames); a truth recorded at another frame rate, or of another recording, is refused
with the first row that does not match.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

TIME_TOLERANCE = 1e-6
"""Seconds by which an estimate's timestamp may differ from its truth frame's (both are written
in full precision from the same frames.csv, so they agree exactly unless they are not the same
frames)."""


@dataclass(frozen=True)
class FrameMatch:
    """The truth frames of an estimate's rows.

    Attributes:
        frames: ``(F,)`` the truth's frame index of each row of the estimate.
        n_truth: frames of the truth.
    """

    frames: NDArray[np.int64]
    n_truth: int

    @property
    def complete(self) -> bool:
        """Whether the estimate has every truth frame."""
        return len(self.frames) == self.n_truth

    def coverage(self) -> str:
        """One line: how many of the truth's frames the estimate has."""
        n = len(self.frames)
        return (f"compared on the {n} frames the estimate has, of the truth's {self.n_truth} "
                f"({100.0 * n / self.n_truth:.1f}%)")


def _interval(times: NDArray[np.float64]) -> str:
    if len(times) < 2:
        return "one frame"
    return f"a frame every {1e3 * float(np.median(np.diff(times))):.4g} ms"


def match_frames(frames: ArrayLike, timestamps: ArrayLike, truth_timestamps: ArrayLike,
                 estimate_name: str, truth_name: str) -> FrameMatch:
    """Match an estimate's rows (frame numbers and timestamps) to a truth's frames.

    Args:
        frames: ``(F,)`` the estimate's frame numbers (0-based, strictly increasing).
        timestamps: ``(F,)`` the estimate's timestamps, seconds.
        truth_timestamps: ``(N,)`` the truth's frame timestamps (frame i at index i).
        estimate_name: the estimate's file, for messages (e.g. ``OUT/theta.csv``).
        truth_name: the truth's file, for messages (e.g. ``SEQ/frames.csv``).

    Raises:
        ValueError: a row's frame is beyond the truth's last frame, or the truth's frame is at
            another time; the message names the estimate's file and line (1-based, the header
            is line 1) and both times and frame rates.
    """
    rows = np.asarray(frames, dtype=np.int64)
    times = np.asarray(timestamps, dtype=float)
    truth = np.asarray(truth_timestamps, dtype=float)
    beyond = np.flatnonzero(rows >= len(truth))
    if len(beyond):
        row = int(beyond[0])
        raise ValueError(f"{estimate_name}: line {row + 2}: frame {int(rows[row])} is beyond "
                         f"the last frame of {truth_name} ({len(truth) - 1}): the estimate has "
                         f"{len(rows)} rows of frames {int(rows[0])}..{int(rows[-1])}, the "
                         f"truth {len(truth)} frames; expected the truth of the estimated "
                         "sequence")
    at = truth[rows]
    off = np.flatnonzero(np.abs(at - times) > TIME_TOLERANCE + 1e-12 * np.abs(times))
    if len(off):
        row = int(off[0])
        raise ValueError(
            f"{estimate_name}: line {row + 2}: frame {int(rows[row])} is at "
            f"{float(times[row])!r} s, but {truth_name} has frame {int(rows[row])} at "
            f"{float(at[row])!r} s ({_interval(times)} against {_interval(truth)}): expected "
            "the truth of the same frames (another frame rate or another recording?)")
    return FrameMatch(rows, len(truth))
