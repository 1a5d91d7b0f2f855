"""Whether a backbone-pose file's quaternions are in the order it says (``docs/formats.md``).

A quaternion written ``x, y, z, w`` and read ``w, x, y, z`` is a valid rotation too, so no row
can tell. The whole recording can: neighbouring markers along a bent backbone should be bent like
a circular arc, the second marker sitting where the arc that their relative rotation describes
ends, and only the right order makes the rotations follow the measured positions. Where the two
readings put the second marker in the same place (a nearly straight backbone, some small bends)
nothing is judged.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from apcc_graph.io.units import UnitsWarning
from apcc_graph.model.arrays import FloatArray

ORDER_MARGIN = 1.5
"""The quaternions are said to look scalar-last when read so they bend the backbone into arcs
this many times closer to the measured positions than read as written, over the samples that
can tell the two readings apart (:data:`TELLING_FACTOR`)."""
TELLING_FACTOR = 3.0
"""A marker pair at one sample tells the two quaternion readings apart when they place its second
marker farther apart than this many times the better reading's RMS misfit: closer than that, the
difference is within what the marker noise, the mounting offsets and the backbone's departure
from an arc explain (a nearly straight backbone puts both readings' arcs in the same place)."""
MIN_TELLING_PAIRS = 30
"""Fewer telling marker-pair samples than this and the order is not judged (no warning). With 30,
two readings that fit equally well differ by the margin 1.5 in RMS only by chance of about 1e-4
(the RMS of 30 3-D errors varies by ~7.5 %, a ratio of two by ~10 %, and ln 1.5 is 4 times that);
with 10 it would be about 1 %."""


def _arc_ends(arclengths: FloatArray, world_T_marker: FloatArray, present: NDArray[np.bool_]
              ) -> tuple[FloatArray, FloatArray]:
    """For every marker pair (neighbours along the backbone, both present at a sample): where
    the constant-curvature arc that their relative rotation describes puts the second marker
    (world, metres) and where it was measured; two ``(N, 3)`` arrays, pairs in a fixed order."""
    ends, measured = [np.zeros((0, 3))], [np.zeros((0, 3))]
    for a in range(len(arclengths) - 1):
        both = present[:, a] & present[:, a + 1]
        if not both.any():
            continue
        base, end = world_T_marker[both, a], world_T_marker[both, a + 1]
        rel = np.einsum("nji,njk->nik", base[:, :3, :3], end[:, :3, :3])
        # the bend: rotation angle and axis projected across the backbone (the local xy plane)
        axis = np.stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0],
                         np.zeros(len(rel))], axis=1)
        sin = 0.5 * np.linalg.norm(axis, axis=1)
        cos = np.clip(0.5 * (np.trace(rel, axis1=1, axis2=2) - 1.0), -1.0, 1.0)
        theta = np.arctan2(sin, cos)
        toward = np.cross(axis, [0.0, 0.0, 1.0]) / np.maximum(2.0 * sin, 1e-12)[:, None]
        small = theta < 1e-6
        across = np.where(small, theta / 2.0, (1.0 - np.cos(theta)) / np.where(small, 1.0, theta))
        along = np.where(small, 1.0, np.sin(theta) / np.where(small, 1.0, theta))
        length = arclengths[a + 1] - arclengths[a]
        arc_end = length * (across[:, None] * toward + along[:, None] * [0.0, 0.0, 1.0])
        ends.append(base[:, :3, 3] + np.einsum("nij,nj->ni", base[:, :3, :3], arc_end))
        measured.append(end[:, :3, 3])
    return np.concatenate(ends), np.concatenate(measured)


def arc_misfit(arclengths: FloatArray, world_T_marker: FloatArray, present: NDArray[np.bool_]
               ) -> tuple[float, int]:
    """How far the markers' rotations are from bending the backbone as circular arcs: the RMS
    distance (metres) between each marker's measured position and the end of the
    constant-curvature arc, from the marker before it, that their relative rotation describes
    (its bend about an axis across the backbone); and how many marker pairs it is over. Marker
    offsets of a few millimetres and degrees, and a real backbone's deviation from an arc, keep
    it at millimetres; rotations read in the wrong quaternion order do not follow the
    positions."""
    ends, measured = _arc_ends(arclengths, world_T_marker, present)
    if len(ends) == 0:
        return float("nan"), 0
    return float(np.sqrt(np.mean(np.sum((ends - measured) ** 2, axis=1)))), len(ends)


