"""Every root in theta of the 2-point eliminant: grid, brackets, close pairs, refinement.

The eliminant ``D(theta)`` of a pair of correspondences (:mod:`~apcc_graph.frontend.eliminant`)
vanishes where the two share a bend on the circle ``|b| = theta``
(docs/estimation.md, "Two correspondences: the 2-point solver of a spatial segment").

- Grid: ``D`` of every pair at once on nodes about a grid step apart over ``[SMALL_BEND,
  theta_max]`` (smaller bends are solved in the bending vector directly). With a fixed base
  ``b = b_a`` solves every pair, so ``D`` vanishes at ``|theta_a|``; it is divided by ``theta -
  |theta_a|`` (deflation) and the grid is anchored half a step off that bend.
- Sign changes bracket roots; Illinois regula falsi refines them.
- Close pairs: two roots of one pair within a grid step are common (at small motions the two
  constraints are nearly parallel, and their curves cross twice close together), and they
  show no sign change on the grid. Every interior local minimum of ``|D|`` without a sign change
  is therefore searched (:func:`_split_dips`): successive parabolic interpolation of ``|D|``
  with golden-section safeguards, until ``D`` changes sign (two brackets) or the minimum is
  located to ``1e-10`` rad without one (no roots there).
- Limits: a close pair in the first or last grid interval, or pairs closer than ``1e-10`` rad,
  may be missed; an exact double root (a tangency) is reported once or not at all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.frontend.eliminant import eliminant
from apcc_graph.frontend.geometry import SegmentTwoView
from apcc_graph.frontend.spatial_basis import spatial_functions
from apcc_graph.model.arrays import FloatArray, IntArray
from apcc_graph.model.segment import Segment

SMALL_BEND = math.radians(0.25)
"""Roots with ``|b_b|`` below this (radians) are found in the bending vector directly."""
DEFAULT_GRID_STEP = math.radians(0.5)


@dataclass(frozen=True)
class PairSetup:
    """What every pair of one frame pair shares: the fixed poses, the grid and F on it.

    Attributes:
        view: fixed parts of ``camA_T_camB`` (built with ``psi = psi_a``).
        b_a: frame a's bending vector (radians).
        anchor: ``|theta_a|`` when the base is fixed (the trivial root's bend), else None.
        grid: bracketing nodes in ``[SMALL_BEND, theta_max]``, radians, ascending.
        functions: ``(G, 9)`` :func:`~apcc_graph.frontend.spatial_basis.spatial_functions` on
            the grid.
    """

    view: SegmentTwoView
    b_a: FloatArray
    anchor: float | None
    grid: FloatArray
    functions: FloatArray

    @classmethod
    def build(cls, theta_a: float, psi_a: float, segment: Segment,
              tip_T_cam: ArrayLike | None, baseA_T_baseB: ArrayLike | None,
              grid_step: float = DEFAULT_GRID_STEP) -> PairSetup:
        """Assemble the set-up of one frame pair (angles in radians)."""
        view = SegmentTwoView.build(theta_a, segment, tip_T_cam, baseA_T_baseB, psi_a)
        b_a = np.array([theta_a * math.cos(psi_a), theta_a * math.sin(psi_a)])
        anchor = abs(float(theta_a)) if view.fixed_base else None
        grid = _grid(SMALL_BEND, segment.theta_max, anchor, grid_step)
        return cls(view, b_a, anchor, grid, spatial_functions(grid, segment))


def _grid(lo: float, hi: float, anchor: float | None, step: float) -> FloatArray:
    """Nodes from lo to hi about ``step`` apart, none within a third of a step of the anchor."""
    if anchor is None or not lo < anchor < hi:
        count = max(2, math.ceil((hi - lo) / step) + 1)
        nodes = np.linspace(lo, hi, count)
        if anchor is not None:  # an anchor at an end (a bend held at its limit) moves that end in
            near = np.abs(nodes - anchor) < step / 3.0
            nodes[near] = anchor + (step / 3.0 if anchor < 0.5 * (lo + hi) else -step / 3.0)
        return nodes
    k = np.arange(math.floor((lo - anchor) / step) - 1, math.ceil((hi - anchor) / step) + 1)
    nodes = anchor + (k + 0.5) * step
    nodes = nodes[(nodes > lo) & (nodes < hi)]
    ends = [e for e in (lo, hi) if abs(e - anchor) > step / 3.0]
    return np.sort(np.concatenate([nodes, ends]))


def pair_eliminant(setup: PairSetup, coef: FloatArray, theta: FloatArray,
                   functions: FloatArray | None = None
                   ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The (deflated) eliminant, the Bezout matrices and the monomial coefficients of pairs.

    Args:
        setup: the frame pair.
        coef: ``(S, 2, 9, 6)`` the pairs' coefficients.
        theta: ``(S,)`` one bend per pair, or ``(K, S)`` several (radians).
        functions: ``spatial_functions(theta)`` if already known.

    Returns:
        ``D`` and the Bezout matrices ``(..., 4, 4)`` and coefficients ``(..., 2, 6)`` at theta.
    """
    F = spatial_functions(theta, setup.view.segment) if functions is None else functions
    c = (np.broadcast_to(F[..., None, :, None], theta.shape + (2, 9, 6)) * coef).sum(axis=-2)
    D, B = eliminant(c, theta)
    if setup.anchor is not None:
        gap = theta - setup.anchor
        D = np.where(gap != 0.0, D / np.where(gap != 0.0, gap, 1.0), np.nan)
    return D, B, c


def grid_eliminant(setup: PairSetup, coef: FloatArray) -> tuple[FloatArray, FloatArray]:
    """:func:`pair_eliminant` of S pairs ``(S, 2, 9, 6)`` on the whole grid: ``D`` ``(G, S)`` and
    the Bezout matrices ``(G, S, 4, 4)`` (one matrix product for all nodes and pairs)."""
    grid = setup.grid
    c = (setup.functions @ np.moveaxis(coef, 2, 0).reshape(9, -1)).reshape(
        (len(grid),) + coef.shape[:2] + (6,))
    theta = np.broadcast_to(grid[:, None], c.shape[:2])
    D, B = eliminant(c, theta)
    if setup.anchor is not None:
        D = D / (theta - setup.anchor)  # the grid keeps a third of a step off the anchor
    return D, B


def _off_anchor(setup: PairSetup, theta: FloatArray, gap: float = 1e-6) -> FloatArray:
    """``theta`` with nodes closer than ``gap`` to the deflation's anchor moved ``gap`` away
    (the deflated D is 0/0 there)."""
    if setup.anchor is None:
        return theta
    off = theta - setup.anchor
    return np.where(np.abs(off) < gap, setup.anchor + np.where(off < 0.0, -gap, gap), theta)


def _sign_changes(nodes: FloatArray, values: FloatArray) -> tuple[IntArray, ...]:
    """Brackets ``(column, lo, hi, f(lo), f(hi))`` of sign changes down each column ``(K, M)``."""
    positive = values > 0.0
    finite = np.isfinite(values)
    rows, cols = np.nonzero((positive[:-1] != positive[1:]) & finite[:-1] & finite[1:])
    return (cols, nodes[rows, cols], nodes[rows + 1, cols], values[rows, cols],
            values[rows + 1, cols])


def _dips(nodes: FloatArray, values: FloatArray) -> tuple[IntArray, ...]:
    """Interior local minima of ``|D|`` down each column ``(K, M)`` without a sign change:
    ``(column, left, middle, right)`` nodes."""
    mag = np.abs(values)
    pos = values > 0.0
    same = (pos[1:-1] == pos[:-2]) & (pos[1:-1] == pos[2:])
    rows, cols = np.nonzero(same & (mag[1:-1] < mag[:-2]) & (mag[1:-1] < mag[2:]))
    return cols, nodes[rows, cols], nodes[rows + 1, cols], nodes[rows + 2, cols]


def _split_dips(setup: PairSetup, coef: FloatArray, pair: IntArray, a: FloatArray,
                m: FloatArray, c: FloatArray, iterations: int = 60) -> tuple[FloatArray, ...]:
    """Brackets of root pairs hidden in dips of ``|D|``: ``(pair, lo, hi, D(lo), D(hi))``.

    Minimises ``y = s D`` (``s`` the sign at the dip, so ``y > 0`` at the three nodes) over
    ``[a, c]`` keeping ``y(m) <= y(a), y(c)``: the vertex of the parabola through the three
    points when it falls inside and not too close to ``m``, else a golden-section point of the
    larger side. A point with ``y < 0`` brackets two roots.
    """
    # Long: one vectorised minimisation loop over all dips, with its bookkeeping.
    fa, fm, fc = (pair_eliminant(setup, coef[pair], x)[0] for x in (a, m, c))
    s = np.sign(fm)
    fa, fm, fc = s * fa, s * fm, s * fc
    found: list[tuple[FloatArray, ...]] = []
    active = np.isfinite(fa) & np.isfinite(fm) & np.isfinite(fc)
    for _ in range(iterations):
        idx = np.flatnonzero(active)
        if len(idx) == 0:
            break
        ai, mi, ci = a[idx], m[idx], c[idx]
        la, lc = mi - ai, ci - mi
        num = la * la * (fm[idx] - fc[idx]) - lc * lc * (fm[idx] - fa[idx])
        den = la * (fm[idx] - fc[idx]) + lc * (fm[idx] - fa[idx])
        x = mi - 0.5 * num / np.where(den != 0.0, den, np.inf)
        small = 0.05 * np.minimum(la, lc)
        golden = np.where(lc > la, mi + 0.381966 * lc, mi - 0.381966 * la)
        x = np.where((x > ai + small) & (x < ci - small) & (np.abs(x - mi) > small), x, golden)
        fx = s[idx] * pair_eliminant(setup, coef[pair[idx]], x)[0]
        crossed = fx < 0.0
        if crossed.any():
            j, xj = idx[crossed], x[crossed]
            far = np.where(xj < m[j], a[j], c[j])
            ffar = np.where(xj < m[j], fa[j], fc[j])
            found.append((np.concatenate([pair[j], pair[j]]), np.concatenate([m[j], xj]),
                          np.concatenate([xj, far]),
                          np.concatenate([s[j] * fm[j], s[j] * fx[crossed]]),
                          np.concatenate([s[j] * fx[crossed], s[j] * ffar])))
            active[j] = False
        better, left = fx < fm[idx], x < mi
        # The new triple: x becomes the middle if lower, else it replaces the end on its side.
        a[idx] = np.where(better, np.where(left, ai, mi), np.where(left, x, ai))
        fa[idx] = np.where(better, np.where(left, fa[idx], fm[idx]), np.where(left, fx, fa[idx]))
        c[idx] = np.where(better, np.where(left, mi, ci), np.where(left, ci, x))
        fc[idx] = np.where(better, np.where(left, fm[idx], fc[idx]), np.where(left, fc[idx], fx))
        m[idx] = np.where(better, x, mi)
        fm[idx] = np.where(better, fx, fm[idx])
        active &= (c - a) > 1e-10
    if not found:
        return ()
    pair, x0, x1, f0, f1 = (np.concatenate(part) for part in zip(*found, strict=True))
    swap = x1 < x0
    return (pair, np.where(swap, x1, x0), np.where(swap, x0, x1), np.where(swap, f1, f0),
            np.where(swap, f0, f1))


def _windows(D: FloatArray) -> tuple[IntArray, IntArray]:
    """Grid intervals ``(row, column)`` worth a finer look: those with a sign change, their
    neighbours, and the two around every local minimum of ``|D|`` (roots cluster)."""
    G = D.shape[0]
    pos = D > 0.0
    marked = np.zeros((G - 1,) + D.shape[1:], dtype=bool)
    change = pos[:-1] != pos[1:]
    marked |= change
    marked[1:] |= change[:-1]
    marked[:-1] |= change[1:]
    mag = np.abs(D)
    dip = (mag[1:-1] < mag[:-2]) & (mag[1:-1] < mag[2:])
    marked[:-1] |= dip
    marked[1:] |= dip
    return np.nonzero(marked)


def theta_brackets(setup: PairSetup, coef: FloatArray, resolve_close: bool = True,
                   split: int = 16) -> tuple[FloatArray, ...]:
    """Brackets ``(pair, lo, hi, D(lo), D(hi))`` of every root in theta of each pair's D.

    Args:
        setup: the frame pair.
        coef: ``(S, 2, 9, 6)`` coefficients of S pairs.
        resolve_close: look closer where roots cluster: the grid intervals of
            :func:`_windows`, widened by a sub-step on each side, are sampled ``split`` times
            finer, and the dips of ``|D|`` there searched (:func:`_split_dips`); else the grid's
            sign changes only.
    """
    grid = setup.grid
    D = grid_eliminant(setup, coef)[0]
    nodes = np.broadcast_to(grid[:, None], D.shape)
    if not resolve_close:
        return _sign_changes(nodes, D)
    rows, pair = _windows(D)
    step = (grid[rows + 1] - grid[rows]) / split
    lo = np.maximum(grid[rows] - step, grid[0])
    hi = np.minimum(grid[rows + 1] + step, grid[-1])
    fine = _off_anchor(setup, lo[None] + (hi - lo)[None]
                       * np.linspace(0.0, 1.0, split + 3)[:, None])
    values = pair_eliminant(setup, coef[pair], fine)[0]
    cols, a, b, fa, fb = _sign_changes(fine, values)
    found = [(pair[cols], a, b, fa, fb)]
    dips, x0, x1, x2 = _dips(fine, values)
    if len(dips):
        split_pairs = _split_dips(setup, coef, pair[dips], x0.copy(), x1.copy(), x2.copy())
        if split_pairs:
            found.append(split_pairs)
    return tuple(np.concatenate(part) for part in zip(*found, strict=True))


def refine_theta(setup: PairSetup, coef: FloatArray, lo: FloatArray, hi: FloatArray,
                 flo: FloatArray, fhi: FloatArray, iterations: int, tolerance: float = 1e-13
                 ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Roots of ``D`` in brackets ``[lo, hi]`` (one pair's coefficients per bracket).

    Illinois regula falsi (the weight of an end kept twice in a row halves), with a bisection
    whenever a step failed to halve the bracket, so that a root next to a nearly vanishing end
    (a close pair) is reached too. Stops per bracket below ``tolerance`` (radians) or after
    ``iterations``.

    Returns:
        the bends (radians), and the Bezout matrices ``(R, 4, 4)`` and monomial coefficients
        ``(R, 2, 6)`` at them (for psi).
    """
    # Long: one vectorised safeguarded regula falsi with its bookkeeping.
    lo, hi, flo, fhi = lo.copy(), hi.copy(), flo.copy(), fhi.copy()
    wlo, whi = flo.copy(), fhi.copy()
    side = np.zeros(len(lo))
    bisect = np.zeros(len(lo), dtype=bool)
    x = 0.5 * (lo + hi)
    B, c = np.zeros((len(lo), 4, 4)), np.zeros((len(lo), 2, 6))
    active = np.ones(len(lo), dtype=bool)
    for _ in range(max(1, iterations)):
        i = np.flatnonzero(active)
        if len(i) == 0:
            break
        left, right = lo[i], hi[i]
        gap = whi[i] - wlo[i]
        xi = left - wlo[i] * (right - left) / np.where(gap != 0.0, gap, np.inf)
        xi = np.where(bisect[i] | ~((xi > left) & (xi < right)), 0.5 * (left + right), xi)
        fx, B[i], c[i] = pair_eliminant(setup, coef[i], xi)
        x[i] = xi
        low = np.sign(fx) == np.sign(flo[i])
        lo[i], flo[i] = np.where(low, xi, left), np.where(low, fx, flo[i])
        hi[i], fhi[i] = np.where(low, right, xi), np.where(low, fhi[i], fx)
        wlo[i] = np.where(low, fx, np.where(side[i] == 1.0, 0.5 * wlo[i], wlo[i]))
        whi[i] = np.where(low, np.where(side[i] == -1.0, 0.5 * whi[i], whi[i]), fx)
        side[i] = np.where(low, -1.0, 1.0)
        width = hi[i] - lo[i]
        bisect[i] = width > 0.5 * (right - left)
        active[i] = (width > tolerance) & (fx != 0.0)
    return x, B, c
