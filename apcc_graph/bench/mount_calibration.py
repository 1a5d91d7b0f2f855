"""``apcc-graph bench mounts``: calibration of the camera mounts beside its Cramer-Rao bound.

The scene of ``bench smoother`` (three 0.3 m segments, room scene, 1 px noise, 30 fps, a
0.1 deg start prior). The sequences are simulated with the true mounts; the estimator is
given mounts each turned by ``deg`` about a random axis and moved by ``mm`` in a random
direction (a mount measured by hand). Per seed, in one run:

- the batch with the true mounts, with the wrong ones, with the wrong ones calibrated
  (``calibrate=True``, the segment models held, mount priors :data:`MOUNT_SIGMAS`), and with
  the wrong ones calibrated together with every segment's k and delta_max: RMS per segment;
- the bound of the angles with the mounts known, with them unknown, and with mounts and
  models unknown (:func:`~apcc_graph.evaluation.sequence_bound.sequence_bound`);
- each calibrated mount's error in its tangent (rotations about the camera's axes, then
  translations along them) against its bound, and the reported sigmas against the bound.

A planar robot's tip cameras never translate along their bending axis, so that component of
a mount is not in the images: its bound is its prior, and it stays where the robot file put it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass, replace

import gtsam
import numpy as np

from apcc_graph.bench import table_cells as _cells
from apcc_graph.bench.self_calibration import CALIBRATION_SIGMAS
from apcc_graph.bench.smoother import NOISE_PX, ROBOT_FILE, THETA0_SIGMA, room_simulation
from apcc_graph.estimation.batch import batch_estimate
from apcc_graph.estimation.model_calibration import MOUNT_SIGMAS, mount_change
from apcc_graph.evaluation.sequence_bound import sequence_bound
from apcc_graph.io.console import progress_bar
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.arrays import rms
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import Sequence


def perturbed_mounts(robot: Robot, deg: float, mm: float, seed: int) -> Robot:
    """``robot`` with every camera's mount turned by ``deg`` degrees about a random axis and
    moved by ``mm`` millimetres in a random direction of the camera frame (seeded)."""
    rng = np.random.default_rng(seed)
    cameras = []
    for camera in robot.cameras:
        axis, way = rng.normal(size=3), rng.normal(size=3)
        error = gtsam.Pose3(
            gtsam.Rot3.Expmap(axis / np.linalg.norm(axis) * math.radians(deg)),
            way / np.linalg.norm(way) * mm * 1e-3)
        cameras.append(None if camera is None else
                       replace(camera, tip_T_cam=camera.tip_T_cam @ error.matrix()))
    return Robot(robot.segments, cameras)


@dataclass(frozen=True)
class MountRun:
    """One seed (angles in radians; mounts in radians and metres)."""

    seed: int
    rms: dict[str, np.ndarray]  # method -> (S,): true, wrong, mounts, all
    bounds: dict[str, np.ndarray]  # known, mounts, all -> (S,) RMS bound
    change_before: np.ndarray  # (S, 6) the wrong mounts against the truth
    change_after: np.ndarray  # (S, 6) the calibrated mounts against the truth
    sigmas: np.ndarray  # (S, 6) reported
    bound: np.ndarray  # (S, 6) bound of the mounts (models known)
    seconds: float  # the mount-calibrating batch


@dataclass(frozen=True)
class MountBenchmark:
    """Everything :func:`run_mount_benchmark` measured."""

    frames: int
    outliers: float
    deg: float
    mm: float
    runs: tuple[MountRun, ...]


def run_mount_benchmark(frames: int = 600, seeds: SequenceOf[int] = (1, 2, 3),
                        outliers: float = 0.1, deg: float = 2.0, mm: float = 5.0,
                        progress: bool = False) -> MountBenchmark:
    """Run the benchmark (see the module docstring)."""
    robot = load_robot(ROBOT_FILE)
    runs = []
    for seed in progress_bar(seeds, desc="mounts", progress=progress):
        sim = room_simulation(robot, frames, outliers, seed)
        seq = sim.sequence
        assert seq.thetas is not None
        wrong = perturbed_mounts(robot, deg, mm, seed)
        wseq = Sequence(wrong, seq.timestamps, seq.tracks, seq.world_T_base, None, seq.psis)
        start = dict(theta0=seq.thetas[0])
        found = {"true": batch_estimate(seq, **start, marginals=False),
                 "wrong": batch_estimate(wseq, **start, marginals=False)}
        begin = time.perf_counter()
        found["mounts"] = batch_estimate(wseq, **start, calibrate=True,
                                         calibration_sigmas=None, mount_sigmas=MOUNT_SIGMAS)
        seconds = time.perf_counter() - begin
        found["all"] = batch_estimate(wseq, **start, calibrate=True, marginals=False,
                                      calibration_sigmas=CALIBRATION_SIGMAS,
                                      mount_sigmas=MOUNT_SIGMAS)
        bound = sequence_bound(sim, NOISE_PX, THETA0_SIGMA, mount_sigmas=MOUNT_SIGMAS)
        bounds = {"known": sequence_bound(sim, NOISE_PX, THETA0_SIGMA).rms(),
                  "mounts": bound.rms(),
                  "all": sequence_bound(sim, NOISE_PX, THETA0_SIGMA,
                                        calibration_sigmas=CALIBRATION_SIGMAS,
                                        mount_sigmas=MOUNT_SIGMAS).rms()}
        calibrated = found["mounts"].robot
        assert bound.mounts is not None and found["mounts"].mount_sigmas is not None
        runs.append(MountRun(
            seed, {k: rms(v.thetas - seq.thetas) for k, v in found.items()}, bounds,
            _changes(wrong, robot), _changes(calibrated, robot),
            found["mounts"].mount_sigmas, bound.mounts, seconds))
    return MountBenchmark(frames, outliers, deg, mm, tuple(runs))


def _changes(robot: Robot, truth: Robot) -> np.ndarray:
    """``(S, 6)`` each camera's mount against the truth's, in the mount's tangent."""
    return np.array([mount_change(a.tip_T_cam, b.tip_T_cam)
                     for a, b in zip(robot.cameras, truth.cameras, strict=True)
                     if a is not None and b is not None])



