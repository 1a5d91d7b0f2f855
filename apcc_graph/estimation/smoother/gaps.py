"""The gaps after which the smoother's window no longer says where the robot is: pure
detectors, each a function of what it observes, each answering with a plan or ``None``.

- :func:`blackout`: tracks return after every camera was blind, and none of them is one the
  window knows (:func:`~apcc_graph.estimation.blackout.tracks_returned`), or the blackout
  lasted longer than :data:`PAUSE`, whatever the tracks' ids;
- :func:`pause`: a gap in the recording longer than :data:`PAUSE` (or the lag) with no track
  seen before it coming back (with some, their points tie the new frame to the old ones);
- :func:`weakly_seen`: a segment seen only through the cameras further out, for which the
  window holds :data:`LONGER` lags;
- :func:`lost_camera`: one camera's tracks come back all new while the others kept seeing,
  after the window lost that camera's segment (its marginal sigma above :data:`LOST`: the last
  camera's segment, seen by no other camera, drifts on the motion prior alone).

A plan (:class:`Gap`) names the re-acquisition to start
(:class:`~apcc_graph.estimation.blackout.Reacquisition`'s start and sigma, the camera, a
second round) and, after a blackout, the last blind frame at which the window restarts. The
smoother's :class:`~apcc_graph.estimation.smoother.restarts.Recovery` carries it out.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.blackout import tracks_returned
from apcc_graph.estimation.projection_tracks import Rows
from apcc_graph.model.arrays import FloatArray

PAUSE = 0.5
"""Seconds: a gap in the recording after which, when none of the tracks seen before comes back,
the robot may have moved anywhere (the motion prior over it is 20 degrees at the default
``motion_sigma``), so the frames after it are re-acquired, whatever the lag (with a 2 s lag a
1.5 s pause, handled as one long frame interval, put the robot 80 degrees off)."""
SECOND_ROUND: float | None = 2.0
"""Seconds: after the first re-acquisition of the frames after a pause (over one lag of them),
they are kept until they span this long and re-acquired once more, and the window restarts from
that batch (``None``: one round). After a pause of 1.5 s it took segment 1 from 4-6 degrees RMS
to 0.9 when the window restarted from one frame; restarted holding the batch's frames, from 1.03
to 0.75 (the bound of a 1 s lag there: 0.85). After a blackout too: on four seeds the bench
never tuned on, the worst error 2 s after every camera's 1 s blackout went from 3.7-43 deg to
1.3-3.0 with it. Not after a contradicted start (segment 1 0.82 to 1.02 degree on the
reliability bench; docs/estimation.md, "What the smoother says when the data go wrong")."""
SURE = math.radians(1.0)
"""Radians: after the second round, the frames after a blackout or a pause are re-acquired in
further rounds, each over twice the last's span (at most :data:`LONGEST`), until the batch
knows the newest of them to this (its largest marginal sigma there). Without a track from
before the gap, what tells a segment's absolute bend is how its camera's motion couples
rotation and translation, which a short span of slow motion tells weakly: after a 1.5 s pause
on a recording the bench never used, the batch over 1, 2, 3 and 3.8 s of frames knew segment
1 to 10.3, 2.7, 1.2 and 0.9 deg (its error 8.0, 9.9, 1.0 and 0.9 deg), and a window restarted
from the 2 s batch stayed 8 deg off: its marginal, linearised there, held it."""
LONGEST = 8.0
"""Seconds: the longest span a re-acquisition's rounds keep (:data:`SURE`)."""
LOOSE = math.pi / 6
"""Radians: the start prior of a re-acquisition when nothing says how far the robot went."""
LOST = math.radians(2.0)
"""Radians: a camera whose tracks come back all new has its segment re-acquired when the
window's marginal sigma of that segment (the frame before) exceeds this."""

LONGER = 2.0
"""The window's length, in lags, while a camera has seen nothing for a lag and a camera further
out along the robot sees: its segment is then told only through the cameras beyond it, whose
poses mix it with the segments after it, and one lag of them does not tell the split (camera 2
never seeing: segments 2 and 3 were 32 / 27 deg RMS with a 1 s lag, 0.60 / 0.56 with 2 s, where
the batch over the recording was 0.43 / 0.45)."""

Known = Callable[[int, NDArray[np.int64]], NDArray[np.bool_]]
"""``(camera, track ids) -> which of them the window knows``."""


@dataclass(frozen=True)
class Gap:
    """A plan: re-acquire the frames from the new one on.

    Attributes:
        kind: ``"blackout"``, ``"pause"`` or ``"lost camera"``.
        start: the re-acquisition's start (a frame vector, radians).
        sigma: its start prior (radians).
        then: keep the frames until they span this many seconds and re-acquire them once more
            (:data:`SECOND_ROUND`), then in rounds while the batch is unsure
            (:func:`next_round`); ``None``: once.
        camera: the one camera whose segment is re-acquired; ``None``: every segment.
        sigmas: ``(dim,)`` the start prior per component (a lost camera), else ``None``.
        since: a lost camera's first graph frame unseen (its blind frames are bridged).
        restart_at: after a blackout, the last blind frame, where the window restarts.
        gap: seconds of a pause; after a lost camera, its segment's sigma (radians).
    """

    kind: str
    start: FloatArray
    sigma: float
    then: float | None = None
    camera: int | None = None
    sigmas: FloatArray | None = None
    since: int | None = None
    restart_at: int | None = None
    gap: float = 0.0


