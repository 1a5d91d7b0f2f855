"""Model error as noise (``docs/estimation.md``, "Model error as noise"): each segment tip's
pose per frame is a variable, tied to its base (the previous tip, or the robot's base) through
the segment's APCC transform at the frame vector with the segment's model noise
(``GraphOptions.model_sigma``; by default the robot file's:
:mod:`~apcc_graph.estimation.model_noise`)
(:func:`~apcc_graph.factors.kinematic.segment_tie_factor`); each track's point is
eliminated inside one factor per chunk of a camera's tracks over that camera's tips
(:mod:`~apcc_graph.factors.tip_projection`), the tracks cut into pieces of at most
:data:`TIP_TRACK_FRAMES` frames. Outliers are decided without the model first
(:func:`~apcc_graph.frontend.rotation_pairs.pair_inliers`), then by residuals.
"""

from __future__ import annotations

import math
from dataclasses import replace

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.graph import observed_cameras, values_from
from apcc_graph.estimation.model_noise import segment_correlations
from apcc_graph.estimation.model_ties import ModelTies
from apcc_graph.estimation.options import GraphOptions, Robustness
from apcc_graph.estimation.robust import gnc_tls_weights
from apcc_graph.factors.keys import frame_key, tip_key
from apcc_graph.factors.projection import chunk_tracks
from apcc_graph.factors.tip_projection import TipProjectionFactor
from apcc_graph.factors.track_points import TrackObservations
from apcc_graph.frontend.rotation_pairs import pair_inliers
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import Sequence

__all__ = ["POINT_PRIOR_SIGMA", "TIP_TRACK_FRAMES", "NoisyTerms", "forward_tips",
           "square_root_information"]

TIP_TRACK_FRAMES = 30
"""With every tip a variable, tracks are cut into pieces of at most this many frames (or
``GraphOptions.max_track_frames`` where shorter): a piece's factor couples six unknowns per
frame it spans, so a long piece makes the system dense in the tips. On 300 frames of a real
replayed stretch, pieces of up to 150 frames took 92 s and pieces of up to 30 took 16 s, with
tip errors of 2.2 / 2.0 and 2.2 / 1.6 mm (docs/estimation.md, "Model error as noise")."""

POINT_PRIOR_SIGMA = 10.0
"""Standard deviation (metres) of the weak prior on each track's point around its first
triangulation where a point is a variable (the smoother's model-noise window): it only holds a
point whose rays are nearly parallel. The batch eliminates its points instead."""


def forward_tips(bending: Bending, x: FloatArray, bases: FloatArray) -> FloatArray:
    """``(F, S, 4, 4)`` every segment tip's ``world_T_tip`` at the frame vectors ``x``
    ``(F, dim)``, from the base poses ``bases`` ``(F, 4, 4)``."""
    out = np.empty((len(x), bending.n_segments, 4, 4))
    for f, (vector, base) in enumerate(zip(x, bases, strict=True)):
        T = base
        for j in range(bending.n_segments):
            T = T @ bending.transform(vector, j)
            out[f, j] = T
    return out


def square_root_information(W: FloatArray) -> FloatArray:
    """``(N, 2, 2)`` upper-triangular ``R`` with ``R^T R = W^T W`` (the same whitened norm as
    ``W``, in the form gtsam's ``SqrtInformation`` expects)."""
    return np.swapaxes(np.linalg.cholesky(np.swapaxes(W, -1, -2) @ W), -1, -2)


class _Camera:
    """One camera's tracks in chunks (:func:`~apcc_graph.factors.projection.chunk_tracks`),
    each a projection factor over its tip poses with the points eliminated."""

    def __init__(self, obs: TrackObservations, mount: FloatArray, weights: FloatArray,
                 frames_per_chunk: int) -> None:
        self.obs = obs
        self.chunks: list[TipProjectionFactor] = []
        for tracks in chunk_tracks(obs, frames_per_chunk):
            rows = np.concatenate([np.arange(obs.starts[t], obs.starts[t + 1]) for t in tracks])
            self.chunks.append(TipProjectionFactor(obs.select(tracks), mount, weights[rows]))

    def measure(self, tips: FloatArray, robust: bool = False) -> None:
        """Every row's residual norm at the tips ``(F, S, 4, 4)`` (``robust``: each track's
        point found afresh from the rows its weights keep)."""
        for c in self.chunks:
            c.residual_norms(tips[c.first:c.last + 1, self.obs.camera], robust)


