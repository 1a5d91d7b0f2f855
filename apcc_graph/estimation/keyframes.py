"""When a frame becomes a keyframe: the rule a real-time smoother uses to keep only some frames
in its window while every frame still gets an estimate.

A frame is compared with the last keyframe, camera by camera, from what the images alone say
(no model): the tracks the two share, their unit bearings ``f_k`` (keyframe) and ``f_n`` (now),
and the camera's rotation between them ``k_R_n`` (the rotation-only fit the front end already
makes; :mod:`~apcc_graph.frontend.rotation_pairs`). Four measures, each of which can make the
frame a keyframe (:class:`KeyframeRule`):

- **time** since the last keyframe: a still robot still gets a keyframe now and then, so the
  window never holds stale frames only;
- **rotation** of any camera, ``|Log(k_R_n)|``: a turning camera loses its tracks quickly, and
  the rotation is what the tip cameras measure best;
- **parallax**, the lower quartile over the shared tracks of the angle between ``f_k`` and
  ``k_R_n f_n`` (the bearing change the rotation does not explain, radians): what carries the
  translations, and so the bends. A quartile, not the median: a pair of rows is clean only
  when both are, and with 30% wrong associations per row only half the pairs are (the median
  then measured an outlier's jump and made 274 of 300 frames keyframes on the smoother
  benchmark); the lower quartile stands while fewer than three pairs in four are wrong;
- **survival**, the share of the keyframe's tracks the camera still sees: below it, the next
  keyframe would share too few tracks with this one to be tied to it.

The measures are per camera; a frame is a keyframe when any camera passes any threshold.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.model.arrays import FloatArray

PARALLAX_QUANTILE = 0.25
"""The quantile of the shared tracks' bearing changes that measures a camera's parallax (module
docstring)."""

TIME_TOLERANCE = 1e-6
"""Seconds: an interval this close to ``max_interval`` reaches it (timestamps of a camera at a
fixed rate are sums of rounded steps)."""


@dataclass(frozen=True)
class KeyframeRule:
    """The thresholds of a new keyframe (module docstring). The defaults were measured against
    the smoother that solves at every frame (docs/estimation.md, "Keyframes": the same final
    accuracy, median over the smoother benchmark's seeds, in about 0.6x the time; worse on
    one seed of five): at 30 fps at least every third frame, more often while the cameras
    turn or see parallax.

    Attributes:
        max_interval: seconds since the last keyframe.
        rotation: radians of any camera's rotation since the last keyframe.
        parallax: radians of the lower quartile of the rotation-compensated bearing changes of
            a camera's tracks shared with the last keyframe.
        survival: the least share of the last keyframe's tracks a camera still sees (0 to 1).
        min_shared: below this many shared tracks a camera's parallax is not measured (and the
            survival decides).
        max_deferral: seconds since the last keyframe within which a busy caller (the live
            loop with frames waiting) may defer a keyframe these measures ask for; after it the
            frame is a keyframe anyway (at 30 fps every sixth frame; every tenth cost up to 56x
            the accuracy of one segment on the smoother benchmark's room scene).
    """

    max_interval: float = 0.1
    rotation: float = 0.1
    parallax: float = 0.03
    survival: float = 0.6
    min_shared: int = 5
    max_deferral: float = 0.2

    def __post_init__(self) -> None:
        for name in ("max_interval", "rotation", "parallax", "max_deferral"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and value > 0.0):
                raise ValueError(f"KeyframeRule.{name} = {value!r}: expected a positive number")
        if not 0.0 <= self.survival <= 1.0:
            raise ValueError(f"KeyframeRule.survival = {self.survival!r}: expected a share "
                             "from 0 to 1")
        if self.min_shared < 1:
            raise ValueError(f"KeyframeRule.min_shared = {self.min_shared!r}: expected at "
                             "least 1 track")


@dataclass(frozen=True)
class ViewChange:
    """One camera's change since the last keyframe (module docstring).

    Attributes:
        rotation: ``|Log(k_R_n)|`` (radians).
        parallax: the lower quartile of the rotation-compensated bearing changes of the
            shared tracks (radians; ``nan`` with fewer than the rule's ``min_shared`` of them).
        survival: the share of the keyframe's tracks still seen (1 for a keyframe without
            tracks).
    """

    rotation: float
    parallax: float
    survival: float


def view_change(f_key: ArrayLike, f_now: ArrayLike, k_R_n: ArrayLike, keyframe_tracks: int,
                min_shared: int = 5) -> ViewChange:
    """One camera's :class:`ViewChange` from the bearings ``(N, 3)`` of the ``N`` tracks it
    shares with the last keyframe (unit or not), in the keyframe (``f_key``) and now
    (``f_now``), its rotation ``k_R_n`` ``(3, 3)`` between them, and how many tracks it had at
    the keyframe."""
    f_key = np.asarray(f_key, dtype=float).reshape(-1, 3)
    f_now = np.asarray(f_now, dtype=float).reshape(-1, 3)
    if f_key.shape != f_now.shape:
        raise ValueError(f"f_key has shape {f_key.shape} and f_now {f_now.shape}: expected the "
                         "same (N, 3) bearings of the shared tracks")
    R = np.asarray(k_R_n, dtype=float)
    rotation = rotation_angle(R)
    shared = len(f_key)
    parallax = float("nan")
    if shared >= min_shared:
        a = f_key / np.linalg.norm(f_key, axis=1, keepdims=True)
        b = f_now @ R.T
        b = b / np.linalg.norm(b, axis=1, keepdims=True)
        angles = np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.sum(a * b, axis=1))
        parallax = float(np.quantile(angles, PARALLAX_QUANTILE))
    survival = 1.0 if keyframe_tracks <= 0 else min(1.0, shared / keyframe_tracks)
    return ViewChange(rotation, parallax, survival)


def keyframe_reasons(rule: KeyframeRule, elapsed: float,
                     changes: dict[int, ViewChange]) -> list[str]:
    """Why a frame ``elapsed`` seconds after the last keyframe, whose cameras changed by
    ``changes`` (camera -> :class:`ViewChange`), is a keyframe: an empty list when it is not,
    else one phrase per reason (``"time"``, ``"rotation of camera 1"``, ...)."""
    reasons = ["time"] if elapsed >= rule.max_interval - TIME_TOLERANCE else []
    for cam, change in sorted(changes.items()):
        if change.rotation >= rule.rotation:
            reasons.append(f"rotation of camera {cam}")
        if np.isfinite(change.parallax) and change.parallax >= rule.parallax:
            reasons.append(f"parallax of camera {cam}")
        if change.survival < rule.survival:
            reasons.append(f"tracks of camera {cam}")
    return reasons


def rotation_angle(R: FloatArray) -> float:
    """``|Log(R)|`` of a rotation matrix (radians; gtsam's ``Rot3.Logmap``)."""
    return float(np.linalg.norm(gtsam.Rot3.Logmap(gtsam.Rot3(np.asarray(R, dtype=float)))))
