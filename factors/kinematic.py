"""APCC kinematic factor, in pose space: a segment's base pose, bending angle and tip pose.

Variables: ``world_T_base`` and ``world_T_tip`` (``gtsam.Pose3``; rotation in radians, translation
in metres, both poses map points in their frame to the world frame) and the bending angle
``theta`` (a Vector1 value, radians). The segment's APCC 2L-5R transform
``base_T_tip(theta; psi)`` is :func:`apcc_graph.model.kinematics.apcc_transform`
(docs/estimation.md, "The robot"; paper III.B eq. 2-5), with a fixed bending-plane angle ``psi``
(radians).

Residual, in the tangent space of Pose3 at the measured tip (GTSAM order ``(omega, v)``: radians,
then metres)::

    E = world_T_tip^-1 . world_T_base . base_T_tip(theta; psi)
    r = Logmap(E)

``r = 0`` exactly when ``world_T_tip = world_T_base . base_T_tip(theta)``; it is whitened by the
factor's noise model (six sigmas: three rotation sigmas in radians, then three translation sigmas
in metres, in the tip frame).

Jacobian convention: GTSAM's right-hand perturbation, ``T . Exp(d)`` for the poses (the tangent
``d`` in the pose's own frame) and ``theta + d`` for the angle. With ``A = base_T_tip(theta)``,
``xi`` its body twist (``A(theta + e) = A(theta) Exp(e xi) + O(e^2)``,
:func:`apcc_graph.model.kinematics.apcc_body_twists`), ``Ad`` the adjoint map and ``J_r^-1`` the
inverse right Jacobian of SE(3) (``gtsam.Pose3.LogmapDerivative``,
``Log(E Exp(d)) = r + J_r^-1(r) d``)::

    H_base  =  J_r^-1(r) . Ad(A^-1)      since  T_tip^-1 T_base Exp(d) A = E Exp(Ad(A^-1) d)
    H_theta =  J_r^-1(r) . xi            since  E(theta + d) = E Exp(d xi)
    H_tip   = -J_r^-1(r) . Ad(E^-1)      since  Exp(-d) E = E Exp(-Ad(E^-1) d)

Pose space versus joint space. :mod:`apcc_graph.factors.projection` works in joint space: the
only variables of a frame are the bending angles (one per segment), and the camera poses are
products of segment transforms inside the residual, so the kinematics hold exactly. This factor
instead gives every segment's tip its own 6-dof pose variable, one angle plus one pose per
segment and frame (seven unknowns per segment instead of one), and ties them with a soft
constraint whose stiffness is the noise model. That costs variables and one more Python factor
per segment, but keeps every factor local (three keys, no chain products), lets other pose
measurements (an external tracker, a tip IMU, a camera on the tip) attach directly to the tip
pose, and lets small model errors (a segment that is not quite APCC) show up as kinematic
residuals instead of being forced into the angles. As the kinematic sigmas go to zero, the
pose-space optimum approaches the joint-space one.
"""

from __future__ import annotations

from collections.abc import Sequence

import gtsam
import numpy as np

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.scalar_kinematics import apcc_transform_scalar
from apcc_graph.model.segment import Segment

KinematicResidual = tuple[FloatArray, FloatArray | None, FloatArray | None, FloatArray | None]


def _transform_and_twist(theta: float, segment: Segment,
                         psi: float) -> tuple[FloatArray, FloatArray]:
    """``A = base_T_tip(theta)`` and its body twist ``xi = vee(A^-1 dA/dtheta)``, ``(omega, v)``.

    Same values as :func:`apcc_graph.model.kinematics.apcc_body_twists`, from the scalar fast path.
    """
    A, dA = apcc_transform_scalar(theta, segment, psi)
    Rt = A[:3, :3].T
    dR = Rt @ dA[:3, :3]  # skew-symmetric: [omega]x
    xi = np.array([dR[2, 1], dR[0, 2], dR[1, 0], *(Rt @ dA[:3, 3])])
    return A, xi


