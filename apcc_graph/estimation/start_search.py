"""Finding the robot's configuration without being told where it started.

The tip cameras fix the absolute angles, not only their changes: a camera's translation between
two frames depends on where on its arc the segment is, not only on how far it bent
(docs/estimation.md, "Starting from an unknown shape"). How well they fix them depends on the
motion: a segment that barely moves in the first second leaves its own absolute angle open.

:func:`find_start` looks at the first ``seconds`` of a recording:

1. **Hypotheses.** The first segment's bend at frame 0 is the worst determined, so the
   hypotheses spread it over its range, the outer segments straight: for a planar robot
   straight and half its ``theta_max`` either way; for a robot that bends in 3-D straight and
   three bending vectors of length half its ``theta_max`` at planes 0 and +-120 degrees. Each
   is propagated over the frames as the batch starts (:func:`~apcc_graph.estimation.
   rotation_start.propagated`): by the paper's chain (the 1-point or 2-point solver, frame
   after frame), or, where the estimator's model noise says the model is materially off, by
   the cameras' own rotations.
2. **Refinement.** Each propagated hypothesis starts the projection batch over those frames
   (every observation once, each track's point eliminated, graduated non-convexity of the
   outlier decisions), with only a weak prior on frame 0 (``prior_sigma``, 30 degrees
   around straight by default: in effect vision alone).
3. **Scoring.** Each solution is scored by the truncated quadratic of its observations'
   whitened reprojection errors, each track's point triangulated at the solution's angles:
   the robust cost the batch minimises, independent of where it started. The lowest wins.
4. **Deciding.** The winner's marginal sigmas of frame 0 say whether the data told: a segment
   above ``max_sigma`` (15 degrees by default, half the weak prior: the images must carry at
   least three quarters of the information; for a bending vector, its sigma along its
   worst-determined direction) is *undetermined* (the robot barely moved, or its camera saw
   too few tracks), and so is a second solution far from the winner (more than 3 of its sigmas
   on some segment, a Mahalanobis distance for a bending vector) whose cost is within
   ``ambiguity`` of it. An undetermined search says why
   in its ``reason`` instead of guessing. The sigmas are honest: on the start benchmark they
   are the Cramér-Rao bound of the window to a few percent. Where the estimator's model noise
   says the model is materially off, the winner's sigmas are those of the images and the
   model with that error as noise
   (:func:`~apcc_graph.estimation.noise_information.start_blocks`, at the winner): the exact
   model's ignore what the error hides (on the real robot's slow recording, after 8 s at
   rest, 12.8 / 3.5 deg from the exact model, 18.3 / 21.0 deg with the error, whose bound at
   the measured motion is 22 / 23 deg).
5. **The images' word.** The ranking and the sigmas assume the model explains the images. A
   winner that does not is not determined either: one with a bend at its joint limit in some
   frame (the limit's prior holds it there, not the images), or one at which the model fails
   the residual test (:mod:`~apcc_graph.estimation.model_fit`). On a real robot's struck
   motion the exact model ranks starts 40-100 degrees off first, rejecting 7-57% per camera
   of what the images alone accept at them, and 73-87% at the measured bends: which start
   fits best is then the model's error, not the start.

:func:`start_from_data` grows the window (1 s, 2 s, 4 s, ... up to the whole recording) until
the start is determined, so a robot that stands still at first is found once it moves; a
recording in which it never moves enough raises :class:`UnknownStartError`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from apcc_graph.estimation.batch_solve import build_terms, projection_solve
from apcc_graph.estimation.bends import parameterisation
from apcc_graph.estimation.graph import CameraTerms
from apcc_graph.estimation.model_fit import check_model_fit
from apcc_graph.estimation.model_noise import approximate, segment_sigmas
from apcc_graph.estimation.noise_information import start_blocks
from apcc_graph.estimation.options import GraphOptions, Robustness
from apcc_graph.estimation.result import StartReport
from apcc_graph.estimation.rotation_start import propagated
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.bending import bending_vector
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.sequence import Sequence

START_SECONDS = 1.0
"""The first window of the search (seconds)."""
PRIOR_SIGMA = math.radians(30.0)
"""The weak prior on frame 0 during the search, around straight (radians)."""
MAX_SIGMA = 0.5 * PRIOR_SIGMA
"""A start whose sigma exceeds this on any segment is undetermined (radians): below it, the
images carry at least three quarters of the start's information, the weak prior the rest."""
FIRM_SIGMA = math.radians(5.0)
"""The sigma the smoother and the chain wait for before they start (radians): unlike the
batch, they cannot revisit the start once they have passed it."""
AMBIGUITY = 9.0
"""Two distant solutions whose robust costs differ by less than this are ambiguous."""
MIN_OBSERVATIONS = 20
"""A camera with fewer observations in the window counts as having seen nothing."""


