"""Helpers shared by the tests (importable: pytest puts this folder on sys.path)."""

from __future__ import annotations

import gtsam
import numpy as np


def random_pose(rng: np.random.Generator, rot: float, trans: float) -> np.ndarray:
    """A random 4x4 pose: rotation vector ~ N(0, rot) rad, translation ~ N(0, trans) m."""
    rotation = gtsam.Rot3.Expmap(rng.normal(0.0, rot, 3))
    return gtsam.Pose3(rotation, rng.normal(0.0, trans, 3)).matrix()
