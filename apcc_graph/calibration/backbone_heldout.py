"""Held-out shape points of a backbone calibration: markers between segment ends.

A marker at arc length ``s`` inside segment i (base at ``s_0``, length L) sits, in the model, at
the end of the first ``f = (s - s_0) / L`` of the segment. A constant-curvature arc's first part
is itself an arc of length ``f L`` bent by ``f theta`` in the same plane; the APCC model of that
part is taken the same way (the segment's k and deviation rate, bending vector ``f b``). With the
bends fitted from the segment ends, only the marker's constant offset from the backbone is fitted
here (six numbers); what remains is how well the model places the middle of the backbone, a test
on data the calibration never saw.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.optimize

from apcc_graph.calibration.backbone_model import (
    pose_matrices,
    rigid_inverse,
    rotation_errors,
    segment_transform,
    tangent_angles,
)
from apcc_graph.io.backbone_poses import BackbonePoses, segment_markers
from apcc_graph.model.arrays import FloatArray, rms
from apcc_graph.model.robot import Robot
from apcc_graph.model.segment import Segment

HELD_OUT_SIGMAS = (1e-3, np.radians(0.5))
"""Position (metres) and angle (radians) weights of the held-out offset fit."""


@dataclass(frozen=True)
class HeldOutMarker:
    """How the calibrated models place one held-out marker (metres, radians).

    Attributes:
        arclength: the marker's arc length from the base.
        segment: 0-based segment it lies in.
        fraction: ``f``, how far along that segment.
        apcc_position, apcc_tangent: ``(n,)`` errors of the APCC model per sample seen.
        pcc_position, pcc_tangent: the same for PCC.
    """

    arclength: float
    segment: int
    fraction: float
    apcc_position: FloatArray
    apcc_tangent: FloatArray
    pcc_position: FloatArray
    pcc_tangent: FloatArray

    def rms(self) -> tuple[float, float, float, float]:
        """RMS ``(APCC position, APCC tangent, PCC position, PCC tangent)``."""
        return tuple(float(rms(a, axis=None)) for a in (  # type: ignore[return-value]
            self.apcc_position, self.apcc_tangent, self.pcc_position, self.pcc_tangent))


def _part_transform(bends: FloatArray, segment: Segment | None, length: float,
                    fraction: float) -> FloatArray:
    """``base_T_point`` of the first ``fraction`` of a segment, APCC (``segment``) or PCC."""
    part = None if segment is None else Segment(fraction * length, segment.k, segment.delta_max,
                                                segment.theta_max)
    return segment_transform(fraction * bends, part, fraction * length)


def _fit_offset(base_T_point: FloatArray, base_T_marker: FloatArray
                ) -> tuple[FloatArray, FloatArray]:
    """Position and tangent errors after fitting the marker's constant offset ``O``:
    ``base_T_marker = base_T_point O``."""
    sp, sa = HELD_OUT_SIGMAS

    def predicted(params: FloatArray) -> FloatArray:
        return base_T_point @ pose_matrices(params[None, :3], params[None, 3:])[0]

    def residuals(params: FloatArray) -> FloatArray:
        model = predicted(params)
        return np.concatenate([
            ((model[:, :3, 3] - base_T_marker[:, :3, 3]) / sp).ravel(),
            (rotation_errors(base_T_marker, model) / sa).ravel()])

    params = scipy.optimize.least_squares(residuals, np.zeros(6), method="lm").x
    model = predicted(params)
    return (np.linalg.norm(model[:, :3, 3] - base_T_marker[:, :3, 3], axis=-1),
            tangent_angles(model, base_T_marker))


def held_out_markers(poses: BackbonePoses, used: FloatArray, robot: Robot,
                     segments: Sequence[Segment], apcc_offsets: FloatArray,
                     apcc_bends: Sequence[FloatArray], pcc_offsets: FloatArray,
                     pcc_bends: Sequence[FloatArray]) -> tuple[HeldOutMarker, ...]:
    """Every marker that is neither the base nor a segment end, placed by both fitted models.

    Args:
        poses: the measured poses.
        used: ``(N,)`` sample indices the calibration fitted.
        robot: the robot (segment lengths).
        segments: the calibrated APCC segments.
        apcc_offsets, pcc_offsets: ``(K, 4, 4)`` fitted ``backbone_T_marker`` of the base and
            segment-end markers, per model.
        apcc_bends, pcc_bends: per segment ``(N, 2)`` fitted bending vectors, per model.
    """
    lengths = [seg.length for seg in robot.segments]
    base, ends, others = segment_markers(poses, lengths)
    starts = np.concatenate([[0.0], np.cumsum(lengths)[:-1]])
    markers = [base, *ends]
    out = []
    for m in others:
        arc = float(poses.arclengths[m])
        i = int(np.clip(np.searchsorted(starts, arc, side="right") - 1, 0, len(lengths) - 1))
        fraction = (arc - starts[i]) / lengths[i]
        seen = poses.present[used, m]
        if not np.any(seen):
            continue
        world_T_marker = poses.world_T_marker[used[seen], m]
        world_T_base_marker = poses.world_T_marker[used[seen], markers[i]]
        errors = []
        for offsets, bends, segment in ((apcc_offsets, apcc_bends, segments[i]),
                                        (pcc_offsets, pcc_bends, None)):
            world_T_backbone = world_T_base_marker @ rigid_inverse(offsets[i])
            base_T_marker = rigid_inverse(world_T_backbone) @ world_T_marker
            part = _part_transform(bends[i][seen], segment, lengths[i], fraction)
            errors.extend(_fit_offset(part, base_T_marker))
        out.append(HeldOutMarker(arc, i, float(fraction), *errors))
    return tuple(out)
