"""The 2-point solver of a spatial segment (every root, the trivial one excluded, through
straight) and 2-point RANSAC around it."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from helpers import random_pose
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph.frontend import one_point, two_point, two_point_ransac
from apcc_graph.frontend.eliminant import common_psi
from apcc_graph.frontend.geometry import SegmentTwoView, essential_matrix, sampson_error
from apcc_graph.frontend.pair_roots import PairSetup, pair_eliminant
from apcc_graph.frontend.spatial_basis import (
    bend_transform,
    spatial_coefficients,
    spatial_constraint,
)
from apcc_graph.model.bending import bending_transform, bending_vector
from apcc_graph.model.kinematics import apcc_transform
from apcc_graph.model.segment import Segment

FOCAL = 500.0
HALF_FOV = (0.64, 0.48)


# ------------------------------------------------------------------------------------ helpers


def random_case(rng: np.random.Generator, fixed_base: bool | None = None,
                step: tuple[float, float] = (1.0, 6.0)) -> dict:
    """A random segment (k in (0.1, 0.4)), frame a's bend within 80% of theta_max at any psi,
    a bending-vector step of 1-6 degrees in any direction, a random mounting and, half of the
    time, a random base motion."""
    theta_max = math.radians(rng.uniform(30.0, 120.0))
    segment = Segment(rng.uniform(0.1, 0.5), rng.uniform(0.1, 0.4),
                      rng.uniform(-0.15, 0.15) * theta_max, theta_max)
    while True:
        theta_a = rng.uniform(-0.8, 0.8) * theta_max
        psi_a = rng.uniform(0.0, 2.0 * math.pi)
        b_a = np.array(bending_vector(theta_a, psi_a))
        size, angle = math.radians(rng.uniform(*step)), rng.uniform(0.0, 2.0 * math.pi)
        b_b = b_a + size * np.array([math.cos(angle), math.sin(angle)])
        if np.hypot(*b_b) < theta_max:
            break
    fixed = rng.random() < 0.5 if fixed_base is None else fixed_base
    return {"theta_a": theta_a, "psi_a": psi_a, "segment": segment, "b_a": b_a, "b_b": b_b,
            "tip_T_cam": random_pose(rng, 0.2, 0.02) if rng.random() < 0.7 else None,
            "baseA_T_baseB": None if fixed else random_pose(rng, 0.03, 0.01)}


def true_pose(case: dict, b: np.ndarray | None = None) -> np.ndarray:
    """camA_T_camB from the model's own transforms (independent of the solver's algebra)."""
    b = case["b_b"] if b is None else b
    tip = np.eye(4) if case["tip_T_cam"] is None else case["tip_T_cam"]
    base = np.eye(4) if case["baseA_T_baseB"] is None else case["baseA_T_baseB"]
    Ta = apcc_transform(case["theta_a"], case["segment"], case["psi_a"])
    Tb = bending_transform(b[0], b[1], case["segment"])
    return np.linalg.inv(tip) @ np.linalg.inv(Ta) @ base @ Tb @ tip


def bearings(rng: np.random.Generator, case: dict, n: int, noise_px: float = 0.0,
             outliers: float = 0.0, depth: tuple[float, float] = (0.3, 4.0)
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(f_a, f_b, is_outlier)``: points at the given depths in camera a's view, seen by b."""
    pose = true_pose(case)
    rows = []
    while sum(len(r) for r in rows) < n:
        z = rng.uniform(*depth, 4 * n)
        P = np.column_stack([rng.uniform(-HALF_FOV[0], HALF_FOV[0], 4 * n) * z,
                             rng.uniform(-HALF_FOV[1], HALF_FOV[1], 4 * n) * z, z])
        in_b = (P - pose[:3, 3]) @ pose[:3, :3]
        rows.append(P[in_b[:, 2] > 0.05])
    P = np.vstack(rows)[:n]
    P_b = (P - pose[:3, 3]) @ pose[:3, :3]
    f_a, f_b = (x / np.linalg.norm(x, axis=1, keepdims=True) for x in (P, P_b))
    if noise_px:
        f_a, f_b = (_pixels_noise(rng, f, noise_px) for f in (f_a, f_b))
    is_out = np.zeros(n, dtype=bool)
    k = int(round(outliers * n))
    if k:
        chosen = rng.choice(n, k, replace=False)
        is_out[chosen] = True
        uv = np.column_stack([rng.uniform(-HALF_FOV[0], HALF_FOV[0], k),
                              rng.uniform(-HALF_FOV[1], HALF_FOV[1], k), np.ones(k)])
        f_b[chosen] = uv / np.linalg.norm(uv, axis=1, keepdims=True)
    return f_a, f_b, is_out


