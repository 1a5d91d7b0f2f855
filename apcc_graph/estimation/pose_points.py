"""The tracks and points of the fixed-lag smoother with model noise
(:mod:`~apcc_graph.estimation.smoother.noisy`; ``docs/estimation.md``, "Model error as noise").

Each camera's track is held back, row by row, until its rays have parallax or its first row's
frame is about to leave the window. Then its point is triangulated at the current camera poses
(the tips' estimates and the mounts), the rows that miss it by more than the inlier threshold
stay out, and the point becomes a variable with a weak prior (:data:`PRIOR_DEPTHS`) and a gtsam
C++ projection factor per row, on the tip pose of the row's frame. Once a point exists, each new
row of its track becomes a factor as it arrives.

Outliers are decided without the model: a row that disagrees with the rotation between its
frame and the previous one (:mod:`~apcc_graph.estimation.rotation_gate`) stays out unless the
next frame agrees with it; every factor has a Cauchy loss for what the gate misses.

A point's timestamp is its last row's: it leaves the window a lag after its track was last
seen, and a track seen again after that starts a new point.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.terms.noisy import POINT_PRIOR_SIGMA
from apcc_graph.estimation.terms.noisy import square_root_information as root_information
from apcc_graph.factors.keys import point_key, tip_key
from apcc_graph.factors.track_points import TrackObservations
from apcc_graph.factors.triangulation import robust_triangulate
from apcc_graph.model.arrays import FloatArray, IntArray

PARALLAX = math.radians(1.0)
"""A held track's point is made once its first and last rays differ by this much in the world
(radians; the camera's turn counts, as it tells the point's bearing)."""

MIN_ROWS = 3
"""... and it has at least this many rows the gate kept; a track whose first row is about to
leave the window needs two."""

PRIOR_DEPTHS = 10.0
"""A new point's prior: isotropic, with a standard deviation of this many times its distance
from the first camera that kept it (at most :data:`~apcc_graph.estimation.terms.noisy.
POINT_PRIOR_SIGMA`). Weak beside any parallax; without parallax it is the point's only depth
information, and a prior much weaker than this leaves the window's system so poorly conditioned
that gtsam's Cholesky reports it indeterminate (measured on the real robot's replay: a restart
every few frames with the 10 m prior of the batch, none with this; a prior of one distance
biases the tips, 22 / 54 mm against 5.5 / 19 mm)."""

BASELINE = math.radians(2.0)
"""A point whose first and last kept cameras are this far apart as seen from it (radians) has
the batch's weak prior (:data:`~apcc_graph.estimation.terms.noisy.POINT_PRIOR_SIGMA`)."""

CAUCHY = 3.0
"""Scale of every projection factor's Cauchy loss (pixel-noise units)."""

_K = gtsam.Cal3_S2(1.0, 1.0, 0.0, 0.0, 0.0)  # normalised image coordinates


class _Row:
    """One held observation: its frame, normalised point, whitening and the gate's verdict."""

    __slots__ = ("frame", "verdict", "whiten", "xy")

    def __init__(self, frame: int, xy: FloatArray, whiten: FloatArray, verdict: int) -> None:
        self.frame, self.xy, self.whiten, self.verdict = frame, xy, whiten, verdict


