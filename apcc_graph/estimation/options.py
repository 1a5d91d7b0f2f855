"""How the factor graph is built: one frozen options record shared by the batch and the smoother."""

from __future__ import annotations

import math
from dataclasses import dataclass

VISIONS = ("projection", "epipolar")
"""Vision models: ``"projection"`` (every observation once, each track's point eliminated; the
default) or ``"epipolar"`` (generalized epipolar factors between frame pairs, for comparison)."""
ROBUST_LOSSES = ("huber", "cauchy", "none")
DEFAULT_GAPS = (1, 2, 5, 10, 20)


@dataclass(frozen=True)
class GraphOptions:
    """How the factor graph is built (shared by the batch optimiser and the smoother).

    Common to both vision models:
        vision: ``"projection"`` or ``"epipolar"`` (see :data:`VISIONS`).
        threshold_px: the pixel noise, standard deviation per coordinate (pixels).
        theta0_sigma: prior standard deviation of the starting configuration (radians).
        motion_sigma: random-walk prior between consecutive frames (rad/sqrt(s)); ``None``
            leaves it out. Weak by default (5 deg between frames at 30 fps): it only carries
            frames the cameras do not constrain.
        limit_sigma: softness of the joint limits (radians).

    Projection model (:mod:`apcc_graph.factors.projection`):
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

    Epipolar model (:mod:`apcc_graph.factors.epipolar`):
        gaps: frame gaps between which epipolar factors are built.
        min_shared: fewest shared (and gated) tracks for a factor.
        gate_px: correspondences with a larger Sampson error at the current estimate are left
            out (pixels).
        loss: robust loss per correspondence (``"huber"``, ``"cauchy"``, ``"none"``).
        loss_sigmas: the robust loss's threshold in pixel-noise sigmas.
        min_baseline: pairs whose camera moved less (metres) are left out (no parallax).
        reuse_inflation: inflate each pair's sigma by ``sqrt(2 * len(gaps))``, the number of
            pairs an observation enters (a composite-likelihood correction).
    """

    vision: str = "projection"
    threshold_px: float = 1.0
    theta0_sigma: float = math.radians(0.1)
    motion_sigma: float | None = 0.5
    limit_sigma: float = math.radians(1.0)
    inlier_sigmas: float = 3.5
    frames_per_chunk: int = 15
    min_track_rows: int = 2
    max_track_frames: int | None = 150
    gaps: tuple[int, ...] = DEFAULT_GAPS
    min_shared: int = 15
    gate_px: float = 5.0
    loss: str = "huber"
    loss_sigmas: float = 1.345
    min_baseline: float = 0.002
    reuse_inflation: bool = True

    def __post_init__(self) -> None:
        if self.vision not in VISIONS:
            raise ValueError(f"vision = {self.vision!r}: expected one of {VISIONS}")
        if self.loss not in ROBUST_LOSSES:
            raise ValueError(f"robust loss {self.loss!r}: expected one of {ROBUST_LOSSES}")
        if not self.gaps or min(self.gaps) < 1:
            raise ValueError(f"gaps = {self.gaps!r}: expected positive frame gaps")
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


def reuse_factor(options: GraphOptions) -> float:
    """The epipolar pair-sigma inflation ``sqrt(2 * len(gaps))`` (1 without
    ``reuse_inflation``)."""
    return math.sqrt(2.0 * len(options.gaps)) if options.reuse_inflation else 1.0


def loss_scale(options: GraphOptions) -> float:
    """The epipolar robust loss threshold in whitened units: ``options.loss_sigmas`` pixel-noise
    sigmas, whatever the pair-sigma inflation."""
    return options.loss_sigmas / reuse_factor(options)
