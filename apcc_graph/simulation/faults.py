"""Faults injected into a simulated recording, with its ground truth kept consistent.

Each function takes a :class:`~apcc_graph.simulation.simulator.Simulation` and returns a new one
whose tracks show the fault, and whose truth (which scene point each row shows, its noise-free
pixel, whether it is a wrong association) still describes every row, so that the Cramer-Rao
bound of the faulted recording can be computed as for any simulation:

- :func:`blind`: cameras that see nothing for a while; a tracker loses its tracks, so every
  track seen again afterwards comes back under a new id (or, with ``keep_ids``, a front end
  that re-identifies the points it was tracking when it went blind: each such point seen again
  comes back under its old track's id);
- :func:`without_camera`: a camera that never sees anything;
- :func:`outlier_burst`: a fraction of one camera's observations replaced by random pixels for
  a while;
- :func:`swapped_ids`: a tracker's wrong association over several frames (tracks exchange ids
  in a cycle, then return to their own), marked as wrong associations in the truth.

A pause in the recording (frames never received while the robot moved on) changes the frames
themselves: :func:`dropped_frames` returns the recording without them, :func:`paused` the
simulation (its truth too).

Motions with faults (the robot frozen, a sudden jump) are new true angles given to
:func:`~apcc_graph.simulation.simulator.simulate` (its ``bends`` option): :func:`frozen_bends`
and :func:`jumped_bends` make them from the undisturbed motion.

Frames are 0-based; ``start`` is the first faulty frame and ``stop`` the first frame after.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from apcc_graph.model.arrays import FloatArray, IntArray
from apcc_graph.model.sequence import Sequence, Tracks
from apcc_graph.simulation.simulator import Simulation


def _with_rows(sim: Simulation, rows: dict[int, dict[str, np.ndarray]]) -> Simulation:
    """``sim`` with the rows of some cameras replaced (``frames``, ``ids``, ``uv`` and the
    truth ``landmarks``, ``clean_uv``, ``outliers``), sorted as :class:`Tracks` sorts them."""
    tracks, truth = dict(sim.sequence.tracks), {
        name: dict(getattr(sim, name)) for name in ("landmarks", "clean_uv", "outliers")}
    for cam, r in rows.items():
        order = np.lexsort((r["ids"], r["frames"]))
        if len(order) == 0:
            tracks.pop(cam, None)
        else:
            tracks[cam] = Tracks(r["frames"][order], r["ids"][order], r["uv"][order])
        for name in truth:
            truth[name][cam] = r[name][order]
    seq = sim.sequence
    sequence = Sequence(seq.robot, seq.timestamps, tracks, world_T_base=seq.world_T_base,
                        thetas=seq.thetas, psis=seq.psis)
    return dataclasses.replace(sim, sequence=sequence, **truth)


def _rows(sim: Simulation, cam: int) -> dict[str, np.ndarray]:
    """Copies of camera ``cam``'s rows and their truth."""
    t = sim.sequence.tracks[cam]
    return {"frames": t.frames.copy(), "ids": t.track_ids.copy(), "uv": t.uv.copy(),
            "landmarks": sim.landmarks[cam].copy(), "clean_uv": sim.clean_uv[cam].copy(),
            "outliers": sim.outliers[cam].copy()}


def _check_span(sim: Simulation, start: int, stop: int) -> None:
    if not 0 <= start < stop <= sim.sequence.n_frames:
        raise ValueError(f"frames {start}..{stop}: expected 0 <= start < stop <= "
                         f"{sim.sequence.n_frames}")


def _check_camera(sim: Simulation, cam: int) -> None:
    if cam not in sim.sequence.tracks:
        raise ValueError(f"camera {cam + 1} (segment index {cam}): the recording has no tracks "
                         f"of it; it has cameras {[c + 1 for c in sim.sequence.tracks]}")


