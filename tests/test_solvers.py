"""The 1-point solver (all roots, trivial root excluded) and 1-point RANSAC around it."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
from helpers import random_pose

from apcc_graph.frontend.geometry import (
    SegmentTwoView,
    epipolar_errors,
    essential_matrix,
    relative_camera_pose,
)
from apcc_graph.frontend.one_point import one_point
from apcc_graph.frontend.ransac import one_point_ransac, refine_theta
from apcc_graph.frontend.roots import DEFAULT_GRID_STEP
from apcc_graph.model.segment import Segment

FOCAL = 500.0
HALF_FOV = (0.64, 0.48)  # tan of the half field of view of a 640x480, f = 500 camera


# ------------------------------------------------------------------------------------ helpers


def random_segment(rng: np.random.Generator, k: float | None = None) -> Segment:
    """k in (0.05, 0.45), delta_max within +/-10 deg, theta_max 10..80 deg."""
    theta_max = math.radians(rng.uniform(10.0, 80.0))
    delta_max = math.radians(rng.uniform(-10.0, 10.0)) * min(1.0, theta_max / math.radians(12.0))
    k = rng.uniform(0.05, 0.45) if k is None else k
    return Segment(rng.uniform(0.1, 0.5), k, delta_max, theta_max)


def random_case(rng: np.random.Generator, moving_base: bool, spatial: bool = False,
                segment: Segment | None = None, tip: bool = True) -> dict:
    """theta_b - theta_a of 0.5..5 degrees either way, random mounting, optional base motion."""
    seg = random_segment(rng) if segment is None else segment
    step = math.radians(rng.uniform(0.5, 5.0)) * rng.choice([-1.0, 1.0])
    theta_a = rng.uniform(-seg.theta_max + abs(step), seg.theta_max - abs(step))
    return {
        "segment": seg,
        "theta_a": theta_a,
        "theta_b": theta_a + step,
        "tip_T_cam": random_pose(rng, 0.2, 0.02) if tip else None,
        "baseA_T_baseB": random_pose(rng, 0.03, 0.01) if moving_base else None,
        "psi": rng.uniform(-math.pi, math.pi) if spatial else 0.0,
    }


def true_pose(case: dict, theta_b: float | np.ndarray | None = None) -> np.ndarray:
    return relative_camera_pose(
        case["theta_a"], case["theta_b"] if theta_b is None else theta_b, case["segment"],
        case["tip_T_cam"], case["baseA_T_baseB"], case["psi"])


def to_pixels(f: np.ndarray) -> np.ndarray:
    return FOCAL * f[:, :2] / f[:, 2:3]


def from_pixels(uv: np.ndarray) -> np.ndarray:
    rays = np.column_stack([uv / FOCAL, np.ones(len(uv))])
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def random_bearings_in_view(rng: np.random.Generator, n: int) -> np.ndarray:
    uv = FOCAL * np.column_stack([rng.uniform(-HALF_FOV[0], HALF_FOV[0], n),
                                  rng.uniform(-HALF_FOV[1], HALF_FOV[1], n)])
    return from_pixels(uv)


def make_bearings(rng: np.random.Generator, case: dict, n: int, noise_px: float = 0.0,
                  outlier_fraction: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(f_a, f_b, is_inlier)`` for n points with z in 2..8 m in camera A's field of view."""
    pose = true_pose(case)
    R, t = pose[:3, :3], pose[:3, 3]
    z = rng.uniform(2.0, 8.0, n)
    P = np.column_stack([rng.uniform(-HALF_FOV[0], HALF_FOV[0], n) * z,
                         rng.uniform(-HALF_FOV[1], HALF_FOV[1], n) * z, z])
    P_b = (P - t) @ R
    f_a = P / np.linalg.norm(P, axis=1, keepdims=True)
    f_b = P_b / np.linalg.norm(P_b, axis=1, keepdims=True)
    if noise_px:
        f_a = from_pixels(to_pixels(f_a) + rng.normal(0.0, noise_px, (n, 2)))
        f_b = from_pixels(to_pixels(f_b) + rng.normal(0.0, noise_px, (n, 2)))
    inlier = np.ones(n, dtype=bool)
    n_out = int(round(outlier_fraction * n))
    if n_out:
        chosen = rng.choice(n, n_out, replace=False)
        f_b[chosen] = random_bearings_in_view(rng, n_out)
        inlier[chosen] = False
    return f_a, f_b, inlier


