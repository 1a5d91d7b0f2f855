"""Files of measured tip poses for calibration (format ``apcc-graph/calibration@1``).

::

    format = "apcc-graph/calibration@1"
    length = 0.496             # segment length, metres
    theta_max_deg = 84.0       # optional: the segment's bending limit
    [[poses]]                  # one or many measured tip poses in the bending plane
    tip_x = 0.308              # metres, across the base axis (base at the origin)
    tip_z = 0.342              # metres, along the base axis
    tip_angle_deg = 76.0       # tip tangent angle from the base axis

One pose is calibrated by the paper's closed form, several by the least-squares sweep fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from apcc_graph.calibration.closed_form import calibrate_from_tip
from apcc_graph.calibration.fit import ThetaFit, fit_segment, fit_thetas
from apcc_graph.io.toml_fields import TomlTable, read_toml
from apcc_graph.io.units import PLAUSIBLE_LENGTH_M
from apcc_graph.model.segment import Segment

CALIBRATION_FORMAT = "apcc-graph/calibration@1"


@dataclass(frozen=True)
class TipMeasurements:
    """Measured tip poses of one segment (metres, radians)."""

    length: float
    tip_positions: NDArray[np.float64]  # (N, 2) of (x, z)
    tip_angles: NDArray[np.float64]  # (N,)
    theta_max: float | None = None


def segment_fields(top: TomlTable) -> tuple[float, float | None]:
    """``length`` (metres, > 0) and the optional ``theta_max_deg`` (as radians, or None) of a
    calibration file's top table; errors name the file and the key."""
    length = top.metres("length")
    if length <= 0.0:
        raise top.error("length", f"expected a segment length > 0 (metres), got {length!r}")
    theta_max = None
    if top.has("theta_max_deg"):
        theta_max_deg = top.number("theta_max_deg")
        if not 0.0 < theta_max_deg <= 180.0:
            raise top.error(
                "theta_max_deg", f"expected 0 < theta_max_deg <= 180, got {theta_max_deg!r}"
            )
        theta_max = math.radians(theta_max_deg)
    return length, theta_max


def load_tip_measurements(path: str | Path) -> TipMeasurements:
    """Read a calibration file.

    Raises:
        ValueError: the message names the file and the key at fault.
    """
    top = TomlTable(path, "", read_toml(path))
    top.check_keys(
        ("format", "length", "theta_max_deg", "poses"), required=("format", "length", "poses")
    )
    top.check_format(CALIBRATION_FORMAT)
    length, theta_max = segment_fields(top)
    positions, angles = [], []
    odd = None  # the first pose whose position is implausibly far, warned about once
    for pose in top.tables("poses"):
        pose.check_keys(
            ("tip_x", "tip_z", "tip_angle_deg"), required=("tip_x", "tip_z", "tip_angle_deg")
        )
        positions.append((pose.number("tip_x"), pose.number("tip_z")))
        angles.append(math.radians(pose.number("tip_angle_deg")))
        if odd is None and max(map(abs, positions[-1])) > PLAUSIBLE_LENGTH_M:
            odd = pose
    if odd is not None and length <= PLAUSIBLE_LENGTH_M:  # else the length was warned about
        far = "tip_x" if abs(odd.number("tip_x")) > PLAUSIBLE_LENGTH_M else "tip_z"
        odd.metres(far, "a tip position")
    return TipMeasurements(
        length=length,
        tip_positions=np.array(positions),
        tip_angles=np.array(angles),
        theta_max=theta_max,
    )


@dataclass(frozen=True)
class CalibrationReport:
    """A calibration from measured poses, with the APCC and best-PCC residuals on the same poses.

    Attributes:
        segment: the calibrated segment.
        n_poses: number of measured poses.
        method: ``"one-pose"`` (paper III.C, closed form) or ``"sweep"`` (least squares).
        k_std: standard deviation of k (``nan`` for one pose: exactly determined).
        delta_max_std: standard deviation of delta_max (radians; ``nan`` for one pose).
        apcc: APCC residuals with the calibrated segment.
        pcc: residuals of the best PCC fit.
    """

    segment: Segment
    n_poses: int
    method: str
    k_std: float
    delta_max_std: float
    apcc: ThetaFit
    pcc: ThetaFit


def calibrate_measurements(measurements: TipMeasurements) -> CalibrationReport:
    """Calibrate one segment from measured tip poses.

    One pose: :func:`~apcc_graph.calibration.closed_form.calibrate_from_tip`; several:
    :func:`~apcc_graph.calibration.fit.fit_segment`. Either way the report carries the residuals
    of the APCC model and of the best PCC fit on the same poses.
    """
    m = measurements
    if len(m.tip_angles) == 1:
        cal = calibrate_from_tip(m.tip_positions[0], float(m.tip_angles[0]), m.length, m.theta_max)
        segment = cal.segment
        return CalibrationReport(
            segment=segment,
            n_poses=1,
            method="one-pose",
            k_std=math.nan,
            delta_max_std=math.nan,
            apcc=fit_thetas(segment, m.tip_positions, m.tip_angles),
            pcc=fit_thetas(None, m.tip_positions, m.tip_angles, length=m.length),
        )
    sweep = fit_segment(m.tip_positions, m.tip_angles, m.length, theta_max=m.theta_max)
    return CalibrationReport(
        segment=sweep.segment,
        n_poses=len(m.tip_angles),
        method="sweep",
        k_std=sweep.k_std,
        delta_max_std=sweep.delta_max_std,
        apcc=sweep.apcc,
        pcc=sweep.pcc,
    )