def blind(sim: Simulation, cams: list[int], start: int, stop: int, keep_ids: bool = False
          ) -> Simulation:
    """Cameras ``cams`` see nothing in frames ``start..stop-1``; their tracks seen after the
    gap come back under new ids (ids above every id the camera had), or with ``keep_ids`` as a
    re-identifying front end gives them (:func:`_reidentified`)."""
    _check_span(sim, start, stop)
    out = {}
    for cam in cams:
        _check_camera(sim, cam)
        r = _rows(sim, cam)
        keep = (r["frames"] < start) | (r["frames"] >= stop)
        r = {name: v[keep] for name, v in r.items()}
        if keep_ids:
            r["ids"] = _reidentified(r["frames"], r["ids"], r["landmarks"], start, stop)
        else:
            later = r["frames"] >= stop
            r["ids"][later] += int(r["ids"].max(initial=-1)) + 1
        out[cam] = r
    return _with_rows(sim, out)


def _reidentified(frames: IntArray, ids: IntArray, landmarks: IntArray, start: int,
                  stop: int) -> IntArray:
    """The track ids of one camera's rows (without those of frames ``start..stop-1``) after a
    front end that re-identifies, after the gap, the points it was tracking in the last frame
    it saw before it: the first track of each such point after the gap takes the id of the
    point's track in that frame (a track the simulation kept through the gap keeps its id, as
    it is; a point that left the view during the gap and came back is recognised too). Other
    tracks keep their ids (unique per run of sightings, so no two tracks share one)."""
    out = ids.copy()
    before = frames < start
    if not before.any():
        return out
    last = frames == frames[before].max()
    tracked = dict(zip(landmarks[last].tolist(), ids[last].tolist(), strict=True))
    after = np.flatnonzero(frames >= stop)  # rows in frame order
    first: dict[int, int] = {}  # point -> its first track id after the gap
    for row in after.tolist():
        first.setdefault(int(landmarks[row]), int(ids[row]))
    for point, old in tracked.items():
        new = first.get(point)
        if new is not None and new != old:
            out[after[ids[after] == new]] = old
    return out


def without_camera(sim: Simulation, cam: int) -> Simulation:
    """Camera ``cam`` never sees anything."""
    _check_camera(sim, cam)
    empty = {name: v[:0] for name, v in _rows(sim, cam).items()}
    return _with_rows(sim, {cam: empty})


def outlier_burst(sim: Simulation, cam: int, start: int, stop: int, fraction: float = 0.5,
                  seed: int = 0) -> Simulation:
    """In frames ``start..stop-1``, ``fraction`` of camera ``cam``'s observations (chosen at
    random among those not yet wrong) become uniformly random pixels."""
    _check_span(sim, start, stop)
    _check_camera(sim, cam)
    if not 0.0 < fraction < 1.0:
        raise ValueError(f"fraction = {fraction!r}: expected (0, 1)")
    rng = np.random.default_rng(seed)
    r = _rows(sim, cam)
    inside = np.flatnonzero((r["frames"] >= start) & (r["frames"] < stop))
    wrong = r["outliers"][inside]
    n_new = max(int(round(fraction * len(inside))) - int(wrong.sum()), 0)
    chosen = rng.choice(inside[~wrong], min(n_new, int((~wrong).sum())), replace=False)
    camera = sim.sequence.robot.cameras[cam]
    assert camera is not None
    r["uv"][chosen] = rng.uniform(0.0, 1.0, (len(chosen), 2)) * [camera.width, camera.height]
    r["outliers"][chosen] = True
    return _with_rows(sim, {cam: r})


def swapped_ids(sim: Simulation, cam: int, start: int, stop: int, fraction: float = 0.2,
                seed: int = 0) -> Simulation:
    """In frames ``start..stop-1``, ``fraction`` of the tracks camera ``cam`` sees throughout
    exchange ids in a cycle (the pixel of track a is reported as track b, ...); outside those
    frames every track has its own id again. The exchanged rows are marked wrong."""
    _check_span(sim, start, stop)
    _check_camera(sim, cam)
    rng = np.random.default_rng(seed)
    r = _rows(sim, cam)
    inside = (r["frames"] >= start) & (r["frames"] < stop)
    ids, counts = np.unique(r["ids"][inside], return_counts=True)
    steady = ids[counts == stop - start]
    n = int(round(fraction * len(steady)))
    if n < 2:
        raise ValueError(f"camera {cam + 1}: {len(steady)} tracks last through frames "
                         f"{start}..{stop - 1}; too few to swap {fraction:.0%} of them")
    cycle = rng.choice(steady, n, replace=False)
    new_id = dict(zip(cycle.tolist(), np.roll(cycle, 1).tolist(), strict=True))
    rows = np.flatnonzero(inside & np.isin(r["ids"], cycle))
    r["ids"][rows] = [new_id[i] for i in r["ids"][rows].tolist()]
    r["outliers"][rows] = True
    return _with_rows(sim, {cam: r})


