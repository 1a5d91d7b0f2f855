"""How an estimate behaves around a fault: recovery time and sigma honesty.

- :func:`recovery_frames`: how many frames after a fault ends the error takes to come back, and
  stay, within a factor of the undisturbed error;
- :func:`sigma_honesty`: the mean of ``(error / sigma)^2`` per segment (1 for honest sigmas,
  far above 1 for overconfident ones) and the fraction of errors within three sigmas.

Angles in radians; frames 0-based.
"""

from __future__ import annotations

import numpy as np

from apcc_graph.model.arrays import FloatArray

WINDOW = 10
"""Frames per moving RMS in :func:`recovery_frames` (one frame's error is too noisy)."""


def moving_rms(errors: FloatArray, window: int = WINDOW) -> FloatArray:
    """``(F - window + 1, S)`` RMS of ``errors`` ``(F, S)`` over each run of ``window`` frames
    (row ``i`` covers frames ``i .. i + window - 1``)."""
    sq = np.asarray(errors, dtype=float) ** 2
    if len(sq) < window:
        return np.zeros((0, sq.shape[1]))
    c = np.cumsum(np.vstack([np.zeros((1, sq.shape[1])), sq]), axis=0)
    return np.sqrt((c[window:] - c[:-window]) / window)


def recovery_frames(errors: FloatArray, undisturbed: FloatArray | None, end: int,
                    factor: float = 2.0, window: int = WINDOW,
                    level: FloatArray | None = None) -> int | None:
    """Frames after ``end`` (the first frame after the fault) until the error is back within
    ``factor`` times the undisturbed error for good.

    The undisturbed error of a ``window``-frame run is the larger of the undisturbed run's
    moving RMS there and its RMS over all frames from ``end`` (a smoother's errors are
    correlated from frame to frame, so a short window of the undisturbed run alone can dip far
    below its typical error). When the faulted recording's noise is not the undisturbed one's
    (the fault changed the motion, so the recording was simulated anew), a window of the
    undisturbed run says nothing of the faulted run's window: give ``level`` instead, the
    undisturbed error per segment (e.g. its RMS over the whole recording).

    Args:
        errors: ``(F, S)`` estimate minus truth of the faulted run.
        undisturbed: ``(F, S)`` estimate minus truth of the same estimator on the same
            recording without the fault (``None`` with ``level``).
        end: first frame after the fault.
        factor: how far above the undisturbed error counts as recovered.
        window: frames per moving RMS.
        level: ``(S,)`` the undisturbed error, instead of ``undisturbed``'s windows.

    Returns:
        ``k``: every moving RMS from frame ``end + k`` on is within ``factor`` times the
        undisturbed error on every segment; ``None`` if that never holds before the end.
    """
    moving = moving_rms(np.asarray(errors, dtype=float)[end:], window)
    if len(moving) == 0:
        return None
    if level is not None:
        limit = factor * np.asarray(level, dtype=float)[None, :]
    elif undisturbed is not None:
        calm = np.asarray(undisturbed, dtype=float)[end:]
        limit = factor * np.maximum(moving_rms(calm, window), np.sqrt(np.mean(calm**2, axis=0)))
    else:
        raise ValueError("recovery_frames: give the undisturbed errors or their level")
    bad = np.flatnonzero(np.any(moving > limit, axis=1))
    if len(bad) == 0:
        return 0
    k = int(bad[-1]) + 1
    return k if k < len(moving) else None


def sigma_honesty(errors: FloatArray, sigmas: FloatArray) -> tuple[FloatArray, FloatArray]:
    """``(S,)`` mean ``(error / sigma)^2`` and ``(S,)`` fraction of ``|error| <= 3 sigma``
    over the frames with a finite sigma (NaN for a segment without any)."""
    e, s = np.asarray(errors, dtype=float), np.asarray(sigmas, dtype=float)
    ok = np.isfinite(s) & (s > 0)
    z2 = np.where(ok, (e / np.where(ok, s, 1.0)) ** 2, np.nan)
    with np.errstate(invalid="ignore"):
        n = ok.sum(axis=0)
        mean = np.where(n > 0, np.nansum(z2, axis=0) / np.maximum(n, 1), np.nan)
        inside = np.where(n > 0, np.sum(ok & (z2 <= 9.0), axis=0) / np.maximum(n, 1), np.nan)
    return mean, inside