def blackout(f: int, rows: Rows, previous: Rows, previous_inside: bool, known: Known,
             estimate: FloatArray, sigmas: Callable[[], FloatArray], blind: float
             ) -> Gap | None:
    """Tracks returned at graph frame ``f`` after every camera was blind for ``blind``
    seconds (``previous``: frame ``f - 1``'s rows, ``previous_inside``: whether it is in the
    window, ``estimate`` its vector, ``sigmas()`` its component sigmas, NaN where unknown,
    asked for only when the tracks did return). A re-acquisition when none of the returning
    tracks is one the window knows, or, whatever their ids, when the blackout lasted longer
    than :data:`PAUSE`: the robot may have moved anywhere meanwhile, and a re-identifying front
    end's old tracks, their points seen from where the robot was, only pull the new frame into
    a wrong basin from the motion prior's guess (a 1 s blackout with the tracks' ids kept ended
    17 deg off)."""
    if not (previous_inside and rows) or previous:
        return None
    if not (blind > PAUSE or tracks_returned(rows, previous, known)):
        return None
    return Gap("blackout", estimate.copy(), float(np.nanmax(sigmas(), initial=LOOSE)),
               then=SECOND_ROUND, restart_at=f - 1, gap=blind)


def pause(t: float, last_time: float | None, lag: float, rows: Rows, known: Known,
          latest: FloatArray | None, motion_sigma: float | None) -> tuple[bool, Gap | None]:
    """A pause before graph time ``t`` (the previous frame at ``last_time``, whose estimate is
    ``latest``): whether there was one, and the plan when no track seen before it returns."""
    if last_time is None or latest is None or not t - last_time > min(lag, PAUSE):
        return False, None
    if any(np.any(known(cam, ids)) for cam, (ids, _, _) in rows.items()):
        return True, None  # tracks seen before the pause tie the new frame to the old ones
    gap = t - last_time
    sigma = LOOSE if motion_sigma is None else min(LOOSE, motion_sigma * math.sqrt(gap))
    return True, Gap("pause", latest.copy(), sigma, then=SECOND_ROUND, gap=gap)


def next_round(span: float | None, then: float | None, newest_sigma: float, lag: float
               ) -> float | None:
    """The span (seconds) of a re-acquisition's next round, or ``None`` when it is done.

    ``span``: the round just solved kept its frames until they spanned this (``None``: one
    lag); ``then``: its plan's second round (``None``: none planned). A plan with neither
    (a lost camera, a contradicted start) has one round. Otherwise the second round follows
    if it is longer than this one, and then every further one while the batch's largest sigma
    at the newest frame (``newest_sigma``, radians; NaN too) exceeds :data:`SURE`, each twice
    this round's span, up to :data:`LONGEST`."""
    if span is None and then is None:
        return None
    current = max(lag, span or 0.0)
    if then is not None and then > current:
        return then
    if current >= LONGEST or newest_sigma <= SURE:
        return None
    return min(2.0 * current, LONGEST)


def weakly_seen(seen_at: Mapping[int, float], cameras: tuple[int, ...], t: float,
                lag: float) -> bool:
    """Whether at graph time ``t`` some camera has seen nothing for ``lag`` seconds (or never;
    ``seen_at``: camera -> graph time it last saw) while a camera further out sees."""
    blind = [c for c in cameras if not t - seen_at.get(c, -math.inf) <= lag]
    return any(c > b for b in blind for c in cameras if c not in blind)


def lost_camera(rows: Rows, previous: Rows, known: Known, seen_before: Mapping[int, int],
                inside: Callable[[int], bool], covariance: Callable[[], FloatArray],
                estimate: FloatArray, width: int) -> Gap | None:
    """A camera whose tracks come back all new while the others saw the previous frame, its
    segment lost by the window (``seen_before``: camera -> the last graph frame it saw;
    ``covariance``: the previous frame's marginal covariance, ``estimate`` its vector)."""
    if not previous:
        return None
    for cam, (ids, _, _) in sorted(rows.items()):
        before, last = previous.get(cam), seen_before.get(cam)
        if (before is not None and len(before[0])) or np.any(known(cam, ids)):
            continue
        if last is not None and inside(last):
            continue  # the window still holds a frame it saw: it follows the return
        sigmas = np.sqrt(np.maximum(np.diagonal(covariance()), 0.0))
        lost = float(np.max(sigmas[width * cam:width * (cam + 1)]))
        if lost <= LOST:  # also False for NaN: then it is lost too
            continue
        return Gap("lost camera", estimate.copy(), LOOSE, camera=cam,
                   sigmas=np.where(np.isfinite(sigmas) & (sigmas > 0.0), sigmas, LOOSE),
                   since=0 if last is None else last + 1, gap=lost)
    return None
