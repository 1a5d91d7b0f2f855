"""The projection batch (every observation once, each track's point eliminated, GNC-TLS outlier
decisions): exact on noise-free data, efficient (Monte Carlo against the sequence Cramer-Rao
bound), consistent sigmas, out of wrong basins, per-observation outlier decisions, and the
epipolar model and argument checks.

Every batch here starts from given angles (``initial=``) or from the chain (``init="chain"``),
never from the fixed-lag smoother.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from apcc_graph.estimation.batch import GraphOptions, batch_estimate, projection_solve
from apcc_graph.estimation.chain import chain_estimate
from apcc_graph.estimation.graph import CameraTerms
from apcc_graph.estimation.image_motion import motion_clock
from apcc_graph.estimation.model_calibration import MOUNT_SIGMAS
from apcc_graph.estimation.options import BatchOptions, Robustness
from apcc_graph.estimation.robust import gnc_schedule
from apcc_graph.estimation.terms import exact as exact_terms
from apcc_graph.evaluation.sequence_bound import sequence_bound
from apcc_graph.factors.track_points import cut_tracks
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.robot import Robot
from apcc_graph.model.segment import Segment
from apcc_graph.model.sequence import Sequence, Tracks
from apcc_graph.simulation.simulator import Simulation, simulate

ROBOT = Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml"
PRIOR = math.radians(0.1)  # GraphOptions' default theta0_sigma
TRACK_FRAMES = GraphOptions().max_track_frames


@pytest.fixture(scope="module")
def robot() -> Robot:
    return load_robot(ROBOT)


def room(robot: Robot, n_frames: int, seed: int, noise_px: float = 1.0,
         outlier_fraction: float = 0.0, moving_base: bool = False) -> Simulation:
    """A room-scene simulation of the three-segment robot (2000 points, 30 fps)."""
    return simulate(robot, n_frames, noise_px, outlier_fraction, seed, scene="room",
                    n_points=2000, moving_base=moving_base)


def renoised(sim: Simulation, rng: np.random.Generator, noise_px: float) -> Sequence:
    """The simulation's sequence (same motion, scene and tracks) with fresh pixel noise on
    the noise-free projections; outlier rows left out."""
    seq = sim.sequence
    tracks = {}
    for cam, trk in seq.tracks.items():
        keep = ~sim.outliers[cam]
        clean = sim.clean_uv[cam][keep]
        tracks[cam] = Tracks(trk.frames[keep], trk.track_ids[keep],
                             clean + rng.normal(0.0, noise_px, clean.shape))
    return Sequence(seq.robot, seq.timestamps, tracks, world_T_base=seq.world_T_base,
                    thetas=seq.thetas, psis=seq.psis)


def rms(errors: np.ndarray) -> np.ndarray:
    """``(S,)`` RMS over every axis but the last."""
    return np.sqrt(np.mean(errors.reshape(-1, errors.shape[-1]) ** 2, axis=0))


# ------------------------------------------------------------------------------ noise-free
@pytest.mark.parametrize("start, schedule", [
    ("constant", None),          # +1, -1, +1 deg on every frame
    ("per-frame", None),         # independent, uniform in +/-1 deg per frame and segment
    ("per-frame", gnc_schedule(0.01, 4.0, 5)),
], ids=["constant-default", "per-frame-default", "per-frame-mu0=0.01"])
def test_noise_free_moving_base_returns_the_truth_from_one_degree_off(
        robot: Robot, start: str, schedule: list[float] | None) -> None:
    seq = room(robot, 20, seed=1, noise_px=0.0, moving_base=True).sequence
    rng = np.random.default_rng(7)
    if start == "constant":
        offset = np.broadcast_to(np.radians([1.0, -1.0, 1.0]), seq.thetas.shape)
    else:
        offset = math.radians(1.0) * rng.uniform(-1.0, 1.0, seq.thetas.shape)
    options = GraphOptions(motion_sigma=None, theta0_sigma=1e-9)  # threshold_px stays 1
    est = batch_estimate(seq, theta0=seq.thetas[0], initial=seq.thetas + offset,
                         options=options, marginals=False,
                         robustness=Robustness(schedule=schedule))
    assert est.method == "batch" and est.thetas.shape == (20, 3)
    worst = np.abs(est.thetas - seq.thetas).max(axis=1)
    assert np.all(worst < 1e-6), (
        f"frames {np.flatnonzero(worst >= 1e-6).tolist()} end up to "
        f"{math.degrees(worst.max()):.3f} deg off")


# ----------------------------------------------------------------------------- Monte Carlo
RUNS = 30


@pytest.fixture(scope="module")
def monte_carlo(robot: Robot) -> dict[str, np.ndarray]:
    """Batch errors and sigmas over pixel-noise redraws of one fixed 25-frame motion and scene.

    The start prior is a measurement too: its mean is drawn around the true frame 0 with the
    prior's own sigma (with the truth as its mean, the prior would be exact and the errors far
    below the bound, which counts it as noisy). The ``(RUNS, S)`` draws are scaled columns of
    an orthogonal matrix, so their sample covariance is exactly ``theta0_sigma^2 I``: the prior's
    share of the error (common to all frames of a run, so only RUNS samples of it) is then
    exact, and the comparison with the bound measures the pixel-noise part.
    """
    sim = room(robot, 25, seed=3, moving_base=True)
    truth = sim.sequence.thetas
    rng = np.random.default_rng(2024)
    q, _ = np.linalg.qr(rng.normal(size=(RUNS, robot.n_segments)))
    prior_means = truth[0] + math.sqrt(RUNS) * PRIOR * q
    errors, sigmas = [], []
    for run in range(RUNS):
        seq = renoised(sim, rng, 1.0)
        est = batch_estimate(seq, theta0=prior_means[run], initial=truth)
        errors.append(est.thetas - truth)
        sigmas.append(est.sigmas)
    bound = sequence_bound(sim, 1.0, PRIOR, max_track_frames=TRACK_FRAMES)
    return {"errors": np.array(errors), "sigmas": np.array(sigmas), "bound": bound.rms()}


def test_monte_carlo_error_and_sigmas_match_the_cramer_rao_bound(
        monte_carlo: dict[str, np.ndarray]) -> None:
    bound = monte_carlo["bound"]
    ratio = rms(monte_carlo["errors"]) / bound
    assert np.all((ratio > 0.7) & (ratio < 1.3)), f"RMS error / bound = {ratio}"
    sigma_ratio = rms(monte_carlo["sigmas"]) / bound
    assert np.all(np.abs(sigma_ratio - 1.0) < 0.1), f"RMS sigma / bound = {sigma_ratio}"


def test_monte_carlo_sigmas_are_consistent_with_the_errors(
        monte_carlo: dict[str, np.ndarray]) -> None:
    z2 = (monte_carlo["errors"] / monte_carlo["sigmas"]) ** 2
    mean_z2 = z2.reshape(-1, z2.shape[-1]).mean(axis=0)
    assert np.all((mean_z2 > 0.5) & (mean_z2 < 2.0)), f"mean (e / sigma)^2 = {mean_z2}"


# ---------------------------------------------------------------------------- wrong basins
@pytest.fixture(scope="module")
def outliers_10(robot: Robot) -> Simulation:
    return room(robot, 100, seed=1, outlier_fraction=0.1)


@pytest.mark.parametrize("segment", [0, 2], ids=["segment-1", "segment-3"])
def test_five_degrees_off_on_one_segment_with_outliers_returns_to_the_bound(
        outliers_10: Simulation, segment: int) -> None:
    seq = outliers_10.sequence
    start = seq.thetas.copy()
    start[:, segment] += math.radians(5.0)
    est = batch_estimate(seq, theta0=seq.thetas[0], initial=start, marginals=False)
    bound = sequence_bound(outliers_10, 1.0, PRIOR, max_track_frames=TRACK_FRAMES).rms()
    ratio = est.rms(seq.thetas) / bound
    assert np.all(ratio < 2.0), f"RMS error / bound = {ratio}"


def test_from_the_chain_with_thirty_percent_outliers(robot: Robot) -> None:
    sim = room(robot, 150, seed=1, outlier_fraction=0.3)
    seq = sim.sequence
    chain = chain_estimate(seq, theta0=seq.thetas[0])
    est = batch_estimate(seq, theta0=seq.thetas[0], init="chain", marginals=False)
    bound = sequence_bound(sim, 1.0, PRIOR, max_track_frames=TRACK_FRAMES).rms()
    ratio = est.rms(seq.thetas) / bound
    assert np.all(ratio < 2.0), f"RMS error / bound = {ratio}"
    gain = chain.rms(seq.thetas) / est.rms(seq.thetas)
    assert np.all(gain > 10.0), f"chain RMS / batch RMS = {gain}"


# -------------------------------------------------------------------------------- outliers
def test_outlier_decisions_match_the_simulated_outliers(
        robot: Robot, monkeypatch: pytest.MonkeyPatch) -> None:
    sim = room(robot, 60, seed=2, outlier_fraction=0.2)
    seq = sim.sequence
    options = GraphOptions()
    built = []

    def build_terms(*args: object, **kwargs: object) -> list[CameraTerms]:
        # the batch's own terms, with their final weights
        terms = original(*args, **kwargs)
        built.append(terms)
        return terms

    original = exact_terms.build_terms
    monkeypatch.setattr(exact_terms, "build_terms", build_terms)
    found = projection_solve(seq, seq.thetas, seq.thetas[0], options, marginals=False)
    inliers, report = found.inliers, found.report
    assert len(built) == 1
    decided, true = [], []
    for terms in built[0]:
        trk = seq.tracks[terms.camera]
        ids = cut_tracks(trk.frames, trk.track_ids, options.max_track_frames,
                         motion_clock(seq, options.threshold_px, still_tick=options.still_tick))
        flags = dict(zip(zip(trk.frames.tolist(), ids.tolist(), strict=True),
                         sim.outliers[terms.camera].tolist(), strict=True))
        for chunk in terms.chunks:
            obs = chunk.obs
            keys = zip(obs.frames.tolist(), obs.ids[obs.tracks].tolist(), strict=True)
            true.append([flags[k] for k in keys])
            decided.append(chunk.weights <= 0.5)
    decided, true = np.concatenate(decided), np.concatenate(true)
    assert report.observations == len(true)
    assert report.outliers == int(decided.sum())
    assert int(inliers.sum()) == report.observations - report.outliers
    assert abs(report.outliers - true.sum()) <= 0.02 * true.sum(), (
        f"{report.outliers} outliers reported, {true.sum()} simulated")
    recall = np.mean(decided[true])
    false_alarms = np.mean(decided[~true])  # chi-square, 2 dof, beyond 3.5: 0.22%
    assert recall > 0.99 and false_alarms < 0.01, (recall, false_alarms)


# ------------------------------------------------------------------------------ arguments
def test_the_batch_never_reads_the_sequences_ground_truth(robot: Robot) -> None:
    """The same tracks with other ground-truth bending planes (``Sequence.psis``) give the same
    estimate: the batch once took a planar robot's planes from them (2.8 deg apart)."""
    seq = room(robot, 20, seed=1).sequence
    tilted = Sequence(seq.robot, seq.timestamps, seq.tracks, seq.world_T_base, seq.thetas,
                      np.full(seq.thetas.shape, 0.3))
    a = batch_estimate(seq, theta0=seq.thetas[0], marginals=False)
    b = batch_estimate(tilted, theta0=seq.thetas[0], marginals=False)
    np.testing.assert_array_equal(a.thetas, b.thetas)


