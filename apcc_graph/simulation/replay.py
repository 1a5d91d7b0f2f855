"""Real motion, simulated cameras: tip cameras riding on a robot's measured segment ends
(docs/estimation.md, "Replaying a real robot's motion").

From motion-capture backbone poses (:mod:`apcc_graph.io.backbone_poses`) and the robot's marker
offsets (``[[markers]]`` of robot.toml, from ``apcc-graph calibrate POSES.csv``), each segment
end's backbone frame is ``world_T_marker @ inv(backbone_T_marker)``. The base is clamped: its
frame is the mean of the measured base frames, and the replay's world is that base frame (a
fixed base, as the sequence format's default).

The motion capture's noise (about half a millimetre and half a degree per sample at the ends) is
not camera motion: a camera riding on the raw poses would shake by several pixels from sample to
sample. So each segment end is smoothed, and resampled, by a local linear fit in time with
Gaussian weights (``smoothing`` seconds): around the nearest sample ``T_0`` the poses are
written as a rotation vector ``Log(R_0^T R_j)`` and a translation ``p_j - p_0``, the fit's value
at the frame's time is taken, and mapped back. The smoothed ends are both what the cameras ride
on and the sequence's ground truth (``truth_tips.csv``). ``smoothing = 0`` interpolates between
the two samples around each frame instead.

Gaps: a frame is written only where every segment end's samples on either side of it are at most
``max_gap`` seconds apart; nothing is made up across a longer gap (a fast motion cannot be
extrapolated). The frames written fall into stretches, split where frames were dropped or the
recording's clock jumps by more than ``max_gap``. A camera cannot see across a gap it did not
record, so no track continues from one stretch into the next: after a gap every camera sees the
scene with new tracks, as after a blackout. ``stretch`` replays one stretch alone.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from apcc_graph.calibration.backbone_model import rigid_inverse
from apcc_graph.io.backbone_poses import BackbonePoses, segment_markers
from apcc_graph.model.arrays import FloatArray, IntArray
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import Sequence, Tracks
from apcc_graph.simulation.simulator import Simulation, observe, scene_points

MIN_SAMPLES = 2
"""A smoothed pose needs at least this many samples within three smoothing widths."""


@dataclass(frozen=True)
class MeasuredEnds:
    """The backbone frames at the base and the segment ends, as measured.

    Attributes:
        times: ``(T,)`` sample times (seconds).
        world_T_end: ``(T, S + 1, 4, 4)`` the base, then each segment end (NaN where missing).
        present: ``(T, S + 1)`` where measured.
    """

    times: FloatArray
    world_T_end: FloatArray
    present: np.ndarray


def measured_ends(poses: BackbonePoses, robot: Robot,
                  markers: Mapping[float, ArrayLike] | None = None) -> MeasuredEnds:
    """Backbone frames at the base and every segment end: marker poses with their offsets
    removed (``markers``: arc length -> ``backbone_T_marker``; missing ones are identity)."""
    base, ends, _ = segment_markers(poses, [seg.length for seg in robot.segments])
    columns = [base, *ends]
    offsets = np.stack([_offset_at(markers or {}, float(poses.arclengths[c])) for c in columns])
    world = poses.world_T_marker[:, columns] @ rigid_inverse(offsets)
    return MeasuredEnds(poses.timestamps.copy(), world, poses.present[:, columns].copy())


def _offset_at(markers: Mapping[float, ArrayLike], arclength: float) -> FloatArray:
    for arc, pose in markers.items():
        if abs(float(arc) - arclength) < 1e-6:
            return np.asarray(pose, dtype=float)
    return np.eye(4)


def _local_fit(times: FloatArray, poses: FloatArray, t: float, smoothing: float) -> FloatArray:
    """The pose at ``t`` from samples ``(n, 4, 4)`` at ``times`` (module docstring)."""
    ref = poses[int(np.argmin(np.abs(times - t)))]
    rot = Rotation.from_matrix(np.swapaxes(ref[:3, :3], 0, 1) @ poses[:, :3, :3]).as_rotvec()
    xi = np.concatenate([rot, poses[:, :3, 3] - ref[:3, 3]], axis=1)
    dt = times - t
    if smoothing > 0.0:
        w = np.sqrt(np.exp(-0.5 * (dt / smoothing) ** 2))
        design = np.stack([np.ones_like(dt), dt], axis=1) * w[:, None]
        coef = np.linalg.lstsq(design, xi * w[:, None], rcond=None)[0][0]
    else:
        after = int(np.searchsorted(times, t))
        lo, hi = max(after - 1, 0), min(after, len(times) - 1)
        a = 0.0 if hi == lo else (t - times[lo]) / (times[hi] - times[lo])
        coef = (1.0 - a) * xi[lo] + a * xi[hi]
    out = np.eye(4)
    out[:3, :3] = ref[:3, :3] @ Rotation.from_rotvec(coef[:3]).as_matrix()
    out[:3, 3] = ref[:3, 3] + coef[3:]
    return out


def smooth_ends(ends: MeasuredEnds, frame_times: FloatArray, smoothing: float,
                max_gap: float) -> tuple[FloatArray, np.ndarray]:
    """``(F, S + 1, 4, 4)`` smoothed poses at ``frame_times`` and ``(F,)`` whether every end's
    samples around each frame are at most ``max_gap`` apart (module docstring)."""
    n_ends = ends.world_T_end.shape[1]
    out = np.tile(np.eye(4), (len(frame_times), n_ends, 1, 1))
    valid = np.ones(len(frame_times), dtype=bool)
    reach = max(3.0 * smoothing, max_gap)
    for e in range(n_ends):
        times = ends.times[ends.present[:, e]]
        poses = ends.world_T_end[ends.present[:, e], e]
        valid &= _bridged(times, frame_times, max_gap)
        for f in np.flatnonzero(valid):
            t = frame_times[f]
            near = np.flatnonzero(np.abs(times - t) <= reach)
            if smoothing == 0.0:  # interpolation: the samples just before and after the frame
                after = int(np.searchsorted(times, t))
                near = np.unique(np.clip([after - 1, after], 0, len(times) - 1))
            elif len(near) < MIN_SAMPLES:
                valid[f] = False
                continue
            out[f, e] = _local_fit(times[near], poses[near], float(t), smoothing)
    return out, valid


def _bridged(times: FloatArray, frame_times: FloatArray, max_gap: float) -> np.ndarray:
    """Whether each frame time is a sample time or lies between two samples at most
    ``max_gap`` apart."""
    if len(times) == 0:
        return np.zeros(len(frame_times), dtype=bool)
    after = np.searchsorted(times, frame_times)
    hi = times[np.minimum(after, len(times) - 1)]
    lo = times[np.maximum(after - 1, 0)]
    exact = np.abs(hi - frame_times) <= 1e-9
    inside = (after > 0) & (after < len(times))
    return exact | (inside & (hi - lo <= max_gap))


def stretch_labels(frame_times: FloatArray, valid: np.ndarray, max_gap: float) -> IntArray:
    """``(F,)`` the stretch of each frame (0, 1, ...; -1 where dropped): the frames kept,
    split where a frame was dropped or the clock jumps by more than ``max_gap``."""
    labels = np.full(len(frame_times), -1, dtype=np.int64)
    kept = np.flatnonzero(valid)
    if len(kept):
        new = np.concatenate([[True], (np.diff(kept) > 1)
                              | (np.diff(frame_times[kept]) > max_gap)])
        labels[kept] = np.cumsum(new) - 1
    return labels


def motion_stretches(ends: MeasuredEnds, *, fps: float | None = None, smoothing: float = 0.05,
                     max_gap: float = 0.25) -> list[tuple[float, float, int]]:
    """The stretches a replay with these settings has: per stretch its first and last frame
    times on the recording's clock (seconds) and its number of frames."""
    times = _frame_times(ends, fps)
    _, valid = smooth_ends(ends, times, smoothing, max_gap)
    labels = stretch_labels(times, valid, max_gap)
    return [(float(times[labels == k][0]), float(times[labels == k][-1]),
             int(np.sum(labels == k))) for k in range(int(labels.max(initial=-1)) + 1)]