def kinematic_residual(
    world_T_base: gtsam.Pose3,
    theta: float,
    world_T_tip: gtsam.Pose3,
    segment: Segment,
    psi: float = 0.0,
    jacobians: bool = True,
) -> KinematicResidual:
    """Unwhitened residual ``Logmap(world_T_tip^-1 world_T_base base_T_tip(theta))`` and Jacobians.

    Args:
        world_T_base: the segment's base pose (rotation radians, translation metres).
        theta: the bending angle (radians).
        world_T_tip: the segment's tip pose.
        segment: the segment's APCC parameters.
        psi: bending-plane angle (radians).
        jacobians: also compute the Jacobians (otherwise they are ``None``).

    Returns:
        ``r`` ``(6,)`` in GTSAM order ``(omega, v)`` (radians, metres), ``H_base`` ``(6, 6)``,
        ``H_theta`` ``(6, 1)`` (per radian) and ``H_tip`` ``(6, 6)``, the derivatives under the
        right-hand perturbations ``T . Exp(d)`` and ``theta + d`` (see the module docstring).
    """
    A, xi = _transform_and_twist(float(theta), segment, float(psi))
    return _pose_tie(world_T_base, A, world_T_tip, xi[:, None] if jacobians else None)


def _pose_tie(world_T_base: gtsam.Pose3, A: FloatArray, world_T_tip: gtsam.Pose3,
              twists: FloatArray | None) -> KinematicResidual:
    """``r = Logmap(world_T_tip^-1 world_T_base A)`` and, given the body twists ``(6, m)`` of
    ``A`` in its ``m`` parameters, the Jacobians in the base, those parameters and the tip
    (module docstring); ``None`` Jacobians without ``twists``."""
    base_T_tip = gtsam.Pose3(A)
    E = world_T_tip.between(world_T_base.compose(base_T_tip))
    r = gtsam.Pose3.Logmap(E)
    if twists is None:
        return r, None, None, None
    Jinv = gtsam.Pose3.LogmapDerivative(r)
    return (r, Jinv @ base_T_tip.inverse().AdjointMap(), Jinv @ twists,
            -Jinv @ E.inverse().AdjointMap())


def kinematic_noise(sigmas: float | Sequence[float] | FloatArray) -> gtsam.noiseModel.Base:
    """A diagonal noise model from one sigma or six: ``(rot x, y, z [rad], trans x, y, z [m])``."""
    s = np.asarray(sigmas, dtype=float)
    if s.ndim == 0:
        s = np.full(6, float(s))
    if s.shape != (6,) or not np.all(np.isfinite(s)) or np.any(s <= 0.0):
        raise ValueError(f"kinematic noise sigmas {sigmas!r}: expected 1 or 6 finite values > 0")
    return gtsam.noiseModel.Diagonal.Sigmas(s)


def kinematic_factor(
    base_key: int,
    theta_key: int,
    tip_key: int,
    segment: Segment,
    noise: gtsam.noiseModel.Base | float | Sequence[float] | FloatArray,
    psi: float = 0.0,
) -> gtsam.CustomFactor:
    """A ``gtsam.CustomFactor`` tying a segment's base pose, angle and tip pose (APCC 2L-5R).

    Args:
        base_key: key of ``world_T_base`` (a ``Pose3`` value).
        theta_key: key of the bending angle (a Vector1 value, radians).
        tip_key: key of ``world_T_tip`` (a ``Pose3`` value).
        segment: the segment's APCC parameters.
        noise: a gtsam noise model of dimension 6, or sigmas for :func:`kinematic_noise` (one
            value, or six: rotation in radians then translation in metres, tip frame).
        psi: bending-plane angle (radians).

    Returns:
        The factor; its error is ``r`` of :func:`kinematic_residual` whitened by ``noise``.
    """
    model = noise if isinstance(noise, gtsam.noiseModel.Base) else kinematic_noise(noise)
    if model.dim() != 6:
        raise ValueError(f"kinematic noise model of dimension {model.dim()}: expected 6")
    psi = float(psi)

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values,
                   H: list[np.ndarray] | None) -> np.ndarray:
        r, h_base, h_theta, h_tip = kinematic_residual(
            values.atPose3(base_key), values.atVector(theta_key)[0], values.atPose3(tip_key),
            segment, psi, jacobians=H is not None)
        if H is not None:
            H[0], H[1], H[2] = h_base, h_theta, h_tip
        return r

    return gtsam.CustomFactor(model, [base_key, theta_key, tip_key], error_func)


