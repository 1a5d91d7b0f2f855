"""A segment's departure from its model, told apart from the measurement's noise
(``docs/estimation.md``, "Model error from the calibration").

After the calibration, each sample's segment end still misses the model's (at the bend fitted
to that sample) by a residual ``r_i``. Two things make it: the motion capture's noise, new at
every sample, and the model's error, a function of the robot's shape and motion that persists
while they do. The first is white, the second is not:

- the residuals are taken as noise alone when their autocorrelation at lags 1 to
  :data:`LAGS` is what white noise gives (the Ljung-Box statistic ``n sum rho(k)^2`` below the
  ``1 - WHITE_LEVEL`` quantile of a chi-square with :data:`LAGS` degrees of freedom): then the
  model's error is zero (a model-exact motion seen by noisy markers);
- otherwise the model's error is their RMS per component, bias included: every departure the
  estimator's tie must allow, the markers' noise too (a fraction of a millimetre and of a degree
  where this was measured, the white part of the variogram ``2 gamma(1) - gamma(2)``, reported
  beside it; the white part also holds departures that last a sample or two, such as a
  segment's shape while it is struck, so it is not removed);
- its correlation time is the lag at which the autocorrelation of the persistent part,
  ``(var - gamma(k)) / (var - white)`` with ``gamma(k) = E|r_(i+k) - r_i|^2 / 2`` the
  variogram and ``var`` the centred variance, falls below ``1/e``;
- its correlation length in bend is the same with the variogram over every pair of samples
  binned by the distance between their fitted frame vectors (radians): the model's error is a
  function of the robot's shape, so two samples at the same bends depart alike however far apart
  in time they are. On the real robot's recordings the correlation in time was not even
  monotonic on the struck one (0.31 at one sample, 0.96 at 3-8 s while it rested), while in bend
  it fell alike on both (about 0.98 within 1 deg, 1/e after 4-15 deg).

A segment whose departure is below :data:`NEGLIGIBLE` in both position and rotation gets a
zero model error (the exact model): the calibration of a model-exact motion with the markers'
noise measures up to 0.1 mm and 0.1 deg, from the parameters it re-fits.

Samples more than :data:`GAP` median intervals apart are not paired (the motion capture lost
the robot between them).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.stats

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.model_error import NEGLIGIBLE, ModelError

LAGS = 10
"""Lags of the whiteness test."""
WHITE_LEVEL = 1e-3
"""The whiteness test's false-alarm rate: residuals of noise alone are taken for a model error
this often."""
GAP = 1.5
"""Two samples further apart than this many median intervals are not neighbours."""
BEND_BINS = np.geomspace(math.radians(0.25), math.radians(90.0), 25)
"""Edges of the bend-distance bins (radians) of the correlation length."""
MIN_BIN_PAIRS = 30
"""A bend-distance bin with fewer pairs of samples is skipped."""
MAX_PAIRED_SAMPLES = 1500
"""Longer recordings are thinned evenly to this many samples for the pairs (quadratic)."""
MAX_LAG_FRACTION = 0.5
"""The correlation time is looked for up to this fraction of the samples (in lags); a slow
motion's model error changes slowly (20 s on a 46 s recording of a real robot)."""


