"""Does the kinematic model explain the images? A residual test of an estimate
(docs/estimation.md, "Does the model explain the images?").

An estimator's sigmas are honest only when its model is: on a real robot, which bends only
approximately as the APCC model says, the exact-model batch can be tens of degrees off while it
reports sigmas of a tenth of a degree. The images say when that happens. Each camera's
observations are split twice:

- **without the model**: the observations that agree with a neighbouring frame of the same
  camera under one rotation (:func:`~apcc_graph.frontend.rotation_pairs.pair_inliers`); a
  wrong association rarely does, a true observation nearly always does, whatever the robot's
  kinematics;
- **with the model**: each track's point is triangulated robustly at the estimate's camera
  poses (the kinematic chain at the estimated bends), and an observation whose whitened
  reprojection error exceeds ``inlier_sigmas`` is rejected, as the estimators decide
  outliers.

When the model explains the images, the model rejects almost none of the observations the
images alone accept: with Gaussian pixel noise a row's whitened error ``r`` has
``r^2 ~ c chi^2_2`` (``c = (2n - 3) / (2n)`` for a track of ``n`` rows, its point eliminated),
so the share beyond ``T`` is about ``exp(-T^2 / (2c))``, 0.2% at ``T = 3.5``. When the real
robot leaves its model by a few millimetres and degrees, no configuration puts every camera
where its images say it is, and the model rejects a share many times that (on the shipped
real robot's replayed motion, 10-14% for the exact-model batch, against 0.3-0.4% on the
model-exact version of the same motion). So does an estimate stuck in a wrong basin. The
estimate's sigmas then describe the pixel noise, not its error, and :func:`check_model_fit`
says so with a :class:`ModelFitWarning`.

A second part needs no image: the first frame's estimate against the start prior it was given
(:class:`StartFit`). Where the images cannot tell a bend (a robot that barely moves), the
model's mismatch can drag a whole recording tens of degrees from its start while every image is
explained; the prior's chi-square says so.

The test needs no ground truth and no setting but the share it tolerates
(``Robustness.misfit_alarm``, 5%: 25 times the share expected at the default threshold).
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.chi_square import FALSE_ALARM, chi2_limit
from apcc_graph.estimation.graph import camera_chain, observed_cameras
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.factors.camera_chain import CameraChain
from apcc_graph.factors.reduced_system import robust_residual_norms
from apcc_graph.factors.track_points import TrackObservations
from apcc_graph.frontend.rotation_pairs import pair_inliers
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.sequence import Sequence

__all__ = ["CameraFit", "ModelFit", "ModelFitWarning", "MIN_REJECTED", "StartFit",
           "check_model_fit", "expected_share", "fit_of_camera"]

MIN_REJECTED = 20
"""Fewer rejected observations than this never raise the alarm (too few to tell)."""

MIN_FRAME_ROWS = 10
"""A frame's own share is computed from at least this many model-free inliers."""


class ModelFitWarning(UserWarning):
    """The images contradict an estimate: at its bends the kinematic model rejects many
    observations that the images alone accept, because the robot leaves its model or the
    estimate sits in a wrong basin. Its sigmas (which assume neither) are then too small, and
    its bends may be far off. The message names the cameras and the shares."""


@dataclass(frozen=True)
class CameraFit:
    """One camera's residual test.

    Attributes:
        camera: the segment the camera rides on (0-based).
        observations: its observations tested (rows of tracks seen at least twice).
        accepted: those the images alone accept (model-free inliers).
        rejected: of those, how many the model rejects (whitened error beyond the threshold
            at the estimate).
        expected: the share of ``accepted`` a model that explains the images rejects.
        frame_shares: ``(F,)`` each frame's share of its model-free inliers rejected (NaN
            where a frame has fewer than :data:`MIN_FRAME_ROWS` of them).
    """

    camera: int
    observations: int
    accepted: int
    rejected: int
    expected: float
    frame_shares: FloatArray

    @property
    def share(self) -> float:
        """The share of the model-free inliers the model rejects (NaN without any)."""
        return self.rejected / self.accepted if self.accepted else math.nan


