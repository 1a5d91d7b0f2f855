"""Batch estimation: exact on noise-free data; better than the chain with noise and outliers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from apcc_graph.estimation.batch import GraphOptions, batch_estimate
from apcc_graph.estimation.chain import chain_estimate
from apcc_graph.io.robot_file import load_robot
from apcc_graph.simulation.simulator import simulate_sequence

ROBOT = Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml"


def test_noise_free_sequence_returns_the_truth() -> None:
    seq = simulate_sequence(load_robot(ROBOT), 12, noise_px=0.0, seed=4, moving_base=True)
    options = GraphOptions(motion_sigma=None, theta0_sigma=1e-6)
    est = batch_estimate(seq, theta0=seq.thetas[0], options=options, marginals=False)
    np.testing.assert_allclose(est.thetas, seq.thetas, atol=1e-6)
    assert est.method == "batch" and est.thetas.shape == (12, 3)


def test_batch_beats_the_chain_and_reports_uncertainty() -> None:
    seq = simulate_sequence(load_robot(ROBOT), 40, noise_px=1.0, outlier_fraction=0.1, seed=8)
    chain = chain_estimate(seq, theta0=seq.thetas[0])
    est = batch_estimate(seq, theta0=seq.thetas[0])
    assert np.mean(est.rms(seq.thetas)) < np.mean(chain.rms(seq.thetas))
    assert np.all(np.isfinite(est.sigmas)) and np.all(est.sigmas > 0)
    # Frame 0 is pinned by the prior; later frames are less certain.
    assert np.all(est.sigmas[0] < est.sigmas[-1])


def test_bad_graph_options_are_refused_by_name() -> None:
    with pytest.raises(ValueError, match="GraphOptions.motion_sigma"):
        GraphOptions(motion_sigma=-1.0)
    with pytest.raises(ValueError, match="min_track_rows"):
        GraphOptions(min_track_rows=1)
    with pytest.raises(TypeError, match="'loss'"):  # an option of the retired epipolar model
        GraphOptions(loss="tukey")  # type: ignore[call-arg]
