"""Running the fixed-lag smoother over a recorded sequence: ``estimate(..., method="smoother")``.

Each frame's angles are its final smoothed estimate (the last update in which it was inside the
window); ground-truth columns are never read.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.estimation.options import GraphOptions, Robustness
from apcc_graph.estimation.result import Estimate
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.io.console import progress_bar
from apcc_graph.model.sequence import Sequence


def stream_estimate(smoother: FixedLagSmoother, sequence: Sequence,
                    progress: bool = False) -> Estimate:
    """Feed a recorded sequence to ``smoother`` frame by frame; each frame's final estimate.

    Ground-truth columns are never read. The estimate's ``method`` is ``"smoother"`` and its
    ``inliers`` are 0 (the smoother weighs each observation instead of counting inliers).
    """
    for f in progress_bar(range(sequence.n_frames), desc="smoother", progress=progress):
        smoother.update(sequence.frame(f))
    frames = smoother.finish()
    n_seg = sequence.n_segments
    spatial = bool(frames) and frames[0].psis is not None
    return Estimate(
        method="smoother", robot=sequence.robot, timestamps=sequence.timestamps.copy(),
        thetas=np.array([fr.thetas for fr in frames]),
        sigmas=np.array([fr.sigmas for fr in frames]),
        status=np.array([fr.status for fr in frames], dtype="<U24"),
        inliers=np.zeros((sequence.n_frames, n_seg), dtype=np.int64),
        world_T_base=sequence.world_T_base,
        psis=np.array([fr.psis for fr in frames]) if spatial else None,
        psi_sigmas=np.array([fr.psi_sigmas for fr in frames]) if spatial else None)


def smoother_estimate(
    sequence: Sequence,
    theta0: ArrayLike | None = None,
    options: GraphOptions | None = None,
    settings: SmootherOptions | None = None,
    robustness: Robustness | None = None,
    progress: bool = False,
    psi0: ArrayLike | None = None,
    spatial: bool = False,
) -> Estimate:
    """Run :class:`~apcc_graph.estimation.smoother.FixedLagSmoother` over a recorded sequence,
    frame by frame (with ``options.model_sigma``, with model error as noise).

    Args:
        sequence: the sequence.
        theta0: ``(S,)`` starting configuration in radians (default straight).
        options: the measurement model (:class:`~apcc_graph.estimation.options.GraphOptions`).
        settings: the smoother's options
            (:class:`~apcc_graph.estimation.smoother_options.SmootherOptions`: the lag, ...).
        robustness: the outlier threshold
            (:class:`~apcc_graph.estimation.options.Robustness`).
        progress: show a progress bar.
        psi0, spatial: as :class:`~apcc_graph.estimation.smoother.FixedLagSmoother`.

    Returns:
        The estimate, ``method = "smoother"``.
    """
    smoother = FixedLagSmoother(sequence.robot, options=options, theta0=theta0,
                                settings=settings, spatial=spatial, psi0=psi0,
                                robustness=robustness)
    return stream_estimate(smoother, sequence, progress)
