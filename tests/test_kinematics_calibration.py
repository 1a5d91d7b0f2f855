"""apcc_transform_scalar_calibration: T and dT/dtheta as the scalar fast path, and the analytic
derivatives in the calibration parameters k and delta_max against central finite differences."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from apcc_graph.model.kinematics import apcc_transform
from apcc_graph.model.scalar_kinematics import (
    apcc_transform_scalar,
    apcc_transform_scalar_calibration,
)
from apcc_graph.model.segment import Segment

STEP = 1e-6
"""Central-difference step in k and delta_max (truncation ~STEP^2, rounding ~1e-16/STEP)."""

RTOL = 1e-6


def with_k(seg: Segment, k: float) -> Segment:
    return Segment(seg.length, k=k, delta_max=seg.delta_max, theta_max=seg.theta_max)


def with_delta_max(seg: Segment, delta_max: float) -> Segment:
    return Segment(seg.length, k=seg.k, delta_max=delta_max, theta_max=seg.theta_max)


def fd_dk(theta: float, seg: Segment, psi: float) -> np.ndarray:
    plus = apcc_transform(theta, with_k(seg, seg.k + STEP), psi)
    minus = apcc_transform(theta, with_k(seg, seg.k - STEP), psi)
    return (plus - minus) / (2.0 * STEP)


def fd_ddelta_max(theta: float, seg: Segment, psi: float) -> np.ndarray:
    plus = apcc_transform(theta, with_delta_max(seg, seg.delta_max + STEP), psi)
    minus = apcc_transform(theta, with_delta_max(seg, seg.delta_max - STEP), psi)
    return (plus - minus) / (2.0 * STEP)


def assert_close(analytic: np.ndarray, numeric: np.ndarray, scale: float) -> None:
    """Entry-wise relative tolerance RTOL, with an absolute floor for entries that vanish.

    The floor (1e-8 * scale, ``scale`` the size of the transform's entries) sits well above the
    finite difference's rounding error (~1e-10 * scale) and well below any derivative that matters.
    """
    np.testing.assert_allclose(analytic, numeric, rtol=RTOL, atol=1e-8 * scale)


# Calibration draws: k in [0.01, 0.49] (the ends are where c = k/(1-k) is smallest and largest);
# delta_max up to 0.95 theta_max of either sign; theta over [-theta_max, theta_max].
@st.composite
def configurations(draw: st.DrawFn) -> tuple[float, Segment, float]:
    theta_max = draw(st.floats(0.05, math.pi))
    seg = Segment(
        length=draw(st.floats(0.01, 2.0)),
        k=draw(st.floats(0.01, 0.49)),
        delta_max=draw(st.floats(-0.95, 0.95)) * theta_max,
        theta_max=theta_max,
    )
    theta = draw(st.floats(-1.0, 1.0)) * theta_max
    psi = draw(st.floats(-math.pi, math.pi))
    return theta, seg, psi


EDGE_CASES = [
    # theta = 0 (straight: both calibration derivatives vanish).
    (0.0, Segment(0.5, k=0.25, delta_max=0.1, theta_max=1.0), 0.3),
    (0.0, Segment(0.5, k=0.01, delta_max=-0.5, theta_max=1.0), -2.0),
    # theta near +-theta_max, k near the ends of its range, theta_max up to pi.
    (math.pi * 0.999, Segment(0.4, k=0.49, delta_max=0.9 * math.pi, theta_max=math.pi), 1.1),
    (-math.pi * 0.999, Segment(0.4, k=0.49, delta_max=-0.9 * math.pi, theta_max=math.pi), -0.7),
    (math.pi, Segment(1.0, k=0.01, delta_max=0.3, theta_max=math.pi), 0.0),
    (-1.0, Segment(0.5, k=0.01 + 2 * STEP, delta_max=0.2, theta_max=1.0), 2.5),
    (1.0, Segment(0.5, k=0.49, delta_max=-0.2, theta_max=1.0), math.pi),
    (1e-9, Segment(0.5, k=0.3, delta_max=0.1, theta_max=1.0), 0.5),
]


# ------------------------------------------------------------ agreement with the scalar fast path
@given(configurations())
@settings(max_examples=300, derandomize=True, deadline=None)
def test_transform_and_theta_derivative_match_the_scalar_fast_path(
    config: tuple[float, Segment, float],
) -> None:
    theta, seg, psi = config
    T, dT, _, _ = apcc_transform_scalar_calibration(theta, seg, psi)
    T_ref, dT_ref = apcc_transform_scalar(theta, seg, psi)
    np.testing.assert_array_equal(T, T_ref)
    np.testing.assert_array_equal(dT, dT_ref)


@pytest.mark.parametrize(("theta", "seg", "psi"), EDGE_CASES)
def test_edge_cases_match_the_scalar_fast_path(theta: float, seg: Segment, psi: float) -> None:
    T, dT, _, _ = apcc_transform_scalar_calibration(theta, seg, psi)
    T_ref, dT_ref = apcc_transform_scalar(theta, seg, psi)
    np.testing.assert_array_equal(T, T_ref)
    np.testing.assert_array_equal(dT, dT_ref)


def test_shapes_and_bottom_rows() -> None:
    out = apcc_transform_scalar_calibration(0.7, Segment(0.5, k=0.3, delta_max=0.1), 0.4)
    assert len(out) == 4
    for M in out:
        assert M.shape == (4, 4)
        assert M.dtype == np.float64
    np.testing.assert_array_equal(out[0][3], [0.0, 0.0, 0.0, 1.0])
    for M in out[1:]:
        np.testing.assert_array_equal(M[3], np.zeros(4))


# ------------------------------------------------------------ calibration derivatives vs FD
@given(configurations())
@settings(max_examples=300, derandomize=True, deadline=None)
@example((0.0, Segment(0.5, k=0.25, delta_max=0.1, theta_max=1.0), 0.3))
@example((1.0, Segment(0.5, k=0.49, delta_max=-0.2, theta_max=1.0), 2.0))
@example((-1.0, Segment(0.5, k=0.011, delta_max=0.2, theta_max=1.0), -1.0))
def test_calibration_derivatives_match_finite_differences(
    config: tuple[float, Segment, float],
) -> None:
    theta, seg, psi = config
    _, _, dT_dk, dT_dd = apcc_transform_scalar_calibration(theta, seg, psi)
    assert_close(dT_dk, fd_dk(theta, seg, psi), scale=seg.length)
    assert_close(dT_dd, fd_ddelta_max(theta, seg, psi), scale=1.0)


@pytest.mark.parametrize(("theta", "seg", "psi"), EDGE_CASES)
def test_edge_case_derivatives_match_finite_differences(
    theta: float, seg: Segment, psi: float
) -> None:
    _, _, dT_dk, dT_dd = apcc_transform_scalar_calibration(theta, seg, psi)
    assert_close(dT_dk, fd_dk(theta, seg, psi), scale=seg.length)
    assert_close(dT_dd, fd_ddelta_max(theta, seg, psi), scale=1.0)


def test_derivatives_vanish_when_straight() -> None:
    """At theta = 0 the chord is L and beta is 0 for every k and delta_max."""
    seg = Segment(0.5, k=0.2, delta_max=0.3, theta_max=1.0)
    for psi in (0.0, 1.0, -2.5):
        _, _, dT_dk, dT_dd = apcc_transform_scalar_calibration(0.0, seg, psi)
        np.testing.assert_array_equal(dT_dk, np.zeros((4, 4)))
        np.testing.assert_array_equal(np.abs(dT_dd), np.zeros((4, 4)))


@pytest.mark.parametrize("k", [0.01, 0.1, 0.25, 0.4, 0.49])
@pytest.mark.parametrize("theta", [-math.pi, -2.0, -1.0, 1.0, 2.0, math.pi])
def test_dk_far_from_straight_where_link_ratio_matters(theta: float, k: float) -> None:
    """Large bends, where chord depends on k through c = k/(1-k) as well as through l1 and l2.

    The c-term of dchord/dk is -l1 c s^2 / ((1-k)^2 root); dropping it changes the result by far
    more than the tolerance here (checked below), so the finite-difference comparison pins it.
    """
    seg = Segment(0.5, k=k, delta_max=0.4, theta_max=math.pi)
    psi = 0.8
    _, _, dT_dk, _ = apcc_transform_scalar_calibration(theta, seg, psi)
    numeric = fd_dk(theta, seg, psi)
    assert_close(dT_dk, numeric, scale=seg.length)

    # The part of the k-derivative that comes through c alone is a large share of the total.
    s = math.sin(0.5 * theta)
    c = seg.link_ratio
    root = math.sqrt(1.0 - (c * s) ** 2)
    c_term = -seg.l1 * c * s * s / ((1.0 - k) ** 2 * root)
    tip_dir = np.array([math.cos(psi) * s, math.sin(psi) * s, math.cos(0.5 * theta)])
    c_part = c_term * tip_dir
    assert np.linalg.norm(c_part) > 1e3 * (RTOL * np.linalg.norm(numeric[:3, 3]) + 1e-8)