class UnknownStartError(ValueError):
    """The recording does not tell where the robot started (it never moved enough, or the
    cameras saw too little); pass the starting configuration instead."""


@dataclass(frozen=True)
class Hypothesis:
    """One refined hypothesis: where it started, where it ended, its robust cost. Frame
    vectors are the search's parameterisation's (radians)."""

    start: FloatArray  # (dim,) frame 0's vector it started from
    x: FloatArray  # (F, dim) the refined frame vectors of the window
    blocks: FloatArray  # (F, S, w, w) their marginal covariance blocks (NaN where singular)
    cost: float  # truncated quadratic of the whitened reprojection errors


@dataclass(frozen=True)
class StartSearch:
    """What :func:`find_start` found over a window of frames.

    Attributes:
        n_frames: frames in the window (from frame 0).
        seconds: the window's length (seconds).
        hypotheses: every refined hypothesis, the winner first.
        determined: whether the data told the start.
        reason: why not (empty when determined).
        bending: the parameterisation searched in (free planes for a spatial robot).
    """

    n_frames: int
    seconds: float
    hypotheses: tuple[Hypothesis, ...]
    determined: bool
    reason: str
    bending: Bending

    @property
    def x0(self) -> FloatArray:
        """``(dim,)`` the winner's frame vector at frame 0 (radians)."""
        return self.hypotheses[0].x[0]

    @property
    def theta0(self) -> FloatArray:
        """``(S,)`` the winner's bends at frame 0 (radians; magnitudes for free planes)."""
        return self.bending.polar(self.x0)[0]

    @property
    def psi0(self) -> FloatArray | None:
        """``(S,)`` the winner's bending planes at frame 0 (radians), or ``None`` (fixed)."""
        return self.bending.polar(self.x0)[1]

    @property
    def sigma0(self) -> FloatArray:
        """``(S,)`` its marginal sigmas (radians; along the worst-determined direction of a
        bending vector; NaN where the data left it singular)."""
        return self.bending.spreads(self.hypotheses[0].blocks[0])

    def report(self) -> StartReport:
        """The summary an :class:`~apcc_graph.estimation.result.Estimate` carries."""
        return StartReport(self.theta0.copy(), self.sigma0.copy(), self.seconds, self.n_frames,
                           len(self.hypotheses), self.psi0)


def start_hypotheses(bending: Bending) -> FloatArray:
    """``(H, dim)`` starting frame vectors tried (radians), the outer segments straight: the
    first segment straight and at half its ``theta_max`` either way (fixed planes), or
    straight and three bending vectors of that length at planes 0 and +-120 degrees (free)."""
    half = 0.5 * bending.segments[0].theta_max
    if not bending.is_free:
        starts = np.zeros((3, bending.dim))
        starts[1:, 0] = (-half, half)
        return starts
    starts = np.zeros((4, bending.dim))
    u, v = bending_vector(half, np.array([0.0, 2.0 * math.pi / 3.0, -2.0 * math.pi / 3.0]))
    starts[1:, 0], starts[1:, 1] = u, v
    return starts


def robust_cost(terms: list[CameraTerms], thetas: FloatArray, inlier_sigmas: float) -> float:
    """The truncated quadratic ``sum min(r^2, c^2)`` of every observation's whitened
    reprojection error ``r`` (``c = inlier_sigmas``) in the projection ``terms`` of a
    window (:func:`~apcc_graph.estimation.batch_solve.build_terms`), each track's point
    triangulated robustly at the frame vectors ``thetas`` (``(F, dim)``, radians)."""
    c = inlier_sigmas
    total = 0.0
    for terms_of_camera in terms:
        terms_of_camera.measure(thetas, robust=True)
        for norms in terms_of_camera.norms:  # NaN or inf (behind the camera) count as outliers
            capped = np.where(np.isfinite(norms), np.minimum(np.abs(norms), c), c)
            total += float(np.sum(capped**2))
    return total


def _refine(sequence: Sequence, bending: Bending, start: FloatArray, options: GraphOptions,
            robustness: Robustness, terms: list[CameraTerms], model: GraphOptions
            ) -> Hypothesis:
    """One hypothesis propagated (by the chain, or by the cameras' rotations where ``model``,
    the estimator's options, says the model is materially off:
    :func:`~apcc_graph.estimation.rotation_start.propagated`), refined by the exact model's
    batch over the window and scored on the window's ``terms`` (built once for every
    hypothesis)."""
    x = propagated(sequence, start, bending, model)
    found = projection_solve(sequence, x, np.zeros(bending.dim), options, robustness,
                             bending=bending)
    return Hypothesis(start, found.x, found.blocks,
                      robust_cost(terms, found.x, robustness.inlier_sigmas))


