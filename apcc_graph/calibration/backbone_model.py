"""The least-squares problem behind calibration from backbone poses (docs/estimation.md,
"Calibrating from backbone poses").

A motion-capture marker is glued near the backbone at arc lengths 0 (the robot's base) and at
every segment end. Its frame sits at a constant offset ``backbone_T_marker = O`` from the backbone
frame there, so a segment whose base marker ``a`` and end marker ``b`` are measured as
``world_T_marker`` poses ``M_a``, ``M_b`` obeys

    M_a^-1 M_b = O_a^-1 . base_T_tip(b_i) . O_b

with ``base_T_tip`` the segment's model (APCC with its k and delta_max, or PCC) at the pose's
bending vector ``b_i = theta (cos psi, sin psi)`` (:mod:`apcc_graph.model.bending`): the bending
plane is free at every pose. The residual of a pose and segment is the position error (metres,
divided by ``position_sigma``) and the rotation error of ``R_measured^T R_model`` (radians,
:func:`rotation_errors`, divided by ``angle_sigma``), six numbers in all.

Unknowns, in this order in the parameter vector:

1. per segment (APCC only) ``k`` and the deviation rate ``delta_max / theta_max``;
2. per marker (the base marker first, then each segment end) the offset ``O = [Exp(w) | t]``:
   ``w`` a rotation vector (radians), ``t`` metres. Rolling every backbone frame about its own
   z axis by one angle changes nothing that is measured (``Rz(a) T(b) Rz(-a) = T(Rz(a) b)``),
   so the base marker's ``w_z`` is fixed at 0: 6 K - 1 offset parameters for K markers;
3. per pose and segment the bending vector ``(u, v)`` (radians).

Each pose's residuals depend on its own bending vectors and on the shared unknowns (1 and 2)
only, so the bends are eliminated pose by pose (variable projection,
:mod:`~apcc_graph.calibration.backbone_solve`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.bending import bending_transform, polar
from apcc_graph.model.kinematics import pcc_transform
from apcc_graph.model.segment import Segment

K_BOUNDS = (1e-3, 0.5 - 1e-3)
"""The range ``k`` may take in the fit (the model needs ``0 < k < 0.5``)."""
RATE_BOUNDS = (-0.999, 0.999)
"""The range of the deviation rate ``delta_max / theta_max`` (``|delta_max| < theta_max``)."""
OFFSET_NAMES = ("rotation x", "rotation y", "rotation z", "translation x", "translation y",
                "translation z")


def pose_matrices(rotvecs: FloatArray, translations: FloatArray) -> FloatArray:
    """``(..., 4, 4)`` poses ``[Exp(w) | t]`` of rotation vectors and translations."""
    shape = rotvecs.shape[:-1]
    out = np.zeros((*shape, 4, 4))
    out[..., :3, :3] = Rotation.from_rotvec(rotvecs.reshape(-1, 3)).as_matrix().reshape(
        *shape, 3, 3)
    out[..., :3, 3] = translations
    out[..., 3, 3] = 1.0
    return out


def rigid_inverse(pose: FloatArray) -> FloatArray:
    """Inverse of ``(..., 4, 4)`` rigid transforms."""
    out = np.zeros_like(pose)
    rt = np.swapaxes(pose[..., :3, :3], -1, -2)
    out[..., :3, :3] = rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", rt, pose[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def rotation_errors(measured: FloatArray, model: FloatArray) -> FloatArray:
    """``(..., 3)`` rotation errors of ``(..., 4, 4)`` poses: ``vee(E - E^T) / 2`` with
    ``E = R_measured^T R_model``, i.e. ``sin(angle)`` times the axis. It is the rotation vector
    ``Log(E)`` to within 0.6% below 10 degrees, zero exactly when the rotations agree, and cheap
    for a million poses."""
    rel = np.swapaxes(measured[..., :3, :3], -1, -2) @ model[..., :3, :3]
    return 0.5 * np.stack([rel[..., 2, 1] - rel[..., 1, 2], rel[..., 0, 2] - rel[..., 2, 0],
                           rel[..., 1, 0] - rel[..., 0, 1]], axis=-1)


def tangent_angles(a: FloatArray, b: FloatArray) -> FloatArray:
    """Angles (radians) between the z axes (backbone tangents) of ``(..., 4, 4)`` poses."""
    cos = np.einsum("...i,...i->...", a[..., :3, 2], b[..., :3, 2])
    sin = np.linalg.norm(np.cross(a[..., :3, 2], b[..., :3, 2]), axis=-1)
    return np.arctan2(sin, cos)


@dataclass(frozen=True)
class Layout:
    """Where each shared unknown sits in the parameter vector ``z`` (module docstring); the
    per-pose bending vectors are kept apart, ``(N, S, 2)``, and eliminated per pose.

    Attributes:
        lengths: ``(S,)`` segment lengths (metres).
        theta_max: ``(S,)`` bending limits (radians): ``delta_max = rate * theta_max``.
        apcc: APCC (k and rate per segment are unknowns) or PCC (no segment unknowns).
    """

    lengths: tuple[float, ...]
    theta_max: tuple[float, ...]
    apcc: bool

    @property
    def n_segments(self) -> int:
        """S."""
        return len(self.lengths)

    @property
    def n_markers(self) -> int:
        """K = S + 1: the base marker and one per segment end."""
        return self.n_segments + 1

    @property
    def n_globals(self) -> int:
        """``2 S`` for APCC (k, rate per segment), 0 for PCC."""
        return 2 * self.n_segments if self.apcc else 0

    @property
    def n_offsets(self) -> int:
        """``6 K - 1``: the base marker's roll is the gauge."""
        return 6 * self.n_markers - 1

    @property
    def size(self) -> int:
        """Length of ``z``."""
        return self.n_globals + self.n_offsets

    def offset_columns(self, marker: int) -> list[int]:
        """Entries of ``z`` holding one marker's offset ``(w_x, w_y, w_z, t_x, t_y, t_z)``
        (``-1`` for the base marker's roll, fixed at 0)."""
        if marker == 0:
            first = self.n_globals
            return [first, first + 1, -1, first + 2, first + 3, first + 4]
        first = self.n_globals + 5 + 6 * (marker - 1)
        return list(range(first, first + 6))

    def offsets(self, z: FloatArray) -> FloatArray:
        """``(K, 6)`` offsets ``(w, t)`` of each marker."""
        out = np.zeros((self.n_markers, 6))
        for m in range(self.n_markers):
            for j, c in enumerate(self.offset_columns(m)):
                if c >= 0:
                    out[m, j] = z[c]
        return out

    def offset_scales(self, prior: tuple[float, float]) -> FloatArray:
        """``(n_offsets,)`` the prior's sigma of each offset entry (rotation, translation)."""
        out = np.empty(self.n_offsets)
        for m in range(self.n_markers):
            for c, name in zip(self.offset_columns(m), OFFSET_NAMES, strict=True):
                if c >= 0:
                    out[c - self.n_globals] = prior[0] if name.startswith("rotation") else prior[1]
        return out

    def segments(self, z: FloatArray) -> list[Segment | None]:
        """The APCC segments of ``z`` (``None`` each for PCC)."""
        if not self.apcc:
            return [None] * self.n_segments
        return [Segment(length, k=float(z[2 * i]), delta_max=float(z[2 * i + 1]) * tmax,
                        theta_max=tmax)
                for i, (length, tmax) in enumerate(zip(self.lengths, self.theta_max,
                                                       strict=True))]

    def start(self) -> FloatArray:
        """``z`` of the nominal model: k = 0.25, no deviation, no offsets."""
        return np.concatenate([[0.25, 0.0] * self.n_segments if self.apcc else [],
                               np.zeros(self.n_offsets)])

    def bounds(self, prior: tuple[float, float], reach: float) -> tuple[FloatArray, FloatArray]:
        """Bounds of ``z``: k and rate in their ranges, each offset within ``reach`` sigmas of
        its prior (a marker glued near the backbone)."""
        lower, upper = np.empty(self.size), np.empty(self.size)
        for i in range(self.n_globals // 2):
            lower[2 * i], upper[2 * i] = K_BOUNDS
            lower[2 * i + 1], upper[2 * i + 1] = RATE_BOUNDS
        lower[self.n_globals:] = -reach * self.offset_scales(prior)
        upper[self.n_globals:] = reach * self.offset_scales(prior)
        return lower, upper


def segment_transform(bends: FloatArray, segment: Segment | None, length: float) -> FloatArray:
    """``base_T_tip`` of ``(..., 2)`` bending vectors: APCC of ``segment`` or PCC (``None``)."""
    if segment is not None:
        return bending_transform(bends[..., 0], bends[..., 1], segment)
    theta, psi = polar(bends[..., 0], bends[..., 1])
    return pcc_transform(theta, length, psi)


def model_relative_poses(layout: Layout, z: FloatArray, bends: FloatArray) -> FloatArray:
    """``(N, S, 4, 4)`` model ``base-marker_T_end-marker`` of every pose and segment."""
    offsets = pose_matrices(*np.split(layout.offsets(z), 2, axis=1))
    inverse = rigid_inverse(offsets)
    out = np.empty((*bends.shape[:2], 4, 4))
    for i, segment in enumerate(layout.segments(z)):
        body = segment_transform(bends[:, i], segment, layout.lengths[i])
        out[:, i] = inverse[i] @ body @ offsets[i + 1]
    return out


def pose_rows(layout: Layout, z: FloatArray, bends: FloatArray, measured: FloatArray,
              sigmas: tuple[float, float]) -> FloatArray:
    """``(N, S, 6)`` whitened residuals of every pose and segment: position error (model minus
    measured, ``/ sigmas[0]``), then ``Log(R_measured^T R_model) / sigmas[1]``."""
    model = model_relative_poses(layout, z, bends)
    dp = (model[..., :3, 3] - measured[..., :3, 3]) / sigmas[0]
    dr = rotation_errors(measured, model) / sigmas[1]
    return np.concatenate([dp, dr], axis=-1)


def initial_bends(measured: FloatArray) -> FloatArray:
    """``(N, S, 2)`` bending vectors with each segment's tip on its measured chord: the chord
    leaves the base at ``theta / 2`` in the plane ``psi``."""
    p = measured[..., :3, 3]
    theta = 2.0 * np.arctan2(np.hypot(p[..., 0], p[..., 1]), p[..., 2])
    psi = np.arctan2(p[..., 1], p[..., 0])
    return np.stack([theta * np.cos(psi), theta * np.sin(psi)], axis=-1)
