"""The information of the images and an approximate model at an estimate
(``apcc_graph.estimation.noise_information``): what the unknown-start search's sigmas are
with the robot file's model error as noise."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from helpers import replayed_stretches

from apcc_graph.bench import ROBOT_FILE
from apcc_graph.estimation import batch_solve
from apcc_graph.estimation.methods import estimate
from apcc_graph.estimation.noise_information import start_blocks
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.evaluation.sequence_bound import sequence_bound
from apcc_graph.io import load_robot
from apcc_graph.model.parameterisation import Bending
from apcc_graph.simulation.simulator import Simulation, simulate

PRIOR = math.radians(30.0)


@pytest.fixture(scope="module")
def second() -> Simulation:
    return simulate(load_robot(ROBOT_FILE), 31, noise_px=1.0, outlier_fraction=0.1, seed=1,
                    scene="room")


def test_a_negligible_model_error_gives_the_vision_only_bound(second: Simulation) -> None:
    """At the true angles of a model-exact second, with a model noise of 0.01 mm / 0.006 deg,
    frame 0's sigmas are the vision-only Cramér-Rao bound (no prior but the search's weak
    one) to 5%, though every point is triangulated at the estimate rather than known: the
    points' prior only keeps the elimination finite (the estimators' 10 m prior, centred on
    those triangulations, made segment 1 eight times too sure)."""
    seq = second.sequence
    bending = Bending.fixed(seq.robot.segments)
    blocks = start_blocks(seq, seq.thetas, bending, GraphOptions(model_sigma=(1e-5, 1e-4)),
                          3.5, PRIOR)
    assert blocks is not None
    bound = sequence_bound(second, 1.0, theta0_sigma=PRIOR).sigmas[0]
    np.testing.assert_allclose(np.sqrt(blocks[:, 0, 0]), bound, rtol=0.05)


def test_a_larger_model_error_tells_less_and_none_is_the_exact_model(second: Simulation
                                                                       ) -> None:
    """Frame 0's sigmas grow with the model noise on every segment; the exact model (no
    model noise) gives ``None`` (the search keeps its own sigmas)."""
    seq = second.sequence
    bending = Bending.fixed(seq.robot.segments)
    sizes = [np.sqrt(start_blocks(seq, seq.thetas, bending, GraphOptions(model_sigma=noise),
                                  3.5, PRIOR)[:, 0, 0])
             for noise in ((1e-5, 1e-4), (1e-3, 1e-2), (5e-3, 5e-2))]
    assert np.all(np.diff(np.array(sizes), axis=0) > 0.0), sizes
    assert start_blocks(seq, seq.thetas, bending, GraphOptions(model_sigma=None), 3.5,
                        PRIOR) is None


def test_the_model_noise_batch_has_sigmas_for_a_robot_at_rest(monkeypatch: pytest.MonkeyPatch
                                                              ) -> None:
    """The first 10 frames of a real replayed stretch that starts at rest (impulse_2's
    last), the robot file's model error as noise: its points are seen from nearly one place
    (with a point variable per track, gtsam's marginals refused that graph and every sigma
    came back NaN). The sigmas are finite, positive and never above the start prior at frame
    0 (the images only add information); and where gtsam's marginals fail, the fallback that
    eliminates the points first gives the same blocks."""
    model, _, k, seq, floor = next(replayed_stretches("impulse_2", [0], [4]))
    prior = math.radians(2.0)

    def run() -> np.ndarray:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the residual test's and the limits' warnings
            return estimate(seq.head(10), "batch", floor.thetas[0], prior,
                            psi0=floor.psis[0], spatial=True).sigmas

    sigmas = run()
    assert np.all(np.isfinite(sigmas)) and np.all(sigmas > 0.0), sigmas
    assert np.all(sigmas[0] <= prior * (1.0 + 1e-6)), np.degrees(sigmas[0])
    used: list[bool] = []
    real = batch_solve._eliminated_blocks

    def spy(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        used.append(True)
        return real(*args, **kwargs)

    monkeypatch.setattr(batch_solve, "_eliminated_blocks", spy)
    monkeypatch.setattr(batch_solve, "_gtsam_blocks", lambda *args: args[-1])  # refused
    fallback = run()
    assert used
    np.testing.assert_allclose(fallback, sigmas, rtol=1e-3)