def _pairs(times: FloatArray, lag: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices ``(i, i + lag)`` whose samples are ``lag`` steps apart with no gap between."""
    dt = float(np.median(np.diff(times)))
    steps_ok = np.diff(times) <= GAP * dt
    if lag > len(steps_ok):
        return np.empty(0, dtype=int), np.empty(0, dtype=int)
    window = np.lib.stride_tricks.sliding_window_view(steps_ok, lag).all(axis=1)
    first = np.flatnonzero(window)
    return first, first + lag


def _variogram(r: FloatArray, times: FloatArray, lag: int) -> tuple[float, int]:
    """``gamma(lag)`` per component of ``(N, 3)`` residuals, and the number of pairs."""
    a, b = _pairs(times, lag)
    if len(a) == 0:
        return math.nan, 0
    return float(np.mean((r[b] - r[a]) ** 2) / 2.0), len(a)


def departure(r: FloatArray, times: FloatArray) -> tuple[float, float, float | None]:
    """Of ``(N, 3)`` residuals sampled at ``times`` (module docstring): the model error's
    standard deviation per component (0 when the residuals are white), the white part's, and
    the correlation time (seconds; ``None`` when zero or not reached within half the
    recording)."""
    r = np.asarray(r, dtype=float)
    times = np.asarray(times, dtype=float)
    if len(r) < 2 * LAGS:
        return 0.0, 0.0, None
    total = float(np.mean(r**2))
    var = float(np.mean((r - r.mean(axis=0)) ** 2))
    gammas = [_variogram(r, times, lag) for lag in range(1, LAGS + 1)]
    n = gammas[0][1]
    if var == 0.0 or n == 0 or not all(math.isfinite(g) for g, _ in gammas):
        return 0.0, 0.0, None
    white = min(max(2.0 * gammas[0][0] - gammas[1][0], 0.0), gammas[0][0])
    q = 3 * n * sum((1.0 - g / var) ** 2 for g, _ in gammas)  # 3 components
    if q <= scipy.stats.chi2.ppf(1.0 - WHITE_LEVEL, LAGS):
        return 0.0, math.sqrt(white), None
    persistent = var - white
    dt = float(np.median(np.diff(times)))
    tau = None
    for lag in range(1, max(2, int(MAX_LAG_FRACTION * len(r)))):
        gamma, pairs = _variogram(r, times, lag)
        if pairs and persistent > 0.0 and (var - gamma) / persistent < 1.0 / math.e:
            tau = lag * dt
            break
    return math.sqrt(total), math.sqrt(white), tau


def correlation_bend(r: FloatArray, bends: FloatArray, white: float) -> float | None:
    """The distance between frame vectors (radians) at which the correlation of the persistent
    part of ``(N, 3)`` residuals falls below ``1/e`` (module docstring), interpolated between
    the bins of :data:`BEND_BINS` in log distance; ``None`` when it never does."""
    r = np.asarray(r, dtype=float)
    x = np.asarray(bends, dtype=float).reshape(len(r), -1)
    if len(r) > MAX_PAIRED_SAMPLES:
        keep = np.linspace(0, len(r) - 1, MAX_PAIRED_SAMPLES).round().astype(int)
        r, x = r[keep], x[keep]
    var = float(np.mean((r - r.mean(axis=0)) ** 2))
    persistent = var - white
    if persistent <= 0.0:
        return None
    a, b = np.triu_indices(len(r), 1)
    distance = np.linalg.norm(x[b] - x[a], axis=1)
    gamma = np.mean((r[b] - r[a]) ** 2, axis=1) / 2.0
    which = np.digitize(distance, BEND_BINS)
    last = None  # (log distance, correlation) of the last bin above 1/e
    for k in range(1, len(BEND_BINS)):
        inside = which == k
        if np.count_nonzero(inside) < MIN_BIN_PAIRS:
            continue
        centre = math.log(math.sqrt(BEND_BINS[k - 1] * BEND_BINS[k]))
        rho = (var - float(np.mean(gamma[inside]))) / persistent
        if rho < 1.0 / math.e:
            if last is None:
                return math.exp(centre)
            w = (last[1] - 1.0 / math.e) / (last[1] - rho)
            return math.exp(last[0] + w * (centre - last[0]))
        last = (centre, rho)
    return None


def measure_model_error(position: FloatArray, rotation: FloatArray, times: FloatArray,
                        source: str, bends: FloatArray | None = None) -> ModelError:
    """One segment's :class:`ModelError` from its residuals over a recording.

    Args:
        position: ``(N, 3)`` the segment end's position residual per sample (metres).
        rotation: ``(N, 3)`` its rotation residual (radians, a rotation vector).
        times: ``(N,)`` the samples' times (seconds, increasing).
        source: what was fitted, for the record.
        bends: ``(N, ...)`` the fitted frame vectors (radians), for the correlation length in
            bend; ``None``: not measured.
    """
    pos, pos_white, tau_p = departure(position, times)
    rot, rot_white, tau_r = departure(rotation, times)
    taus = [t for t in (tau_p, tau_r) if t is not None]
    lengths = [] if bends is None else [
        length for r, size, white in ((position, pos, pos_white), (rotation, rot, rot_white))
        if size > 0.0 and (length := correlation_bend(r, bends, white**2)) is not None]
    how = (f"backbone calibration of {source}, {len(times)} samples: the segment end's RMS "
           f"residual per component where it is not white (white part {pos_white * 1e3:.2f} "
           f"mm, {math.degrees(rot_white):.2f} deg)")
    if pos < NEGLIGIBLE[0] and rot < NEGLIGIBLE[1]:
        return ModelError(0.0, 0.0, None, f"{how}: {pos * 1e3:.2f} mm, "
                          f"{math.degrees(rot):.2f} deg, negligible")
    return ModelError(pos, rot, min(taus) if taus else None, how,
                      min(lengths) if lengths else None)
