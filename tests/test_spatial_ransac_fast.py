"""The compiled 2-point RANSAC held to its numpy reference: every kernel on seeded random cases
(fixed and moving bases, random mountings and segments), and whole RANSAC calls (the same
estimate, inliers, pairs drawn, hypotheses and refusals)."""

from __future__ import annotations

import hashlib
import inspect
import math
from pathlib import Path

import numpy as np
import pytest
from test_two_point import FOCAL, bearings, random_case

from apcc_graph.frontend import pair_jit, ransac_jit, spatial_basis, spatial_jit, two_point_ransac
from apcc_graph.frontend.pair_jit import (
    bezout_matrix,
    coefficients,
    grid_functions,
    grid_nodes,
    left_part,
    pair_on_grid,
)
from apcc_graph.frontend.pair_roots import SMALL_BEND, PairSetup, _grid, grid_eliminant
from apcc_graph.frontend.ransac_jit import _best_of, batch_hypotheses, pairs_of
from apcc_graph.frontend.spatial_basis import (
    bend_transform,
    bending_sampson,
    spatial_coefficients,
)
from apcc_graph.frontend.spatial_jit import (
    CHUNK,
    bend_matrices,
    essential_matrices,
    msac_score,
    refine,
    sampson_errors,
    segment_parameters,
)
from apcc_graph.frontend.spatial_ransac import (
    RANSAC_GRID_STEP,
    _draws,
    _pairs,
    quick_roots,
    refine_bending,
)
from apcc_graph.frontend.two_point import TRIVIAL_TOLERANCE

THRESHOLD = 1.0 / FOCAL


def frame_pair(case: dict) -> tuple[PairSetup, dict]:
    """The reference set-up of a case and the compiled kernels' view of the same frame pair."""
    setup = PairSetup.build(case["theta_a"], case["psi_a"], case["segment"], case["tip_T_cam"],
                            case["baseA_T_baseB"], RANSAC_GRID_STEP)
    seg = segment_parameters(case["segment"])
    tip = np.eye(4) if case["tip_T_cam"] is None else case["tip_T_cam"]
    base = np.eye(4) if case["baseA_T_baseB"] is None else case["baseA_T_baseB"]
    anchor = math.nan if setup.anchor is None else setup.anchor
    grid = grid_nodes(SMALL_BEND, case["segment"].theta_max, anchor, RANSAC_GRID_STEP)
    jit = {"seg": seg, "tip": tip, "anchor": anchor, "grid": grid,
           "left": left_part(case["theta_a"], case["psi_a"], seg, tip, base),
           "Ft": grid_functions(grid, seg)}
    return setup, jit


def scaled_coefficients(f_a: np.ndarray, f_b: np.ndarray, setup: PairSetup) -> np.ndarray:
    coef = spatial_coefficients(f_a, f_b, setup.view)
    return coef / np.max(np.abs(coef), axis=(1, 2), keepdims=True)