@dataclass(frozen=True)
class ModelFit:
    """The residual test of one estimate (module docstring).

    Attributes:
        cameras: each observing camera's test.
        alarm: the share of model-free inliers the model may reject before the test fails.
        inlier_sigmas: the rejection threshold (whitened pixel-noise units).
        start: whether the first frame's estimate agrees with the start prior it was given
            (:class:`StartFit`); ``None`` without a start prior.
    """

    cameras: tuple[CameraFit, ...]
    alarm: float
    inlier_sigmas: float
    start: StartFit | None = None

    def failing(self) -> list[CameraFit]:
        """The cameras whose test fails: more than ``alarm`` of their model-free inliers
        rejected (and at least :data:`MIN_REJECTED` of them)."""
        return [c for c in self.cameras
                if c.rejected >= MIN_REJECTED and c.share > self.alarm]

    @property
    def start_contradicted(self) -> bool:
        """Whether the first frame's estimate contradicts its start prior."""
        return self.start is not None and self.start.contradicted

    @property
    def explained(self) -> bool:
        """Whether the model explains every camera's images at the estimate, and the estimate
        agrees with its start prior."""
        return not self.failing() and not self.start_contradicted

    def frames_failing(self, camera: CameraFit) -> float:
        """The share of ``camera``'s frames (those with a share) above the alarm."""
        shares = camera.frame_shares[np.isfinite(camera.frame_shares)]
        return float(np.mean(shares > self.alarm)) if len(shares) else math.nan

    def summary(self) -> str:
        """One line per camera: the share rejected beside the share expected."""
        lines = [] if self.start is None else [self.start.summary()]
        for c in self.cameras:
            verdict = "FAILS" if c in self.failing() else "ok"
            lines.append(f"cam_{c.camera + 1}: the model rejects "
                         f"{100 * c.share:.1f}% of the {c.accepted} observations the images "
                         f"alone accept (expected {100 * c.expected:.1f}%, alarm "
                         f"{100 * self.alarm:.0f}%): {verdict}")
        return "\n".join(lines)

    def message(self) -> str:
        """The warning's text (empty when the test passes)."""
        bad = self.failing()
        said = []
        if bad:
            parts = [f"segment {c.camera + 1}'s camera {100 * c.share:.1f}% (expected "
                     f"{100 * c.expected:.1f}%; in {100 * self.frames_failing(c):.0f}% of its "
                     "frames above the alarm)" for c in bad]
            said.append("at its bends the kinematic model rejects, of the observations the "
                        "images alone accept, " + "; ".join(parts))
        if self.start is not None and self.start.contradicted:
            said.append(self.start.summary())
        if not said:
            return ""
        return ("the images contradict the estimate: " + "; and ".join(said) + ". Either the "
                "robot leaves its model (calibrate it, check the camera mounts, or treat the "
                "model error as noise) or the estimate is in a wrong basin (a wrong start); "
                "either way its sigmas are too small and its bends may be far off")


@dataclass(frozen=True)
class StartFit:
    """Whether the first frame's estimate agrees with its start prior.

    With the prior ``x0 +- sigma0`` per component and the estimate ``x_hat`` of the first
    frame, ``chi2 = |x_hat - x0|^2 / sigma0^2``. If prior and images agree, the Mahalanobis
    distance ``u^T (sigma0^2 I - Sigma)^-1 u`` (``Sigma`` the frame's marginal covariance) is
    chi-square with ``dof`` degrees of freedom, and ``chi2`` never exceeds it: testing ``chi2``
    against that law's tail is conservative (it needs no covariance, and warns less often).

    Attributes:
        moved: ``(dim,)`` ``x_hat - x0`` (radians).
        sigma0: the start prior's standard deviation per component (radians).
        false_alarm: the tail probability beyond which the start is contradicted.
    """

    moved: FloatArray
    sigma0: float
    false_alarm: float = FALSE_ALARM

    @property
    def chi2(self) -> float:
        """``|x_hat - x0|^2 / sigma0^2``."""
        return float(np.sum(np.asarray(self.moved) ** 2) / self.sigma0**2)

    @property
    def limit(self) -> float:
        """The chi-square value with ``dof`` degrees of freedom exceeded with probability
        ``false_alarm``."""
        return chi2_limit(len(self.moved), self.false_alarm)

    @property
    def contradicted(self) -> bool:
        """Whether ``chi2`` lies beyond ``limit``."""
        return self.chi2 > self.limit

    def summary(self) -> str:
        """One line: how far the first frame moved from its start, against the prior."""
        moved = ", ".join(f"{v:+.2f}" for v in np.degrees(self.moved))
        verdict = "contradicted" if self.contradicted else "ok"
        return (f"first frame moved from the start by {moved} deg against a prior of "
                f"{math.degrees(self.sigma0):.2f} deg (chi-square {self.chi2:.1f}, limit "
                f"{self.limit:.1f} with {len(self.moved)} degrees of freedom): {verdict}")


