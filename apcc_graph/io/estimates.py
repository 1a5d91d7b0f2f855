"""Estimates on disk: ``theta.csv`` and one TUM trajectory per segment tip (docs/formats.md).

- ``theta.csv``: ``frame,timestamp,theta_1..theta_S,sigma_1..sigma_S`` (radians; a sigma is
  written as ``nan`` where the method gives none); an estimate of a spatial robot adds
  ``psi_1..psi_S,psi_sigma_1..psi_sigma_S``, the bending planes and their standard deviations
  (radians; ``theta >= 0`` then, and a ``psi_sigma`` is ``inf`` at exactly straight);
- ``tips_seg_<i>.tum``: ``timestamp tx ty tz qx qy qz qw`` per frame, the pose of segment i's tip
  in the world frame (metres; Hamilton quaternion, scalar last as TUM and evo expect).

Files are written atomically (temporary file, then rename).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.io.atomic import atomic_write_text
from apcc_graph.io.csv_table import format_number, read_header, read_table
from apcc_graph.model.arrays import FloatArray


class Estimate(Protocol):
    """What is written of an estimate (``apcc_graph.estimation.result.Estimate`` is one; this
    layer reads files and does not import the estimators)."""

    @property
    def timestamps(self) -> FloatArray: ...  # (F,) seconds

    @property
    def thetas(self) -> FloatArray: ...  # (F, S) radians

    @property
    def sigmas(self) -> FloatArray: ...  # (F, S) radians, NaN where unknown

    @property
    def psis(self) -> FloatArray | None: ...  # (F, S) radians, spatial estimates only

    @property
    def psi_sigmas(self) -> FloatArray | None: ...  # (F, S) radians, spatial estimates only

    @property
    def n_frames(self) -> int: ...

    def world_T_tip(self) -> FloatArray: ...  # (F, S, 4, 4)


def theta_columns(n_segments: int, spatial: bool = False, clamped: bool = False) -> list[str]:
    """The header of ``theta.csv`` (with the bending-plane columns when ``spatial``, and the
    live run's ``clamped_i`` flags when ``clamped``)."""
    names = (["frame", "timestamp"] + [f"theta_{i}" for i in range(1, n_segments + 1)]
             + [f"sigma_{i}" for i in range(1, n_segments + 1)])
    if spatial:
        names += ([f"psi_{i}" for i in range(1, n_segments + 1)]
                  + [f"psi_sigma_{i}" for i in range(1, n_segments + 1)])
    if clamped:
        names += [f"clamped_{i}" for i in range(1, n_segments + 1)]
    return names


def theta_csv(estimate: Estimate) -> str:
    """The text of ``theta.csv``."""
    n_seg = estimate.thetas.shape[1]
    psis = getattr(estimate, "psis", None)
    columns = [estimate.thetas, estimate.sigmas]
    if psis is not None:
        psi_sigmas = getattr(estimate, "psi_sigmas", None)
        columns += [psis, np.full(psis.shape, np.nan) if psi_sigmas is None else psi_sigmas]
    values = np.hstack(columns)
    lines = [",".join(theta_columns(n_seg, psis is not None))]
    for f in range(estimate.n_frames):
        fields = [str(f), format_number(estimate.timestamps[f])]
        fields += [format_number(v) for v in values[f].tolist()]
        lines.append(",".join(fields))
    return "\n".join(lines) + "\n"


def tum_text(timestamps: np.ndarray, world_T_tip: np.ndarray) -> str:
    """TUM lines ``timestamp tx ty tz qx qy qz qw`` for ``(F, 4, 4)`` poses."""
    lines = []
    for t, pose in zip(timestamps.tolist(), world_T_tip, strict=True):
        q = gtsam.Rot3(pose[:3, :3]).toQuaternion()
        x, y, z = pose[:3, 3].tolist()
        lines.append(" ".join(repr(float(v)) for v in (t, x, y, z, q.x(), q.y(), q.z(), q.w())))
    return "\n".join(lines) + "\n"


def save_estimate(estimate: Estimate, folder: str | Path) -> list[Path]:
    """Write ``theta.csv`` and ``tips_seg_<i>.tum`` into ``folder``; returns the files written.

    Each file is written atomically with the umask's permissions. To replace an estimate
    folder whole (no old TUM file beside a new ``theta.csv``), write into
    :func:`apcc_graph.io.output_folder.staged_folder`, as ``apcc-graph estimate`` does.

    Raises:
        OSError: a file could not be written (a full disk, no permission), naming it.
    """
    folder = Path(folder)
    written = [folder / "theta.csv"]
    atomic_write_text(written[0], theta_csv(estimate))
    tips = estimate.world_T_tip()
    for i in range(estimate.thetas.shape[1]):
        path = folder / f"tips_seg_{i + 1}.tum"
        atomic_write_text(path, tum_text(estimate.timestamps, tips[:, i]))
        written.append(path)
    return written


class AppendedEstimate:
    """``theta.csv`` and ``tips_seg_<i>.tum`` of an estimate that grows frame by frame (a live
    run): each final estimate is appended to every file and flushed, so a run that stops or
    crashes leaves complete, readable files of everything estimated so far.

    Frame numbers are the source's and increase strictly; frames the run skipped are absent
    (gaps). ``theta.csv`` adds ``clamped_1..clamped_S``: 1 where an angle was beyond its
    segment's ``theta_max`` and is written clamped to it, else 0.

    Args:
        folder: where the files go (created if needed; the files are replaced).
        n_segments: segments of the robot.
        forward: ``(F, S) angles -> (F, S, 4, 4)`` tip poses (the robot's kinematics).
    """

    def __init__(self, folder: str | Path, n_segments: int,
                 forward: Callable[[np.ndarray], np.ndarray]) -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)
        self.forward = forward
        self.n_segments = n_segments
        self.rows = 0
        self.clamped_rows = 0
        self._last: tuple[int, float] | None = None
        self._theta = open(self.folder / "theta.csv", "w", encoding="utf-8")  # noqa: SIM115
        self._tips = [open(self.folder / f"tips_seg_{i + 1}.tum", "w",  # noqa: SIM115
                           encoding="utf-8") for i in range(n_segments)]
        self._theta.write(",".join(theta_columns(n_segments, clamped=True)) + "\n")
        self._theta.flush()

    def append(self, frame: int, timestamp: float, thetas: np.ndarray, sigmas: np.ndarray,
               clamped: np.ndarray | None = None) -> None:
        """One frame's final estimate (angles and sigmas in radians; ``clamped``: ``(S,)``
        which angles were clamped to their limit), written and flushed.

        Raises:
            ValueError: a frame number or timestamp not after the previous row's.
        """
        if self._last is not None and not (frame > self._last[0]
                                           and timestamp > self._last[1]):
            raise ValueError(f"{self.folder / 'theta.csv'}: frame {frame} at {timestamp!r} s "
                             f"after frame {self._last[0]} at {self._last[1]!r} s; expected "
                             "strictly increasing frames and times")
        flags = (np.zeros(self.n_segments, dtype=bool) if clamped is None
                 else np.asarray(clamped, dtype=bool))
        fields = [str(frame), format_number(timestamp)]
        fields += [format_number(v) for v in np.concatenate([thetas, sigmas]).tolist()]
        fields += [str(int(v)) for v in flags.tolist()]
        self._theta.write(",".join(fields) + "\n")
        tips = self.forward(np.asarray(thetas, dtype=float)[None])[0]
        for i, out in enumerate(self._tips):
            out.write(tum_text(np.array([timestamp]), tips[i][None]))
        for out in (self._theta, *self._tips):
            out.flush()
        self._last = (frame, timestamp)
        self.rows += 1
        self.clamped_rows += int(flags.any())

    def close(self) -> None:
        """Close the files."""
        for out in (self._theta, *self._tips):
            out.close()


