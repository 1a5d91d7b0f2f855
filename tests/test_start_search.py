"""Starting from an unknown shape: the search, its refusals, the API and the command line."""

from __future__ import annotations

import math
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from helpers import fast_stretch_replay

import apcc_graph
from apcc_graph.bench import ROBOT_FILE
from apcc_graph.cli import main
from apcc_graph.estimation.methods import estimate
from apcc_graph.estimation.noise_information import start_blocks
from apcc_graph.estimation.options import GraphOptions, Robustness
from apcc_graph.estimation.start_search import (
    Hypothesis,
    UnknownStartError,
    _not_the_images,
    _undetermined,
    find_start,
    start_from_data,
    start_hypotheses,
)
from apcc_graph.evaluation.sequence_bound import sequence_bound
from apcc_graph.io import load_robot, save_sequence
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.sequence import Sequence
from apcc_graph.simulation.simulator import Simulation, simulate

OPTIONS = GraphOptions(threshold_px=1.0)


def _simulate(n_frames: int, seed: int = 1, bends: np.ndarray | None = None) -> Simulation:
    return simulate(load_robot(ROBOT_FILE), n_frames, noise_px=1.0, outlier_fraction=0.1,
                    seed=seed, scene="room", bends=bends)


@pytest.fixture(scope="module")
def one_second() -> Simulation:
    return _simulate(31)


def test_hypotheses_spread_the_first_segment() -> None:
    robot = load_robot(ROBOT_FILE)
    starts = start_hypotheses(Bending.fixed(robot.segments))
    assert starts.shape == (3, 3)
    assert np.all(starts[:, 1:] == 0.0)
    assert sorted(starts[:, 0]) == pytest.approx([-math.radians(30), 0.0, math.radians(30)])
    # free planes: straight and a ring of three bending vectors of half theta_max
    free = Bending.free(robot.segments)
    ring = start_hypotheses(free)
    assert ring.shape == (4, 6) and np.all(ring[:, 2:] == 0.0)
    lengths = free.magnitudes(ring)[:, 0]
    assert sorted(lengths) == pytest.approx([0.0] + [math.radians(30)] * 3)
    planes = np.sort(np.degrees(free.polar(ring[1:])[1][:, 0]))
    np.testing.assert_allclose(planes, [-120.0, 0.0, 120.0], atol=1e-9)


def test_an_unknown_start_is_found_within_its_bound(one_second: Simulation) -> None:
    """From no prior at all, one second of images: the start within 3 of its own sigmas, and
    those sigmas are the vision-only Cramer-Rao bound of that second."""
    truth = one_second.sequence.thetas[0]
    assert np.max(np.abs(truth)) > math.radians(15)  # not straight: the old default is wrong
    search = find_start(one_second.sequence, 1.0, OPTIONS)
    bound = sequence_bound(one_second, 1.0, theta0_sigma=None).sigmas[0]
    assert search.determined and search.reason == ""
    assert search.n_frames == 31 and search.seconds == pytest.approx(1.0)
    assert np.all(np.abs(search.theta0 - truth) < 3.0 * search.sigma0)
    assert np.all((search.sigma0 > 0.8 * bound) & (search.sigma0 < 1.25 * bound))
    costs = [h.cost for h in search.hypotheses]
    assert costs == sorted(costs) and len(costs) == 3
    report = search.report()
    assert np.array_equal(report.theta0, search.theta0) and report.hypotheses == 3


def test_standing_still_is_refused_not_guessed() -> None:
    still = _simulate(45, seed=2, bends=np.tile(np.radians([20.0, -10.0, 15.0]), (45, 1)))
    search = find_start(still.sequence, 1.0, OPTIONS)
    assert not search.determined
    assert "barely moved" in search.reason and "segment 1" in search.reason
    with pytest.raises(UnknownStartError, match="whole recording.*theta0"):
        start_from_data(still.sequence, options=OPTIONS)
    with pytest.raises(UnknownStartError, match="barely moved"):
        apcc_graph.estimate(still.sequence, method="batch")


