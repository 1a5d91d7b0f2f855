"""The 1-point solver for a segment's angle, and 1-point RANSAC around it.

Problem (docs/estimation.md, "Two frames"). With frame a's angle ``theta_a``, the camera mounting
and the base motion known, one correspondence ``(f_a, f_b)`` gives one equation in the unknown
``theta_b``:
``g(theta_b) = f_a . (t x R f_b) = 0`` with ``(R, t) = camA_T_camB(theta_b)``.

Method (works for every 0 < k < 0.5 and keeps delta exactly). Write
``camA_T_camB = [Rc | tc] . T(theta_b) . [Rm | tm]`` and ``a = Rc^T f_a``, ``w = Rm f_b``,
``d = Rc^T tc``. The segment's rotation turns about a fixed axis ``n`` by
``beta = theta_b - delta(theta_b)``, so by Rodrigues ``u . R_beta v`` is linear in
``(1, cos beta, sin beta)``, and its tip is ``px(theta_b) e1 + pz(theta_b) e3``. Hence exactly

    g(theta) = sum_k c_k phi_k(theta),   phi = [1, cos b, sin b] x [1, px(theta), pz(theta)]

nine basis functions shared by all correspondences, and nine coefficients per correspondence
(cheap vector algebra). Nothing is approximated: ``phi`` are the model's own functions.

- Trivial root: with a fixed base, ``theta_b = theta_a`` makes ``t = 0`` and satisfies every
  correspondence. It is removed exactly by deflation: ``g(theta_a) = 0``, so the other roots are
  those of the divided difference ``h(theta) = (g(theta) - g(theta_a)) / (theta - theta_a)``, a
  smooth function whose basis ``(phi_k(theta) - phi_k(theta_a)) / (theta - theta_a)`` is again
  shared. A true root 0.5 degrees from theta_a is an ordinary simple root of h.
- All roots: h is evaluated for all correspondences at once on a grid over
  ``[-theta_max, theta_max]`` (one matrix product), anchored half a step off theta_a; every sign
  change brackets a root, refined by safeguarded Newton (bisection when a step leaves the bracket)
  to machine precision. Two roots closer than the grid step (default 1 degree) show no sign
  change; they sit on either side of a local extremum of h, so wherever ``|h|`` has a local
  minimum on the grid without a sign change (and a parabola through the three nodes comes near
  zero), the extremum is located (Illinois regula falsi on h') and, if h changes sign there,
  both roots are bracketed. The basis functions vary on the scale of a radian (frequencies
  <= ~2 per radian), so h rarely turns twice within a grid step. What remains: when three roots
  fall within one grid step, the sign change shows one of them and the other two may be missed
  (tests construct such cases: under 1% of deliberately close root pairs; 90,000 random
  correspondences produced none); an exact double root (a tangency, where the correspondence
  carries no information) is reported once or not at all.

Returns follow PoseLib's convention: all admissible roots, padded with NaN.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.frontend.geometry import SegmentTwoView, epipolar_errors, skew
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.kinematics import apcc_in_plane
from apcc_graph.model.segment import Segment

DEFAULT_GRID_STEP = math.radians(1.0)
_NEWTON_ITERATIONS = 40


def _basis(theta: FloatArray, segment: Segment) -> tuple[FloatArray, FloatArray]:
    """``phi_k(theta)`` and ``phi_k'(theta)``, each ``theta.shape + (9,)``."""
    planar = apcc_in_plane(theta, segment)
    cb, sb = np.cos(planar.beta), np.sin(planar.beta)
    rate = planar.dbeta
    one = np.ones_like(cb)
    zero = np.zeros_like(cb)
    rot = (one, cb, sb)
    drot = (zero, -rate * sb, rate * cb)
    S, H, dS, dH = planar.px, planar.pz, planar.dpx, planar.dpz
    phi = np.stack([*rot, *(S * r for r in rot), *(H * r for r in rot)], axis=-1)
    dphi = np.stack([*drot, *(dS * r + S * q for r, q in zip(rot, drot, strict=True)),
                     *(dH * r + H * q for r, q in zip(rot, drot, strict=True))], axis=-1)
    return phi, dphi


