"""Landmarks: tracks that outlive a smoother's window keep their point as a variable.

The projection factor (:mod:`apcc_graph.factors.projection`) eliminates each track's point inside
the factor. A fixed-lag smoother that does so must cut a track whose first frame leaves the
window:
the rest of the track gets a new point, and whatever the old observations said about the point
is lost to the new frames. The cut raises the Cramer-Rao bound of the fixed lag
(``docs/estimation.md``, "The bound of a fixed-lag smoother"), and the estimate drifts. A track
that outlives the window is therefore promoted to a *landmark*: its point becomes a ``Point3``
variable (:func:`~apcc_graph.factors.keys.point_key`) that the smoother keeps while the track
is seen and
marginalises like a frame afterwards, so what its old observations said carries over to the
frames still in the window.

The landmarks' observations are gtsam's C++ ``GenericProjectionFactorCal3_S2`` between the
point and a ``Pose3`` variable per frame and camera, ``world_T_cam``
(:func:`~apcc_graph.factors.keys.camera_pose_key`),
one factor per observation: each row then depends on its own point only, the structure sparse
elimination needs (a Python factor over many points would make the smoother's cliques dense),
and C++ factors cost no Python time. The pixel is the undistorted one (``fx x + cx``,
``fy y + cy``) with an isotropic noise: exact for a pinhole camera, an approximation of the
whitening under lens distortion.

A camera-pose variable is tied to its frame's angles by :func:`camera_pose_factor`::

    E = world_T_cam^-1 . T_cam(theta),   r = Logmap(E)   (gtsam order: rotation, translation)

where ``T_cam(theta)`` is the camera's pose along the APCC chain
(:mod:`apcc_graph.factors.camera_chain`), with a stiff noise (a constraint, in practice).
Jacobians, under the right-hand perturbations ``X . Exp(d)`` and ``theta + d``, with ``J_r^-1`` the
inverse right Jacobian of SE(3) (``gtsam.Pose3.LogmapDerivative``) and ``xi_j = vee(T_cam^-1
dT_cam/dtheta_j)`` the body twist of angle j::

    H_theta_j = J_r^-1(r) xi_j,     H_X = -J_r^-1(r) Ad(E^-1)
"""

from __future__ import annotations

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.factors.camera_chain import CameraChain
from apcc_graph.factors.keys import camera_pose_key, frame_key, point_key
from apcc_graph.factors.kinematic import vee
from apcc_graph.model.arrays import FloatArray


def camera_pose_residual(X: gtsam.Pose3, thetas: FloatArray, chain: CameraChain, frame: int,
                         jacobians: bool = True
                         ) -> tuple[FloatArray, FloatArray | None, FloatArray | None]:
    """``r = Logmap(X^-1 T_cam(theta))`` and its Jacobians in the camera's components of the
    frame vector ``(6, n)`` (``n = chain.n_parameters``) and in ``X`` ``(6, 6)`` (see the module
    docstring).

    Args:
        X: the camera-pose variable's value.
        thetas: the frame's vector (radians).
        chain: the camera's chain (its base poses cover ``frame``).
        frame: the frame.
    """
    n = chain.n_parameters
    poses, d_poses = chain.poses(np.asarray(thetas, dtype=float)[None, :], frame, jacobians)
    T = poses[0]
    E = X.between(gtsam.Pose3(T))
    r = gtsam.Pose3.Logmap(E)
    if not jacobians:
        return r, None, None
    assert d_poses is not None
    Jinv = gtsam.Pose3.LogmapDerivative(r)
    T_inv = np.linalg.inv(T)
    xi = np.column_stack([vee(T_inv @ d_poses[0, j]) for j in range(n)])
    return r, Jinv @ xi, -Jinv @ E.inverse().AdjointMap()


def camera_pose_factor(frame: int, camera: int, chain: CameraChain, n_segments: int,
                       sigma: float) -> gtsam.CustomFactor:
    """Tie camera ``camera``'s pose variable at ``frame`` to that frame's angles.

    Args:
        frame, camera: which pose (:func:`~apcc_graph.factors.keys.camera_pose_key`) and angles
            (:func:`~apcc_graph.factors.keys.frame_key`).
        chain: the camera's chain (its base poses cover ``frame``).
        n_segments: the dimension of the frame's vector (the robot's
            :attr:`~apcc_graph.model.parameterisation.Bending.dim`).
        sigma: the tie's standard deviation (radians and metres alike): small, a constraint.
    """
    theta_key, pose_key = frame_key(frame), camera_pose_key(frame, camera)
    n = chain.n_parameters

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values,
                   H: list[np.ndarray] | None) -> np.ndarray:
        r, h_theta, h_pose = camera_pose_residual(values.atPose3(pose_key),
                                                  values.atVector(theta_key), chain, frame,
                                                  H is not None)
        if H is not None:
            assert h_theta is not None and h_pose is not None
            block = np.zeros((6, n_segments), order="F")
            block[:, :n] = h_theta
            H[0], H[1] = block, np.asfortranarray(h_pose)
        return r

    return gtsam.CustomFactor(gtsam.noiseModel.Isotropic.Sigma(6, sigma),
                              [theta_key, pose_key], error_func)


def observation_factors(frames: NDArray[np.int64], camera: int,
                        landmarks: NDArray[np.int64], xy: FloatArray,
                        calibration: gtsam.Cal3_S2, sigma_px: float
                        ) -> list[gtsam.NonlinearFactor]:
    """gtsam's C++ projection factors of landmark observations.

    Args:
        frames: ``(N,)`` each observation's frame.
        camera: the camera.
        landmarks: ``(N,)`` each observation's point number
            (:func:`~apcc_graph.factors.keys.point_key`).
        xy: ``(N, 2)`` undistorted normalised image coordinates.
        calibration: the camera's pinhole intrinsics (``fx, fy, 0, cx, cy``).
        sigma_px: the pixel noise (pixels).
    """
    noise = gtsam.noiseModel.Isotropic.Sigma(2, sigma_px)
    fx, fy = calibration.fx(), calibration.fy()
    cx, cy = calibration.px(), calibration.py()
    out = []
    for f, lm, (x, y) in zip(frames.tolist(), landmarks.tolist(), xy.tolist(), strict=True):
        out.append(gtsam.GenericProjectionFactorCal3_S2(
            gtsam.Point2(fx * x + cx, fy * y + cy), noise, camera_pose_key(f, camera),
            point_key(camera, lm), calibration))
    return out
