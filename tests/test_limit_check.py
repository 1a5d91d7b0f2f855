"""A bend at its joint limit is never reported with a small sigma, and frames where the
residual test fails are flagged (``apcc_graph.estimation.limit_check``)."""

from __future__ import annotations

import math
import warnings
from dataclasses import replace

import numpy as np
import pytest
from helpers import fast_stretch_replay

from apcc_graph.bench.smoother import FPS, ROBOT_FILE
from apcc_graph.estimation.limit_check import (
    AT_LIMIT,
    MISFIT,
    LimitWarning,
    at_the_limits,
    flag_misfits,
    wrong_basin,
)
from apcc_graph.estimation.methods import estimate
from apcc_graph.estimation.model_fit import CameraFit, ModelFit
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.start_search import UnknownStartError
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


def _fit(shares: list[list[float]], rejected: int = 100) -> ModelFit:
    """A residual test of two cameras (segments 1 and 2) with these per-frame shares."""
    cameras = tuple(CameraFit(c, 1000, 900, rejected, 0.002, np.array(s, dtype=float))
                    for c, s in enumerate(shares))
    return ModelFit(cameras, 0.05, 3.5)


def test_frames_where_the_residual_test_fails_are_flagged() -> None:
    """Camera 2 fails in frames 1 and 3: those frames are ``misfit`` for segments 1 and 2 (both
    place camera 2), except a bend whose status already says something (at its limit,
    reacquired); camera 1's frames above the alarm are not flagged while camera 1 passes as a
    whole (few rejected); a passing test changes nothing."""
    sim = simulate(load_robot(ROBOT_FILE), 5, noise_px=1.0, seed=4, fps=FPS, n_points=200)
    est = estimate(sim.sequence, method="chain", theta0=sim.sequence.thetas[0])
    status = np.full(est.status.shape, "ok", dtype=est.status.dtype)
    status[3, 0] = AT_LIMIT
    status[1, 2] = "reacquired"
    est = replace(est, status=status)
    camera_2 = [0.0, 0.2, 0.01, 0.3, math.nan]
    fit = _fit([[0.5] * 5, camera_2])
    fit = ModelFit((replace(fit.cameras[0], rejected=5), fit.cameras[1]), 0.05, 3.5)
    flagged = flag_misfits(est, fit)
    misfit = flagged.status == MISFIT
    assert misfit[:, :2].tolist() == [[False, False], [True, True], [False, False],
                                      [False, True], [False, False]]
    assert flagged.status[3, 0] == AT_LIMIT and not misfit[:, 2].any()
    assert flagged.status[1, 2] == "reacquired"
    assert flag_misfits(est, _fit([[0.0] * 5, [0.01] * 5], rejected=5)) is est


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_the_exact_model_on_real_motion_is_flagged() -> None:
    """The exact-model batch on 20 frames of the real robot's replayed motion fails the
    residual test and flags frames ``misfit``; the same on the model-exact version of the
    motion flags none."""
    for exact, flags in ((False, True), (True, False)):
        _, seq, _, floor = fast_stretch_replay(20, exact=exact)
        est = estimate(seq, method="batch", theta0=floor.thetas[0], psi0=floor.psis[0],
                       spatial=True, theta0_sigma=math.radians(2.0),
                       graph=GraphOptions(model_sigma=None))
        assert bool((est.status == MISFIT).any()) == flags, est.model_fit
        assert (est.model_fit is not None and not est.model_fit.explained) == flags


def test_an_unknown_start_that_ends_at_the_limits_is_a_wrong_basin(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """:func:`wrong_basin` names a segment at its limit in more than a tenth of the frames and
    nothing below that; from a start found in the images, :func:`estimate` raises
    :class:`UnknownStartError` with it (the estimator's answer replaced by one at the limit),
    and with a given start it keeps the answer, flagged."""
    import apcc_graph.estimation.methods as methods

    sim = simulate(load_robot(ROBOT_FILE), 20, noise_px=1.0, seed=4, fps=FPS, n_points=800)
    seq = sim.sequence
    est = estimate(seq, method="chain", theta0=seq.thetas[0])
    status = est.status.copy()
    status[:2, 1] = AT_LIMIT  # 10%: not more
    assert wrong_basin(replace(est, status=status)) is None
    status[:3, 1] = AT_LIMIT
    why = wrong_basin(replace(est, status=status))
    assert why is not None and "segment 2 in 15% of the frames" in why
    limit = seq.robot.segments[0].theta_max
    original = methods._run

    def at_the_limit(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        found = original(*args, **kwargs)
        thetas = found.thetas.copy()
        thetas[:, 0] = limit
        return replace(found, thetas=thetas)

    monkeypatch.setattr(methods, "_run", at_the_limit)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(UnknownStartError, match="segment 1 in 100% of the frames"):
            estimate(seq, method="chain")
        kept = estimate(seq, method="chain", theta0=seq.thetas[0])
    assert (kept.status[:, 0] == AT_LIMIT).all()