def _cross(u: FloatArray, v: FloatArray) -> FloatArray:
    """Row-wise cross products of ``(N, 3)`` arrays (or one row and ``(N, 3)``)."""
    u0, u1, u2 = u[..., 0], u[..., 1], u[..., 2]
    v0, v1, v2 = v[..., 0], v[..., 1], v[..., 2]
    return np.stack([u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0], axis=-1)


def _rodrigues_terms(u: FloatArray, v: FloatArray, n: FloatArray) -> FloatArray:
    """Coefficients of ``u . R_beta v`` on ``(1, cos beta, sin beta)``, ``(N, 3)``.

    ``R_beta v = (n.v) n + cos(beta) (v - (n.v) n) + sin(beta) (n x v)``, and
    ``u . (n x v) = (u x n) . v``.
    """
    un, vn = u @ n, v @ n
    out = np.empty((len(u), 3))
    out[:, 0] = un * vn
    out[:, 1] = np.einsum("ij,ij->i", u, v) - out[:, 0]
    out[:, 2] = np.einsum("ij,ij->i", _cross(u, n), v)
    return out


def constraint_coefficients(f_a: FloatArray, f_b: FloatArray, view: SegmentTwoView) -> FloatArray:
    """The nine coefficients ``c`` of ``g(theta) = c . phi(theta)`` per correspondence, ``(N, 9)``.

    ``g`` is ``f_a . (t x R f_b)`` in metres (the scale of t).
    """
    Rc, tc = view.left[:3, :3], view.left[:3, 3]
    Rm, tm = view.right[:3, :3], view.right[:3, 3]
    a = f_a @ Rc  # Rc^T f_a
    w = f_b @ Rm.T  # Rm f_b
    d = Rc.T @ tc
    cp, sp = math.cos(view.psi), math.sin(view.psi)
    n = np.array([-sp, cp, 0.0])
    e1 = np.array([cp, sp, 0.0])
    e3 = np.array([0.0, 0.0, 1.0])
    coef = np.empty((len(a), 9))
    coef[:, 0:3] = (_rodrigues_terms(a, _cross(tm, w), n)
                    + _rodrigues_terms(_cross(a, d), w, n))
    coef[:, 3:6] = _rodrigues_terms(_cross(a, e1), w, n)
    coef[:, 6:9] = _rodrigues_terms(_cross(a, e3), w, n)
    return coef


class _Function:
    """g, or its deflation h = (g - g(theta_a)) / (theta - theta_a), from the coefficients."""

    def __init__(self, view: SegmentTwoView) -> None:
        self.view = view
        self.deflate = view.fixed_base
        if self.deflate:
            self.phi_a = _basis(np.asarray(view.theta_a), view.segment)[0]

    def grid(self, step: float) -> tuple[FloatArray, FloatArray]:
        """The bracketing grid and the (deflated) basis on it, built once per step."""
        cached = getattr(self, "_grid_cache", None)
        if cached is None or cached[0] != step:
            nodes = _grid(self.view, step)
            cached = self._grid_cache = (step, nodes, self.basis(nodes))
        return cached[1], cached[2]

    def basis(self, theta: FloatArray) -> FloatArray:
        """The (deflated) basis at grid points, ``theta.shape + (9,)``."""
        phi = _basis(theta, self.view.segment)[0]
        if not self.deflate:
            return phi
        return (phi - self.phi_a) / (theta - self.view.theta_a)[..., None]

    def value_and_slope(self, c: FloatArray, theta: FloatArray) -> tuple[FloatArray, FloatArray]:
        """``f(theta)`` and ``f'(theta)`` for one theta per row of ``c`` (column arithmetic)."""
        planar = apcc_in_plane(theta, self.view.segment)
        cb, sb = np.cos(planar.beta), np.sin(planar.beta)
        r = planar.dbeta
        S, H, dS, dH = planar.px, planar.pz, planar.dpx, planar.dpz
        rot = [c[:, 3 * j] + c[:, 3 * j + 1] * cb + c[:, 3 * j + 2] * sb for j in range(3)]
        drot = [r * (c[:, 3 * j + 2] * cb - c[:, 3 * j + 1] * sb) for j in range(3)]
        g = rot[0] + S * rot[1] + H * rot[2]
        dg = drot[0] + dS * rot[1] + S * drot[1] + dH * rot[2] + H * drot[2]
        if not self.deflate:
            return g, dg
        gap = theta - self.view.theta_a
        h = (g - c @ self.phi_a) / gap
        return h, (dg - h) / gap


