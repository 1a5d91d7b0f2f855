"""Simulated tip-camera sequences with ground truth, in exactly the sequence format.

The robot bends along a smooth random motion (or the paper's random-step protocol); each tip
camera sees a static scene of 3-D points; a point in view becomes a track, observed with Gaussian
pixel noise, and a chosen fraction of observations are wrong associations (the pixel replaced by a
random one). Options cover a moving base, finite track lifetimes, frames where a camera sees
nothing, and a model mismatch (simulate with other k and delta_max than the robot file's, or with
curvature that grows along each segment), so estimators can be tested against a robot that is not
exactly the model.

Same seed, same sequence: all randomness comes from one ``numpy.random.default_rng(seed)``.
Units: metres, radians, seconds, pixels.
"""

from __future__ import annotations

import math
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.io.console import progress_bar
from apcc_graph.model.arrays import FloatArray, IntArray
from apcc_graph.model.camera import TipCamera
from apcc_graph.model.robot import Robot
from apcc_graph.model.segment import Segment
from apcc_graph.model.sequence import Sequence, Tracks
from apcc_graph.simulation.motion import (
    MOTIONS,
    base_motion,
    bends_of,
    given_bends,
    smooth_signal,
)
from apcc_graph.simulation.planar_curves import growing_curvature_transform

SCENES = ("points", "room")
NEAR = 0.05
"""Points closer than this in front of a camera (metres) are not seen."""


@dataclass(frozen=True)
class Simulation:
    """A simulated sequence and the ground truth behind its tracks.

    Attributes:
        sequence: the sequence, as it would be saved (robot = the model given).
        points_world: ``(P, 3)`` scene points in the world frame (metres).
        landmarks: camera -> ``(N,)`` index into ``points_world`` of each row of its Tracks.
        clean_uv: camera -> ``(N, 2)`` noise-free projection of each row (also for outliers).
        outliers: camera -> ``(N,)`` True where the row is a wrong association.
        world_T_cam: camera -> ``(F, 4, 4)`` true camera poses.
        world_T_tip: ``(F, S, 4, 4)`` true tip poses.
        scene_centre: ``(3,)`` centre of the scene (the room box or the point shell), metres.
        room_half_size: ``(3,)`` half extents of the room box (also set for the points scene,
            where it is unused), metres.
    """

    sequence: Sequence
    points_world: FloatArray
    landmarks: dict[int, IntArray]
    clean_uv: dict[int, FloatArray]
    outliers: dict[int, NDArray[np.bool_]]
    world_T_cam: dict[int, FloatArray]
    world_T_tip: FloatArray
    scene_centre: FloatArray = field(default_factory=lambda: np.zeros(3))
    room_half_size: FloatArray = field(default_factory=lambda: np.ones(3))


def scene_points(rng: np.random.Generator, scene: str, n_points: int, centre: FloatArray,
                 depth_range: tuple[float, float], room_half_size: tuple[float, float, float],
                 ) -> FloatArray:
    """``(P, 3)`` static scene points (metres, world frame): the ``"points"`` shell or the
    walls of the ``"room"`` box around ``centre`` (see :func:`simulate`)."""
    if scene == "points":
        directions = rng.normal(size=(n_points, 3))
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        lo, hi = depth_range
        radii = np.cbrt(rng.uniform(lo**3, hi**3, n_points))  # uniform in the shell's volume
        return centre + directions * radii[:, None]
    half = np.asarray(room_half_size, dtype=float)
    areas = np.array([half[1] * half[2], half[0] * half[2], half[0] * half[1]])
    axis = rng.choice(3, size=n_points, p=areas / areas.sum())
    points = rng.uniform(-1.0, 1.0, (n_points, 3)) * half
    sign = rng.choice([-1.0, 1.0], size=n_points)
    points[np.arange(n_points), axis] = sign * half[axis]
    return centre + points


def _true_tips(robot: Robot, thetas: FloatArray, psis: FloatArray | None,
               base: FloatArray | None, truth_segments: SequenceOf[Segment] | None,
               curvature_growth: float) -> FloatArray:
    segments = list(truth_segments) if truth_segments is not None else list(robot.segments)
    if curvature_growth == 0.0:
        return Robot(segments).forward(thetas, psis, base)
    n_frames = len(thetas)
    psis = np.zeros_like(thetas) if psis is None else psis
    acc = np.broadcast_to(np.eye(4) if base is None else base, (n_frames, 4, 4))
    out = np.empty((n_frames, len(segments), 4, 4))
    for i, seg in enumerate(segments):
        local = growing_curvature_transform(thetas[:, i], seg.length, curvature_growth,
                                            psis[:, i])
        acc = acc @ local
        out[:, i] = acc
    return out


