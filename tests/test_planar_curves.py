"""Rods with curvature growing along the arc: PCC as the special case, arc-length bounds."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from apcc_graph.model.kinematics import pcc_in_plane
from apcc_graph.simulation.planar_curves import growing_curvature_tip


def test_zero_growth_is_constant_curvature() -> None:
    thetas = np.linspace(-3.0, 3.0, 61)
    x, z, angle = growing_curvature_tip(thetas, 0.5, 0.0)
    px, pz = pcc_in_plane(thetas, 0.5)
    np.testing.assert_allclose(x, px, atol=1e-15)
    np.testing.assert_allclose(z, pz, atol=1e-15)
    np.testing.assert_array_equal(angle, thetas)


@given(theta=st.floats(-3.0, 3.0), growth=st.floats(-0.9, 5.0))
def test_tip_within_reach_and_quadrature_converged(theta: float, growth: float) -> None:
    x, z, _ = growing_curvature_tip(theta, 0.5, growth)
    assert np.hypot(x, z) <= 0.5 + 1e-15
    x2, z2, _ = growing_curvature_tip(theta, 0.5, growth, n_nodes=128)
    assert abs(x - x2) < 1e-14 and abs(z - z2) < 1e-14


def test_growth_toward_the_tip_pulls_the_chord_angle_below_half_theta() -> None:
    """Curvature concentrated near the tip leaves the base straighter: chord angle < theta/2."""
    x, z, _ = growing_curvature_tip(1.0, 0.5, 2.0)
    assert np.arctan2(x, z) < 0.5
    x, z, _ = growing_curvature_tip(1.0, 0.5, -0.6)
    assert np.arctan2(x, z) > 0.5


def test_invalid_growth() -> None:
    with pytest.raises(ValueError, match="growth"):
        growing_curvature_tip(1.0, 0.5, -1.0)
