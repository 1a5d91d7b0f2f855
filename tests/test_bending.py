"""The bending vector b = theta (cos psi, sin psi): same transforms as (theta, psi), exact
derivatives, and nothing breaks at or through straight."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph.model.bending import (
    bending_transform,
    bending_transform_derivative,
    bending_vector,
    polar,
)
from apcc_graph.model.kinematics import apcc_transform
from apcc_graph.model.robot import Robot
from apcc_graph.model.segment import Segment


@st.composite
def segments(draw: st.DrawFn) -> Segment:
    theta_max = draw(st.floats(0.2, math.pi))
    return Segment(length=draw(st.floats(0.05, 1.0)), k=draw(st.floats(0.05, 0.45)),
                   delta_max=draw(st.floats(-0.8, 0.8)) * theta_max, theta_max=theta_max)


def _numeric(u: float, v: float, seg: Segment, h: float = 1e-6) -> tuple[np.ndarray, ...]:
    du = (bending_transform(u + h, v, seg) - bending_transform(u - h, v, seg)) / (2 * h)
    dv = (bending_transform(u, v + h, seg) - bending_transform(u, v - h, seg)) / (2 * h)
    return du, dv


@settings(max_examples=200, deadline=None)
@given(segments(), st.floats(0.0, 1.5), st.floats(-math.pi, math.pi))
def test_the_bending_vector_is_the_polar_transform(seg: Segment, theta: float,
                                                   psi: float) -> None:
    u, v = bending_vector(theta, psi)
    np.testing.assert_allclose(bending_transform(u, v, seg), apcc_transform(theta, seg, psi),
                               atol=1e-12)
    back_theta, back_psi = polar(u, v)
    assert abs(back_theta - theta) < 1e-12
    if theta > 1e-9:
        assert abs(math.remainder(float(back_psi) - psi, 2 * math.pi)) < 1e-9


@settings(max_examples=100, deadline=None)
@given(segments(), st.floats(-1.2, 1.2))
def test_a_planar_bend_of_either_sign_is_u_alone(seg: Segment, theta: float) -> None:
    np.testing.assert_allclose(bending_transform(theta, 0.0, seg), apcc_transform(theta, seg),
                               atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(segments(), st.floats(-1.2, 1.2), st.floats(-1.2, 1.2))
def test_derivatives_match_central_differences(seg: Segment, u: float, v: float) -> None:
    du, dv = bending_transform_derivative(u, v, seg)
    nu, nv = _numeric(u, v, seg)
    np.testing.assert_allclose(du, nu, atol=2e-7)
    np.testing.assert_allclose(dv, nv, atol=2e-7)
    assert np.all(du[3] == 0.0) and np.all(dv[3] == 0.0)


def test_derivatives_at_and_through_straight() -> None:
    """At b = 0 exactly and on a path crossing it: finite, continuous, and the numerical
    derivative (which straddles straight) agrees."""
    seg = Segment(length=0.3, k=0.22, delta_max=math.radians(6), theta_max=math.radians(60))
    for u, v in [(0.0, 0.0), (1e-9, 0.0), (0.0, -1e-9), (3e-6, -2e-6), (2e-4, 1e-4)]:
        du, dv = bending_transform_derivative(u, v, seg)
        nu, nv = _numeric(u, v, seg, h=1e-5)
        np.testing.assert_allclose(du, nu, atol=1e-8)
        np.testing.assert_allclose(dv, nv, atol=1e-8)
    # a robot passing through straight: b(t) = (t, 0.3 t) for t from -1 to 1 degree
    t = np.radians(np.linspace(-1, 1, 2001))
    du, dv = bending_transform_derivative(t, 0.3 * t, seg)
    assert np.all(np.isfinite(du)) and np.all(np.isfinite(dv))
    assert np.max(np.abs(np.diff(du, axis=0))) < 1e-4  # smooth: a psi flip would be O(1)
    assert np.max(np.abs(np.diff(dv, axis=0))) < 1e-4
    poses = bending_transform(t, 0.3 * t, seg)
    assert np.max(np.abs(np.diff(poses, axis=0))) < 1e-4  # no jump where psi flips by pi


def test_spatial_camera_poses_and_their_derivatives() -> None:
    """The chain in bending vectors: the poses of (theta, psi), and derivatives that match
    central differences column by column (u_j at 2 j, v_j at 2 j + 1)."""
    from apcc_graph.factors.camera_chain import CameraChain, camera_poses
    from apcc_graph.model.parameterisation import Bending

    segs = tuple(Segment(length=0.3, k=k, delta_max=math.radians(d), theta_max=math.radians(60))
                 for k, d in ((0.22, 6.0), (0.24, 3.0), (0.25, 0.0)))
    rng = np.random.default_rng(3)
    thetas = rng.uniform(0, 0.8, (5, 3))
    thetas[0, 1] = 0.0  # one segment straight
    psis = rng.uniform(-math.pi, math.pi, (5, 3))
    u, v = bending_vector(thetas, psis)
    bends = np.stack([u, v], axis=-1).reshape(5, 6)
    mount = np.eye(4)
    mount[:3, 3] = (0.01, 0.0, 0.02)
    free = Bending.free(segs)
    poses, d_poses = camera_poses(bends, free, mount)
    polar_poses = Robot(segs, [None] * 3).forward(thetas, psis)[:, 2] @ mount
    np.testing.assert_allclose(poses, polar_poses, atol=1e-12)
    h = 1e-6
    for c in range(6):
        step = np.zeros(6)
        step[c] = h
        up = camera_poses(bends + step, free, mount, derivatives=False)[0]
        down = camera_poses(bends - step, free, mount, derivatives=False)[0]
        np.testing.assert_allclose(d_poses[:, c], (up - down) / (2 * h), atol=1e-7)
    chain = CameraChain(free.head(2), mount, None)
    assert chain.n_parameters == 4
    short, d_short = chain.poses(bends, 0, True)
    np.testing.assert_allclose(short, camera_poses(bends[:, :4], free.head(2), mount)[0])
    assert d_short.shape == (5, 4, 4, 4)