def expected_share(track_rows: NDArray[np.int64], inlier_sigmas: float) -> float:
    """The share of observations whose whitened error exceeds ``inlier_sigmas`` when the
    model explains the images: ``mean(exp(-T^2 / (2 c)))`` over the rows, ``c = (2n - 3) /
    (2n)`` for a row of a track of ``n >= 2`` rows (its point eliminated)."""
    n = np.asarray(track_rows, dtype=float)
    if not len(n):
        return 0.0
    c = np.maximum(2.0 * n - 3.0, 0.0) / (2.0 * n)
    with np.errstate(divide="ignore"):
        tail = np.where(c > 0.0, np.exp(-inlier_sigmas**2 / (2.0 * np.maximum(c, 1e-300))),
                        0.0)
    return float(np.mean(tail))


def fit_of_camera(obs: TrackObservations, chain: CameraChain, x: FloatArray, n_frames: int,
                  inlier_sigmas: float) -> CameraFit:
    """One camera's test at the ``(F, dim)`` frame vectors ``x``, its camera poses from
    ``chain``."""
    first = int(obs.frames.min())
    last = int(obs.frames.max())
    norms, _ = robust_residual_norms(obs, chain, x[first:last + 1], first,
                                     np.ones(len(obs)))
    bearings = np.column_stack([obs.xy, np.ones(len(obs))])
    free = pair_inliers(obs.frames, obs.tracks, bearings)
    rejected = free & ~(norms <= inlier_sigmas)  # NaN (an undetermined point) counts
    rows = np.diff(obs.starts)[obs.tracks]
    accepted_per = np.bincount(obs.frames[free], minlength=n_frames)[:n_frames]
    rejected_per = np.bincount(obs.frames[rejected], minlength=n_frames)[:n_frames]
    with np.errstate(invalid="ignore", divide="ignore"):
        shares = np.where(accepted_per >= MIN_FRAME_ROWS, rejected_per / accepted_per, np.nan)
    return CameraFit(obs.camera, len(obs), int(free.sum()), int(rejected.sum()),
                     expected_share(rows[free], inlier_sigmas), shares)


def check_model_fit(sequence: Sequence, x: FloatArray, bending: Bending,
                    options: GraphOptions | None = None, inlier_sigmas: float = 3.5,
                    alarm: float = 0.05, warn: bool = True,
                    start: tuple[FloatArray, float] | None = None) -> ModelFit:
    """The residual test of the frame vectors ``x`` (``(F, dim)`` of ``bending``) on
    ``sequence``'s tracks, with ``sequence.robot``'s segments and mounts (module docstring).

    Args:
        sequence: the sequence (its robot: the one the estimate holds, calibrated or not).
        x: the estimate's frame vectors.
        bending: their parameterisation.
        options: the tracks as the graph builds them (pixel noise, shortest tracks).
        inlier_sigmas: the rejection threshold (whitened pixel-noise units).
        alarm: the share of model-free inliers rejected beyond which the test fails.
        warn: issue a :class:`ModelFitWarning` when it fails.
        start: the start prior the estimate was given, ``(x0, sigma0)``: the first frame's
            vector ``(dim,)`` and its standard deviation per component (radians); tested as
            :class:`StartFit`.

    Raises:
        ValueError: ``x`` not one frame vector per frame, or ``alarm`` outside ``(0, 1)``.
    """
    options = GraphOptions() if options is None else options
    x = np.asarray(x, dtype=float)
    if x.shape != (sequence.n_frames, bending.dim):
        raise ValueError(f"frame vectors of shape {x.shape}: expected ({sequence.n_frames}, "
                         f"{bending.dim})")
    if not 0.0 < alarm < 1.0:
        raise ValueError(f"alarm = {alarm!r}: expected a share in (0, 1)")
    cameras = []
    for obs in observed_cameras(sequence, options):
        chain = camera_chain(sequence.robot, obs.camera, bending, sequence.world_T_base)
        cameras.append(fit_of_camera(obs, chain, x, sequence.n_frames, inlier_sigmas))
    start_fit = None if start is None else StartFit(
        x[0] - np.asarray(start[0], dtype=float), float(start[1]))
    fit = ModelFit(tuple(cameras), float(alarm), float(inlier_sigmas), start_fit)
    if warn and not fit.explained:
        warnings.warn(fit.message(), ModelFitWarning, stacklevel=2)
    return fit