def _check_options(
    robot: Robot,
    n_frames: int,
    *,
    noise_px: float,
    outlier_fraction: float,
    blackout_fraction: float,
    fps: float,
    motion: str,
    scene: str,
    track_lifetime: float | None,
    depth_range: tuple[float, float],
    truth_segments: SequenceOf[Segment] | None,
    decimals: int | None,
) -> None:
    """Raise ``ValueError`` naming the first option of :func:`simulate` out of range."""
    if n_frames < 2:
        raise ValueError(f"n_frames = {n_frames}: expected at least 2 frames")
    if not (math.isfinite(noise_px) and noise_px >= 0):
        raise ValueError(f"noise_px = {noise_px!r}: expected a finite value >= 0 (pixels)")
    if not 0.0 <= outlier_fraction < 1.0:
        raise ValueError(f"outlier_fraction = {outlier_fraction!r}: expected 0 <= p < 1")
    if not 0.0 <= blackout_fraction < 1.0:
        raise ValueError(f"blackout_fraction = {blackout_fraction!r}: expected 0 <= p < 1")
    if motion not in MOTIONS:
        raise ValueError(f"motion = {motion!r}: expected one of {MOTIONS}")
    if scene not in SCENES:
        raise ValueError(f"scene = {scene!r}: expected one of {SCENES}")
    if not fps > 0:
        raise ValueError(f"fps = {fps!r}: expected > 0")
    if track_lifetime is not None and not track_lifetime >= 1.0:
        raise ValueError(f"track_lifetime = {track_lifetime!r}: expected >= 1 frame or None")
    if not 0.0 < depth_range[0] < depth_range[1]:
        raise ValueError(f"depth_range = {depth_range!r}: expected 0 < min < max (metres)")
    if truth_segments is not None and len(truth_segments) != robot.n_segments:
        raise ValueError(f"truth_segments has {len(truth_segments)} segments, the robot "
                         f"{robot.n_segments}")
    if decimals is not None and not 0 <= decimals <= 12:
        raise ValueError(f"decimals = {decimals!r}: expected 0..12 or None")
    if not robot.camera_segments:
        raise ValueError("the robot has no camera: nothing to observe")


def projections(points: FloatArray, camera: TipCamera, world_T_cam: FloatArray,
                progress: bool = False, label: str = "") -> tuple[FloatArray, NDArray[np.bool_]]:
    """``(F, P, 2)`` noise-free pixels of every scene point in every frame (``-1`` behind the
    camera) and ``(F, P)`` whether the point is in view."""
    n_frames = len(world_T_cam)
    visible = np.zeros((n_frames, len(points)), dtype=bool)
    pixels = np.zeros((n_frames, len(points), 2))
    for f in progress_bar(range(n_frames), desc=label, progress=progress, leave=False):
        R, p = world_T_cam[f, :3, :3], world_T_cam[f, :3, 3]
        in_cam = (points - p) @ R
        front = in_cam[:, 2] > NEAR
        uv = np.full((len(points), 2), -1.0)
        uv[front] = camera.project(in_cam[front])
        visible[f] = front & camera.in_image(uv)
        pixels[f] = uv
    return pixels, visible


def _tracks_of(rng: np.random.Generator, visible: NDArray[np.bool_], blackout_fraction: float,
               track_lifetime: float | None) -> tuple[NDArray[np.bool_], IntArray]:
    """Blackouts and track ids: ``(F, P)`` visibility with the blacked-out frames cleared, and
    the track id of every (frame, point), meaningful where it is visible."""
    if blackout_fraction > 0.0:
        dark = rng.random(len(visible)) < blackout_fraction
        visible = visible & ~dark[:, None]
    starts = visible.copy()
    starts[1:] &= ~visible[:-1]
    if track_lifetime is not None:
        starts |= visible & (rng.random(visible.shape) < 1.0 / track_lifetime)
    # Number the starts landmark by landmark; each observation takes the id of the latest start
    # of its landmark.
    ids = (np.cumsum(starts.T.ravel()) - 1).reshape(starts.T.shape).T
    return visible, ids


@dataclass(frozen=True)
class _CameraTruth:
    """One camera's tracks and the ground truth of their rows (see :class:`Simulation`)."""

    tracks: Tracks
    landmarks: IntArray
    clean_uv: FloatArray
    outliers: NDArray[np.bool_]


