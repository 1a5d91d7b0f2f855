"""Keyframes: the frames at which the smoother solves (:class:`Keyframes`).

With a :class:`~apcc_graph.estimation.keyframes.KeyframeRule` every frame still enters the
window with its variables and rows (the stages up to "add" run for each), but iSAM2 runs only
at a keyframe, once for every frame since the last one. A frame that is not a keyframe returns
at once the estimate of the "predict" stage, the *frame step*: the motion's prediction fitted
to the frame's rows of the points the window knows
(:func:`~apcc_graph.estimation.initial_guess.refine`; status ``"pending"``); the next keyframe's
update then smooths it with the others, and it leaves the window with the smoothed estimate
like any frame. No row is dropped, so the final estimates are close to those of the smoother
that solves at every frame: they differ where rows were judged (the outlier decisions taken at
a frame's fit rather than at a solved estimate) and in iSAM2's relinearisation; what changes is
the number of updates, and so the time (docs/estimation.md, "Keyframes", with the figures, and
why a window that holds keyframes alone was measured and left out).

The rule compares the frame with the last keyframe
(:func:`~apcc_graph.estimation.keyframes.view_change`): each camera's rotation from the two
frames' estimates (the keyframe's as the window now holds it), the bearings of the tracks both
saw. A frame the frame step could not fit to known points is a keyframe ("unmeasured"), and so
is every frame of the first lag after the start and after each restart ("first", "warm-up"),
and of a re-acquisition.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace

import numpy as np

from apcc_graph.estimation.graph import camera_chain
from apcc_graph.estimation.keyframes import (
    TIME_TOLERANCE,
    KeyframeRule,
    ViewChange,
    keyframe_reasons,
    view_change,
)
from apcc_graph.estimation.projection_tracks import Rows
from apcc_graph.estimation.smoother.solver import Additions
from apcc_graph.estimation.window import SmootherFrame
from apcc_graph.factors.camera_chain import CameraChain
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot

PENDING = "pending"
"""The status of a frame's estimate returned before the smoother solved with it (the frame
step's); its final estimate has the usual statuses."""


