"""The APCC 2L-5R segment built joint by joint (docs/estimation.md, "The robot"): the joint
frames, for drawing the two links, and as a check of the closed form of
:func:`~apcc_graph.model.kinematics.apcc_transform`.

Joints from base to tip::

    Rz(psi) . Ry(theta - phi) . [link l1 along z] . Ry(phi) . [link l2 along z]
            . Ry(-delta) . Rz(-psi)

with ``phi = theta/2 + asin(c sin(theta/2))``, ``c = k / (1 - k)``, ``l1 = (1 - k) L``,
``l2 = k L`` and ``delta = delta_max * theta / theta_max``. Frames are ``base_T_*`` as in
:mod:`~apcc_graph.model.kinematics`, and everything broadcasts over ``theta`` and ``psi``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.segment import Segment


def apcc_phi(theta: ArrayLike, k: float) -> FloatArray:
    """The second joint angle ``phi = theta/2 + asin(k/(1-k) sin(theta/2))`` (radians).

    Closed-form solution of paper eq. (2)-(3); defined for every theta when 0 < k < 0.5.
    """
    theta = np.asarray(theta, dtype=float)
    c = k / (1.0 - k)
    return 0.5 * theta + np.arcsin(c * np.sin(0.5 * theta))


def _rot_y(angle: FloatArray) -> FloatArray:
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros(np.shape(angle) + (4, 4))
    out[..., 0, 0] = c
    out[..., 0, 2] = s
    out[..., 2, 0] = -s
    out[..., 2, 2] = c
    out[..., 1, 1] = 1.0
    out[..., 3, 3] = 1.0
    return out


def _rot_z(angle: FloatArray) -> FloatArray:
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros(np.shape(angle) + (4, 4))
    out[..., 0, 0] = c
    out[..., 0, 1] = -s
    out[..., 1, 0] = s
    out[..., 1, 1] = c
    out[..., 2, 2] = 1.0
    out[..., 3, 3] = 1.0
    return out


def _trans_z(distance: float) -> FloatArray:
    out = np.eye(4)
    out[2, 3] = distance
    return out


@dataclass(frozen=True)
class APCCJointFrames:
    """Frames of the APCC 2L-5R chain, all expressed in the segment's base frame (``(..., 4, 4)``).

    Attributes:
        base_T_link1: link 1 frame; origin at the base, link 1 runs ``l1`` along its +z.
        base_T_link2: link 2 frame; origin at the middle joint, link 2 runs ``l2`` along its +z.
        base_T_tip: the tip frame, equal to
            :func:`~apcc_graph.model.kinematics.apcc_transform`.
    """

    base_T_link1: FloatArray
    base_T_link2: FloatArray
    base_T_tip: FloatArray

    @property
    def points(self) -> FloatArray:
        """Base, middle joint and tip positions, ``(..., 3, 3)`` (last axis: x, y, z in metres)."""
        return np.stack(
            [
                self.base_T_link1[..., :3, 3],
                self.base_T_link2[..., :3, 3],
                self.base_T_tip[..., :3, 3],
            ],
            axis=-2,
        )


def apcc_joint_frames(theta: ArrayLike, segment: Segment, psi: ArrayLike = 0.0) -> APCCJointFrames:
    """Build the five-joint chain joint by joint (for drawing the two links, and as a check).

    Args:
        theta: bending angle(s) in radians.
        segment: the segment.
        psi: bending-plane angle(s) in radians.

    Returns:
        The link frames and the tip frame, broadcast over ``theta`` and ``psi``.
    """
    theta, psi = np.broadcast_arrays(np.asarray(theta, dtype=float), np.asarray(psi, dtype=float))
    phi = apcc_phi(theta, segment.k)
    link1 = _rot_z(psi) @ _rot_y(theta - phi)
    link2 = link1 @ _trans_z(segment.l1) @ _rot_y(phi)
    tip = link2 @ _trans_z(segment.l2) @ _rot_y(-segment.delta(theta)) @ _rot_z(-psi)
    return APCCJointFrames(base_T_link1=link1, base_T_link2=link2, base_T_tip=tip)
