"""One approximately-constant-curvature (ACC) segment and its APCC 2L-5R parameters.

Units: metres and radians. The parameters follow docs/estimation.md ("The robot") and the
paper's Table I:

- ``length`` L: arc length of the segment (metres);
- ``k``: deviation coefficient; the two rigid links have lengths ``l1 = (1 - k) L`` (base side) and
  ``l2 = k L`` (tip side). ``k = 0.25`` is the value that matches constant curvature (PCC);
- ``delta_max``: tip-angle deviation at ``theta = theta_max`` (radians, either sign);
- ``theta_max``: the largest bend the segment reaches (radians); the deviation grows linearly,
  ``delta(theta) = delta_max * theta / theta_max`` (paper eq. 5).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Real

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.model.model_error import ModelError

DEFAULT_THETA_MAX = math.radians(60.0)
"""Default bending limit (radians): the paper's segments bend "generally less than 60 degrees"."""


def require_finite(owner: str, name: str, value: object) -> float:
    """Return ``value`` as a float; raise ``ValueError`` naming ``owner.name`` if not finite.

    Args:
        owner: what the value belongs to, for the message (e.g. ``"Segment"``).
        name: the field name.
        value: the value to check; booleans and non-numbers are rejected.

    Returns:
        The value as a Python float.
    """
    if isinstance(value, bool) or not isinstance(value, (Real, np.floating, np.integer)):
        raise ValueError(f"{owner}.{name} = {value!r}: expected a finite real number")
    out = float(value)
    if not math.isfinite(out):
        raise ValueError(f"{owner}.{name} = {out!r}: expected a finite real number")
    return out


@dataclass(frozen=True)
class Segment:
    """An ACC segment modelled by APCC 2L-5R (two rigid links, five revolute joints).

    Args:
        length: arc length L in metres, > 0.
        k: deviation coefficient, 0 < k < 0.5 (0.25 reproduces PCC to fourth order).
        delta_max: tip-angle deviation at ``theta_max`` in radians, ``|delta_max| < theta_max``.
        theta_max: bending limit in radians, 0 < theta_max <= pi.
        model_error: how far the real segment departs from this model, as its calibration
            measured it (:class:`~apcc_graph.model.model_error.ModelError`); ``None`` when
            nothing was measured. Not part of the kinematics: the estimators take it as the
            model's noise (docs/estimation.md, "Model error from the calibration").

    Raises:
        ValueError: a field is not finite or out of range; the message names the field, the value
            and the allowed range.
    """

    length: float
    k: float = 0.25
    delta_max: float = 0.0
    theta_max: float = DEFAULT_THETA_MAX
    model_error: ModelError | None = None

    def __post_init__(self) -> None:
        length = require_finite("Segment", "length", self.length)
        k = require_finite("Segment", "k", self.k)
        delta_max = require_finite("Segment", "delta_max", self.delta_max)
        theta_max = require_finite("Segment", "theta_max", self.theta_max)
        if length <= 0.0:
            raise ValueError(f"Segment.length = {length!r}: expected length > 0 (metres)")
        if not 0.0 < k < 0.5:
            raise ValueError(f"Segment.k = {k!r}: expected 0 < k < 0.5")
        if not 0.0 < theta_max <= math.pi:
            raise ValueError(
                f"Segment.theta_max = {theta_max!r} rad: expected 0 < theta_max <= pi (radians)"
            )
        if not abs(delta_max) < theta_max:
            raise ValueError(
                f"Segment.delta_max = {delta_max!r} rad: expected |delta_max| < theta_max "
                f"= {theta_max!r} rad"
            )
        if self.model_error is not None and not isinstance(self.model_error, ModelError):
            raise ValueError(f"Segment.model_error = {self.model_error!r}: expected a "
                             "ModelError or None")
        # Store plain floats so that equality, hashing and repr are predictable.
        object.__setattr__(self, "length", length)
        object.__setattr__(self, "k", k)
        object.__setattr__(self, "delta_max", delta_max)
        object.__setattr__(self, "theta_max", theta_max)

    @property
    def l1(self) -> float:
        """Length of the base-side rigid link, ``(1 - k) L`` (metres)."""
        return (1.0 - self.k) * self.length

    @property
    def l2(self) -> float:
        """Length of the tip-side rigid link, ``k L`` (metres)."""
        return self.k * self.length

    @property
    def link_ratio(self) -> float:
        """``c = k / (1 - k) = l2 / l1``, as in ``sin(phi - theta/2) = c sin(theta/2)``."""
        return self.k / (1.0 - self.k)

    @property
    def deviation_rate(self) -> float:
        """``delta_max / theta_max``: the tip tangent is at ``theta * (1 - deviation_rate)``."""
        return self.delta_max / self.theta_max

    def delta(self, theta: ArrayLike) -> NDArray[np.float64]:
        """Tip-angle deviation ``delta = delta_max * theta / theta_max`` (paper eq. 5), radians."""
        return np.asarray(theta, dtype=float) * self.deviation_rate

    def tip_angle(self, theta: ArrayLike) -> NDArray[np.float64]:
        """Tip tangent angle ``theta_hat = theta - delta`` (paper eq. 4), radians."""
        return np.asarray(theta, dtype=float) * (1.0 - self.deviation_rate)


K_MARGIN = 1e-3
"""How close to its open range ``(0, 0.5)`` a calibrated ``k`` may come."""


def calibrated(segment: Segment, k: float, delta_max: float) -> Segment:
    """``segment`` with ``k`` and ``delta_max`` replaced, clamped into their valid ranges
    (``K_MARGIN <= k <= 0.5 - K_MARGIN``, ``|delta_max| <= 0.999 theta_max``): what an optimiser
    that treats them as free variables may propose is always a valid segment."""
    k = min(max(float(k), K_MARGIN), 0.5 - K_MARGIN)
    lim = 0.999 * segment.theta_max
    return Segment(segment.length, k, min(max(float(delta_max), -lim), lim), segment.theta_max)
