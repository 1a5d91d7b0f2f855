"""Tests of the real-robot tools on synthetic motion-capture data generated from the model.

A two-segment robot (the real TDCR's lengths) sweeps both segments through 10..80 deg in
changing bending planes; the backbone frames are the model's (``Robot.forward`` from a fixed base
pose), and each motion-capture marker sits at a known offset ``backbone_T_marker`` from its
backbone frame: the base, both segment ends, and a held-out marker half way along segment 1.
On such data the calibration (:func:`fit_backbone`) must give back the model, the replay
(:func:`replay_motion`) must put the cameras exactly on the model's tips, and the floor
(:func:`tip_floor`) must be zero. The command line is run in-process through ``cli.main``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from apcc_graph.bench.real_robot import format_real_bench, run_real_bench
from apcc_graph.calibration.backbone_fit import BackboneCalibration, fit_backbone
from apcc_graph.calibration.backbone_model import pose_matrices, segment_transform
from apcc_graph.cli import main
from apcc_graph.evaluation.tip_floor import rotation_floor, tip_errors, tip_floor
from apcc_graph.io import load_sequence, save_backbone_poses, save_sequence
from apcc_graph.io.backbone_poses import BackbonePoses
from apcc_graph.io.robot_file import load_markers, load_robot, save_robot
from apcc_graph.model.bending import bending_transform
from apcc_graph.model.camera import TipCamera
from apcc_graph.model.robot import Robot
from apcc_graph.model.segment import Segment
from apcc_graph.simulation.replay import Replay, measured_ends, motion_stretches, replay_motion

RATE = 16.7
"""Motion-capture sample rate (Hz)."""
LENGTH = 0.233
CAMERA = TipCamera(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480)
THETA_MAX = math.radians(120.0)
ROBOT = Robot([Segment(LENGTH, k=0.18, delta_max=math.radians(12.0), theta_max=THETA_MAX),
               Segment(LENGTH, k=0.3, delta_max=math.radians(-6.0), theta_max=THETA_MAX)],
              [CAMERA, CAMERA])
ARCLENGTHS = np.array([0.0, 0.5 * LENGTH, LENGTH, 2.0 * LENGTH])
"""Base, held-out midpoint of segment 1, end of segment 1, end of segment 2."""
ENDS = [0, 2, 3]
"""Columns of :data:`ARCLENGTHS` of the base and the segment-end markers."""
OFFSET_ROTVECS = np.radians([[2.0, -1.5, 0.0],  # the base's roll about z is the gauge: 0
                             [1.0, 2.5, -3.0],
                             [-2.0, 1.0, 4.0],
                             [1.5, -2.5, 2.0]])
OFFSET_TRANSLATIONS = 1e-3 * np.array([[3.0, -2.0, 4.0],
                                       [-4.0, 3.0, 2.0],
                                       [2.0, 5.0, -3.0],
                                       [-3.0, -4.0, 5.0]])
OFFSETS = pose_matrices(OFFSET_ROTVECS, OFFSET_TRANSLATIONS)
"""``backbone_T_marker`` of each marker: a few millimetres and degrees."""
WORLD_T_BASE = pose_matrices(np.array([0.1, -0.2, 0.3]), np.array([0.5, -0.3, 0.8]))
TRUE_MARKERS = {float(ARCLENGTHS[m]): OFFSETS[m] for m in ENDS}
"""The offsets as ``robot.toml``'s ``[[markers]]`` hold them (arc length -> pose)."""


# ------------------------------------------------------------------------------------ helpers
def _times(n: int) -> np.ndarray:
    return np.arange(n) / RATE


