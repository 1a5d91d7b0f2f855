"""How the factor graph is built: one frozen options record shared by the batch and the
smoother."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class GraphOptions:
    """How the factor graph is built (shared by the batch optimiser and the smoother).

    Attributes:
        threshold_px: the pixel noise, standard deviation per coordinate (pixels).
        theta0_sigma: prior standard deviation of the starting configuration (radians).
        motion_sigma: random-walk prior between consecutive frames (rad/sqrt(s)); ``None``
            leaves it out. Weak by default (5 deg between frames at 30 fps): it only carries
            frames the cameras do not constrain.
        limit_sigma: softness of the joint limits (radians).
        inlier_sigmas: an observation whose whitened reprojection error (pixel-noise units,
            2 degrees of freedom) at its track's point exceeds this is an outlier (truncated
            least squares); 3.5 keeps 99.8% of true observations.
        frames_per_chunk: tracks starting within this many frames of each other share one
            gtsam factor (one Python callback per chunk and linearisation).
        min_track_rows: tracks seen in fewer frames are left out (one observation of an
            unknown point carries no information; two carry one number).
        max_track_frames: longer tracks are cut into pieces of this many frames, each with a
            point of its own, so that no factor spans more frames than this (its dense block
            grows with the square of its span); ``None`` keeps whole tracks.
    """

    threshold_px: float = 1.0
    theta0_sigma: float = math.radians(0.1)
    motion_sigma: float | None = 0.5
    limit_sigma: float = math.radians(1.0)
    inlier_sigmas: float = 3.5
    frames_per_chunk: int = 15
    min_track_rows: int = 2
    max_track_frames: int | None = 150

    def __post_init__(self) -> None:
        for name in ("threshold_px", "theta0_sigma", "limit_sigma", "inlier_sigmas"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"GraphOptions.{name} = {value!r}: expected a finite value > 0")
        if self.motion_sigma is not None and not (math.isfinite(self.motion_sigma)
                                                  and self.motion_sigma > 0.0):
            raise ValueError(f"GraphOptions.motion_sigma = {self.motion_sigma!r}: expected a "
                             "finite value > 0 (rad/sqrt(s)) or None")
        if self.frames_per_chunk < 1 or self.min_track_rows < 2:
            raise ValueError("GraphOptions: frames_per_chunk >= 1 and min_track_rows >= 2 "
                             f"expected, got {self.frames_per_chunk}, {self.min_track_rows}")
