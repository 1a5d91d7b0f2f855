"""The fixed-lag smoother with model error as noise (docs/estimation.md, "Model error as noise"):
the real robot's replay, the model-exact replay, the batch over the same graph, its pieces
(tip factors, elimination order, restarts)."""

from __future__ import annotations

import math
import warnings

import gtsam
import numpy as np
import pytest
from helpers import fast_stretch_bound, fast_stretch_replay

from apcc_graph.estimation.batch import batch_estimate
from apcc_graph.estimation.methods import estimate
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother.fixed_lag import FixedLagISAM2
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.estimation.smoother_runs import smoother_estimate
from apcc_graph.estimation.tip_tracks import TipTracks
from apcc_graph.estimation.window import RestartWarning
from apcc_graph.evaluation.tip_floor import tip_errors
from apcc_graph.factors.keys import elimination_group, frame_key, kind, point_key, tip_key
from apcc_graph.factors.track_points import TrackObservations
from apcc_graph.model.parameterisation import Bending

MODEL_SIGMA = (1e-3, math.radians(0.5))
START_SIGMA = math.radians(2.0)


def _tip_rms(model, est, truth) -> np.ndarray:  # noqa: ANN001
    return tip_errors(model.forward(est.thetas, est.psis), truth).rms_position


def _run(seq, floor, model_sigma, correlation: object = 0.0):  # noqa: ANN001, ANN202
    """The smoother from the floor's start; ``model_sigma`` None: the exact model. The model
    error independent per frame unless ``correlation`` says otherwise ("robot": drifting, the
    default)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return estimate(seq, method="smoother", theta0=floor.thetas[0], psi0=floor.psis[0],
                        spatial=True, theta0_sigma=START_SIGMA,
                        graph=GraphOptions(model_sigma=model_sigma,
                                           model_correlation=correlation))


def test_model_noise_keeps_the_smoother_near_the_real_tips_where_the_exact_one_is_driven_away(
        ) -> None:
    """The default (the robot file's model error, drifting along the bends) against the exact
    model, on 40 frames of real motion. Measured: floor 1.6 / 0.6 mm, bound 6.4 / 18.4 mm,
    exact smoother 36 / 136 mm, with model noise 6.1 / 25.9 mm (5.5 / 23.7 and 5.6 / 26.1 on
    replay seeds 1 and 2; the batch 4.9 / 15.3). (With a tight 1 mm / 0.5 deg independent per
    frame, which the measured tips break by 3.5 sigma on average, 7.9 / 27.8 mm; each point a
    variable under a prior, 3.7 / 9.1.)"""
    model, seq, truth, floor = fast_stretch_replay(40, exact=False)
    exact, noise = (_tip_rms(model, _run(seq, floor, s, "robot"), truth)
                    for s in (None, "robot"))
    bound_rms = fast_stretch_bound(40, "robot", START_SIGMA, drifting=True)
    assert np.all(noise < 0.25 * exact), (noise, exact)
    assert np.all(noise < 2.0 * bound_rms), (noise, bound_rms)


def test_model_noise_costs_the_smoother_little_on_model_exact_motion() -> None:
    """Measured: exact smoother 2.9 / 8.0 mm; with model noise 2.1 / 5.6 mm while it guessed
    each new frame by the exact model's two-frame solver, 4.2 / 11.3 mm since it guesses from
    the cameras' rotations (whose parallax the exact solver does not have; on the real
    impulse_2 replay the same change took the smoother from 26 / 72 to 17 / 66 mm). Independent
    per frame: with the calibration's drifting ties (the default) 5.1 / 15.6 mm."""
    model, seq, truth, floor = fast_stretch_replay(30, exact=True)
    exact, noise = (_tip_rms(model, _run(seq, floor, s), truth) for s in (None, MODEL_SIGMA))
    assert np.all(noise < 1.5 * exact), (noise, exact)
    assert np.all(noise < 15e-3), noise


