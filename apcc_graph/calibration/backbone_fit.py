"""Calibration of every segment of a robot from a sweep of measured backbone poses
(docs/estimation.md, "Calibrating from backbone poses").

:func:`fit_backbone` fits, jointly over all poses where the base and every segment-end marker
were measured, each segment's k and delta_max, one bending vector per pose and segment (the
bending plane is free at every pose) and the constant offset of each marker frame from the
backbone frame (:mod:`~apcc_graph.calibration.backbone_model` has the residuals). The same poses
are fitted by PCC (with its own offsets) for comparison, and the markers between segment ends are
held out: with the bends fitted from the ends, only their constant offset is fitted, and what is
left is how well the model places the middle of the backbone.

Uncertainty: the Gauss-Newton covariance of the shared parameters (bends eliminated by the Schur
complement), scaled by the residual variance and by ``(1 + rho) / (1 - rho)`` with ``rho`` the
lag-1 autocorrelation of the residuals in time: consecutive poses of a slow motion carry the same
model error, and counting them as independent would make the standard deviations too small.
Parameters that end at a bound, that the data cannot tell from another (correlation above
:data:`CORRELATION_LIMIT`) or that only the offsets' prior holds, are warnings that name them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from apcc_graph.calibration.backbone_heldout import HeldOutMarker, held_out_markers
from apcc_graph.calibration.backbone_model import (
    K_BOUNDS,
    OFFSET_NAMES,
    RATE_BOUNDS,
    Layout,
    initial_bends,
    model_relative_poses,
    pose_matrices,
    rigid_inverse,
    rotation_errors,
    tangent_angles,
)
from apcc_graph.calibration.backbone_solve import OFFSET_REACH, ProjectedProblem
from apcc_graph.calibration.model_error import measure_model_error
from apcc_graph.io.backbone_poses import BackbonePoses, segment_markers
from apcc_graph.model.arrays import FloatArray, rms
from apcc_graph.model.model_error import ModelError
from apcc_graph.model.robot import Robot
from apcc_graph.model.segment import Segment

CORRELATION_LIMIT = 0.98
"""Two shared parameters correlated beyond this cannot be told apart by the sweep."""
PRIOR_DOMINATED = 0.5
"""An offset parameter whose standard deviation is above this fraction of its prior's is held by
the prior, not by the data."""
AT_BOUND = 1e-3
"""A parameter this close to its bound has ended there."""


@dataclass(frozen=True)
class SegmentResiduals:
    """How one model fits one segment over the sweep.

    Attributes:
        bends: ``(N, 2)`` fitted bending vectors (radians).
        position: ``(N,)`` distance of the model's segment end from the measured one (metres).
        tangent: ``(N,)`` angle between the model's and the measured end tangents (radians).
    """

    bends: FloatArray
    position: FloatArray
    tangent: FloatArray

    @property
    def rms_position(self) -> float:
        """RMS position error (metres)."""
        return float(rms(self.position, axis=None))

    @property
    def rms_tangent(self) -> float:
        """RMS tangent error (radians)."""
        return float(rms(self.tangent, axis=None))


@dataclass(frozen=True)
class BackboneCalibration:
    """Result of :func:`fit_backbone` (metres, radians).

    Attributes:
        segments: the calibrated segments (k, delta_max; length and theta_max of the robot).
        k_std: ``(S,)`` standard deviation of each k.
        delta_max_std: ``(S,)`` standard deviation of each delta_max.
        marker_arclengths: ``(K,)`` arc lengths of the base and segment-end markers.
        backbone_T_marker: ``(K, 4, 4)`` the fitted offset of each of those marker frames.
        offset_std: ``(K, 6)`` standard deviations of the offsets (rotation vector, radians;
            translation, metres); 0 for the base marker's roll, fixed by the gauge.
        apcc: per segment, the APCC fit's residuals.
        pcc: per segment, the best PCC fit's residuals (with its own offsets).
        held_out: the markers between segment ends, as the fitted models place them.
        sample_times: ``(N,)`` times of the poses fitted (seconds).
        skipped: samples left out because a base or segment-end marker was missing.
        warnings: parameters at a bound, not told apart, or held by the prior; a bend beyond
            theta_max.
        model_errors: per segment, its departure from the calibrated model that persists
            from sample to sample (:mod:`~apcc_graph.calibration.model_error`); the robot of
            :meth:`robot` carries them.
    """

    segments: tuple[Segment, ...]
    k_std: FloatArray
    delta_max_std: FloatArray
    marker_arclengths: FloatArray
    backbone_T_marker: FloatArray
    offset_std: FloatArray
    apcc: tuple[SegmentResiduals, ...]
    pcc: tuple[SegmentResiduals, ...]
    held_out: tuple[HeldOutMarker, ...]
    sample_times: FloatArray
    skipped: int
    warnings: tuple[str, ...]
    model_errors: tuple[ModelError, ...] = ()

    def robot(self, robot: Robot) -> Robot:
        """``robot`` with these segments and their model errors (its cameras kept)."""
        segments = [seg if i >= len(self.model_errors)
                     else replace(seg, model_error=self.model_errors[i])
                     for i, seg in enumerate(self.segments)]
        return Robot(segments, list(robot.cameras))


def _measured(poses: BackbonePoses, robot: Robot) -> tuple[FloatArray, FloatArray, FloatArray,
                                                           int]:
    """``(N, S, 4, 4)`` measured ``base-marker_T_end-marker``, the ``(N,)`` sample indices used,
    the ``(K,)`` arc lengths of the base and segment-end markers, and the number skipped."""
    base, ends, _ = segment_markers(poses, [seg.length for seg in robot.segments])
    markers = [base, *ends]
    complete = np.all(poses.present[:, markers], axis=1)
    used = np.flatnonzero(complete)
    if len(used) < 2:
        raise ValueError(f"{poses.source}: {len(used)} sample(s) with the base and every segment "
                         "end measured; expected at least 2 to calibrate")
    world = poses.world_T_marker[used][:, markers]
    rel = rigid_inverse(world[:, :-1]) @ world[:, 1:]
    return rel, used, poses.arclengths[markers], int(len(complete) - len(used))


def _segment_residuals(layout: Layout, z: FloatArray, bends: FloatArray, measured: FloatArray
                       ) -> tuple[SegmentResiduals, ...]:
    model = model_relative_poses(layout, z, bends)
    return tuple(SegmentResiduals(
        bends=bends[:, i].copy(),
        position=np.linalg.norm(model[:, i, :3, 3] - measured[:, i, :3, 3], axis=-1),
        tangent=tangent_angles(model[:, i], measured[:, i]))
        for i in range(layout.n_segments))


def _model_errors(layout: Layout, z: FloatArray, bends: FloatArray, measured: FloatArray,
                  times: FloatArray, source: str) -> tuple[ModelError, ...]:
    """Each segment's persistent departure from the fitted model (its residuals' position
    and rotation parts; :func:`~apcc_graph.calibration.model_error.measure_model_error`)."""
    model = model_relative_poses(layout, z, bends)
    return tuple(measure_model_error(model[:, i, :3, 3] - measured[:, i, :3, 3],
                                     rotation_errors(measured[:, i], model[:, i]), times,
                                     source, bends)
                 for i in range(layout.n_segments))


def _lag_one_correlation(rows: FloatArray) -> float:
    """Mean lag-1 autocorrelation over time of the ``(N, S, 6)`` residual series, in [0, 0.99]."""
    centred = rows - rows.mean(axis=0, keepdims=True)
    num = np.sum(centred[1:] * centred[:-1], axis=0)
    den = np.sum(centred**2, axis=0)
    rho = np.mean(num[den > 0] / den[den > 0]) if np.any(den > 0) else 0.0
    return float(np.clip(rho, 0.0, 0.99))


def shared_covariance(problem: ProjectedProblem, z: FloatArray) -> FloatArray:
    """Covariance of the shared unknowns: the projected Jacobian's information (bends
    eliminated), scaled by the residual variance and the correlation in time, plus the offsets'
    prior unscaled."""
    layout = problem.layout
    bends = problem.solve_bends(z)
    rows = problem.rows_of(z)(bends)
    jac = problem.jacobian(z)[:rows.size]
    n_pose, n_seg = rows.shape[:2]
    dof = max(rows.size - (2 * n_pose * n_seg + layout.size), 1)
    variance = max(float(np.sum(rows**2)) / dof, 1e-30)
    rho = _lag_one_correlation(rows)
    info = jac.T @ jac / (variance * (1.0 + rho) / (1.0 - rho))
    info[layout.n_globals:, layout.n_globals:] += np.diag(layout.offset_scales(problem.prior)
                                                          ** -2.0)
    return np.linalg.pinv(info)


def _names(layout: Layout, arclengths: FloatArray) -> list[str]:
    names = [""] * layout.size
    for i in range(layout.n_globals // 2):
        names[2 * i], names[2 * i + 1] = f"segment {i + 1} k", f"segment {i + 1} delta_max"
    for m, arc in enumerate(arclengths):
        for c, what in zip(layout.offset_columns(m), OFFSET_NAMES, strict=True):
            if c >= 0:
                names[c] = f"offset of the marker at {arc:g} m, {what}"
    return names


def _warnings(layout: Layout, z: FloatArray, cov: FloatArray, arclengths: FloatArray,
              prior: tuple[float, float], thetas: FloatArray) -> list[str]:
    """Parameters at a bound, pairs not told apart, offsets held by the prior (one line per
    marker), bends beyond theta_max."""
    names = _names(layout, arclengths)
    out = []
    for i in range(layout.n_globals // 2):
        for value, (lo, hi), what in ((z[2 * i], K_BOUNDS, "k"),
                                      (z[2 * i + 1], RATE_BOUNDS, "delta_max / theta_max")):
            if min(value - lo, hi - value) < AT_BOUND:
                out.append(f"segment {i + 1}: {what} = {value:.4f} ended at its bound "
                           f"({lo:g} .. {hi:g}): the model cannot explain this sweep inside its "
                           "range, so the value is a limit, not a measurement")
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    corr = cov / np.maximum(np.outer(std, std), 1e-300)
    for a, b in zip(*np.nonzero(np.triu(np.abs(corr) > CORRELATION_LIMIT, 1)), strict=True):
        out.append(f"{names[a]} and {names[b]} cannot be told apart by this sweep "
                   f"(correlation {corr[a, b]:+.3f})")
    scales = layout.offset_scales(prior)
    reach = OFFSET_REACH * scales
    for m, arc in enumerate(arclengths):
        ended = [what for c, what in zip(layout.offset_columns(m), OFFSET_NAMES, strict=True)
                 if c >= 0 and reach[c - layout.n_globals] - abs(z[c])
                 < AT_BOUND * reach[c - layout.n_globals]]
        if ended:
            out.append(f"the offset of the marker at {arc:g} m ended at its bound "
                       f"({OFFSET_REACH:g} prior sigmas) in {', '.join(ended)}: it absorbs "
                       "model error there, not "
                       "a mounting offset")
        held = [what for c, what in zip(layout.offset_columns(m), OFFSET_NAMES, strict=True)
                if c >= 0 and std[c] > PRIOR_DOMINATED * scales[c - layout.n_globals]]
        if held:
            out.append(f"the offset of the marker at {arc:g} m is held by its prior, not by the "
                       f"data, in {', '.join(held)} (standard deviation above "
                       f"{PRIOR_DOMINATED:g} of the prior's)")
    for i, tmax in enumerate(layout.theta_max):
        worst = float(np.max(thetas[:, i]))
        if worst > tmax:
            out.append(f"segment {i + 1}: the sweep bends it to {math.degrees(worst):.1f} deg, "
                       f"beyond its theta_max of {math.degrees(tmax):.1f} deg in the robot file")
    return out


def fit_backbone(
    poses: BackbonePoses,
    robot: Robot,
    position_sigma: float = 1e-3,
    angle_sigma: float = math.radians(0.5),
    offset_prior: tuple[float, float] = (math.radians(3.0), 0.003),
) -> BackboneCalibration:
    """Calibrate every segment's k and delta_max, and the marker offsets, from backbone poses.

    Args:
        poses: the measured marker poses (a marker at arc length 0 and at every segment end).
        robot: the robot: its segment lengths say which markers are segment ends; theta_max is
            kept (``delta_max = rate * theta_max``).
        position_sigma: position noise of a segment end relative to its base (metres).
        angle_sigma: rotation noise of the same (radians).
        offset_prior: zero-mean prior sigmas of each marker offset, rotation (radians) and
            translation (metres): a marker is glued a few millimetres and degrees off the
            backbone; a parameter the sweep cannot tell stays near zero and is named in the
            warnings. Offsets are bounded to five of these sigmas.

    Returns:
        The calibration, its uncertainty, the APCC and PCC residuals and the held-out markers.

    Raises:
        ValueError: a base or segment-end marker missing from the file, or fewer than two
            complete samples.
    """
    measured, used, arclengths, skipped = _measured(poses, robot)
    sigmas = (float(position_sigma), float(angle_sigma))
    prior = (float(offset_prior[0]), float(offset_prior[1]))
    lengths = tuple(seg.length for seg in robot.segments)
    tmax = tuple(seg.theta_max for seg in robot.segments)
    problems, solutions = {}, {}
    for apcc in (True, False):
        layout = Layout(lengths, tmax, apcc)
        problems[apcc] = ProjectedProblem(layout, measured, sigmas, prior,
                                          initial_bends(measured))
        solutions[apcc] = problems[apcc].solve(layout.start()).x
    problem, z = problems[True], solutions[True]
    layout = problem.layout
    bends = problem.solve_bends(z)
    cov = shared_covariance(problem, z)
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    segments = tuple(seg for seg in layout.segments(z) if seg is not None)
    offsets = layout.offsets(z)
    offset_std = np.array([[std[c] if c >= 0 else 0.0 for c in layout.offset_columns(m)]
                           for m in range(layout.n_markers)])
    apcc_fit = _segment_residuals(layout, z, bends, measured)
    pcc, z_pcc = problems[False], solutions[False]
    pcc_bends = pcc.solve_bends(z_pcc)
    backbone_T_marker = pose_matrices(offsets[:, :3], offsets[:, 3:])
    return BackboneCalibration(
        segments=segments,
        k_std=std[0:layout.n_globals:2].copy(),
        delta_max_std=std[1:layout.n_globals:2] * np.asarray(tmax),
        marker_arclengths=np.asarray(arclengths, dtype=float),
        backbone_T_marker=backbone_T_marker,
        offset_std=offset_std,
        apcc=apcc_fit,
        pcc=_segment_residuals(pcc.layout, z_pcc, pcc_bends, measured),
        held_out=held_out_markers(
            poses, used, robot, segments, backbone_T_marker, list(np.moveaxis(bends, 1, 0)),
            pose_matrices(*np.split(pcc.layout.offsets(z_pcc), 2, axis=1)),
            list(np.moveaxis(pcc_bends, 1, 0))),
        sample_times=poses.timestamps[used].copy(),
        skipped=skipped,
        warnings=tuple(_warnings(layout, z, cov, arclengths, prior,
                                 np.linalg.norm(bends, axis=-1))),
        model_errors=_model_errors(layout, z, bends, measured, poses.timestamps[used],
                                   "/".join(Path(str(poses.source)).parts[-2:])),
    )