class PosePoints:
    """The held rows and the points of every camera's tracks (module docstring).

    Args:
        mounts: camera -> ``tip_T_cam`` ``(4, 4)``.
        lag: the window's length (seconds).
        inlier_sigmas: a row that misses its new point by more (pixel-noise units) stays out.

    Attributes:
        committed: rows that became factors.
        outliers: rows left out (by the gate or at their point's triangulation).
    """

    def __init__(self, mounts: Mapping[int, FloatArray], lag: float, inlier_sigmas: float
                 ) -> None:
        self.mounts = {cam: np.asarray(T, dtype=float) for cam, T in mounts.items()}
        self.lag = float(lag)
        self.inlier_sigmas = float(inlier_sigmas)
        self.held: dict[tuple[int, int], list[_Row]] = {}
        self.points: dict[tuple[int, int], tuple[int, float]] = {}  # -> (key, stamp)
        self._serial = 0
        self.committed = 0
        self.outliers = 0

    def reset(self) -> None:
        """Forget every point and held row (a new gtsam window)."""
        self.held.clear()
        self.points.clear()

    def judge(self, frame: int, cam: int, ids: IntArray, agree: NDArray[np.bool_]) -> None:
        """The next frame agrees with ``frame``'s held rows of ``ids`` where ``agree``: they
        are kept whatever their own pair said (the gate's protocol)."""
        for i in np.asarray(ids)[np.asarray(agree, dtype=bool)].tolist():
            rows = self.held.get((cam, i))
            if rows and rows[-1].frame == frame:
                rows[-1].verdict = 1

    def observe(self, graph: gtsam.NonlinearFactorGraph, stamps: dict[int, float], f: int,
                t: float, rows: Mapping[int, tuple[IntArray, FloatArray, FloatArray]],
                verdicts: Mapping[int, NDArray[np.int8]]) -> None:
        """Frame ``f``'s rows (at ``t`` seconds): a factor each for the tracks with a point,
        held otherwise; ``verdicts`` are the gate's (0: an outlier)."""
        for cam, (ids, xy, whiten) in rows.items():
            R = root_information(whiten)
            for k, i in enumerate(ids.tolist()):
                point = self.points.get((cam, i))
                if point is not None and point[1] < t - self.lag:
                    del self.points[cam, i]  # it left the window: the track starts anew
                    point = None
                verdict = int(verdicts[cam][k])
                if point is None:
                    self.held.setdefault((cam, i), []).append(_Row(f, xy[k], whiten[k], verdict))
                elif verdict == 0:
                    self.outliers += 1
                else:
                    graph.add(self._factor(cam, f, point[0], xy[k], R[k]))
                    self.points[cam, i] = (point[0], t)
                    stamps[point[0]] = t
                    self.committed += 1

    def make(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
             stamps: dict[int, float], t: float, tips: Mapping[int, FloatArray],
             due: set[int], force: bool = False) -> None:
        """Make the points of the held tracks that are ready (module docstring): ``tips`` holds
        frame -> ``(S, 4, 4)`` tip poses of the frames in the window, ``due`` the frames about to
        leave it; ``force``: every track with two kept rows. Rows of frames not in ``tips`` are
        dropped."""
        ready: dict[int, list[tuple[int, list[_Row]]]] = {}
        for (cam, i), rows in list(self.held.items()):
            rows = [r for r in rows if r.frame in tips]
            kept = [r for r in rows if r.verdict != 0]
            if not kept:
                self._drop(cam, i, rows)
                continue
            self.held[cam, i] = rows
            must = force or rows[0].frame in due
            if len(kept) >= 2 and (must or (
                    len(kept) >= MIN_ROWS and self._turn(cam, kept, tips) >= PARALLAX)):
                ready.setdefault(cam, []).append((i, kept))
            elif must:  # too few rows: the leaving ones are lost
                self._drop(cam, i, [r for r in rows if r.frame not in due])
        for cam, tracks in sorted(ready.items()):
            self._triangulate(graph, values, stamps, t, cam, tracks, tips)

    def _drop(self, cam: int, i: int, remaining: list[_Row]) -> None:
        lost = len(self.held.get((cam, i), [])) - len(remaining)
        self.outliers += lost
        if remaining:
            self.held[cam, i] = remaining
        else:
            self.held.pop((cam, i), None)

    def _turn(self, cam: int, rows: list[_Row], tips: Mapping[int, FloatArray]) -> float:
        """Angle (radians) between the first and last row's rays in the world."""
        rays = []
        for r in (rows[0], rows[-1]):
            R = tips[r.frame][cam, :3, :3] @ self.mounts[cam][:3, :3]
            rays.append(R @ np.array([r.xy[0], r.xy[1], 1.0]))
        c = rays[0] @ rays[1] / (np.linalg.norm(rays[0]) * np.linalg.norm(rays[1]))
        return math.acos(min(1.0, max(-1.0, c)))

    def _triangulate(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                     stamps: dict[int, float], t: float, cam: int,
                     tracks: list[tuple[int, list[_Row]]], tips: Mapping[int, FloatArray]
                     ) -> None:
        """Points of ``tracks`` (id, kept rows) at the current tips, with their factors."""
        rows = [(i, r) for i, kept in tracks for r in kept]
        obs = TrackObservations.build(cam, [r.frame for _, r in rows], [i for i, _ in rows],
                                      np.array([r.xy for _, r in rows]),
                                      np.array([r.whiten for _, r in rows]))
        cams = np.array([tips[int(g)][cam] for g in obs.frames]) @ self.mounts[cam]
        centres = cams[:, :3, 3]
        points, norms = robust_triangulate(obs, cams[:, :3, :3], centres, np.ones(len(obs)))
        good = np.isfinite(norms) & (norms <= self.inlier_sigmas)
        count = np.bincount(obs.tracks, good, obs.n_tracks)
        R = root_information(obs.whiten)
        for track, i in enumerate(obs.ids.tolist()):
            rows_of = np.arange(obs.starts[track], obs.starts[track + 1])
            inside = rows_of[good[rows_of]]
            if count[track] < 2 or not np.all(np.isfinite(points[track])):
                continue  # held on: later rows may tell its point
            p = points[track]
            key = point_key(cam, self._serial)
            self._serial += 1
            values.insert(key, p)
            a, b = centres[inside[0]] - p, centres[inside[-1]] - p
            depth = float(np.linalg.norm(a))
            angle = math.acos(min(1.0, a @ b / max(depth * np.linalg.norm(b), 1e-300)))
            sigma = POINT_PRIOR_SIGMA if angle >= BASELINE else min(POINT_PRIOR_SIGMA,
                                                                    PRIOR_DEPTHS * depth)
            graph.add(gtsam.PriorFactorPoint3(key, p, gtsam.noiseModel.Isotropic.Sigma(3, sigma)))
            for k in inside.tolist():
                graph.add(self._factor(cam, int(obs.frames[k]), key, obs.xy[k], R[k]))
            self.committed += int(count[track])
            self.outliers += len(rows_of) - int(count[track])
            self.points[cam, i] = (key, t)
            stamps[key] = t
            del self.held[cam, i]

    def _factor(self, cam: int, frame: int, key: int, xy: FloatArray, root: FloatArray
                ) -> gtsam.NonlinearFactor:
        noise = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Cauchy.Create(CAUCHY),
            gtsam.noiseModel.Gaussian.SqrtInformation(root, False))
        return gtsam.GenericProjectionFactorCal3_S2(
            np.asarray(xy, dtype=float), noise, tip_key(frame, cam), key, _K,
            gtsam.Pose3(self.mounts[cam]))

