"""Accuracy of an estimate against ground truth: RMS per segment overall and per window, max."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.model.arrays import FloatArray, rms, window_rms


@dataclass(frozen=True)
class AccuracyReport:
    """Errors of estimated angles against the truth (radians).

    Attributes:
        rms: ``(S,)`` RMS error per segment over all frames.
        max_abs: ``(S,)`` largest absolute error per segment.
        window: frames per window.
        window_starts: ``(W,)`` first frame of each window.
        window_rms: ``(W, S)`` RMS error per window and segment (drift shows as growth).
    """

    rms: FloatArray
    max_abs: FloatArray
    window: int
    window_starts: NDArray[np.int64]
    window_rms: FloatArray


def compare(thetas: ArrayLike, truth: ArrayLike, window: int = 100) -> AccuracyReport:
    """Compare ``(F, S)`` estimated angles with ``(F, S)`` true angles.

    Raises:
        ValueError: shapes differ, or the window is not positive.
    """
    est = np.asarray(thetas, dtype=float)
    ref = np.asarray(truth, dtype=float)
    if est.shape != ref.shape or est.ndim != 2:
        raise ValueError(f"estimate {est.shape} and truth {ref.shape}: expected the same (F, S)")
    if window < 1:
        raise ValueError(f"window = {window}: expected at least 1 frame")
    err = est - ref
    starts = np.arange(0, len(err), window)
    return AccuracyReport(rms=rms(err), max_abs=np.max(np.abs(err), 0), window=window,
                          window_starts=starts, window_rms=window_rms(err, window))
