"""Does every camera observe its segment? The checks before an estimate (a camera with no or
almost no tracks) and after the paper's chain (a camera whose RANSAC kept almost nothing), each an
``ObservationWarning`` naming the camera: a bend resting on a handful of points may end far off
without any other sign."""

from __future__ import annotations

import warnings

import numpy as np
from numpy.typing import NDArray

from apcc_graph.model.sequence import Sequence


class ObservationWarning(UserWarning):
    """A camera of the robot observed nothing in the whole sequence (its segment's angle rests
    on the cameras further out and on the motion prior), or almost nothing (fewer than
    :data:`FEW_TRACKS_PER_FRAME` tracks per frame, or, in the chain, inliers per frame)."""


FEW_TRACKS_PER_FRAME = 5
"""Fewer tracks (or the chain's RANSAC inliers) per frame than this, on average, and a camera
is warned about: a bend rests on a handful of points then."""


def check_observations(sequence: Sequence) -> None:
    """Warn for each camera without a single observation; refuse a sequence without any.

    Raises:
        ValueError: no camera observed anything (e.g. ``tracks/`` empty or missing).
    """
    counts = {cam: 0 if sequence.tracks.get(cam) is None else len(sequence.tracks[cam])
              for cam in sequence.robot.camera_segments}
    if not any(counts.values()):
        raise ValueError("the sequence has no observations: no camera has a track (tracks/ "
                         "empty or missing? a folder of images needs `apcc-graph track` first)")
    for cam, count in counts.items():
        if count == 0:
            warnings.warn(f"camera cam_{cam + 1} (segment {cam + 1}) observed nothing in the "
                          f"whole sequence: segment {cam + 1}'s angle rests on the cameras "
                          "further out and on the motion prior", ObservationWarning,
                          stacklevel=3)
        elif count < FEW_TRACKS_PER_FRAME * sequence.n_frames:
            warnings.warn(f"camera cam_{cam + 1} (segment {cam + 1}) has {count} observations "
                          f"in {sequence.n_frames} frames ({count / sequence.n_frames:.2g} per "
                          f"frame; fewer than {FEW_TRACKS_PER_FRAME} per frame observe a bend "
                          "poorly): check its tracks and its camera's calibration",
                          ObservationWarning, stacklevel=3)


UNJUDGED = ("no-motion", "no-camera", "initial")
"""Chain statuses of a frame pair that say nothing of a camera's tracks: its segment did not
move (no parallax to solve from), no camera, or no pair at all."""


def warn_few_inliers(sequence: Sequence, inliers: NDArray[np.int64],
                     status: NDArray[np.str_]) -> None:
    """An ``ObservationWarning`` for each camera whose RANSAC kept fewer than a handful of
    correspondences per frame pair, or less than :data:`FEW_KEPT` of them (its segment's angle
    then drifts unseen). Only the frame pairs the RANSAC was asked to solve count: a segment
    standing still (status ``no-motion``) keeps no inliers without anything being wrong.

    Args:
        sequence: the sequence the chain estimated.
        inliers: ``(F, S)`` RANSAC inliers of each frame's pair with the previous frame.
        status: ``(F, S)`` the chain's status of each (module ``apcc_graph.estimation.chain``).
    """
    if sequence.n_frames < 2:
        return
    for i in sequence.robot.camera_segments:
        trk = sequence.tracks.get(i)
        solved = ~np.isin(status[1:, i], UNJUDGED)
        if trk is None or len(trk) == 0 or not solved.any():
            continue  # warned about before the estimate, or nothing to judge
        seen = np.bincount(trk.frames, minlength=sequence.n_frames)
        possible = int(np.minimum(seen[:-1], seen[1:])[solved].sum())
        per_pair = float(inliers[1:, i][solved].mean())
        kept = int(inliers[1:, i][solved].sum()) / max(possible, 1)
        if per_pair < FEW_TRACKS_PER_FRAME or kept < FEW_KEPT:
            warnings.warn(f"chain: camera cam_{i + 1} (segment {i + 1}) kept {per_pair:.2g} "
                          f"correspondences per frame pair, {100 * kept:.0f}% of what its "
                          "tracks offer "
                          f"(expected at least {FEW_TRACKS_PER_FRAME} and "
                          f"{100 * FEW_KEPT:.0f}%): segment {i + 1}'s angle is barely observed "
                          "and may drift far; check its tracks and its camera's calibration",
                          ObservationWarning, stacklevel=4)


FEW_KEPT = 0.2
"""The chain warns about a camera whose RANSAC keeps less than this fraction of the
correspondences its tracks offer (chance agreement of unrelated points is a few percent)."""
