"""The smoother with keyframes (:mod:`apcc_graph.estimation.smoother.keyframing`): every frame
gets an estimate at once and a final one, in order; iSAM2 runs at keyframes only; no row is
dropped, so the final estimates are those of the smoother that solves at every frame.

Every simulation uses a fixed seed (the room scene of the smoother benchmark, 1 px, 10%
outliers, the shipped three-segment robot, 30 fps).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from apcc_graph.estimation.keyframes import KeyframeRule
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother.keyframing import PENDING
from apcc_graph.estimation.smoother_options import SmootherOptions, WindowOptions
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.sequence import FrameObservations
from apcc_graph.simulation.simulator import simulate

ROBOT = Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml"
FRAMES = 60
RULE = KeyframeRule(rotation=0.1, max_interval=0.2, parallax=0.03)


class CountingSolver:
    """Counts the smoother's iSAM2 updates (wraps its window)."""

    def __init__(self, inner) -> None:
        self.inner, self.updates = inner, 0

    def update(self, *args, **kwargs):
        self.updates += 1
        return self.inner.update(*args, **kwargs)

    def __getattr__(self, name: str):
        return getattr(self.inner, name)


def _run(rule: KeyframeRule | None, frames: int = FRAMES, seed: int = 2,
         drop: tuple[int, ...] = (), busy: bool = False):
    """The smoother over a room-scene simulation (the frames ``drop`` without observations):
    (sequence, estimates returned by each update, final estimates from pop_final and finish,
    the smoother, its iSAM2 updates)."""
    robot = load_robot(ROBOT)
    seq = simulate(robot, frames, noise_px=1.0, outlier_fraction=0.1, seed=seed, fps=30.0,
                   scene="room", n_points=4000).sequence
    smoother = FixedLagSmoother(robot, theta0=seq.thetas[0], settings=SmootherOptions(
        window=WindowOptions(lag=0.5), keyframes=rule))
    counter = CountingSolver(smoother._smoother)
    smoother._smoother = counter
    now, final = [], []
    for f in range(frames):
        obs = seq.frame(f)
        if f in drop:
            obs = FrameObservations(obs.timestamp, {}, world_T_base=obs.world_T_base)
        now.append(smoother.update(obs, busy=busy))
        final += smoother.pop_final()
    final += smoother.finish()
    return seq, now, final, smoother, counter.updates


@pytest.fixture(scope="module")
def every():
    return _run(None)


@pytest.fixture(scope="module")
def keyed():
    return _run(RULE)


def _rms(estimates, truth: np.ndarray) -> np.ndarray:
    err = np.array([e.thetas for e in estimates]) - truth
    return np.degrees(np.sqrt(np.mean(err**2, axis=0)))


def test_every_frame_once_in_order_and_pending_ones_say_so(keyed) -> None:
    seq, now, final, smoother, updates = keyed
    assert [e.frame for e in now] == list(range(FRAMES))
    assert [e.frame for e in final] == list(range(FRAMES))
    assert [e.timestamp for e in final] == [seq.frame(f).timestamp for f in range(FRAMES)]
    pending = [e.frame for e in now if e.status[0] == PENDING]
    keys = smoother._keys
    assert keys.frames == FRAMES and keys.keyframes + len(pending) == FRAMES
    assert 0 not in pending
    # measured: 26 keyframes of 60 (the first, 14 of the warm-up, rotation 10, time 3)
    assert 0.2 * FRAMES < keys.keyframes < 0.7 * FRAMES
    assert updates == keys.keyframes + 1  # one update per keyframe, one at the end
    assert not any(e.status[0] == PENDING for e in final)
    assert np.all(np.isnan([e.sigmas for e in now if e.status[0] == PENDING]))
    assert np.all(np.isfinite([e.sigmas for e in final]))


def test_final_estimates_are_the_every_frame_smoothers(keyed, every) -> None:
    """Same rows, fewer updates: each final estimate within two of its sigmas of the
    smoother that solves at every frame (measured: 0.73 sigma at most; rows are judged at
    other estimates). Over 60 frames that moves the RMS by up to 1.8x per segment (0.041 /
    0.053 / 0.049 against 0.022 / 0.036 / 0.040 deg), too few frames to compare RMS: the
    smoother benchmark compares them over 5 x 600 frames (bench smoother)."""
    seq, _, final, _, _ = keyed
    _, _, reference, smoother, updates = every
    assert smoother._keys is None and updates == FRAMES + 1
    x = np.array([e.thetas for e in final])
    ref = np.array([e.thetas for e in reference])
    sigma = np.array([e.sigmas for e in reference])
    assert np.all(np.abs(x - ref) < 2.0 * sigma), np.max(np.abs(x - ref) / sigma)


