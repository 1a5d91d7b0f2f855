"""What the fixed-lag smoother does differently for a spatial robot.

The smoother's variables are then every frame's bending vectors ``(u_0, v_0, u_1, ...)``
(:mod:`apcc_graph.estimation.spatial_bends`). This module holds the three pieces that differ
from the planar smoother, and the front end that starts either:

- :func:`two_point_guess`: a new frame's bends from the previous frame's by the 2-point RANSAC
  (:func:`~apcc_graph.frontend.spatial_ransac.two_point_ransac`), per segment from the base
  outward, where the window knows too few points (the planar smoother's 1-point front end);
- :func:`front_end_guess`: either front end, planar or spatial, and the tracks it accepted
  (they join the graph early: :meth:`~apcc_graph.estimation.live_tracks.LiveTracks.vouch`);
- :func:`covariance_blocks`: what the window keeps of a frame's marginal covariance, the
  ``2 x 2`` block of each bending vector, flattened to ``(4 S,)``;
- :func:`present`: a frame as the smoother returns it, ``thetas`` and ``sigmas`` of the bends'
  magnitudes, and ``psis`` and ``psi_sigmas`` (first order, as the spatial batch's).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.initial_guess import (
    FramePairs,
    chained_guess,
    frame_pairs,
    one_point_guess,
)
from apcc_graph.estimation.spatial_bends import bends_from, polar_from, polar_sigmas
from apcc_graph.estimation.window import SmootherFrame
from apcc_graph.frontend.spatial_ransac import two_point_ransac
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.bending import polar
from apcc_graph.model.robot import Robot

Rows = Mapping[int, tuple[NDArray[np.int64], FloatArray, FloatArray]]
"""A frame's observations: camera -> (track ids, normalised points, whitening)."""


def two_point_guess(previous: FloatArray, prediction: FloatArray, robot: Robot,
                    base_previous: FloatArray | None, base_now: FloatArray | None,
                    pairs: list[FramePairs], threshold_px: float,
                    rng: np.random.Generator | None = None
                    ) -> tuple[FloatArray, dict[int, NDArray[np.bool_]]]:
    """The new frame's bending vectors ``(2 S,)`` by the 2-point front end, from the previous
    frame's; arguments and result as
    :func:`~apcc_graph.estimation.initial_guess.one_point_guess`, in bending vectors."""
    def solve(i: int, before: FloatArray, motion: FloatArray, found: FramePairs,
              threshold: float, rng: np.random.Generator
              ) -> tuple[FloatArray | None, NDArray[np.bool_]]:
        theta_a, psi_a = polar(before[0], before[1])
        bend, info = two_point_ransac(float(theta_a), float(psi_a), robot.segments[i],
                                      robot.cameras[i].tip_T_cam, motion, found.f_a, found.f_b,
                                      threshold=threshold, rng=rng)
        return (bends_from(bend[:1], bend[1:]) if info.success else None), info.inliers

    return chained_guess(previous, prediction, robot, base_previous, base_now, pairs,
                         threshold_px, rng, solve, spatial=True)


def front_end_guess(spatial: bool, previous: FloatArray, prediction: FloatArray, robot: Robot,
                    base_previous: FloatArray | None, base_now: FloatArray | None,
                    previous_rows: Rows, rows: Rows, threshold_px: float,
                    rng: np.random.Generator | None = None
                    ) -> tuple[FloatArray, dict[int, NDArray[np.int64]]]:
    """The new frame's angles (or bending vectors, ``spatial``) by the front end from the
    previous frame's (:func:`~apcc_graph.estimation.initial_guess.one_point_guess` or
    :func:`two_point_guess`), over the two frames' observations ``camera -> (track ids,
    normalised points, whitening)``; and per camera whose RANSAC succeeded the ids of the
    tracks it accepted as inliers of its consensus."""
    pairs = frame_pairs(previous_rows, rows)
    guess, inliers = (two_point_guess if spatial else one_point_guess)(
        previous, prediction, robot, base_previous, base_now, pairs, threshold_px, rng)
    return guess, {p.camera: rows[p.camera][0][p.rows[inliers[p.camera]]]
                   for p in pairs if p.camera in inliers}


def covariance_blocks(covariance: FloatArray) -> FloatArray:
    """``(4 S,)`` the flattened ``2 x 2`` diagonal blocks of a frame's ``(2 S, 2 S)`` marginal
    covariance."""
    C = np.asarray(covariance, dtype=float)
    S = len(C) // 2
    return np.array([C[2 * j:2 * j + 2, 2 * j:2 * j + 2] for j in range(S)]).ravel()


def present(frame: SmootherFrame) -> SmootherFrame:
    """A spatial frame as returned: from its bending vectors ``thetas`` ``(2 S,)`` and
    :func:`covariance_blocks` ``sigmas`` ``(4 S,)``, the magnitudes ``thetas`` with their
    ``sigmas`` and the bending planes ``psis`` with ``psi_sigmas`` (each ``(S,)``)."""
    bends = np.asarray(frame.thetas, dtype=float)
    S = len(bends) // 2
    thetas, psis = polar_from(bends)
    sigma, psi_sigma = polar_sigmas(bends, np.asarray(frame.sigmas).reshape(S, 2, 2))
    return replace(frame, thetas=thetas, sigmas=sigma, psis=psis, psi_sigmas=psi_sigma)
