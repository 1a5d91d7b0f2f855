"""The fixed-lag smoother (:class:`~apcc_graph.estimation.smoother.core.FixedLagSmoother`) and
its parts: the stages of an update (:mod:`.core`), the only owner of iSAM2 (:mod:`.solver`), the
two measurement models (:mod:`.measurement`, :mod:`.exact`, :mod:`.noisy`), the gap detectors
(:mod:`.gaps`) and the restarts that carry out their plans (:mod:`.restarts`)."""

from apcc_graph.estimation.smoother.core import FixedLagSmoother

__all__ = ["FixedLagSmoother"]
