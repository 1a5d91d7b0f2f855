"""Running a fixed-lag smoother over a recorded sequence: ``estimate(..., method="smoother")``.

Each frame's angles are its final smoothed estimate (the last update in which it was inside the
window); ground-truth columns are never read. The projection smoother
(:class:`~apcc_graph.estimation.projection_smoother.ProjectionFixedLagSmoother`) is the default,
the epipolar one (:class:`~apcc_graph.estimation.smoother.FixedLagSmoother`) stays for
comparison.
"""

from __future__ import annotations

from typing import Any

from numpy.typing import ArrayLike

from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.projection_smoother import ProjectionFixedLagSmoother
from apcc_graph.estimation.result import Estimate
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.window import stream_estimate
from apcc_graph.model.sequence import Sequence


def projection_smoother_estimate(
    sequence: Sequence,
    theta0: ArrayLike | None = None,
    lag: float | None = None,
    options: GraphOptions | None = None,
    progress: bool = False,
    **smoother_options: Any,
) -> Estimate:
    """Run :class:`ProjectionFixedLagSmoother` over a recorded sequence, frame by frame.

    Each frame's angles are its final smoothed estimate (the last update in which it was inside
    the window). Ground-truth columns are never read.

    Args:
        sequence: the sequence.
        theta0: ``(S,)`` starting configuration in radians (default straight).
        lag: window length in seconds (default the smoother options' 1 s).
        options: graph construction (:class:`~apcc_graph.estimation.options.GraphOptions`).
        progress: show a progress bar.
        **smoother_options: further :class:`ProjectionFixedLagSmoother` arguments (fields of
            :class:`~apcc_graph.estimation.smoother_options.ProjectionSmootherOptions`, or
            ``settings``).

    Returns:
        The estimate, ``method = "smoother"``.
    """
    smoother = ProjectionFixedLagSmoother(sequence.robot, lag=lag, options=options,
                                          theta0=theta0, **smoother_options)
    return stream_estimate(smoother, sequence, progress)


def smoother_estimate(
    sequence: Sequence,
    theta0: ArrayLike | None = None,
    lag: float | None = None,
    options: GraphOptions | None = None,
    progress: bool = False,
    vision: str = "projection",
    **smoother_options: Any,
) -> Estimate:
    """Run a fixed-lag smoother over a recorded sequence, frame by frame.

    Each frame's angles are its final smoothed estimate (the last update in which it was inside
    the window). Ground-truth columns are never read.

    Args:
        sequence: the sequence.
        theta0: ``(S,)`` starting configuration in radians (default straight).
        lag: window length in seconds (default the smoother options' 1 s).
        options: graph construction (:class:`~apcc_graph.estimation.options.GraphOptions`).
        progress: show a progress bar.
        vision: ``"projection"`` (default:
            :class:`~apcc_graph.estimation.projection_smoother.ProjectionFixedLagSmoother`,
            every observation once) or ``"epipolar"`` (:class:`FixedLagSmoother`, the
            generalized epipolar model, for comparison; it also self-calibrates).
        **smoother_options: further smoother arguments (fields of the smoother's options
            record, or ``settings``).

    Returns:
        The estimate, ``method = "smoother"``; ``inliers`` is 0 (the factors weigh each
        correspondence instead of classifying it).
    """
    if vision == "projection":
        if smoother_options.get("calibrate"):
            raise ValueError("calibrate=True: the projection smoother does not self-calibrate; "
                             "use the batch (method 'batch', calibrate=True) or the epipolar "
                             "smoother (vision='epipolar')")
        smoother_options.pop("calibrate", None)
        return projection_smoother_estimate(sequence, theta0=theta0, lag=lag, options=options,
                                            progress=progress, **smoother_options)
    if vision != "epipolar":
        raise ValueError(f"vision = {vision!r}: expected 'epipolar' or 'projection'")
    smoother = FixedLagSmoother(sequence.robot, lag=lag, options=options, theta0=theta0,
                                **smoother_options)
    return stream_estimate(smoother, sequence, progress)