def find_start(sequence: Sequence, seconds: float = START_SECONDS,
               options: GraphOptions | None = None, max_sigma: float = MAX_SIGMA,
               prior_sigma: float = PRIOR_SIGMA, ambiguity: float = AMBIGUITY,
               spatial: bool = False, robustness: Robustness | None = None) -> StartSearch:
    """The configuration over the first ``seconds`` of ``sequence``, without a start prior.

    Args:
        sequence: the recording (ground truth is never read).
        seconds: the window, from the first frame's timestamp (at least two frames are used).
        options: graph options (pixel noise, outlier threshold); the start prior is replaced by
            ``prior_sigma`` around straight.
        max_sigma: a start with a larger marginal sigma on any segment is undetermined
            (radians).
        prior_sigma: the weak prior on frame 0 (radians).
        ambiguity: robust-cost margin under which a distant second solution makes the start
            ambiguous.
        spatial: the robot bends in 3-D: search the bending vectors (the planes too).
        robustness: how outliers are decided (default
            :class:`~apcc_graph.estimation.options.Robustness`).

    Returns:
        The search; ``determined`` says whether to trust it, ``reason`` why not.

    Raises:
        ValueError: ``seconds``, ``max_sigma`` or ``prior_sigma`` not positive.
    """
    for name, value in (("seconds", seconds), ("max_sigma", max_sigma),
                        ("prior_sigma", prior_sigma)):
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"find_start: {name} = {value!r}: expected a positive number")
    ts = sequence.timestamps
    n_frames = max(2, int(np.searchsorted(ts, ts[0] + seconds, side="right")))
    window = sequence.head(min(n_frames, sequence.n_frames))
    span = float(window.timestamps[-1] - window.timestamps[0])
    # Starts are compared through the exact model, whatever the estimator's measurement model
    # (which picks how the hypotheses are propagated).
    model = GraphOptions() if options is None else options
    options = replace(model, theta0_sigma=prior_sigma, model_sigma=None)
    bending = parameterisation(sequence.robot, spatial)
    if window.n_frames < 2:
        w = bending.width
        empty = Hypothesis(np.zeros(bending.dim), np.zeros((1, bending.dim)),
                           np.full((1, sequence.n_segments, w, w), np.nan), math.inf)
        return StartSearch(1, 0.0, (empty,), False, "a single frame shows no motion", bending)
    terms = build_terms(window, options, bending)
    robustness = Robustness() if robustness is None else robustness
    refined = sorted((_refine(window, bending, start, options, robustness, terms, model)
                      for start in start_hypotheses(bending)), key=lambda h: h.cost)
    noisy = approximate(segment_sigmas(model.model_sigma, sequence.robot))
    if noisy:  # the winner's sigmas with the model's error as noise
        refined[0] = _with_model_noise(window, bending, refined[0], model, robustness,
                                       prior_sigma)
    reason = (_undetermined(window, bending, refined, max_sigma, ambiguity, noisy)
              or _not_the_images(window, bending, refined[0], options, robustness))
    return StartSearch(window.n_frames, span, tuple(refined), not reason, reason, bending)


def _with_model_noise(window: Sequence, bending: Bending, best: Hypothesis,
                      model: GraphOptions, robustness: Robustness, prior_sigma: float
                      ) -> Hypothesis:
    """``best`` with frame 0's covariance blocks those of the information at its frame
    vectors with the model's error as noise (``model``'s; module docstring, step 4;
    :func:`~apcc_graph.estimation.noise_information.start_blocks`), NaN where that
    information is singular."""
    found = start_blocks(window, best.x, bending, model, robustness.inlier_sigmas, prior_sigma)
    blocks = best.blocks.copy()
    blocks[0] = np.nan if found is None else found
    return replace(best, blocks=blocks)


def _undetermined(window: Sequence, bending: Bending, refined: list[Hypothesis],
                  max_sigma: float, ambiguity: float, noisy: bool = False) -> str:
    """Why the window does not tell the start ('' when it does; ``noisy``: the winner's
    sigmas are with the model's error as noise)."""
    best = refined[0]
    sigma0 = bending.spreads(best.blocks[0])
    span = float(window.timestamps[-1] - window.timestamps[0])
    seen = {cam: len(window.tracks[cam]) if cam in window.tracks else 0
            for cam in window.robot.camera_segments}
    few = [f"cam_{cam + 1} ({n})" for cam, n in seen.items() if n < MIN_OBSERVATIONS]
    open_ = [j for j, s in enumerate(sigma0) if not (math.isfinite(s) and s <= max_sigma)]
    if open_:
        moved = np.degrees(np.max(bending.magnitudes(best.x - best.x[0]), axis=0))
        sigma_text = ["undetermined" if not math.isfinite(s) else f"{math.degrees(s):.1f} deg"
                      for s in sigma0]
        shown = "; ".join(f"segment {j + 1}: sigma {sigma_text[j]}, moved {moved[j]:.1f} deg"
                          for j in open_)
        why = (f"cameras with too few observations: {', '.join(few)}" if few else
               "the robot barely moved, or too little for the model's error (the robot "
               "file's) to leave it told" if noisy else "the robot barely moved")
        return (f"the first {span:.2f} s do not tell the start ({shown}; limit "
                f"{math.degrees(max_sigma):.1f} deg): {why}")
    for other in refined[1:]:
        far = _distances(bending, other.x[0] - best.x[0], best.blocks[0]) > 3.0
        if np.any(far) and other.cost - best.cost < ambiguity:
            a, b = (", ".join(f"{v:+.1f}" for v in np.degrees(h.x[0]))
                    for h in (best, other))
            return (f"the first {span:.2f} s fit two starts about equally well ({a} deg, cost "
                    f"{best.cost:.1f}; {b} deg, cost {other.cost:.1f})")
    return ""