def _checked_bearings(f_a: ArrayLike, f_b: ArrayLike) -> tuple[FloatArray, FloatArray]:
    f_a = np.asarray(f_a, dtype=float)
    f_b = np.asarray(f_b, dtype=float)
    if f_a.ndim == 1 and f_a.shape == (3,):
        f_a = f_a[None]
    if f_b.ndim == 1 and f_b.shape == (3,):
        f_b = f_b[None]
    if f_a.ndim != 2 or f_a.shape[1] != 3 or f_a.shape != f_b.shape:
        raise ValueError(f"f_a has shape {f_a.shape} and f_b {f_b.shape}: expected the same "
                         "(N, 3) unit bearings")
    return f_a, f_b


def one_point(
    f_a: ArrayLike,
    f_b: ArrayLike,
    theta_a: float,
    segment: Segment,
    tip_T_cam: ArrayLike | None = None,
    baseA_T_baseB: ArrayLike | None = None,
    psi: float = 0.0,
    grid_step: float = DEFAULT_GRID_STEP,
) -> FloatArray:
    """Every admissible root theta_b of each correspondence's epipolar constraint.

    Args:
        f_a, f_b: ``(N, 3)`` unit bearings in the camera at frames a and b.
        theta_a: the segment's bend at frame a (radians).
        segment: the segment the camera rides on (any 0 < k < 0.5, delta kept exactly).
        tip_T_cam: camera mounting (default identity).
        baseA_T_baseB: motion of the segment's base from a to b (default identity: fixed base,
            and the trivial root theta_a is excluded).
        psi: bending-plane angle (radians).
        grid_step: bracketing grid step (radians); roots closer together than this may merge.

    Returns:
        ``(N, R)`` roots in ``[-theta_max, theta_max]``, ascending per row, padded with NaN
        (``R >= 1``; a row of NaN where a correspondence has no admissible root, e.g. NaN input).
    """
    f_a, f_b = _checked_bearings(f_a, f_b)
    view = SegmentTwoView.build(theta_a, segment, tip_T_cam, baseA_T_baseB, psi)
    return _solve(constraint_coefficients(f_a, f_b, view), view, grid_step)


def _grid(view: SegmentTwoView, step: float) -> FloatArray:
    lim = view.segment.theta_max
    ta = view.theta_a
    k = np.arange(math.floor((-lim - ta) / step - 0.5), math.ceil((lim - ta) / step + 0.5) + 1)
    nodes = ta + (k + 0.5) * step
    nodes = nodes[(nodes > -lim) & (nodes < lim)]
    ends = [e for e in (-lim, lim) if abs(e - ta) > 1e-9 or not view.fixed_base]
    return np.sort(np.concatenate([nodes, ends]))


