"""``apcc-graph bench kinematics``: wall time of vectorised forward kinematics and its peers.

Measured in one run on the same random configurations of the three-segment planar robot:

- ``Robot.forward`` (planar: psi absent) and ``Robot.forward`` with psi (spatial), 10^6 frames;
- peer ``joint-by-joint matmul``: the five-joint chain as stacked 4x4 ``numpy.matmul`` products
  (:func:`apcc_graph.model.kinematics.apcc_joint_frames`), the direct way to vectorise the model;
- peer ``gtsam.Pose3 loop``: a Python loop composing ``gtsam.Pose3`` per frame and segment.

Peers run on fewer frames (they are slow) and are compared per frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from apcc_graph.bench import best_time
from apcc_graph.model.joint_chain import apcc_joint_frames
from apcc_graph.model.kinematics import apcc_in_plane
from apcc_graph.model.robot import Robot


@dataclass(frozen=True)
class TimingRow:
    """One method's timing: best wall time over the repeats, for ``frames`` frames."""

    method: str
    frames: int
    seconds: float

    @property
    def per_frame_ns(self) -> float:
        """Nanoseconds per frame (all segments)."""
        return 1e9 * self.seconds / self.frames


@dataclass(frozen=True)
class KinematicsBenchmark:
    """Result of :func:`run_kinematics_benchmark`."""

    n_segments: int
    rows: tuple[TimingRow, ...]
    max_abs_difference: float  # largest |forward - peer| over the compared frames (metres)

    @property
    def reference(self) -> TimingRow:
        """The row the ratios are taken against (planar ``Robot.forward``)."""
        return self.rows[0]

    def ratio(self, row: TimingRow) -> float:
        """How many times slower per frame than the reference."""
        return row.per_frame_ns / self.reference.per_frame_ns


def _pose3_loop(robot: Robot, thetas: np.ndarray) -> np.ndarray:
    out = np.empty(thetas.shape + (4, 4))
    for f, row in enumerate(thetas):
        pose = gtsam.Pose3()
        for i, seg in enumerate(robot.segments):
            planar = apcc_in_plane(row[i], seg)
            step = gtsam.Pose3(
                gtsam.Rot3.Ry(float(planar.beta)),
                np.array([float(planar.px), 0.0, float(planar.pz)]),
            )
            pose = pose.compose(step)
            out[f, i] = pose.matrix()
    return out


def _matmul_chain(robot: Robot, thetas: np.ndarray) -> np.ndarray:
    out = np.empty(thetas.shape + (4, 4))
    acc = np.broadcast_to(np.eye(4), (len(thetas), 4, 4))
    for i, seg in enumerate(robot.segments):
        acc = acc @ apcc_joint_frames(thetas[:, i], seg).base_T_tip
        out[:, i] = acc
    return out


def run_kinematics_benchmark(
    robot: Robot,
    n_frames: int = 1_000_000,
    repeats: int = 3,
    peer_frames: int = 100_000,
    loop_frames: int = 5_000,
    seed: int = 0,
) -> KinematicsBenchmark:
    """Time forward kinematics of ``robot`` and its peers on the same random angles.

    Args:
        robot: the robot (all segments are bent within their limits).
        n_frames: frames for ``Robot.forward``.
        repeats: timing repeats; the best is kept.
        peer_frames: frames for the stacked-matmul peer.
        loop_frames: frames for the gtsam loop peer.
        seed: random seed for the angles.
    """
    rng = np.random.default_rng(seed)
    limits = np.array([seg.theta_max for seg in robot.segments])
    thetas = rng.uniform(-1.0, 1.0, (n_frames, robot.n_segments)) * limits
    psis = rng.uniform(-np.pi, np.pi, (n_frames, robot.n_segments))
    peer_frames = min(peer_frames, n_frames)
    loop_frames = min(loop_frames, n_frames)

    rows = [
        TimingRow(
            "Robot.forward (planar)", n_frames, best_time(lambda: robot.forward(thetas), repeats)
        ),
        TimingRow(
            "Robot.forward (with psi)",
            n_frames,
            best_time(lambda: robot.forward(thetas, psis), repeats),
        ),
        TimingRow(
            "peer: joint-by-joint 4x4 matmul",
            peer_frames,
            best_time(lambda: _matmul_chain(robot, thetas[:peer_frames]), repeats),
        ),
        TimingRow(
            "peer: gtsam.Pose3 Python loop",
            loop_frames,
            best_time(lambda: _pose3_loop(robot, thetas[:loop_frames]), 1),
        ),
    ]
    ours = robot.forward(thetas[:loop_frames])
    diff = max(
        float(np.max(np.abs(ours - _matmul_chain(robot, thetas[:loop_frames])))),
        float(np.max(np.abs(ours - _pose3_loop(robot, thetas[:loop_frames])))),
    )
    return KinematicsBenchmark(
        n_segments=robot.n_segments, rows=tuple(rows), max_abs_difference=diff
    )