@dataclass(frozen=True)
class OrderEvidence:
    """What the quaternion-order check measured (metres; see :func:`quaternion_order_evidence`).

    Attributes:
        written: RMS arc misfit, quaternions read as written, over the telling samples.
        other: the same, quaternions read the other way (columns as x, y, z, w).
        telling: how many marker-pair samples tell the two readings apart.
        pairs: how many marker-pair samples there are.
    """

    written: float
    other: float
    telling: int
    pairs: int

    @property
    def looks_other(self) -> bool:
        """Whether the other reading fits the telling samples ORDER_MARGIN times better."""
        return self.telling >= MIN_TELLING_PAIRS and self.written > ORDER_MARGIN * self.other


def quaternion_order_evidence(arclengths: FloatArray, poses: FloatArray, other: FloatArray,
                              present: NDArray[np.bool_]) -> OrderEvidence:
    """Compare two readings of the same quaternions (``poses`` as written, ``other`` the other
    order) by how well each bends the backbone into arcs through the measured positions.

    Only the marker-pair samples where the two readings put the second marker more than
    :data:`TELLING_FACTOR` times the better reading's RMS misfit apart are compared: elsewhere
    (a nearly straight backbone, small bends) noise and mounting offsets decide, not the order.

    Args:
        arclengths: ``(M,)`` the markers' arc lengths (metres).
        poses: ``(T, M, 4, 4)`` the poses with the quaternions read as written.
        other: ``(T, M, 4, 4)`` the same rows, quaternions read in the other order.
        present: ``(T, M)`` which markers were measured.

    Returns:
        The misfits over the telling samples and how many there are.
    """
    ends, measured = _arc_ends(arclengths, poses, present)
    other_ends, _ = _arc_ends(arclengths, other, present)
    if len(ends) == 0:
        return OrderEvidence(float("nan"), float("nan"), 0, 0)
    err = np.sum((ends - measured) ** 2, axis=1)
    other_err = np.sum((other_ends - measured) ** 2, axis=1)
    floor = min(np.mean(err), np.mean(other_err))
    telling = np.sum((ends - other_ends) ** 2, axis=1) > TELLING_FACTOR ** 2 * floor
    if not telling.any():
        return OrderEvidence(float("nan"), float("nan"), 0, len(ends))
    return OrderEvidence(float(np.sqrt(np.mean(err[telling]))),
                         float(np.sqrt(np.mean(other_err[telling]))),
                         int(telling.sum()), len(ends))


def check_quaternion_order(path: str | Path, arclengths: FloatArray, poses: FloatArray,
                            swapped: FloatArray, present: NDArray[np.bool_]) -> None:
    """Warn (:class:`~apcc_graph.io.units.UnitsWarning`) when the quaternion columns read
    scalar-last describe the backbone's bends far better than read as the format says.

    Args:
        path: the file, named in the warning.
        arclengths: ``(M,)`` the markers' arc lengths (metres).
        poses: ``(T, M, 4, 4)`` the poses, quaternions read as written (w, x, y, z).
        swapped: ``(T, M, 4, 4)`` the same rows, the quaternion columns read as x, y, z, w.
        present: ``(T, M)`` which markers were measured.
    """
    found = quaternion_order_evidence(arclengths, poses, swapped, present)
    if not found.looks_other:
        return
    written, other = found.written, found.other
    warnings.warn(f"{path}: the quaternion columns qw,qx,qy,qz look written in the order "
                  f"x, y, z, w: read so, the markers' rotations bend the backbone into arcs "
                  f"{other * 1e3:.1f} mm RMS from the measured positions, read as written "
                  f"(w, x, y, z) {written * 1e3:.1f} mm; the format's order is w, x, y, z: "
                  "move the w column first (calibrations from this file are wrong otherwise)",
                  UnitsWarning, stacklevel=2)
