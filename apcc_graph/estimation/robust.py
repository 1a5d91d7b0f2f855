"""Outlier decisions per observation: graduated non-convexity with a truncated quadratic.

Each observation's whitened reprojection error ``r`` (pixel-noise units) is judged against its
own track's point. The loss is the truncated quadratic (TLS) ``min(r^2, c^2)``: an observation
further than ``c`` from its track's point is an outlier and contributes nothing. Minimising it
directly is non-convex, so the estimators follow graduated non-convexity (Yang, Antonante,
Tzoumas and Carlone, "Graduated Non-Convexity for Robust Spatial Perception", 2020): the
surrogate ``rho_mu`` is convex for small ``mu`` and becomes the TLS as ``mu`` grows; for fixed
weights the problem is a weighted least squares, and the optimal weights for fixed residuals
are, in closed form,

    w = 1                                   if r^2 <= mu / (mu + 1) c^2
    w = 0                                   if r^2 >= (mu + 1) / mu c^2
    w = c sqrt(mu (mu + 1)) / |r| - mu      otherwise.

``mu = inf`` gives the TLS's own weights (1 inside ``c``, 0 outside).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from apcc_graph.model.arrays import FloatArray, IntArray


def gnc_tls_weights(norms: FloatArray, threshold: float, mu: float) -> FloatArray:
    """GNC weights of the truncated quadratic for residual norms ``norms`` (see the module).

    Args:
        norms: whitened residual norms (``inf`` for an observation that cannot be an inlier).
        threshold: ``c``, the inlier threshold (same units as ``norms``).
        mu: the continuation parameter, > 0; ``inf`` for the plain truncated quadratic.
    """
    norms = np.asarray(norms, dtype=float)
    if math.isinf(mu):
        return (norms <= threshold).astype(float)
    r2, c2 = norms**2, threshold**2
    with np.errstate(divide="ignore", invalid="ignore"):
        middle = threshold * math.sqrt(mu * (mu + 1.0)) / norms - mu
    w = np.where(r2 <= mu / (mu + 1.0) * c2, 1.0,
                 np.where(r2 >= (mu + 1.0) / mu * c2, 0.0, middle))
    return np.clip(np.nan_to_num(w, nan=0.0), 0.0, 1.0)


def gnc_schedule(mu0: float = 1.0, factor: float = 4.0, steps: int = 3) -> list[float]:
    """``mu0, mu0 factor, ..., mu0 factor^(steps-1), inf``: the continuation the estimators use.

    The default starts with weights that fall from 1 to 0 between ``0.7 c`` and ``1.4 c``; a
    start that is far off (so that true observations sit beyond the threshold) wants a smaller
    ``mu0``.
    """
    return [mu0 * factor**i for i in range(steps)] + [math.inf]


def gnc_start(norms: FloatArray, threshold: float, spread: float = 4.0, factor: float = 4.0,
              mu_last: float = 10.0) -> list[float]:
    """A GNC continuation fitted to the residuals at the start.

    The first ``mu`` puts the surrogate's cut-off (the residual beyond which the weight is 0,
    ``sqrt((mu + 1) / mu) c``) at ``spread`` times the median residual, and never below
    ``sqrt(2) c`` (``mu = 1``) nor above ``30 c``: a start whose true observations sit several
    thresholds away (angles a degree off are 9 px at f = 500 px) keeps them in while the
    solution moves, and a good start begins at ``mu = 1``. ``mu`` then grows by ``factor``
    until it passes ``mu_last``, and the truncated quadratic itself (``inf``) ends it.
    """
    finite = np.asarray(norms, dtype=float)
    finite = finite[np.isfinite(finite)]
    median = float(np.median(finite)) if len(finite) else 0.0
    cutoff = min(max(spread * median, math.sqrt(2.0) * threshold), 30.0 * threshold)
    mu = threshold**2 / (cutoff**2 - threshold**2)
    out = [mu]
    while out[-1] < mu_last:
        out.append(out[-1] * factor)
    return out + [math.inf]


def enough_rows(weights: FloatArray, tracks: IntArray, starts: IntArray, least: int
                ) -> NDArray[np.bool_]:
    """Per row, whether its track has at least ``least`` rows of weight > 0, or all its rows
    when it has fewer (never fewer than two).

    A track with one weighted row says nothing about the angles, yet its point, held off that
    row's ray between re-triangulations, makes a large spurious cost; and a track whose rows
    the model-free gate closed but for one or two has no point worth judging other rows
    against (on the reliability bench a track that began with two wrong associations was
    decided on no open row at all, and its wrong point pulled segment 3 by 17 degrees).

    Args:
        weights: ``(N,)`` row weights (robust decisions, gate weights or both).
        tracks, starts: the rows' compact track index and the tracks' row offsets
            (:class:`~apcc_graph.factors.track_points.TrackObservations`).
        least: weighted rows a track needs.
    """
    if len(weights) == 0:
        return np.zeros(0, dtype=bool)
    open_per_track = np.add.reduceat((np.asarray(weights) > 0.0).astype(np.int64), starts[:-1])
    need = np.maximum(np.minimum(least, np.diff(starts)), 2)
    return (open_per_track >= need)[tracks]
