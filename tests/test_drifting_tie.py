"""A model error that drifts: the transition factor between two frames' ties (its residual, its
Jacobians against central differences over every key), the chain of them as the Gauss-Markov
process it stands for (steady state at every frame, correlation ``a`` between neighbours), the
decay, the choice of tie per frame, and the option that names the correlation time."""

from __future__ import annotations

import math
from dataclasses import replace

import gtsam
import numpy as np
import pytest
from helpers import random_pose
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph import Segment
from apcc_graph.estimation.model_noise import segment_correlations
from apcc_graph.estimation.model_ties import MIN_DECAY, MIN_DISTANCE, ModelTies
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.factors.drifting_tie import decay, drifting_tie_factor
from apcc_graph.factors.keys import frame_key, tip_key
from apcc_graph.factors.kinematic import segment_tie_residual
from apcc_graph.model.model_error import ModelError
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot

SEGMENTS = (Segment(0.3, k=0.2, delta_max=0.15, theta_max=1.0),
            Segment(0.25, k=0.35, delta_max=-0.3, theta_max=1.4))
SIGMAS = np.array([0.01, 0.02, 0.015, 0.002, 0.001, 0.003])


def _two_frames(seed: int, j: int) -> tuple[Bending, gtsam.Values, tuple, tuple, list]:
    """Two frames of a two-segment robot off its model: values, both ties of segment ``j``,
    and the base poses the ties read ((4, 4) for segment 0, else a tip key)."""
    rng = np.random.default_rng(seed)
    bending = Bending.free(SEGMENTS)
    values = gtsam.Values()
    bases = []
    for f in range(2):
        x = rng.uniform(-0.8, 0.8, bending.dim)
        values.insert(frame_key(f), x)
        base = random_pose(rng, 0.3, 0.2)
        bases.append(base)
        T = base
        for s in range(len(SEGMENTS)):
            T = T @ bending.transform(x, s) @ random_pose(rng, 0.05, 0.01)
            values.insert(tip_key(f, s), gtsam.Pose3(T))
    ties = tuple((frame_key(f), tip_key(f, j), bases[f] if j == 0 else tip_key(f, j - 1))
                 for f in range(2))
    return bending, values, ties[0], ties[1], bases


def _residual(values: gtsam.Values, tie: tuple, bending: Bending, j: int) -> np.ndarray:
    x_key, t_key, base = tie
    base_pose = gtsam.Pose3(base) if not isinstance(base, int) else values.atPose3(base)
    return segment_tie_residual(base_pose, values.atVector(x_key), values.atPose3(t_key),
                                bending, j, jacobians=False)[0]


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10**6), j=st.integers(0, 1), a=st.floats(0.0, 0.999))
def test_residual_and_jacobians(seed: int, j: int, a: float) -> None:
    bending, values, earlier, later, _ = _two_frames(seed, j)
    factor = drifting_tie_factor(earlier, later, bending, j, a, SIGMAS)
    sigma = SIGMAS * math.sqrt(1.0 - a * a)
    expected = (_residual(values, later, bending, j) - a * _residual(values, earlier, bending, j))
    np.testing.assert_allclose(factor.unwhitenedError(values), expected, atol=1e-12)
    np.testing.assert_allclose(factor.error(values), 0.5 * np.sum((expected / sigma) ** 2),
                               rtol=1e-9)
    A, _ = factor.linearize(values).jacobian()
    column = 0
    h = 1e-6
    for key in factor.keys():
        is_pose = gtsam.Symbol(key).chr() == ord("t")
        n = 6 if is_pose else bending.dim
        for i in range(n):
            d = np.zeros(n)
            d[i] = h
            moved = []
            for sign in (1.0, -1.0):
                v = gtsam.Values(values)
                if is_pose:
                    v.update(key, values.atPose3(key).retract(sign * d))
                else:
                    v.update(key, values.atVector(key) + sign * d)
                moved.append(factor.unwhitenedError(v))
            numeric = (moved[0] - moved[1]) / (2 * h) / sigma
            np.testing.assert_allclose(A[:, column + i], numeric, atol=1e-5)
        column += n
    assert column == A.shape[1]


def test_keys_of_both_frames() -> None:
    bending, _, earlier, later, _ = _two_frames(1, 0)
    assert len(drifting_tie_factor(earlier, later, bending, 0, 0.5, SIGMAS).keys()) == 4
    bending, _, earlier, later, _ = _two_frames(1, 1)
    assert len(drifting_tie_factor(earlier, later, bending, 1, 0.5, SIGMAS).keys()) == 6


def test_bad_arguments_are_refused() -> None:
    bending, _, earlier, later, _ = _two_frames(2, 1)
    with pytest.raises(ValueError, match="decay 1.0"):
        drifting_tie_factor(earlier, later, bending, 1, 1.0, SIGMAS)
    with pytest.raises(ValueError, match="6 finite values"):
        drifting_tie_factor(earlier, later, bending, 1, 0.5, SIGMAS[:3])
    with pytest.raises(ValueError, match="segment 2"):
        drifting_tie_factor(earlier, later, bending, 2, 0.5, SIGMAS)
    with pytest.raises(ValueError, match="repeated keys"):
        drifting_tie_factor(later, later, bending, 1, 0.5, SIGMAS)
    with pytest.raises(ValueError, match="expected finite values >= 0"):
        decay(-0.1, 1.0)


