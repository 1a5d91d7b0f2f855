"""A simulated recording generated one frame at a time, for streams of any length.

:func:`~apcc_graph.simulation.simulator.simulate` builds a whole sequence in memory: fine for
thousands of frames, not for a soak of 100,000. :class:`SimulatedStream` draws the same kind of
recording (the smooth motion, a static scene, tracks with Gaussian pixel noise and wrong
associations) but computes each frame only when it is asked for, from state that does not
grow: the motion is a closed-form function of time, and each camera keeps only which points
it saw last frame and their track ids.

Differences from :func:`simulate`: outliers are drawn per observation with probability
``outlier_fraction`` (not an exact count per camera), and the base is fixed. Same seed, same
stream. Units: metres, radians, seconds, pixels.
"""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from apcc_graph.model.arrays import FloatArray, IntArray
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import FrameObservations
from apcc_graph.simulation.motion import SmoothSignal
from apcc_graph.simulation.simulator import projections, scene_points


class SimulatedStream:
    """Frames of a simulated recording, made on demand and in order.

    Args:
        robot: the robot model; its cameras observe.
        noise_px: standard deviation of the pixel noise, per coordinate (pixels).
        outlier_fraction: probability that an observation is a wrong association (a uniformly
            random pixel), in [0, 1).
        seed: random seed; the same seed gives the same stream.
        fps: frame rate (frame ``f`` is at ``f / fps`` seconds).
        amplitude: fraction of each segment's theta_max the smooth motion uses.
        scene: ``"room"`` (points on the walls of a box) or ``"points"`` (a spherical shell).
        n_points: number of scene points.

    Raises:
        ValueError: an option out of range.
    """

    def __init__(self, robot: Robot, noise_px: float = 1.0, outlier_fraction: float = 0.1,
                 seed: int = 0, *, fps: float = 30.0, amplitude: float = 0.8,
                 scene: str = "room", n_points: int = 4000) -> None:
        if not 0.0 <= outlier_fraction < 1.0:
            raise ValueError(f"outlier_fraction = {outlier_fraction!r}: expected [0, 1)")
        if not (noise_px >= 0.0 and fps > 0.0 and 0.0 < amplitude <= 1.0):
            raise ValueError(f"noise_px = {noise_px!r}, fps = {fps!r}, amplitude = "
                             f"{amplitude!r}: expected noise_px >= 0, fps > 0, 0 < amplitude <= 1")
        if not robot.camera_segments:
            raise ValueError("the robot has no camera: nothing to observe")
        self.robot = robot
        self.noise_px = noise_px
        self.outlier_fraction = outlier_fraction
        self.fps = fps
        self._rng = np.random.default_rng(seed)
        self._limits = amplitude * np.array([seg.theta_max for seg in robot.segments])
        self._motion = SmoothSignal.draw(self._rng, robot.n_segments)
        centre = np.array([0.0, 0.0, 0.5 * sum(seg.length for seg in robot.segments)])
        self.points = scene_points(self._rng, scene, n_points, centre, (1.0, 4.0),
                                   (2.0, 2.0, 1.5))
        self._seen = {cam: np.zeros(n_points, dtype=bool) for cam in robot.camera_segments}
        self._ids = {cam: np.zeros(n_points, dtype=np.int64) for cam in robot.camera_segments}
        self._next_id = dict.fromkeys(robot.camera_segments, 0)
        self.count = 0

    def thetas(self, frames: IntArray | int) -> FloatArray:
        """True angles ``(S,)`` of one frame, or ``(F, S)`` of several (radians)."""
        f = np.asarray(frames, dtype=float)
        out = self._limits * self._motion(np.atleast_1d(f) / self.fps)
        return out[0] if f.ndim == 0 else out

    def next_frame(self) -> tuple[FrameObservations, FloatArray]:
        """The next frame's observations and its true angles ``(S,)``."""
        f = self.count
        thetas = self.thetas(f)
        tips = self.robot.forward(thetas[None])[0]
        tracks: dict[int, tuple[IntArray, FloatArray]] = {}
        for cam in self.robot.camera_segments:
            ids, uv = self._observe(cam, tips[cam])
            if len(ids):
                tracks[cam] = (ids, uv)
        self.count += 1
        return FrameObservations(f / self.fps, tracks), thetas

    def _observe(self, cam: int, world_T_tip: FloatArray) -> tuple[IntArray, FloatArray]:
        """Camera ``cam``'s tracks in this frame: a point newly in view starts a new id."""
        camera = self.robot.cameras[cam]
        assert camera is not None
        pixels, visible = projections(self.points, camera, (world_T_tip @ camera.tip_T_cam)[None])
        visible = visible[0]
        new = visible & ~self._seen[cam]
        self._ids[cam][new] = self._next_id[cam] + np.arange(int(new.sum()))
        self._next_id[cam] += int(new.sum())
        self._seen[cam] = visible
        index = np.flatnonzero(visible)
        uv = pixels[0, index] + self._rng.normal(0.0, self.noise_px, (len(index), 2))
        wrong = self._rng.random(len(index)) < self.outlier_fraction
        uv[wrong] = self._rng.uniform(0.0, 1.0, (int(wrong.sum()), 2)) * [camera.width,
                                                                        camera.height]
        keep = camera.in_image(uv)
        ids = self._ids[cam][index[keep]]
        order = np.argsort(ids)
        return ids[order], uv[keep][order]

    def __iter__(self) -> Iterator[tuple[FrameObservations, FloatArray]]:
        """Frames without end (stop with ``itertools.islice`` or a loop bound)."""
        while True:
            yield self.next_frame()