def solve(case: dict, f_a: np.ndarray, f_b: np.ndarray, **kw: object) -> np.ndarray:
    return one_point(f_a, f_b, case["theta_a"], case["segment"], case["tip_T_cam"],
                     case["baseA_T_baseB"], case["psi"], **kw)


def ransac(case: dict, f_a: np.ndarray, f_b: np.ndarray, **kw: object):
    return one_point_ransac(f_a, f_b, case["theta_a"], case["segment"], case["tip_T_cam"],
                            case["baseA_T_baseB"], psi=case["psi"], **kw)


def reference_roots(case: dict, f_a: np.ndarray, f_b: np.ndarray, n_grid: int = 200001,
                    lo: float | None = None, hi: float | None = None
                    ) -> tuple[list[np.ndarray], float]:
    """Roots of ``g = f_a . (t x R f_b)`` by a dense sign-change scan of relative_camera_pose.

    Returns the mid-points of the grid intervals where g changes sign (the trivial root at
    theta_a excluded for a fixed base) and the grid step.
    """
    lim = case["segment"].theta_max
    grid = np.linspace(-lim if lo is None else lo, lim if hi is None else hi, n_grid)
    step = float(grid[1] - grid[0])
    E = essential_matrix(true_pose(case, grid))
    g = np.einsum("ni,gij,nj->gn", f_a, E, f_b, optimize=True)
    sign = np.sign(g)
    out = []
    for j in range(len(f_a)):
        idx = np.flatnonzero(sign[:-1, j] * sign[1:, j] <= 0)
        mids = 0.5 * (grid[idx] + grid[idx + 1])
        if case["baseA_T_baseB"] is None:
            mids = mids[np.abs(mids - case["theta_a"]) > 3 * step]
        out.append(mids)
    return out, step


def finite(row: np.ndarray) -> np.ndarray:
    return row[np.isfinite(row)]


# ------------------------------------------------------------------------- noise-free roots
@pytest.mark.parametrize("moving_base", [False, True])
def test_true_root_is_among_the_roots_and_trivial_root_is_excluded(moving_base: bool) -> None:
    rng = np.random.default_rng(1 if moving_base else 0)
    n_cases, n_corr = 120, 30
    for i in range(n_cases):
        case = random_case(rng, moving_base, spatial=i % 3 == 2)
        f_a, f_b, _ = make_bearings(rng, case, n_corr)
        roots = solve(case, f_a, f_b)
        assert roots.ndim == 2 and roots.shape[0] == n_corr
        dist = np.min(np.abs(np.where(np.isnan(roots), np.inf, roots - case["theta_b"])), axis=1)
        assert np.all(dist < 1e-9), (i, case, dist.max())
        if not moving_base:
            assert not np.any(np.abs(roots - case["theta_a"]) < 1e-6), (i, case)
            # theta_a genuinely satisfies every correspondence (E = 0): it was excluded.
            assert np.max(np.abs(essential_matrix(true_pose(case, case["theta_a"])))) < 1e-14


def test_roots_satisfy_the_constraint() -> None:
    """Every returned root (not just the true one) zeroes g, checked from relative_camera_pose."""
    rng = np.random.default_rng(2)
    for i in range(20):
        case = random_case(rng, moving_base=i % 2 == 1)
        f_a, f_b, _ = make_bearings(rng, case, 20, noise_px=2.0, outlier_fraction=0.5)
        roots = solve(case, f_a, f_b)
        rows, cols = np.nonzero(np.isfinite(roots))
        E = essential_matrix(true_pose(case, roots[rows, cols]))
        g = np.einsum("ni,nij,nj->n", f_a[rows], E, f_b[rows])
        # Relative to the slope scale |g'| ~ |dt/dtheta| (~ segment length): tiny residuals.
        assert np.max(np.abs(g)) < 1e-13


