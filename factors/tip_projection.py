"""The projection factor over a camera's tip poses: every observation once, each track's point
eliminated (model error as noise, where each segment tip's pose is a variable).

Variables: segment ``c``'s ``world_T_tip`` at each frame of the chunk (a ``Pose3``, key
:func:`~apcc_graph.factors.keys.tip_key`); camera ``c`` rides on that tip through its known
mounting ``tip_T_cam``::

    world_T_cam(f) = world_T_tip(f) . tip_T_cam

The maths is the joint-space factor's (:mod:`apcc_graph.factors.projection`): the pixel
reprojection error with each track's point eliminated by the Schur complement
(:func:`~apcc_graph.factors.reduced_system.reduced_at_poses`, variable projection), Cholesky
compressed for gtsam. Only the pose derivatives differ.

Jacobian convention: gtsam's right perturbation of a ``Pose3``, ``T . Exp(xi)`` with
``xi = (omega, v)`` in the tip frame, so ``d world_T_cam / d xi_i = world_T_tip . G_i .
tip_T_cam`` for the generators ``G_i`` of se(3) in that order (:data:`GENERATORS`).

Why the points are eliminated here rather than kept as gtsam variables: with a point variable
per track, a point whose rays are nearly parallel makes Levenberg-Marquardt's Gauss-Newton
steps throw it along its ray, so most iterations are rejected and the solver stops on its
relative tolerance far from the optimum; eliminated points sit at their optimum for every
step (docs/estimation.md, "Model error as noise").
"""

from __future__ import annotations

import gtsam
import numpy as np

from apcc_graph.factors.keys import tip_key
from apcc_graph.factors.projection import compress, restarted_points
from apcc_graph.factors.reduced_system import ReducedSystem, reduced_at_poses
from apcc_graph.factors.track_points import TrackObservations
from apcc_graph.factors.triangulation import robust_triangulate
from apcc_graph.model.arrays import FloatArray

GENERATORS = np.zeros((6, 4, 4))
"""The generators of se(3) in gtsam's tangent order ``(omega_x, omega_y, omega_z, v_x, v_y,
v_z)``."""
for _i, (_a, _b) in enumerate([(2, 1), (0, 2), (1, 0)]):
    GENERATORS[_i, _a, _b], GENERATORS[_i, _b, _a] = 1.0, -1.0
    GENERATORS[3 + _i, _i, 3] = 1.0


def tip_camera_poses(tips: FloatArray, tip_T_cam: FloatArray, derivatives: bool = True
                     ) -> tuple[FloatArray, FloatArray | None]:
    """``world_T_cam`` ``(F, 4, 4)`` of a camera mounted at ``tip_T_cam`` on the tips ``(F, 4,
    4)`` and, with ``derivatives``, ``(F, 6, 4, 4)`` their derivatives in each tip's tangent
    (module docstring)."""
    poses = tips @ tip_T_cam
    if not derivatives:
        return poses, None
    return poses, np.einsum("fab,ibc,cd->fiad", tips, GENERATORS, tip_T_cam)