def test_bad_options_and_schedule_are_refused(robot: Robot) -> None:
    with pytest.raises(ValueError, match="Robustness.inlier_sigmas"):
        Robustness(inlier_sigmas=0.0)
    with pytest.raises(TypeError, match="inlier_sigmas"):  # not the measurement model's
        GraphOptions(inlier_sigmas=3.0)  # type: ignore[call-arg]
    for schedule in ([1.0, 4.0, 16.0], []):
        with pytest.raises(ValueError, match="schedule.*inf"):
            Robustness(schedule=schedule)
    seq = room(robot, 5, seed=0).sequence
    with pytest.raises(ValueError, match="'bogus'"):
        batch_estimate(seq, theta0=seq.thetas[0], init="bogus")
    with pytest.raises(ValueError, match="BatchOptions.init = 'bogus'"):
        BatchOptions(init="bogus")


# ---------------------------------------------------------------------- self-calibration
def _wrong_models(seq: Sequence, dk: float = 0.03, dd_deg: float = 3.0) -> Sequence:
    """The sequence with every segment's k off by ``dk`` and delta_max off by ``dd_deg``."""
    robot = Robot([Segment(s.length, s.k + dk, s.delta_max + math.radians(dd_deg), s.theta_max)
                   for s in seq.robot.segments], seq.robot.cameras)
    return Sequence(robot, seq.timestamps, seq.tracks, seq.world_T_base, seq.thetas, seq.psis)