def _solve(coef: FloatArray, view: SegmentTwoView, step: float,
           fn: _Function | None = None) -> FloatArray:
    n = len(coef)
    if n == 0:
        return np.zeros((0, 1))
    fn = _Function(view) if fn is None else fn
    grid, grid_basis = fn.grid(step)
    # (G, N), grid-major: neighbouring grid rows are contiguous blocks for the comparisons below.
    values = grid_basis @ coef.T
    positive = values > 0.0
    # A sign change brackets a root; an exact zero counts as non-positive, so it ends a bracket
    # (the refinement then stops there at once).
    cols, rows = np.nonzero(positive[:-1] != positive[1:])
    lo, hi = grid[cols], grid[cols + 1]
    flo, fhi = values[cols, rows], values[cols + 1, rows]
    extra = _split_near_double_roots(coef, fn, grid, values, positive)
    if extra is not None:
        rows = np.concatenate([rows, extra[0]])
        lo, hi = np.concatenate([lo, extra[1]]), np.concatenate([hi, extra[2]])
        flo, fhi = np.concatenate([flo, extra[3]]), np.concatenate([fhi, extra[4]])
    roots = _refine(coef[rows], fn, lo, hi, flo, fhi)
    order = np.argsort(rows, kind="stable")
    rows, roots = rows[order], roots[order]
    counts = np.bincount(rows, minlength=n)
    width = max(1, int(counts.max()))
    out = np.full((n, width), np.nan)
    slot = np.arange(len(rows)) - np.repeat(np.cumsum(counts) - counts, counts)
    out[rows, slot] = roots
    return np.sort(out, axis=1)


def _refine(c: FloatArray, fn: _Function, lo: FloatArray, hi: FloatArray, flo: FloatArray,
            fhi: FloatArray) -> FloatArray:
    """Safeguarded Newton in brackets ``[lo, hi]`` with ``f(lo) f(hi) <= 0``, vectorised."""
    x = np.where(fhi == 0.0, hi, lo - flo * (hi - lo) / np.where(fhi != flo, fhi - flo, 1.0))
    active = fhi != 0.0
    tol = 1e-13
    for _ in range(_NEWTON_ITERATIONS):
        idx = np.flatnonzero(active)
        if len(idx) == 0:
            break
        xi = x[idx]
        f, df = fn.value_and_slope(c[idx], xi)
        same = np.sign(f) == np.sign(flo[idx])
        lo[idx] = np.where(same, xi, lo[idx])
        flo[idx] = np.where(same, f, flo[idx])
        hi[idx] = np.where(same, hi[idx], xi)
        newton = xi - f / np.where(df != 0.0, df, np.nan)
        inside = (newton >= lo[idx]) & (newton <= hi[idx])
        new_x = np.where(f == 0.0, xi, np.where(inside, newton, 0.5 * (lo[idx] + hi[idx])))
        x[idx] = new_x
        active[idx] = (np.abs(new_x - xi) > tol) & (f != 0.0)
    return x


