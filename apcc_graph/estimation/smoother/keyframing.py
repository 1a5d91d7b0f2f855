"""Keyframes in the smoother's window: which frames enter it, and the estimates of the frames
that do not (:class:`Keyframes`).

With a :class:`~apcc_graph.estimation.keyframes.KeyframeRule` the smoother runs its full update
(the graph, iSAM2) on keyframes only. Every frame first gets a cheap *frame step*: its vector
predicted at constant velocity in time from the last two frames' estimates, then fitted to its
rows of the tracks whose points the window knows (the live pieces' points at the last
linearisation and the landmarks': :func:`~apcc_graph.estimation.initial_guess.refine`, a
perspective-n-point problem in joint space). The rule then compares the frame with the last
keyframe (:func:`~apcc_graph.estimation.keyframes.view_change`, each camera's rotation taken
from the two frames' estimates); a frame no measure flags is a *between frame*: the frame step's
vector is its estimate at once (status ``"between"``), and its rows wait. When the keyframe
before it leaves the window (its value final, the keyframes after it close to final), the
between frame is fitted again, from its frame step, to the window's points at that moment:
its final estimate. Its covariance is that fit's (points held) plus the keyframe's marginal.

The between frames' rows do not enter the graph: the tracks continue through them, and the
keyframes carry the tracks' information. How close this comes to the smoother that keeps
every frame, per keyframe rate: docs/estimation.md, "Keyframes".
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.initial_guess import frame_poses
from apcc_graph.estimation.keyframe_fit import Keyframe, KeyframePoints, keyframe_points
from apcc_graph.estimation.keyframes import KeyframeRule, ViewChange, keyframe_reasons, view_change
from apcc_graph.estimation.projection_tracks import Rows
from apcc_graph.estimation.window import SmootherFrame
from apcc_graph.factors.camera_chain import CameraChain
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot

BETWEEN = "between"
"""The status of a between frame's estimate (the frame step's, and its final fit's)."""


@dataclass
class BetweenFrame:
    """A frame kept out of the window, until the keyframe before it leaves.

    Attributes:
        frame: its number as received; ``timestamp``: as received (seconds).
        rows, base: its observations and base pose.
        x: its vector: the frame step's, then the final fit's (radians).
        blocks: its flattened covariance blocks (NaN until known).
        final: whether ``x`` is the final fit's.
    """

    frame: int
    timestamp: float
    rows: Rows
    base: FloatArray | None
    x: FloatArray
    blocks: FloatArray
    final: bool = False


FrameFit = Callable[[BetweenFrame, int, KeyframePoints], tuple[FloatArray, FloatArray]]
"""(between frame, its keyframe's slot, the points of the keyframes around it) -> its final
vector and flattened covariance blocks."""