def frozen_bends(thetas: FloatArray, start: int, frames: int) -> FloatArray:
    """``(F, S)`` angles: ``thetas`` held at frame ``start`` for ``frames`` frames, then the
    motion continues where it stopped (the recording keeps its length)."""
    n = len(thetas)
    if not (0 <= start < n and frames > 0):
        raise ValueError(f"start = {start}, frames = {frames}: expected 0 <= start < {n} and "
                         "frames > 0")
    source = np.arange(n)
    source[start:] = np.maximum(source[start:] - frames, start)
    return np.asarray(thetas, dtype=float)[source]


def jumped_bends(thetas: FloatArray, frame: int, segment: int, jump_deg: float,
                 theta_max: float) -> FloatArray:
    """``(F, S)`` angles: segment ``segment`` jumps by ``jump_deg`` degrees between frames
    ``frame - 1`` and ``frame`` and stays offset (a collision); towards zero if the jump would
    pass ``theta_max`` (radians)."""
    out = np.asarray(thetas, dtype=float).copy()
    if not 0 < frame < len(out):
        raise ValueError(f"frame = {frame}: expected 1..{len(out) - 1}")
    jump = math.radians(jump_deg)
    after = out[frame:, segment]
    sign = 1.0 if np.all(np.abs(after + jump) <= theta_max) else -1.0
    out[frame:, segment] = after + sign * jump
    if np.any(np.abs(out[:, segment]) > theta_max):
        raise ValueError(f"a jump of {jump_deg} deg takes segment {segment + 1} beyond its "
                         "theta_max either way")
    return out


def dropped_frames(sequence: Sequence, start: int, stop: int) -> Sequence:
    """``sequence`` without frames ``start..stop-1``: the recording paused while the robot
    moved on (the frames after keep their timestamps, so the gap shows in time; tracks keep
    their ids, as a tracker that picked them up again would).

    Raises:
        ValueError: an empty or out-of-range span.
    """
    if not 0 < start < stop < sequence.n_frames:
        raise ValueError(f"frames {start}..{stop - 1}: expected 0 < start < stop < "
                         f"{sequence.n_frames} (frames before and after the pause)")
    keep = np.r_[0:start, stop:sequence.n_frames]
    index = np.full(sequence.n_frames, -1)
    index[keep] = np.arange(len(keep))
    tracks = {}
    for cam, t in sequence.tracks.items():
        m = index[t.frames] >= 0
        tracks[cam] = Tracks(index[t.frames[m]], t.track_ids[m], t.uv[m])
    base = None if sequence.world_T_base is None else sequence.world_T_base[keep]
    thetas = None if sequence.thetas is None else sequence.thetas[keep]
    psis = None if sequence.psis is None else sequence.psis[keep]
    return Sequence(sequence.robot, sequence.timestamps[keep], tracks, world_T_base=base,
                    thetas=thetas, psis=psis)


def paused(sim: Simulation, start: int, stop: int) -> Simulation:
    """``sim`` without frames ``start..stop-1`` (:func:`dropped_frames`), its truth (each
    row's scene point, noise-free pixel and association; the true poses) without them too, so
    the bound of the paused recording can be computed.

    Raises:
        ValueError: an empty or out-of-range span.
    """
    sequence = dropped_frames(sim.sequence, start, stop)
    keep = np.r_[0:start, stop:sim.sequence.n_frames]
    truth: dict[str, dict[int, np.ndarray]] = {"landmarks": {}, "clean_uv": {}, "outliers": {}}
    for cam, t in sim.sequence.tracks.items():
        rows = (t.frames < start) | (t.frames >= stop)  # dropped_frames keeps their order
        for name, by_cam in truth.items():
            by_cam[cam] = getattr(sim, name)[cam][rows]
    return dataclasses.replace(
        sim, sequence=sequence, world_T_tip=sim.world_T_tip[keep],
        world_T_cam={cam: poses[keep] for cam, poses in sim.world_T_cam.items()}, **truth)