def test_noise_free_self_calibration_returns_the_true_models(robot: Robot) -> None:
    """Wrong k and delta_max on every segment, noise-free pixels, loose calibration priors
    (the mounts held): the angles and the models come back (the priors' pull is ~1e-6
    here); without calibration the same start stays degrees off."""
    sim = room(robot, 40, seed=2, noise_px=0.0, moving_base=True)
    seq = _wrong_models(sim.sequence)
    options = GraphOptions(motion_sigma=None, theta0_sigma=1e-9)  # no prior pulls the truth
    fixed = batch_estimate(seq, theta0=sim.sequence.thetas[0], initial=sim.sequence.thetas,
                           options=options, marginals=False)
    assert np.abs(fixed.thetas - sim.sequence.thetas).max() > math.radians(0.2)
    est = batch_estimate(seq, theta0=sim.sequence.thetas[0], initial=sim.sequence.thetas,
                         options=options, calibrate=True, calibration_sigmas=(10.0, 10.0),
                         mount_sigmas=None)
    assert np.abs(est.thetas - sim.sequence.thetas).max() < 1e-5
    found = np.array([[s.k, s.delta_max] for s in est.robot.segments])
    truth = np.array([[s.k, s.delta_max] for s in robot.segments])
    np.testing.assert_allclose(found, truth, rtol=0, atol=1e-5)
    assert est.calibration_sigmas.shape == (3, 2)
    assert np.all(np.isfinite(est.calibration_sigmas))
    assert est.mount_sigmas is None