def _not_the_images(window: Sequence, bending: Bending, best: Hypothesis,
                    options: GraphOptions, robustness: Robustness) -> str:
    """Why the winner's fit of the window is not the images' word on the start ('' when it
    is): some bend at its joint limit in some frame of the window (within
    ``options.limit_sigma``: the limit's prior holds it, not the images), or the model failing
    the residual test at the winner (:mod:`~apcc_graph.estimation.model_fit`, with
    ``robustness.misfit_alarm``). Either way the model does not explain the images there, and
    the robust costs compare the model's errors, not the starts: on a real robot's struck
    recording the exact model preferred starts 40-100 deg off, and its robust cost at the
    measured bends was higher than at any of them."""
    span = float(window.timestamps[-1] - window.timestamps[0])
    limits = np.array([seg.theta_max for seg in window.robot.segments])
    reach = np.max(bending.magnitudes(best.x), axis=0)
    held = [j for j in range(bending.n_segments) if reach[j] >= limits[j] - options.limit_sigma]
    if held:
        shown = ", ".join(f"segment {j + 1} at {math.degrees(reach[j]):.1f} of "
                          f"{math.degrees(limits[j]):.0f} deg" for j in held)
        return (f"the first {span:.2f} s fit best with bends at their joint limits ({shown}): "
                "the images pull them further than the robot bends, so the model does not "
                "explain them there")
    if robustness.misfit_alarm is None:
        return ""
    fit = check_model_fit(window, best.x, bending, options, robustness.inlier_sigmas,
                          robustness.misfit_alarm, warn=False)
    failing = fit.failing()
    if not failing:
        return ""
    shown = ", ".join(f"cam_{c.camera + 1} {100 * c.share:.0f}%" for c in failing)
    return (f"the model does not explain the first {span:.2f} s of images at the best start "
            f"(it rejects {shown} of the observations the images alone accept; alarm "
            f"{100 * fit.alarm:.0f}%): the robot departs from its model there, and which start "
            "fits best is then the model's error, not the images' word")


def _distances(bending: Bending, d: FloatArray, blocks: FloatArray) -> FloatArray:
    """``(S,)`` each segment's Mahalanobis distance of the difference ``d`` ``(dim,)`` under
    its covariance block (``|d| / sigma`` for an angle; ``inf`` where the block is singular
    and ``d`` is not zero)."""
    out = np.empty(bending.n_segments)
    for j in range(bending.n_segments):
        dj, C = d[bending.columns(j)], blocks[j]
        try:
            squared = float(dj @ np.linalg.solve(C, dj))
        except np.linalg.LinAlgError:
            squared = math.nan
        if math.isfinite(squared):
            out[j] = math.sqrt(max(squared, 0.0))
        else:
            out[j] = math.inf if np.any(dj) else 0.0
    return out


def start_from_data(sequence: Sequence, seconds: float = START_SECONDS,
                    options: GraphOptions | None = None, max_sigma: float = MAX_SIGMA,
                    prior_sigma: float = PRIOR_SIGMA, spatial: bool = False,
                    robustness: Robustness | None = None) -> StartSearch:
    """:func:`find_start` over 1, 2, 4, ... times ``seconds`` until the start is determined.

    Raises:
        UnknownStartError: not determined even over the whole recording (the message says
            why, and how to give the start instead).
    """
    window = seconds
    while True:
        search = find_start(sequence, window, options, max_sigma, prior_sigma,
                            spatial=spatial, robustness=robustness)
        if search.determined:
            return search
        if search.n_frames >= sequence.n_frames:
            raise UnknownStartError(
                f"{search.reason}; that is the whole recording ({sequence.n_frames} frames). "
                "Give the starting configuration (theta0, or --theta0-deg on the command "
                "line) to estimate it anyway")
        window *= 2.0
