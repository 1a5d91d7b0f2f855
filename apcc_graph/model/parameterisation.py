"""The one parameterisation of a robot's shape that every estimator solves for.

A frame's unknowns are one vector ``x``, segment by segment from the base (docs/estimation.md,
"Robots that bend in 3-D"):

- **free bending planes** (a robot that bends in 3-D): two components per segment, the bending
  vector ``b_j = (u_j, v_j) = theta_j (cos psi_j, sin psi_j)``
  (:mod:`apcc_graph.model.bending`), ``x = (u_0, v_0, u_1, v_1, ...)``, smooth through straight;
- **fixed bending planes** (a planar robot, or any robot whose planes are known): one component
  per segment, the signed angle ``theta_j`` in the fixed plane ``psi_j`` (0 for a planar
  robot), ``x = (theta_0, theta_1, ...)``. This is the bending vector restricted to the line
  ``b_j = theta_j (cos psi_j, sin psi_j)``; its arithmetic is the planar kinematics' own
  (:func:`~apcc_graph.model.kinematics.apcc_transform` at the fixed plane), so a planar robot
  is estimated exactly as by planar code.

:class:`Bending` maps ``x`` to each segment's transform ``base_T_tip``, its derivatives (matrix
derivatives in the components, ``(w, ..., 4, 4)`` for width ``w``), the derivatives in each
segment's ``k`` and ``delta_max``, the bend magnitudes that the joint limits bound, and back to
``(theta, psi)`` with first-order standard deviations. Radians throughout.

Uncertainty of a free bending vector, to first order: with its ``2 x 2`` marginal covariance
``C``, ``sigma_theta^2 = r^T C r`` along ``r = b / |b|`` and ``sigma_psi^2 = t^T C t / |b|^2``
across, ``t = (-v, u) / |b|``. ``sigma_psi`` grows like ``1 / |b|`` toward straight, where psi
is undefined; at exactly ``b = 0`` it is ``inf`` and ``sigma_theta`` is the larger axis of ``C``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.bending import (
    SMALL_THETA,
    bending_transform,
    bending_transform_derivative,
    bending_vector,
    polar,
)
from apcc_graph.model.kinematics import (
    apcc_transform,
    apcc_transform_calibration_derivative,
    apcc_transform_derivative,
)
from apcc_graph.model.scalar_kinematics import apcc_transform_scalar, bending_transform_scalar
from apcc_graph.model.segment import Segment


@dataclass(frozen=True, eq=False)
class Bending:
    """How a frame's vector ``x`` fixes each segment's transform (module docstring).

    Build it with :meth:`fixed` (width 1: angles in fixed planes) or :meth:`free` (width 2:
    bending vectors). ``planes`` is ``None`` for free planes.
    """

    segments: tuple[Segment, ...]
    planes: FloatArray | None = None
    _plane: tuple[float, ...] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "segments", tuple(self.segments))
        if self.planes is not None:
            planes = np.asarray(self.planes, dtype=float)
            if planes.shape != (len(self.segments),) or not np.all(np.isfinite(planes)):
                raise ValueError(f"planes = {self.planes!r}: expected {len(self.segments)} "
                                 "finite bending-plane angles (radians)")
            object.__setattr__(self, "planes", planes)
        planes = np.zeros(len(self.segments)) if self.planes is None else self.planes
        object.__setattr__(self, "_plane", tuple(float(p) for p in planes))

    @classmethod
    def fixed(cls, segments: Sequence[Segment], planes: ArrayLike | None = None) -> Bending:
        """Angles in fixed bending planes (``None``: every plane 0, a planar robot)."""
        planes = np.zeros(len(segments)) if planes is None else planes
        return cls(tuple(segments), np.asarray(planes, dtype=float))

    @classmethod
    def free(cls, segments: Sequence[Segment]) -> Bending:
        """Bending vectors: every segment's plane is estimated."""
        return cls(tuple(segments), None)

    # ------------------------------------------------------------------------ layout
    @property
    def is_free(self) -> bool:
        """Whether the bending planes are unknowns."""
        return self.planes is None

    @property
    def width(self) -> int:
        """Components per segment: 1 (fixed planes) or 2 (free)."""
        return 2 if self.planes is None else 1

    @property
    def n_segments(self) -> int:
        return len(self.segments)

    @property
    def dim(self) -> int:
        """Components of a frame's vector."""
        return self.width * len(self.segments)

    @property
    def theta_max(self) -> FloatArray:
        """``(S,)`` each segment's joint limit (radians)."""
        return np.array([s.theta_max for s in self.segments])

    def columns(self, j: int) -> slice:
        """Segment j's components in a frame's vector."""
        return slice(self.width * j, self.width * (j + 1))

    def head(self, n: int) -> Bending:
        """The parameterisation of segments ``0..n-1`` (a camera on segment n - 1)."""
        return Bending(self.segments[:n], None if self.planes is None else self.planes[:n])

    def with_segments(self, segments: Sequence[Segment]) -> Bending:
        """The same planes with other segment models (self-calibration)."""
        return Bending(tuple(segments), self.planes)

    # -------------------------------------------------------------------- kinematics
    def transform(self, x: ArrayLike, j: int) -> FloatArray:
        """Segment j's ``base_T_tip`` ``(..., 4, 4)`` for frame vectors ``x`` ``(..., dim)``."""
        x = np.asarray(x, dtype=float)
        seg = self.segments[j]
        if x.ndim == 1:  # one frame: the scalar fast path (the factors' callbacks)
            if self.planes is None:  # the transform alone: no derivative in the plane angle
                u, v = float(x[2 * j]), float(x[2 * j + 1])
                return apcc_transform_scalar(math.hypot(u, v), seg, math.atan2(v, u))[0]
            return apcc_transform_scalar(float(x[j]), seg, float(self._plane[j]))[0]
        if self.planes is None:
            return bending_transform(x[..., 2 * j], x[..., 2 * j + 1], seg)
        return apcc_transform(x[..., j], seg, self._plane[j])

    def transform_and_derivatives(self, x: ArrayLike, j: int
                                  ) -> tuple[FloatArray, tuple[FloatArray, ...]]:
        """Segment j's ``base_T_tip`` ``(4, 4)`` and its matrix derivatives (:meth:`transform`
        and :meth:`derivatives`) for one frame vector ``x`` ``(dim,)``, computed once."""
        return self._scalar(np.asarray(x, dtype=float), j)

    def _scalar(self, x: FloatArray, j: int) -> tuple[FloatArray, tuple[FloatArray, ...]]:
        """Segment j's transform and derivatives for one frame vector ``x`` ``(dim,)``
        (:mod:`~apcc_graph.model.scalar_kinematics`: the same values as the vectorised
        functions without numpy's per-call overhead)."""
        seg = self.segments[j]
        if self.planes is None:
            T, du, dv = bending_transform_scalar(float(x[2 * j]), float(x[2 * j + 1]), seg,
                                                 SMALL_THETA)
            return T, (du, dv)
        T, d = apcc_transform_scalar(float(x[j]), seg, float(self._plane[j]))
        return T, (d,)

    def derivatives(self, x: ArrayLike, j: int) -> tuple[FloatArray, ...]:
        """Segment j's matrix derivatives in its ``width`` components, each ``(..., 4, 4)``."""
        x = np.asarray(x, dtype=float)
        seg = self.segments[j]
        if x.ndim == 1:
            return self._scalar(x, j)[1]
        if self.planes is None:
            return bending_transform_derivative(x[..., 2 * j], x[..., 2 * j + 1], seg)
        return (apcc_transform_derivative(x[..., j], seg, self._plane[j])[0],)

    def calibration_derivatives(self, x: ArrayLike, j: int) -> tuple[FloatArray, FloatArray]:
        """Segment j's matrix derivatives in its ``(k, delta_max)``, each ``(..., 4, 4)``."""
        x = np.asarray(x, dtype=float)
        seg = self.segments[j]
        if self.planes is None:
            theta, psi = polar(x[..., 2 * j], x[..., 2 * j + 1])
            return apcc_transform_calibration_derivative(theta, seg, psi)
        return apcc_transform_calibration_derivative(x[..., j], seg, self._plane[j])

    def frame_transforms(self, x: ArrayLike) -> tuple[list[FloatArray], list[FloatArray]]:
        """One frame's transforms ``(4, 4)`` and derivatives ``(width, 4, 4)`` per segment
        (fixed planes: the scalar fast path,
        :func:`~apcc_graph.model.scalar_kinematics.apcc_transform_scalar`)."""
        x = np.asarray(x, dtype=float)
        if self.planes is None:
            b = x.reshape(-1, 2)
            return ([bending_transform(u, v, s) for (u, v), s in zip(b, self.segments,
                                                                      strict=True)],
                    [np.stack(bending_transform_derivative(u, v, s))
                     for (u, v), s in zip(b, self.segments, strict=True)])
        pairs = [apcc_transform_scalar(float(x[j]), s, self._plane[j])
                 for j, s in enumerate(self.segments)]
        return [t for t, _ in pairs], [d[None] for _, d in pairs]

    # ------------------------------------------------------------------------ limits
    def magnitudes(self, x: ArrayLike) -> FloatArray:
        """``(..., S)`` each segment's bend ``|theta|`` (or ``|b|``), which its limit bounds."""
        x = np.asarray(x, dtype=float)
        if self.planes is None:
            return np.hypot(x[..., 0::2], x[..., 1::2])
        return np.abs(x)

    def limit_residual(self, x: ArrayLike, sigma: float) -> tuple[FloatArray, FloatArray]:
        """Soft joint limits of one frame: ``r_j = max(0, |b_j| - theta_max_j) / sigma``
        ``(S,)`` and its Jacobian ``(S, dim)`` (the gradient ``b_j / |b_j|``, or the sign of
        ``theta_j``, only outside the limit: smooth through straight)."""
        x = np.asarray(x, dtype=float)
        norm = self.magnitudes(x)
        out = norm > self.theta_max
        J = np.zeros((self.n_segments, self.dim), order="F")
        for j in np.flatnonzero(out):
            cols = self.columns(j)
            J[j, cols] = x[cols] / (norm[j] * sigma)
        return np.where(out, norm - self.theta_max, 0.0) / sigma, J

    def clip(self, x: ArrayLike) -> FloatArray:
        """``x`` within the limits: angles clipped, bending vectors shortened to
        ``theta_max``."""
        lim = self.theta_max
        if self.planes is not None:
            return np.clip(x, -lim, lim)
        b = np.asarray(x, dtype=float).reshape(-1, 2)
        norm = np.hypot(b[:, 0], b[:, 1])
        shrink = np.where(norm > lim, lim / np.maximum(norm, 1e-300), 1.0)
        return (b * shrink[:, None]).ravel()

    # ------------------------------------------------------------------- (theta, psi)
    def vector(self, thetas: ArrayLike, psis: ArrayLike | None = None) -> FloatArray:
        """``(..., dim)`` frame vectors of bends ``(..., S)`` (``theta`` may be negative) in
        planes ``psis`` (``None``: 0; with fixed planes ``psis`` must be ``None``, the planes
        are the parameterisation's)."""
        thetas = np.asarray(thetas, dtype=float)
        if self.planes is not None:
            if psis is not None:
                raise ValueError("bending planes given for a robot whose planes are fixed")
            return thetas.copy()
        u, v = bending_vector(thetas, np.zeros_like(thetas) if psis is None else psis)
        return np.stack([u, v], axis=-1).reshape(*u.shape[:-1], 2 * u.shape[-1])

    def polar(self, x: ArrayLike) -> tuple[FloatArray, FloatArray | None]:
        """``(thetas, psis)``, each ``(..., S)``: free planes give ``theta >= 0`` and ``psi``
        in ``(-pi, pi]`` (0 where straight); fixed planes give the signed angles and ``None``."""
        x = np.asarray(x, dtype=float)
        if self.planes is not None:
            return x.copy(), None
        return polar(x[..., 0::2], x[..., 1::2])

    def blocks(self, covariance: ArrayLike) -> FloatArray:
        """``(..., S, w, w)`` the per-segment diagonal blocks of frame covariances
        ``(..., dim, dim)``."""
        C = np.asarray(covariance, dtype=float)
        w = self.width
        return np.stack([C[..., w * j:w * (j + 1), w * j:w * (j + 1)]
                         for j in range(self.n_segments)], axis=-3)

    def spreads(self, blocks: ArrayLike) -> FloatArray:
        """``(..., S)`` each segment's standard deviation along its worst-determined direction:
        the square root of its block's largest eigenvalue (fixed planes: the angle's sigma);
        NaN where a block is NaN."""
        C = np.asarray(blocks, dtype=float)
        if self.planes is not None:
            return np.sqrt(np.maximum(C[..., 0, 0], 0.0))
        bad = np.isnan(C).any(axis=(-2, -1))
        largest = np.linalg.eigvalsh(np.where(bad[..., None, None], 0.0, C))[..., -1]
        return np.where(bad, np.nan, np.sqrt(np.maximum(largest, 0.0)))

    def deviations(self, x: ArrayLike, blocks: ArrayLike
                   ) -> tuple[FloatArray, FloatArray | None]:
        """First-order ``(sigma_theta, sigma_psi)``, each ``(..., S)``, of frame vectors
        ``(..., dim)`` with per-segment covariance :meth:`blocks` ``(..., S, w, w)`` (module
        docstring); fixed planes give ``sigma_psi = None``. NaN where a block is NaN."""
        C = np.asarray(blocks, dtype=float)
        if self.planes is not None:
            return np.sqrt(np.maximum(C[..., 0, 0], 0.0)), None
        b = np.asarray(x, dtype=float)
        b = b.reshape(*b.shape[:-1], b.shape[-1] // 2, 2)
        norm = np.hypot(b[..., 0], b[..., 1])
        straight = norm == 0.0
        safe = np.where(straight, 1.0, norm)
        r = np.where(straight[..., None], np.array([1.0, 0.0]), b / safe[..., None])
        t = np.stack([-r[..., 1], r[..., 0]], axis=-1)
        along = np.einsum("...i,...ij,...j->...", r, C, r)
        across = np.einsum("...i,...ij,...j->...", t, C, t)
        with np.errstate(invalid="ignore"):
            largest = np.linalg.eigvalsh(np.nan_to_num(C))[..., -1]
        largest = np.where(np.isnan(C).any(axis=(-2, -1)), np.nan, largest)
        sigma_theta = np.sqrt(np.maximum(np.where(straight, largest, along), 0.0))
        with np.errstate(divide="ignore"):
            sigma_psi = np.where(straight, np.inf, np.sqrt(np.maximum(across, 0.0)) / safe)
        return sigma_theta, np.where(np.isnan(across), np.nan, sigma_psi)