def test_a_recording_shorter_than_the_lag_is_near_its_bound_and_the_batch_s() -> None:
    """0.76 s of real motion: the smoother, and the batch started from its answer, both within
    twice the Cramer-Rao bound of those frames with the model noise (the drifting default).
    Measured: bound 5.7 / 15.9 mm; smoother 4.2 / 20.9 mm, the batch 4.3 / 21.3 mm (each
    point a variable under a prior, the smoother was 4.4 / 8.8 and the batch 3.9 / 5.8 mm: the
    priors knew more than the images)."""
    model, seq, truth, floor = fast_stretch_replay(14, exact=False)  # 0.76 s
    smoothed = _run(seq, floor, MODEL_SIGMA, "robot")
    bending = Bending.free(model.segments)
    batch = batch_estimate(seq, floor.thetas[0], psi0=floor.psis[0], spatial=True,
                           initial=bending.vector(smoothed.thetas, smoothed.psis),
                           options=GraphOptions(theta0_sigma=START_SIGMA,
                                                model_sigma=MODEL_SIGMA), marginals=False)
    bound_rms = fast_stretch_bound(14, MODEL_SIGMA, START_SIGMA, drifting=True)
    ours, theirs = _tip_rms(model, smoothed, truth), _tip_rms(model, batch, truth)
    assert np.all(ours < 2.0 * bound_rms), (ours, bound_rms)
    assert np.all(theirs < 2.0 * bound_rms), (theirs, bound_rms)


@pytest.mark.filterwarnings("ignore")  # the exact smoother's residual test warns here
def test_the_smoother_with_model_noise_is_chosen_by_the_model_sigma_and_is_reproducible(
        monkeypatch: pytest.MonkeyPatch) -> None:
    import apcc_graph.estimation.smoother_runs as runs

    model, seq, truth, floor = fast_stretch_replay(12, exact=False)
    kinds = []
    original = runs.stream_estimate

    def spy(smoother, sequence, progress=False):  # noqa: ANN001, ANN202
        kinds.append(smoother.measurement_model)
        return original(smoother, sequence, progress)

    monkeypatch.setattr(runs, "stream_estimate", spy)
    noise = GraphOptions(model_sigma=MODEL_SIGMA)
    first, again = (smoother_estimate(seq, floor.thetas[0], noise, psi0=floor.psis[0],
                                      spatial=True) for _ in range(2))
    smoother_estimate(seq, floor.thetas[0], GraphOptions(model_sigma=None), psi0=floor.psis[0],
                      spatial=True)
    assert kinds == ["model noise", "model noise", "exact"]
    assert first.thetas.tobytes() == again.thetas.tobytes()
    assert first.sigmas.tobytes() == again.sigmas.tobytes()


def test_the_chain_refuses_model_noise() -> None:
    model, seq, truth, floor = fast_stretch_replay(2, exact=False)
    with pytest.raises(ValueError, match="the chain has the exact model"):
        estimate(seq, method="chain", theta0=floor.thetas[0], psi0=floor.psis[0],
                 spatial=True, graph=GraphOptions(model_sigma=MODEL_SIGMA))


def test_a_gtsam_failure_restarts_the_window_at_the_last_estimate() -> None:
    model, seq, truth, floor = fast_stretch_replay(12, exact=False)
    smoother = FixedLagSmoother(seq.robot, options=GraphOptions(model_sigma=MODEL_SIGMA,
                                                                theta0_sigma=START_SIGMA),
                                theta0=floor.thetas[0], psi0=floor.psis[0], spatial=True)
    for f in range(6):
        smoother.update(seq.frame(f))
    solver = smoother._smoother

    class Failing:
        def update(self, *args, **kwargs):  # noqa: ANN002, ANN003, ANN202
            raise RuntimeError("Indeterminate linear system (provoked)")

    smoother._smoother = Failing()
    with pytest.warns(RestartWarning, match="frame 6"):
        frame = smoother.update(seq.frame(6))
    assert smoother._smoother is not solver  # a new window
    assert smoother.recoveries == 1 and set(frame.status) == {"recovered"}
    for f in range(7, 12):
        smoother.update(seq.frame(f))
    final = smoother.finish()
    assert [fr.frame for fr in final] == list(range(12))
    assert all(np.all(np.isfinite(fr.thetas)) for fr in final)


def test_the_window_eliminates_points_then_tips_then_frame_vectors() -> None:
    assert elimination_group(point_key(1, 5)) == 0
    assert elimination_group(tip_key(3, 1)) == 1
    assert elimination_group(frame_key(3)) == 2


