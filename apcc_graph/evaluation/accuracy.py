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


def compare(thetas: ArrayLike, truth: ArrayLike, window: int = 100,
            psis: ArrayLike | None = None, truth_psis: ArrayLike | None = None
            ) -> AccuracyReport:
    """Compare ``(F, S)`` estimated angles with ``(F, S)`` true angles.

    With ``psis`` (a spatial estimate's bending planes) the error of each frame and segment is
    the length of the bending-vector error ``|theta (cos psi, sin psi) - theta_true (cos
    psi_true, sin psi_true)|``, with ``truth_psis`` (``None``: a planar truth, ``psi = 0``).

    Raises:
        ValueError: shapes differ, or the window is not positive.
    """
    est = np.asarray(thetas, dtype=float)
    ref = np.asarray(truth, dtype=float)
    if est.shape != ref.shape or est.ndim != 2:
        raise ValueError(f"estimate {est.shape} and truth {ref.shape}: expected the same (F, S)")
    if window < 1:
        raise ValueError(f"window = {window}: expected at least 1 frame")
    if psis is None:
        err = est - ref
    else:
        psi = np.asarray(psis, dtype=float)
        psi_true = np.zeros_like(ref) if truth_psis is None else np.asarray(truth_psis, float)
        if psi.shape != est.shape or psi_true.shape != est.shape:
            raise ValueError(f"psis {psi.shape} and truth_psis {psi_true.shape}: expected "
                             f"{est.shape}")
        err = np.hypot(est * np.cos(psi) - ref * np.cos(psi_true),
                       est * np.sin(psi) - ref * np.sin(psi_true))
    starts = np.arange(0, len(err), window)
    return AccuracyReport(rms=rms(err), max_abs=np.max(np.abs(err), 0), window=window,
                          window_starts=starts, window_rms=window_rms(err, window))
