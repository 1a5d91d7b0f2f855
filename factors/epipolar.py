"""The generalized epipolar constraint of one tip camera between two frames, as a GTSAM factor
over the two frames' vectors (``docs/estimation.md``, "Two frames").

Camera ``c`` rides on segment ``c``; its poses at frames a and b come from the APCC chain
(:class:`~apcc_graph.factors.camera_chain.CameraChain`: ``A = world_T_cam(a)``,
``B = world_T_cam(b)``)::

    M = camA_T_camB = A^-1 B,   (R, t) = M,   E = [t]x R

Each correspondence (unit bearings ``f_a``, ``f_b`` in the two cameras) gives the Sampson error
``e_k`` of ``f_a^T E f_b = 0`` (radians on the bearings' tangent planes;
:func:`~apcc_graph.frontend.geometry.sampson_terms`), 0 where the camera did not move. The only
unknowns are the frame vectors: no pose and no point variable, which is what makes the
constraint cheap for a per-frame step or a user's own small graph. It carries less than a
projection factor over the same rows (a track seen in many frames is one point, not a chain of
pairs), so the library's estimators use the projection factor; this one is the paper's
constraint, exact for any ``k`` and ``delta_max``.

Jacobians (a ``Vector`` variable's tangent is plain addition): with ``dA_p``, ``dB_p`` the
matrix derivatives of the camera poses in component p of the frame vector
(:func:`~apcc_graph.factors.camera_chain.camera_poses`),

    dM/dx_bp = A^-1 dB_p,   dM/dx_ap = -A^-1 dA_p M,   dE = [dt]x R + [t]x dR

and ``de_k/dx = <G_k, dE>`` with ``G_k = de_k/dE``
(:func:`~apcc_graph.frontend.geometry.sampson_gradient`). Columns of segments above the camera's
are zero. Where the camera did not move (``x_a = x_b`` with a still base: the constraint's
trivial root) every error and Jacobian is 0: a solve must start away from it.
"""

from __future__ import annotations

import gtsam
import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.factors.camera_chain import CameraChain
from apcc_graph.factors.keys import frame_key
from apcc_graph.frontend.geometry import checked_bearings, essential_matrix, sampson_gradient, skew
from apcc_graph.model.arrays import FloatArray

NO_MOTION = 1e-12
"""Below this Sampson denominator (unit bearings; it scales with the camera's translation in
metres) a correspondence shows no motion: its error and Jacobians are 0. At round-off
baselines the ratio would otherwise be 0/0 noise with Jacobians near 1e16."""


def epipolar_residual(x_a: ArrayLike, x_b: ArrayLike, chain: CameraChain, a: int, b: int,
                      f_a: ArrayLike, f_b: ArrayLike, dim: int | None = None,
                      jacobians: bool = True
                      ) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
    """The Sampson errors ``(N,)`` of a camera's correspondences between frames a and b
    (radians), and their Jacobians ``(N, dim)`` in ``x_a`` and ``x_b`` (module docstring).

    Args:
        x_a, x_b: the two frames' vectors (radians; at least the camera's columns).
        chain: the camera's chain (its base poses cover frames ``a`` and ``b``).
        a, b: the frames.
        f_a, f_b: ``(N, 3)`` unit bearings of the correspondences in the camera at a and b.
        dim: the length of the frame vector (default: ``len(x_a)``).
        jacobians: also return the Jacobians (else ``None``, ``None``).
    """
    f_a, f_b = checked_bearings(f_a, f_b)
    x_a = np.atleast_1d(np.asarray(x_a, dtype=float))
    x_b = np.atleast_1d(np.asarray(x_b, dtype=float))
    dim = len(x_a) if dim is None else int(dim)
    A, dA = chain.poses(x_a[None], a, jacobians)
    B, dB = chain.poses(x_b[None], b, jacobians)
    A_inv = np.linalg.inv(A[0])
    M = A_inv @ B[0]
    E = essential_matrix(M)
    n = len(f_a)
    e, G = sampson_gradient(f_a, f_b, np.broadcast_to(E, (n, 3, 3)), NO_MOTION)
    if not jacobians:
        return e, None, None
    assert dA is not None and dB is not None
    p = chain.n_parameters
    dM_a = -A_inv @ dA[0] @ M  # (p, 4, 4)
    dM_b = A_inv @ dB[0]
    out = []
    for dM in (dM_a, dM_b):
        dE = skew(dM[:, :3, 3]) @ M[:3, :3] + skew(M[:3, 3]) @ dM[:, :3, :3]  # (p, 3, 3)
        H = np.zeros((n, dim))
        H[:, :p] = G @ dE.reshape(p, 9).T
        out.append(H)
    return e, out[0], out[1]


def epipolar_factor(a: int, b: int, chain: CameraChain, f_a: ArrayLike, f_b: ArrayLike,
                    sigma: float, dim: int,
                    noise: gtsam.noiseModel.Base | None = None) -> gtsam.CustomFactor:
    """The generalized epipolar factor of one camera between frames ``a`` and ``b``, over
    their frame vectors (:func:`~apcc_graph.factors.keys.frame_key`).

    Args:
        a, b: the frames (different).
        chain: the camera's chain (its base poses cover both frames).
        f_a, f_b: ``(N, 3)`` unit bearings of the correspondences (undistorted, normalised
            to unit length).
        sigma: one correspondence's Sampson noise (radians: pixel noise / focal length).
        dim: the length of the robot's frame vector
            (:attr:`~apcc_graph.model.parameterisation.Bending.dim`).
        noise: another noise model of the ``N`` rows (e.g. gtsam's robust models, which weigh
            a factor as a whole: for a weight per correspondence make one factor per
            correspondence); default isotropic ``sigma``.

    Raises:
        ValueError: the frames are the same, the bearings' shapes differ, there is no
            correspondence, or ``sigma`` is not positive.
    """
    if a == b:
        raise ValueError(f"frames a = b = {a}: an epipolar factor needs two frames")
    f_a, f_b = checked_bearings(f_a, f_b)
    if len(f_a) == 0:
        raise ValueError("no correspondence: expected (N, 3) bearings with N >= 1")
    if not sigma > 0.0:
        raise ValueError(f"sigma = {sigma}: expected a positive noise (radians)")
    f_a = f_a / np.linalg.norm(f_a, axis=1, keepdims=True)
    f_b = f_b / np.linalg.norm(f_b, axis=1, keepdims=True)
    key_a, key_b = frame_key(a), frame_key(b)

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values,
                   H: list[np.ndarray] | None) -> np.ndarray:
        e, H_a, H_b = epipolar_residual(values.atVector(key_a), values.atVector(key_b), chain,
                                        a, b, f_a, f_b, dim, H is not None)
        if H is not None:
            assert H_a is not None and H_b is not None
            H[0], H[1] = np.asfortranarray(H_a), np.asfortranarray(H_b)
        return e

    model = gtsam.noiseModel.Isotropic.Sigma(len(f_a), sigma) if noise is None else noise
    return gtsam.CustomFactor(model, [key_a, key_b], error_func)