def _observe(rng: np.random.Generator, camera: TipCamera, pixels: FloatArray,
             visible: NDArray[np.bool_], ids: IntArray, noise_px: float, outlier_fraction: float,
             decimals: int | None) -> _CameraTruth:
    """The observations of one camera: pixel noise, then outliers, then rounding."""
    frame_idx, point_idx = np.nonzero(visible)
    clean_uv = pixels[frame_idx, point_idx]
    uv = clean_uv + rng.normal(0.0, noise_px, clean_uv.shape) if noise_px else clean_uv.copy()
    keep = camera.in_image(uv)  # noise may push a point just outside the image
    frame_idx, point_idx, clean_uv, uv = (a[keep] for a in (frame_idx, point_idx, clean_uv, uv))
    is_outlier = np.zeros(len(uv), dtype=bool)
    n_out = int(round(outlier_fraction * len(uv)))
    if n_out:
        chosen = rng.choice(len(uv), n_out, replace=False)
        is_outlier[chosen] = True
        uv[chosen] = rng.uniform(0.0, 1.0, (n_out, 2)) * [camera.width, camera.height]
    if decimals is not None:
        uv = np.round(uv, decimals)
    track_ids = ids[frame_idx, point_idx]
    # Tracks sorts rows by (frame, id); put the ground truth in the same order.
    order = np.lexsort((track_ids, frame_idx))
    return _CameraTruth(Tracks(frame_idx, track_ids, uv), point_idx[order], clean_uv[order],
                        is_outlier[order])


def observe(rng: np.random.Generator, robot: Robot, tips: FloatArray, points: FloatArray, *,
            noise_px: float, outlier_fraction: float, blackout_fraction: float = 0.0,
            track_lifetime: float | None = None, decimals: int | None = None,
            progress: bool = False) -> tuple[dict[int, _CameraTruth], dict[int, FloatArray]]:
    """What every tip camera riding on ``tips`` (``(F, S, 4, 4)`` world_T_tip) sees of the scene
    ``points``: each camera's tracks with their ground truth, and its ``(F, 4, 4)`` poses."""
    cameras, world_T_cam = {}, {}
    for cam in robot.camera_segments:
        camera = robot.cameras[cam]
        assert camera is not None
        world_T_cam[cam] = tips[:, cam] @ camera.tip_T_cam
        pixels, visible = projections(points, camera, world_T_cam[cam], progress,
                                       f"camera {cam + 1}")
        visible, ids = _tracks_of(rng, visible, blackout_fraction, track_lifetime)
        cameras[cam] = _observe(rng, camera, pixels, visible, ids, noise_px, outlier_fraction,
                                decimals)
    return cameras, world_T_cam


def _assemble(robot: Robot, t: FloatArray, thetas: FloatArray, psis: FloatArray | None,
              base: FloatArray | None, *, cameras: dict[int, _CameraTruth],
              world_T_cam: dict[int, FloatArray], tips: FloatArray, points: FloatArray,
              centre: FloatArray, room_half_size: tuple[float, float, float]) -> Simulation:
    """The :class:`Sequence` of the motion and the cameras' tracks, and its ground truth."""
    tracks = {cam: truth.tracks for cam, truth in cameras.items()}
    sequence = Sequence(robot, t, tracks, world_T_base=base, thetas=thetas, psis=psis)
    return Simulation(sequence=sequence, points_world=points,
                      landmarks={cam: truth.landmarks for cam, truth in cameras.items()},
                      clean_uv={cam: truth.clean_uv for cam, truth in cameras.items()},
                      outliers={cam: truth.outliers for cam, truth in cameras.items()},
                      world_T_cam=world_T_cam, world_T_tip=tips, scene_centre=centre,
                      room_half_size=np.asarray(room_half_size, dtype=float))


