"""Every root in theta_b of the expanded epipolar constraint: the 1-point solver's root finding.

The constraint of each correspondence is ``g(theta) = c . phi(theta)`` on nine shared basis
functions (:mod:`~apcc_graph.frontend.basis`; docs/estimation.md, "Two frames").

- Trivial root: with a fixed base, ``theta_b = theta_a`` makes ``t = 0`` and satisfies every
  correspondence. It is removed exactly by deflation: ``g(theta_a) = 0``, so the other roots are
  those of the divided difference ``h(theta) = (g(theta) - g(theta_a)) / (theta - theta_a)``, a
  smooth function whose basis ``(phi_k(theta) - phi_k(theta_a)) / (theta - theta_a)`` is again
  shared. A true root half a degree from theta_a is an ordinary simple root of h.
- All roots: h is evaluated for all correspondences at once on a grid over
  ``[-theta_max, theta_max]`` (one matrix product), anchored half a step off theta_a; every sign
  change brackets a root, refined by safeguarded Newton (bisection when a step leaves the bracket)
  to machine precision.
- Close roots: two roots closer than the grid step (default 1 degree) show no sign change; they
  sit on either side of a local extremum of h, so wherever ``|h|`` has a local minimum on the
  grid without a sign change (and a parabola through the three nodes comes near zero), the
  extremum is located (Illinois regula falsi on h') and, if h changes sign there, both roots are
  bracketed. The basis functions vary on the scale of a radian (frequencies <= ~2 per radian),
  so h rarely turns twice within a grid step.
- Limits: when three roots fall within one grid step, the sign change shows one of them and the
  other two may be missed (the tests construct such cases deliberately; random correspondences
  rarely produce them); an exact double root (a tangency, where the correspondence carries no
  information) is reported once or not at all.
"""

from __future__ import annotations

import math

import numpy as np

from apcc_graph.frontend.basis import basis_functions
from apcc_graph.frontend.geometry import SegmentTwoView
from apcc_graph.model.arrays import FloatArray, IntArray
from apcc_graph.model.kinematics import apcc_in_plane

DEFAULT_GRID_STEP = math.radians(1.0)
_NEWTON_ITERATIONS = 40
_ILLINOIS_ITERATIONS = 8

#: Candidate brackets around a local minimum of ``|f|``: rows, grid indices of the bracket's
#: ends, and ``f`` at the lower end, at the minimum's node and at the upper end.
_Dips = tuple[IntArray, IntArray, IntArray, FloatArray, FloatArray, FloatArray]


class ConstraintFunction:
    """g, or its deflation h = (g - g(theta_a)) / (theta - theta_a), from the coefficients."""

    def __init__(self, view: SegmentTwoView) -> None:
        self.view = view
        self.deflate = view.fixed_base
        if self.deflate:
            self.phi_a = basis_functions(np.asarray(view.theta_a), view.segment)[0]

    def grid(self, step: float) -> tuple[FloatArray, FloatArray]:
        """The bracketing grid and the (deflated) basis on it, built once per step."""
        cached = getattr(self, "_grid_cache", None)
        if cached is None or cached[0] != step:
            nodes = _grid(self.view, step)
            cached = self._grid_cache = (step, nodes, self.basis(nodes))
        return cached[1], cached[2]

    def basis(self, theta: FloatArray) -> FloatArray:
        """The (deflated) basis at grid points, ``theta.shape + (9,)``."""
        phi = basis_functions(theta, self.view.segment)[0]
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


def _grid(view: SegmentTwoView, step: float) -> FloatArray:
    lim = view.segment.theta_max
    ta = view.theta_a
    k = np.arange(math.floor((-lim - ta) / step - 0.5), math.ceil((lim - ta) / step + 0.5) + 1)
    nodes = ta + (k + 0.5) * step
    nodes = nodes[(nodes > -lim) & (nodes < lim)]
    ends = [e for e in (-lim, lim) if abs(e - ta) > 1e-9 or not view.fixed_base]
    return np.sort(np.concatenate([nodes, ends]))


def solve_roots(coef: FloatArray, view: SegmentTwoView, step: float = DEFAULT_GRID_STEP,
                fn: ConstraintFunction | None = None) -> FloatArray:
    """Every admissible root of each row's constraint ``c . phi``, ``(N, R)`` padded with NaN.

    Args:
        coef: ``(N, 9)`` coefficients (:func:`~apcc_graph.frontend.basis.constraint_coefficients`).
        view: the two-view set-up.
        step: bracketing grid step (radians).
        fn: the constraint function of ``view`` (reuse one to keep its grid).
    """
    n = len(coef)
    if n == 0:
        return np.zeros((0, 1))
    fn = ConstraintFunction(view) if fn is None else fn
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


