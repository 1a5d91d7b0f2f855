"""The residual test (:mod:`apcc_graph.estimation.model_fit`): does the kinematic model explain
the images? Quiet on model-exact data, loud on the real robot's replayed motion (where the
exact-model batch is driven tens of millimetres off while its sigmas say a tenth of a degree),
and loud on a wrong estimate."""

from __future__ import annotations

import math
import warnings
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from helpers import fast_stretch_replay

from apcc_graph.cli import main
from apcc_graph.estimation.methods import estimate
from apcc_graph.estimation.model_fit import (
    MIN_REJECTED,
    CameraFit,
    ModelFit,
    ModelFitWarning,
    check_model_fit,
    expected_share,
)
from apcc_graph.estimation.options import GraphOptions, Robustness
from apcc_graph.evaluation.tip_floor import TipFloor
from apcc_graph.io import load_robot
from apcc_graph.io.sequence_folder import save_sequence
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.sequence import Sequence
from apcc_graph.simulation.simulator import Simulation, simulate

ROOT = Path(__file__).resolve().parents[1]


@cache
def _simulation() -> Simulation:
    robot = load_robot(ROOT / "data" / "robots" / "planar_three.toml")
    return simulate(robot, 60, noise_px=1.0, outlier_fraction=0.1, seed=3, scene="room",
                    n_points=2000)


def _replay(exact: bool, frames: int = 40) -> tuple[Sequence, TipFloor]:
    """The first frames of the fast stretch of the shipped real recording (cameras on the
    measured segment ends, or on the model's tips at the floor's bends), and the floor."""
    _, seq, _, floor = fast_stretch_replay(frames, exact)
    return seq, floor


def test_expected_share_hand_computed() -> None:
    T = 3.5
    # long tracks: a row's error is chi^2_2, its tail exp(-T^2 / 2)
    assert expected_share(np.array([10**6]), T) == pytest.approx(math.exp(-T**2 / 2), rel=1e-5)
    # a track of 3 rows keeps half the degrees of freedom per row: c = 3 / 6
    assert expected_share(np.array([3]), T) == pytest.approx(math.exp(-T**2), rel=1e-12)
    # two rows: the point fits both exactly (c = 1/4)
    assert expected_share(np.array([2, 2]), T) == pytest.approx(math.exp(-2 * T**2))
    assert expected_share(np.array([], dtype=np.int64), T) == 0.0


def test_the_verdict_needs_enough_rejections_and_a_share_above_the_alarm() -> None:
    shares = np.full(5, np.nan)

    def camera(accepted: int, rejected: int) -> CameraFit:
        return CameraFit(0, accepted, accepted, rejected, 0.002, shares)

    assert ModelFit((camera(1000, 60),), 0.05, 3.5).failing()  # 6% > 5%
    assert ModelFit((camera(1000, 40),), 0.05, 3.5).explained  # 4%
    few = MIN_REJECTED - 1
    assert ModelFit((camera(few * 2, few),), 0.05, 3.5).explained  # 50%, but too few
    assert ModelFit((), 0.05, 3.5).message() == ""


def test_quiet_on_model_exact_data() -> None:
    sim = _simulation()
    seq = sim.sequence
    with warnings.catch_warnings():
        warnings.simplefilter("error", ModelFitWarning)
        est = estimate(seq, method="batch", theta0=seq.thetas[0])
    fit = est.model_fit
    assert fit is not None and fit.explained
    assert {c.camera for c in fit.cameras} == set(seq.robot.camera_segments)
    for c in fit.cameras:
        # the images alone keep the true observations (10% are wrong associations)
        assert 0.8 < c.accepted / c.observations < 0.95
        # the model rejects the share Gaussian noise puts beyond the threshold, no more
        assert c.share < 3.0 * c.expected + 0.002
        # a track's own point absorbs some of its noise: never more than a chi^2_2 tail
        assert 0.0 < c.expected < math.exp(-3.5**2 / 2)
        assert c.frame_shares.shape == (seq.n_frames,)


