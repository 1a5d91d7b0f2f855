"""No confident answer at a joint limit (``docs/estimation.md``, "What the estimators say when
the data go wrong").

A bend the estimator leaves at (or beyond) its joint limit ``theta_max`` is held there by the
soft limit prior, not by the images: the images pulled it further than the robot can bend, so
the model does not explain them there (a wrong basin, or a robot that departs from its model).
The prior's curvature then makes the marginal sigma small (0.11 deg at a 120 deg limit, for a
real robot's segment whose measured bend was about 11 deg). :func:`at_the_limits` marks
those bends ``"at-limit"``, reports their sigma as the whole range ``theta_max`` (the bend is
somewhere in it, as far as the estimate can tell) and warns once, naming the segments.

Where the residual test fails (:mod:`~apcc_graph.estimation.model_fit`: the model rejects many
of the observations the images alone accept), :func:`flag_misfits` marks the frames where it
fails ``"misfit"``: each failing camera's frames whose own share of rejected observations is
above the alarm, for the camera's segment and every segment below it (they all place that
camera), where their status was ``"ok"`` (a status that already says something, such as
``"reacquired"`` or ``"at-limit"``, is kept). Their sigmas describe the pixel noise, not what
the model leaves unexplained; the status says so frame by frame, and the
:class:`~apcc_graph.estimation.model_fit.ModelFitWarning` says it for the whole estimate.
"""

from __future__ import annotations

import warnings
from dataclasses import replace

import numpy as np

from apcc_graph.estimation.model_fit import ModelFit
from apcc_graph.estimation.result import Estimate

AT_LIMIT = "at-limit"
"""The status of a bend within the margin of its joint limit."""
MISFIT = "misfit"
"""The status of a bend in a frame where the residual test fails (module docstring)."""
WRONG_BASIN_SHARE = 0.1
"""An estimate from an unknown start with some segment at its joint limit in more than this
share of the frames is taken for a wrong basin (:func:`wrong_basin`)."""


class LimitWarning(UserWarning):
    """Bends ended at their joint limits: their sigmas say nothing."""


def at_the_limits(result: Estimate, margin: float) -> Estimate:
    """``result`` with every bend within ``margin`` (radians) of its joint limit marked
    (module docstring); the same object when none is."""
    limits = np.array([seg.theta_max for seg in result.robot.segments])
    at = np.abs(result.thetas) >= limits - margin
    if not at.any():
        return result
    sigmas = np.where(at, np.broadcast_to(limits, at.shape), result.sigmas)
    status = np.where(at, AT_LIMIT, result.status)
    counts = at.sum(axis=0)
    named = ", ".join(f"segment {j + 1} in {n} of {len(at)} frames"
                      for j, n in enumerate(counts) if n)
    warnings.warn(f"{result.method}: bends at their joint limits ({named}): the images pull "
                  "them further than the robot bends, so the model does not explain them "
                  "there (a wrong start or basin, or a robot that leaves its model); their "
                  "sigmas are reported as the whole range and their status is "
                  f"{AT_LIMIT!r}", LimitWarning, stacklevel=3)
    return replace(result, sigmas=sigmas, status=status)


def flag_misfits(result: Estimate, fit: ModelFit) -> Estimate:
    """``result`` with the frames where ``fit`` fails marked :data:`MISFIT` (module docstring;
    only bends whose status was ``"ok"``); the same object when the test passes."""
    failing = fit.failing()
    if not failing:
        return result
    flagged = np.zeros(result.status.shape, dtype=bool)
    for camera in failing:
        shares = camera.frame_shares
        frames = np.isfinite(shares) & (shares > fit.alarm)
        flagged[:len(frames), :camera.camera + 1] |= frames[:len(flagged), None]
    status = np.where(flagged & (result.status == "ok"), MISFIT, result.status)
    return replace(result, status=status)


def wrong_basin(result: Estimate) -> str | None:
    """Why an estimate from a start found in the images sits in a wrong basin, or ``None``.

    A segment at its joint limit in more than :data:`WRONG_BASIN_SHARE` of the frames: the
    images pulled it past what the robot bends, which from a start the search found means the
    search picked the wrong start (on a real robot's struck recording, from an unknown start
    the batch held segment 1 at its 120 deg limit in 137 of 139 frames, its tips 204 / 342 mm
    off, where a given start put them 0.9 / 2.1 mm off). The caller raises
    :class:`~apcc_graph.estimation.start_search.UnknownStartError` with it.
    """
    share = np.mean(result.status == AT_LIMIT, axis=0)
    bad = [j for j, s in enumerate(share) if s > WRONG_BASIN_SHARE]
    if not bad:
        return None
    named = ", ".join(f"segment {j + 1} in {100 * share[j]:.0f}% of the frames" for j in bad)
    return (f"{result.method}: from the start found in the images the bends end at their joint "
            f"limits ({named}): a wrong start; pass the starting configuration (theta0)")
