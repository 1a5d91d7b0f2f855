"""The fixed-lag smoother (:class:`~apcc_graph.estimation.smoother.core.FixedLagSmoother`) and
its parts: the stages of an update (:mod:`.core`), the only owner of iSAM2 (:mod:`.solver`), the
two measurement models (:mod:`.measurement`, :mod:`.exact`, :mod:`.noisy`), the gap detectors
(:mod:`.gaps`) and the restarts that carry out their plans (:mod:`.restarts`).

May import: the layers below :mod:`apcc_graph.estimation`, and from it the options, the graph
building, the batch (a re-acquisition runs it), the start search and the window's helpers; never
the command line, the benchmarks or the evaluation."""

from apcc_graph.estimation.smoother.core import FixedLagSmoother

__all__ = ["FixedLagSmoother"]
