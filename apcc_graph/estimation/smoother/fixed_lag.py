"""A fixed-lag smoother over gtsam's iSAM2 that marginalises the same way on every run.

gtsam 4.3's ``IncrementalFixedLagSmoother`` finds the cliques to re-eliminate before a
marginalisation by walking a hash set of clique pointers, so what it re-eliminates, and with it
the order of the floating-point sums, depends on where the cliques lie in memory: once landmarks
are in the window, two runs on the same data drift apart. :class:`FixedLagISAM2` does the same
three things (an ordering constraint that eliminates the leaving variables first, extra keys
re-eliminated so that they end up in leaf cliques, ``ISAM2.marginalizeLeaves``) but marks
*every* variable of the window for re-elimination whenever one leaves: a set that depends on the
window's keys alone, and always enough. That costs iSAM2 a batch step, so it marginalises in
blocks: only once the oldest variable is ``slack`` seconds past the lag, and then every variable
past it; between blocks the window holds up to ``lag + slack`` seconds. The drift and the cost
of each schedule, measured: docs/estimation.md, "The fixed-lag smoother".

It answers the calls the smoother makes of gtsam's class (``update``, ``calculateEstimate``,
``marginalCovariance``, ``getISAM2Result``, ``getFactors``), with the new variables'
timestamps as a mapping from key to seconds.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import gtsam


class FixedLagISAM2:
    """iSAM2 holding the variables of the last ``lag`` seconds (see the module docstring).

    Args:
        lag: seconds; a variable whose timestamp is more than ``lag`` older than the newest
            is marginalised, at the latest once it is ``slack`` seconds past that.
        params: iSAM2's parameters.
        slack: seconds (default a quarter of the lag; 0: marginalise at every update).
        groups: the elimination order at every update: key -> group (lower first, after the
            leaving variables); ``None``: gtsam's own order between marginalisations.
    """

    def __init__(self, lag: float, params: gtsam.ISAM2Params, slack: float | None = None,
                 groups: Callable[[int], int] | None = None) -> None:
        self.lag = float(lag)
        self.groups = groups
        self.slack = 0.25 * self.lag if slack is None else float(slack)
        self.isam = gtsam.ISAM2(params)
        self.stamps: dict[int, float] = {}  # key -> seconds, for every variable held
        self._result: gtsam.ISAM2Result | None = None

    def update(self, graph: gtsam.NonlinearFactorGraph | None = None,
               values: gtsam.Values | None = None, stamps: Mapping[int, float] | None = None,
               remove: Sequence[int] = ()) -> gtsam.ISAM2Result:
        """Add ``graph`` with the new variables ``values`` (timestamps ``stamps``, seconds; a
        known key takes the new time), remove the factors at indices ``remove``, then, once
        the oldest variable is ``slack`` past the lag, marginalise every variable older than
        the lag."""
        held = set(self.stamps)
        self.stamps.update({int(k): float(s) for k, s in (stamps or {}).items()})
        now = max(self.stamps.values(), default=0.0)
        oldest = min(self.stamps.values(), default=now)
        leaving = [] if oldest >= now - self.lag - self.slack else sorted(
            k for k, s in self.stamps.items() if s < now - self.lag)
        constrained = extra = None
        if leaving or self.groups is not None:
            constrained = gtsam.KeyGroupMap()
            for key in leaving:  # the first group is eliminated first
                constrained.insert2(key, 0)
            if self.groups is not None:  # every kept key in its group, after the leaving
                # ccolamd needs every label below the number of keys it orders: at least the
                # new factors' keys (and every key when some leave, all re-eliminated)
                n = len(self.stamps) if leaving else (graph or gtsam.NonlinearFactorGraph()
                                                      ).keys().size()
                for key in sorted(self.stamps):
                    constrained.insert2(key, min(1 + self.groups(key), max(n - 1, 0)))
            else:
                for key in sorted(self.stamps):
                    constrained.insert2(key, 1)  # no effect on the keys already in group 0
        if leaving:
            extra = gtsam.KeyList()
            for key in sorted(held):
                extra.push_back(key)
        self._result = self.isam.update(graph or gtsam.NonlinearFactorGraph(),
                                        values or gtsam.Values(), [int(i) for i in remove],
                                        constrained, None, extra)
        if leaving:
            keys = gtsam.KeyList()
            for key in leaving:
                keys.push_back(key)
            self.isam.marginalizeLeaves(keys)
            for key in leaving:
                del self.stamps[key]
        return self._result

    def calculateEstimate(self) -> gtsam.Values:  # noqa: N802 (gtsam's name)
        """The current estimate of every variable held."""
        return self.isam.calculateEstimate()

    def marginalCovariance(self, key: int):  # noqa: N802, ANN201 (gtsam's name; a matrix)
        """The marginal covariance of variable ``key``."""
        return self.isam.marginalCovariance(key)

    def getISAM2Result(self) -> gtsam.ISAM2Result:  # noqa: N802 (gtsam's name)
        """What the last update did (its new factors' indices)."""
        if self._result is None:
            raise RuntimeError("FixedLagISAM2.getISAM2Result: no update yet")
        return self._result

    def getFactors(self) -> gtsam.NonlinearFactorGraph:  # noqa: N802 (gtsam's name)
        """The factors held (removed ones are empty slots)."""
        return self.isam.getFactorsUnsafe()


class GtsamFixedLag:
    """gtsam's own ``IncrementalFixedLagSmoother`` behind the same calls (timestamps as a
    mapping): faster than :class:`FixedLagISAM2`, not reproducible (module docstring)."""

    def __init__(self, lag: float, params: gtsam.ISAM2Params) -> None:
        self.inner = gtsam.IncrementalFixedLagSmoother(lag, params)

    def update(self, graph: gtsam.NonlinearFactorGraph | None = None,
               values: gtsam.Values | None = None, stamps: Mapping[int, float] | None = None,
               remove: Sequence[int] = ()) -> gtsam.ISAM2Result:
        """As :meth:`FixedLagISAM2.update`, marginalising at every update."""
        timestamps = gtsam.FixedLagSmootherKeyTimestampMap()
        for key, stamp in (stamps or {}).items():
            timestamps.insert((int(key), float(stamp)))
        self.inner.update(graph or gtsam.NonlinearFactorGraph(), values or gtsam.Values(),
                          timestamps, [int(i) for i in remove])
        return self.inner.getISAM2Result()

    def calculateEstimate(self) -> gtsam.Values:  # noqa: N802 (gtsam's name)
        """The current estimate of every variable held."""
        return self.inner.calculateEstimate()

    def marginalCovariance(self, key: int):  # noqa: N802, ANN201 (gtsam's name; a matrix)
        """The marginal covariance of variable ``key``."""
        return self.inner.marginalCovariance(key)

    def getISAM2Result(self) -> gtsam.ISAM2Result:  # noqa: N802 (gtsam's name)
        """What the last update did (its new factors' indices)."""
        return self.inner.getISAM2Result()

    def getFactors(self) -> gtsam.NonlinearFactorGraph:  # noqa: N802 (gtsam's name)
        """The factors held (removed ones are empty slots)."""
        return self.inner.getFactors()


WindowSolver = FixedLagISAM2 | GtsamFixedLag
"""What holds the smoother's window: either class answers the same calls."""