def _frame_times(ends: MeasuredEnds, fps: float | None) -> FloatArray:
    if fps is not None and not fps > 0:
        raise ValueError(f"fps = {fps!r}: expected > 0 (frames per second)")
    start, stop = ends.times[0], ends.times[-1]
    return ends.times if fps is None else start + np.arange(0.0, stop - start + 1e-9, 1.0 / fps)


def _cut_tracks(tracks: Tracks, labels: IntArray) -> Tracks:
    """The same observations with every stretch's track ids apart from the others' (``labels``:
    stretch of each frame of the sequence)."""
    span = int(tracks.track_ids.max(initial=-1)) + 1
    return Tracks(tracks.frames, tracks.track_ids + labels[tracks.frames] * span, tracks.uv)


@dataclass(frozen=True)
class Replay:
    """A replayed recording: the simulation and what was dropped.

    Attributes:
        simulation: the sequence (``truth_tips`` set) and its ground truth.
        dropped: frames not written for a gap in some segment end's samples.
        stretches: the sequence's frames ``(first, stop)`` of each stretch (no track
            continues from one into the next).
        start: the recording's clock at the sequence's first frame (seconds).
    """

    simulation: Simulation
    dropped: int
    stretches: tuple[tuple[int, int], ...] = ()
    start: float = 0.0


