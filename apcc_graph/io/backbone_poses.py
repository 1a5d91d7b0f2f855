"""Backbone poses measured by motion capture: ``backbone_poses.csv`` (``docs/formats.md``).

Conventions: one row per marker and sample time, header ``timestamp,arclength,x,y,z,qw,qx,qy,qz``.
``timestamp`` is in seconds, ``arclength`` is the marker's place along the backbone in metres from
the base, and ``x,y,z,qw,qx,qy,qz`` is the marker's pose ``world_T_marker`` (it maps marker
coordinates to the world): a translation in metres and a unit quaternion in the order
``w, x, y, z``. Rows of one sample time are adjacent and timestamps never decrease. A marker may be
missing at some sample times (occlusion); in memory its pose is then NaN and ``present`` is False.
Arc lengths are grouped as distinct values after rounding to 1e-6 m.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.io.atomic import atomic_write_text
from apcc_graph.io.csv_table import CsvTable, format_number, read_table
from apcc_graph.io.poses import quaternion_for_file
from apcc_graph.io.quaternion_order import ORDER_MARGIN as ORDER_MARGIN
from apcc_graph.io.quaternion_order import arc_misfit as arc_misfit
from apcc_graph.io.quaternion_order import check_quaternion_order
from apcc_graph.model.arrays import FloatArray

BACKBONE_COLUMNS = ("timestamp", "arclength", "x", "y", "z", "qw", "qx", "qy", "qz")
QUATERNION_TOLERANCE = 1e-3
"""A quaternion read from a file must have norm 1 within this; it is then normalised."""
ARCLENGTH_DECIMALS = 6
"""Arc lengths that agree after rounding to this many decimals (1e-6 m) are the same marker."""


@dataclass(frozen=True, eq=False)
class BackbonePoses:
    """Poses of markers along a continuum robot's backbone, sampled over time.

    Attributes:
        timestamps: ``(T,)`` seconds, finite and strictly increasing.
        arclengths: ``(M,)`` metres from the base, >= 0 and strictly increasing (distinct after
            rounding to 1e-6 m): one per marker.
        world_T_marker: ``(T, M, 4, 4)`` marker poses (metres), NaN wherever a marker is missing.
        present: ``(T, M)`` bool, whether marker m was measured at sample t.
        source: the file the poses were read from, or ``"<memory>"``.

    Raises:
        ValueError: a shape or value that breaks these conventions; the message names the field.
    """

    timestamps: FloatArray
    arclengths: FloatArray
    world_T_marker: FloatArray
    present: NDArray[np.bool_]
    source: str = "<memory>"

    def __post_init__(self) -> None:
        times = _array("timestamps", self.timestamps, float, 1)
        arcs = _array("arclengths", self.arclengths, float, 1)
        poses = _array("world_T_marker", self.world_T_marker, float, 4)
        present = _array("present", self.present, bool, 2)
        shape = (len(times), len(arcs))
        if poses.shape != (*shape, 4, 4):
            raise ValueError(f"BackbonePoses.world_T_marker: expected shape {(*shape, 4, 4)} "
                             f"(timestamps, arclengths, 4, 4), got {poses.shape}")
        if present.shape != shape:
            raise ValueError(f"BackbonePoses.present: expected shape {shape} "
                             f"(timestamps, arclengths), got {present.shape}")
        if not np.all(np.diff(times) > 0.0) or not np.isfinite(times).all():
            raise ValueError("BackbonePoses.timestamps: expected finite, strictly increasing "
                             "seconds")
        keys = np.round(arcs, ARCLENGTH_DECIMALS)
        if not (np.all(np.diff(keys) > 0.0) and np.all(arcs >= 0.0)):
            raise ValueError("BackbonePoses.arclengths: expected metres >= 0, strictly "
                             "increasing and distinct after rounding to 1e-6 m, got "
                             f"{arcs.tolist()}")
        seen = poses[present]
        if not np.isfinite(seen).all() or not np.isnan(poses[~present]).all():
            raise ValueError("BackbonePoses.world_T_marker: expected finite poses where "
                             "present is True and NaN where it is False")
        rot = seen[:, :3, :3]
        orthonormal = np.abs(rot @ rot.transpose(0, 2, 1) - np.eye(3)).max(initial=0.0) < 1e-6
        bottom = np.array_equal(seen[:, 3], np.broadcast_to([0.0, 0.0, 0.0, 1.0], (len(seen), 4)))
        if not (orthonormal and bottom and (np.linalg.det(rot) > 0.0).all()):
            raise ValueError("BackbonePoses.world_T_marker: expected rigid transforms (a "
                             "rotation within 1e-6 and a last row 0, 0, 0, 1)")
        for name, value in (("timestamps", times), ("arclengths", arcs),
                            ("world_T_marker", poses), ("present", present)):
            object.__setattr__(self, name, value)

    @property
    def n_samples(self) -> int:
        """T, the number of sample times."""
        return len(self.timestamps)

    @property
    def n_markers(self) -> int:
        """M, the number of markers (distinct arc lengths)."""
        return len(self.arclengths)

    @property
    def positions(self) -> FloatArray:
        """``(T, M, 3)`` marker positions in the world (metres), NaN where missing."""
        return self.world_T_marker[:, :, :3, 3]

    def marker(self, arclength: float, tolerance: float = 1e-3) -> int:
        """The index of the marker at ``arclength``.

        Args:
            arclength: metres from the base.
            tolerance: how far (metres) the marker's arc length may be from ``arclength``.

        Returns:
            The index into :attr:`arclengths` of the nearest marker within ``tolerance``.

        Raises:
            ValueError: no marker there; the message lists the arc lengths present.
        """
        gaps = np.abs(self.arclengths - float(arclength))
        if len(gaps) == 0 or gaps.min() > tolerance:
            raise ValueError(f"{self.source}: no marker at arc length {_metres(arclength)} m "
                             f"(within {tolerance!r} m); arc lengths present: "
                             f"{_listed(self.arclengths)}")
        return int(np.argmin(gaps))


def load_backbone_poses(path: str | Path) -> BackbonePoses:
    """Read a ``backbone_poses.csv`` file (see the module docstring and ``docs/formats.md``).

    Args:
        path: the CSV file.

    Returns:
        The poses, one sample per distinct timestamp and one marker per distinct arc length.

    Raises:
        ValueError: a wrong header, a field that is not a finite number, a negative arc length,
            a timestamp smaller than the previous row's, a (timestamp, arclength) given twice, a
            quaternion whose norm differs from 1 by more than 1e-3, or no rows; the message names
            the file, the line and the column.
    """
    table = read_table(Path(path), BACKBONE_COLUMNS)
    if len(table) == 0:
        raise table.error(0, None, "no data rows; expected one row per marker and sample time "
                          f"after the header ({','.join(BACKBONE_COLUMNS)})")
    table.require_finite()
    time, arc = table.column("timestamp"), table.column("arclength")
    _refuse_first(table, arc < 0.0, "arclength",
                  lambda r: f"expected an arc length >= 0 (metres), got {arc[r]!r}")
    back = np.zeros(len(time), dtype=bool)
    back[1:] = time[1:] < time[:-1]
    _refuse_first(table, back, "timestamp",
                  lambda r: f"timestamp {time[r]!r} is smaller than the previous row's "
                            f"{time[r - 1]!r}; timestamps must not decrease; rows of one sample "
                            "time are adjacent")
    new = np.ones(len(time), dtype=bool)
    new[1:] = time[1:] != time[:-1]
    sample = np.cumsum(new) - 1
    keys, first, marker = np.unique(np.round(arc, ARCLENGTH_DECIMALS), return_index=True,
                                    return_inverse=True)
    marker = marker.reshape(-1)
    _refuse_duplicates(table, sample * len(keys) + marker)
    quat = table.values[:, 5:9]
    w, x, y, z = quat.T
    norm = np.sqrt(w * w + x * x + y * y + z * z)  # as apcc_graph.io.poses: same bits
    _refuse_first(table, np.abs(norm - 1.0) > QUATERNION_TOLERANCE, "qw",
                  lambda r: f"the quaternion (qw,qx,qy,qz) has norm {norm[r]!r}; expected a unit "
                            f"quaternion (norm 1 within {QUATERNION_TOLERANCE})")
    poses = np.full((int(sample[-1]) + 1, len(keys), 4, 4), np.nan)
    poses[sample, marker] = _transforms(table.values[:, 2:5], quat / norm[:, None])
    present = np.zeros(poses.shape[:2], dtype=bool)
    present[sample, marker] = True
    swapped = poses.copy()
    scalar_last = (quat / norm[:, None])[:, [3, 0, 1, 2]]  # the columns read as x, y, z, w
    swapped[sample, marker] = _transforms(table.values[:, 2:5], scalar_last)
    check_quaternion_order(path, arc[first], poses, swapped, present)
    return BackbonePoses(time[new], arc[first], poses, present, str(path))


def save_backbone_poses(poses: BackbonePoses, path: str | Path) -> None:
    """Write ``poses`` as a ``backbone_poses.csv`` file, atomically.

    Only present markers get a row; rows are ordered by (timestamp, arclength). Numbers are
    written so that :func:`load_backbone_poses` reads back the same timestamps, arc lengths and
    translations exactly and the same rotations to ~1e-15. A sample time at which no marker is
    present, or a marker present at no sample time, has no row, so it is not read back.

    Args:
        poses: what to write.
        path: the CSV file (its folder is created if needed).
    """
    lines = [",".join(BACKBONE_COLUMNS)]
    for t, m in zip(*np.nonzero(poses.present), strict=True):
        pose = poses.world_T_marker[t, m]
        fields = [poses.timestamps[t], poses.arclengths[m], *pose[:3, 3]]
        lines.append(",".join([*map(format_number, fields),
                               *map(format_number, quaternion_for_file(pose[:3, :3]))]))
    atomic_write_text(path, "\n".join(lines) + "\n")


def segment_markers(poses: BackbonePoses, lengths: Sequence[float],
                    tolerance: float = 1e-3) -> tuple[int, list[int], list[int]]:
    """Which markers are the base, the segment ends and held-out shape points.

    Args:
        poses: the measured poses.
        lengths: the robot's segment lengths (metres, base to tip), e.g. from its ``robot.toml``;
            segment i ends at arc length ``sum(lengths[:i + 1])``.
        tolerance: how far (metres) a marker's arc length may be from where it is expected.

    Returns:
        ``(base, ends, held_out)``: the index of the marker at arc length 0, the indices of the
        markers at each segment's end (base to tip), and the indices of all other markers.

    Raises:
        ValueError: a length that is not positive, or no marker at the base or at a segment end;
            the message names the arc length expected, the segment, the file and the arc lengths
            present.
    """
    lengths = [float(v) for v in lengths]
    if not lengths or not all(np.isfinite(v) and v > 0.0 for v in lengths):
        raise ValueError(f"segment lengths {lengths}: expected at least one, each > 0 (metres)")
    wanted = [("the base of segment 1", 0.0)]
    wanted += [(f"the end of segment {i + 1}", float(s))
               for i, s in enumerate(np.cumsum(lengths))]
    found = []
    for what, arclength in wanted:
        try:
            found.append(poses.marker(arclength, tolerance))
        except ValueError:
            raise ValueError(
                f"{poses.source}: no marker at arc length {_metres(arclength)} m (within "
                f"{tolerance!r} m), {what}; arc lengths present: {_listed(poses.arclengths)}"
            ) from None
    held_out = [m for m in range(poses.n_markers) if m not in found]
    return found[0], found[1:], held_out


def _array(name: str, value: ArrayLike, dtype: type, ndim: int) -> NDArray:
    """``value`` as a read-only array copy of ``dtype`` with ``ndim`` dimensions."""
    try:
        out = np.array(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"BackbonePoses.{name}: expected an array of {dtype.__name__}: "
                         f"{exc}") from None
    if out.ndim != ndim:
        raise ValueError(f"BackbonePoses.{name}: expected {ndim} dimensions, got shape "
                         f"{out.shape}")
    out.flags.writeable = False
    return out


def _refuse_first(table: CsvTable, bad: NDArray[np.bool_], column: str,
                  message: Callable[[int], str]) -> None:
    """Raise ``table.error`` on the first row where ``bad``, with ``message(row)``."""
    if bad.any():
        row = int(np.flatnonzero(bad)[0])
        raise table.error(row, column, message(row))


def _refuse_duplicates(table: CsvTable, cell: NDArray[np.int64]) -> None:
    """Refuse two rows for the same (sample, marker) ``cell``; name both lines."""
    order = np.argsort(cell, kind="stable")
    same = np.flatnonzero(cell[order][1:] == cell[order][:-1])
    if len(same):
        earlier, later = order[same], order[same + 1]
        k = int(np.argmin(later))
        row, first = int(later[k]), int(earlier[k])
        time, arc = table.column("timestamp")[row], table.column("arclength")[row]
        raise table.error(row, "arclength",
                          f"timestamp {time!r} and arc length {arc!r} were already given on "
                          f"line {table.line(first)}; expected one row per (timestamp, "
                          "arclength)")


def _transforms(translation: FloatArray, quat: FloatArray) -> FloatArray:
    """``(N, 4, 4)`` poses from ``(N, 3)`` translations and ``(N, 4)`` unit quaternions.

    The arithmetic is Eigen's ``toRotationMatrix``, operation for operation, so the result equals
    :func:`apcc_graph.io.poses.rotation_from_quaternion` bit for bit, the rotation that
    :func:`~apcc_graph.io.poses.quaternion_for_file` expects the written quaternion to give.
    """
    w, x, y, z = quat.T
    tx, ty, tz = 2.0 * x, 2.0 * y, 2.0 * z
    twx, twy, twz, txx, txy, txz = tx * w, ty * w, tz * w, tx * x, ty * x, tz * x
    tyy, tyz, tzz = ty * y, tz * y, tz * z
    out = np.zeros((len(quat), 4, 4))
    out[:, 0, :3] = np.stack([1.0 - (tyy + tzz), txy - twz, txz + twy], axis=1)
    out[:, 1, :3] = np.stack([txy + twz, 1.0 - (txx + tzz), tyz - twx], axis=1)
    out[:, 2, :3] = np.stack([txz - twy, tyz + twx, 1.0 - (txx + tyy)], axis=1)
    out[:, :3, 3] = translation
    out[:, 3, 3] = 1.0
    return out


def _metres(value: float) -> str:
    """An arc length for a message, to 1e-6 m: ``0.533``, not ``0.5330000000000001``."""
    return np.format_float_positional(float(value), precision=6, trim="-")


def _listed(arclengths: FloatArray) -> str:
    """``0, 0.1165, 0.233 m``: arc lengths for a message."""
    return ", ".join(map(_metres, arclengths)) + " m" if len(arclengths) else "none"