class Keyframes:
    """The keyframe decisions of a smoother.

    Args:
        rule: when a frame is a keyframe.
        robot: the robot (its cameras' mountings).
        bending: the parameterisation of the frames' vectors.
        warmup: seconds after the first frame, and after each restart, in which every frame
            is a keyframe (``"warm-up"``): while the window is young its points are, and the
            frames between keyframes, judged at fits to them, went 0.5-2 deg off.

    Attributes:
        commit_due: the pieces of ended tracks are committed before the next frame (the first
            after a keyframe), so that they enter the graph at the next keyframe together.
        reasons: how many keyframes each reason made (``"first"``, ``"warm-up"``,
            ``"unmeasured"``, ``"time"``, ``"rotation"``, ``"parallax"``, ``"tracks"``).
        frames, keyframes: frames decided so far, and how many were keyframes.
        deferred: frames the rule made keyframes that waited instead, because the caller was
            busy (``decide(..., busy=True)``).
    """

    def __init__(self, rule: KeyframeRule, robot: Robot, bending: Bending,
                 warmup: float = 0.0) -> None:
        self.rule, self.robot, self.bending, self.warmup = rule, robot, bending, warmup
        self._start = 0.0  # graph time of the first frame since the window (re)started
        self._chains = {c: camera_chain(robot, c, bending) for c in robot.camera_segments}
        self.reasons: dict[str, int] = {}
        self.frames = self.keyframes = self.deferred = 0
        self._key: tuple[int, float, Rows, FloatArray | None] | None = None
        self.commit_due = True  # the ended tracks' pieces are committed at the next frame
        self._pending: Additions | None = None  # what the frames since the keyframe added
        self._restarts = 0  # the solver's restarts seen
        self._key_rotations: tuple[bytes, dict[int, FloatArray]] = (b"", {})  # slot, key_x

    def changes(self, rows: Rows, x: FloatArray, base: FloatArray | None,
                key_x: FloatArray) -> dict[int, ViewChange]:
        """Each camera's change since the last keyframe, whose vector is now ``key_x``."""
        assert self._key is not None
        slot, _, key_rows, key_base = self._key
        stamp = slot.to_bytes(8, "little", signed=True) + np.asarray(key_x, float).tobytes()
        if self._key_rotations[0] != stamp:  # the keyframe's vector moves only at solves
            self._key_rotations = (stamp, {c: _rotation(chain, key_x, key_base)
                                           for c, chain in self._chains.items()})
        out = {}
        for cam, (ids, xy, _) in rows.items():
            R_key = self._key_rotations[1][cam]
            R_now = _rotation(self._chains[cam], x, base)
            old = key_rows.get(cam)
            old_ids = np.empty(0, dtype=np.int64) if old is None else old[0]
            _, i_key, i_now = np.intersect1d(old_ids, ids, assume_unique=True,
                                             return_indices=True)
            f_key = (np.empty((0, 3)) if old is None else
                     np.column_stack([old[1][i_key], np.ones(len(i_key))]))
            f_now = np.column_stack([xy[i_now], np.ones(len(i_now))])
            out[cam] = view_change(f_key, f_now, R_key.T @ R_now, len(old_ids),
                                   self.rule.min_shared)
        for cam, (ids, _, _) in key_rows.items():  # a camera that saw tracks then, none now
            if cam not in out and len(ids):
                out[cam] = ViewChange(0.0, float("nan"), 0.0)
        return out

    def decide(self, t: float, rows: Rows, x: FloatArray, base: FloatArray | None,
               measured: bool, latest: Callable[[int], FloatArray | None],
               busy: bool = False) -> list[str]:
        """Why the frame at graph time ``t`` whose frame step gave ``x`` is a keyframe (empty:
        it is not); ``measured``: the frame step fitted it to known points; ``latest``: the
        window's estimate of a frame (``None``: it left); ``busy``: the caller has frames
        waiting, so the rule's own reasons wait too while the last keyframe is less than the
        rule's ``max_deferral`` old (the first frame, the warm-up and an unmeasured frame
        never wait)."""
        self.frames += 1
        key_x = None if self._key is None else latest(self._key[0])
        if self._key is None or key_x is None:
            reasons, self._start = ["first"], t
        elif t - self._start < self.warmup:
            reasons = ["warm-up"]
        elif not measured:
            reasons = ["unmeasured"]
        else:
            elapsed = t - self._key[1]
            reasons = keyframe_reasons(self.rule, elapsed, self.changes(rows, x, base, key_x))
            if reasons and busy and elapsed < self.rule.max_deferral - TIME_TOLERANCE:
                self.deferred += 1
                reasons = []
        for reason in {r.split(" of ")[0] for r in reasons}:
            self.reasons[reason] = self.reasons.get(reason, 0) + 1
        if reasons:
            self.keyframes += 1
        return reasons

    def keyframe(self, slot: int, t: float, rows: Rows, base: FloatArray | None) -> None:
        """Graph frame ``slot`` (graph time ``t``) was a keyframe."""
        self._key = (slot, t, rows, base)
        self.commit_due = True

    def commit_now(self) -> bool:
        """Whether the pieces of ended tracks are committed before this frame enters (the
        first after a keyframe: they then enter the graph at the next keyframe together)."""
        due, self.commit_due = self.commit_due, False
        return due

    def wait(self, add: Additions, restarts: int) -> None:
        """What a frame that is not a keyframe added waits for the next keyframe's update
        (``restarts``: the solver's restarts so far)."""
        self._pending, self._restarts = add, restarts

    def take(self, restarts: int) -> Additions:
        """What the frames since the last keyframe added, for this frame to add to; new
        additions if none or if the window restarted since (``restarts``: the solver's
        restarts so far): the frames that waited left the window at the restart, and this
        frame is a keyframe."""
        pending, self._pending = self._pending, None
        if restarts != self._restarts:
            self._restarts, self._key, pending = restarts, None, None
        return Additions() if pending is None else pending


def with_status(frame: SmootherFrame, status: str) -> SmootherFrame:
    """``frame`` with every segment's status ``status``."""
    return replace(frame, status=np.full(len(frame.status), status, dtype="<U24"))


def _rotation(chain: CameraChain, x: FloatArray, base: FloatArray | None) -> FloatArray:
    """The camera's ``world_R_cam`` at frame vector ``x`` on base pose ``base``."""
    R = chain.poses(np.asarray(x, dtype=float)[None], 0, False)[0][0][:3, :3]
    return R if base is None else np.asarray(base, dtype=float)[:3, :3] @ R