class Keyframes:
    """The keyframe decisions of a smoother and the frames between its keyframes.

    Args:
        rule: when a frame is a keyframe.
        robot: the robot (its cameras' mountings).
        bending: the parameterisation of the frames' vectors.

    Attributes:
        between: slot -> the between frames after that keyframe, in order.
        reasons: how many keyframes each reason made (``"time"``, ``"rotation"``, ...).
        frames, keyframes: frames decided so far, and how many were keyframes.
    """

    def __init__(self, rule: KeyframeRule, robot: Robot, bending: Bending,
                 chains: Mapping[int, CameraChain]) -> None:
        self.rule, self.robot, self.bending, self.chains = rule, robot, bending, chains
        self.between: dict[int, list[BetweenFrame]] = {}
        self.reasons: dict[str, int] = {}
        self.frames = self.keyframes = 0
        self._key: tuple[float, Rows, FloatArray, FloatArray | None] | None = None
        self.slots: dict[int, tuple[Rows, FloatArray | None]] = {}  # keyframe rows, base
        self.left: dict[int, FloatArray] = {}  # final vectors of keyframes that left
        self._recent: list[tuple[float, FloatArray]] = []

    def prediction(self, t: float) -> FloatArray | None:
        """The vector at graph time ``t`` at constant velocity from the last two estimates
        returned (``None`` before two)."""
        if len(self._recent) < 2:
            return None
        (t0, x0), (t1, x1) = self._recent
        if t1 <= t0:
            return x1.copy()
        return self.bending.clip(x1 + (x1 - x0) * (t - t1) / (t1 - t0))

    def returned(self, t: float, x: FloatArray) -> None:
        """The estimate returned for the frame at graph time ``t`` (the next predictions')."""
        self._recent = [*self._recent[-1:], (t, np.array(x, dtype=float))]

    def changes(self, rows: Rows, x: FloatArray, base: FloatArray | None
                ) -> dict[int, ViewChange]:
        """Each camera's change since the last keyframe (its rotation from the two frames'
        estimates; bearings of the tracks both saw)."""
        assert self._key is not None
        _, key_rows, key_x, key_base = self._key
        tips_key, _ = frame_poses(key_x, self.bending, key_base)
        tips_now, _ = frame_poses(x, self.bending, base)
        out = {}
        for cam, (ids, xy, _) in rows.items():
            camera = self.robot.cameras[cam]
            assert camera is not None
            R_key = (tips_key[cam] @ camera.tip_T_cam)[:3, :3]
            R_now = (tips_now[cam] @ camera.tip_T_cam)[:3, :3]
            old = key_rows.get(cam)
            old_ids = np.empty(0, dtype=np.int64) if old is None else old[0]
            _, i_key, i_now = np.intersect1d(old_ids, ids, assume_unique=True,
                                             return_indices=True)
            f_key = np.column_stack([old[1][i_key], np.ones(len(i_key))]) if old else \
                np.empty((0, 3))
            f_now = np.column_stack([xy[i_now], np.ones(len(i_now))])
            out[cam] = view_change(f_key, f_now, R_key.T @ R_now, len(old_ids),
                                   self.rule.min_shared)
        for cam in self._key[1]:  # a camera that saw tracks then and none now
            if cam not in out and len(self._key[1][cam][0]):
                out[cam] = ViewChange(0.0, float("nan"), 0.0)
        return out

    def decide(self, t: float, rows: Rows, x: FloatArray, base: FloatArray | None,
               measured: bool) -> list[str]:
        """Why the frame at graph time ``t`` with frame-step vector ``x`` is a keyframe (empty:
        it is not); ``measured``: the frame step fitted it to known points (else it is a
        keyframe: nothing but the window can measure it)."""
        self.frames += 1
        if self._key is None:
            reasons = ["first"]
        elif not measured:
            reasons = ["unmeasured"]
        else:
            reasons = keyframe_reasons(self.rule, t - self._key[0], self.changes(rows, x, base))
        for reason in {r.split(" of ")[0] for r in reasons}:
            self.reasons[reason] = self.reasons.get(reason, 0) + 1
        return reasons

    def keyframe(self, slot: int, t: float, rows: Rows, x: FloatArray,
                 base: FloatArray | None) -> None:
        """A keyframe entered the window as ``slot`` at graph time ``t`` with estimate ``x``."""
        self.keyframes += 1
        self.slots[slot] = (rows, base)
        self._key = (t, rows, np.array(x, dtype=float), base)

    def hold(self, slot: int, frame: BetweenFrame) -> None:
        """A between frame after the keyframe of ``slot``."""
        self.between.setdefault(slot, []).append(frame)

    def neighbours(self, slot: int, x: Callable[[int], FloatArray | None], span: int = 2
                   ) -> list[Keyframe]:
        """The keyframes ``slot - span + 1 .. slot + span`` (those recorded), at their
        vectors ``x(slot)`` (``None``: left out)."""
        out = []
        for g in range(slot - span + 1, slot + span + 1):
            value = self.left.get(g)
            value = x(g) if value is None else value
            if g in self.slots and value is not None:
                out.append(Keyframe(value, *self.slots[g]))
        return out

    def finalise(self, slots: Iterable[int], fit: FrameFit, x: Callable[[int], FloatArray | None],
                 final: bool = True) -> None:
        """The between frames after the keyframes ``slots`` (about to leave the window) take
        their final fits, to the points of the keyframes around them at their vectors ``x``
        (``final``: those of ``slots`` are final, kept for their neighbours' fits)."""
        slots = list(slots)
        if final:
            for slot in slots:
                value = x(slot)
                if value is not None:
                    self.left[slot] = np.array(value, dtype=float)
            for g in [g for g in self.slots if g < min(slots, default=0) - 3]:
                self.slots.pop(g)
                self.left.pop(g, None)
        for slot in slots:
            waiting = [b for b in self.between.get(slot, []) if not b.final]
            if not waiting:
                continue
            points = keyframe_points(self.neighbours(slot, x), self.chains)
            for frame in waiting:
                frame.x, frame.blocks = fit(frame, slot, points)
                frame.final = True

    def estimate(self, frame: BetweenFrame, present: Callable[[SmootherFrame], SmootherFrame],
                 n_segments: int) -> SmootherFrame:
        """A between frame's estimate as the smoother returns it (status ``"between"``)."""
        status: NDArray[np.str_] = np.full(n_segments, BETWEEN, dtype="<U24")
        return present(SmootherFrame(frame.frame, frame.timestamp, frame.x.copy(),
                                     frame.blocks.copy(), status))

    def expand(self, estimates: list[SmootherFrame], slots: list[int],
               present: Callable[[SmootherFrame], SmootherFrame], n_segments: int,
               done: bool = True) -> list[SmootherFrame]:
        """``estimates`` (of frames as received, the slot's frames among them) with each
        between frame's estimate in place of the copy of its slot's (``slots``: the slots
        those estimates came from); ``done``: forget those slots' between frames."""
        own = {}
        for slot in slots:
            for frame in (self.between.pop(slot, []) if done else self.between.get(slot, [])):
                own[frame.frame] = self.estimate(frame, present, n_segments)
        return [own.get(e.frame, e) for e in estimates]

    def reset(self) -> None:
        """A restarted window: the next frame is a keyframe (the between frames so far keep
        their frame-step estimates)."""
        self._key = None


def with_status(frame: SmootherFrame, status: str) -> SmootherFrame:
    """``frame`` with every segment's status ``status``."""
    return replace(frame, status=np.full(len(frame.status), status, dtype="<U24"))
