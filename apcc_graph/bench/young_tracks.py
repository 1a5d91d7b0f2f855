"""``apcc-graph bench young-tracks``: what the observations of young tracks are worth to the
smoother's newest frame.

The fixed-lag smoother puts every observation into the projection factor of its track, whose
point is eliminated. A track seen in only two or three frames says little and cannot yet be
told from a wrong association, so its observations wait (``min_live_rows`` = 4 by default)
before they inform the newest frame's estimate; they always count in the final, smoothed
estimate. A generalized epipolar factor between the frames of such a young track is the
classical way to use them at once. Its information is exactly that of the same two or three
observations in a projection factor whose point is eliminated (one epipolar constraint per
frame pair), so running the smoother with ``min_live_rows`` = 2 gives an upper bound on what
epipolar factors for young tracks could add to the newest frame (an upper bound: it also lets
wrong young associations in, which an epipolar factor would have to weigh the same way).

Scenario: the 3-segment robot of ``bench smoother`` (``data/robots/planar_three.toml``), the
room scene, 1 px, the given outlier fraction, 30 fps, the start known (0.1 deg prior). Printed,
per ``min_live_rows``: the RMS error of the newest frame's estimate (what a live user gets),
the RMS of the final estimates, both per segment, and the share of each frame's observations
that belong to tracks in their second or third frame.
"""

from __future__ import annotations

import time
from collections.abc import Sequence as SequenceOf
from dataclasses import dataclass

import numpy as np

from apcc_graph.bench import ROBOT_FILE
from apcc_graph.bench.smoother import LAG, THETA0_SIGMA, room_simulation
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import SmootherOptions, TrackOptions, WindowOptions
from apcc_graph.io.console import progress_bar
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.arrays import rms
from apcc_graph.model.sequence import Sequence

LIVE_ROWS = (4, 2)


@dataclass(frozen=True)
class YoungTracksRow:
    """One ``min_live_rows`` setting over every seed (radians, ``(S,)``)."""

    min_live_rows: int
    newest_rms: np.ndarray
    final_rms: np.ndarray
    seconds_per_frame: float


@dataclass(frozen=True)
class YoungTracksBenchmark:
    """Everything :func:`run_young_tracks_benchmark` measured."""

    frames: int
    seeds: tuple[int, ...]
    outliers: float
    young_share: float  # of all observations: rows 2 and 3 of their track
    rows: tuple[YoungTracksRow, ...]


def young_share(sequence: Sequence) -> float:
    """The share of all observations that are their track's second or third."""
    young = total = 0
    for table in sequence.tracks.values():
        order = np.lexsort((table.frames, table.track_ids))
        ids = table.track_ids[order]
        starts = np.r_[True, ids[1:] != ids[:-1]]
        first_row = np.maximum.accumulate(np.where(starts, np.arange(len(ids)), 0))
        age = np.arange(len(ids)) - first_row
        young += int(np.count_nonzero((age == 1) | (age == 2)))
        total += len(ids)
    return young / max(total, 1)


def _run(sequence: Sequence, live_rows: int, progress: bool
         ) -> tuple[np.ndarray, np.ndarray, float]:
    """Newest-frame and final angles ``(F, S)`` and seconds of one smoother run."""
    assert sequence.thetas is not None
    smoother = FixedLagSmoother(
        sequence.robot, lag=LAG, theta0=sequence.thetas[0],
        options=GraphOptions(theta0_sigma=THETA0_SIGMA),
        settings=SmootherOptions(window=WindowOptions(uncertainty=False),
                                 tracks=TrackOptions(min_live_rows=live_rows)))
    newest = np.empty_like(sequence.thetas)
    start = time.perf_counter()
    for f in progress_bar(range(sequence.n_frames), desc=f"min_live_rows {live_rows}",
                          progress=progress, leave=False):
        newest[f] = smoother.update(sequence.frame(f)).thetas
    final = np.array([fr.thetas for fr in smoother.finish()])
    return newest, final, time.perf_counter() - start


def run_young_tracks_benchmark(frames: int = 300, seeds: SequenceOf[int] = (0, 1, 2),
                               outliers: float = 0.1, live_rows: SequenceOf[int] = LIVE_ROWS,
                               progress: bool = False) -> YoungTracksBenchmark:
    """Run the smoother with each ``min_live_rows`` on the same simulated sequences."""
    robot = load_robot(ROBOT_FILE)
    errors: dict[int, tuple[list[np.ndarray], list[np.ndarray], float]] = {
        n: ([], [], 0.0) for n in live_rows}
    shares = []
    for seed in seeds:
        sequence = room_simulation(robot, frames, outliers, seed).sequence
        assert sequence.thetas is not None
        shares.append(young_share(sequence))
        for n in live_rows:
            newest, final, seconds = _run(sequence, n, progress)
            new_errs, final_errs, total = errors[n]
            new_errs.append(newest - sequence.thetas)
            final_errs.append(final - sequence.thetas)
            errors[n] = (new_errs, final_errs, total + seconds)
    rows = tuple(YoungTracksRow(n, rms(np.concatenate(e[0])), rms(np.concatenate(e[1])),
                                e[2] / (frames * len(seeds))) for n, e in errors.items())
    return YoungTracksBenchmark(frames, tuple(seeds), outliers, float(np.mean(shares)), rows)


def format_young_tracks(bench: YoungTracksBenchmark) -> str:
    """The table ``apcc-graph bench young-tracks`` prints (degrees)."""
    lines = [f"young tracks: {len(bench.seeds)} seeds x {bench.frames} frames, "
             f"{bench.outliers:.0%} outliers; {bench.young_share:.1%} of the observations are "
             "their track's 2nd or 3rd",
             "min_live_rows | newest frame RMS (deg) per segment | final RMS (deg) | ms/frame"]
    base = bench.rows[0]
    for row in bench.rows:
        newest = " / ".join(f"{v:.4f}" for v in np.degrees(row.newest_rms))
        final = " / ".join(f"{v:.4f}" for v in np.degrees(row.final_rms))
        gain = " / ".join(f"{v:.2f}" for v in row.newest_rms / base.newest_rms)
        lines.append(f"{row.min_live_rows:13d} | {newest} (x{gain}) | {final} | "
                     f"{1e3 * row.seconds_per_frame:.1f}")
    return "\n".join(lines)