def _split_near_double_roots(
    coef: FloatArray, fn: _Function, grid: FloatArray, values: FloatArray, positive: FloatArray
) -> tuple[FloatArray, ...] | None:
    """Brackets for root pairs closer than the grid step (``values`` is grid-major, (G, N)).

    Where ``|f|`` has a local minimum at a node without a sign change on either side, ``f`` may
    dip through zero and back between the neighbouring nodes. Minima whose parabola through the
    three nodes stays well away from zero are dropped (f is smooth on the grid scale); for the
    others the stationary point of ``f`` in ``[node - 1, node + 1]`` is located by regula falsi
    on ``f'``, and if ``f`` there has the other sign both roots are bracketed around it.
    """
    mag = np.abs(values)
    same = (positive[1:-1] == positive[:-2]) & (positive[1:-1] == positive[2:])
    cand = same & (mag[1:-1] < mag[:-2]) & (mag[1:-1] < mag[2:])
    cols, rows = np.nonzero(cand)
    fl, fm, fr = values[cols, rows], values[cols + 1, rows], values[cols + 2, rows]
    # Parabola through the three nodes (spacing may differ at the ends): vertex value.
    h0, h1 = grid[cols + 1] - grid[cols], grid[cols + 2] - grid[cols + 1]
    d0, d1 = (fm - fl) / h0, (fr - fm) / h1
    curv = (d1 - d0) / (h0 + h1)
    slope_m = (d0 * h1 + d1 * h0) / (h0 + h1)
    vertex = fm - slope_m**2 / (4.0 * np.where(curv != 0.0, curv, np.inf))
    keep = vertex * fm < 0.75 * fm * fm
    lo_idx, hi_idx = cols[keep], cols[keep] + 2
    rows, fl, fm, fr = rows[keep], fl[keep], fm[keep], fr[keep]
    # The end intervals: |f| smallest at the end node and rising there (f f' > 0 at the upper
    # end, < 0 at the lower end) means a minimum of |f| inside the last interval.
    last = len(grid) - 1
    for end, inner, sign in ((last, last - 1, 1.0), (0, 1, -1.0)):
        at_end = (positive[end] == positive[inner]) & (mag[end] < mag[inner])
        r = np.flatnonzero(at_end)
        if len(r) == 0:
            continue
        slope = fn.value_and_slope(coef[r], np.full(len(r), grid[end]))[1]
        r = r[sign * values[end, r] * slope > 0.0]
        lo_i, hi_i = (inner, end) if end == last else (end, inner)
        lo_idx = np.concatenate([lo_idx, np.full(len(r), lo_i)])
        hi_idx = np.concatenate([hi_idx, np.full(len(r), hi_i)])
        rows = np.concatenate([rows, r])
        fl = np.concatenate([fl, values[lo_i, r]])
        fm = np.concatenate([fm, values[end, r]])
        fr = np.concatenate([fr, values[hi_i, r]])
    if len(rows) == 0:
        return None
    c = coef[rows]
    a, b = grid[lo_idx], grid[hi_idx]
    da = fn.value_and_slope(c, a)[1]
    db = fn.value_and_slope(c, b)[1]
    x = 0.5 * (a + b)
    for _ in range(8):  # Illinois: regula falsi on f' that halves a stale end's weight
        x = np.where(db != da, a - da * (b - a) / np.where(db != da, db - da, 1.0), 0.5 * (a + b))
        x = np.clip(x, np.minimum(a, b), np.maximum(a, b))
        dx = fn.value_and_slope(c, x)[1]
        same_side = np.sign(dx) == np.sign(da)
        a, da = np.where(same_side, x, a), np.where(same_side, dx, da)
        b, db = np.where(same_side, b, x), np.where(same_side, 0.5 * db, dx)
    fx = fn.value_and_slope(c, x)[0]
    split = fx * fm < 0.0
    if not split.any():
        return None
    r, x, fx = rows[split], x[split], fx[split]
    lo_node, hi_node = grid[lo_idx[split]], grid[hi_idx[split]]
    return (np.concatenate([r, r]), np.concatenate([lo_node, x]), np.concatenate([x, hi_node]),
            np.concatenate([fl[split], fx]), np.concatenate([fx, fr[split]]))


# ------------------------------------------------------------------------------------ RANSAC
@dataclass(frozen=True)
class RansacInfo:
    """Outcome of :func:`one_point_ransac`.

    Attributes:
        success: whether theta_b was estimated.
        status: ``"ok"``, ``"too-few-correspondences"``, ``"no-motion"`` or ``"no-consensus"``.
        message: a sentence for people.
        inliers: ``(N,)`` inlier mask of the returned estimate (all False on failure).
        iterations: samples drawn.
        score: MSAC score of the best hypothesis (sum of ``min(e^2, threshold^2)``, radians^2).
        n_inliers: number of inliers.
        hypotheses: number of hypotheses scored.
    """

    success: bool
    status: str
    message: str
    inliers: NDArray[np.bool_]
    iterations: int
    score: float
    n_inliers: int = 0
    hypotheses: int = 0
    errors: FloatArray = field(default_factory=lambda: np.zeros(0), repr=False)