def vee(M: FloatArray) -> FloatArray:
    """``(omega, v)`` (gtsam's order) of a 4x4 twist matrix ``[[omega]x, v; 0, 0]``."""
    return np.array([M[2, 1], M[0, 2], M[1, 0], M[0, 3], M[1, 3], M[2, 3]])


def segment_tie_residual(world_T_base: gtsam.Pose3, x: FloatArray, world_T_tip: gtsam.Pose3,
                         bending: Bending, segment: int, jacobians: bool = True
                         ) -> KinematicResidual:
    """The kinematic residual of segment ``segment`` in any parameterisation of the frame.

    The same residual as :func:`kinematic_residual`, ``Logmap(world_T_tip^-1 world_T_base
    base_T_tip(x))``, with the segment's transform taken from its components of the whole frame
    vector ``x`` (:class:`~apcc_graph.model.parameterisation.Bending`: an angle in a fixed
    plane, or a bending vector).

    Returns:
        ``r`` ``(6,)``, ``H_base`` ``(6, 6)``, ``H_x`` ``(6, dim)`` (zero outside the segment's
        columns) and ``H_tip`` ``(6, 6)``, under ``T . Exp(d)`` and ``x + d``.
    """
    x = np.asarray(x, dtype=float)
    if not jacobians:
        return _pose_tie(world_T_base, bending.transform(x, segment), world_T_tip, None)
    A, dAs = bending.transform_and_derivatives(x, segment)
    A_inv = np.linalg.inv(A)
    twists = np.column_stack([vee(A_inv @ dA) for dA in dAs])
    r, h_base, h_segment, h_tip = _pose_tie(world_T_base, A, world_T_tip, twists)
    H_x = np.zeros((6, bending.dim))
    H_x[:, bending.columns(segment)] = h_segment
    return r, h_base, H_x, h_tip


def segment_tie_factor(x_key: int, tip_key: int, base: int | FloatArray, bending: Bending,
                       segment: int,
                       noise: gtsam.noiseModel.Base | float | Sequence[float] | FloatArray
                       ) -> gtsam.CustomFactor:
    """A ``gtsam.CustomFactor`` tying one segment's tip pose to its base and the frame vector.

    Args:
        x_key: key of the frame vector (a ``Vector`` of ``bending.dim``).
        tip_key: key of the segment's ``world_T_tip`` (a ``Pose3``).
        base: key of the segment's ``world_T_base`` (the previous segment's tip), or a known
            ``(4, 4)`` base pose (the robot's base): then the factor has two keys.
        bending: the robot's parameterisation.
        segment: the segment (0-based).
        noise: a noise model of dimension 6, or sigmas for :func:`kinematic_noise` (the model
            error of the segment: rotation in radians then translation in metres, tip frame).

    Returns:
        The factor over ``[x_key, tip_key]`` (and ``base`` when it is a key); its error is the
        residual of :func:`segment_tie_residual` whitened by ``noise``.
    """
    model = noise if isinstance(noise, gtsam.noiseModel.Base) else kinematic_noise(noise)
    if model.dim() != 6:
        raise ValueError(f"kinematic noise model of dimension {model.dim()}: expected 6")
    if not 0 <= segment < bending.n_segments:
        raise ValueError(f"segment {segment}: expected 0 <= segment < {bending.n_segments}")
    known = None if isinstance(base, int) else gtsam.Pose3(np.asarray(base, dtype=float))
    keys = [x_key, tip_key] + ([] if known is not None else [int(base)])  # type: ignore[arg-type]

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values,
                   H: list[np.ndarray] | None) -> np.ndarray:
        world_T_base = known if known is not None else values.atPose3(keys[2])
        r, h_base, h_x, h_tip = segment_tie_residual(
            world_T_base, values.atVector(x_key), values.atPose3(tip_key), bending, segment,
            jacobians=H is not None)
        if H is not None:
            H[0], H[1] = h_x, h_tip
            if known is None:
                H[2] = h_base
        return r

    return gtsam.CustomFactor(model, keys, error_func)
