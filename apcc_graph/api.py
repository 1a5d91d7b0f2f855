"""``apcc_graph.estimate``: one entry point for every estimator."""

from __future__ import annotations

from typing import Any

from numpy.typing import ArrayLike

from apcc_graph.estimation.result import Estimate
from apcc_graph.sequence import Sequence

METHODS = ("chain", "batch", "smoother")
"""Estimators available."""


def estimate(sequence: Sequence, method: str = "batch", theta0: ArrayLike | None = None,
             **options: Any) -> Estimate:
    """Estimate every frame's segment angles.

    Args:
        sequence: the sequence; ground-truth columns are never read.
        method: ``"chain"`` (the paper's front end), ``"batch"`` (factor graph, whole
            sequence) or ``"smoother"`` (fixed-lag smoother, frame by frame).
        theta0: ``(S,)`` starting configuration in radians (default straight).
        **options: passed to the estimator (:func:`~apcc_graph.estimation.chain.chain_estimate`,
            :func:`~apcc_graph.estimation.batch.batch_estimate` or
            :func:`~apcc_graph.estimation.smoother.smoother_estimate`).

    Raises:
        ValueError: an unknown method.
    """
    if method == "chain":
        from apcc_graph.estimation.chain import chain_estimate

        return chain_estimate(sequence, theta0=theta0, **options)
    if method == "batch":
        from apcc_graph.estimation.batch import batch_estimate

        return batch_estimate(sequence, theta0=theta0, **options)
    if method == "smoother":
        from apcc_graph.estimation.smoother import smoother_estimate

        return smoother_estimate(sequence, theta0=theta0, **options)
    raise ValueError(f"method = {method!r}: expected one of {', '.join(METHODS)}")
