"""Tip-camera poses along the APCC chain and their derivatives, vectorised over frames.

Camera ``c`` rides on segment ``c`` (0-based). At frame ``f``, with the base pose known::

    world_T_cam(f) = world_T_base(f) . T_0(theta_f0) ... T_c(theta_fc) . tip_T_cam

where ``T_j`` is the APCC 2L-5R transform ``base_T_tip`` of segment j
(:func:`apcc_graph.model.kinematics.apcc_transform`). The derivatives are matrix derivatives,
``d world_T_cam / d theta_fj = P_j . dT_j . S_j+1`` with the prefix ``P_j = world_T_base T_0 ...
T_j-1`` and the suffix ``S_j+1 = T_j+1 ... T_c tip_T_cam``; their bottom rows are zero. Units:
metres and radians.

:class:`CameraChain` holds what fixes one camera's poses given the angles (its segments,
mounting, base poses and bending planes) for the projection factor.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.bending import bending_transform, bending_transform_derivative
from apcc_graph.model.kinematics import (
    apcc_transform,
    apcc_transform_calibration_derivative,
    apcc_transform_derivative,
)
from apcc_graph.model.segment import Segment


def camera_poses(
    thetas: ArrayLike,
    segments: Sequence[Segment],
    tip_T_cam: ArrayLike,
    world_T_base: ArrayLike | None = None,
    psis: ArrayLike | None = None,
    derivatives: bool = True,
    calibration: bool = False,
) -> tuple[FloatArray, FloatArray | None] | tuple[FloatArray, FloatArray, FloatArray]:
    """``world_T_cam`` of a camera on the last of ``segments``, for every frame.

    Args:
        thetas: ``(F, n)`` angles of segments ``0..n-1`` (radians), ``n = len(segments)``.
        segments: the segments from the base to the camera's segment.
        tip_T_cam: ``(4, 4)`` the camera's mounting on its segment's tip.
        world_T_base: ``(F, 4, 4)`` or ``(4, 4)`` robot base poses; ``None`` for identity.
        psis: ``(F, n)`` bending-plane angles (radians); ``None`` for a planar robot.
        derivatives: also return the derivatives.
        calibration: also return the derivatives in each segment's ``k`` and ``delta_max``
            (implies ``derivatives``).

    Returns:
        ``poses`` ``(F, 4, 4)`` and, with ``derivatives``, ``d poses`` ``(F, n, 4, 4)``:
        ``d world_T_cam(f) / d theta_fj``; otherwise ``None``. With ``calibration`` a third
        array ``(F, n, 2, 4, 4)``: ``d world_T_cam(f) / d (k_j, delta_max_j)``.
    """
    thetas = np.atleast_2d(np.asarray(thetas, dtype=float))
    n_frames, n = thetas.shape
    if n != len(segments):
        raise ValueError(f"thetas has {n} columns for {len(segments)} segments")
    psis = np.zeros_like(thetas) if psis is None else np.broadcast_to(
        np.asarray(psis, dtype=float), thetas.shape)
    M = np.asarray(tip_T_cam, dtype=float)
    T = [apcc_transform(thetas[:, j], s, psis[:, j]) for j, s in enumerate(segments)]
    prefix = [np.broadcast_to(np.eye(4) if world_T_base is None
                              else np.asarray(world_T_base, dtype=float), (n_frames, 4, 4))]
    for j in range(n):
        prefix.append(prefix[-1] @ T[j])
    poses = prefix[n] @ M
    if not (derivatives or calibration):
        return poses, None
    suffix = [np.broadcast_to(M, (n_frames, 4, 4))]
    for j in range(n - 1, 0, -1):
        suffix.append(T[j] @ suffix[-1])
    suffix.reverse()  # suffix[j] = T_j+1 ... T_n-1 M
    d_poses = np.empty((n_frames, n, 4, 4))
    for j, s in enumerate(segments):
        dT = apcc_transform_derivative(thetas[:, j], s, psis[:, j])[0]
        d_poses[:, j] = prefix[j] @ dT @ suffix[j]
    if not calibration:
        return poses, d_poses
    d_cal = np.empty((n_frames, n, 2, 4, 4))
    for j, s in enumerate(segments):
        for i, dT in enumerate(apcc_transform_calibration_derivative(thetas[:, j], s,
                                                                      psis[:, j])):
            d_cal[:, j, i] = prefix[j] @ dT @ suffix[j]
    return poses, d_poses, d_cal


def spatial_camera_poses(
    bends: ArrayLike,
    segments: Sequence[Segment],
    tip_T_cam: ArrayLike,
    world_T_base: ArrayLike | None = None,
    derivatives: bool = True,
) -> tuple[FloatArray, FloatArray | None]:
    """:func:`camera_poses` of a spatial robot, in bending vectors.

    Args:
        bends: ``(F, 2 n)`` bending vectors ``(u_0, v_0, u_1, v_1, ...)`` of segments
            ``0..n-1`` (radians; :mod:`apcc_graph.model.bending`).
        segments, tip_T_cam, world_T_base, derivatives: as :func:`camera_poses`.

    Returns:
        ``poses`` ``(F, 4, 4)`` and, with ``derivatives``, ``(F, 2 n, 4, 4)``: the derivative
        in ``u_j`` at column ``2 j`` and in ``v_j`` at ``2 j + 1``; otherwise ``None``.
    """
    bends = np.atleast_2d(np.asarray(bends, dtype=float))
    n_frames, n = bends.shape[0], len(segments)
    if bends.shape[1] != 2 * n:
        raise ValueError(f"bends has {bends.shape[1]} columns for {n} segments: expected "
                         f"{2 * n} (u, v per segment)")
    M = np.asarray(tip_T_cam, dtype=float)
    T = [bending_transform(bends[:, 2 * j], bends[:, 2 * j + 1], s)
         for j, s in enumerate(segments)]
    prefix = [np.broadcast_to(np.eye(4) if world_T_base is None
                              else np.asarray(world_T_base, dtype=float), (n_frames, 4, 4))]
    for j in range(n):
        prefix.append(prefix[-1] @ T[j])
    poses = prefix[n] @ M
    if not derivatives:
        return poses, None
    suffix = [np.broadcast_to(M, (n_frames, 4, 4))]
    for j in range(n - 1, 0, -1):
        suffix.append(T[j] @ suffix[-1])
    suffix.reverse()
    d_poses = np.empty((n_frames, 2 * n, 4, 4))
    for j, s in enumerate(segments):
        for i, dT in enumerate(bending_transform_derivative(bends[:, 2 * j], bends[:, 2 * j + 1],
                                                            s)):
            d_poses[:, 2 * j + i] = prefix[j] @ dT @ suffix[j]
    return poses, d_poses


@dataclass(frozen=True)
class CameraChain:
    """What fixes one camera's pose given the angles: its segments, mounting, base poses.

    A planar chain's frame vector is the angles ``theta`` (one per segment, bending planes
    fixed by ``psis``); a ``spatial`` chain's is the bending vectors ``(u_0, v_0, u_1, ...)``,
    two per segment, and ``psis`` is unused.
    """

    segments: tuple[Segment, ...]  # segments 0..c
    tip_T_cam: FloatArray
    world_T_base: FloatArray | None  # (F, 4, 4) base poses of frames frame0.., or None
    psis: FloatArray | None  # (F, S) bending-plane angles of frames frame0.., or None
    frame0: int = 0  # the frame of world_T_base[0] and psis[0]
    spatial: bool = False

    @property
    def n_parameters(self) -> int:
        """Columns of the frame vector this camera depends on: ``n`` or ``2 n``."""
        return (2 if self.spatial else 1) * len(self.segments)

    def poses(self, thetas: FloatArray, first: int, derivatives: bool,
              calibration: bool = False) -> tuple:
        """Poses (and derivatives) of frames ``first .. first + len(thetas) - 1``; see
        :func:`camera_poses` (:func:`spatial_camera_poses` for a spatial chain)."""
        n = len(self.segments)
        rows = slice(first - self.frame0, first - self.frame0 + len(thetas))
        base = None if self.world_T_base is None else self.world_T_base[rows]
        if self.spatial:
            if calibration:
                raise ValueError("self-calibration of a spatial robot is not supported")
            return spatial_camera_poses(thetas[:, :2 * n], self.segments, self.tip_T_cam,
                                        base, derivatives)
        psis = None if self.psis is None else self.psis[rows, :n]
        return camera_poses(thetas[:, :n], self.segments, self.tip_T_cam, base, psis,
                            derivatives, calibration)

    def with_segments(self, segments: Sequence[Segment]) -> CameraChain:
        """The same chain with other segment models (self-calibration)."""
        return CameraChain(tuple(segments), self.tip_T_cam, self.world_T_base, self.psis,
                           self.frame0, self.spatial)
