"""The smoother with keyframes (:mod:`apcc_graph.estimation.smoother.keyframing`): every frame
gets an estimate at once and a final one, in order; only keyframes enter the window; a frame
between keyframes ends as the fit to its keyframes' final values.

Every simulation uses a fixed seed (the room scene of the smoother benchmark, 1 px, 10%
outliers, the shipped three-segment robot, 30 fps).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from apcc_graph.estimation.graph import camera_chain
from apcc_graph.estimation.initial_guess import refine
from apcc_graph.estimation.keyframe_fit import Keyframe, fit_between_keyframes, keyframe_points
from apcc_graph.estimation.keyframes import KeyframeRule
from apcc_graph.estimation.projection_tracks import frame_rows
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother.keyframing import BETWEEN
from apcc_graph.estimation.smoother_options import SmootherOptions, WindowOptions
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.parameterisation import Bending
from apcc_graph.simulation.simulator import simulate

ROBOT = Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml"
FRAMES = 75
RULE = KeyframeRule(rotation=0.1, max_interval=0.2, parallax=0.03)


def _run(rule: KeyframeRule | None, frames: int = FRAMES, seed: int = 3):
    """The smoother over a room-scene simulation: (sequence, estimates returned by each
    update, final estimates from pop_final and finish, the smoother)."""
    robot = load_robot(ROBOT)
    seq = simulate(robot, frames, noise_px=1.0, outlier_fraction=0.1, seed=seed, fps=30.0,
                   scene="room", n_points=4000).sequence
    smoother = FixedLagSmoother(robot, theta0=seq.thetas[0], settings=SmootherOptions(
        window=WindowOptions(lag=0.5), keyframes=rule))
    now, final = [], []
    for f in range(frames):
        now.append(smoother.update(seq.frame(f)))
        final += smoother.pop_final()
    final += smoother.finish()
    return seq, now, final, smoother


@pytest.fixture(scope="module")
def keyed():
    return _run(RULE)


def _rms(estimates, truth: np.ndarray) -> np.ndarray:
    err = np.array([e.thetas for e in estimates]) - truth
    return np.degrees(np.sqrt(np.mean(err**2, axis=0)))


def test_every_frame_once_in_order_and_between_frames_say_so(keyed) -> None:
    seq, now, final, smoother = keyed
    assert [e.frame for e in now] == list(range(FRAMES))
    assert [e.frame for e in final] == list(range(FRAMES))
    assert [e.timestamp for e in final] == [seq.frame(f).timestamp for f in range(FRAMES)]
    between = [e.frame for e in final if e.status[0] == BETWEEN]
    assert [e.frame for e in now if e.status[0] == BETWEEN] == between
    keys = smoother._keys
    # measured: 30 keyframes of 75, for rotation, parallax, time and the first unmeasured
    assert keys.keyframes + len(between) == FRAMES
    assert 0.2 * FRAMES < keys.keyframes < 0.8 * FRAMES
    assert smoother._window.count == keys.keyframes  # only keyframes entered the graph


def test_estimates_at_once_and_final_ones_are_close_to_the_truth(keyed) -> None:
    """Measured: at once 0.10 / 0.21 / 0.17 deg RMS, final 0.02 / 0.06 / 0.05."""
    seq, now, final, _ = keyed
    assert np.all(_rms(now, seq.thetas) < 0.5)
    assert np.all(_rms(final, seq.thetas) < 0.15)
    assert np.all(_rms(final, seq.thetas) < _rms(now, seq.thetas))


def test_a_between_frame_ends_as_the_fit_to_its_keyframes_final_values(keyed) -> None:
    """Recomputed from the outputs alone: the keyframes around a between frame at their
    final values, their points, the fit from its first estimate. The smoother fitted it as
    its keyframe left, when the keyframes after it had not quite their final values: equal
    to a fraction of the frame's sigma (measured: 0.1 sigma at most). And that fit is the
    batch over those keyframes and the frame's rows to within its sigma."""
    seq, now, final, _ = keyed
    robot = load_robot(ROBOT)
    bending = Bending.fixed(robot.segments)
    chains = {c: camera_chain(robot, c, bending) for c in robot.camera_segments}
    rows = [frame_rows(robot, f, seq.frame(f), 1.0) for f in range(FRAMES)]
    keys = [e.frame for e in final if e.status[0] != BETWEEN]
    checked = 0
    for e in final:
        if e.status[0] != BETWEEN:
            continue
        slot = int(np.searchsorted(keys, e.frame)) - 1
        around = [Keyframe(final[k].thetas, rows[k], None)
                  for k in keys[max(slot - 1, 0):slot + 3]]
        points = keyframe_points(around, chains)
        again = refine(now[e.frame].thetas, robot, bending, None, points.rows(rows[e.frame]),
                       3.5).thetas
        exact = fit_between_keyframes(now[e.frame].thetas, rows[e.frame], None, around,
                                      chains, bending, 3.5)
        sigma = np.sqrt(np.diag(exact.covariance))
        assert np.all(np.abs(e.thetas - again) < 0.5 * sigma), (e.frame, (e.thetas - again)
                                                                / sigma)
        assert np.all(np.abs(e.thetas - exact.x) < 1.5 * sigma), (e.frame, (e.thetas - exact.x)
                                                                  / sigma)
        checked += 1
    assert checked > 10


def test_keyframes_come_close_to_the_smoother_that_keeps_every_frame(keyed) -> None:
    """Same sequence: final RMS per segment at most 1.5x (measured: 0.6-1.2x)."""
    seq, _, final, _ = keyed
    _, _, every, smoother = _run(None)
    assert smoother._keys is None
    assert np.all(_rms(final, seq.thetas) < 1.5 * _rms(every, seq.thetas) + 0.005)


def test_a_keyframe_rule_that_is_not_one_is_refused_by_name() -> None:
    with pytest.raises(TypeError, match="SmootherOptions.keyframes: expected KeyframeRule"):
        SmootherOptions(keyframes=0.1)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="KeyframeRule.rotation"):
        KeyframeRule(rotation=-math.radians(1.0))