def simulate(
    robot: Robot,
    n_frames: int,
    noise_px: float = 0.5,
    outlier_fraction: float = 0.0,
    seed: int = 0,
    *,
    fps: float = 30.0,
    motion: str = "smooth",
    amplitude: float = 0.8,
    max_step_deg: float = 5.0,
    paper_range_deg: float = 50.0,
    spatial: bool = False,
    moving_base: bool = False,
    base_rotation_deg: float = 5.0,
    base_translation: float = 0.1,
    scene: str = "points",
    n_points: int = 2700,
    depth_range: tuple[float, float] = (1.0, 4.0),
    room_half_size: tuple[float, float, float] = (2.0, 2.0, 1.5),
    track_lifetime: float | None = None,
    blackout_fraction: float = 0.0,
    truth_segments: SequenceOf[Segment] | None = None,
    curvature_growth: float = 0.0,
    decimals: int | None = None,
    bends: ArrayLike | None = None,
    progress: bool = False,
) -> Simulation:
    """Simulate what the robot's tip cameras see, with the ground truth.

    Args:
        robot: the robot model (saved with the sequence); its cameras observe.
        n_frames: number of frames F >= 2.
        noise_px: standard deviation of the Gaussian pixel noise, per coordinate (pixels).
        outlier_fraction: fraction of observations (per camera, exact up to rounding) replaced by
            a uniformly random pixel, in [0, 1).
        seed: random seed; the same seed gives the same sequence.
        fps: frame rate (timestamps are ``frame / fps`` seconds).
        motion: ``"smooth"`` (sums of slow sinusoids within ``amplitude * theta_max``) or
            ``"paper"`` (the paper's protocol: random steps under ``max_step_deg`` within
            ``+/- paper_range_deg``, capped by theta_max).
        amplitude: fraction of each segment's theta_max used by the smooth motion.
        max_step_deg: largest per-frame step of the paper protocol (degrees).
        paper_range_deg: range of the paper protocol (degrees).
        spatial: also vary the bending-plane angles psi (otherwise psi = 0, a planar robot).
        moving_base: move the robot base (rotation within ``base_rotation_deg`` degrees about each
            axis, translation within ``base_translation`` metres).
        base_rotation_deg: bound of the base rotation (degrees).
        base_translation: bound of the base translation norm (metres).
        scene: ``"points"`` (random points in a spherical shell ``depth_range`` metres around the
            robot's middle) or ``"room"`` (points on the walls of a box ``room_half_size``).
        n_points: number of scene points (2700 gives ~200 tracks per 640x480, f = 500 camera).
        depth_range: shell radii of the ``"points"`` scene (metres).
        room_half_size: half extents of the ``"room"`` box (metres).
        track_lifetime: mean length of a track in frames (tracks break at random and restart
            with a new id); ``None`` for tracks that last while the point stays in view.
        blackout_fraction: fraction of (frame, camera) pairs in which the camera sees nothing.
        truth_segments: segments to simulate with instead of the robot's (model mismatch in k,
            delta_max, length).
        curvature_growth: simulate each segment as a rod whose curvature grows along the arc by
            ``1 + g`` from base to tip (:mod:`apcc_graph.simulation.planar_curves`); 0 for the
            APCC model.
        decimals: round the observed pixels to this many decimals (a tracker's precision; keeps
            saved files small); ``None`` keeps full precision.
        bends: ``(F, S)`` true angles (radians) to use instead of the drawn motion (e.g. a
            motion with a fault, :mod:`apcc_graph.simulation.faults`); the random draws stay
            as without it, so the scene, the tracks' noise and outliers are those of the same
            seed's undisturbed recording wherever the cameras see the same points.
        progress: show a progress bar.

    Returns:
        The sequence and its ground truth.

    Raises:
        ValueError: an option out of range (named in the message).
    """
    _check_options(robot, n_frames, noise_px=noise_px, outlier_fraction=outlier_fraction,
                   blackout_fraction=blackout_fraction, fps=fps, motion=motion, scene=scene,
                   track_lifetime=track_lifetime, depth_range=depth_range,
                   truth_segments=truth_segments, decimals=decimals)
    rng = np.random.default_rng(seed)  # drawn in this order: motion, scene, then per camera
    t = np.arange(n_frames) / fps
    thetas = bends_of(rng, robot, t, motion, amplitude, max_step_deg, paper_range_deg)
    if bends is not None:
        thetas = given_bends(robot, bends, n_frames)
    psis = math.pi * smooth_signal(rng, t, robot.n_segments, (0.02, 0.1)) if spatial else None
    base = base_motion(rng, t, base_rotation_deg, base_translation) if moving_base else None
    tips = _true_tips(robot, thetas, psis, base, truth_segments, curvature_growth)
    centre = np.array([0.0, 0.0, 0.5 * sum(seg.length for seg in robot.segments)])
    points = scene_points(rng, scene, n_points, centre, depth_range, room_half_size)

    cameras, world_T_cam = observe(rng, robot, tips, points, noise_px=noise_px,
                                   outlier_fraction=outlier_fraction,
                                   blackout_fraction=blackout_fraction,
                                   track_lifetime=track_lifetime, decimals=decimals,
                                   progress=progress)
    return _assemble(robot, t, thetas, psis, base, cameras=cameras, world_T_cam=world_T_cam,
                     tips=tips, points=points, centre=centre, room_half_size=room_half_size)


def simulate_sequence(robot: Robot, n_frames: int, noise_px: float = 0.5,
                      outlier_fraction: float = 0.0, seed: int = 0,
                      **options: object) -> Sequence:
    """:func:`simulate`, returning only the sequence (see :func:`simulate` for the options)."""
    sim = simulate(robot, n_frames, noise_px, outlier_fraction, seed, **options)  # type: ignore[arg-type]
    return sim.sequence