def _pixels_noise(rng: np.random.Generator, f: np.ndarray, sigma: float) -> np.ndarray:
    uv = FOCAL * f[:, :2] / f[:, 2:3] + rng.normal(0.0, sigma, (len(f), 2))
    rays = np.column_stack([uv / FOCAL, np.ones(len(f))])
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def solve(case: dict, f_a: np.ndarray, f_b: np.ndarray, **kw: object) -> np.ndarray:
    return two_point(case["theta_a"], case["psi_a"], case["segment"], case["tip_T_cam"],
                     case["baseA_T_baseB"], f_a, f_b, **kw)


def as_vectors(roots: np.ndarray) -> np.ndarray:
    return np.column_stack(bending_vector(roots[:, 0], roots[:, 1]))


def distance_to(roots: np.ndarray, b: np.ndarray) -> float:
    return float(np.min(np.hypot(*(as_vectors(roots) - b).T))) if len(roots) else math.inf


@functools.cache
def random_runs(seed: int, count: int) -> tuple[tuple, ...]:
    """``(case, f_a, f_b, roots)`` of ``count`` noise-free random cases (computed once)."""
    rng = np.random.default_rng(seed)
    runs = []
    for _ in range(count):
        case = random_case(rng)
        f_a, f_b, _ = bearings(rng, case, 2)
        runs.append((case, f_a, f_b, solve(case, f_a, f_b)))
    return tuple(runs)


# ------------------------------------------------------------------------------- the solver


def test_the_true_bend_is_among_the_roots_of_at_least_99_5_percent_of_1000_cases() -> None:
    runs = random_runs(7, 1000)
    found = [distance_to(roots, case["b_b"]) < 1e-6 for case, _, _, roots in runs]
    assert np.mean(found) >= 0.995, f"{np.sum(found)} of {len(found)}"
    assert np.mean([len(r) for *_, r in runs]) < 6  # a handful of roots, not a flood


def test_every_root_solves_both_constraints_and_the_trivial_root_is_never_returned() -> None:
    checked = trivial = 0
    for case, f_a, f_b, roots in random_runs(7, 1000)[:300]:
        assert roots.shape[1] == 2 and np.all(roots[:, 0] >= 0.0)
        assert np.all(roots[:, 0] <= case["segment"].theta_max * (1 + 1e-12))
        assert np.all((roots[:, 1] > -math.pi) & (roots[:, 1] <= math.pi))
        assert np.all(np.diff(roots[:, 0]) >= 0.0)
        for b in as_vectors(roots):
            errors = sampson_error(f_a, f_b, essential_matrix(true_pose(case, b)))
            assert np.max(np.abs(errors)) < 1e-9
            checked += 1
        if case["baseA_T_baseB"] is None:
            trivial += 1
            assert np.min(np.hypot(*(as_vectors(roots) - case["b_a"]).T), initial=1.0) > 1e-7
    assert checked > 300 and trivial > 100


def test_through_straight() -> None:
    rng = np.random.default_rng(3)
    for fixed in (True, False):
        case = random_case(rng, fixed_base=fixed)
        case["theta_a"], case["psi_a"] = math.radians(0.5), 0.0
        case["b_a"] = np.array([math.radians(0.5), 0.0])
        case["b_b"] = np.radians([-2.0, 1.0])
        for _ in range(5):
            f_a, f_b, _ = bearings(rng, case, 2)
            roots = solve(case, f_a, f_b)
            assert distance_to(roots, case["b_b"]) < 1e-9
            theta, psi = roots[np.argmin(np.hypot(*(as_vectors(roots) - case["b_b"]).T))]
            assert theta == pytest.approx(math.hypot(2.0, 1.0) * math.pi / 180.0, abs=1e-9)
            assert psi == pytest.approx(math.atan2(1.0, -2.0), abs=1e-8)


@pytest.mark.parametrize("fixed", [True, False])
def test_an_exactly_straight_segment_at_frame_b(fixed: bool) -> None:
    rng = np.random.default_rng(4)
    for _ in range(5):
        case = random_case(rng, fixed_base=fixed)
        case["theta_a"], case["psi_a"] = math.radians(3.0), rng.uniform(0.0, 2.0 * math.pi)
        case["b_a"] = np.array(bending_vector(case["theta_a"], case["psi_a"]))
        case["b_b"] = np.zeros(2)
        f_a, f_b, _ = bearings(rng, case, 2)
        roots = solve(case, f_a, f_b)
        assert distance_to(roots, np.zeros(2)) < 1e-9
        assert np.min(roots[:, 0]) < 1e-9 and roots[np.argmin(roots[:, 0]), 1] == 0.0


