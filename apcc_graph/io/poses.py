"""Rigid poses in files: a translation (metres) and a unit quaternion ``(w, x, y, z)``.

Quaternions are written with 15 decimals. Loading normalises the written quaternion, which can move
it by ~1e-15, so plain rounding could change the last digit each time a file is loaded and saved.
:func:`quaternion_for_file` therefore writes a fixed point of "load, convert back, round": a file
that is loaded and saved again is byte-for-byte unchanged.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import gtsam
import numpy as np
from numpy.typing import NDArray

QUATERNION_DECIMALS = 15
UNIT_TOLERANCE = 1e-6
"""A quaternion read from a file must have norm 1 within this; it is then normalised."""


def rotation_from_quaternion(quat: Sequence[float]) -> NDArray[np.float64]:
    """The 3x3 rotation of a (nearly) unit quaternion ``(w, x, y, z)``, normalised first."""
    norm = math.sqrt(sum(q * q for q in quat))
    w, x, y, z = (q / norm for q in quat)
    return gtsam.Rot3.Quaternion(w, x, y, z).matrix()


def _rounded_quaternion(rotation: NDArray[np.float64]) -> list[float]:
    q = gtsam.Rot3(rotation).toQuaternion()
    quat = [round(v, QUATERNION_DECIMALS) + 0.0 for v in (q.w(), q.x(), q.y(), q.z())]
    # q and -q are the same rotation: keep the one whose first non-zero component is positive.
    if next((v for v in quat if v != 0.0), 1.0) < 0.0:
        quat = [-v + 0.0 for v in quat]
    return quat


def quaternion_for_file(rotation: NDArray[np.float64]) -> list[float]:
    """The quaternion ``(w, x, y, z)`` to write for ``rotation``: stable under load -> save."""
    quat = _rounded_quaternion(rotation)
    for _ in range(10):
        again = _rounded_quaternion(rotation_from_quaternion(quat))
        if again == quat:
            break
        quat = again
    return quat


def quaternion_norm_error(quat: Sequence[float]) -> float:
    """``| |q| - 1 |``, to check a quaternion read from a file."""
    return abs(math.sqrt(sum(q * q for q in quat)) - 1.0)
