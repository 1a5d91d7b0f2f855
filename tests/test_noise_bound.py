"""The tip bound with the model's error as noise (``apcc_graph.evaluation.noise_bound``),
checked against a dense finite-difference Fisher matrix."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest

from apcc_graph.bench.smoother import FPS, ROBOT_FILE
from apcc_graph.evaluation.noise_bound import (
    model_noise_graph,
    model_noise_lag_bound,
    model_noise_tip_bound,
)
from apcc_graph.factors.keys import tip_key
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.parameterisation import Bending
from apcc_graph.simulation.simulator import simulate

SIGMAS = ((1e-3, math.radians(0.5)),) * 3


def _retract(values: gtsam.Values, key: int, k: int, h: float) -> gtsam.Values:
    """``values`` with unknown ``key`` moved by ``h`` along its ``k``-th tangent direction."""
    out = gtsam.Values(values)
    try:
        pose = values.atPose3(key)
        delta = np.zeros(6)
        delta[k] = h
        out.update(key, pose.retract(delta))
        return out
    except RuntimeError:
        pass
    try:
        p = np.array(values.atPoint3(key), dtype=float)
        p[k] += h
        out.update(key, p)
        return out
    except RuntimeError:
        x = np.array(values.atVector(key), dtype=float)
        x[k] += h
        out.update(key, x)
        return out


def _whitened(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> np.ndarray:
    parts = []
    for i in range(graph.size()):
        factor = graph.at(i)
        parts.append(factor.noiseModel().whiten(factor.unwhitenedError(values)))
    return np.concatenate(parts)


@pytest.mark.parametrize("correlations", [(), (0.05, 0.05, 0.05)])
def test_the_bound_is_the_inverse_of_the_finite_difference_fisher_matrix(
        correlations: tuple[float, ...]) -> None:
    """On three frames and 40 points, the bound from the model-noise graph (independent ties,
    or drifting ones) is the same (within 2%) as the inverse of ``J^T J``, ``J`` the central
    differences of every whitened residual in every unknown's tangent directions."""
    sim = simulate(load_robot(ROBOT_FILE), 3, noise_px=1.0, seed=1, fps=FPS, n_points=40)
    bending = Bending.fixed(sim.sequence.robot.segments)
    vectors = sim.sequence.thetas
    graph, values = model_noise_graph(sim, vectors, bending, SIGMAS, 1.0, math.radians(2.0),
                                      correlations)
    if correlations:  # the drifting ties are there
        assert any(len(graph.at(i).keys()) > 3 for i in range(graph.size()))
    keys = list(values.keys())
    dims = [6 if _is_pose(values, k) else (3 if _is_point(values, k) else
                                            len(values.atVector(k))) for k in keys]
    columns, where = [], {}
    h = 1e-6
    for key, d in zip(keys, dims, strict=True):
        where[key] = len(columns)
        for k in range(d):
            plus = _whitened(graph, _retract(values, key, k, h))
            minus = _whitened(graph, _retract(values, key, k, -h))
            columns.append((plus - minus) / (2.0 * h))
    J = np.column_stack(columns)
    cov = np.linalg.inv(J.T @ J)
    bound = model_noise_tip_bound(sim, vectors, bending, SIGMAS, 1.0, math.radians(2.0),
                                  step=1, correlations=correlations)
    for f in range(3):
        for j in range(3):
            at = where[tip_key(f, j)] + 3
            dense = math.sqrt(np.trace(cov[at:at + 3, at:at + 3]))
            assert abs(bound.sigmas[f, j] / dense - 1.0) < 0.02, (f, j, bound.sigmas[f, j],
                                                                  dense)


def _is_pose(values: gtsam.Values, key: int) -> bool:
    try:
        values.atPose3(key)
        return True
    except RuntimeError:
        return False


def _is_point(values: gtsam.Values, key: int) -> bool:
    return gtsam.Symbol(key).chr() == ord("l")


def test_a_tighter_model_tells_more() -> None:
    """The bound grows with the model noise (1e-6, 0.3 and 3 mm with ten times as many
    radians), every segment end."""
    sim = simulate(load_robot(ROBOT_FILE), 12, noise_px=1.0, seed=2, fps=FPS, n_points=300)
    bending = Bending.fixed(sim.sequence.robot.segments)
    vectors = sim.sequence.thetas
    sizes = [model_noise_tip_bound(sim, vectors, bending, ((s, s * 10.0),) * 3, 1.0,
                                   math.radians(0.1), step=4).rms()
             for s in (1e-6, 3e-4, 3e-3)]
    assert np.all(sizes[0] < sizes[1]) and np.all(sizes[1] < sizes[2]), sizes


def test_a_robot_at_rest_has_a_finite_bound() -> None:
    """Points seen from nearly one place (a robot at rest) have only the weak prior along
    their rays: gtsam's marginals refuse the graph as indeterminate; the bound eliminates them
    and is finite."""
    robot = load_robot(ROBOT_FILE)
    still = simulate(robot, 10, noise_px=1.0, seed=3, fps=FPS, n_points=300, amplitude=1e-6)
    bending = Bending.fixed(robot.segments)
    graph, values = model_noise_graph(still, still.sequence.thetas, bending, SIGMAS, 1.0,
                                      math.radians(2.0))
    with pytest.raises(RuntimeError, match="Indeterminate"):
        gtsam.Marginals(graph, values)
    bound = model_noise_tip_bound(still, still.sequence.thetas, bending, SIGMAS, 1.0,
                                  math.radians(2.0), step=3)
    assert np.all(np.isfinite(bound.sigmas)) and np.all(bound.sigmas > 0.0), bound.sigmas


def test_a_lag_bound_lies_between_the_filter_and_the_whole_recording() -> None:
    """A smoother's bound with the model noise: the frames a lag later tell more about a frame
    than none do, and everything tells most. With a lag past the recording's end it is the
    whole recording's bound; with no lag it is the filter's, larger where frames followed."""
    sim = simulate(load_robot(ROBOT_FILE), 12, noise_px=1.0, seed=2, fps=FPS, n_points=300)
    bending = Bending.fixed(sim.sequence.robot.segments)
    vectors = sim.sequence.thetas
    args = (sim, vectors, bending, SIGMAS, 1.0, math.radians(0.1))
    whole = model_noise_tip_bound(*args, step=4).sigmas
    lagged = {lag: model_noise_lag_bound(*args, lag_frames=lag, step=4).sigmas
              for lag in (0, 3, 11)}
    np.testing.assert_allclose(lagged[11], whole, rtol=1e-6)
    assert np.all(lagged[0] >= lagged[3] * (1 - 1e-9)) and np.all(lagged[3] >= whole * (1 - 1e-9))
    assert np.all(lagged[0][:-1] > 1.01 * whole[:-1])  # later frames told the early ones more
    with pytest.raises(ValueError, match="lag_frames"):
        model_noise_lag_bound(*args, lag_frames=-1)