def _sweep(times: np.ndarray, cycles: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """``(T, 2)`` thetas through 10..80 deg and psis swinging over ~140 and ~230 deg: smooth
    sinusoids of time, ``cycles`` periods of the first over the recording."""
    w = 2.0 * np.pi * cycles * (times - times[0]) / (times[-1] - times[0])
    thetas = np.radians(np.stack([45.0 + 35.0 * np.sin(w),
                                  45.0 + 35.0 * np.sin(1.3 * w + 2.0)], axis=1))
    psis = np.stack([0.4 + 1.2 * np.sin(0.7 * w + 0.5),
                     -1.0 + 2.0 * np.sin(0.5 * w + 1.0)], axis=1)
    return thetas, psis


def _bends(thetas: np.ndarray, psis: np.ndarray) -> np.ndarray:
    return np.stack([thetas * np.cos(psis), thetas * np.sin(psis)], axis=-1)


def _midpoint_frames(thetas: np.ndarray, psis: np.ndarray) -> np.ndarray:
    """``base_T_backbone`` half way along segment 1: the model's first half of the segment
    (backbone_heldout.py: length L / 2, the same k and deviation rate, bending vector b / 2)."""
    seg = ROBOT.segments[0]
    half = Segment(0.5 * seg.length, seg.k, seg.delta_max, seg.theta_max)
    return segment_transform(0.5 * _bends(thetas, psis)[:, 0], half, 0.5 * seg.length)


def _poses(times: np.ndarray, backbone: np.ndarray) -> BackbonePoses:
    """Marker poses ``backbone @ offset`` of ``(T, 4, 4, 4)`` backbone frames, all present."""
    return BackbonePoses(times, ARCLENGTHS, backbone @ OFFSETS,
                         np.ones((len(times), len(ARCLENGTHS)), dtype=bool))


def _model_poses(n: int, cycles: float = 1.0) -> tuple[BackbonePoses, np.ndarray, np.ndarray]:
    """Model-exact backbone poses of the sweep, and its thetas and psis."""
    times = _times(n)
    thetas, psis = _sweep(times, cycles)
    tips = ROBOT.forward(thetas, psis, WORLD_T_BASE)
    base = np.broadcast_to(WORLD_T_BASE, (n, 4, 4))
    backbone = np.stack([base, WORLD_T_BASE @ _midpoint_frames(thetas, psis), tips[:, 0],
                         tips[:, 1]], axis=1)
    return _poses(times, backbone), thetas, psis


def _noisy(poses: BackbonePoses, rng: np.random.Generator, position: float,
           angle: float = 0.0) -> BackbonePoses:
    """``poses`` with white Gaussian noise: ``position`` metres per coordinate, ``angle``
    radians per axis of a rotation vector applied in the marker frame."""
    world = poses.world_T_marker.copy()
    shape = world.shape[:2]
    world[..., :3, 3] += rng.normal(0.0, position, (*shape, 3))
    if angle > 0.0:
        turn = Rotation.from_rotvec(rng.normal(0.0, angle, (math.prod(shape), 3)))
        world[..., :3, :3] = world[..., :3, :3] @ turn.as_matrix().reshape(*shape, 3, 3)
    return BackbonePoses(poses.timestamps, poses.arclengths, world, poses.present)


def _exact_replay(poses: BackbonePoses, **options: object) -> Replay:
    ends = measured_ends(poses, ROBOT, TRUE_MARKERS)
    return replay_motion(ROBOT, ends, **{"smoothing": 0.0, "noise_px": 1.0,
                                         "outlier_fraction": 0.0, "decimals": None, **options})


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


@pytest.fixture(scope="module")
def model_exact() -> tuple[BackbonePoses, np.ndarray, np.ndarray]:
    return _model_poses(120)


@pytest.fixture(scope="module")
def exact_fit(model_exact: tuple[BackbonePoses, np.ndarray, np.ndarray]
              ) -> BackboneCalibration:
    # The sweep hardly tells k, delta_max and the markers' offsets along the backbone tangent
    # apart (the fit's own warnings: correlations 0.99 to 1.000; the smallest singular value of
    # the whitened Jacobian is ~3 against ~2e4 for the largest). So even on noise-free data any
    # real prior on the offsets moves the optimum along that direction: the default prior
    # (3 deg, 3 mm) leaves k off by ~7e-3 and delta_max by ~2 deg, (30 deg, 5 cm) still by
    # ~3e-3 and ~1 deg, and (3 rad, 5 m) by ~1e-6. A flat prior (100 rad, 100 m) leaves the
    # data alone: k, delta_max and the offsets come back to ~1e-8.
    return fit_backbone(model_exact[0], ROBOT, offset_prior=(100.0, 100.0))


# -------------------------------------------------------------------------------- calibration
def test_calibration_recovers_model_parameters_noise_free(exact_fit: BackboneCalibration
                                                          ) -> None:
    cal = exact_fit
    for fitted, truth in zip(cal.segments, ROBOT.segments, strict=True):
        assert fitted.length == truth.length and fitted.theta_max == truth.theta_max
        assert abs(fitted.k - truth.k) < 1e-6
        assert abs(fitted.delta_max - truth.delta_max) < 1e-6
    np.testing.assert_allclose(cal.marker_arclengths, ARCLENGTHS[ENDS])
    assert np.abs(cal.backbone_T_marker[:, :3, 3] - OFFSET_TRANSLATIONS[ENDS]).max() < 1e-6
    fitted_rot = Rotation.from_matrix(cal.backbone_T_marker[:, :3, :3])
    angle = (fitted_rot.inv() * Rotation.from_rotvec(OFFSET_ROTVECS[ENDS])).magnitude()
    assert angle.max() < 1e-6
    assert cal.offset_std[0, 2] == 0.0  # the base marker's roll: the gauge
    assert len(cal.sample_times) == 120 and cal.skipped == 0
    for apcc, pcc in zip(cal.apcc, cal.pcc, strict=True):
        assert apcc.rms_position < 1e-8 and apcc.rms_tangent < 1e-7
        assert apcc.rms_position <= pcc.rms_position and apcc.rms_tangent <= pcc.rms_tangent
    assert not [w for w in cal.warnings if "bound" in w]
    # the near-degeneracy that makes the flat prior necessary (fixture comment) is reported
    assert any("cannot be told apart" in w and "translation z" in w for w in cal.warnings)


def test_calibration_fits_the_sweeps_bends(exact_fit: BackboneCalibration,
                                            model_exact: tuple[BackbonePoses, np.ndarray,
                                                               np.ndarray]) -> None:
    _, thetas, psis = model_exact
    bends = _bends(thetas, psis)
    for i, apcc in enumerate(exact_fit.apcc):
        assert np.abs(apcc.bends - bends[:, i]).max() < 1e-6
    # PCC is not the model: its residuals are millimetres and degrees, not zero
    assert min(p.rms_position for p in exact_fit.pcc) > 1e-3
    assert min(p.rms_tangent for p in exact_fit.pcc) > math.radians(0.5)


def test_calibration_with_noise_is_within_three_sigma(
        model_exact: tuple[BackbonePoses, np.ndarray, np.ndarray]) -> None:
    rng = np.random.default_rng(7)
    poses = _noisy(model_exact[0], rng, 0.5e-3, math.radians(0.3))
    cal = fit_backbone(poses, ROBOT)
    for i, (fitted, truth) in enumerate(zip(cal.segments, ROBOT.segments, strict=True)):
        assert 0.0 < cal.k_std[i] < 0.05 and 0.0 < cal.delta_max_std[i] < math.radians(5.0)
        assert abs(fitted.k - truth.k) < 3.0 * cal.k_std[i], (i, fitted.k, cal.k_std[i])
        assert abs(fitted.delta_max - truth.delta_max) < 3.0 * cal.delta_max_std[i], \
            (i, fitted.delta_max, cal.delta_max_std[i])
    # the noise is there: the residuals are of its size, not zero
    for apcc in cal.apcc:
        assert 2e-4 < apcc.rms_position < 3e-3


def test_a_parameter_at_its_bound_warns() -> None:
    """Segment 2 shortens as it bends (its end pulled in by ``1 - 0.15 theta^2``, 30% at 80 deg):
    no k inside (0, 0.5) explains that."""
    n = 60
    times = _times(n)
    thetas, psis = _sweep(times)
    bends = _bends(thetas, psis)
    chain = [np.broadcast_to(WORLD_T_BASE, (n, 4, 4))]
    for i, seg in enumerate(ROBOT.segments):
        body = bending_transform(bends[:, i, 0], bends[:, i, 1], seg).copy()
        if i == 1:
            body[:, :3, 3] *= (1.0 - 0.15 * thetas[:, i] ** 2)[:, None]
        chain.append(chain[-1] @ body)
    columns = np.array(ENDS)
    poses = BackbonePoses(times, ARCLENGTHS[columns], np.stack(chain, axis=1) @ OFFSETS[columns],
                          np.ones((n, 3), dtype=bool))
    cal = fit_backbone(poses, ROBOT)
    k2 = cal.segments[1].k
    assert min(k2 - 1e-3, 0.499 - k2) < 1e-3
    bound = [w for w in cal.warnings if w.startswith("segment 2: k = ") and "bound" in w]
    assert len(bound) == 1 and f"{k2:.4f}" in bound[0], cal.warnings
    assert not [w for w in cal.warnings if w.startswith("segment 1: k = ")]


def test_held_out_midpoint_is_placed(exact_fit: BackboneCalibration) -> None:
    (mid,) = exact_fit.held_out
    assert mid.arclength == pytest.approx(0.5 * LENGTH)
    assert mid.segment == 0 and mid.fraction == pytest.approx(0.5)
    assert len(mid.apcc_position) == 120
    apcc_position, apcc_tangent, pcc_position, pcc_tangent = mid.rms()
    assert apcc_position < 1e-6 and apcc_tangent < 1e-6
    # PCC, with its own bends and offsets, does not place it: the test tells the models apart
    assert pcc_position > 1e-4


# ------------------------------------------------------------------------------------- replay
def test_replay_of_model_exact_motion_reprojects_to_the_noise(
        model_exact: tuple[BackbonePoses, np.ndarray, np.ndarray]) -> None:
    poses, thetas, psis = model_exact
    rep = _exact_replay(poses)
    sim, seq = rep.simulation, rep.simulation.sequence
    assert rep.dropped == 0 and seq.n_frames == 120
    np.testing.assert_allclose(seq.timestamps, poses.timestamps - poses.timestamps[0],
                               atol=1e-12)
    # the replay's world is the (constant) base frame: the model's tips from the identity
    tips = ROBOT.forward(thetas, psis)
    assert seq.truth_tips is not None
    assert np.abs(seq.truth_tips - tips).max() < 1e-12  # measured: ~2e-15
    assert seq.thetas is None and seq.psis is None
    assert seq.cameras == (0, 1)
    for cam in seq.cameras:
        world_T_cam = tips[:, cam] @ CAMERA.tip_T_cam
        assert np.abs(sim.world_T_cam[cam] - world_T_cam).max() < 1e-12
        tracks = seq.tracks[cam]
        assert len(tracks) > 100 * seq.n_frames
        assert not sim.outliers[cam].any()
        rot, pos = world_T_cam[tracks.frames, :3, :3], world_T_cam[tracks.frames, :3, 3]
        points = sim.points_world[sim.landmarks[cam]]
        in_cam = np.einsum("nji,nj->ni", rot, points - pos)
        predicted = CAMERA.project(in_cam)
        assert np.abs(sim.clean_uv[cam] - predicted).max() < 1e-9  # measured: ~1e-12 px
        rms_uv = np.sqrt(np.mean((tracks.uv - predicted) ** 2, axis=0))
        assert np.all(np.abs(rms_uv - 1.0) < 0.1), rms_uv


def test_replay_smoothing_removes_jitter() -> None:
    # A slow motion (one period in 14 s): the local linear fit's own error on the curvature of
    # the motion stays well under the 0.5 mm noise.
    poses, thetas, psis = _model_poses(240, cycles=1.0)
    noisy = _noisy(poses, np.random.default_rng(3), 0.5e-3)
    clean = ROBOT.forward(thetas, psis)
    errors = {}
    for smoothing in (0.0, 0.05):
        rep = _exact_replay(noisy, smoothing=smoothing, n_points=200)
        assert rep.dropped == 0
        tips = rep.simulation.sequence.truth_tips
        assert tips is not None
        errors[smoothing] = _rms(tips[..., :3, 3] - clean[..., :3, 3])
    # raw samples: the noise itself (0.5 mm per coordinate, plus a little from the mean base)
    assert 0.4e-3 < errors[0.0] < 0.6e-3
    assert errors[0.05] < 0.75 * errors[0.0], errors  # measured: 0.31 vs 0.51 mm


def _with_gap(poses: BackbonePoses, start: float, stop: float, marker: int = 2
              ) -> tuple[BackbonePoses, np.ndarray]:
    """``poses`` with ``marker`` (default: the end of segment 1) lost over ``[start, stop)``."""
    gap = (poses.timestamps >= start) & (poses.timestamps < stop)
    present = poses.present.copy()
    present[gap, marker] = False
    world = poses.world_T_marker.copy()
    world[gap, marker] = np.nan
    return BackbonePoses(poses.timestamps, poses.arclengths, world, present), gap


def _interpolated(two: np.ndarray, times: np.ndarray, t: float) -> np.ndarray:
    """The module docstring's interpolation of two ``(4, 4)`` poses at ``times`` to ``t``:
    about the nearer one, the rotation vector and translation to each, weighted linearly."""
    ref = two[int(np.argmin(np.abs(times - t)))]
    a = (t - times[0]) / (times[1] - times[0])
    rotvecs = Rotation.from_matrix(ref[:3, :3].T @ two[:, :3, :3]).as_rotvec()
    out = np.eye(4)
    out[:3, :3] = ref[:3, :3] @ Rotation.from_rotvec((1.0 - a) * rotvecs[0]
                                                     + a * rotvecs[1]).as_matrix()
    out[:3, 3] = ref[:3, 3] + (1.0 - a) * (two[0, :3, 3] - ref[:3, 3]) + a * (two[1, :3, 3]
                                                                              - ref[:3, 3])
    return out


def test_replay_without_smoothing_interpolates_between_samples(
        model_exact: tuple[BackbonePoses, np.ndarray, np.ndarray]) -> None:
    poses, thetas, psis = model_exact
    times = poses.timestamps
    rep = _exact_replay(poses, fps=2.5 * RATE, n_points=200)
    seq = rep.simulation.sequence
    assert rep.dropped == 0
    frame_times = np.arange(seq.n_frames) / (2.5 * RATE)
    np.testing.assert_allclose(seq.timestamps, frame_times, atol=1e-9)
    assert frame_times[-1] <= times[-1] - times[0] < frame_times[-1] + 1.0 / (2.5 * RATE)
    tips = ROBOT.forward(thetas, psis)
    assert seq.truth_tips is not None
    for f in (1, 2, 3, 77, len(frame_times) - 2):
        t = frame_times[f] + times[0]
        hi = int(np.searchsorted(times, t))
        for i in range(2):
            expected = _interpolated(tips[[hi - 1, hi], i], times[[hi - 1, hi]], t)
            assert np.abs(seq.truth_tips[f, i] - expected).max() < 1e-9


def test_replay_drops_frames_in_a_gap_and_cuts_the_tracks(
        tmp_path: Path, model_exact: tuple[BackbonePoses, np.ndarray, np.ndarray]) -> None:
    poses, thetas, psis = model_exact
    times = poses.timestamps
    holey, gap = _with_gap(poses, 3.0, 3.6)  # 0.6 s of the end of segment 1 lost
    rep = _exact_replay(holey, max_gap=0.25)
    seq = rep.simulation.sequence
    # exactly the frames inside the gap are dropped: nothing is made up across 0.66 s
    assert rep.dropped == gap.sum() > 0
    kept = np.round((seq.timestamps + rep.start) * RATE).astype(int)
    np.testing.assert_array_equal(kept, np.flatnonzero(~gap))
    np.testing.assert_allclose(seq.timestamps, times[kept] - times[0], atol=1e-12)
    # two stretches, split at the gap, and no track continues across it
    split = int(np.flatnonzero(gap)[0])
    assert rep.stretches == ((0, split), (split, seq.n_frames))
    for tracks in seq.tracks.values():
        before = set(tracks.track_ids[tracks.frames < split].tolist())
        after = set(tracks.track_ids[tracks.frames >= split].tolist())
        assert before and after and not before & after
    # the frames kept are exact
    tips = ROBOT.forward(thetas, psis)[kept]
    assert seq.truth_tips is not None
    assert np.abs(seq.truth_tips - tips).max() < 1e-9
    save_sequence(seq, tmp_path / "seq")
    loaded = load_sequence(tmp_path / "seq")
    assert loaded.n_frames == len(times) - rep.dropped < len(times)
    # one stretch alone: its frames, on its own clock, and a stretch that is not there refused
    second = _exact_replay(holey, max_gap=0.25, stretch=1)
    assert second.stretches == ((0, seq.n_frames - split),) and second.dropped == 0
    assert second.start == pytest.approx(times[kept[split]])
    assert second.simulation.sequence.truth_tips is not None
    assert np.abs(second.simulation.sequence.truth_tips - tips[split:]).max() < 1e-9
    assert [n for *_, n in motion_stretches(measured_ends(holey, ROBOT, TRUE_MARKERS),
                                             smoothing=0.0)] == [split, seq.n_frames - split]
    with pytest.raises(ValueError, match=r"stretch 2: expected 0 \.\. 1"):
        _exact_replay(holey, max_gap=0.25, stretch=2)


def test_replay_without_smoothing_interpolates_across_a_short_gap(
        model_exact: tuple[BackbonePoses, np.ndarray, np.ndarray]) -> None:
    poses, thetas, psis = model_exact
    times = poses.timestamps
    holey, gap = _with_gap(poses, 3.0, 3.15)  # 2 samples lost: 0.18 s between the neighbours
    before, after = np.flatnonzero(gap)[0] - 1, np.flatnonzero(gap)[-1] + 1
    rep = _exact_replay(holey, max_gap=0.25)
    seq = rep.simulation.sequence
    assert rep.dropped == 0 and rep.stretches == ((0, seq.n_frames),)
    frame = before + 2  # 0.12 s into the gap, interpolated between its neighbours
    expected = _interpolated(ROBOT.forward(thetas, psis)[[before, after], 0],
                             times[[before, after]], times[frame])
    assert seq.truth_tips is not None
    assert np.abs(seq.truth_tips[frame, 0] - expected).max() < 1e-9
    # a gap longer than max_gap is not bridged
    assert _exact_replay(holey, max_gap=0.15).dropped == gap.sum() == 2


# -------------------------------------------------------------------------- tip errors, floor
def test_tip_errors_hand_computed() -> None:
    measured = np.tile(np.eye(4), (1, 3, 1, 1))
    measured[0, :, :3, 3] = [[0.1, 0.0, 0.2], [0.0, 0.0, 0.4], [0.2, 0.1, 0.3]]
    estimated = measured.copy()
    estimated[0, 0, :3, 3] += [3e-3, 4e-3, 0.0]
    estimated[0, 1, :3, :3] = Rotation.from_rotvec([math.radians(10.0), 0.0, 0.0]).as_matrix()
    # a roll about the backbone's own tangent is not a tangent error
    estimated[0, 2, :3, :3] = Rotation.from_rotvec([0.0, 0.0, math.radians(30.0)]).as_matrix()
    errors = tip_errors(estimated, measured)
    np.testing.assert_allclose(errors.position, [[5e-3, 0.0, 0.0]], atol=1e-15)
    np.testing.assert_allclose(errors.tangent, [[0.0, math.radians(10.0), 0.0]], atol=1e-12)
    np.testing.assert_allclose(errors.rms_position, [5e-3, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(errors.rms_tangent, [0.0, math.radians(10.0), 0.0], atol=1e-12)
    with pytest.raises(ValueError, match="same"):
        tip_errors(estimated[:, :2], measured)


def test_floor_is_zero_on_model_tips_and_recovers_bends() -> None:
    times = _times(60)
    thetas, psis = _sweep(times)
    bends = _bends(thetas, psis)
    for base in (None, np.broadcast_to(WORLD_T_BASE, (60, 4, 4))):
        floor = tip_floor(ROBOT, ROBOT.forward(thetas, psis, base), base)
        assert floor.errors.position.max() < 1e-12  # measured: ~3e-16 m
        assert floor.errors.tangent.max() < 1e-12
        assert np.abs(floor.bends - bends).max() < 1e-10  # measured: ~6e-15 rad
        np.testing.assert_allclose(floor.thetas, thetas, atol=1e-10)
        np.testing.assert_allclose(floor.psis, psis, atol=1e-10)
    # on tips the model cannot reach the floor is not zero, and no worse than the true bends
    shifted = ROBOT.forward(thetas, psis).copy()
    shifted[:, 1, :3, 3] += [1e-3, 0.0, 0.0]
    floor = tip_floor(ROBOT, shifted)
    truth_errors = tip_errors(ROBOT.forward(thetas, psis), shifted)
    assert floor.errors.rms_position.max() > 1e-5
    assert np.sum(floor.errors.position**2) < np.sum(truth_errors.position**2)


def test_rotation_floor_is_zero_on_model_tips_and_ignores_positions() -> None:
    times = _times(60)
    thetas, psis = _sweep(times)
    bends = _bends(thetas, psis)
    tips = ROBOT.forward(thetas, psis)
    floor = rotation_floor(ROBOT, tips)
    assert floor.errors.position.max() < 1e-9
    assert np.abs(floor.bends - bends).max() < 1e-8
    # Moving the measured positions leaves it where the rotations are (the true bends), while
    # the position floor moves away from them; turning a tip moves it.
    shifted = tips.copy()
    shifted[:, 1, :3, 3] += [3e-3, -2e-3, 0.0]
    assert np.abs(rotation_floor(ROBOT, shifted).bends - bends).max() < 1e-8
    assert np.abs(tip_floor(ROBOT, shifted).bends - bends).max() > 1e-3
    turned = tips.copy()
    turned[:, 1, :3, :3] = turned[:, 1, :3, :3] @ Rotation.from_rotvec([0.02, 0.0, 0.0]).as_matrix()
    moved = rotation_floor(ROBOT, turned)
    assert np.abs(moved.bends - bends).max() > 1e-3
    rel = np.swapaxes(moved.tips[..., :3, :3], -1, -2) @ turned[..., :3, :3]
    fit = np.linalg.norm(Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_rotvec(), axis=-1)
    rel = np.swapaxes(tips[..., :3, :3], -1, -2) @ turned[..., :3, :3]
    truth = np.linalg.norm(Rotation.from_matrix(rel.reshape(-1, 3, 3)).as_rotvec(), axis=-1)
    assert np.sum(fit**2) < np.sum(truth**2)


# -------------------------------------------------------------------------------- truth tips
def test_truth_tips_round_trip(tmp_path: Path) -> None:
    poses, _, _ = _model_poses(20)
    seq = _exact_replay(poses, n_points=300).simulation.sequence
    save_sequence(seq, tmp_path / "seq")
    loaded = load_sequence(tmp_path / "seq")
    assert loaded.truth_tips is not None and seq.truth_tips is not None
    assert np.abs(loaded.truth_tips - seq.truth_tips).max() < 1e-12
    assert loaded.n_frames == 20 and loaded.thetas is None
    assert loaded.cameras == seq.cameras
    for cam in seq.cameras:
        assert loaded.tracks[cam].equals(seq.tracks[cam])


def test_truth_tips_missing_row_is_refused(tmp_path: Path) -> None:
    poses, _, _ = _model_poses(5)
    save_sequence(_exact_replay(poses, n_points=300).simulation.sequence, tmp_path / "seq")
    path = tmp_path / "seq" / "truth_tips.csv"
    lines = path.read_text().splitlines()
    assert len(lines) == 1 + 5 * 2
    del lines[1 + 2 * 3]  # frame 3, segment 1
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError) as info:
        load_sequence(tmp_path / "seq")
    message = str(info.value)
    assert str(path) in message and "frame 3, segment 1" in message


# ------------------------------------------------------------------------------ command line
def test_calibrate_simulate_estimate_evaluate(tmp_path: Path, capsys: pytest.CaptureFixture[str]
                                              ) -> None:
    poses, _, _ = _model_poses(60)
    poses_file, robot_file = tmp_path / "poses.csv", tmp_path / "robot.toml"
    save_backbone_poses(poses, poses_file)
    nominal = Robot([Segment(LENGTH, theta_max=THETA_MAX)] * 2, [CAMERA, CAMERA])
    save_robot(nominal, robot_file)
    calibrated = tmp_path / "out.toml"
    assert main(["calibrate", str(poses_file), "--robot", str(robot_file),
                 "--output", str(calibrated)]) == 0
    out = capsys.readouterr().out
    assert "APCC" in out and "PCC" in out and "held-out" in out
    assert "[[markers]]" in calibrated.read_text()
    markers = load_markers(calibrated)
    assert sorted(markers) == pytest.approx(list(ARCLENGTHS[ENDS]))
    for arc, pose in markers.items():  # across the tangent the offsets are well measured
        truth = TRUE_MARKERS[min(TRUE_MARKERS, key=lambda a: abs(a - arc))]
        assert np.abs(pose[:2, 3] - truth[:2, 3]).max() < 0.5e-3
    robot = load_robot(calibrated)
    assert robot.cameras == nominal.cameras and robot.segments != nominal.segments

    seq_dir = tmp_path / "seq"
    assert main(["simulate", "--motion", str(poses_file), "--robot", str(calibrated),
                 "--out", str(seq_dir), "--noise-px", "1", "--outliers", "0.1",
                 "--seed", "1"]) == 0
    out = capsys.readouterr().out
    assert "60 frames" in out and "0 dropped" in out and "floor" in out
    assert (seq_dir / "truth_tips.csv").is_file()
    seq = load_sequence(seq_dir)
    assert seq.truth_tips is not None and seq.n_frames == 60
    floor = tip_floor(seq.robot, seq.truth_tips)
    assert floor.errors.rms_position.max() < 1e-3  # the calibrated model fits the motion
    theta0 = ",".join(f"{v:.4f}" for v in np.degrees(floor.thetas[0]))
    psi0 = ",".join(f"{v:.4f}" for v in np.degrees(floor.psis[0]))
    est_dir = tmp_path / "est"
    assert main(["estimate", str(seq_dir), "--method", "chain", "--spatial",
                 f"--theta0-deg={theta0}", f"--psi0-deg={psi0}", "--out", str(est_dir)]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(est_dir), "--truth", str(seq_dir)]) == 0
    out = capsys.readouterr().out
    assert "floor" in out and "tip errors" in out
    rows = [line.split() for line in out.splitlines() if line.strip()[:2] in ("1 ", "2 ")]
    assert len(rows) == 2
    position, floor_mm = (np.array([float(row[c]) for row in rows]) for c in (1, 2))
    assert position.max() < 10.0  # mm: the estimator follows the replayed motion
    # the floor is, frame by frame, the least sum of squared position errors over the segment
    # ends: no estimate of the same model does better on that sum (printed to 0.01 mm)
    assert np.sum(position**2) >= np.sum(floor_mm**2) - 0.01


def test_calibrate_backbone_poses_needs_robot(tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    poses, _, _ = _model_poses(5)
    poses_file = tmp_path / "poses.csv"
    save_backbone_poses(poses, poses_file)
    assert main(["calibrate", str(poses_file)]) == 1
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "--robot" in err[0] and str(poses_file) in err[0]
    assert "Traceback" not in captured.err and captured.out == ""


def test_simulate_motion_lists_the_stretches_and_replays_one(
        tmp_path: Path, capsys: pytest.CaptureFixture[str],
        model_exact: tuple[BackbonePoses, np.ndarray, np.ndarray]) -> None:
    holey, gap = _with_gap(model_exact[0], 3.0, 3.6)
    poses_file, robot_file = tmp_path / "poses.csv", tmp_path / "robot.toml"
    save_backbone_poses(holey, poses_file)
    save_robot(ROBOT, robot_file)
    split = int(np.flatnonzero(gap)[0])
    common = ["simulate", "--motion", str(poses_file), "--robot", str(robot_file),
              "--points", "300"]
    assert main([*common, "--out", str(tmp_path / "all")]) == 0
    out = capsys.readouterr().out
    assert f"{gap.sum()} dropped" in out and "2 stretches" in out, out
    assert f"  1: frames 0-{split - 1}," in out and f"  2: frames {split}-" in out, out
    assert main([*common, "--out", str(tmp_path / "two"), "--stretch", "2"]) == 0
    out = capsys.readouterr().out
    assert "stretch 2 of the recording" in out
    assert load_sequence(tmp_path / "two").n_frames == len(gap) - gap.sum() - split
    assert main([*common, "--out", str(tmp_path / "three"), "--stretch", "3"]) == 1
    err = capsys.readouterr().err
    assert "--stretch 3" in err and "2 stretch(es)" in err and str(poses_file) in err
    assert not (tmp_path / "three").exists()
    assert main(["simulate", "--frames", "10", "--robot", str(robot_file), "--out",
                 str(tmp_path / "random"), "--stretch", "1"]) == 1
    assert "--stretch applies to --motion POSES.csv only" in capsys.readouterr().err


# ------------------------------------------------------------------------------------ bench real
def test_bench_real_scores_each_stretch_and_pools_them(
        tmp_path: Path, model_exact: tuple[BackbonePoses, np.ndarray, np.ndarray]) -> None:
    poses, thetas, psis = model_exact
    holey, gap = _with_gap(poses, 3.0, 3.6)
    folder = tmp_path / "sweep"
    save_backbone_poses(holey, folder / "backbone_poses.csv")
    nominal = Robot([Segment(LENGTH, k=0.25, delta_max=0.0, theta_max=THETA_MAX)] * 2,
                    ROBOT.cameras)
    rows = run_real_bench(tmp_path, nominal, noise_px=1.0, outliers=0.0, seed=0,
                          start_sigma=math.radians(2.0), methods=("chain",),
                          recordings=("sweep",))
    by = {(r.version, r.method): r for r in rows}
    assert set(by) == {("real", "floor"), ("real", "rot-floor"), ("real", "chain"),
                       ("model-exact", "chain"), ("model-exact", "bound")}
    # both stretches (2.9 s and 3.5 s), every frame outside the gap, nothing across it
    assert all(r.frames == len(thetas) - gap.sum() for r in rows if r.method != "bound")
    # the bound of the tips, sampled (measured 0.50 / 1.19 mm; the chain, which takes its start
    # as exact where the bound has a 2 deg prior, is at 0.90 / 1.17 mm)
    bound = by["model-exact", "bound"].position
    assert np.all(bound > 0.2e-3) and np.all(bound < 3e-3), bound
    # the data obey the model: the floor is the calibration's leftover, far below a millimetre
    assert np.all(by["real", "floor"].position < 0.3e-3), by["real", "floor"]
    assert np.all(by["real", "rot-floor"].position < 1e-3), by["real", "rot-floor"]
    # the chain within millimetres on both versions (measured: 0.9 / 1.2 mm model-exact, and
    # 0.9 / 5.2 mm on the recording, where the floor is 0.06 mm)
    real, exact = by["real", "chain"].position, by["model-exact", "chain"].position
    assert np.all(exact < 3e-3) and np.all(real < 10e-3), (real, exact)
    # the frame-to-frame turn of the tip cameras, over the frames of each stretch
    tips = ROBOT.forward(thetas, psis)
    split = int(np.flatnonzero(gap)[0])
    turns = [Rotation.from_matrix(np.swapaxes(part[:-1, i, :3, :3], -1, -2)
                                  @ part[1:, i, :3, :3]).magnitude()
             for part in (tips[:split], tips[~gap][split:]) for i in range(2)]
    expected = [np.percentile(np.concatenate(turns[i::2]), 95) for i in range(2)]
    np.testing.assert_allclose(by["real", "floor"].turn, expected, rtol=0.05)
    table = format_real_bench(rows)
    assert f"sweep: {len(thetas) - gap.sum()} frames in the stretches" in table
    with pytest.raises(ValueError, match="no such file"):
        run_real_bench(tmp_path, nominal, recordings=("missing",))


def test_bench_real_replays_at_the_rate_asked(
        tmp_path: Path, model_exact: tuple[BackbonePoses, np.ndarray, np.ndarray],
        monkeypatch: pytest.MonkeyPatch) -> None:
    """``fps`` reaches both replays of a stretch (the measured motion and its model-exact
    version), whose frames are then at that rate (the replay's resampling is tested above)."""
    import apcc_graph.bench.real_robot as bench

    poses, _, _ = model_exact
    first = poses.timestamps < poses.timestamps[0] + 2.5  # one stretch of 2.5 s is enough
    poses = BackbonePoses(poses.timestamps[first], poses.arclengths,
                          poses.world_T_marker[first], poses.present[first])
    save_backbone_poses(poses, tmp_path / "sweep" / "backbone_poses.csv")
    nominal = Robot([Segment(LENGTH, k=0.25, delta_max=0.0, theta_max=THETA_MAX)] * 2,
                    ROBOT.cameras)
    seen = []
    original = bench.replay_motion

    class Enough(Exception):
        pass

    def spy(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        replay = original(*args, **kwargs)
        seen.append((kwargs.get("fps"), np.diff(replay.simulation.sequence.timestamps)))
        if len(seen) == 2:
            raise Enough
        return replay

    monkeypatch.setattr(bench, "replay_motion", spy)
    # the model-exact motion's own calibration is not what this test is about
    monkeypatch.setattr(bench, "_model_exact_robot", lambda poses, cal, robot, seed:
                        cal.robot(robot))
    with pytest.raises(Enough):
        run_real_bench(tmp_path, nominal, methods=("chain",), recordings=("sweep",),
                       fps=2.0 * RATE)
    for fps, steps in seen:
        assert fps == 2.0 * RATE
        np.testing.assert_allclose(steps, 1.0 / (2.0 * RATE), rtol=1e-6)


def test_bench_real_pools_the_honesty_of_every_stretch() -> None:
    from apcc_graph.bench.real_honesty import Honesty as _Honesty
    from apcc_graph.bench.real_honesty import pooled_honesty as _pooled_honesty
    from apcc_graph.bench.real_robot import RealRow

    a = _Honesty(np.array([[1.0, 4.0], [3.0, np.nan]]), np.array([10.0, 0.0]),
                 np.array([100.0, 50.0]), True)
    b = _Honesty(np.array([[2.0, 2.0]]), np.array([5.0, 1.0]), np.array([400.0, 50.0]), False)
    nees, share, warned = _pooled_honesty([a, b], 2)
    # every frame counts once; a NaN (no sigma) is left out of its segment's mean
    np.testing.assert_allclose(nees, [2.0, 3.0])
    # the shares pool the observations, not the stretches
    np.testing.assert_allclose(share, [15.0 / 500.0, 1.0 / 100.0])
    assert warned == 1
    nees, share, warned = _pooled_honesty([], 2)
    assert np.isnan(nees).all() and np.isnan(share).all() and warned == 0
    row = RealRow("rec", "real", "batch", np.array([0.01, 0.02]), np.array([0.1, 0.2]), 1.0,
                  3, None, np.array([2.0, 3.0]), np.array([0.03, 0.01]), 1, 2, 4)
    floor = RealRow("rec", "real", "floor", np.array([0.001, 0.002]), np.array([0.0, 0.0]),
                    0.0, 3)
    bound = RealRow("rec", "model-exact", "bound", np.array([0.002, 0.004]),
                    np.array([np.nan, np.nan]), 0.0, 2)
    exact = RealRow("rec", "model-exact", "batch", np.array([0.003, 0.002]),
                    np.array([0.1, 0.2]), 1.0, 3)
    table = format_real_bench([floor, row, bound, exact])
    cells: dict[tuple[str, ...], list[str]] = {}
    for line in table.splitlines():  # the first table's rows (the honesty table follows)
        if line.startswith("rec "):
            cells.setdefault(tuple(line.split()[1:3]), line.split()[3:])
    # each row over its yardstick: the floor on the measured motion, the bound on the exact
    assert cells["real", "batch"][:2] == ["10.00", "10.0x"]
    assert cells["model-exact", "batch"][:5] == ["3.00", "1.5x", "5.73", "2.00", "0.5x"]
    assert cells["model-exact", "bound"][:3] == ["2.00", "-", "-"]
    honest = [line for line in table.splitlines() if line.startswith("rec") and "%" in line]
    assert len(honest) == 1
    assert honest[0].split()[3:] == ["2", "3", "3.0%", "1.0%", "1/2", "4"]