def test_still_at_first_then_found_once_it_moves() -> None:
    """The robot stands still for 1.5 s, then moves: the window grows until it tells."""
    moving = _simulate(120, seed=1).sequence.thetas
    bends = np.vstack([np.tile(moving[0], (45, 1)), moving[:75]])
    sim = _simulate(120, seed=1, bends=bends)
    assert not find_start(sim.sequence, 1.0, OPTIONS).determined
    search = start_from_data(sim.sequence, options=OPTIONS)
    assert search.determined and search.seconds > 1.9
    assert np.all(np.abs(search.theta0 - bends[0]) < 3.0 * search.sigma0)


def test_a_blind_camera_is_named(one_second: Simulation) -> None:
    seq = one_second.sequence
    blind = Sequence(seq.robot, seq.timestamps, {c: t for c, t in seq.tracks.items() if c != 0})
    search = find_start(blind, 1.0, OPTIONS)
    assert not search.determined
    assert "cam_1 (0)" in search.reason


def test_two_distant_fits_of_equal_cost_are_ambiguous(one_second: Simulation) -> None:
    window = one_second.sequence
    thetas = np.zeros((window.n_frames, 3))
    blocks = np.full((window.n_frames, 3, 1, 1), math.radians(1.0) ** 2)
    planar = Bending.fixed(window.robot.segments)

    def hyp(offset_deg: float, cost: float) -> Hypothesis:
        return Hypothesis(np.zeros(3), thetas + math.radians(offset_deg), blocks, cost)

    def why(*hyps: Hypothesis) -> str:
        return _undetermined(window, planar, list(hyps), math.radians(5), 9.0)

    assert why(hyp(0, 100.0), hyp(0.5, 101.0)) == ""
    assert why(hyp(0, 100.0), hyp(10, 150.0)) == ""
    reason = why(hyp(0, 100.0), hyp(10, 104.0))
    assert "two starts" in reason and "104.0" in reason


def test_find_start_refuses_bad_arguments(one_second: Simulation) -> None:
    for kwargs in ({"seconds": 0.0}, {"max_sigma": -1.0}, {"prior_sigma": math.nan}):
        with pytest.raises(ValueError, match=next(iter(kwargs))):
            find_start(one_second.sequence, **{"seconds": 1.0, **kwargs})


def test_estimate_without_a_start_reports_where_it_found_it() -> None:
    sim = _simulate(60, seed=4)
    est = apcc_graph.estimate(sim.sequence, method="batch", noise_px=1.0)
    assert est.start is not None and est.start.n_frames == 31
    truth = sim.sequence.thetas
    assert np.all(np.abs(est.start.theta0 - truth[0]) < 3.0 * est.start.sigma0)
    # the batch over two seconds refines the start's second: within 4 of its own sigmas
    assert np.all(np.abs(est.thetas - truth) < 4.0 * est.sigmas)
    with pytest.raises(ValueError, match="theta0_sigma without theta0"):
        apcc_graph.estimate(sim.sequence, method="batch", theta0_sigma=0.01)
    given = apcc_graph.estimate(sim.sequence, method="chain", theta0=truth[0])
    assert given.start is None


def test_sequence_head_cuts_everything(one_second: Simulation) -> None:
    seq = one_second.sequence
    head = seq.head(10)
    assert head.n_frames == 10 and np.array_equal(head.thetas, seq.thetas[:10])
    for cam, trk in head.tracks.items():
        assert trk.frames.max() == 9
        assert len(trk) == int(np.sum(seq.tracks[cam].frames < 10))
    assert head.frame(9).tracks[0][0].tolist() == seq.frame(9).tracks[0][0].tolist()
    for bad in (0, 32):
        with pytest.raises(ValueError, match="n_frames"):
            seq.head(bad)


def test_cli_estimates_without_a_start(tmp_path: Path, one_second: Simulation,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "seq"
    save_sequence(one_second.sequence, folder)
    assert main(["estimate", str(folder), "--method", "batch", "--out", str(tmp_path / "e"),
                 "--noise-px", "1"]) == 0
    out = capsys.readouterr().out
    found = re.search(r"start found from the first 1\.00 s \(31 frames\): (.*) deg", out)
    assert found
    values = [float(part.split("+/-")[0]) for part in found.group(1).split(",")]
    assert np.allclose(values, np.degrees(one_second.sequence.thetas[0]), atol=8.0)
    assert (tmp_path / "e" / "theta.csv").is_file()
    code = main(["estimate", str(folder), "--out", str(tmp_path / "f"),
                 "--theta0-sigma-deg", "0.5"])
    assert code == 1
    assert "--theta0-sigma-deg applies to a given start" in capsys.readouterr().err
    assert not (tmp_path / "f").exists()


def test_bench_start_small_run(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "start", "--runs", "2", "--seed", "1", "--workers", "1"]) == 0
    text = capsys.readouterr().out
    assert "start search over 2 recordings of 1 s" in text
    meets = int(re.search(r"meets the bound .*: (\d+)", text).group(1))
    told_not = int(re.search(r"said it could not tell: (\d+)", text).group(1))
    assert meets + told_not == 2 and "silent failures): 0" in text
    assert re.search(r"target .*: (met|not met)", text)