class TipProjectionFactor:
    """One camera's chunk of tracks as a gtsam factor over its tip poses at the frames they
    span (module docstring).

    Args:
        obs: the tracks (rows of a contiguous range of frames); ``obs.camera`` is the segment
            whose tip carries the camera.
        tip_T_cam: ``(4, 4)`` the camera's mounting.
        weights: ``(N,)`` row weights, used in place (the estimator updates its robust
            decisions between solves).
    """

    def __init__(self, obs: TrackObservations, tip_T_cam: FloatArray,
                 weights: FloatArray | None = None) -> None:
        if len(obs) == 0:
            raise ValueError("a projection factor needs at least one observation")
        self.obs, self.mount = obs, np.asarray(tip_T_cam, dtype=float)
        self.weights = np.ones(len(obs)) if weights is None else weights
        self.first, self.last = int(obs.frames.min()), int(obs.frames.max())
        self.keys = [tip_key(f, obs.camera) for f in range(self.first, self.last + 1)]
        self.points: FloatArray | None = None
        self.norms: FloatArray | None = None
        self.dim = 6 * len(self.keys) + 1
        self.point_iterations = 10  # from the kept points; 1 suits iSAM2's re-linearisations

    def _rows(self, obs: TrackObservations, tips: FloatArray, derivatives: bool
              ) -> tuple[FloatArray, FloatArray, FloatArray | None]:
        """Row-last camera orientations ``(3, 3, N)``, positions ``(3, N)`` and pose
        derivatives ``(4, 4, 6, N)`` of the rows ``obs`` at the chunk's tips ``(F', 4, 4)``."""
        poses, d_poses = tip_camera_poses(tips, self.mount, derivatives)
        lf = obs.frames - self.first
        P = np.moveaxis(poses, 0, -1)[:, :, lf]
        dX = None if d_poses is None else np.ascontiguousarray(
            np.moveaxis(d_poses, (0, 1), (-1, -2))[..., lf])
        return np.ascontiguousarray(P[:3, :3]), np.ascontiguousarray(P[:3, 3]), dX

    def _reduced(self, obs: TrackObservations, tips: FloatArray, weights: FloatArray,
                 points: FloatArray | None, jacobians: bool) -> ReducedSystem:
        """The reduced system of the rows ``obs`` (the chunk's, or some of its tracks)."""
        Rb, ob, dX = self._rows(obs, tips, jacobians)
        return reduced_at_poses(obs, Rb, ob, dX, len(tips), 6, obs.frames - self.first,
                                weights, points, point_iterations=self.point_iterations)

    def system(self, tips: FloatArray, jacobians: bool = True) -> ReducedSystem:
        """The reduced system at the chunk's tips ``(F', 4, 4)``; the points are kept (the
        next triangulation starts from them, stale ones afresh)."""
        out = self._reduced(self.obs, tips, self.weights, self.points, jacobians)
        if self.points is not None:
            restarted = restarted_points(
                self.obs, self.weights, out,
                lambda part, w: self._reduced(part, tips, w, None, False))
            if restarted is not None:
                out = self._reduced(self.obs, tips, self.weights, restarted, jacobians)
        self.points, self.norms = out.points, out.residuals
        return out

    def residual_norms(self, tips: FloatArray, robust: bool = False) -> FloatArray:
        """Whitened residual norms of every row at the chunk's tips ``(F', 4, 4)``; with
        ``robust``, each track's point is found afresh, robust to wrong rows, from the rows
        the weights keep (the first decisions)."""
        if robust:
            Rb, ob, _ = self._rows(self.obs, tips, False)
            self.points, self.norms = robust_triangulate(self.obs, np.moveaxis(Rb, -1, 0),
                                                         ob.T, self.weights)
            return self.norms
        return self.system(tips, jacobians=False).residuals

    def tips(self, values: gtsam.Values) -> FloatArray:
        """``(F', 4, 4)`` the chunk's tip poses in ``values``."""
        return np.array([values.atPose3(k).matrix() for k in self.keys])

    def error_func(self, this: gtsam.CustomFactor, values: gtsam.Values,
                   H: list[np.ndarray] | None) -> np.ndarray:
        """gtsam's callback: compressed error and, when asked, the Jacobian blocks."""
        out = self.system(self.tips(values), jacobians=H is not None)
        if H is None:
            e = np.zeros(self.dim)
            e[-1] = np.sqrt(out.cost)
            return e
        A, e = compress(out.H, out.g, out.cost)
        for i in range(len(self.keys)):
            H[i] = np.asfortranarray(A[:, 6 * i:6 * i + 6])
        return e

    def factor(self) -> gtsam.CustomFactor:
        """The ``gtsam.CustomFactor`` (unit noise: the residuals are already whitened)."""
        return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(self.dim), self.keys,
                                  self.error_func)