def test_a_planar_case_agrees_with_the_1_point_solver() -> None:
    rng = np.random.default_rng(5)
    for _ in range(20):
        case = random_case(rng)
        case["psi_a"] = 0.0
        case["b_a"] = np.array([case["theta_a"], 0.0])
        case["b_b"] = np.array([case["theta_a"] + math.radians(rng.uniform(1.0, 5.0))
                                * rng.choice([-1.0, 1.0]), 0.0])
        f_a, f_b, _ = bearings(rng, case, 2)
        roots = solve(case, f_a, f_b)
        ones = one_point(f_a, f_b, case["theta_a"], case["segment"], case["tip_T_cam"],
                         case["baseA_T_baseB"])
        # In the plane (psi = 0 or pi), a 2-point root is a root of both correspondences.
        planar = [t if abs(p) < 1e-6 else -t for t, p in roots
                  if min(abs(p), abs(abs(p) - math.pi)) < 1e-6 or t < 1e-12]
        first, second = (row[np.isfinite(row)] for row in ones)
        common = [t for t in first if np.min(np.abs(second - t), initial=np.inf) < 1e-8]
        assert any(abs(t - case["b_b"][0]) < 1e-8 for t in planar)
        for t in planar:
            assert np.min(np.abs(np.asarray(common) - t), initial=np.inf) < 1e-7
        for t in common:
            assert np.min(np.abs(np.asarray(planar) - t), initial=np.inf) < 1e-7


def test_the_eliminant_vanishes_at_the_true_bend_and_its_kernel_gives_psi() -> None:
    rng = np.random.default_rng(6)
    case = random_case(rng, fixed_base=False)
    f_a, f_b, _ = bearings(rng, case, 2)
    setup = PairSetup.build(case["theta_a"], case["psi_a"], case["segment"], case["tip_T_cam"],
                            case["baseA_T_baseB"])
    coef = spatial_coefficients(f_a, f_b, setup.view)[None]
    theta = np.hypot(*case["b_b"])
    D, B, _ = pair_eliminant(setup, coef, np.array([theta, theta + 1e-3]))
    assert abs(D[0]) < 1e-9 * abs(D[1])
    assert common_psi(B[:1])[0] == pytest.approx(math.atan2(case["b_b"][1], case["b_b"][0]),
                                                 abs=1e-7)


@st.composite
def segments(draw: st.DrawFn) -> Segment:
    theta_max = draw(st.floats(0.3, math.pi))
    return Segment(draw(st.floats(0.05, 1.0)), draw(st.floats(0.1, 0.4)),
                   draw(st.floats(-0.5, 0.5)) * theta_max, theta_max)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(segments(), st.floats(-1.0, 1.0), st.floats(-1.0, 1.0), st.integers(0, 2**31))
def test_the_expansion_is_exact(segment: Segment, u: float, v: float, seed: int) -> None:
    """g = sum_k F_k(theta) P_k(u, v) equals f_a . (t x R f_b) everywhere, through straight."""
    rng = np.random.default_rng(seed)
    u, v = u * segment.theta_max * 0.7, v * segment.theta_max * 0.7
    view = SegmentTwoView.build(rng.uniform(-1.0, 1.0), segment, random_pose(rng, 0.3, 0.05),
                                random_pose(rng, 0.1, 0.05), rng.uniform(-3.0, 3.0))
    f_a, f_b = (x / np.linalg.norm(x, axis=1, keepdims=True) for x in rng.normal(size=(2, 4, 3)))
    coef = spatial_coefficients(f_a, f_b, view)
    for b in ((u, v), (0.0, 0.0), (1e-9 * u, 0.0)):
        E = essential_matrix(view.left @ bending_transform(*b, segment) @ view.right)
        direct = np.einsum("ni,ij,nj->n", f_a, E, f_b)
        np.testing.assert_allclose(spatial_constraint(coef, *b, segment), direct, atol=1e-14)


@settings(max_examples=60, deadline=None, derandomize=True)
@given(segments(), st.floats(-1.0, 1.0), st.floats(-1.0, 1.0),
       st.sampled_from([1.0, 1e-3, 1e-9, 0.0]))
def test_the_bend_transform_and_its_derivatives(segment: Segment, u: float, v: float,
                                                scale: float) -> None:
    u, v = u * segment.theta_max * scale, v * segment.theta_max * scale
    T, du, dv = bend_transform(u, v, segment)
    np.testing.assert_allclose(T, bending_transform(u, v, segment), atol=1e-14)
    h = 1e-6
    num_u = (bending_transform(u + h, v, segment) - bending_transform(u - h, v, segment)) / 2 / h
    num_v = (bending_transform(u, v + h, segment) - bending_transform(u, v - h, segment)) / 2 / h
    np.testing.assert_allclose(du, num_u, atol=1e-8)
    np.testing.assert_allclose(dv, num_v, atol=1e-8)


