"""Array type aliases shared by every layer (float64 and int64 numpy arrays) and the one
root-mean-square every error figure uses."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]



def rms(values: ArrayLike, axis: int | None = 0, skip_nan: bool = False) -> FloatArray:
    """Root mean square of ``values`` along ``axis`` (over all of them with ``axis=None``), in
    their unit. NaN propagates unless ``skip_nan`` (then NaN entries, e.g. frames an estimator
    gave no value for, are left out)."""
    mean = np.nanmean if skip_nan else np.mean
    return np.sqrt(mean(np.square(np.asarray(values, dtype=float)), axis=axis))


def window_rms(values: ArrayLike, window: int) -> FloatArray:
    """``(W, ...)`` :func:`rms` over consecutive blocks of ``window`` rows of ``values`` (the last
    block may be shorter)."""
    values = np.asarray(values, dtype=float)
    return np.array([rms(values[s:s + window]) for s in range(0, len(values), window)])
