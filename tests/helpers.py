"""Helpers shared by the tests (importable: pytest puts this folder on sys.path)."""

from __future__ import annotations

import gtsam
import numpy as np


def random_pose(rng: np.random.Generator, rot: float, trans: float) -> np.ndarray:
    """A random 4x4 pose: rotation vector ~ N(0, rot) rad, translation ~ N(0, trans) m."""
    rotation = gtsam.Rot3.Expmap(rng.normal(0.0, rot, 3))
    return gtsam.Pose3(rotation, rng.normal(0.0, trans, 3)).matrix()


def factor_hessian(factor: gtsam.NonlinearFactor, values: gtsam.Values
                   ) -> tuple[np.ndarray, np.ndarray]:
    """gtsam's information matrix and information vector of one factor linearised at
    ``values``, in the order of the factor's keys (gtsam's ``eta`` is minus the gradient)."""
    graph = gtsam.GaussianFactorGraph()
    graph.push_back(factor.linearize(values))
    ordering = gtsam.Ordering()
    for k in factor.keys():
        ordering.push_back(k)
    return graph.hessian(ordering)