def test_the_solver_refuses_bad_input_clearly() -> None:
    case = random_case(np.random.default_rng(8))
    f = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0]])
    with pytest.raises(ValueError, match=r"expected \(2, 3\)"):
        solve(case, np.vstack([f, f]), np.vstack([f, f]))
    with pytest.raises(ValueError, match="same"):
        solve(case, f, f[:1])
    with pytest.raises(ValueError, match="finite"):
        solve(case, f * np.nan, f)
    with pytest.raises(ValueError, match="theta_a"):
        two_point(math.nan, 0.0, case["segment"], None, None, f, f)
    with pytest.raises(ValueError, match="grid_step"):
        solve(case, f, f, grid_step=0.0)


# ---------------------------------------------------------------------------------- RANSAC


def ransac(case: dict, f_a: np.ndarray, f_b: np.ndarray, **kw: object):
    kw.setdefault("threshold", 1.0 / FOCAL)
    return two_point_ransac(case["theta_a"], case["psi_a"], case["segment"], case["tip_T_cam"],
                            case["baseA_T_baseB"], f_a, f_b, **kw)


@pytest.mark.parametrize("seed", range(6))
def test_ransac_with_outliers_and_noise(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    case = random_case(rng, step=(3.0, 6.0))
    f_a, f_b, is_out = bearings(rng, case, 200, noise_px=0.5, outliers=0.1, depth=(1.0, 4.0))
    bend, info = ransac(case, f_a, f_b, rng=np.random.default_rng(seed))
    assert info.success and info.status == "ok"
    b = np.array(bending_vector(*bend))
    assert np.hypot(*(b - case["b_b"])) < math.radians(0.3)
    # Outliers flagged (a random point near the epipole, or near its epipolar line, can pass
    # for an inlier: 0-2 of the 20 here), inliers kept.
    assert np.mean(info.inliers[is_out]) <= 0.1
    assert np.mean(info.inliers[~is_out]) > 0.95
    assert info.iterations >= 5 and info.hypotheses >= 1
    assert info.errors.shape == (200,)


def test_ransac_is_deterministic_for_a_seed_and_ignores_nan_rows() -> None:
    rng = np.random.default_rng(9)
    case = random_case(rng, step=(3.0, 6.0))
    f_a, f_b, _ = bearings(rng, case, 80, noise_px=0.5, outliers=0.1, depth=(1.0, 4.0))
    first = ransac(case, f_a, f_b, rng=np.random.default_rng(1))
    second = ransac(case, f_a, f_b, rng=np.random.default_rng(1))
    np.testing.assert_array_equal(first[0], second[0])
    np.testing.assert_array_equal(first[1].inliers, second[1].inliers)
    f_a[3] = np.nan
    bend, info = ransac(case, f_a, f_b, rng=np.random.default_rng(1))
    assert info.success and not info.inliers[3] and math.isnan(info.errors[3])


def test_ransac_refusals() -> None:
    rng = np.random.default_rng(10)
    case = random_case(rng, fixed_base=True)
    f_a, f_b, _ = bearings(rng, case, 30)
    bend, info = ransac(case, f_a[:3], f_b[:3])
    assert info.status == "too-few-correspondences" and np.all(np.isnan(bend))
    bend, info = ransac(case, f_a, f_a)  # the camera did not move
    assert info.status == "no-motion" and not info.success
    noise = rng.normal(size=(30, 3))
    bend, info = ransac(case, f_a, noise / np.linalg.norm(noise, axis=1, keepdims=True),
                        max_iterations=16)
    assert not info.success and info.status == "no-consensus"


@pytest.mark.parametrize(("kw", "match"), [
    ({"threshold": 0.0}, "threshold"), ({"threshold": math.nan}, "threshold"),
    ({"confidence": 1.0}, "confidence"), ({"batch": 0}, "batch"),
    ({"max_iterations": 0}, "max_iterations"), ({"engine": "cuda"}, "engine")])
def test_ransac_refuses_bad_arguments_by_name(kw: dict, match: str) -> None:
    case = random_case(np.random.default_rng(11))
    f = np.tile([0.0, 0.0, 1.0], (10, 1))
    with pytest.raises(ValueError, match=match):
        ransac(case, f, f, **kw)


def test_ransac_refuses_bad_shapes_and_types() -> None:
    case = random_case(np.random.default_rng(12))
    f = np.tile([0.0, 0.0, 1.0], (10, 1))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        ransac(case, f.T, f.T)
    with pytest.raises(TypeError, match="Segment"):
        two_point_ransac(0.1, 0.0, "segment", None, None, f, f)
    with pytest.raises(ValueError, match="psi_a"):
        two_point_ransac(0.1, math.inf, case["segment"], None, None, f, f)
