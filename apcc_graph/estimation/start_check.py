"""Whether the start given to a smoother agrees with what the images say about the first frame.

The first frame carries a prior ``theta0 +- sigma0``. When that frame leaves the smoother's
window, its estimate ``theta_hat`` has moved from ``theta0`` by ``u = theta_hat - theta0``
under the pull of the images, and its marginal covariance is ``Sigma``. If the prior and the
images agree, ``u`` is Gaussian with covariance ``sigma0^2 I - Sigma`` (the prior's variance
minus what remains after the images: the part the images explain), so

    chi2 = u^T (sigma0^2 I - Sigma)^-1 u

follows a chi-square law with S degrees of freedom. A value far in its tail says the start
contradicts the images: the estimates then carry the wrong start, which a tight prior will not
let go of. Linear-Gaussian reasoning at the current estimate; angles in radians.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable

import numpy as np
import scipy.stats

from apcc_graph.model.arrays import FloatArray

FALSE_ALARM = 1e-4
"""Probability of warning on a start that agrees with the images."""


class StartWarning(UserWarning):
    """The start configuration given to a smoother contradicts its first frames' images."""


def start_chi2(theta0: FloatArray, sigma0: float, estimate: FloatArray,
               covariance: FloatArray) -> float:
    """The statistic of the module docstring (``nan`` when the images add nothing)."""
    u = np.asarray(estimate, dtype=float) - np.asarray(theta0, dtype=float)
    C = sigma0**2 * np.eye(len(u)) - np.asarray(covariance, dtype=float)
    lam, vec = np.linalg.eigh(0.5 * (C + C.T))
    keep = lam > 1e-6 * sigma0**2  # directions the images informed
    if not keep.any():
        return float("nan")
    proj = vec[:, keep].T @ u
    return float(np.sum(proj**2 / lam[keep]))


def check_start(theta0: FloatArray, sigma0: float, estimate: FloatArray,
                covariance: Callable[[], FloatArray], frame_time: float) -> bool:
    """Warn (:class:`StartWarning`) when the start contradicts the images; whether it does.

    ``covariance`` gives the first frame's marginal covariance (gtsam may fail to: then no
    verdict); ``frame_time`` is the time of the newest frame, for the message."""
    try:
        cov = covariance()
    except (RuntimeError, IndexError, ValueError):
        return False
    chi2 = start_chi2(theta0, sigma0, estimate, cov)
    limit = float(scipy.stats.chi2.isf(FALSE_ALARM, len(theta0)))
    if not chi2 > limit:
        return False
    moved = ", ".join(f"{v:+.2f}" for v in np.degrees(np.asarray(estimate) - theta0))
    warnings.warn(
        f"the start configuration contradicts the images (chi-square {chi2:.0f} with "
        f"{len(theta0)} degrees of freedom, over {limit:.0f} happens with probability "
        f"{FALSE_ALARM:g}): by {frame_time:.2f} s the images had pulled the first frame by "
        f"{moved} deg against a prior of {np.degrees(sigma0):.2f} deg. The estimates keep the "
        "wrong start; give a better start or a looser start sigma", StartWarning, stacklevel=5)
    return True