def _required_iterations(inlier_ratio: float, confidence: float) -> float:
    if inlier_ratio <= 0.0:
        return math.inf
    if inlier_ratio >= 1.0:
        return 1.0
    return math.log(1.0 - confidence) / math.log(1.0 - inlier_ratio)


def refine_theta(
    f_a: FloatArray, f_b: FloatArray, view: SegmentTwoView, theta_b: float, threshold: float,
    iterations: int = 5,
) -> float:
    """Robust 1-D Gauss-Newton on the Sampson error (Huber weights, scale = threshold).

    Iteratively reweighted least squares; 1-D, so each step is a ratio of sums and cheaper than a
    general solver call inside RANSAC's inner loop.
    """
    return _huber_gauss_newton(
        lambda t: epipolar_errors(f_a, f_b, view, t, derivative=True),
        theta_b, view.segment.theta_max, threshold, iterations)


def _huber_gauss_newton(errors, theta_b: float, lim: float, threshold: float,  # noqa: ANN001
                        iterations: int) -> float:
    """IRLS on a 1-D robust least squares: ``errors(theta) -> (e, de/dtheta)``, Huber weights."""
    theta = float(theta_b)
    for _ in range(iterations):
        e, de = errors(theta)
        r = np.abs(e)
        weight = np.where(r <= threshold, 1.0, threshold / np.maximum(r, 1e-300))
        hess = float(np.sum(weight * de * de))
        if hess <= 0.0:
            break
        delta = float(np.sum(weight * de * e)) / hess
        theta = min(max(theta - delta, -lim), lim)
        if abs(delta) < 1e-9:  # radians; far below any measurable change
            break
    return theta


def _refine_with_basis(basis: EpipolarBasis, mask: NDArray[np.bool_], theta_b: float,
                       threshold: float, iterations: int = 5) -> float:
    """:func:`refine_theta` on the rows in ``mask``, with errors from the basis expansion."""

    def errors(theta: float) -> tuple[FloatArray, FloatArray]:
        e, de = basis.errors(theta, derivative=True)
        return e[0, mask], de[0, mask]

    return _huber_gauss_newton(errors, theta_b, basis.view.segment.theta_max, threshold,
                               iterations)


