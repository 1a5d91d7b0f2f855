"""Kinematics: the identities of the APCC model (docs/estimation.md), finiteness at 0, and exact
derivatives."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph.model.joint_chain import apcc_joint_frames, apcc_phi
from apcc_graph.model.kinematics import (
    apcc_body_twists,
    apcc_transform,
    apcc_transform_derivative,
    pcc_transform,
    sinc,
)
from apcc_graph.model.scalar_kinematics import apcc_transform_scalar
from apcc_graph.model.segment import Segment

STRAIGHT = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0.5], [0, 0, 0, 1.0]])


@st.composite
def segments(draw: st.DrawFn) -> Segment:
    """Random valid segments, delta_max of either sign."""
    theta_max = draw(st.floats(0.05, math.pi))
    return Segment(
        length=draw(st.floats(0.01, 2.0)),
        k=draw(st.floats(0.01, 0.49)),
        delta_max=draw(st.floats(-0.95, 0.95)) * theta_max,
        theta_max=theta_max,
    )


angles = st.floats(-math.pi, math.pi)


def rot_z(psi: float) -> np.ndarray:
    return gtsam.Rot3.Rz(psi).matrix()


# ------------------------------------------------------------------------------------- sinc
def test_sinc_matches_ratio_and_is_one_at_zero() -> None:
    x = np.concatenate([-np.logspace(-8, 1, 50), np.logspace(-8, 1, 50)])
    np.testing.assert_allclose(sinc(x), np.sin(x) / x, rtol=2e-16, atol=0)
    assert sinc(0.0) == 1.0
    # Continuous across the switch to the series.
    below, above = sinc(np.nextafter(1e-3, 0)), sinc(1e-3)
    assert abs(below - above) < 1e-15


# -------------------------------------------------------------------------------------- PCC
def test_pcc_is_exactly_straight_at_zero_and_finite_near_it() -> None:
    np.testing.assert_array_equal(np.abs(pcc_transform(0.0, 0.5)), STRAIGHT)
    for theta in (1e-12, -1e-12, 1e-300):
        T = pcc_transform(theta, 0.5)
        assert np.all(np.isfinite(T))
        np.testing.assert_allclose(T, STRAIGHT, atol=1e-12)


@given(theta=st.floats(0.01, math.pi), length=st.floats(0.01, 2.0))
def test_pcc_matches_webster_jones(theta: float, length: float) -> None:
    T = pcc_transform(theta, length)
    expected = length / theta * np.array([1 - math.cos(theta), 0.0, math.sin(theta)])
    np.testing.assert_allclose(T[:3, 3], expected, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(T[:3, :3], gtsam.Rot3.Ry(theta).matrix(), atol=1e-15)


@given(theta=angles, psi=angles)
def test_pcc_psi_turns_the_bending_plane(theta: float, psi: float) -> None:
    T0, T = pcc_transform(theta, 0.4), pcc_transform(theta, 0.4, psi)
    Z = np.eye(4)
    Z[:3, :3] = rot_z(psi)
    np.testing.assert_allclose(T, Z @ T0 @ np.linalg.inv(Z), atol=1e-14)


def test_pcc_broadcasts() -> None:
    theta = np.linspace(-1, 1, 3)
    psi = np.array([[0.0], [0.5]])
    T = pcc_transform(theta, 0.5, psi)
    assert T.shape == (2, 3, 4, 4)
    np.testing.assert_allclose(T[1, 2], pcc_transform(1.0, 0.5, 0.5), atol=1e-15)
    assert pcc_transform(0.3, 0.5).shape == (4, 4)


# ------------------------------------------------------------------------------------- APCC
@settings(max_examples=200)
@given(segment=segments(), theta=angles, psi=angles)
def test_closed_form_equals_the_five_joint_chain(segment: Segment, theta: float,
                                                 psi: float) -> None:
    frames = apcc_joint_frames(theta, segment, psi)
    np.testing.assert_allclose(apcc_transform(theta, segment, psi), frames.base_T_tip,
                               atol=1e-14 * max(1.0, segment.length))


@settings(max_examples=200)
@given(segment=segments(), theta=st.floats(-math.pi, math.pi).filter(lambda t: abs(t) > 1e-6))
def test_tip_lies_on_the_chord_at_half_theta(segment: Segment, theta: float) -> None:
    p = apcc_transform(theta, segment)[:3, 3]
    assert abs(p[1]) < 1e-15
    assert math.atan2(p[0], p[2]) == pytest.approx(theta / 2, abs=1e-12)


@settings(max_examples=200)
@given(segment=segments(), theta=angles)
def test_ellipse_property_op_plus_ptip_is_length(segment: Segment, theta: float) -> None:
    tip = apcc_transform(theta, segment)[:3, 3]
    P = np.array([0.0, 0.0, segment.k * segment.length])
    total = np.linalg.norm(P) + np.linalg.norm(tip - P)
    assert total == pytest.approx(segment.length, rel=1e-12)
    # The joint between the links is where link 1 ends: |base -> joint| = l1, |joint -> tip| = l2.
    pts = apcc_joint_frames(theta, segment).points
    assert np.linalg.norm(pts[1] - pts[0]) == pytest.approx(segment.l1, rel=1e-12)
    assert np.linalg.norm(pts[2] - pts[1]) == pytest.approx(segment.l2, rel=1e-12)


@settings(max_examples=200)
@given(segment=segments(), theta=angles)
def test_tip_tangent_is_at_theta_minus_delta(segment: Segment, theta: float) -> None:
    R = apcc_transform(theta, segment)[:3, :3]
    tangent = R[:, 2]  # the tip's backbone direction in the base frame
    expected = theta - segment.delta_max * theta / segment.theta_max
    assert math.atan2(tangent[0], tangent[2]) == pytest.approx(
        math.remainder(expected, 2 * math.pi), abs=1e-12)
    np.testing.assert_allclose(R, gtsam.Rot3.Ry(expected).matrix(), atol=1e-14)


def test_phi_solves_paper_eq_3() -> None:
    k = 0.3
    c = k / (1 - k)
    theta = np.linspace(-3, 3, 101)
    phi = apcc_phi(theta, k)
    # tan(theta/2) = sin(phi) / (cos(phi) + c)  (paper eq. 3), in cross-multiplied form.
    np.testing.assert_allclose(np.sin(phi) * np.cos(theta / 2),
                               (np.cos(phi) + c) * np.sin(theta / 2), atol=1e-14)


@pytest.mark.parametrize("theta", [0.0, 1e-12, -1e-12, 1e-300])
def test_apcc_exact_and_finite_at_zero(theta: float) -> None:
    seg = Segment(0.5, k=0.2, delta_max=0.1, theta_max=1.0)
    T = apcc_transform(theta, seg)
    assert np.all(np.isfinite(T))
    np.testing.assert_allclose(T, STRAIGHT, atol=1e-12)
    for D in apcc_transform_derivative(theta, seg, 0.3) + apcc_body_twists(theta, seg, 0.3):
        assert np.all(np.isfinite(D))
    if theta == 0.0:
        np.testing.assert_array_equal(np.abs(T), STRAIGHT)


def test_apcc_is_continuous_through_zero() -> None:
    seg = Segment(0.5, k=0.2, delta_max=0.1, theta_max=1.0)
    theta = np.linspace(-1e-6, 1e-6, 2001)
    T = apcc_transform(theta, seg)
    assert np.max(np.abs(np.diff(T, axis=0))) < 1e-9


def _pcc_gap(theta: float, k: float) -> float:
    seg = Segment(0.5, k=k)
    return float(np.linalg.norm(apcc_transform(theta, seg)[:3, 3]
                                - pcc_transform(theta, 0.5)[:3, 3]))


def test_k_quarter_agrees_with_pcc_to_fourth_order() -> None:
    """The tip gap to PCC scales as theta^4 for k = 0.25 and only theta^2 for other k."""
    thetas = np.array([0.01, 0.02, 0.04, 0.08])
    gaps = np.array([_pcc_gap(t, 0.25) for t in thetas])
    slopes = np.diff(np.log(gaps)) / np.diff(np.log(thetas))
    np.testing.assert_allclose(slopes, 4.0, atol=0.02)
    other = np.array([_pcc_gap(t, 0.2) for t in thetas])
    np.testing.assert_allclose(np.diff(np.log(other)) / np.diff(np.log(thetas)), 2.0, atol=0.02)
    # Expected: about 3e-8 m at 5 deg and 7e-6 m at 20 deg for L = 0.5 m.
    assert 2e-8 < _pcc_gap(math.radians(5), 0.25) < 4e-8
    assert 5e-6 < _pcc_gap(math.radians(20), 0.25) < 9e-6


@given(segment=segments(), theta=angles, psi=angles)
def test_apcc_psi_turns_the_bending_plane(segment: Segment, theta: float, psi: float) -> None:
    Z = np.eye(4)
    Z[:3, :3] = rot_z(psi)
    np.testing.assert_allclose(apcc_transform(theta, segment, psi),
                               Z @ apcc_transform(theta, segment) @ Z.T, atol=1e-14)


def test_apcc_broadcasts_like_its_inputs() -> None:
    seg = Segment(0.5)
    theta = np.linspace(-1, 1, 5)
    psi = np.array([[0.0], [1.0]])
    T = apcc_transform(theta, seg, psi)
    assert T.shape == (2, 5, 4, 4)
    np.testing.assert_allclose(T[1, 3], apcc_transform(theta[3], seg, 1.0), atol=1e-15)
    assert apcc_transform_derivative(theta, seg, psi)[0].shape == (2, 5, 4, 4)
    assert apcc_body_twists(theta, seg, psi)[1].shape == (2, 5, 6)


def test_deviation_sign_changes_tip_angle_only() -> None:
    plus = Segment(0.5, k=0.2, delta_max=0.1, theta_max=1.0)
    minus = Segment(0.5, k=0.2, delta_max=-0.1, theta_max=1.0)
    Tp, Tm = apcc_transform(0.8, plus), apcc_transform(0.8, minus)
    np.testing.assert_allclose(Tp[:3, 3], Tm[:3, 3], atol=1e-15)
    assert math.atan2(Tp[0, 2], Tp[2, 2]) == pytest.approx(0.8 - 0.08)
    assert math.atan2(Tm[0, 2], Tm[2, 2]) == pytest.approx(0.8 + 0.08)


# ------------------------------------------------------------------------------ derivatives
@settings(max_examples=100)
@given(segment=segments(), theta=st.floats(-3.0, 3.0), psi=angles)
def test_matrix_derivatives_match_central_differences(segment: Segment, theta: float,
                                                      psi: float) -> None:
    h = 1e-6
    d_theta, d_psi = apcc_transform_derivative(theta, segment, psi)
    num_theta = (apcc_transform(theta + h, segment, psi)
                 - apcc_transform(theta - h, segment, psi)) / (2 * h)
    num_psi = (apcc_transform(theta, segment, psi + h)
               - apcc_transform(theta, segment, psi - h)) / (2 * h)
    scale = max(1.0, segment.length)
    np.testing.assert_allclose(d_theta, num_theta, atol=1e-8 * scale)
    np.testing.assert_allclose(d_psi, num_psi, atol=1e-8 * scale)


@settings(max_examples=100)
@given(segment=segments(), theta=st.floats(-3.0, 3.0), psi=angles)
def test_body_twists_match_gtsam_retraction(segment: Segment, theta: float, psi: float) -> None:
    """xi such that T(theta + e) = T(theta) * Exp(e xi): central differences through Logmap."""
    h = 1e-6
    T = gtsam.Pose3(apcc_transform(theta, segment, psi))

    def log_between(th: float, ps: float) -> np.ndarray:
        return gtsam.Pose3.Logmap(T.between(gtsam.Pose3(apcc_transform(th, segment, ps))))

    num_theta = (log_between(theta + h, psi) - log_between(theta - h, psi)) / (2 * h)
    num_psi = (log_between(theta, psi + h) - log_between(theta, psi - h)) / (2 * h)
    xi_theta, xi_psi = apcc_body_twists(theta, segment, psi)
    scale = max(1.0, segment.length)
    np.testing.assert_allclose(xi_theta, num_theta, atol=1e-7 * scale)
    np.testing.assert_allclose(xi_psi, num_psi, atol=1e-7 * scale)


def test_twist_and_matrix_derivative_agree() -> None:
    seg = Segment(0.4, k=0.3, delta_max=-0.2, theta_max=1.2)
    theta, psi = np.linspace(-1, 1, 7), np.linspace(-2, 2, 7)
    T = apcc_transform(theta, seg, psi)
    for twist, deriv in zip(apcc_body_twists(theta, seg, psi),
                            apcc_transform_derivative(theta, seg, psi), strict=True):
        for i in range(len(theta)):
            hat = np.zeros((4, 4))
            w, v = twist[i, :3], twist[i, 3:]
            hat[:3, :3] = [[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]
            hat[:3, 3] = v
            np.testing.assert_allclose(T[i] @ hat, deriv[i], atol=1e-14)


def test_scalar_kinematics_match_the_vectorised_functions() -> None:
    """The scalar path (one angle at a time, no array overhead) equals the vectorised one."""
    seg = Segment(0.4, k=0.3, delta_max=-0.2, theta_max=1.2)
    for theta, psi in [(0.0, 0.0), (0.7, 0.3), (-1.1, -2.0), (1e-9, 1.0)]:
        T, dT = apcc_transform_scalar(theta, seg, psi)
        np.testing.assert_allclose(T, apcc_transform(theta, seg, psi), atol=1e-15)
        np.testing.assert_allclose(dT, apcc_transform_derivative(theta, seg, psi)[0], atol=1e-15)
