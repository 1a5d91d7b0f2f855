"""``truth_tips.csv`` of a sequence folder: the measured pose of every segment end, frame by frame
(docs/formats.md, "Sequence folder").

Columns ``frame,segment,x,y,z,qw,qx,qy,qz``: frame 0-based, segment 1..S (as the cameras'
files), the pose ``world_T_tip`` of that segment's end (metres, unit quaternion ``w, x, y, z``).
A real-motion replay writes it as the sequence's ground truth, where no bending angles are known.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from apcc_graph.io.csv_table import format_number, read_table
from apcc_graph.io.poses import UNIT_TOLERANCE, quaternion_for_file
from apcc_graph.model.arrays import FloatArray

TRUTH_TIP_COLUMNS = ("frame", "segment", "x", "y", "z", "qw", "qx", "qy", "qz")


def truth_tips_csv(tips: FloatArray) -> str:
    """The text of ``truth_tips.csv`` for ``(F, S, 4, 4)`` poses."""
    rows = []
    for f, i in np.ndindex(*tips.shape[:2]):
        pose = tips[f, i]
        values = [*pose[:3, 3].tolist(), *quaternion_for_file(pose[:3, :3])]
        rows.append(f"{f},{i + 1}," + ",".join(format_number(v) for v in values) + "\n")
    return ",".join(TRUTH_TIP_COLUMNS) + "\n" + "".join(rows)


def load_truth_tips(path: Path, n_frames: int, n_segments: int) -> FloatArray:
    """``(F, S, 4, 4)`` poses of ``truth_tips.csv``: one row per frame and segment.

    Raises:
        ValueError: wrong header or numbers, a frame or segment out of range, a (frame, segment)
            missing or twice, a quaternion that is not unit; the message names file, line, column.
    """
    table = read_table(path, TRUTH_TIP_COLUMNS)
    table.require_finite()
    frames = table.integers("frame")
    segments = table.integers("segment", minimum=1)
    for name, values, limit in (("frame", frames, n_frames - 1), ("segment", segments,
                                                                  n_segments)):
        bad = np.flatnonzero(values > limit)
        if len(bad):
            raise table.error(int(bad[0]), name, f"{values[bad[0]]} is beyond the sequence's "
                              f"last {name} ({limit})")
    cell = frames * n_segments + (segments - 1)
    seen = np.zeros(n_frames * n_segments, dtype=np.int64) - 1
    for row, c in enumerate(cell.tolist()):
        if seen[c] >= 0:
            raise table.error(row, "segment", f"frame {frames[row]}, segment {segments[row]} "
                              f"already given on line {table.line(seen[c])}")
        seen[c] = row
    if np.any(seen < 0):
        c = int(np.flatnonzero(seen < 0)[0])
        raise ValueError(f"{path}: no row for frame {c // n_segments}, segment "
                         f"{c % n_segments + 1}: expected one row per frame and segment")
    quat = table.values[:, 5:9]
    norm = np.linalg.norm(quat, axis=1)
    bad = np.flatnonzero(np.abs(norm - 1.0) > UNIT_TOLERANCE)
    if len(bad):
        raise table.error(int(bad[0]), "qw", f"expected a unit quaternion, norm {norm[bad[0]]:.9g}")
    w, x, y, z = (quat / norm[:, None]).T
    rot = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                    2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                    2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
                   axis=-1).reshape(-1, 3, 3)
    out = np.zeros((n_frames * n_segments, 4, 4))
    out[cell, :3, :3] = rot
    out[cell, :3, 3] = table.values[:, 2:5]
    out[:, 3, 3] = 1.0
    return out.reshape(n_frames, n_segments, 4, 4)
