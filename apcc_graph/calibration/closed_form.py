"""Calibration of one segment from one measured tip pose, in closed form (the paper's III.C
steps 3-4; docs/estimation.md, "Calibrating a segment"), and the input checks the sweep fit
shares.

A tip pose is measured in the segment's bending plane with the base at the origin and the base
axis along +z: its position ``(x, z)`` in metres and its tangent angle ``theta_hat`` in radians
from the base axis. :func:`calibrate_from_tip` reads off ``theta = 2 atan2(x, z)`` (the tip lies
on the chord at theta/2), ``delta = theta - theta_hat`` and
``k = |OP| / L = (L^2 - x^2 - z^2) / (2 L (L - z))``, where P is the point on the base axis with
``|OP| + |P tip| = L`` (the ellipse with foci base and tip and major axis L).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.segment import Segment

MIN_BEND = math.radians(1.0)
"""A pose bent less than this (radians) carries too little information about k."""


@dataclass(frozen=True)
class TipCalibration:
    """Result of :func:`calibrate_from_tip` (metres, radians).

    Attributes:
        k: deviation coefficient.
        delta_max: tip-angle deviation at ``theta_max``.
        theta_max: the segment's bending limit used for ``delta_max``.
        theta: the bend of the measured pose, ``2 atan2(x, z)``.
        length: the segment length.
    """

    k: float
    delta_max: float
    theta_max: float
    theta: float
    length: float

    @property
    def segment(self) -> Segment:
        """The calibrated segment."""
        return Segment(self.length, k=self.k, delta_max=self.delta_max, theta_max=self.theta_max)


def finite_array(name: str, value: ArrayLike, shape: tuple[int | None, ...]) -> FloatArray:
    """``value`` as a float array of ``shape`` (``None``: any length) with finite entries.

    Raises:
        ValueError: another shape or a non-finite entry; the message names ``name``.
    """
    arr = np.asarray(value, dtype=float)
    if arr.ndim != len(shape) or any(
        s is not None and s != a for s, a in zip(shape, arr.shape, strict=False)
    ):
        want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
        raise ValueError(f"{name} has shape {arr.shape}: expected {want}")
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise ValueError(f"{name}{list(bad)}: expected finite values, got {arr[tuple(bad)]!r}")
    return arr


def positive_number(name: str, value: float) -> float:
    """``value`` as a float, checked finite and > 0 (the message names ``name``)."""
    value = float(value)
    if not math.isfinite(value) or value <= 0.0:
        raise ValueError(f"{name} = {value!r}: expected a finite value > 0")
    return value


def _bend_of(x: float, z: float, length: float) -> float:
    """The pose's bend ``theta = 2 atan2(x, z)``, checked to be within reach and bent."""
    reach = math.hypot(x, z)
    theta = 2.0 * math.atan2(x, z)
    if reach > length:
        raise ValueError(
            f"tip_position ({x:g}, {z:g}) is {reach:g} m from the base, beyond the reach of a "
            f"segment of length {length:g} m; check the units (metres) and the length"
        )
    if abs(theta) > math.pi:
        raise ValueError(
            f"tip_position ({x:g}, {z:g}) implies a bend of {math.degrees(theta):.1f} deg; "
            "expected |theta| <= 180 deg with the base axis along +z"
        )
    if abs(theta) < MIN_BEND or reach == length:
        raise ValueError(
            f"the pose is bent only {math.degrees(theta):.3f} deg: k is not observable from a "
            "straight or nearly straight segment; photograph it bent to theta_max"
        )
    return theta


def calibrate_from_tip(
    tip_position: ArrayLike,
    tip_angle: float,
    length: float,
    theta_max: float | None = None,
) -> TipCalibration:
    """The paper's one-pose calibration (III.C steps 3-4), in closed form.

    Args:
        tip_position: ``(x, z)`` of the tip in the bending plane, base at the origin (metres).
        tip_angle: measured tip tangent angle ``theta_hat`` from the base axis (radians).
        length: segment length L (metres).
        theta_max: the segment's bending limit (radians) if the photographed pose is not at it;
            default: the pose's own bend ``|theta|`` (the paper photographs at theta_max).

    Returns:
        k, delta_max, theta_max and the pose's theta.

    Raises:
        ValueError: non-finite input, a tip at or beyond the segment's reach, a pose bent less than
            1 degree, or a measurement that implies k or delta_max outside the model's range.
    """
    x, z = finite_array("tip_position", tip_position, (2,))
    tip_angle = float(finite_array("tip_angle", tip_angle, ()))
    length = positive_number("length", length)
    theta = _bend_of(x, z, length)
    k = (length**2 - math.hypot(x, z) ** 2) / (2.0 * length * (length - z))
    if not 0.0 < k < 0.5:
        raise ValueError(
            f"tip_position ({x:g}, {z:g}) implies k = {k:.4g}, outside the APCC range 0 < k < 0.5;"
            " check the tip position and the length"
        )
    if theta_max is None:
        theta_max = abs(theta)
    else:
        theta_max = positive_number("theta_max", theta_max)
    delta_max = (theta - tip_angle) * theta_max / theta
    if not abs(delta_max) < theta_max:
        raise ValueError(
            f"tip_angle = {math.degrees(tip_angle):.2f} deg at a bend of "
            f"{math.degrees(theta):.2f} deg implies delta_max = {math.degrees(delta_max):.2f} deg, "
            f"expected |delta_max| < theta_max = {math.degrees(theta_max):.2f} deg"
        )
    return TipCalibration(k=k, delta_max=delta_max, theta_max=theta_max, theta=theta, length=length)
