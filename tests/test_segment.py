"""Segment: validation with messages that name the field, and the deviation model (eq. 4-5)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from apcc_graph import Segment
from apcc_graph.model.segment import DEFAULT_THETA_MAX


def test_defaults_and_link_lengths() -> None:
    seg = Segment(0.5)
    assert (seg.k, seg.delta_max, seg.theta_max) == (0.25, 0.0, DEFAULT_THETA_MAX)
    assert seg.l1 == pytest.approx(0.375)
    assert seg.l2 == pytest.approx(0.125)
    assert seg.l1 + seg.l2 == pytest.approx(seg.length)
    assert seg.link_ratio == pytest.approx(1 / 3)


def test_paper_deviation_at_sixty_degrees() -> None:
    """The paper's calibration example (docs/estimation.md): delta(60 deg) = 8 * 60 / 84
    = 5.71 deg."""
    seg = Segment(0.496, k=0.224, delta_max=math.radians(8), theta_max=math.radians(84))
    assert math.degrees(float(seg.delta(math.radians(60)))) == pytest.approx(8 * 60 / 84)
    assert math.degrees(float(seg.tip_angle(math.radians(84)))) == pytest.approx(76.0)
    np.testing.assert_allclose(seg.delta([-1.0, 0.0, 1.0]), [-seg.deviation_rate, 0.0,
                                                             seg.deviation_rate])


@pytest.mark.parametrize(
    ("kwargs", "field", "fragment"),
    [
        ({"length": 0.0}, "length", "length > 0"),
        ({"length": -1.0}, "length", "length > 0"),
        ({"length": math.inf}, "length", "finite"),
        ({"length": math.nan}, "length", "finite"),
        ({"length": "0.5"}, "length", "finite real number"),
        ({"length": True}, "length", "finite real number"),
        ({"length": 0.5, "k": 0.0}, "k", "0 < k < 0.5"),
        ({"length": 0.5, "k": 0.5}, "k", "0 < k < 0.5"),
        ({"length": 0.5, "k": -0.1}, "k", "0 < k < 0.5"),
        ({"length": 0.5, "k": math.nan}, "k", "finite"),
        ({"length": 0.5, "theta_max": 0.0}, "theta_max", "0 < theta_max <= pi"),
        ({"length": 0.5, "theta_max": 3.2}, "theta_max", "0 < theta_max <= pi"),
        ({"length": 0.5, "delta_max": 1.0, "theta_max": 1.0}, "delta_max", "|delta_max| <"),
        ({"length": 0.5, "delta_max": -1.5, "theta_max": 1.0}, "delta_max", "|delta_max| <"),
        ({"length": 0.5, "delta_max": math.inf}, "delta_max", "finite"),
    ],
)
def test_invalid_fields_name_field_value_and_range(kwargs: dict, field: str,
                                                   fragment: str) -> None:
    with pytest.raises(ValueError) as info:
        Segment(**kwargs)
    message = str(info.value)
    assert f"Segment.{field}" in message
    assert fragment in message
    assert repr(kwargs[field]) in message or str(float(kwargs[field])) in message


def test_negative_delta_max_and_numpy_scalars_are_accepted() -> None:
    seg = Segment(np.float32(0.5), k=np.float64(0.2), delta_max=-0.3, theta_max=np.pi)
    assert isinstance(seg.length, float) and seg.delta_max == -0.3
    assert seg == Segment(0.5, k=0.2, delta_max=-0.3, theta_max=math.pi)
    assert hash(seg) == hash(Segment(0.5, k=0.2, delta_max=-0.3, theta_max=math.pi))


def test_segment_is_immutable() -> None:
    seg = Segment(0.5)
    with pytest.raises(AttributeError):
        seg.k = 0.3  # type: ignore[misc]
