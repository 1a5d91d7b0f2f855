"""``theta_now.csv`` of a live run: every processed frame's estimate as it came out, beside
``theta.csv``'s final ones (:class:`NowEstimates`).

Columns: ``frame, timestamp, theta_1..theta_S, sigma_1..sigma_S, clamped_1..clamped_S``
(as ``theta.csv``), then ``estimate`` and ``latency_ms``:

- ``estimate`` says which it is: ``filtered`` (the smoother solved with the frame: only frames
  up to it were seen) or ``fit`` (with keyframes, a frame between keyframes: its fit to the
  window's points, sigmas empty; the next keyframe smooths it);
- ``latency_ms``: milliseconds from the frame's arrival to this estimate (0 when the run did
  not play the source in real time).

The frame's final, smoothed estimate is the row of the same ``frame`` in ``theta.csv``. Every
row is flushed as it is written, so a run that stops leaves a readable file.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from apcc_graph.io.csv_table import format_number
from apcc_graph.io.estimates import theta_columns

FILE = "theta_now.csv"


class NowEstimates:
    """Appends each estimate of a live run to ``folder/theta_now.csv`` (module docstring).

    Args:
        folder: where the file goes (created if needed; the file is replaced).
        n_segments: segments of the robot.
    """

    def __init__(self, folder: str | Path, n_segments: int) -> None:
        self.path = Path(folder) / FILE
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.n_segments = n_segments
        self.rows = 0
        self._file = open(self.path, "w", encoding="utf-8")  # noqa: SIM115
        self._file.write(",".join([*theta_columns(n_segments, clamped=True), "estimate",
                                   "latency_ms"]) + "\n")
        self._file.flush()

    def append(self, frame: int, timestamp: float, thetas: np.ndarray, sigmas: np.ndarray,
               clamped: np.ndarray | None, pending: bool, latency: float) -> None:
        """One frame's estimate as it came out (radians; ``pending``: the frame step's fit,
        else filtered; ``latency`` in seconds), written and flushed."""
        flags = (np.zeros(self.n_segments, dtype=bool) if clamped is None
                 else np.asarray(clamped, dtype=bool))
        sig = np.asarray(sigmas, dtype=float)
        fields = [str(frame), format_number(timestamp)]
        fields += [format_number(v) for v in np.asarray(thetas, dtype=float).tolist()]
        fields += ["" if not np.isfinite(v) else format_number(v) for v in sig.tolist()]
        fields += [str(int(v)) for v in flags.tolist()]
        fields += ["fit" if pending else "filtered", f"{1e3 * latency:.1f}"]
        self._file.write(",".join(fields) + "\n")
        self._file.flush()
        self.rows += 1

    def close(self) -> None:
        """Close the file."""
        self._file.close()