def test_a_wrong_estimate_fails_on_the_cameras_it_moves() -> None:
    sim = _simulation()
    seq = sim.sequence
    bending = Bending.fixed(seq.robot.segments)
    wrong = seq.thetas.copy()
    wrong[:, 1] += math.radians(3.0) * np.sin(np.linspace(0, 6, seq.n_frames))
    with pytest.warns(ModelFitWarning, match="segment 2's camera"):
        fit = check_model_fit(seq, wrong, bending)
    verdict = {c.camera: c in fit.failing() for c in fit.cameras}
    assert verdict == {0: False, 1: True, 2: True}  # camera 1 rides before segment 2
    right = check_model_fit(seq, seq.thetas, bending, warn=False)
    assert right.explained


def test_loud_on_the_real_robots_motion_quiet_on_its_model_exact_version() -> None:
    verdicts = {}
    for exact in (False, True):
        seq, floor = _replay(exact)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            est = estimate(seq, method="batch", spatial=True, theta0=floor.thetas[0],
                           psi0=floor.psis[0], theta0_sigma=math.radians(2.0),
                           graph=GraphOptions(model_sigma=None))  # the exact model
        said = [w for w in caught if issubclass(w.category, ModelFitWarning)]
        assert est.model_fit is not None
        verdicts[exact] = (est.model_fit, said, est)
    fit, said, est = verdicts[False]
    # the exact-model batch on the measured motion is confidently wrong ...
    nees = (est.errors(_replay(False)[1].thetas, _replay(False)[1].psis)
            / est.bend_sigmas()) ** 2
    assert np.nanmean(nees) > 100.0
    # ... and the residual test says so
    assert not fit.explained and len(said) == 1
    assert "batch: the images contradict the estimate" in str(said[0].message)
    assert max(c.share for c in fit.cameras) > 0.05
    fit, said, _ = verdicts[True]
    assert fit.explained and not said
    assert max(c.share for c in fit.cameras) < 0.02


def test_skipped_when_asked_and_refused_when_the_alarm_is_no_share() -> None:
    seq = _simulation().sequence.head(20)
    est = estimate(seq, method="batch", theta0=seq.thetas[0],
                   robustness=Robustness(misfit_alarm=None))
    assert est.model_fit is None
    assert estimate(seq, method="chain", theta0=seq.thetas[0]).model_fit is None
    for bad in (0.0, 1.0, -0.1, math.nan):
        with pytest.raises(ValueError, match="misfit_alarm"):
            Robustness(misfit_alarm=bad)
    with pytest.raises(ValueError, match=r"frame vectors of shape \(19, 3\)"):
        check_model_fit(seq, seq.thetas[:19], Bending.fixed(seq.robot.segments))


def test_the_command_line_prints_the_test(tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    seq = _simulation().sequence.head(30)
    save_sequence(seq, tmp_path / "seq")
    theta0 = ",".join(f"{v:.6f}" for v in np.degrees(seq.thetas[0]))
    assert main(["estimate", str(tmp_path / "seq"), "--method", "smoother",
                 f"--theta0-deg={theta0}", "--out", str(tmp_path / "est")]) == 0
    out = capsys.readouterr().out
    assert "residual test" in out
    assert out.count("images alone accept") == 3 and out.count(": ok") == 4
    assert "first frame moved from the start by" in out


def test_a_first_frame_pulled_far_from_its_start_prior_fails() -> None:
    sim = _simulation()
    seq = sim.sequence
    bending = Bending.fixed(seq.robot.segments)
    sigma0 = math.radians(0.1)
    start = seq.thetas[0].copy()
    fit = check_model_fit(seq, seq.thetas, bending, start=(start + 0.5 * sigma0, sigma0),
                          warn=False)
    assert fit.start is not None and fit.start.chi2 == pytest.approx(3 * 0.25)
    assert not fit.start_contradicted and fit.explained
    # the images explain the bends, but they sit 1 deg from a 0.1 deg start prior: a wrong
    # start, or a model the images pulled away from it
    start[1] += math.radians(1.0)
    with pytest.warns(ModelFitWarning, match="first frame moved from the start by"):
        fit = check_model_fit(seq, seq.thetas, bending, start=(start, sigma0))
    assert not fit.failing() and fit.start_contradicted and not fit.explained
    assert fit.start is not None and fit.start.chi2 == pytest.approx(100.0)
    # chi-square with 3 degrees of freedom beyond probability 1e-4
    assert fit.start.limit == pytest.approx(21.108, abs=1e-3)
