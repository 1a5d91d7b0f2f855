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

So a smoother keeps the observations of its frames while the first is in its window
(:class:`FirstFrames`); when the start contradicts them, the unknown-start search
(:func:`~apcc_graph.estimation.start_search.find_start`) looks at those frames without the
prior, and its answer, if the data determine one, replaces the start: the smoother re-acquires
the frames from it in one batch (:class:`~apcc_graph.estimation.blackout.Reacquisition`), with a
warning that says so.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from dataclasses import replace

import numpy as np

from apcc_graph.estimation.blackout import Reacquisition
from apcc_graph.estimation.chi_square import FALSE_ALARM, chi2_limit
from apcc_graph.estimation.options import Robustness
from apcc_graph.estimation.start_search import find_start
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.sequence import FrameObservations


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


AGREE = 3.0
"""A start search's answer this many combined sigmas (its own and the start prior's) from the
start, on some component, replaces the start; closer, the start is kept."""

KEEPS = "The estimates keep the wrong start; give a better start or a looser start sigma"
"""What follows a contradicted start that nothing replaced."""


def check_start(theta0: FloatArray, sigma0: float, estimate: FloatArray,
                covariance: Callable[[], FloatArray], frame_time: float,
                consequence: Callable[[], str] = lambda: KEEPS) -> bool:
    """Warn (:class:`StartWarning`) when the start contradicts the images; whether it does.

    ``covariance`` gives the first frame's marginal covariance (gtsam may fail to: then no
    verdict); ``frame_time`` is the time of the newest frame, for the message; ``consequence``
    says what happens next (called only when the start is contradicted)."""
    try:
        cov = covariance()
    except (RuntimeError, IndexError, ValueError):
        return False
    chi2 = start_chi2(theta0, sigma0, estimate, cov)
    limit = chi2_limit(len(theta0))
    if not chi2 > limit:
        return False
    moved = ", ".join(f"{v:+.2f}" for v in np.degrees(np.asarray(estimate) - theta0))
    warnings.warn(
        f"the start configuration contradicts the images (chi-square {chi2:.0f} with "
        f"{len(theta0)} degrees of freedom, over {limit:.0f} happens with probability "
        f"{FALSE_ALARM:g}): by {frame_time:.2f} s the images had pulled the first frame by "
        f"{moved} deg against a prior of {np.degrees(sigma0):.2f} deg. {consequence()}",
        StartWarning, stacklevel=5)
    return True


class FirstFrames:
    """A smoother's frames while its first is in the window, for the start search.

    Args:
        kept: the store of frames (its ``theta0`` and ``sigma`` are replaced by the search's).
        spatial: the robot bends in 3-D (the search's parameterisation).
        robustness: the smoother's outlier threshold.
    """

    def __init__(self, kept: Reacquisition, spatial: bool, robustness: Robustness) -> None:
        self.kept, self.spatial, self.robustness = kept, spatial, robustness
        self.replacement: Reacquisition | None = None

    def keep(self, slot: int, t: float, observations: FrameObservations,
             first_inside: bool) -> FirstFrames | None:
        """Keep graph frame ``slot`` (at graph time ``t``) while the first frame is in the
        window (``first_inside``); ``None`` once it is not."""
        if not first_inside:
            return None
        self.kept.add(slot, t, observations)
        return self

    def check(self, theta0: FloatArray, sigma0: float, estimate: FloatArray,
              covariance: Callable[[], FloatArray], frame_time: float
              ) -> tuple[bool, Reacquisition | None]:
        """:func:`check_start`; when the start is contradicted, search the kept frames.
        Returns whether the start was contradicted and, if the search determines the start,
        the plan: the frames to re-acquire from the search's answer."""
        contradicted = check_start(theta0, sigma0, estimate, covariance, frame_time,
                                   lambda: self._search(np.asarray(theta0, dtype=float),
                                                        sigma0))
        return contradicted, self.replacement

    def _search(self, theta0: FloatArray, sigma0: float) -> str:
        sequence = self.kept.sequence()
        span = float(sequence.timestamps[-1] - sequence.timestamps[0])
        try:
            found = find_start(sequence, span + 1.0, self.kept.options, spatial=self.spatial,
                               robustness=self.robustness)
        except (RuntimeError, ValueError, IndexError) as error:
            return f"{KEEPS} (the start search failed: {error})"
        if not found.determined:
            return f"{KEEPS} (the start search could not tell: {found.reason})"
        variance = np.diagonal(found.hypotheses[0].blocks[0], axis1=-2, axis2=-1).ravel()
        z = np.abs(found.x0 - theta0) / np.sqrt(np.nan_to_num(variance, nan=np.inf) + sigma0**2)
        if not np.max(z) > AGREE:
            # The images, through the model, do not tell another start: what contradicts them
            # is the model (a real robot's mismatch), not the start; a search answer within
            # its own sigma would only trade the start for noise.
            return (f"{KEEPS} (the start search over the first {found.n_frames} frames finds a "
                    f"start within {AGREE:g} sigma of it: the images and the model disagree, "
                    "more than the start does)")
        sigma = float(np.nanmax(found.sigma0, initial=math.radians(1.0)))
        self.replacement = replace(self.kept, theta0=found.x0.copy(), sigma=sigma,
                                   search=False)
        shown = ", ".join(f"{v:.2f}" for v in np.degrees(found.theta0))
        spread = ", ".join(f"{v:.2f}" for v in np.degrees(found.sigma0))
        return (f"The start is replaced by the unknown-start search's answer over the first "
                f"{found.n_frames} frames: {shown} deg (sigma {spread} deg), and those frames "
                "are re-estimated from it")
