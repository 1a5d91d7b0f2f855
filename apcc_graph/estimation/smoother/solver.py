"""The only owner of the smoother's iSAM2: its updates, its restarts and its failures.

Nothing else in the smoother calls gtsam's incremental solver. An update adds what a frame
brought (:class:`Additions`: factors, new variables and their timestamps) and replaces the
previous update's *replaceable* factors (the exact model's live projection factors, which
grow with every frame of their tracks) by the new ones; the solver remembers where gtsam put
them. A restart throws the window away and starts a new one from what the caller gives it
(a prior and the frames it keeps). A gtsam failure in an update is caught and counted
(:attr:`Solver.recoveries`); the caller decides how to restart.

The window is held by :class:`~apcc_graph.estimation.smoother.fixed_lag.FixedLagISAM2` (the
same bytes on every run) or gtsam's own ``IncrementalFixedLagSmoother``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import gtsam
import numpy as np

from apcc_graph.estimation.smoother.fixed_lag import FixedLagISAM2, GtsamFixedLag, WindowSolver
from apcc_graph.model.arrays import FloatArray

UPDATE_FAILURES = (RuntimeError, IndexError)
"""What gtsam raises in an update when the window's system is indeterminate or its bookkeeping
fails."""
QUERY_FAILURES = (RuntimeError, IndexError, ValueError)
"""... and when asked for a variable it does not hold."""


class Additions:
    """What one update adds to the window: factors, new values and their timestamps."""

    def __init__(self) -> None:
        self.graph = gtsam.NonlinearFactorGraph()
        self.values = gtsam.Values()
        self.stamps: dict[int, float] = {}

    def variable(self, key: int, value: object, stamp: float) -> None:
        """A new variable ``key`` at ``value`` with timestamp ``stamp`` (seconds)."""
        self.values.insert(key, value)
        self.stamps[int(key)] = float(stamp)


def new_window(lag: float, relinearize_threshold: float, factorization: str = "CHOLESKY",
               reproducible: bool = True, groups: Callable[[int], int] | None = None,
               trust_region: bool = False) -> WindowSolver:
    """iSAM2 over the last ``lag`` seconds, factoring the window's linear system by
    ``factorization`` (``"CHOLESKY"`` or ``"QR"``): marginalising the same way on every run
    (:class:`~apcc_graph.estimation.smoother.fixed_lag.FixedLagISAM2`), or gtsam's fixed-lag
    smoother; ``groups`` orders the elimination (key -> group, lower first; the reproducible
    one only); ``trust_region``: each update's step is Powell's dogleg inside a trust region
    that adapts to how well the linearisation predicted the last step, instead of the full
    Gauss-Newton step."""
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(relinearize_threshold)
    params.relinearizeSkip = 1
    params.findUnusedFactorSlots = True
    params.setFactorization(factorization)
    if trust_region:
        params.setOptimizationParams(gtsam.ISAM2DoglegParams())
    if groups is not None and not reproducible:
        raise ValueError("new_window: an elimination order needs the reproducible smoother")
    return (FixedLagISAM2(lag, params, groups=groups) if reproducible
            else GtsamFixedLag(lag, params))


class Solver:
    """The smoother's iSAM2 and the bookkeeping of its replaceable factors.

    Args:
        new_window: makes an empty gtsam window (again at every restart).

    Attributes:
        window: gtsam's smoother holding the window's variables (tests replace it to
            provoke failures).
        recoveries: gtsam failures caught so far.
        restarts: new windows started so far (:meth:`restart`).
        last_error: the last of them.
    """

    def __init__(self, new_window: Callable[[], WindowSolver]) -> None:
        self._new_window = new_window
        self.window = new_window()
        self.recoveries = 0
        self.restarts = 0  # new windows so far
        self.last_error: BaseException | None = None
        self._replaceable: list[int] = []  # gtsam's indices of the live factors held

    def update(self, add: Additions, replaceable: Sequence[int] = ()) -> bool:
        """Add ``add`` to the window, replacing the previous update's replaceable factors by
        those at positions ``replaceable`` of ``add.graph``; ``False`` (and one more
        recovery) when gtsam fails, the window then being unusable until :meth:`restart`."""
        try:
            self.window.update(add.graph, add.values, add.stamps, self._replaceable)
        except UPDATE_FAILURES as error:
            self.recoveries += 1
            self.last_error = error
            self._replaceable = []
            return False
        indices = self.window.getISAM2Result().getNewFactorsIndices()
        self._replaceable = [int(indices[pos]) for pos in replaceable]
        return True

    def set_lag(self, lag: float) -> None:
        """Hold the last ``lag`` seconds from the next update on (the reproducible window only;
        gtsam's own keeps the lag it was made with)."""
        if isinstance(self.window, FixedLagISAM2):
            self.window.lag = float(lag)

    def restart(self, add: Additions, replaceable: Sequence[int] = ()) -> bool:
        """A new, empty window given ``add`` (its prior and the frames it keeps); ``False``
        when gtsam fails on that too (counted)."""
        self.window = self._new_window()
        self.restarts += 1
        self._replaceable = []
        return self.update(add, replaceable)

    def relinearise(self, steps: int) -> bool:
        """``steps`` more Gauss-Newton steps of the whole window (no new factors)."""
        try:
            for _ in range(steps):
                self.window.update()
        except UPDATE_FAILURES as error:
            self.recoveries += 1
            self.last_error = error
            return False
        return True

    def estimate(self) -> gtsam.Values:
        """The current estimate of every variable in the window."""
        return self.window.calculateEstimate()

    def covariance(self, key: int, size: int) -> FloatArray:
        """Variable ``key``'s ``(size, size)`` marginal covariance; NaN when gtsam cannot give
        it (not in the window, or an indeterminate system)."""
        try:
            return np.asarray(self.window.marginalCovariance(key), dtype=float)
        except QUERY_FAILURES:
            return np.full((size, size), np.nan)
