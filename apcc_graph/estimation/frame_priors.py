"""The priors a streaming estimator adds with each new frame (docs/estimation.md, "The
fixed-lag smoother"): the start prior on frame 0, the random-walk motion prior from the previous
frame (or, after a pause longer than the window, from its last estimate), a loose prior at the
initial guess when there is no motion prior (so that a frame without tracks never leaves the
system undetermined), and the soft joint limits when the initial guess comes near them.

Frame vectors are the robot's parameterisation's
(:class:`~apcc_graph.model.parameterisation.Bending`); the limits bound each segment's bend.
"""

from __future__ import annotations

import math

import gtsam
import numpy as np

from apcc_graph.estimation.graph import limit_factor
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.window import Window
from apcc_graph.factors.keys import frame_key
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending

LIMIT_MARGIN = math.radians(10.0)
"""Soft joint limits join frames whose initial angles come within this of a limit (radians)."""


def near_limits(x: FloatArray, bending: Bending) -> bool:
    """Whether a frame's vector comes within :data:`LIMIT_MARGIN` of a joint limit."""
    return bool(np.any(bending.magnitudes(x) > bending.theta_max - LIMIT_MARGIN))


def frame_priors(graph: gtsam.NonlinearFactorGraph, f: int, dt: float, x: FloatArray,
                 start: FloatArray, window: Window, bending: Bending, options: GraphOptions,
                 loose_sigma: float) -> None:
    """Add frame f's priors to ``graph``: ``x`` is its initial guess, ``start`` the start
    prior's mean (frame 0), ``dt`` the seconds since the previous frame."""
    dim = len(x)
    key = frame_key(f)
    if f == 0:
        graph.add(gtsam.PriorFactorVector(
            key, start, gtsam.noiseModel.Isotropic.Sigma(dim, options.theta0_sigma)))
    elif options.motion_sigma is not None:
        motion = gtsam.noiseModel.Isotropic.Sigma(dim, options.motion_sigma
                                                  * math.sqrt(max(dt, 1e-9)))
        if window.inside(f - 1):
            graph.add(gtsam.BetweenFactorVector(frame_key(f - 1), key, np.zeros(dim), motion))
        else:  # a pause longer than the lag: the previous frame has left the window
            graph.add(gtsam.PriorFactorVector(key, window.latest(f - 1), motion))
    if f > 0 and options.motion_sigma is None:
        graph.add(gtsam.PriorFactorVector(
            key, x, gtsam.noiseModel.Isotropic.Sigma(dim, loose_sigma)))
    if near_limits(x, bending):
        graph.add(limit_factor(key, bending, options.limit_sigma))
