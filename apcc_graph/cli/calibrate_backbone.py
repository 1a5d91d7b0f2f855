"""``apcc-graph calibrate POSES.csv --robot robot.toml``: every segment's k and delta_max, and the
motion-capture marker offsets, from measured backbone poses (docs/estimation.md, "Calibrating from
backbone poses"; the file format in docs/formats.md)."""

from __future__ import annotations

import math
from pathlib import Path

from apcc_graph.calibration.backbone_fit import BackboneCalibration
from apcc_graph.model.robot import Robot


def calibrate_backbone_file(poses_path: Path, robot_path: str, output: str | None) -> str:
    """Fit, write ``output`` (the robot with the calibrated segments and ``[[markers]]``) and
    return the report."""
    from apcc_graph.calibration.backbone_fit import fit_backbone
    from apcc_graph.io.backbone_poses import load_backbone_poses
    from apcc_graph.io.robot_file import load_robot, save_robot

    robot = load_robot(robot_path)
    poses = load_backbone_poses(poses_path)
    cal = fit_backbone(poses, robot)
    if output is not None:
        save_robot(cal.robot(robot), output, marker_offsets(cal))
    return format_backbone_calibration(cal, robot, str(poses_path), output)


def marker_offsets(cal: BackboneCalibration) -> dict[float, object]:
    """Arc length -> ``backbone_T_marker`` of the calibrated markers, for ``save_robot``."""
    return {float(arc): pose for arc, pose in zip(cal.marker_arclengths, cal.backbone_T_marker,
                                                 strict=True)}


def format_backbone_calibration(cal: BackboneCalibration, robot: Robot, source: str,
                                output: str | None) -> str:
    """The report: per segment the parameters with their standard deviations, the APCC and PCC
    residuals, the held-out markers, the marker offsets and the warnings."""
    n = len(cal.sample_times)
    lines = [f"calibration of {source}: {n} samples with the base and every segment end "
             f"measured ({cal.skipped} left out for a missing marker), bending plane free"]
    lines.append(f"  {'segment':<9}{'k':>18}{'delta_max (deg)':>22}{'theta_max (deg)':>17}")
    for i, seg in enumerate(cal.segments):
        lines.append(f"  {i + 1:<9}{f'{seg.k:.4f} +/- {cal.k_std[i]:.4f}':>18}"
                     f"{f'{math.degrees(seg.delta_max):.2f} +/- {math.degrees(cal.delta_max_std[i]):.2f}':>22}"  # noqa: E501
                     f"{math.degrees(seg.theta_max):>17.1f}")
    lines.append("segment ends, RMS over the samples (position mm, tangent deg):")
    lines.append(f"  {'segment':<9}{'APCC':>20}{'PCC':>20}")
    for i, (a, p) in enumerate(zip(cal.apcc, cal.pcc, strict=True)):
        lines.append(f"  {i + 1:<9}{a.rms_position * 1e3:>11.2f}{math.degrees(a.rms_tangent):>9.2f}"
                     f"{p.rms_position * 1e3:>11.2f}{math.degrees(p.rms_tangent):>9.2f}")
    if cal.held_out:
        lines.append("held-out markers (bends from the segment ends; only the marker's offset "
                     "fitted), RMS position mm, tangent deg:")
        for h in cal.held_out:
            ap, at, pp, pt = h.rms()
            lines.append(f"  {h.arclength:.4f} m (segment {h.segment + 1}, {h.fraction:.2f} "
                         f"along)  APCC {ap * 1e3:.2f} mm {math.degrees(at):.2f} deg   "
                         f"PCC {pp * 1e3:.2f} mm {math.degrees(pt):.2f} deg")
    lines.append("marker offsets backbone_T_marker (rotation vector deg, translation mm, "
                 "+/- one standard deviation):")
    from scipy.spatial.transform import Rotation

    for arc, pose, std in zip(cal.marker_arclengths, cal.backbone_T_marker, cal.offset_std,
                              strict=True):
        rot = Rotation.from_matrix(pose[:3, :3]).as_rotvec()
        parts = [f"{math.degrees(v):+.2f}+/-{math.degrees(s):.2f}" for v, s in zip(rot, std[:3],
                                                                                  strict=True)]
        parts += [f"{v * 1e3:+.2f}+/-{s * 1e3:.2f}" for v, s in zip(pose[:3, 3], std[3:],
                                                                      strict=True)]
        lines.append(f"  {arc:.4f} m: rot ({', '.join(parts[:3])}) deg, t ({', '.join(parts[3:])})"
                     " mm")
    if cal.model_errors:
        lines.append("model error per segment, each component of the segment end's departure "
                     "from the calibrated model that is not the markers' white noise (the "
                     "batch and the smoother take it as noise by default; zero: the exact model):")
        for i, error in enumerate(cal.model_errors):
            lines.append(f"  {i + 1}: {error.describe()}")
    for warning in cal.warnings:
        lines.append(f"warning: {warning}")
    if output is not None:
        lines.append(f"wrote {output} (the robot of {robot.n_segments} segments with these "
                     "k, delta_max and model errors, its cameras, and the marker offsets)")
    return "\n".join(lines)
