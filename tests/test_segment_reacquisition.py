"""The pieces of a one-camera re-acquisition (the smoother re-acquires the segment of a camera
whose tracks come back all new after the window lost that segment): the batch's start prior per
component, the start that takes the search's answer for that segment only, and the window's
records that take the re-acquired segment and leave the others. The smoother's run on a
blackout is in ``tests/test_faults.py``."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest

from apcc_graph.bench.smoother import ROBOT_FILE
from apcc_graph.estimation.blackout import MIN_SIGMA, Reacquisition
from apcc_graph.estimation.graph import prior_factors
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.window import SmootherFrame, Window
from apcc_graph.factors.keys import frame_key
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.parameterisation import Bending


def _sigmas_of(factor: gtsam.PriorFactorVector) -> np.ndarray:
    return np.asarray(factor.noiseModel().sigmas(), dtype=float)


def test_the_start_prior_takes_one_sigma_per_component() -> None:
    robot = load_robot(ROBOT_FILE)
    bending = Bending.fixed(robot.segments)
    options = GraphOptions()
    theta0 = np.array([0.1, -0.2, 0.3])
    given = np.array([0.002, 0.004, 0.5])
    start = prior_factors([0, 1], [0.0, 0.1], theta0, bending, options, start_sigmas=given)[0]
    assert start.keys()[0] == frame_key(0)
    np.testing.assert_allclose(_sigmas_of(start), given)
    default = prior_factors([0, 1], [0.0, 0.1], theta0, bending, options)[0]
    np.testing.assert_allclose(_sigmas_of(default), options.theta0_sigma)
    for bad in (np.array([0.1, 0.1]), np.array([0.1, 0.0, 0.1]), np.array([0.1, np.nan, 0.1])):
        with pytest.raises(ValueError, match="start_sigmas"):
            prior_factors([0], [0.0], theta0, bending, options, start_sigmas=bad)


def _reacquisition(camera: int | None, sigmas: np.ndarray | None = None) -> Reacquisition:
    robot = load_robot(ROBOT_FILE)
    return Reacquisition(robot, GraphOptions(), 3.5, Bending.fixed(robot.segments),
                         np.array([0.1, 0.2, 0.3]), math.radians(30.0), camera=camera,
                         sigmas=sigmas)


def test_a_one_segment_start_takes_the_search_for_that_segment_only() -> None:
    kept = _reacquisition(2, np.array([0.001, 0.002, 0.004]))
    assert kept.block() == slice(2, 3)
    searched = np.array([0.5, 0.6, 0.7])
    theta0, sigmas = kept._one_segment(searched, np.array([0.03, 0.02, 0.05]))
    np.testing.assert_allclose(theta0, [0.1, 0.2, 0.7])  # the others stay the window's
    np.testing.assert_allclose(sigmas, [0.001, 0.002, 0.05])
    # an undetermined search leaves the window's start, the lost segment at least MIN_SIGMA
    theta0, sigmas = kept._one_segment(searched, None)
    np.testing.assert_allclose(theta0, [0.1, 0.2, 0.3])
    np.testing.assert_allclose(sigmas, [0.001, 0.002, MIN_SIGMA])
    with pytest.raises(ValueError, match="every segment"):
        _reacquisition(None).block()


def test_the_window_takes_the_reacquired_segment_and_keeps_the_others() -> None:
    """Frames inside the window and frames that left (not taken yet) get segment 2's angle,
    covariance cell and status; segments 0 and 1 keep theirs; a frame already taken is not
    touched."""
    window = Window(1.0, 3)
    ok = np.array(["ok", "ok", "ok"], dtype="<U24")
    window.enter(5, 0.5, 0.5, ok.copy())
    window.thetas[5] = np.array([1.0, 2.0, 3.0])
    window.final[4] = SmootherFrame(4, 0.4, np.array([1.0, 2.0, 3.0]),
                                    np.array([0.1, 0.2, 0.3]), ok.copy())
    thetas = np.array([[9.0, 9.0, 7.0], [9.0, 9.0, 8.0], [9.0, 9.0, 6.0]])
    blocks = np.array([[9.0, 9.0, 0.7], [9.0, 9.0, 0.8], [9.0, 9.0, 0.6]])
    window.reacquired_segment([3, 4, 5], 2, slice(2, 3), thetas, blocks)
    np.testing.assert_allclose(window.thetas[5], [1.0, 2.0, 6.0])
    assert list(window.status[5]) == ["ok", "ok", "reacquired"]
    left = window.final[4]
    np.testing.assert_allclose(left.thetas, [1.0, 2.0, 8.0])
    np.testing.assert_allclose(left.sigmas, [0.1, 0.2, 0.8])
    assert list(left.status) == ["ok", "ok", "reacquired"]
    assert 3 not in window.final and not window.inside(3)


def test_a_frame_that_left_and_was_not_taken_reenters_the_window_in_order() -> None:
    """A restart that holds the frames a batch re-acquired takes back those a gtsam failure
    pushed out, in frame order, with their status; a frame already taken stays out."""
    window = Window(1.0, 3)
    done = np.array(["reacquired"] * 3, dtype="<U24")
    window.enter(7, 0.7, 0.7, done.copy())
    window.thetas[7] = np.zeros(3)
    window.final[6] = SmootherFrame(6, 0.6, np.ones(3), np.full(3, 0.1), done.copy())
    assert window.reenter(6, np.array([0.5, 0.6, 0.7]))
    assert list(window.stamps) == [6, 7] and list(window.thetas) == [6, 7]
    assert window.inside(6) and 6 not in window.final and window.times[6] == 0.6
    np.testing.assert_allclose(window.thetas[6], [0.5, 0.6, 0.7])
    assert list(window.status[6]) == ["reacquired"] * 3
    assert not window.reenter(5, np.zeros(3)) and not window.inside(5)  # taken already