class NoisyTerms:
    """The batch's terms with model error as noise (module docstring): ``sigmas``, per segment
    (position m, rotation rad), from ``options.model_sigma`` and the robot
    (:func:`~apcc_graph.estimation.terms.measurement_model`)."""

    calibration = None
    stage_iterations = 3
    """Most Levenberg-Marquardt iterations a stage: with the damping below, each costs as
    much as a few of gtsam's default and the later ones gained nothing measurable (300 real
    frames: the same tips with 3, 5, 10 and 30; docs/estimation.md, "Model error as
    noise")."""
    diagonal_damping = True
    """Damping scaled by the information's diagonal: the cost is far from quadratic in the
    tips' positions (tracks with little parallax), and gtsam's isotropic damping, unable to
    shorten those steps enough, gave up far from the optimum (300 real frames at rest: cost
    39160 against 38018, tip errors 2.2 / 1.6 mm against 2.1 / 0.5 with the floor at
    2.1 / 0.3)."""

    def __init__(self, robot: Robot, options: GraphOptions, bending: Bending,
                 sigmas: tuple[tuple[float, float], ...]) -> None:
        self.robot, self.options, self.bending = robot, options, bending
        self.ties = ModelTies(bending, sigmas,
                              segment_correlations(options.model_correlation, robot))
        self.cameras: list[_Camera] = []
        self.bases = self.tips = np.empty((0, bending.n_segments, 4, 4))
        self.x = np.empty((0, bending.dim))

    def start(self, sequence: Sequence, x: FloatArray, robustness: Robustness) -> list[float]:
        """The first decisions from the images alone, the points triangulated with them at the
        model's tips at ``x``; a truncated stage (``[inf]``; no GNC schedule is used)."""
        base = np.eye(4) if sequence.world_T_base is None else sequence.world_T_base
        self.bases = np.broadcast_to(base, (sequence.n_frames, 4, 4))
        self.x = np.array(x, dtype=float)
        self.tips = forward_tips(self.bending, np.asarray(x, dtype=float), self.bases)
        self.cameras = []
        cut = self.options.max_track_frames
        pieces = replace(self.options, max_track_frames=TIP_TRACK_FRAMES if cut is None
                         else min(cut, TIP_TRACK_FRAMES))
        for obs in observed_cameras(sequence, pieces):
            camera = self.robot.cameras[obs.camera]
            assert camera is not None
            bearings = np.column_stack([obs.xy, np.ones(len(obs))])
            weights = pair_inliers(obs.frames, obs.tracks, bearings).astype(float)
            self.cameras.append(_Camera(obs, camera.tip_T_cam, weights,
                                        self.options.frames_per_chunk))
            self.cameras[-1].measure(self.tips, robust=True)
        return [math.inf]

    def factors(self) -> list[gtsam.NonlinearFactor]:
        """Every frame's segment ties (each a transition from the frame before where the model
        error drifts: :mod:`~apcc_graph.estimation.model_ties`), then each camera's projection
        factors over its tips."""
        out: list[gtsam.NonlinearFactor] = []
        for f in range(len(self.tips)):
            previous = None if f == 0 else (f - 1, self.x[f - 1], self.bases[f - 1])
            out += self.ties.frame(f, self.x[f], self.bases[f], previous)
        return out + [chunk.factor() for c in self.cameras for chunk in c.chunks]

    def values(self, x: FloatArray) -> tuple[gtsam.Values, None]:
        """The frame vectors ``x`` and the tips; gtsam orders them."""
        values = values_from(x, range(len(x)))
        for f, tips in enumerate(self.tips):
            for j, T in enumerate(tips):
                values.insert(tip_key(f, j), gtsam.Pose3(T))
        return values, None

    def measure(self, values: gtsam.Values) -> None:
        """Take the frame vectors and the tips of the solution ``values``; every residual
        there."""
        F, S = self.tips.shape[:2]
        self.x = np.array([values.atVector(frame_key(f)) for f in range(F)])
        self.tips = np.array([[values.atPose3(tip_key(f, j)).matrix() for j in range(S)]
                              for f in range(F)])
        for c in self.cameras:
            c.measure(self.tips)

    def set_weights(self, threshold: float, mu: float) -> int:
        """Decide every row by its last residual norm; returns how many rows changed side."""
        changed = 0
        for chunk in (chunk for c in self.cameras for chunk in c.chunks):
            assert chunk.norms is not None
            new = gnc_tls_weights(chunk.norms, threshold, mu)
            changed += int(np.sum((new > 0.5) != (chunk.weights > 0.5)))
            chunk.weights[:] = new
        return changed

    def decisions(self) -> tuple[NDArray[np.int64], int, int]:
        """``(F, S)`` inliers per frame and camera, outliers (weight <= 1/2), observations."""
        F, S = self.tips.shape[:2]
        inliers = np.zeros((F, S), dtype=np.int64)
        chunks = [(c.obs.camera, chunk) for c in self.cameras for chunk in c.chunks]
        for camera, chunk in chunks:
            inliers[:, camera] += np.bincount(chunk.obs.frames[chunk.weights > 0.5],
                                              minlength=F)[:F]
        return (inliers, int(sum(np.sum(chunk.weights <= 0.5) for _, chunk in chunks)),
                int(sum(len(c.obs) for c in self.cameras)))