def test_a_best_start_at_the_joint_limits_is_not_the_images_word(one_second: Simulation
                                                                  ) -> None:
    """A winner that reaches a joint limit (within ``limit_sigma``) in any frame of the window
    is not determined, naming the segment; 2 deg inside the limit it is."""
    seq = one_second.sequence
    bending = Bending.fixed(seq.robot.segments)
    limit = seq.robot.segments[1].theta_max
    x = np.array(seq.thetas, dtype=float)
    blocks = np.full((seq.n_frames, seq.n_segments, 1, 1), 1e-4)
    x[5, 1] = -(limit - math.radians(2.0))
    inside = _not_the_images(seq, bending, Hypothesis(x[0], x, blocks, 0.0), OPTIONS,
                             Robustness())
    assert inside == "", inside
    x[5, 1] = -(limit - math.radians(0.5))
    why = _not_the_images(seq, bending, Hypothesis(x[0], x, blocks, 0.0), OPTIONS,
                          Robustness())
    assert "joint limits (segment 2 at" in why, why


def test_the_unknown_start_on_real_motion_is_refused_not_wrong() -> None:
    """The first second (18 frames) of the real robot's fast replayed stretch, with the model
    calibrated on the recording: the exact model's best start is more than 20 deg from the
    measured bends (without the residual test the search calls it determined); the residual
    test fails at it, so the search says the model does not explain the images and
    :func:`estimate` raises :class:`UnknownStartError` rather than answer. On the model-exact
    version of the motion the test passes at the search's best start."""
    _, seq, _, floor = fast_stretch_replay(18, exact=False)
    bending = Bending.free(seq.robot.segments)
    blind = find_start(seq, spatial=True, robustness=Robustness(misfit_alarm=None))
    off = np.degrees(np.abs(blind.x0 - bending.vector(floor.thetas, floor.psis)[0]).max())
    assert blind.determined and off > 20.0, (blind.reason, off)
    with pytest.raises(UnknownStartError, match="the model does not explain the first"):
        estimate(seq, "batch", spatial=True)
    _, exact, _, _ = fast_stretch_replay(18, exact=True)
    search = find_start(exact, spatial=True)
    assert "does not explain" not in search.reason, search.reason


def test_with_a_model_error_the_sigmas_are_the_images_and_the_models(
        one_second: Simulation) -> None:
    """With a model error as noise (here 5 mm / 3 deg, far more than the model-exact recording
    has) the search's sigmas of frame 0 are those of the information with that noise at its
    winner (:func:`start_blocks`), larger than the exact model's on every segment; past the
    bar the search is undetermined, and says the model's error may be why."""
    seq = one_second.sequence
    exact = find_start(seq, options=replace(OPTIONS, model_sigma=None))
    noisy_options = replace(OPTIONS, model_sigma=(5e-3, math.radians(3.0)))
    noisy = find_start(seq, options=noisy_options)
    # The same basin (the noisy search's hypotheses are propagated by the rotations).
    np.testing.assert_allclose(noisy.x0, exact.x0, atol=math.radians(2.0))
    blocks = start_blocks(seq, noisy.hypotheses[0].x, noisy.bending, noisy_options, 3.5,
                          math.radians(30.0))
    np.testing.assert_allclose(noisy.sigma0, np.sqrt(blocks[:, 0, 0]), rtol=1e-9)
    assert np.all(noisy.sigma0 > exact.sigma0), (noisy.sigma0, exact.sigma0)
    tight = find_start(seq, options=noisy_options, max_sigma=0.5 * float(noisy.sigma0.max()))
    assert not tight.determined and "the model's error" in tight.reason, tight.reason