def test_estimates_at_once_are_the_frame_step_and_close(keyed) -> None:
    """A pending frame's estimate at once is its fit to the points the window knows: after
    the first second (measured) 0.16 / 0.14 / 0.15 deg RMS, against 0.04 / 0.05 / 0.05
    final."""
    seq, now, final, _, _ = keyed
    pending = [e for e in now[30:] if e.status[0] == PENDING]
    assert len(pending) > 10
    truth = seq.thetas[[e.frame for e in pending]]
    assert np.all(_rms(pending, truth) < 0.4)
    assert np.all(_rms(final, seq.thetas) < 0.1)


def test_a_frame_without_observations_is_a_keyframe_and_nothing_is_lost() -> None:
    """Frame 30 sees nothing: the frame step cannot measure it, so it is a keyframe; every
    frame still comes out once, in order."""
    seq, now, final, smoother, _ = _run(RULE, frames=40, drop=(30,))
    assert [e.frame for e in final] == list(range(40))
    assert now[30].status[0] != PENDING
    assert smoother._keys.reasons.get("unmeasured", 0) >= 1


def test_a_keyframe_rule_that_is_not_one_is_refused_by_name() -> None:
    with pytest.raises(TypeError, match="SmootherOptions.keyframes: expected KeyframeRule"):
        SmootherOptions(keyframes=0.1)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="KeyframeRule.rotation"):
        KeyframeRule(rotation=-math.radians(1.0))


class FailAt:
    """The smoother's window, raising a gtsam error at its ``at``-th update from now."""

    def __init__(self, inner, at: int) -> None:
        self.inner, self.left = inner, at

    def update(self, *args, **kwargs):
        self.left -= 1
        if self.left == 0:
            raise RuntimeError("indeterminate linear system")
        return self.inner.update(*args, **kwargs)

    def __getattr__(self, name: str):
        return getattr(self.inner, name)


def test_a_gtsam_failure_at_a_keyframe_restarts_and_loses_no_frame() -> None:
    """iSAM2 fails at a keyframe's update: the window restarts at that frame (the frames that
    waited for it leave with their own fits), the frames of the next second are keyframes (as
    after the first frame), and every frame still comes out once, in order (measured: 0.11 deg
    at worst before, 0.31 after; with no such warm-up 0.91 after)."""
    from apcc_graph.estimation.window import RestartWarning

    robot = load_robot(ROBOT)
    seq = simulate(robot, 50, noise_px=1.0, outlier_fraction=0.1, seed=2, fps=30.0,
                   scene="room", n_points=4000).sequence
    smoother = FixedLagSmoother(robot, theta0=seq.thetas[0], settings=SmootherOptions(
        window=WindowOptions(uncertainty=False), keyframes=RULE))
    for f in range(30):
        smoother.update(seq.frame(f))
    keys = smoother._keys.keyframes
    smoother._smoother = FailAt(smoother._smoother, 1)
    with pytest.warns(RestartWarning):
        for f in range(30, 50):
            smoother.update(seq.frame(f))
    assert smoother.recoveries == 1
    assert smoother._keys.reasons["first"] == 2  # the frame after the restart
    assert smoother._keys.reasons["warm-up"] >= 29 + 10  # the second after each
    assert smoother._keys.keyframes > keys
    final = smoother.finish()
    assert [e.frame for e in final] == list(range(50))
    err = np.degrees(np.abs(np.array([e.thetas for e in final]) - seq.thetas))
    assert err[:25].max() < 0.3 and err.max() < 0.6, (err[:25].max(), err.max())


def test_a_busy_caller_defers_keyframes_up_to_the_rules_limit(keyed) -> None:
    """Every frame given with ``busy`` (the live loop with frames waiting): after the warm-up
    the rule's keyframes wait until the last keyframe is ``max_deferral`` old, so fewer solves
    (counted on the window) and never two rule-made keyframes closer than that; every frame
    still gets its estimate at once and its final one, in order, and the finals stay within
    0.5 deg RMS of the truth."""
    rule = KeyframeRule(rotation=0.1, max_interval=0.1, parallax=0.03, max_deferral=0.2)
    seq, now, final, smoother, updates = _run(rule, busy=True)
    keys = smoother._keys
    assert keys.deferred > 0
    _, _, _, calm, calm_updates = _run(rule)
    assert updates < calm_updates and calm._keys.deferred == 0
    solved = [e.timestamp for e in now if e.status[0] != PENDING]
    after = [t for t in solved if t >= 0.5]  # the warm-up solves every frame for one lag
    assert np.all(np.diff(after) >= 0.2 - 1e-6 - 1 / 30.0), np.diff(after)
    assert [e.frame for e in final] == list(range(FRAMES))
    assert np.all(_rms(final, seq.thetas) < 0.5), _rms(final, seq.thetas)