def _refine(c: FloatArray, fn: ConstraintFunction, lo: FloatArray, hi: FloatArray,
            flo: FloatArray, fhi: FloatArray) -> FloatArray:
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
    coef: FloatArray, fn: ConstraintFunction, grid: FloatArray, values: FloatArray,
    positive: FloatArray
) -> tuple[FloatArray, ...] | None:
    """Brackets for root pairs closer than the grid step (``values`` is grid-major, (G, N)).

    Where ``|f|`` has a local minimum at a node without a sign change on either side
    (:func:`_interior_dips`, :func:`_end_dips`), ``f`` may dip through zero and back between the
    neighbouring nodes. The stationary point of ``f`` there is located
    (:func:`_stationary_points`), and if ``f`` there has the other sign both roots are bracketed
    around it.

    Returns:
        ``(rows, lo, hi, f(lo), f(hi))`` of the new brackets, or None.
    """
    dips = [_interior_dips(grid, values, positive), *_end_dips(coef, fn, grid, values, positive)]
    rows, lo_idx, hi_idx, fl, fm, fr = (np.concatenate(part) for part in zip(*dips, strict=True))
    if len(rows) == 0:
        return None
    c = coef[rows]
    x = _stationary_points(c, fn, grid[lo_idx], grid[hi_idx])
    fx = fn.value_and_slope(c, x)[0]
    split = fx * fm < 0.0
    if not split.any():
        return None
    r, x, fx = rows[split], x[split], fx[split]
    lo_node, hi_node = grid[lo_idx[split]], grid[hi_idx[split]]
    return (np.concatenate([r, r]), np.concatenate([lo_node, x]), np.concatenate([x, hi_node]),
            np.concatenate([fl[split], fx]), np.concatenate([fx, fr[split]]))


def _interior_dips(grid: FloatArray, values: FloatArray, positive: FloatArray) -> _Dips:
    """Local minima of ``|f|`` at inner nodes without a sign change on either side.

    Minima whose parabola through the three nodes stays well away from zero are dropped (f is
    smooth on the grid scale).
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
    return rows[keep], cols[keep], cols[keep] + 2, fl[keep], fm[keep], fr[keep]


def _end_dips(coef: FloatArray, fn: ConstraintFunction, grid: FloatArray, values: FloatArray,
              positive: FloatArray) -> list[_Dips]:
    """Minima of ``|f|`` inside the two end intervals.

    ``|f|`` smallest at the end node and rising there (``f f' > 0`` at the upper end, ``< 0`` at
    the lower end) means a minimum of ``|f|`` inside the last interval. The end node plays the
    part of the minimum's node.
    """
    mag = np.abs(values)
    last = len(grid) - 1
    dips = []
    for end, inner, sign in ((last, last - 1, 1.0), (0, 1, -1.0)):
        at_end = (positive[end] == positive[inner]) & (mag[end] < mag[inner])
        r = np.flatnonzero(at_end)
        if len(r) == 0:
            continue
        slope = fn.value_and_slope(coef[r], np.full(len(r), grid[end]))[1]
        r = r[sign * values[end, r] * slope > 0.0]
        lo_i, hi_i = (inner, end) if end == last else (end, inner)
        dips.append((r, np.full(len(r), lo_i), np.full(len(r), hi_i), values[lo_i, r],
                     values[end, r], values[hi_i, r]))
    return dips


def _stationary_points(c: FloatArray, fn: ConstraintFunction, a: FloatArray,
                       b: FloatArray) -> FloatArray:
    """Zeros of ``f'`` in ``[a, b]`` per row: Illinois regula falsi (a stale end's weight
    halves)."""
    da = fn.value_and_slope(c, a)[1]
    db = fn.value_and_slope(c, b)[1]
    x = 0.5 * (a + b)
    for _ in range(_ILLINOIS_ITERATIONS):
        x = np.where(db != da, a - da * (b - a) / np.where(db != da, db - da, 1.0), 0.5 * (a + b))
        x = np.clip(x, np.minimum(a, b), np.maximum(a, b))
        dx = fn.value_and_slope(c, x)[1]
        same_side = np.sign(dx) == np.sign(da)
        a, da = np.where(same_side, x, a), np.where(same_side, dx, da)
        b, db = np.where(same_side, b, x), np.where(same_side, 0.5 * db, dx)
    return x
