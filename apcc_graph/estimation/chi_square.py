"""The chi-square tail that both start tests use: the smoother's check of its start prior as the
first frame leaves the window (:mod:`apcc_graph.estimation.start_check`) and the residual test's
start part after an estimate (:class:`apcc_graph.estimation.model_fit.StartFit`)."""

from __future__ import annotations

from functools import cache

import scipy.stats

FALSE_ALARM = 1e-4
"""Probability of saying a start contradicts the images when it agrees with them."""


@cache
def chi2_limit(dof: int, false_alarm: float = FALSE_ALARM) -> float:
    """The chi-square value with ``dof`` degrees of freedom exceeded with probability
    ``false_alarm``."""
    return float(scipy.stats.chi2.isf(false_alarm, dof))