def one_point_ransac(
    f_a: ArrayLike,
    f_b: ArrayLike,
    theta_a: float,
    segment: Segment,
    tip_T_cam: ArrayLike | None = None,
    baseA_T_baseB: ArrayLike | None = None,
    threshold: float = 1.0 / 500.0,
    confidence: float = 0.999,
    rng: np.random.Generator | None = None,
    psi: float = 0.0,
    max_iterations: int = 1000,
    batch: int = 8,
    min_inliers: int = 5,
) -> tuple[float, RansacInfo]:
    """Estimate theta_b from correspondences with outliers: 1-point RANSAC plus local refinement.

    Hypotheses come from single correspondences (``batch`` samples per numpy call, every root of
    each), all hypotheses of a batch are scored on all correspondences in one array operation
    (MSAC: truncated squared Sampson error), the number of samples adapts to the best inlier
    ratio, and the best hypothesis is refined on its inliers by robust 1-D least squares.

    Args:
        f_a, f_b: ``(N, 3)`` unit bearings.
        theta_a: the bend at frame a (radians).
        segment: the segment.
        tip_T_cam: camera mounting (default identity).
        baseA_T_baseB: base motion a -> b (default identity, fixed base).
        threshold: inlier threshold on the Sampson error in radians (pixels / focal length).
        confidence: probability of drawing at least one all-inlier sample.
        rng: random generator (default ``numpy.random.default_rng(0)``: deterministic).
        psi: bending-plane angle (radians).
        max_iterations: cap on samples.
        batch: samples per vectorised step.
        min_inliers: fewer inliers than this is a failure.

    Returns:
        ``(theta_b, info)``; on failure theta_b is NaN and ``info.status`` says why.
    """
    f_a, f_b = _checked_bearings(f_a, f_b)
    rng = np.random.default_rng(0) if rng is None else rng
    view = SegmentTwoView.build(theta_a, segment, tip_T_cam, baseA_T_baseB, psi)
    valid = np.all(np.isfinite(f_a), axis=1) & np.all(np.isfinite(f_b), axis=1)
    n = len(f_a)
    none = np.zeros(n, dtype=bool)
    if valid.sum() < max(1, min_inliers):
        return math.nan, RansacInfo(False, "too-few-correspondences",
                                    f"{int(valid.sum())} valid correspondences, need at least "
                                    f"{max(1, min_inliers)}", none, 0, math.inf)
    idx = np.flatnonzero(valid)
    fa, fb = f_a[idx], f_b[idx]
    if view.fixed_base:
        # Zero segment motion: the bearings coincide. Trivial root excluded, nothing to estimate.
        parallax = np.linalg.norm(np.cross(fa, fb), axis=1)
        if np.mean(parallax < threshold) >= 0.5:
            return math.nan, RansacInfo(
                False, "no-motion", "most correspondences show no parallax: the camera did not "
                "move, theta_b = theta_a is the only consistent reading and is not a measurement",
                none, 0, math.inf)
    fn = _Function(view)
    basis = EpipolarBasis(fa, fb, view)
    thr2 = threshold * threshold
    best_score, best_theta, hyp_count, iterations = math.inf, math.nan, 0, 0
    needed = float(max_iterations)
    while iterations < min(needed, max_iterations):
        take = int(min(batch, max_iterations - iterations))
        sample = rng.integers(0, len(fa), take)
        iterations += take
        roots = _solve(basis.coef[sample], view, DEFAULT_GRID_STEP, fn).ravel()
        roots = roots[np.isfinite(roots)]
        if len(roots) == 0:
            continue
        hyp_count += len(roots)
        errors = basis.errors(roots)  # (M, N): all hypotheses scored in one array operation
        scores = np.minimum(errors * errors, thr2).sum(axis=1)
        j = int(np.argmin(scores))
        if scores[j] < best_score:
            best_score, best_theta = float(scores[j]), float(roots[j])
            ratio = float(np.mean(np.abs(errors[j]) < threshold))
            needed = _required_iterations(ratio, confidence)
    if not math.isfinite(best_theta):
        return math.nan, RansacInfo(False, "no-consensus", "no correspondence gave an admissible "
                                    "root", none, iterations, math.inf, 0, hyp_count)
    # Local optimisation (LO-RANSAC): refine on the inliers, re-select them, refine again.
    errors = basis.errors(best_theta)[0]
    for steps in (3, 2):
        inl = np.abs(errors) < threshold
        if inl.sum() < 2:
            break
        best_theta = _refine_with_basis(basis, inl, best_theta, threshold, steps)
        errors = basis.errors(best_theta)[0]
    inl = np.abs(errors) < threshold
    score = float(np.minimum(errors * errors, thr2).sum())
    inliers = none.copy()
    inliers[idx[inl]] = True
    all_errors = np.full(n, np.nan)
    all_errors[idx] = errors
    if inl.sum() < min_inliers:
        return math.nan, RansacInfo(False, "no-consensus", f"best hypothesis has {int(inl.sum())}"
                                    f" inliers, need {min_inliers}", none, iterations, score,
                                    int(inl.sum()), hyp_count, all_errors)
    return best_theta, RansacInfo(True, "ok", f"{int(inl.sum())} of {n} inliers", inliers,
                                  iterations, score, int(inl.sum()), hyp_count, all_errors)


