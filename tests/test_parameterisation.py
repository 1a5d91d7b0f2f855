"""The one parameterisation (apcc_graph.model.parameterisation.Bending): fixed planes are the
bending vector restricted to a line, exactly the planar kinematics at plane 0; the limits and
their Jacobians; the conversions; and a planar robot estimated in a rotated fixed plane gives
the planar estimate to 1e-9 (chain and batch)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph.estimation.batch_solve import projection_solve
from apcc_graph.estimation.chain import chain_vectors
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.io import load_sequence
from apcc_graph.model.camera import TipCamera
from apcc_graph.model.kinematics import apcc_transform, apcc_transform_derivative
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot
from apcc_graph.model.segment import Segment
from apcc_graph.model.sequence import Sequence

ROOT = Path(__file__).resolve().parents[1]
SEGMENTS = (Segment(0.3, k=0.2, delta_max=0.1, theta_max=1.0),
            Segment(0.3, k=0.3, delta_max=-0.05, theta_max=0.8),
            Segment(0.25, k=0.25, delta_max=0.03, theta_max=1.2))


def test_fixed_planes_at_zero_are_the_planar_kinematics_bit_for_bit() -> None:
    rng = np.random.default_rng(0)
    x = rng.uniform(-1.0, 1.0, (7, 3))
    planar = Bending.fixed(SEGMENTS)
    assert (planar.width, planar.dim, planar.is_free) == (1, 3, False)
    for j, seg in enumerate(SEGMENTS):
        np.testing.assert_array_equal(planar.transform(x, j), apcc_transform(x[:, j], seg))
        (d,) = planar.derivatives(x, j)
        np.testing.assert_array_equal(d, apcc_transform_derivative(x[:, j], seg)[0])
    thetas, psis = planar.polar(x)
    np.testing.assert_array_equal(thetas, x)
    assert psis is None
    np.testing.assert_array_equal(planar.clip(x), np.clip(x, -planar.theta_max,
                                                          planar.theta_max))


@settings(max_examples=80, deadline=None)
@given(u=st.floats(-1.0, 1.0), v=st.floats(-1.0, 1.0), scale=st.sampled_from([1.0, 1e-9, 0.0]),
       j=st.integers(0, 2), free=st.booleans())
def test_one_frame_takes_the_scalar_path_with_the_vectorised_values(
        u: float, v: float, scale: float, j: int, free: bool) -> None:
    """A single frame vector (what the factors' callbacks pass) goes through the scalar fast
    path: its transform and derivatives equal the vectorised functions' on a batch of one,
    straight (``b = 0``) and nearly straight bends included."""
    bending = Bending.free(SEGMENTS) if free else Bending.fixed(SEGMENTS, [0.3, -1.0, 2.0])
    x = np.array([0.2, -0.4, 0.6, 0.1, -0.3, 0.5])[:bending.dim]
    cols = bending.columns(j)
    x[cols] = np.array([u, v])[:bending.width] * scale
    np.testing.assert_allclose(bending.transform(x, j), bending.transform(x[None], j)[0],
                               atol=1e-12)
    for mine, theirs in zip(bending.derivatives(x, j), bending.derivatives(x[None], j),
                            strict=True):
        # near straight both take the psi derivative at SMALL_THETA (1e-8): equal to that
        np.testing.assert_allclose(mine, theirs[0], atol=1e-12 if math.hypot(u, v) * scale > 1e-6
                                   else 1e-8)


@settings(max_examples=60, deadline=None)
@given(theta=st.floats(-1.0, 1.0), plane=st.floats(-math.pi, math.pi), j=st.integers(0, 2))
def test_a_fixed_plane_is_the_bending_vector_on_its_line(theta: float, plane: float,
                                                          j: int) -> None:
    """``x_j = theta`` in plane psi is ``b_j = theta (cos psi, sin psi)``: same transform, and
    d/dtheta is the bending-vector derivative along the line."""
    planes = np.array([0.3, -1.0, 2.0])
    planes[j] = plane
    fixed, free = Bending.fixed(SEGMENTS, planes), Bending.free(SEGMENTS)
    x = np.array([0.2, -0.4, 0.6])
    x[j] = theta
    b = free.vector(x, planes)
    np.testing.assert_allclose(fixed.transform(x, j), free.transform(b, j), atol=1e-12)
    (d_theta,) = fixed.derivatives(x, j)
    d_u, d_v = free.derivatives(b, j)
    along = math.cos(plane) * d_u + math.sin(plane) * d_v
    np.testing.assert_allclose(d_theta, along, atol=1e-7)  # the free kernel's 1e-8 near 0
    for mine, theirs in zip(fixed.calibration_derivatives(x, j),
                            free.calibration_derivatives(b, j), strict=True):
        np.testing.assert_allclose(mine, theirs, atol=1e-12)


@pytest.mark.parametrize("free", [False, True])
def test_limit_residual_and_its_jacobian(free: bool) -> None:
    bending = Bending.free(SEGMENTS) if free else Bending.fixed(SEGMENTS)
    rng = np.random.default_rng(3)
    for _ in range(20):
        x = rng.uniform(-1.4, 1.4, bending.dim)
        r, J = bending.limit_residual(x, 0.01)
        want = np.maximum(bending.magnitudes(x) - bending.theta_max, 0.0) / 0.01
        np.testing.assert_allclose(r, want, rtol=1e-12)
        h = 1e-7
        for k in range(bending.dim):
            d = np.zeros(bending.dim)
            d[k] = h
            numeric = (bending.limit_residual(x + d, 0.01)[0]
                       - bending.limit_residual(x - d, 0.01)[0]) / (2 * h)
            np.testing.assert_allclose(J[:, k], numeric, atol=1e-4)
        inside = bending.clip(x)
        assert np.all(bending.magnitudes(inside) <= bending.theta_max * (1 + 1e-12))
        np.testing.assert_array_equal(bending.limit_residual(inside * 0.999, 0.01)[0], 0.0)


def test_conversions_and_their_refusals() -> None:
    free, fixed = Bending.free(SEGMENTS), Bending.fixed(SEGMENTS)
    np.testing.assert_allclose(free.vector([0.1, -0.2, 0.0], [0.0, math.pi / 2, 1.0]),
                               [0.1, 0.0, 0.0, -0.2, 0.0, 0.0], atol=1e-16)
    with pytest.raises(ValueError, match="planes are fixed"):
        fixed.vector([0.1, 0.2, 0.3], [0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="3 finite bending-plane angles"):
        Bending.fixed(SEGMENTS, [0.0, math.nan, 0.0])
    assert free.head(2).dim == 4 and fixed.head(2).dim == 2
    C = np.arange(36.0).reshape(6, 6)
    blocks = free.blocks(C)
    assert blocks.shape == (3, 2, 2)
    np.testing.assert_array_equal(blocks[1], C[2:4, 2:4])
    sigmas, psi_sigmas = fixed.deviations(np.zeros(3), fixed.blocks(np.diag([4.0, 9.0, -1.0])))
    np.testing.assert_array_equal(sigmas, [2.0, 3.0, 0.0])
    assert psi_sigmas is None


def _rotated(sequence: Sequence, psi: float) -> Sequence:
    """The same recording of a robot whose segments all bend in the plane ``psi``: the base
    turned by ``-psi`` about its z axis and every camera's mounting by ``psi``, so that every
    camera pose, and so every observation, is the same."""
    c, s = math.cos(psi), math.sin(psi)
    Rz = np.eye(4)
    Rz[:2, :2] = [[c, -s], [s, c]]
    robot = sequence.robot
    cameras = [None if cam is None else
               TipCamera(cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height,
                         cam.distortion, Rz @ cam.tip_T_cam) for cam in robot.cameras]
    base = (np.broadcast_to(np.eye(4), (sequence.n_frames, 4, 4)) if sequence.world_T_base
            is None else sequence.world_T_base) @ np.linalg.inv(Rz)
    return Sequence(Robot(robot.segments, cameras), sequence.timestamps, sequence.tracks, base)


def test_a_planar_robot_in_a_rotated_fixed_plane_estimates_the_same() -> None:
    """The fixed-plane parameterisation with every plane at 0.7 rad, on the recording rotated
    to match, gives the planar chain and batch to 1e-9: the plane enters only through the
    kinematics (1-point solver included), as it should."""
    seq = load_sequence(ROOT / "data/sequences/planar_three").head(30)
    turned = _rotated(seq, 0.7)
    planar = Bending.fixed(seq.robot.segments)
    tilted = Bending.fixed(seq.robot.segments, np.full(seq.n_segments, 0.7))
    theta0 = seq.thetas[0]  # the start, as a user gives it
    x, status, _ = chain_vectors(seq, planar, theta0)
    y, status_y, _ = chain_vectors(turned, tilted, theta0)
    np.testing.assert_array_equal(status, status_y)
    np.testing.assert_allclose(y, x, rtol=0, atol=1e-9)
    options = GraphOptions()
    found = projection_solve(seq, x, theta0, options, bending=planar)
    again = projection_solve(turned, y, theta0, options, bending=tilted)
    assert np.abs(found.x - x).max() > 1e-4  # the batch moved: the comparison is not trivial
    np.testing.assert_allclose(again.x, found.x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(again.sigmas, found.sigmas, rtol=1e-6)
