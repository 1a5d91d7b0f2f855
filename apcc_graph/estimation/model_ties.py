"""One frame's kinematic ties with model error as noise, the same in the batch and the smoother
(``docs/estimation.md``, "A model error that drifts").

Each segment's tie holds its tip to its base through the segment's APCC transform at the frame
vector, with the model error's noise. Where the segment's model error has a correlation length in
bend (:func:`~apcc_graph.estimation.model_noise.segment_correlations`) and the frame follows
another in the graph, the tie is the model error's transition from that frame, over the
distance between the two frames' vectors at the current estimate
(:func:`apcc_graph.factors.drifting_tie.drifting_tie_factor`); otherwise, and on the first
frame, the plain tie (:func:`apcc_graph.factors.kinematic.segment_tie_factor`): the steady state
of the model error.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import gtsam
import numpy as np

from apcc_graph.estimation.model_noise import tie_sigmas
from apcc_graph.factors.drifting_tie import decay, drifting_tie_factor
from apcc_graph.factors.keys import frame_key, tip_key
from apcc_graph.factors.kinematic import segment_tie_factor
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending

MIN_DECAY = 0.05
"""Below this decay between two frames the plain tie is used: the transition's residual
``r_g - a r_f`` then differs from ``r_g`` by at most 5% of the earlier error, and costs two
ties' evaluation."""

MIN_DISTANCE = math.radians(0.1)
"""The least distance (radians) counted between two frames' vectors: about what the estimates
of two frames' bends can be told apart by; a stiffer tie would hold two frames' model errors
equal on the strength of estimates that are not."""

Previous = tuple[int, FloatArray, FloatArray]
"""The frame before in the graph: its number, its frame vector's estimate and its base pose."""


class ModelTies:
    """The ties of every frame for one robot (module docstring).

    Args:
        bending: the robot's parameterisation.
        sigmas: per segment, the model error's (position m, rotation rad).
        correlations: per segment, its correlation length in bend (radians; 0: independent per
            frame).
    """

    def __init__(self, bending: Bending, sigmas: Sequence[tuple[float, float]],
                 correlations: Sequence[float]) -> None:
        self.bending = bending
        self.noise = [tie_sigmas(tuple(sigmas), j) for j in range(bending.n_segments)]
        self.correlations = tuple(float(length) for length in correlations)

    def frame(self, f: int, x: FloatArray, base: FloatArray,
              previous: Previous | None) -> list[gtsam.NonlinearFactor]:
        """Frame ``f``'s ties (its frame vector's estimate ``x``, the robot's base pose
        ``base``), one per segment, each a transition from ``previous`` where its model error
        drifts. The decay is fixed when the factor is made (the batch makes its factors anew
        at every stage, from its last solution)."""
        distance = (0.0 if previous is None else
                    max(float(np.linalg.norm(np.asarray(x) - np.asarray(previous[1]))),
                        MIN_DISTANCE))
        out: list[gtsam.NonlinearFactor] = []
        for j, (noise, length) in enumerate(zip(self.noise, self.correlations, strict=True)):
            own = base if j == 0 else tip_key(f, j - 1)
            a = 0.0 if previous is None else decay(distance, length)
            if previous is None or a < MIN_DECAY:
                out.append(segment_tie_factor(frame_key(f), tip_key(f, j), own, self.bending,
                                              j, noise))
                continue
            e = previous[0]
            earlier = (frame_key(e), tip_key(e, j), previous[2] if j == 0 else tip_key(e, j - 1))
            out.append(drifting_tie_factor(earlier, (frame_key(f), tip_key(f, j), own),
                                           self.bending, j, a, noise))
        return out
