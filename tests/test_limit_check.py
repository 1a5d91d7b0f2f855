"""A bend at its joint limit is never reported with a small sigma
(``apcc_graph.estimation.limit_check``)."""

from __future__ import annotations

import math
import warnings
from dataclasses import replace

import numpy as np
import pytest

from apcc_graph.bench.smoother import FPS, ROBOT_FILE
from apcc_graph.estimation.limit_check import AT_LIMIT, LimitWarning, at_the_limits
from apcc_graph.estimation.methods import estimate
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.robot import Robot
from apcc_graph.simulation.simulator import simulate


def test_a_robot_bent_beyond_its_file_limit_is_said_and_not_confident() -> None:
    """The robot file's limit of segment 1 set 3 deg below where the robot truly bends: the
    batch leaves segment 1 at the limit there, marks those frames ``at-limit`` with the
    whole range as their sigma, and warns naming segment 1; the other segments and frames
    keep their marginal sigmas."""
    sim = simulate(load_robot(ROBOT_FILE), 40, noise_px=1.0, seed=4, fps=FPS, n_points=800)
    seq = sim.sequence
    peak = float(np.abs(seq.thetas[:, 0]).max())
    segments = list(seq.robot.segments)
    segments[0] = replace(segments[0], theta_max=peak - math.radians(3.0))
    assert abs(seq.thetas[0, 0]) < segments[0].theta_max - math.radians(1.0)
    tight = seq.with_robot(Robot(segments, list(seq.robot.cameras)))
    with pytest.warns(LimitWarning, match="segment 1 in"):
        est = estimate(tight, method="batch", theta0=seq.thetas[0], noise_px=1.0)
    at = est.status[:, 0] == AT_LIMIT
    assert at.any() and not (est.status[:, 1:] == AT_LIMIT).any()
    assert np.all(est.sigmas[at, 0] == segments[0].theta_max)
    assert np.all(est.sigmas[~at, 0] < math.radians(1.0))
    truly_beyond = np.abs(seq.thetas[:, 0]) > segments[0].theta_max + math.radians(1.0)
    assert truly_beyond.any() and at[truly_beyond].all()


def test_inside_the_limits_nothing_changes() -> None:
    sim = simulate(load_robot(ROBOT_FILE), 20, noise_px=1.0, seed=4, fps=FPS, n_points=800)
    seq = sim.sequence
    with warnings.catch_warnings():
        warnings.simplefilter("error", LimitWarning)
        est = estimate(seq, method="batch", theta0=seq.thetas[0], noise_px=1.0)
    assert at_the_limits(est, math.radians(1.0)) is est
    assert not (est.status == AT_LIMIT).any()