def test_self_calibration_sigmas_are_the_bound_of_the_models(robot: Robot) -> None:
    """On a noisy sequence the batch's calibration sigmas equal the Cramer-Rao bound of k and
    delta_max (same information, evaluated at the solution instead of the truth), and the
    angle sigmas the bound with unknown models and mounts, the mounts' sigmas theirs."""
    sim = room(robot, 120, seed=5)
    seq = _wrong_models(sim.sequence)
    sigmas = (0.05, math.radians(5.0))
    est = batch_estimate(seq, theta0=sim.sequence.thetas[0], initial=sim.sequence.thetas,
                         calibrate=True, calibration_sigmas=sigmas)
    # The default self-calibration also estimates the mounts: the bound has them unknown too.
    bound = sequence_bound(sim, 1.0, PRIOR, max_track_frames=TRACK_FRAMES,
                           calibration_sigmas=sigmas, mount_sigmas=MOUNT_SIGMAS)
    np.testing.assert_allclose(est.calibration_sigmas, bound.calibration, rtol=0.1)
    np.testing.assert_allclose(est.mount_sigmas, bound.mounts, rtol=0.1)
    np.testing.assert_allclose(rms(est.sigmas), bound.rms(), rtol=0.1)
    # Within a few sigmas of the true models.
    found = np.array([[s.k, s.delta_max] for s in est.robot.segments])
    truth = np.array([[s.k, s.delta_max] for s in robot.segments])
    assert np.all(np.abs(found - truth) < 4.0 * est.calibration_sigmas)
