"""Tracks that come back after a blackout: every camera saw nothing, and none of the tracks
that return is one the smoother knows.

Nothing then ties the new frames to the frames before the blackout but the motion prior across
it, loose by then (``motion_sigma`` times the square root of its length: about 29 degrees after
a second at the default). The new tracks give the motion back at once, but the absolute angles
only as far as the cameras' parallax and the kinematic chain tell them, and the smoother's
Gauss-Newton steps from a start that far off can end far from the truth. The projection
smoother does not recover that today; it says so (:class:`BlackoutWarning`, with the sigma the
motion prior had left).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.projection_tracks import Rows
from apcc_graph.model.arrays import FloatArray


class BlackoutWarning(UserWarning):
    """Every camera lost its tracks and only new ones came back: the absolute angles after the
    blackout may be far off (see :mod:`apcc_graph.estimation.blackout`)."""


def tracks_returned(rows: Rows, previous: Rows,
                    known: Callable[[int, NDArray[np.int64]], NDArray[np.bool_]]) -> bool:
    """Whether the new frame has tracks, the previous frame had none, and no new track is
    known (``known(camera, ids)``: which ids are landmarks or live tracks)."""
    if not rows or previous:
        return False
    return not any(np.any(known(cam, ids)) for cam, (ids, _, _) in rows.items())


def warn_blackout(frame: int, timestamp: float, sigmas: FloatArray) -> None:
    """Say that tracks came back after a blackout at ``frame`` (``sigmas``: the smoother's
    marginal sigmas of the last blind frame, radians; NaN if unknown)."""
    shown = ", ".join("?" if not math.isfinite(s) else f"{math.degrees(s):.2g}" for s in sigmas)
    warnings.warn(f"frame {frame} ({timestamp:.3f} s): every camera had lost its tracks and "
                  "only new ones came back; the angles across the blackout rest on the motion "
                  f"prior (sigma {shown} deg), and the estimate may stay far off after it: "
                  "check it against another sensor or restart from a known configuration",
                  BlackoutWarning, stacklevel=4)
