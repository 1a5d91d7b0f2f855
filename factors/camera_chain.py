"""Tip-camera poses along the APCC chain and their derivatives, vectorised over frames.

Camera ``c`` rides on segment ``c`` (0-based). At frame ``f``, with the base pose known::

    world_T_cam(f) = world_T_base(f) . T_0(x_f) ... T_c(x_f) . tip_T_cam

where ``T_j`` is the APCC 2L-5R transform ``base_T_tip`` of segment j at its components of
the frame vector ``x_f`` (:class:`~apcc_graph.model.parameterisation.Bending`: an angle in a
fixed plane, or a bending vector). The derivatives are matrix derivatives,
``d world_T_cam / d x_fp = P_j . dT_j/dx_fp . S_j+1`` for a component p of segment j, with the
prefix ``P_j = world_T_base T_0 ... T_j-1`` and the suffix ``S_j+1 = T_j+1 ... T_c tip_T_cam``;
their bottom rows are zero. Units: metres and radians.

:class:`CameraChain` holds what fixes one camera's poses given the frame vectors (the
parameterisation of its segments, its mounting, the base poses) for the projection factor.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.factors import chain_jit
from apcc_graph.factors.engine import resolve
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.segment import Segment


def camera_poses(
    x: ArrayLike,
    bending: Bending,
    tip_T_cam: ArrayLike,
    world_T_base: ArrayLike | None = None,
    derivatives: bool = True,
    calibration: bool = False,
    engine: str | None = None,
) -> tuple[FloatArray, FloatArray | None] | tuple[FloatArray, FloatArray, FloatArray]:
    """``world_T_cam`` of a camera on the last of ``bending``'s segments, for every frame.

    Args:
        x: ``(F, P)`` frame vectors of segments ``0..n-1`` (:class:`Bending`: ``P = n`` angles
            in fixed planes or ``2 n`` bending-vector components), radians.
        bending: the parameterisation of the segments from the base to the camera's segment.
        tip_T_cam: ``(4, 4)`` the camera's mounting on its segment's tip.
        world_T_base: ``(F, 4, 4)`` or ``(4, 4)`` robot base poses; ``None`` for identity.
        derivatives: also return the derivatives.
        calibration: also return the derivatives in each segment's ``k`` and ``delta_max``
            (implies ``derivatives``).
        engine: ``"numba"`` runs segments in fixed planes without ``calibration`` through the
            compiled kernel (:mod:`apcc_graph.factors.chain_jit`; the same poses to rounding),
            anything else through the numpy code below (``"numpy"``, the reference); ``None``:
            the default (:mod:`apcc_graph.factors.engine`).

    Returns:
        ``poses`` ``(F, 4, 4)`` and, with ``derivatives``, ``d poses`` ``(F, P, 4, 4)``:
        ``d world_T_cam(f) / d x_fp``; otherwise ``None``. With ``calibration`` a third array
        ``(F, n, 2, 4, 4)``: ``d world_T_cam(f) / d (k_j, delta_max_j)``.
    """
    x = np.atleast_2d(np.asarray(x, dtype=float))
    n_frames, P = x.shape
    n = bending.n_segments
    if P != bending.dim:
        raise ValueError(f"x has {P} columns for {n} segments: expected {bending.dim} "
                         f"({bending.width} per segment)")
    M = np.asarray(tip_T_cam, dtype=float)
    if resolve(engine) == "numba" and not (calibration or bending.is_free):
        base = (np.eye(4)[None] if world_T_base is None
                else np.asarray(world_T_base, dtype=float).reshape(-1, 4, 4))
        if len(base) not in (1, n_frames):
            raise ValueError(f"world_T_base has {len(base)} poses for {n_frames} frames")
        poses, d_poses = chain_jit.fixed_plane_poses(
            x, chain_jit.segment_table(bending.segments), bending.planes,
            np.ascontiguousarray(M), np.ascontiguousarray(base), derivatives)
        return poses, d_poses if derivatives else None
    T = [bending.transform(x, j) for j in range(n)]
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
    d_poses = np.empty((n_frames, P, 4, 4))
    for j in range(n):
        for i, dT in enumerate(bending.derivatives(x, j)):
            d_poses[:, bending.width * j + i] = prefix[j] @ dT @ suffix[j]
    if not calibration:
        return poses, d_poses
    d_cal = np.empty((n_frames, n, 2, 4, 4))
    for j in range(n):
        for i, dT in enumerate(bending.calibration_derivatives(x, j)):
            d_cal[:, j, i] = prefix[j] @ dT @ suffix[j]
    return poses, d_poses, d_cal


def mount_derivatives(poses: FloatArray) -> FloatArray:
    """``(F, 6, 4, 4)`` derivatives of ``world_T_cam`` in the camera mounting ``tip_T_cam``,
    perturbed on the right as gtsam's ``Pose3`` is: ``tip_T_cam . Exp(xi)`` with ``xi = (omega,
    v)``, rotation first, both in the camera frame. Since ``world_T_cam = P . tip_T_cam``, the
    derivative in ``xi_i`` at ``xi = 0`` is ``world_T_cam . G_i`` with ``G_i`` the i-th
    generator of se(3)."""
    return np.einsum("fij,cjk->fcik", np.asarray(poses, dtype=float), _SE3_GENERATORS)


def _generators() -> FloatArray:
    G = np.zeros((6, 4, 4))
    for i in range(3):
        axis = np.zeros(3)
        axis[i] = 1.0
        G[i, :3, :3] = np.cross(np.eye(3), axis)  # hat(e_i): hat(w) @ v = w x v
        G[3 + i, i, 3] = 1.0
    return G


_SE3_GENERATORS = _generators()


@dataclass(frozen=True)
class CameraChain:
    """What fixes one camera's pose given the frame vectors: the parameterisation of its
    segments (:class:`~apcc_graph.model.parameterisation.Bending`), its mounting, the base
    poses."""

    bending: Bending  # segments 0..c
    tip_T_cam: FloatArray
    world_T_base: FloatArray | None  # (F, 4, 4) base poses of frames frame0.., or None
    frame0: int = 0  # the frame of world_T_base[0]

    @property
    def segments(self) -> tuple[Segment, ...]:
        """The segments from the base to the camera's."""
        return self.bending.segments

    @property
    def n_parameters(self) -> int:
        """Columns of the frame vector this camera depends on."""
        return self.bending.dim

    def poses(self, x: FloatArray, first: int, derivatives: bool,
              calibration: bool = False, engine: str | None = None) -> tuple:
        """Poses (and derivatives) of frames ``first .. first + len(x) - 1`` from their
        vectors ``x`` ``(F', P)`` (columns beyond the camera's segments ignored); see
        :func:`camera_poses`."""
        rows = slice(first - self.frame0, first - self.frame0 + len(x))
        base = None if self.world_T_base is None else self.world_T_base[rows]
        return camera_poses(x[:, :self.bending.dim], self.bending, self.tip_T_cam, base,
                            derivatives, calibration, engine)

    def with_mount(self, tip_T_cam: ArrayLike) -> CameraChain:
        """The same chain with another camera mounting (mount calibration)."""
        return CameraChain(self.bending, np.asarray(tip_T_cam, dtype=float),
                           self.world_T_base, self.frame0)

    def with_segments(self, segments: Sequence[Segment]) -> CameraChain:
        """The same chain with other segment models (self-calibration)."""
        return CameraChain(self.bending.with_segments(segments), self.tip_T_cam,
                           self.world_T_base, self.frame0)