# ---------------------------------------------------------------------- brute-force reference
@pytest.mark.parametrize("seed", range(6))
def test_roots_match_a_dense_reference_scan(seed: int) -> None:
    rng = np.random.default_rng(10 + seed)
    case = random_case(rng, moving_base=seed % 2 == 1, spatial=seed >= 4)
    f_a, f_b, _ = make_bearings(rng, case, 12, noise_px=1.0)
    # Half the rows: wrong associations, whose constraints have several roots or none.
    f_b[::2] = random_bearings_in_view(rng, 6)
    ref, step = reference_roots(case, f_a, f_b)
    roots = solve(case, f_a, f_b)
    assert sum(len(r) for r in ref) >= 6  # the scan found roots to compare
    for j in range(len(f_a)):
        got = finite(roots[j])
        assert len(got) == len(ref[j]), (j, got, ref[j])
        assert np.all(np.abs(got - ref[j]) <= step), (j, got, ref[j])


def close_root_pairs(seed: int, n_cases: int
                     ) -> list[tuple[dict, np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """Correspondences built to have two roots t1 < t2 a fraction of a grid step apart.

    For a given f_a, ``f_b = (E(t1)^T f_a) x (E(t2)^T f_a)`` satisfies both constraints.
    """
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n_cases):
        case = random_case(rng, moving_base=i % 2 == 1)
        f_a, _, _ = make_bearings(rng, case, 20)
        sep = math.radians(rng.uniform(0.1, 0.9))
        lim = 0.95 * case["segment"].theta_max
        lo, hi = max(-lim, case["theta_a"] - 0.3), min(lim - sep, case["theta_a"] + 0.3)
        t1 = rng.uniform(lo, hi, len(f_a))
        t2 = t1 + sep
        n1 = np.einsum("nij,ni->nj", essential_matrix(true_pose(case, t1)), f_a)
        n2 = np.einsum("nij,ni->nj", essential_matrix(true_pose(case, t2)), f_a)
        f_b = np.cross(n1, n2)
        f_b /= np.linalg.norm(f_b, axis=1, keepdims=True)
        if case["baseA_T_baseB"] is None:  # keep away from the trivial root
            far = np.minimum(np.abs(t1 - case["theta_a"]), np.abs(t2 - case["theta_a"])) > 0.02
            f_a, f_b, t1, t2 = f_a[far], f_b[far], t1[far], t2[far]
        out.append((case, f_a, f_b, t1, t2))
    return out


@functools.cache
def resolved_close_pairs(seed: int, n_cases: int) -> tuple[int, int, tuple]:
    """How many constructed close root pairs the solver returns, checked by a local dense scan.

    For each correspondence g is scanned on 1001 points over ``[t1 - 0.005, t2 + 0.005]``; every
    sign change there must be matched by a returned root within the scan step.
    """
    total, found, missed = 0, 0, []
    for case, f_a, f_b, t1, t2 in close_root_pairs(seed, n_cases):
        roots = solve(case, f_a, f_b)
        # Split pairs are appended to the other roots: the rows must still come out ascending.
        assert not np.any(np.diff(roots, axis=1) < 0)  # NaN differences compare False
        assert np.all(np.diff(np.isnan(roots).astype(int), axis=1) >= 0)  # NaN padding last
        grid = np.linspace(t1 - 0.005, t2 + 0.005, 1001, axis=1)  # (N, G), one grid per row
        step = grid[:, 1] - grid[:, 0]
        E = essential_matrix(true_pose(case, grid))  # (N, G, 3, 3)
        sign = np.sign(np.einsum("ni,ngij,nj->ng", f_a, E, f_b))
        for j in range(len(f_a)):
            idx = np.flatnonzero(sign[j, :-1] * sign[j, 1:] <= 0)
            ref = 0.5 * (grid[j, idx] + grid[j, idx + 1])
            if len(ref) < 2:  # rounding in f_b merged the pair: nothing to check
                continue
            total += 1
            got = finite(roots[j])
            ok = all(np.any(np.abs(got - r) <= step[j]) for r in ref)
            found += ok
            if not ok:
                missed.append((case["theta_a"], ref, got))
    return total, found, tuple(missed)


CLOSE_PAIR_CASES = (7, 40)


def test_root_pairs_closer_than_the_grid_step_are_mostly_resolved() -> None:
    """The extremum search splits most pairs that show no sign change on the 1-degree grid."""
    total, found, _ = resolved_close_pairs(*CLOSE_PAIR_CASES)
    assert total > 600
    assert found >= 0.97 * total


@pytest.mark.xfail(strict=True, reason=(
    "known limitation, documented in apcc_graph/frontend/roots.py: when three roots fall "
    "within one grid step the sign change shows only one of them (5 of 767 deliberately "
    "close root pairs here)"))
def test_every_root_pair_closer_than_the_grid_step_is_resolved() -> None:
    total, found, missed = resolved_close_pairs(*CLOSE_PAIR_CASES)
    assert total > 600
    assert found == total, f"{total - found} of {total} close root pairs missed: {missed[:3]}"


# ---------------------------------------------------------------------------- output contract
def test_output_shape_padding_order_and_range() -> None:
    rng = np.random.default_rng(3)
    widths = set()
    for i in range(30):
        case = random_case(rng, moving_base=i % 2 == 1)
        f_a, f_b, _ = make_bearings(rng, case, 25, noise_px=1.0, outlier_fraction=0.6)
        roots = solve(case, f_a, f_b)
        assert roots.shape[0] == 25 and roots.shape[1] >= 1
        widths.add(roots.shape[1])
        lim = case["segment"].theta_max
        fin = roots[np.isfinite(roots)]
        assert np.all((fin >= -lim) & (fin <= lim))
        for row in roots:
            n = int(np.sum(np.isfinite(row)))
            # Finite roots first (ascending), then NaN padding.
            assert np.all(np.isfinite(row[:n])) and np.all(np.isnan(row[n:]))
            assert np.all(np.diff(row[:n]) > 0)
        assert np.any(np.isfinite(roots).all(axis=1)), "at least one row fills the width"
    assert len(widths) > 1, "the width adapts to the largest number of roots"


def test_nan_bearings_give_a_nan_row() -> None:
    rng = np.random.default_rng(4)
    case = random_case(rng, moving_base=False)
    f_a, f_b, _ = make_bearings(rng, case, 6)
    clean = solve(case, f_a, f_b)
    f_a[1] = np.nan
    f_b[4, 2] = np.nan
    roots = solve(case, f_a, f_b)
    assert np.all(np.isnan(roots[[1, 4]]))
    others = [0, 2, 3, 5]
    np.testing.assert_allclose(finite(roots[others].ravel()), finite(clean[others].ravel()),
                               atol=1e-12)


def test_empty_input_gives_shape_0_by_1() -> None:
    seg = Segment(0.3)
    for base in (None, random_pose(np.random.default_rng(0), 0.01, 0.01)):
        roots = one_point(np.zeros((0, 3)), np.zeros((0, 3)), 0.1, seg, baseA_T_baseB=base)
        assert roots.shape == (0, 1)


def test_mismatched_bearings_raise() -> None:
    rng = np.random.default_rng(5)
    seg = Segment(0.3)
    f = random_bearings_in_view(rng, 5)
    with pytest.raises(ValueError, match="shape"):
        one_point(f, f[:4], 0.1, seg)
    with pytest.raises(ValueError, match="shape"):
        one_point_ransac(f, f[:4], 0.1, seg)


@pytest.mark.parametrize("which", ["transposed", "two_columns"])
def test_bearings_that_are_not_n_by_3_raise(which: str) -> None:
    rng = np.random.default_rng(6)
    seg = Segment(0.3)
    f = random_bearings_in_view(rng, 6)
    f_a, f_b = (f, f.T.copy()) if which == "transposed" else (f[:, :2], f[:, :2])
    with pytest.raises(ValueError):
        one_point(f_a, f_b, 0.1, seg)


# ----------------------------------------------------------------------------- any k, delta
def test_k_quarter_without_deviation_is_not_special() -> None:
    """The paper's case (k = 0.25, delta = 0) is the generic solver's limit, no special path."""
    rng = np.random.default_rng(7)
    for i in range(10):
        seg = Segment(0.3, 0.25, 0.0, math.radians(60.0))
        case = random_case(rng, moving_base=i % 2 == 1, segment=seg)
        f_a, f_b, _ = make_bearings(rng, case, 30)
        roots = solve(case, f_a, f_b)
        dist = np.nanmin(np.abs(roots - case["theta_b"]), axis=1)
        assert np.all(dist < 1e-9)
        for k, delta in ((0.25 + 1e-9, 0.0), (0.25 - 1e-9, 1e-9)):
            near = dict(case, segment=Segment(0.3, k, delta, math.radians(60.0)))
            other = solve(near, f_a, f_b)
            assert other.shape == roots.shape
            np.testing.assert_allclose(other, roots, atol=1e-6)


@pytest.mark.parametrize("k", [0.05, 0.45, 0.01, 0.49])
def test_extreme_k(k: float) -> None:
    rng = np.random.default_rng(int(k * 1000))
    for i in range(20):
        case = random_case(rng, moving_base=i % 2 == 1, segment=random_segment(rng, k=k))
        f_a, f_b, _ = make_bearings(rng, case, 30)
        roots = solve(case, f_a, f_b)
        dist = np.nanmin(np.abs(roots - case["theta_b"]), axis=1)
        assert np.all(dist < 1e-9)


def test_delta_is_kept_exactly() -> None:
    """Data made with a tip deviation are solved exactly only with that deviation."""
    rng = np.random.default_rng(8)
    seg = Segment(0.3, 0.2, math.radians(8.0), math.radians(50.0))
    case = random_case(rng, moving_base=False, segment=seg)
    case["theta_a"], case["theta_b"] = 0.5, 0.5 + math.radians(3.0)
    f_a, f_b, _ = make_bearings(rng, case, 30)
    good = np.nanmin(np.abs(solve(case, f_a, f_b) - case["theta_b"]), axis=1)
    assert np.all(good < 1e-9)
    no_delta = dict(case, segment=Segment(0.3, 0.2, 0.0, math.radians(50.0)))
    bad = np.nanmin(np.abs(solve(no_delta, f_a, f_b) - case["theta_b"]), axis=1)
    assert np.median(bad) > 1e-4


# --------------------------------------------------------------------------------- RANSAC
@pytest.mark.parametrize("seed", range(4))
def test_ransac_with_half_outliers(seed: int) -> None:
    rng = np.random.default_rng(30 + seed)
    case = random_case(rng, moving_base=seed % 2 == 1)
    n = 300
    f_a, f_b, inlier = make_bearings(rng, case, n, noise_px=0.5, outlier_fraction=0.5)
    theta, info = ransac(case, f_a, f_b, rng=np.random.default_rng(seed))
    assert info.success and info.status == "ok"
    assert abs(theta - case["theta_b"]) < math.radians(0.5)
    assert np.mean(info.inliers == inlier) > 0.9
    assert info.n_inliers == int(info.inliers.sum())
    assert 0.35 * n < info.n_inliers < 0.6 * n


def test_ransac_without_outliers_and_info_fields() -> None:
    rng = np.random.default_rng(40)
    case = random_case(rng, moving_base=False)
    n = 200
    f_a, f_b, _ = make_bearings(rng, case, n, noise_px=0.5)
    theta, info = ransac(case, f_a, f_b)
    assert info.success and info.status == "ok"
    assert abs(theta - case["theta_b"]) < math.radians(0.3)
    assert info.inliers.dtype == np.bool_ and info.inliers.shape == (n,)
    assert info.n_inliers >= 0.95 * n
    assert info.iterations >= 1 and info.hypotheses >= 1
    assert math.isfinite(info.score) and info.score >= 0.0
    assert isinstance(info.message, str) and info.message
    assert info.errors.shape == (n,)
    # The score is the MSAC score of the returned theta.
    e = epipolar_errors(f_a, f_b, SegmentTwoView.build(
        case["theta_a"], case["segment"], case["tip_T_cam"], None, case["psi"]), theta)
    threshold = 1.0 / FOCAL
    assert info.score == pytest.approx(float(np.minimum(e**2, threshold**2).sum()), rel=1e-9)
    np.testing.assert_array_equal(info.inliers, np.abs(e) < threshold)


def test_ransac_is_deterministic_for_a_seed() -> None:
    rng = np.random.default_rng(41)
    case = random_case(rng, moving_base=True)
    f_a, f_b, _ = make_bearings(rng, case, 150, noise_px=0.5, outlier_fraction=0.4)
    runs = [ransac(case, f_a, f_b, rng=np.random.default_rng(5)) for _ in range(2)]
    assert runs[0][0] == runs[1][0]
    np.testing.assert_array_equal(runs[0][1].inliers, runs[1][1].inliers)
    assert runs[0][1].iterations == runs[1][1].iterations
    defaults = [ransac(case, f_a, f_b) for _ in range(2)]  # rng=None: seeded default
    assert defaults[0][0] == defaults[1][0]


def test_ransac_sample_count_adapts_to_the_inlier_ratio() -> None:
    rng = np.random.default_rng(46)
    case = random_case(rng, moving_base=False)
    n = 200
    f_a, f_b, _ = make_bearings(rng, case, n, noise_px=0.5, outlier_fraction=0.5)
    confidence = 0.99999
    _, info = ransac(case, f_a, f_b, confidence=confidence)
    assert info.success
    ratio = info.n_inliers / n + 0.05  # generous: fewer samples needed than with the true ratio
    assert info.iterations >= math.log(1 - confidence) / math.log(1 - ratio)
    assert info.iterations <= 1000
    # All inliers: one or two batches suffice.
    f_a, f_b, _ = make_bearings(rng, case, n, noise_px=0.5)
    _, info = ransac(case, f_a, f_b, confidence=confidence, batch=8)
    assert info.success and info.iterations <= 16
    # The cap holds on data without any consensus.
    f_b = random_bearings_in_view(rng, n)
    _, info = ransac(case, f_a, f_b, max_iterations=24, batch=8)
    assert info.iterations <= 24


def test_too_few_inliers_is_no_consensus() -> None:
    rng = np.random.default_rng(47)
    case = random_case(rng, moving_base=True)
    n = 300
    f_a, f_b, _ = make_bearings(rng, case, n, noise_px=0.5, outlier_fraction=0.5)
    theta, info = ransac(case, f_a, f_b, min_inliers=200)
    assert math.isnan(theta)
    assert not info.success and info.status == "no-consensus"
    assert not info.inliers.any()
    assert 100 < info.n_inliers < 200  # the best hypothesis is reported, just not accepted
    theta, info = ransac(case, f_a, f_b, min_inliers=100)
    assert info.success and abs(theta - case["theta_b"]) < math.radians(0.5)


def test_too_few_correspondences() -> None:
    rng = np.random.default_rng(42)
    case = random_case(rng, moving_base=False)
    f_a, f_b, _ = make_bearings(rng, case, 4)
    theta, info = ransac(case, f_a, f_b)  # min_inliers = 5
    assert math.isnan(theta)
    assert not info.success and info.status == "too-few-correspondences"
    assert info.inliers.shape == (4,) and not info.inliers.any()
    theta, info = ransac(case, np.zeros((0, 3)), np.zeros((0, 3)))
    assert math.isnan(theta) and info.status == "too-few-correspondences"
    # NaN rows do not count.
    f_a, f_b, _ = make_bearings(rng, case, 10)
    f_b[:6] = np.nan
    theta, info = ransac(case, f_a, f_b)
    assert math.isnan(theta) and info.status == "too-few-correspondences"
    assert info.inliers.shape == (10,) and not info.inliers.any()


def test_identical_frames_are_no_motion_not_an_invented_angle() -> None:
    rng = np.random.default_rng(43)
    case = random_case(rng, moving_base=False)
    f_a, _, _ = make_bearings(rng, case, 100)
    f_b = from_pixels(to_pixels(f_a) + rng.normal(0.0, 0.3, (100, 2)))
    for fb in (f_a.copy(), f_b):
        theta, info = ransac(case, f_a, fb)
        assert math.isnan(theta)
        assert not info.success and info.status == "no-motion"
        assert not info.inliers.any()


def test_random_correspondences_do_not_report_a_consensus() -> None:
    rng = np.random.default_rng(44)
    for i in range(4):
        case = random_case(rng, moving_base=i % 2 == 1)
        n = 200
        f_a, f_b = random_bearings_in_view(rng, n), random_bearings_in_view(rng, n)
        theta, info = ransac(case, f_a, f_b, rng=np.random.default_rng(i))
        assert info.status in ("ok", "no-consensus")
        assert not (info.success and info.n_inliers > n / 2)
        assert info.n_inliers < 0.2 * n
        if not info.success:
            assert math.isnan(theta) and not info.inliers.any()


def test_nan_rows_are_ignored() -> None:
    rng = np.random.default_rng(45)
    case = random_case(rng, moving_base=True)
    n = 120
    f_a, f_b, _ = make_bearings(rng, case, n, noise_px=0.5, outlier_fraction=0.2)
    bad = rng.choice(n, 20, replace=False)
    f_a[bad[:10]] = np.nan
    f_b[bad[10:], 1] = np.nan
    theta, info = ransac(case, f_a, f_b)
    assert info.success and info.status == "ok"
    assert abs(theta - case["theta_b"]) < math.radians(0.5)
    assert not info.inliers[bad].any()
    assert info.inliers.shape == (n,)
    assert np.all(np.isnan(info.errors[bad]))


# ------------------------------------------------------------------------------ refinement
def huber_cost(e: np.ndarray, threshold: float) -> float:
    r = np.abs(e)
    return float(np.sum(np.where(r <= threshold, 0.5 * r**2, threshold * (r - 0.5 * threshold))))


@pytest.mark.parametrize("seed", range(4))
def test_refine_theta_reduces_the_robust_cost(seed: int) -> None:
    rng = np.random.default_rng(50 + seed)
    case = random_case(rng, moving_base=seed % 2 == 1)
    f_a, f_b, inlier = make_bearings(rng, case, 150, noise_px=0.5, outlier_fraction=0.2)
    view = SegmentTwoView.build(case["theta_a"], case["segment"], case["tip_T_cam"],
                                case["baseA_T_baseB"], case["psi"])
    threshold = 1.0 / FOCAL
    truth = case["theta_b"]
    start = truth + math.radians(0.5) * rng.choice([-1.0, 1.0])

    def cost(theta: float, mask: np.ndarray) -> float:
        return huber_cost(epipolar_errors(f_a[mask], f_b[mask], view, theta), threshold)

    # On the inliers (as RANSAC uses it): to the optimum near the truth.
    refined = refine_theta(f_a[inlier], f_b[inlier], view, start, threshold)
    assert cost(refined, inlier) < cost(start, inlier)
    assert cost(refined, inlier) <= cost(truth, inlier) * (1 + 1e-9)
    assert abs(refined - truth) < math.radians(0.2)
    scan = truth + np.radians(np.linspace(-0.5, 0.5, 201))
    assert cost(refined, inlier) <= min(cost(t, inlier) for t in scan) * (1 + 1e-6)
    # Refining again from the result barely moves it (a stationary point).
    again = refine_theta(f_a[inlier], f_b[inlier], view, refined, threshold)
    assert abs(again - refined) < 1e-6
    # With the outliers in: the robust cost still goes down.
    everything = np.ones(len(f_a), dtype=bool)
    refined_all = refine_theta(f_a, f_b, view, start, threshold)
    assert cost(refined_all, everything) < cost(start, everything)
    # Never outside the segment's range.
    lim = case["segment"].theta_max
    edge = refine_theta(f_a, f_b, view, lim, threshold, iterations=3)
    assert -lim <= edge <= lim


def test_grid_step_constant() -> None:
    assert DEFAULT_GRID_STEP == pytest.approx(math.radians(1.0))


# ------------------------------------------------------------------ basis expansion of E
@pytest.mark.parametrize("moving_base", [False, True])
@pytest.mark.parametrize("psi", [0.0, 0.7])
def test_epipolar_basis_matches_direct_sampson_errors(moving_base: bool, psi: float) -> None:
    """E(theta) = sum_k phi_k(theta) E_k exactly: errors, derivatives and coefficients agree."""
    from apcc_graph.frontend.basis import EpipolarBasis, constraint_coefficients
    from apcc_graph.frontend.geometry import SegmentTwoView, epipolar_errors

    rng = np.random.default_rng(21)
    seg = Segment(0.4, k=0.31, delta_max=math.radians(7.0), theta_max=1.2)
    mount = random_pose(rng, 0.3, 0.05)
    base = random_pose(rng, 0.05, 0.05) if moving_base else None
    f_a = random_bearings_in_view(rng, 40)
    f_b = random_bearings_in_view(rng, 40)
    view = SegmentTwoView.build(0.3, seg, mount, base, psi)
    basis = EpipolarBasis(f_a, f_b, view)
    thetas = np.array([-1.1, -0.2, 0.31, 0.9])
    e_fast, de_fast = basis.errors(thetas, derivative=True)
    e_ref, de_ref = epipolar_errors(f_a, f_b, view, thetas, derivative=True)
    np.testing.assert_allclose(e_fast, e_ref, atol=1e-12)
    np.testing.assert_allclose(de_fast, de_ref, atol=1e-11)
    np.testing.assert_allclose(basis.coef, constraint_coefficients(f_a, f_b, view), atol=1e-14)