def format_mount_benchmark(r: MountBenchmark) -> str:
    """The tables ``apcc-graph bench mounts`` prints."""
    deg = np.degrees
    out = [f"bench mounts: 3 x 0.3 m segments, room scene, {NOISE_PX:g} px, {r.outliers:.0%} "
           f"outliers, {r.frames} frames; the estimator's mounts are off by {r.deg:g} deg and "
           f"{r.mm:g} mm; mount priors {math.degrees(MOUNT_SIGMAS[0]):g} deg, "
           f"{MOUNT_SIGMAS[1] * 1e3:g} mm", "",
           "RMS per segment (deg): the batch with the true mounts, the wrong ones, the wrong "
           "ones calibrated, and calibrated with k and delta_max; the bound with the mounts "
           "known, unknown, and with the models unknown too",
           f"  {'seed':>4}  " + "  ".join(f"{name:>20}" for name in (
               "true mounts", "wrong mounts", "mounts calibrated", "all calibrated",
               "bound, known", "bound, mounts", "bound, all")) + f"  {'seconds':>7}"]
    for x in r.runs:
        cells = [x.rms[k] for k in ("true", "wrong", "mounts", "all")]
        cells += [x.bounds[k] for k in ("known", "mounts", "all")]
        out.append(f"  {x.seed:>4}  " + "  ".join(_cells(deg(c)) for c in cells)
                   + f"  {x.seconds:7.1f}")

    def median(values: list[np.ndarray]) -> str:
        return _cells(np.median(values, axis=0), "6.2f")

    ratios = [("mounts calibrated / true mounts", [x.rms["mounts"] / x.rms["true"]
                                                   for x in r.runs]),
              ("wrong / true mounts", [x.rms["wrong"] / x.rms["true"] for x in r.runs]),
              ("all calibrated / true mounts", [x.rms["all"] / x.rms["true"] for x in r.runs]),
              ("bound, mounts / known", [x.bounds["mounts"] / x.bounds["known"]
                                         for x in r.runs]),
              ("bound, all / known", [x.bounds["all"] / x.bounds["known"] for x in r.runs])]
    out += ["", "median over seeds, per segment"]
    out += [f"  {name:<34} {median(values)}" for name, values in ratios]
    out += ["", "mounts per seed and camera: error after (before) calibration in the mount's "
            "tangent, rotations about x, y, z (deg) then translations (mm); [bound]"]
    scale = np.array([180.0 / math.pi] * 3 + [1e3] * 3)
    for x in r.runs:
        for c in range(len(x.change_after)):
            cells = [f"{a * s:+.3f} ({b * s:+.2f}) [{d * s:.3f}]" for a, b, d, s in zip(
                x.change_after[c], x.change_before[c], x.bound[c], scale, strict=True)]
            out.append(f"  seed {x.seed} camera {c + 1}: " + ", ".join(cells))
    z = np.array([x.change_after / x.bound for x in r.runs])  # (seeds, S, 6)
    q = np.array([x.sigmas / x.bound for x in r.runs])
    largest, mean = np.max(np.abs(z), axis=(0, 2)), np.mean(z**2, axis=(0, 2))
    out.append(f"  largest |error| / bound per camera {_cells(largest, '5.2f')}; "
               f"mean (error / bound)^2 per camera {_cells(mean, '5.2f')}")
    out.append(f"  reported sigma / bound: {np.min(q):.3f} to {np.max(q):.3f}")
    return "\n".join(out)