def test_an_elimination_order_with_more_groups_than_keys_is_safe_and_changes_nothing() -> None:
    """ccolamd wants every group label below the number of keys it orders: a first update with
    two keys and three groups must neither crash nor change the answer."""
    params = gtsam.ISAM2Params()
    plain = FixedLagISAM2(1.0, params)
    ordered = FixedLagISAM2(1.0, params, groups=elimination_group)
    noise = gtsam.noiseModel.Isotropic.Sigma(2, 0.1)
    for t in range(40):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        a, b = frame_key(t), point_key(0, t)
        graph.add(gtsam.PriorFactorVector(a, np.array([t, 1.0]), noise))
        graph.add(gtsam.BetweenFactorVector(a, b, np.array([0.5, 0.5]), noise))
        if t:
            graph.add(gtsam.BetweenFactorVector(frame_key(t - 1), a, np.array([1.0, 0.0]),
                                                noise))
        values.insert(a, np.zeros(2))
        values.insert(b, np.zeros(2))
        stamps = {a: 0.1 * t, b: 0.1 * t}
        for solver in (plain, ordered):
            solver.update(graph, values, stamps)
        np.testing.assert_allclose(ordered.calculateEstimate().atVector(a),
                                   plain.calculateEstimate().atVector(a), atol=1e-9)
        np.testing.assert_allclose(ordered.marginalCovariance(a), plain.marginalCovariance(a),
                                   atol=1e-9)
    assert min(ordered.stamps.values()) >= 3.9 - 1.0 - 0.25  # it marginalised


def test_the_window_has_no_point_variables_and_its_projection_factors_are_over_the_tips(
        ) -> None:
    """Model error as noise (the default, from the robot file): every variable in the window
    is a frame vector or a tip pose (each track's point is eliminated inside its factor), the
    projection factors span several tips, and every observation enters once (a second finish
    adds nothing)."""
    model, seq, truth, floor = fast_stretch_replay(30, exact=False)
    smoother = FixedLagSmoother(seq.robot, options=GraphOptions(theta0_sigma=START_SIGMA),
                                theta0=floor.thetas[0], psi0=floor.psis[0], spatial=True)
    assert smoother.measurement_model == "model noise"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for f in range(seq.n_frames):
            smoother.update(seq.frame(f))
        graph = smoother._smoother.getFactors()
        kinds, over_tips = set(), 0
        for i in range(graph.size()):
            factor = graph.at(i)
            if factor is None:
                continue
            letters = {kind(k) for k in factor.keys()}
            kinds |= letters
            over_tips += int(letters == {"t"} and len(factor.keys()) > 2)
        assert kinds == {"x", "t"} and over_tips > 0
        smoother.finish()
        committed = smoother.committed_observations
        smoother.finish()
    total = sum(len(trk.frames) for trk in seq.tracks.values())
    assert 0.9 * total <= committed <= total
    assert smoother.committed_observations == committed
    assert smoother.recoveries == 0


def test_a_piece_is_judged_against_its_robust_point_at_the_current_tips() -> None:
    """Eight frames of one camera whose tip slides sideways (2 cm a frame), looking at a point
    1 m away; one row is off by 25 sigma. The piece's robust point is near the true one, that
    row alone is judged an outlier, and the committed factor spans the camera's eight tips
    with no error left at them."""
    model, seq, truth, floor = fast_stretch_replay(2, exact=False)
    robot = seq.robot
    cam = robot.camera_segments[-1]
    mount = robot.cameras[cam].tip_T_cam
    tips = {}
    for f in range(8):
        tips[f] = np.broadcast_to(np.eye(4), (robot.n_segments, 4, 4)).copy()
        tips[f][cam, :3, 3] = 0.02 * f * mount[:3, 0]  # along the camera's x axis
    point = (tips[0][cam] @ mount @ np.array([0.02, -0.01, 1.0, 1.0]))[:3]
    xy = []
    for f in range(8):
        local = np.linalg.inv(tips[f][cam] @ mount) @ np.append(point, 1.0)
        xy.append(local[:2] / local[2])
    xy = np.array(xy)
    xy[2, 0] += 25.0 / 500.0  # 25 sigma off
    obs = TrackObservations.build(cam, range(8), [7] * 8, xy,
                                  np.broadcast_to(500.0 * np.eye(2), (8, 2, 2)))
    tracks = TipTracks(robot, GraphOptions(), SmootherOptions(), None,  # type: ignore[arg-type]
                       Bending.free(robot.segments), 3.5, tips)
    norms, points = tracks.robust_norms(cam, obs, np.ones(8))
    np.testing.assert_allclose(points[0], point, atol=5e-3)
    assert norms[2] > 20.0 and np.all(np.delete(norms, 2) < 0.5)
    graph = gtsam.NonlinearFactorGraph()
    tracks.commit(graph, cam, obs)
    assert tracks.committed == 8 and tracks.outliers == 1 and graph.size() == 1
    factor = graph.at(0)
    assert list(factor.keys()) == [tip_key(f, cam) for f in range(8)]
    # (the outlier row kept would cost about 25^2 / 2; one triangulation step per
    # linearisation from the robust point leaves a trace)
    assert factor.error(tracks.linear_values(cam, 0, 7)) < 1e-4