def test_decay() -> None:
    assert decay(0.1, 0.0) == 0.0
    assert decay(0.0, 2.0) == 1.0
    assert decay(0.5, 0.5) == pytest.approx(math.exp(-1.0))


@pytest.mark.parametrize("length", [0.01, 0.1, 1.0])
def test_a_chain_is_the_gauss_markov_process(length: float) -> None:
    """Tips tied only by the model error (frame vectors and base held, the bends moving 0.02
    rad a frame): each frame's tip varies by the steady-state sigma, neighbours correlate by
    ``a = exp(-0.02 / length)``, in every component."""
    bending = Bending.free(SEGMENTS[:1])
    sigmas = ((float(SIGMAS[3]), float(SIGMAS[0])),)
    ties = ModelTies(bending, sigmas, (length,))
    path = np.array([0.3, -0.2]) + np.outer(np.arange(12) * 0.02, [0.6, 0.8])
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    held = gtsam.noiseModel.Isotropic.Sigma(bending.dim, 1e-9)
    for f, x in enumerate(path):
        values.insert(frame_key(f), x)
        values.insert(tip_key(f, 0), gtsam.Pose3(bending.transform(x, 0)))
        graph.add(gtsam.PriorFactorVector(frame_key(f), x, held))
        previous = None if f == 0 else (f - 1, path[f - 1], np.eye(4))
        for factor in ties.frame(f, x, np.eye(4), previous):
            graph.add(factor)
    marginals = gtsam.Marginals(graph, values)
    steady = np.array([sigmas[0][1]] * 3 + [sigmas[0][0]] * 3) ** 2
    a = math.exp(-0.02 / length)
    for f in (0, 5, 11):
        np.testing.assert_allclose(np.diag(marginals.marginalCovariance(tip_key(f, 0))), steady,
                                   rtol=1e-6)
    keys = gtsam.KeyVector([tip_key(5, 0), tip_key(6, 0)])
    joint = marginals.jointMarginalCovariance(keys).fullMatrix()
    np.testing.assert_allclose(np.diag(joint[:6, 6:]), (a if a >= MIN_DECAY else 0.0) * steady,
                               rtol=1e-6, atol=1e-14)


def test_plain_ties_where_the_error_decays_within_a_frame() -> None:
    bending = Bending.free(SEGMENTS)
    ties = ModelTies(bending, ((0.002, 0.01), (0.003, 0.02)), (0.5, 0.001))
    x0, x1 = np.zeros(bending.dim), np.full(bending.dim, 0.01)
    first = ties.frame(0, x0, np.eye(4), None)
    assert [len(f.keys()) for f in first] == [2, 3]
    later = ties.frame(1, x1, np.eye(4), (0, x0, np.eye(4)))
    assert [len(f.keys()) for f in later] == [4, 3]  # a drifting tie, then a plain one


def test_frames_at_the_same_bends_are_not_tied_rigidly() -> None:
    """Two frames at the same estimate count :data:`MIN_DISTANCE` apart: the transition's
    sigma stays a finite fraction of the steady state's."""
    bending = Bending.free(SEGMENTS[:1])
    ties = ModelTies(bending, ((0.002, 0.01),), (math.radians(12.0),))
    x = np.array([0.2, 0.1])
    factor = ties.frame(1, x, np.eye(4), (0, x, np.eye(4)))[0]
    a = math.exp(-MIN_DISTANCE / math.radians(12.0))
    sigmas = factor.noiseModel().sigmas()
    np.testing.assert_allclose(sigmas[0], 0.01 * math.sqrt(1 - a * a), rtol=1e-9)
    assert sigmas[0] > 0.1 * 0.01


def test_the_option_and_the_robot_file() -> None:
    robot = Robot(list(SEGMENTS))
    assert segment_correlations("robot", robot) == (0.0, 0.0)
    errors = [ModelError(0.002, 0.01, correlation_time=3.0, correlation_bend=0.2), None]
    measured = Robot([replace(SEGMENTS[0], model_error=errors[0]), SEGMENTS[1]])
    assert segment_correlations("robot", measured) == (0.2, 0.0)
    assert segment_correlations(0.5, measured) == (0.5, 0.5)
    # by default the file's correlation length (it measured better)
    assert segment_correlations(GraphOptions().model_correlation, measured) == (0.2, 0.0)
    assert GraphOptions(model_correlation=2).model_correlation == 2.0
    for bad in (-1.0, math.inf, "often", True):
        with pytest.raises(ValueError, match="GraphOptions.model_correlation"):
            GraphOptions(model_correlation=bad)