@dataclass(frozen=True)
class ThetaTable:
    """The contents of ``theta.csv`` (radians, seconds).

    Attributes:
        timestamps: ``(F,)``.
        thetas, sigmas: ``(F, S)``.
        psis, psi_sigmas: ``(F, S)`` for a spatial estimate, else ``None``.
        frames: ``(F,)`` the sequence's frame numbers of the rows, strictly increasing (a live
            run that skipped frames has gaps); ``None`` means ``0..F-1``.
        clamped: ``(F, S)`` a live run's flags: the angle was beyond its segment's limit and
            is written clamped to it; ``None`` when the file has no such columns.
    """

    timestamps: FloatArray
    thetas: FloatArray
    sigmas: FloatArray
    psis: FloatArray | None = None
    psi_sigmas: FloatArray | None = None
    frames: NDArray[np.int64] | None = None
    clamped: NDArray[np.bool_] | None = None

    def frame_numbers(self) -> NDArray[np.int64]:
        """The rows' frame numbers (``0..F-1`` when not read from a file)."""
        return np.arange(len(self.timestamps)) if self.frames is None else self.frames


def load_theta_csv(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Read ``theta.csv``: ``(timestamps (F,), thetas (F, S), sigmas (F, S))``; the bending
    planes of a spatial estimate are read by :func:`load_theta_table`.

    Raises:
        ValueError: bad header or values; the message names the file and the line.
    """
    table = load_theta_table(path)
    return table.timestamps, table.thetas, table.sigmas


def load_theta_table(path: str | Path) -> ThetaTable:
    """Read ``theta.csv``, with its bending-plane columns if it has them. Frame numbers and
    timestamps must increase strictly; frames may be skipped (a live run's file has gaps).

    Raises:
        ValueError: bad header or values (a ``psi`` that is not finite included); the message
            names the file and the line.
    """
    path = Path(path)
    names = read_header(path)
    n_seg = sum(1 for n in names if n.startswith("theta_"))
    if n_seg == 0:
        raise ValueError(f"{path}: line 1: expected columns {','.join(theta_columns(1))}...")
    spatial = "psi_1" in names
    table = read_table(path, theta_columns(n_seg, spatial, clamped="clamped_1" in names))
    if len(table) == 0:
        raise ValueError(f"{path}: no frames")
    frames = table.integers("frame")
    back = np.flatnonzero(np.diff(frames) <= 0)
    if len(back):
        row = int(back[0]) + 1
        raise table.error(row, "frame", f"frame {int(frames[row])} after frame "
                          f"{int(frames[row - 1])}; expected strictly increasing frame numbers")
    times = table.column("timestamp")
    if not np.all(np.isfinite(times)):
        row = int(np.flatnonzero(~np.isfinite(times))[0])
        raise table.error(row, "timestamp", f"expected a finite time (seconds), got "
                          f"{float(times[row])!r}")
    back = np.flatnonzero(np.diff(times) <= 0)
    if len(back):
        row = int(back[0]) + 1
        raise table.error(row, "timestamp", f"{float(times[row])!r} s is not after the previous "
                          f"row's {float(times[row - 1])!r} s; expected strictly increasing times")
    values = table.values
    thetas = values[:, 2:2 + n_seg]
    if not np.all(np.isfinite(thetas)):
        row, col = np.argwhere(~np.isfinite(thetas))[0]
        raise table.error(int(row), f"theta_{col + 1}", "expected a finite angle (radians)")
    sigmas = values[:, 2 + n_seg:2 + 2 * n_seg].copy()
    if not spatial:
        return ThetaTable(values[:, 1].copy(), thetas.copy(), sigmas, frames=frames,
                          clamped=_clamped(values, n_seg, names))
    psis = values[:, 2 + 2 * n_seg:2 + 3 * n_seg]
    if not np.all(np.isfinite(psis)):
        row, col = np.argwhere(~np.isfinite(psis))[0]
        raise table.error(int(row), f"psi_{col + 1}", "expected a finite angle (radians)")
    return ThetaTable(values[:, 1].copy(), thetas.copy(), sigmas, psis.copy(),
                      values[:, 2 + 3 * n_seg:2 + 4 * n_seg].copy(), frames,
                      _clamped(values, n_seg, names))


def _clamped(values: np.ndarray, n_seg: int, names: list[str]) -> NDArray[np.bool_] | None:
    """The ``clamped_i`` flags (the last ``n_seg`` columns), if the file has them."""
    return values[:, -n_seg:] != 0 if "clamped_1" in names else None