# ---------------------------------------------------------------------- fast Sampson scoring
class EpipolarBasis:
    """Sampson errors of many hypotheses theta_b through the same nine basis functions.

    ``E(theta) = sum_k phi_k(theta) E_k`` exactly: with ``camA_T_camB = [Rc|tc] T [Rm|tm]``,
    ``E = Rc [R_b tm + px e1 + pz e3 + d]x R_b Rm`` and ``R_b = n n^T + cos(b) (I - n n^T) +
    sin(b) [n]x``, using ``[R x]x R = R [x]x``. The products ``E_k f_b`` and ``E_k^T f_a`` are
    computed once per call; scoring M hypotheses is then two ``(M, 9) @ (9, 3N)`` products.

    Args:
        f_a, f_b: ``(N, 3)`` unit bearings.
        view: the two-view set-up.
    """

    def __init__(self, f_a: FloatArray, f_b: FloatArray, view: SegmentTwoView) -> None:
        self.view = view
        Rc, tc = view.left[:3, :3], view.left[:3, 3]
        Rm, tm = view.right[:3, :3], view.right[:3, 3]
        d = Rc.T @ tc
        cp, sp = math.cos(view.psi), math.sin(view.psi)
        n = np.array([-sp, cp, 0.0])
        e1 = np.array([cp, sp, 0.0])
        e3 = np.array([0.0, 0.0, 1.0])
        rot = [np.outer(n, n), np.eye(3) - np.outer(n, n), skew(n)]
        mats = ([A @ skew(tm) + skew(d) @ A for A in rot]
                + [skew(e1) @ A for A in rot] + [skew(e3) @ A for A in rot])
        E_k = Rc @ np.stack(mats) @ Rm  # (9, 3, 3)
        self.n = len(f_a)
        # Layout (9, 3, N): each vector component is a contiguous block of N values.
        self.Efb = (E_k.reshape(27, 3) @ f_b.T).reshape(9, -1)  # rows: E_k f_b
        self.Etfa = (np.swapaxes(E_k, 1, 2).reshape(27, 3) @ f_a.T).reshape(9, -1)
        self.coef = (self.Efb.reshape(9, 3, self.n) * f_a.T).sum(axis=1).T  # (N, 9)

    @staticmethod
    def _sq(x: FloatArray) -> FloatArray:
        return x[:, 0] * x[:, 0] + x[:, 1] * x[:, 1] + x[:, 2] * x[:, 2]

    @staticmethod
    def _dot(x: FloatArray, y: FloatArray) -> FloatArray:
        return x[:, 0] * y[:, 0] + x[:, 1] * y[:, 1] + x[:, 2] * y[:, 2]

    def errors(self, theta: ArrayLike, derivative: bool = False
               ) -> FloatArray | tuple[FloatArray, FloatArray]:
        """Sampson errors ``(M, N)`` (radians) for ``(M,)`` hypotheses (and d/dtheta)."""
        theta = np.atleast_1d(np.asarray(theta, dtype=float))
        phi, dphi = _basis(theta, self.view.segment)
        m = len(theta)
        Efb = (phi @ self.Efb).reshape(m, 3, self.n)
        Etfa = (phi @ self.Etfa).reshape(m, 3, self.n)
        num = phi @ self.coef.T
        den2 = self._sq(Efb) + self._sq(Etfa) - 2.0 * num * num
        den = np.sqrt(np.maximum(den2, 0.0))
        ok = den > 1e-300
        safe = np.where(ok, den, 1.0)
        e = np.where(ok, num / safe, 0.0)
        if not derivative:
            return e
        dEfb = (dphi @ self.Efb).reshape(m, 3, self.n)
        dEtfa = (dphi @ self.Etfa).reshape(m, 3, self.n)
        dnum = dphi @ self.coef.T
        dden = (self._dot(Efb, dEfb) + self._dot(Etfa, dEtfa) - 2.0 * num * dnum) / safe
        return e, np.where(ok, (dnum * den - num * dden) / (safe * safe), 0.0)
