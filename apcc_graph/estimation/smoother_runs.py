"""Running the fixed-lag smoother over a recorded sequence: ``estimate(..., method="smoother")``.

Each frame's angles are its final smoothed estimate (the last update in which it was inside the
window); ground-truth columns are never read.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from tqdm import tqdm

from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.result import Estimate
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.model.sequence import Sequence


def stream_estimate(smoother: FixedLagSmoother, sequence: Sequence, progress: bool = False
                    ) -> Estimate:
    """Feed a recorded sequence to ``smoother`` frame by frame; each frame's final estimate.

    Ground-truth columns are never read. The estimate's ``method`` is ``"smoother"`` and its
    ``inliers`` are 0 (the smoother weighs each observation instead of counting inliers).
    """
    for f in tqdm(range(sequence.n_frames), desc="smoother", disable=not progress):
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
    lag: float | None = None,
    options: GraphOptions | None = None,
    progress: bool = False,
    **smoother_options: Any,
) -> Estimate:
    """Run :class:`~apcc_graph.estimation.smoother.FixedLagSmoother` over a recorded sequence,
    frame by frame.

    Args:
        sequence: the sequence.
        theta0: ``(S,)`` starting configuration in radians (default straight).
        lag: window length in seconds (default the smoother options' 1 s).
        options: graph construction (:class:`~apcc_graph.estimation.options.GraphOptions`).
        progress: show a progress bar.
        **smoother_options: further :class:`FixedLagSmoother` arguments (fields of
            :class:`~apcc_graph.estimation.smoother_options.SmootherOptions`, ``settings``,
            ``spatial``, ``psi0``).

    Returns:
        The estimate, ``method = "smoother"``.
    """
    if smoother_options.get("calibrate"):
        raise ValueError("calibrate=True: the smoother does not self-calibrate; use the batch "
                         "(method 'batch', calibrate=True)")
    smoother_options.pop("calibrate", None)
    smoother = FixedLagSmoother(sequence.robot, lag=lag, options=options, theta0=theta0,
                                **smoother_options)
    return stream_estimate(smoother, sequence, progress)