def replay_motion(robot: Robot, ends: MeasuredEnds, *, fps: float | None = None,
                  smoothing: float = 0.05, max_gap: float = 0.25, noise_px: float = 1.0,
                  outlier_fraction: float = 0.1, seed: int = 0, scene: str = "room",
                  n_points: int = 2700, room_half_size: tuple[float, float, float] =
                  (2.0, 2.0, 1.5), decimals: int | None = 3, model_tips: FloatArray | None = None,
                  bends: FloatArray | None = None, stretch: int | None = None) -> Replay:
    """Tip cameras on the measured segment ends, seeing a simulated scene.

    Args:
        robot: the robot (its cameras and ``tip_T_cam``), saved with the sequence.
        ends: the measured backbone frames (:func:`measured_ends`).
        fps: resample to this frame rate; ``None`` keeps the recording's sample times.
        smoothing: width (seconds) of the local fit that removes the motion capture's noise;
            0 interpolates between samples.
        max_gap: a frame is dropped where some end's samples around it are further apart than
            this (seconds); the frames kept fall into stretches (module docstring).
        noise_px, outlier_fraction, seed, scene, n_points, room_half_size, decimals: as for
            :func:`apcc_graph.simulation.simulator.simulate`.
        model_tips: ``(F, S, 4, 4)`` replace the smoothed ends by these (in the base frame, for
            the frames kept): the model-exact version of the motion, with ``bends``.
        bends: ``(F, S, 2)`` bending vectors behind ``model_tips``, written as theta and psi.
        stretch: replay only this stretch (0-based, in the order of :func:`motion_stretches`).

    Returns:
        The replay (sequence with ``truth_tips``), how many frames were dropped, the stretches.

    Raises:
        ValueError: bad settings, no such stretch, or fewer than 2 frames to write.
    """
    if not smoothing >= 0 or not max_gap > 0:
        raise ValueError(f"smoothing = {smoothing!r}, max_gap = {max_gap!r}: expected "
                         "smoothing >= 0 and max_gap > 0 (seconds)")
    times = _frame_times(ends, fps)
    smoothed, valid = smooth_ends(ends, times, smoothing, max_gap)
    labels = stretch_labels(times, valid, max_gap)
    dropped = int(np.sum(labels < 0)) if stretch is None else 0
    if stretch is not None:
        count = int(labels.max(initial=-1)) + 1
        if not 0 <= stretch < count:
            raise ValueError(f"stretch {stretch}: expected 0 .. {count - 1} (the recording has "
                             f"{count} stretch(es) between its gaps)")
        valid &= labels == stretch
    if valid.sum() < 2:
        raise ValueError(f"only {int(valid.sum())} frame(s) have every segment end measured "
                         f"within {max_gap} s; expected at least 2")
    labels = labels[valid] - labels[valid][0]
    base = _mean_pose(smoothed[valid, 0])
    tips = rigid_inverse(base) @ smoothed[valid, 1:]
    if model_tips is not None:
        tips = np.asarray(model_tips, dtype=float)
    t = times[valid] - times[valid][0]
    rng = np.random.default_rng(seed)
    centre = np.array([0.0, 0.0, 0.5 * sum(seg.length for seg in robot.segments)])
    points = scene_points(rng, scene, n_points, centre, (1.0, 4.0), room_half_size)
    cameras, world_T_cam = observe(rng, robot, tips, points, noise_px=noise_px,
                                   outlier_fraction=outlier_fraction, decimals=decimals)
    thetas = psis = None
    if bends is not None:
        thetas, psis = np.linalg.norm(bends, axis=-1), np.arctan2(bends[..., 1], bends[..., 0])
    tracks = {cam: _cut_tracks(c.tracks, labels) for cam, c in cameras.items()}
    sequence = Sequence(robot, t, tracks, thetas=thetas, psis=psis, truth_tips=tips)
    sim = Simulation(sequence=sequence, points_world=points,
                     landmarks={cam: c.landmarks for cam, c in cameras.items()},
                     clean_uv={cam: c.clean_uv for cam, c in cameras.items()},
                     outliers={cam: c.outliers for cam, c in cameras.items()},
                     world_T_cam=world_T_cam, world_T_tip=tips, scene_centre=centre,
                     room_half_size=np.asarray(room_half_size, dtype=float))
    edges = np.flatnonzero(np.diff(labels)) + 1
    bounds = np.concatenate([[0], edges, [len(labels)]])
    return Replay(sim, dropped, tuple(zip(bounds[:-1].tolist(), bounds[1:].tolist(),
                                          strict=True)), float(times[valid][0]))


def _mean_pose(poses: FloatArray) -> FloatArray:
    """The mean of nearby poses: rotation by the chordal mean, translation by the mean."""
    out = np.eye(4)
    out[:3, :3] = Rotation.from_matrix(poses[:, :3, :3]).mean().as_matrix()
    out[:3, 3] = poses[:, :3, 3].mean(axis=0)
    return out
