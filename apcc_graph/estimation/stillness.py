"""A robot standing still: frames held out of the smoother's graph.

When the robot does not move, no camera sees parallax: a track born during the stillness has
no depth, and once the whole window is still the smoother's system is close to singular (gtsam
then fails, or the points it guessed derail the frames after the robot moves again). A still
frame adds nothing but another look at the same configuration, so after ``settle`` frames
without motion the smoother *holds* the frames that follow: they do not enter the graph, they
take the estimate of the last frame that did (status ``"still"``), and the smoother's clock
stops, so that the window still holds the moving frames before the stillness and the first
moving frame afterwards joins them as if one frame interval had passed (the motion prior then
spans the motion of that one interval, which is all the robot did).

The test, per camera, against the *anchor* (the first frame of the still run), is the coherent
flow of :func:`~apcc_graph.estimation.image_motion.flow_statistics`: a frame is still when its
chi-square stays below ``chi2`` in every camera with at least ``min_tracks`` tracks in common
(and the spread below ``SPREAD_LIMIT``, which catches a roll about the optical axis), at least
one camera has that many, and the robot's base did not move. Comparing against the anchor
rather than the previous frame lets slow motion accumulate until it shows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from apcc_graph.estimation.image_motion import CHI2, SPREAD_LIMIT, flow_statistics
from apcc_graph.estimation.projection_tracks import Rows
from apcc_graph.estimation.window import SmootherFrame
from apcc_graph.model.arrays import FloatArray


@dataclass
class StillFrames:
    """Which incoming frames the smoother holds, and the frames each graph frame stands for.

    Args:
        settle: still frames that still enter the graph before the holding starts.
        chi2: a camera is still while its coherent-flow chi-square stays below this.
        min_tracks: tracks a camera needs in common with the anchor to take part.

    Graph frames ("slots") are numbered in the order they enter the graph; incoming frames
    are numbered in the order they arrive. ``paused`` is the time held so far (seconds): a
    slot's graph time is its timestamp minus the time paused before it.
    """

    settle: int = 10
    chi2: float = CHI2
    min_tracks: int = 8
    paused: float = 0.0
    count: int = 0
    last_time: float | None = None
    _anchor: tuple[Rows, FloatArray | None] | None = None
    _run: int = 0
    _members: dict[int, list[tuple[int, float]]] = field(default_factory=dict)

    def hold(self, rows: Rows, base: FloatArray | None, slot: int, t: float,
             can_hold: bool = True) -> bool:
        """Whether the incoming frame (at ``t`` seconds) is held; ``slot`` is the graph frame
        it would become, and the slot before stands for it if it is held (only when
        ``can_hold``: that slot is still in the window)."""
        frame, previous = self.count, self.last_time
        self.count, self.last_time = frame + 1, t
        still = self.settle != math.inf and self._still(rows, base)
        if not still:
            self._anchor, self._run = (rows, base), 0
        else:
            self._run += 1
        if still and self._run > self.settle and slot > 0 and can_hold:
            self.paused += t - (t if previous is None else previous)
            self._members.setdefault(slot - 1, []).append((frame, t))
            return True
        self._members[slot] = [(frame, t)]
        return False

    def join(self, slot: int) -> None:
        """The frame just received, which :meth:`hold` made slot ``slot``, joins the slot
        before instead (a keyframe smoother's between frame: it keeps its own estimate)."""
        self._members.setdefault(slot - 1, []).append(self._members.pop(slot)[0])

    def _still(self, rows: Rows, base: FloatArray | None) -> bool:
        if self._anchor is None:
            return False
        anchor_rows, anchor_base = self._anchor
        if (base is None) != (anchor_base is None) or (
                base is not None and not np.array_equal(base, anchor_base)):
            return False
        flows = flow_statistics(anchor_rows, rows, self.min_tracks).values()
        return bool(flows) and all(c < self.chi2 and s < SPREAD_LIMIT for c, s in flows)

    def frame_of(self, estimate: SmootherFrame) -> SmootherFrame:
        """A slot's estimate as the incoming frame that became that slot."""
        frame, t = self._members[estimate.frame][0]
        return replace(estimate, frame=frame, timestamp=t)

    def held(self, slot_estimate: SmootherFrame) -> SmootherFrame:
        """The estimate of the frame just held: its slot's, with status ``"still"``."""
        frame, t = self._members[slot_estimate.frame][-1]
        return replace(slot_estimate, frame=frame, timestamp=t,
                       status=np.full(len(slot_estimate.status), "still", dtype="<U24"))

    def expand(self, estimates: list[SmootherFrame], done: bool = True) -> list[SmootherFrame]:
        """Each slot's estimate as every incoming frame it stands for, in order (held frames
        with status ``"still"``); ``done``: the slots are final and forgotten."""
        out = []
        for est in estimates:
            members = self._members.pop(est.frame) if done else self._members[est.frame]
            out.append(replace(est, frame=members[0][0], timestamp=members[0][1]))
            still = np.full(len(est.status), "still", dtype="<U24")
            out += [replace(est, frame=f, timestamp=t, status=still) for f, t in members[1:]]
        return out
