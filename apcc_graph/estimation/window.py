"""The window of the fixed-lag smoother (:mod:`apcc_graph.estimation.smoother`).

- :class:`SmootherFrame`: one frame's estimate as a smoother returns it;
- :class:`Window`: which frames are inside the window (each with the gtsam timestamp of its
  variables), their latest estimates and statuses, which of them the next update marginalises,
  the final estimates of the frames that left (the variables themselves are in gtsam's iSAM2,
  which :mod:`apcc_graph.estimation.smoother.solver` owns);
- :func:`key_stamps`: the timestamps of new variables per key;
- :func:`start_angles` and :func:`observed_camera`: the checks of a stream's robot, start and
  observations.

A frame's final estimate (and marginal sigma) is the one of the last update in which it was
inside the window.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import ArrayLike, NDArray

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.camera import TipCamera
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot


class RestartWarning(UserWarning):
    """gtsam failed on a smoother's window (typically an indeterminate system: the data no
    longer determine some variable) and the smoother started afresh from its last estimate:
    what the window knew is lost, and the estimates may be off until the images pull them
    back. The message names the frame."""


def warn_restart(frame: int, timestamp: float, error: BaseException | None) -> None:
    """Say that a smoother restarted at ``frame`` (see :class:`RestartWarning`)."""
    from apcc_graph.estimation.failures import gtsam_cause

    cause = "" if error is None else gtsam_cause(error)[:120]
    warnings.warn(f"frame {frame} ({timestamp:.3f} s): gtsam failed on the window "
                  f"({cause or 'no message'}); the smoother restarted from its last estimate "
                  "with a loose prior, so the angles may be off until the images pull them "
                  "back", RestartWarning, stacklevel=4)


@dataclass(frozen=True)
class SmootherFrame:
    """One frame's estimate as a smoother returns it.

    Attributes:
        frame: 0-based frame index (the order of the smoother's ``update`` calls).
        timestamp: seconds.
        thetas: ``(S,)`` angles (radians; a spatial robot's bend magnitudes).
        sigmas: ``(S,)`` marginal standard deviations (radians; NaN without uncertainty).
        status: ``(S,)`` per segment: ``"ok"`` (measured), ``"initial"`` (first frame),
            ``"predicted"`` (no known point seen: the prediction stands), ``"recovered"``
            (after a gtsam failure), ``"reacquired"`` (re-acquired by a batch after a
            blackout; only the segment a lost camera's return re-acquired, after one camera's)
            or ``"still"`` (the robot stood still: the frame takes the estimate of
            the last one that moved; :mod:`apcc_graph.estimation.stillness`).
        psis, psi_sigmas: for a spatial robot, ``(S,)`` bending planes and their standard
            deviations (radians; ``thetas`` are then the bends' magnitudes, as in
            :class:`~apcc_graph.estimation.result.Estimate`); ``None`` otherwise.

    Inside the window a frame is recorded in the smoother's parameterisation (``thetas`` its
    frame vector, ``sigmas`` its flattened covariance blocks); :func:`present_frame` turns
    that record into the above.
    """

    frame: int
    timestamp: float
    thetas: FloatArray
    sigmas: FloatArray
    status: NDArray[np.str_]
    psis: FloatArray | None = None
    psi_sigmas: FloatArray | None = None


def present_frame(bending: Bending, frame: SmootherFrame) -> SmootherFrame:
    """A frame as a smoother returns it, from its record: the frame vector ``thetas`` and the
    flattened per-segment covariance blocks ``sigmas``
    (:meth:`~apcc_graph.model.parameterisation.Bending.blocks`)."""
    x = np.asarray(frame.thetas, dtype=float)
    w = bending.width
    blocks = np.asarray(frame.sigmas, dtype=float).reshape(bending.n_segments, w, w)
    thetas, psis = bending.polar(x)
    sigmas, psi_sigmas = bending.deviations(x, blocks)
    return replace(frame, thetas=thetas, sigmas=sigmas, psis=psis, psi_sigmas=psi_sigmas)


def component_sigmas(bending: Bending, blocks: FloatArray) -> FloatArray:
    """``(dim,)`` standard deviations of a frame vector's components from its flattened
    covariance blocks (NaN stays NaN)."""
    w = bending.width
    C = np.asarray(blocks, dtype=float).reshape(bending.n_segments, w, w)
    return np.sqrt(np.maximum(np.diagonal(C, axis1=-2, axis2=-1), 0.0)).ravel()


def key_stamps(stamps: Iterable[tuple[int, float]] = ()) -> dict[int, float]:
    """The timestamp of each new variable (seconds, by key), from ``(key, seconds)``."""
    return {int(key): float(stamp) for key, stamp in stamps}


def check_timestamp(frame: int, timestamp: float, last: float | None) -> float:
    """Frame ``frame``'s timestamp (seconds), which must be finite and after ``last``, the
    previous frame's (``None`` for the first frame)."""
    t = float(timestamp)
    if not math.isfinite(t) or (last is not None and t <= last):
        shown = float("nan") if last is None else last
        raise ValueError(f"frame {frame}: timestamp {t!r} s is not after the previous "
                         f"frame's {shown!r} s")
    return t


class Window:
    """The frames inside a fixed-lag smoother's window and the final estimates of those that
    left it.

    Args:
        lag: window length (seconds).
        n_segments: the length of a frame's recorded sigmas (the ``S w^2`` entries of its
            covariance blocks, :func:`present_frame`).
        present: turns a frame's record into what the smoother returns
            (:func:`present_frame`); default as recorded.

    Attributes:
        stamps: frame -> gtsam timestamp of its variables (seconds), for frames inside.
        times: frame -> its timestamp (seconds), for frames inside.
        thetas: frame -> its latest estimate (its frame vector), for frames inside (and the
            new one).
        status: frame -> its status ``(S,)``, for frames inside.
        final: frame -> final estimate, for frames that left (until :meth:`pop_final`).
        recent: frame -> final estimate of the two newest frames that left, kept for
            :meth:`latest` (after a pause longer than the lag, or a lag shorter than a
            marginalisation block, the previous frame has left when the next one arrives).
        count: frames received so far.
        last_time: the timestamp of the last frame received (``None`` before the first).
    """

    def __init__(self, lag: float, n_segments: int,
                 present: Callable[[SmootherFrame], SmootherFrame] | None = None) -> None:
        self.lag = lag
        self.n_segments = n_segments
        self.present = present or (lambda frame: frame)
        self.stamps: dict[int, float] = {}
        self.times: dict[int, float] = {}
        self.thetas: dict[int, FloatArray] = {}
        self.status: dict[int, NDArray[np.str_]] = {}
        self.final: dict[int, SmootherFrame] = {}
        self.recent: dict[int, FloatArray] = {}
        self.count = 0
        self.last_time: float | None = None

    def leaving(self, stamp: float) -> list[int]:
        """Frames the next update marginalises: their variables' timestamps are more than the
        lag older than ``stamp``."""
        return [g for g, sg in self.stamps.items() if sg < stamp - self.lag]

    def enter(self, frame: int, t: float, stamp: float, status: NDArray[np.str_]) -> None:
        """Record a frame inside the window."""
        self.stamps[frame] = stamp
        self.times[frame] = t
        self.status[frame] = status

    def leave(self, frame: int, thetas: FloatArray, sigmas: FloatArray) -> None:
        """A frame leaves the window with its final estimate."""
        self.stamps.pop(frame)
        self.final[frame] = SmootherFrame(frame, self.times.pop(frame), thetas, sigmas,
                                          self.status.pop(frame))
        self.thetas.pop(frame, None)
        self._keep_recent(frame, thetas)

    def _keep_recent(self, frame: int, thetas: FloatArray) -> None:
        self.recent[frame] = np.asarray(thetas, dtype=float).copy()
        for g in sorted(self.recent)[:-2]:
            del self.recent[g]

    def latest(self, frame: int) -> FloatArray | None:
        """The latest estimate (frame vector) of ``frame``: inside the window, or one of the two
        newest frames that left; ``None`` otherwise (e.g. before the stream began)."""
        inside = self.thetas.get(frame)
        return inside if inside is not None else self.recent.get(frame)

    def inside(self, frame: int) -> bool:
        """Whether ``frame``'s variables are still in the window (not marginalised)."""
        return frame in self.stamps

    def leave_all_but(self, frame: int, fallback: FloatArray,
                      sigmas: Mapping[int, FloatArray] | None = None) -> None:
        """After a restart every frame but ``frame`` leaves with its latest estimate (or
        ``fallback``) and its sigmas from ``sigmas`` (else none): the new gtsam smoother no
        longer holds them."""
        nan = np.full(self.n_segments, np.nan)
        for g in [g for g in self.stamps if g != frame]:
            est = self.thetas.pop(g, fallback)
            self.stamps.pop(g)
            self.final[g] = SmootherFrame(g, self.times.pop(g), est.copy(),
                                          (sigmas or {}).get(g, nan), self.status.pop(g))
            self._keep_recent(g, est)

    def reacquired(self, slots: Iterable[int], thetas: FloatArray, blocks: FloatArray,
                   n_segments: int) -> None:
        """Frames ``slots`` take re-acquired estimates ``thetas`` and flattened covariance
        blocks (status ``"reacquired"``): those in the window, and those that left at a
        restart and were not taken yet."""
        status = np.full(n_segments, "reacquired", dtype="<U24")
        for h, th, cov in zip(slots, thetas, blocks, strict=True):
            if self.inside(h):
                self.thetas[h], self.status[h] = th, status
            elif h in self.final:
                self.final[h] = SmootherFrame(h, self.final[h].timestamp, th, cov, status)

    def reacquired_segment(self, slots: Iterable[int], segment: int, block: slice,
                           thetas: FloatArray, blocks: FloatArray) -> None:
        """Frames ``slots`` take segment ``segment``'s components ``block`` of the re-acquired
        frame vectors ``thetas`` (and its covariance block of the flattened ``blocks``;
        status ``"reacquired"`` for that segment): those in the window, and those that left
        and were not taken yet."""
        w2 = (block.stop - block.start) ** 2
        cells = slice(w2 * segment, w2 * (segment + 1))
        for h, th, cov in zip(slots, thetas, blocks, strict=True):
            if self.inside(h):
                self.thetas[h][block] = th[block]
                self.status[h][segment] = "reacquired"
            elif h in self.final:
                old = self.final[h]
                x, s, status = old.thetas.copy(), old.sigmas.copy(), old.status.copy()
                x[block], s[cells], status[segment] = th[block], cov[cells], "reacquired"
                self.final[h] = SmootherFrame(h, old.timestamp, x, s, status)

    def reenter(self, frame: int, thetas: FloatArray) -> bool:
        """A frame that left (at a restart) and was not taken yet comes back into the window
        at ``thetas`` (a restart that holds the frames a batch re-acquired); returns whether
        it did."""
        record = self.final.pop(frame, None)
        if record is None:
            return False
        self.stamps[frame] = self.times[frame] = record.timestamp
        self.thetas[frame], self.status[frame] = np.array(thetas, dtype=float), record.status
        for kept in (self.stamps, self.times, self.thetas, self.status):
            ordered = sorted(kept.items())
            kept.clear()
            kept.update(ordered)
        return True

    def revise(self, frame: int, thetas: FloatArray, blocks: FloatArray) -> None:
        """A frame that left takes a better final estimate (its status unchanged), unless it
        was taken already (:meth:`pop_final`)."""
        if frame in self.final:
            self.final[frame] = replace(self.final[frame], thetas=thetas, sigmas=blocks)

    def pop_final(self) -> list[SmootherFrame]:
        """The frames that left since the last call, in order, and forget them."""
        out = [self.present(self.final[g]) for g in sorted(self.final)]
        self.final.clear()
        return out

    def frames(self, sigmas: Callable[[int], FloatArray]) -> list[SmootherFrame]:
        """Every frame's final estimate in order: frames inside the window with their current
        estimate and ``sigmas(frame)``."""
        out = dict(self.final)
        for g in self.stamps:
            out[g] = SmootherFrame(g, self.times[g], self.thetas[g].copy(), sigmas(g),
                                   self.status[g].copy())
        return [self.present(out[g]) for g in sorted(out)]


def start_angles(owner: str, robot: Robot, theta0: ArrayLike | None) -> FloatArray:
    """The stream's starting configuration ``(S,)`` (radians; default straight), after checking
    that ``robot`` is a :class:`~apcc_graph.model.robot.Robot`."""
    if not isinstance(robot, Robot):
        raise ValueError(f"{owner}.robot: expected a Robot, got {type(robot).__name__}")
    return robot.configuration(theta0, f"{owner}.theta0")


def observed_camera(robot: Robot, frame: int, cam: int) -> TipCamera:
    """The camera of segment ``cam``, which a frame's observations name."""
    camera = robot.cameras[cam] if 0 <= cam < robot.n_segments else None
    if camera is None:
        raise ValueError(f"frame {frame}: observations of camera {cam}, but segment {cam} "
                         f"has no camera (cameras ride on {robot.camera_segments})")
    return camera