def noisy_case(seed: int, n: int = 200, **kw: object) -> tuple[dict, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    case = random_case(rng, step=(3.0, 6.0), **kw)
    f_a, f_b, _ = bearings(rng, case, n, noise_px=0.5, outliers=0.1, depth=(1.0, 4.0))
    return case, f_a, f_b


# ------------------------------------------------------------------------------- the kernels


def digest(*texts: str) -> str:
    return hashlib.sha256("".join(texts).encode()).hexdigest()[:16]


def test_each_kernel_module_records_the_sources_it_compiles_in() -> None:
    """numba's cache knows each file's own text only: every kernel module carries a digest of
    the other sources its kernels compile in, so that changing those changes it too."""
    def text(module: object) -> str:
        return Path(module.__file__).read_text()

    series = (spatial_basis._sinc, spatial_basis._odd_ratio, spatial_basis._even_ratio)
    expected = {spatial_jit: digest(*(inspect.getsource(f) for f in series)),
                pair_jit: digest(text(spatial_jit)),
                ransac_jit: digest(text(pair_jit), text(spatial_jit))}
    stale = [f"{module.__name__}.DEPENDS = {value!r}" for module, value in expected.items()
             if module.DEPENDS != value]
    assert not stale, f"set {stale[0]}, then run this test again (the next may change)"



@pytest.mark.parametrize("seed", range(8))
def test_fixed_parts_grid_and_functions_match_the_reference(seed: int) -> None:
    case = random_case(np.random.default_rng(seed), fixed_base=seed % 2 == 0)
    setup, jit = frame_pair(case)
    np.testing.assert_allclose(jit["left"], setup.view.left, rtol=0.0, atol=1e-12)
    assert jit["grid"].shape == setup.grid.shape
    np.testing.assert_allclose(jit["grid"], setup.grid, rtol=0.0, atol=1e-15)
    np.testing.assert_allclose(jit["Ft"], setup.functions.T, rtol=0.0, atol=1e-14)


@pytest.mark.parametrize("anchor", [math.nan, 0.0, SMALL_BEND + 1e-9, 0.3, 0.9999, 1.0, 2.0])
def test_grid_nodes_match_the_reference_anchor_anywhere(anchor: float) -> None:
    step = math.radians(2.0)
    ours = grid_nodes(SMALL_BEND, 1.0, anchor, step)
    theirs = _grid(SMALL_BEND, 1.0, None if math.isnan(anchor) else anchor, step)
    np.testing.assert_array_equal(ours, theirs)
    assert np.all(np.diff(ours) > 0.0)


@pytest.mark.parametrize("u, v", [(0.0, 0.0), (1e-9, -2e-9), (0.3, -0.2), (-0.9, 0.1)])
def test_the_bend_and_its_derivatives_match_the_reference(u: float, v: float) -> None:
    case = random_case(np.random.default_rng(3))
    seg = segment_parameters(case["segment"])
    np.testing.assert_allclose(bend_matrices(u, v, seg, True),
                               np.stack(bend_transform(u, v, case["segment"])), atol=1e-15)


@pytest.mark.parametrize("seed", range(4))
def test_coefficients_and_grid_eliminant_match_the_reference(seed: int) -> None:
    rng = np.random.default_rng(20 + seed)
    case = random_case(rng, fixed_base=seed % 2 == 0)
    f_a, f_b, _ = bearings(rng, case, 30)
    setup, jit = frame_pair(case)
    coef = scaled_coefficients(f_a, f_b, setup)
    W = np.empty((30, 9, 6))
    for i in range(30):
        coefficients(f_a[i], f_b[i], jit["left"], jit["tip"], W[i])
    np.testing.assert_allclose(W, coef, rtol=0.0, atol=1e-14)
    pairs = _pairs(_draws(rng, 12), 30)
    D_ref, B_ref = grid_eliminant(setup, coef[pairs])  # (G, S), (G, S, 4, 4)
    G = len(setup.grid)
    for s, (i, j) in enumerate(pairs):
        D, B = np.empty(G), np.empty((10, G))
        pair_on_grid(W[i], W[j], jit["Ft"], jit["grid"], D, B)
        if setup.anchor is not None:
            D /= jit["grid"] - setup.anchor
        scale = np.max(np.abs(B_ref[:, s]))
        for g in range(G):
            np.testing.assert_allclose(bezout_matrix(B[:, g]), B_ref[g, s], rtol=0.0,
                                       atol=1e-13 * scale)
        np.testing.assert_allclose(D, D_ref[:, s], rtol=0.0,
                                   atol=1e-11 * np.max(np.abs(D_ref[:, s])))
        assert np.array_equal(D > 0.0, D_ref[:, s] > 0.0)  # the same brackets


@pytest.mark.parametrize("seed", range(6))
def test_hypotheses_match_the_reference_quick_roots(seed: int) -> None:
    rng = np.random.default_rng(40 + seed)
    case = random_case(rng, fixed_base=seed % 2 == 0, step=(3.0, 6.0))
    f_a, f_b, _ = bearings(rng, case, 40, depth=(1.0, 4.0))
    setup, jit = frame_pair(case)
    pairs = _pairs(_draws(rng, 64), 40)
    for straight in (True, False):
        ours = batch_hypotheses(pairs, f_a, f_b, jit["left"], jit["tip"], jit["grid"],
                                jit["Ft"], jit["anchor"], setup.b_a, straight,
                                TRIVIAL_TOLERANCE)
        theirs = quick_roots(setup, scaled_coefficients(f_a, f_b, setup)[pairs], straight)
        assert ours.shape == theirs.shape and len(ours) > 64
        np.testing.assert_allclose(ours, theirs, rtol=0.0, atol=1e-9)
    # Noise-free pairs: the true bend is among the hypotheses, to the secant's error on a 2 deg
    # grid.
    assert np.min(np.hypot(*(ours - case["b_b"]).T)) < math.radians(0.5)


@pytest.mark.parametrize("seed", range(4))
def test_errors_scores_and_refinement_match_the_reference(seed: int) -> None:
    case, f_a, f_b = noisy_case(60 + seed, fixed_base=seed % 2 == 0)
    setup, jit = frame_pair(case)
    ca, cb = np.ascontiguousarray(f_a.T), np.ascontiguousarray(f_b.T)
    b = case["b_b"] + np.radians([0.3, -0.2])
    E = essential_matrices(jit["left"], jit["tip"], bend_matrices(b[0], b[1], jit["seg"],
                                                                  False))[0]
    errors = bending_sampson(f_a, f_b, setup.view, b[:1], b[1:])[0]
    np.testing.assert_allclose(sampson_errors(E, ca, cb), errors, rtol=1e-12, atol=1e-16)
    thr2 = THRESHOLD**2
    full = float(np.minimum(errors**2, thr2).sum())
    scratch = np.empty(CHUNK)
    assert msac_score(E, ca, cb, thr2, math.inf, scratch) == pytest.approx(full, rel=1e-12)
    # Abandoned early: above the bound, at most the full score, and not all of it.
    partial = msac_score(E, ca, cb, thr2, 0.1 * full, scratch)
    assert 0.1 * full < partial < full
    for steps in (1, 3):
        u, v, e = refine(jit["left"], jit["tip"], jit["seg"], ca, cb, b[0], b[1], THRESHOLD,
                         steps)
        b_ref, e_ref = refine_bending(f_a, f_b, setup, b, THRESHOLD, steps)
        np.testing.assert_allclose([u, v], b_ref, rtol=0.0, atol=1e-12)
        np.testing.assert_allclose(e, e_ref, rtol=1e-9, atol=1e-15)
    assert np.hypot(u - case["b_b"][0], v - case["b_b"][1]) < math.radians(0.3)


def test_early_exit_keeps_the_first_best_hypothesis() -> None:
    case, f_a, f_b = noisy_case(70)
    setup, jit = frame_pair(case)
    ca, cb = np.ascontiguousarray(f_a.T), np.ascontiguousarray(f_b.T)
    rng = np.random.default_rng(0)
    hyps = case["b_b"] + rng.normal(0.0, 0.02, (12, 2))
    hyps[7] = hyps[3] = case["b_b"]  # a tie: the first wins, as numpy's argmin
    scores = np.minimum(bending_sampson(f_a, f_b, setup.view, hyps[:, 0], hyps[:, 1]) ** 2,
                        THRESHOLD**2).sum(axis=1)
    args = (ca, cb, jit["left"], jit["tip"], jit["seg"], THRESHOLD**2)
    j, low = _best_of(hyps, *args, math.inf)
    assert j == int(np.argmin(scores)) == 3 and low == pytest.approx(scores[3], rel=1e-12)
    assert _best_of(hyps, *args, 0.5 * scores.min()) == (-1, math.inf)


def test_pairs_are_distinct_uniform_and_the_same_in_both_engines() -> None:
    draws = _draws(np.random.default_rng(1), 42_000)
    pairs = _pairs(draws, 7)
    np.testing.assert_array_equal(pairs_of(draws, 7), pairs)
    assert np.all(pairs[:, 0] != pairs[:, 1]) and pairs.min() == 0 and pairs.max() == 6
    counts = np.bincount(7 * pairs[:, 0] + pairs[:, 1], minlength=49).reshape(7, 7)
    off = counts[~np.eye(7, dtype=bool)]
    assert np.all(np.abs(off - 1000) < 150)  # 42 ordered pairs, 1000 each expected


# ------------------------------------------------------------------------- whole RANSAC calls


def both_engines(case: dict, f_a: np.ndarray, f_b: np.ndarray, seed: int = 0, **kw: object):
    out = []
    for engine in ("numba", "numpy"):
        rng = np.random.default_rng(seed)
        bend, info = two_point_ransac(case["theta_a"], case["psi_a"], case["segment"],
                                      case["tip_T_cam"], case["baseA_T_baseB"], f_a, f_b,
                                      threshold=THRESHOLD, rng=rng, engine=engine, **kw)
        out.append((bend, info, rng.integers(0, 1 << 30)))  # and where the generator is
    return out


def assert_same(runs: list) -> None:
    (bend, info, after), (bend_ref, info_ref, after_ref) = runs
    assert (info.status, info.success) == (info_ref.status, info_ref.success)
    assert (info.iterations, info.hypotheses) == (info_ref.iterations, info_ref.hypotheses)
    assert info.n_inliers == info_ref.n_inliers and after == after_ref
    np.testing.assert_array_equal(info.inliers, info_ref.inliers)
    np.testing.assert_allclose(bend, bend_ref, rtol=0.0, atol=1e-10)
    if info_ref.errors is not None:
        np.testing.assert_allclose(info.errors, info_ref.errors, rtol=1e-8, atol=1e-14)


@pytest.mark.parametrize("seed", range(10))
def test_the_engines_agree_on_noisy_cases_with_outliers(seed: int) -> None:
    case, f_a, f_b = noisy_case(80 + seed, fixed_base=seed % 2 == 0)
    runs = both_engines(case, f_a, f_b, seed)
    assert_same(runs)
    bend, info, _ = runs[0]
    assert info.success
    b = np.array([bend[0] * math.cos(bend[1]), bend[0] * math.sin(bend[1])])
    assert np.hypot(*(b - case["b_b"])) < math.radians(0.3)


def test_the_engines_agree_with_nan_rows_small_batches_and_few_rows() -> None:
    case, f_a, f_b = noisy_case(90, n=60)
    f_a[[2, 17]] = np.nan
    f_b[40, 1] = np.nan
    assert_same(both_engines(case, f_a, f_b, batch=3))
    assert_same(both_engines(case, f_a[:12], f_b[:12], min_inliers=4))


def test_the_engines_refuse_alike() -> None:
    case, f_a, f_b = noisy_case(91, n=30, fixed_base=True)
    for kw in ({"f_b": f_a}, {"f_a": f_a[:3], "f_b": f_b[:3]}):  # no motion; too few rows
        args = {"f_a": f_a, "f_b": f_b} | kw
        runs = both_engines(case, args["f_a"], args["f_b"])
        assert runs[0][1].status in ("no-motion", "too-few-correspondences")
        assert_same(runs)
    noise = np.random.default_rng(3).normal(size=(30, 3))
    noise /= np.linalg.norm(noise, axis=1, keepdims=True)
    runs = both_engines(case, f_a, noise, max_iterations=16)
    assert runs[0][1].status == "no-consensus"
    assert_same(runs)


@pytest.mark.parametrize("engine", ["numba", "numpy"])
@pytest.mark.parametrize("bad", [np.zeros((4, 4)), np.diag([1.0, 1.0, 0.0, 1.0]),
                                 np.full((4, 4), np.nan)], ids=["zeros", "singular", "nan"])
def test_a_transform_that_is_not_rigid_is_refused_by_name(engine: str, bad: np.ndarray) -> None:
    """Before, the compiled engine raised ZeroDivisionError, the reference LinAlgError, and a
    singular base motion gave a 'successful' straight bend."""
    case, f_a, f_b = noisy_case(92, n=30)
    for name in ("tip_T_cam", "baseA_T_baseB"):
        args = {"tip_T_cam": case["tip_T_cam"], "baseA_T_baseB": case["baseA_T_baseB"]}
        args[name] = bad
        with pytest.raises(ValueError, match=name):
            two_point_ransac(case["theta_a"], case["psi_a"], case["segment"], args["tip_T_cam"],
                             args["baseA_T_baseB"], f_a, f_b, threshold=THRESHOLD,
                             engine=engine)
