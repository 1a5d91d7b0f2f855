"""A frame between keyframes, fitted against its keyframes' values: the final estimate of a
frame a keyframe smoother kept out of its window.

The frame's rows and the rows of the same tracks in the keyframes around it form, per camera,
one small problem: the keyframes' vectors held at their values, the frame's vector free, each
track's point free. Each point is eliminated exactly as in the smoother's own projection factor
(:func:`~apcc_graph.factors.reduced_system.reduced_system`, the Schur complement), so the frame's
block of that reduced system is the Gauss-Newton system of this batch in the frame's vector
alone; a few steps solve it (:func:`fit_between_keyframes`). A track enters when the keyframes
saw it at least ``least_rows`` times (its point is then fixed by the keyframes, and the frame's
row measures the frame). Outliers: each track's point is found robustly from all its rows at the
frame's starting vector, and a row more than ``inlier_sigmas`` off it is left out (the truncated
quadratic, as the smoother decides its rows).

Frames: the keyframes' vectors ``(m, P)`` and base poses, the frame's last (local index ``m``).
Units: radians, metres, whitened residuals in pixel-noise units (``Rows``' whitening).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.initial_guess import FrameRows
from apcc_graph.estimation.projection_tracks import Rows
from apcc_graph.estimation.robust import gnc_tls_weights
from apcc_graph.factors.camera_chain import CameraChain
from apcc_graph.factors.reduced_system import reduced_system, robust_residual_norms
from apcc_graph.factors.track_points import TrackObservations
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending


@dataclass(frozen=True)
class Keyframe:
    """One keyframe as a frame between keyframes is fitted against it.

    Attributes:
        x: its vector (the parameterisation's, radians): held fixed.
        rows: its observations (camera -> track ids, normalised points, whitening).
        base: its base pose ``world_T_base`` (``None``: identity).
    """

    x: FloatArray
    rows: Rows
    base: FloatArray | None


@dataclass(frozen=True)
class FrameFit:
    """The frame's fitted vector and what backed it.

    Attributes:
        x: the vector (radians).
        covariance: ``(P, P)`` its covariance with the keyframes held fixed (``inf`` on the
            diagonal where no row constrains a component).
        rows: the frame's rows that entered (inliers of tracks the keyframes saw enough).
        cost: the final weighted sum of squared whitened residuals.
    """

    x: FloatArray
    covariance: FloatArray
    rows: int
    cost: float


def _camera_problem(cam: int, chain: CameraChain, rows: Rows, base: FloatArray | None,
                    keyframes: Sequence[Keyframe], least_rows: int
                    ) -> tuple[TrackObservations, CameraChain] | None:
    """Camera ``cam``'s tracks seen by the frame and at least ``least_rows`` keyframes, with
    the chain holding every local frame's base pose (keyframes ``0..m-1``, the frame ``m``)."""
    ids, xy, whiten = rows[cam]
    frames, tids, pts, wts = [np.full(len(ids), len(keyframes))], [ids], [xy], [whiten]
    for k, key in enumerate(keyframes):
        found = key.rows.get(cam)
        if found is None:
            continue
        keep = np.isin(found[0], ids)
        frames.append(np.full(int(keep.sum()), k))
        tids.append(found[0][keep])
        pts.append(found[1][keep])
        wts.append(found[2][keep])
    obs = TrackObservations.build(cam, np.concatenate(frames), np.concatenate(tids),
                                  np.concatenate(pts), np.concatenate(wts))
    seen = np.diff(obs.starts) - 1  # the frame's row is one of each track's
    obs = obs.select(np.flatnonzero(seen >= least_rows))
    if len(obs) == 0:
        return None
    return obs, _with_bases(chain, keyframes, base, frame=True)


def _cauchy(norms: FloatArray, inlier_sigmas: float) -> FloatArray:
    """Cauchy weights of scale three times the threshold (0 behind a camera)."""
    finite = np.isfinite(norms)
    return np.where(finite, 1.0 / (1.0 + (np.where(finite, norms, 0.0)
                                          / (3.0 * inlier_sigmas)) ** 2), 0.0)


def fit_between_keyframes(x0: FloatArray, rows: Rows, base: FloatArray | None,
                          keyframes: Sequence[Keyframe], chains: Mapping[int, CameraChain],
                          bending: Bending, inlier_sigmas: float, least_rows: int = 2,
                          iterations: int = 6, tolerance: float = 1e-8) -> FrameFit:
    """The frame's vector that best explains its rows and its keyframes' rows with the
    keyframes held at their values (module docstring).

    Args:
        x0: ``(P,)`` the starting vector (the frame's own estimate).
        rows: the frame's observations.
        base: the frame's base pose (``None``: identity).
        keyframes: the keyframes around the frame (any order).
        chains: camera -> its chain (no base poses: they come from ``base`` and the
            keyframes').
        bending: the parameterisation (its limits bound the vector).
        inlier_sigmas: the outlier threshold (whitened residual norm).
        least_rows: a track enters when at least this many keyframes saw it.
        iterations: most Gauss-Newton steps.
        tolerance: stop once no component moves more than this (radians).

    Returns:
        The fit; where no track enters, ``x0`` with an infinite covariance.
    """
    x = np.asarray(x0, dtype=float).copy()
    P, m = len(x), len(keyframes)
    problems = []
    for cam in sorted(rows):
        found = None if cam not in chains else _camera_problem(cam, chains[cam], rows, base,
                                                                keyframes, least_rows)
        if found is not None:
            problems.append(found)
    fixed = np.array([k.x for k in keyframes], dtype=float).reshape(m, P)

    def stacked(v: FloatArray) -> FloatArray:
        return np.vstack([fixed, v[None]])

    weights, points, mine = [], [], []
    for obs, chain in problems:  # each point robustly from the keyframes' rows alone
        own = obs.frames == m
        norms, pts = robust_residual_norms(obs, chain, stacked(x), 0, (~own).astype(float))
        weights.append(gnc_tls_weights(norms, inlier_sigmas, math.inf))
        weights[-1][own] = _cauchy(norms[own], inlier_sigmas)
        points.append(pts)
        mine.append(own)
    H = np.zeros((P, P))
    cost = 0.0
    for it in range(iterations + 1):
        H, g, cost = np.zeros((P, P)), np.zeros(P), 0.0
        for i, (obs, chain) in enumerate(problems):
            out = reduced_system(obs, chain, stacked(x), 0, weights[i], points[i])
            d = chain.n_parameters
            H[:d, :d] += out.H[m * d:(m + 1) * d, m * d:(m + 1) * d]
            g[:d] += out.g[m * d:(m + 1) * d]
            cost += out.cost
            points[i] = out.points
            # the frame's rows: Cauchy weights while the vector moves, then the decision
            own = out.residuals[mine[i]]
            weights[i][mine[i]] = (_cauchy(own, inlier_sigmas) if it < iterations // 2 else
                                   gnc_tls_weights(own, inlier_sigmas, math.inf))
        free = np.diag(H) > 0.0
        if it == iterations or not free.any():
            break
        step = np.zeros(P)
        step[free] = -np.linalg.solve(H[np.ix_(free, free)], g[free])
        x = bending.clip(x + step)
        if np.max(np.abs(step)) < tolerance and it >= iterations // 2:
            break
    used = sum(int(w[own].sum()) for w, own in zip(weights, mine, strict=True))
    free = np.diag(H) > 0.0
    covariance = np.zeros((P, P))
    if free.any():
        covariance[np.ix_(free, free)] = np.linalg.inv(H[np.ix_(free, free)])
    covariance[np.flatnonzero(~free), np.flatnonzero(~free)] = math.inf
    return FrameFit(x, covariance, used, float(cost))


@dataclass(frozen=True)
class KeyframePoints:
    """Per camera, the points of the tracks some keyframes saw, found from those keyframes'
    rows alone at their values (:func:`keyframe_points`).

    Attributes:
        ids: camera -> ``(T,)`` track ids, increasing.
        points: camera -> ``(T, 3)`` their points (world, metres).
    """

    ids: dict[int, NDArray[np.int64]]
    points: dict[int, FloatArray]

    def rows(self, rows: Rows) -> list[FrameRows]:
        """A frame's rows of these tracks, with their points (for
        :func:`~apcc_graph.estimation.initial_guess.refine`)."""
        out = []
        for cam, (ids, xy, whiten) in rows.items():
            known = self.ids.get(cam)
            if known is None or not len(known):
                continue
            at = np.clip(np.searchsorted(known, ids), 0, len(known) - 1)
            hit = known[at] == ids
            if hit.any():
                out.append(FrameRows(cam, self.points[cam][at[hit]], xy[hit], whiten[hit]))
        return out


def keyframe_points(keyframes: Sequence[Keyframe], chains: Mapping[int, CameraChain],
                    least_rows: int = 2) -> KeyframePoints:
    """Each camera's tracks the ``keyframes`` saw at least ``least_rows`` times, and their
    points, found robustly from those rows at the keyframes' values (the frames between them
    are then fitted to these points: the batch of :func:`fit_between_keyframes` with each
    point fixed by the keyframes alone, which the frame's one row moves little)."""
    ids: dict[int, NDArray[np.int64]] = {}
    points: dict[int, FloatArray] = {}
    if not keyframes:
        return KeyframePoints(ids, points)
    x = np.array([k.x for k in keyframes], dtype=float)
    for cam, chain in chains.items():
        parts = [(k, key.rows[cam]) for k, key in enumerate(keyframes) if cam in key.rows]
        if not parts:
            continue
        obs = TrackObservations.build(
            cam, np.concatenate([np.full(len(r[0]), k) for k, r in parts]),
            np.concatenate([r[0] for _, r in parts]), np.concatenate([r[1] for _, r in parts]),
            np.concatenate([r[2] for _, r in parts]))
        obs = obs.select(np.flatnonzero(np.diff(obs.starts) >= least_rows))
        if len(obs) == 0:
            continue
        _, pts = robust_residual_norms(obs, _with_bases(chain, keyframes, None), x, 0,
                                       np.ones(len(obs)))
        ids[cam], points[cam] = obs.ids, pts
    return KeyframePoints(ids, points)


def _with_bases(chain: CameraChain, keyframes: Sequence[Keyframe],
                base: FloatArray | None, frame: bool = False) -> CameraChain:
    """``chain`` with the keyframes' base poses (and, with ``frame``, ``base`` after them)."""
    bases = [key.base for key in keyframes] + ([base] if frame else [])
    if all(b is None for b in bases):
        return chain
    stack = np.stack([np.eye(4) if b is None else np.asarray(b, dtype=float) for b in bases])
    return CameraChain(chain.bending, chain.tip_T_cam, stack, 0)
