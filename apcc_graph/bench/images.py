"""``apcc-graph bench images``: the whole pipeline on pixels, images -> tracks -> smoother.

For each seed, one simulated motion of the robot in the textured room
(:mod:`apcc_graph.simulation.render`) is observed twice:

- **images**: every tip camera's view rendered (scikit-image textures, sensor noise), tracked by
  :class:`~apcc_graph.frontend.tracking.KLTTracker`, then estimated;
- **simulated 1 px tracks** (the peer): :func:`~apcc_graph.simulation.simulator.simulate` of
  the same motion with its point room and 1 px Gaussian pixel noise, estimated the same way.

Both go through the same estimator (the fixed-lag smoother, and the chain for reference), started
from the true first configuration. Reported per seed and segment: RMS error (degrees), the ratio
images / simulated, and the end-to-end targets (every segment at most 1.5x the simulated-track
pipeline and under 1 degree). Throughput: rendering and tracking, images per second over every
image of the run (640x480, in memory; the tracker alone, PNG decoding not included).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

import apcc_graph
from apcc_graph.bench import ROBOT_FILE
from apcc_graph.frontend.tracking import track_images
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import Sequence
from apcc_graph.simulation.render import SensorModel, render_images, textured_room
from apcc_graph.simulation.simulator import simulate

METHODS = ("smoother", "chain")
RATIO_TARGET = 1.5
RMS_TARGET_DEG = 1.0


@dataclass(frozen=True)
class ImagesRun:
    """One seed: RMS per method, source (``"images"``/``"tracks"``) and segment (degrees)."""

    seed: int
    rms: dict[tuple[str, str], np.ndarray]
    tracks_per_frame: dict[str, float]
    render_seconds: float
    track_seconds: float
    n_images: int


def run_images_benchmark(frames: int = 150, seeds: tuple[int, ...] = (1, 2, 3, 4, 5),
                         noise_grey: float = 2.0, robot: Robot | None = None,
                         texture_source: str = "skimage", progress: bool = False,
                         ) -> list[ImagesRun]:
    """Run the end-to-end comparison for each seed (see the module docstring)."""
    from apcc_graph.io.console import progress_bar

    robot = load_robot(ROBOT_FILE) if robot is None else robot
    runs = []
    for seed in progress_bar(seeds, desc="seeds", progress=progress):
        sim = simulate(robot, frames, noise_px=1.0, seed=seed, scene="room")
        room = textured_room(sim.scene_centre, sim.room_half_size, texture_source, seed=seed)
        sensor = SensorModel(noise_grey=noise_grey)
        tracks, render_s, track_s, n_images = {}, 0.0, 0.0, 0
        for cam in robot.camera_segments:
            camera = robot.cameras[cam]
            assert camera is not None
            start = time.perf_counter()
            images = list(render_images(room, camera, sim.world_T_cam[cam], sensor,
                                        seed=seed + cam))
            render_s += time.perf_counter() - start
            start = time.perf_counter()
            tracks[cam] = track_images(images, (camera.width, camera.height))
            track_s += time.perf_counter() - start
            n_images += len(images)
        truth = sim.sequence.thetas
        assert truth is not None
        sources = {
            "images": Sequence(robot, sim.sequence.timestamps, tracks,
                               world_T_base=sim.sequence.world_T_base, thetas=truth),
            "tracks": sim.sequence,
        }
        rms = {}
        for method in METHODS:
            for name, sequence in sources.items():
                est = apcc_graph.estimate(sequence, method, theta0=truth[0])
                rms[(method, name)] = np.degrees(est.rms(truth))
        per_frame = {name: float(np.mean([len(s.tracks[c]) for c in s.tracks]) / frames)
                     for name, s in sources.items()}
        runs.append(ImagesRun(seed, rms, per_frame, render_s, track_s, n_images))
    return runs


def format_images_benchmark(runs: list[ImagesRun], frames: int, noise_grey: float) -> str:
    """The benchmark's tables and the verdict on the end-to-end targets."""
    n_seg = len(next(iter(runs[0].rms.values())))
    segs = " ".join(f"{'seg ' + str(i + 1):>7}" for i in range(n_seg))
    lines = [
        f"end to end on rendered images: {frames} frames x {n_seg} cameras per seed, 640x480, "
        f"sensor noise {noise_grey:g} grey levels; peer: the same motion as simulated 1 px "
        "tracks",
        "",
        "RMS error per segment (deg), estimators started at the true first frame:",
        f"  {'seed':>4} {'method':<9} {'input':<16} {segs}  {'tracks/frame':>12}",
    ]
    for run in runs:
        for method in METHODS:
            for name, label in (("images", "images (KLT)"), ("tracks", "simulated 1 px")):
                values = " ".join(f"{v:7.3f}" for v in run.rms[(method, name)])
                lines.append(f"  {run.seed:>4} {method:<9} {label:<16} {values}  "
                             f"{run.tracks_per_frame[name]:>12.0f}")
    lines += ["", f"smoother, images / simulated 1 px (target <= {RATIO_TARGET:g}, and images "
              f"< {RMS_TARGET_DEG:g} deg on every segment):"]
    met_all = True
    for run in runs:
        ours, peer = run.rms[("smoother", "images")], run.rms[("smoother", "tracks")]
        ratio = ours / peer
        met = bool(np.all(ratio <= RATIO_TARGET) and np.all(ours < RMS_TARGET_DEG))
        met_all &= met
        lines.append(f"  seed {run.seed}: ratio " + " / ".join(f"{r:.2f}" for r in ratio)
                     + f"; max RMS {ours.max():.3f} deg -> {'met' if met else 'NOT met'}")
    images = sum(r.n_images for r in runs)
    render_s = sum(r.render_seconds for r in runs)
    track_s = sum(r.track_seconds for r in runs)
    lines += [
        f"  all seeds: {'met' if met_all else 'NOT met'}",
        "",
        f"throughput over {images} images: tracking {images / track_s:.0f} images/s "
        f"(target >= 30), rendering {images / render_s:.0f} images/s",
    ]
    return "\n".join(lines)
