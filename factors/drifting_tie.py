"""A model error that drifts: consecutive frames' kinematic ties of one segment, correlated.

A real segment is only approximately APCC; its tip departs from the model's by
``E = world_T_tip^-1 . world_T_base . base_T_tip(x)`` (the kinematic tie's residual
``r = Logmap(E)``: :func:`~apcc_graph.factors.kinematic.segment_tie_residual`; radians then
metres, in the tip's frame). That departure is a smooth function of the robot's shape, so it
changes little between two frames whose bends are close. Modelled as a first-order
Gauss-Markov process per component along the path of the frame vectors (an Ornstein-Uhlenbeck
process: steady-state standard deviation ``sigma``, correlation length ``L``), the ties of
frames ``f`` and ``g`` whose frame vectors are ``d`` apart are tied by the process's
transition::

    r_g = a r_f + w,    a = exp(-d / L),    w ~ N(0, sigma^2 (1 - a^2))

so the factor's residual is ``r_g - a r_f``, whitened by ``sigma sqrt(1 - a^2)``. A chain of
them, with the plain tie (``sigma``) on its first frame, is exactly the process's density: the
steady state holds at every frame, and consecutive frames differ by about
``sigma sqrt(2 d / L)`` when ``d << L``. As ``L -> 0`` (``a -> 0``) it becomes the
independent per-frame tie of each frame (``docs/estimation.md``, "A model error that drifts").
The same factor serves a process in time (``d`` seconds, ``L`` a correlation time).

Jacobian convention: that of :func:`~apcc_graph.factors.kinematic.segment_tie_residual`
(right-hand perturbations ``T . Exp(d)``, ``x + d``); the earlier frame's blocks are scaled by
``-a``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import gtsam
import numpy as np

from apcc_graph.factors.kinematic import segment_tie_residual
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending

Tie = tuple[int, int, "int | FloatArray"]
"""One frame's tie of a segment: its frame vector's key, its tip's key, and its base's key (the
previous segment's tip) or known ``(4, 4)`` base pose (the robot's base)."""


def decay(distance: float, length: float) -> float:
    """``a = exp(-distance / length)``, the fraction of a model error left after the frame
    vectors moved ``distance`` (0 for ``length = 0``, an independent error per frame).

    Raises:
        ValueError: a negative or non-finite ``distance`` or ``length``.
    """
    if not (math.isfinite(distance) and distance >= 0.0 and math.isfinite(length)
            and length >= 0.0):
        raise ValueError(f"decay(distance={distance!r}, length={length!r}): expected finite "
                         "values >= 0")
    return 0.0 if length == 0.0 else math.exp(-distance / length)


def drifting_tie_factor(earlier: Tie, later: Tie, bending: Bending, segment: int, a: float,
                        sigmas: Sequence[float] | FloatArray) -> gtsam.CustomFactor:
    """The transition of segment ``segment``'s model error from frame ``earlier`` to ``later``
    (module docstring).

    Args:
        earlier, later: the two frames' ties (:data:`Tie`).
        bending: the robot's parameterisation.
        segment: the segment (0-based).
        a: the decay between the frames (:func:`decay`), in ``[0, 1)``.
        sigmas: the model error's steady-state standard deviations, rotation (3, radians) then
            translation (3, metres), in the tip's frame.

    Returns:
        A factor over the keys of both ties (5 or 6), its error ``r_later - a r_earlier``
        whitened by ``sigmas sqrt(1 - a^2)``.
    """
    s = np.asarray(sigmas, dtype=float)
    if s.shape != (6,) or not np.all(np.isfinite(s)) or np.any(s <= 0.0):
        raise ValueError(f"drifting tie sigmas {sigmas!r}: expected 6 finite values > 0")
    if not 0.0 <= a < 1.0:
        raise ValueError(f"drifting tie decay {a!r}: expected 0 <= a < 1")
    if not 0 <= segment < bending.n_segments:
        raise ValueError(f"segment {segment}: expected 0 <= segment < {bending.n_segments}")
    ties = []
    keys: list[int] = []
    for x_key, tip_key, base in (earlier, later):
        known = None if isinstance(base, int) else gtsam.Pose3(np.asarray(base, dtype=float))
        slots = list(range(len(keys), len(keys) + (2 if known is not None else 3)))
        keys += [x_key, tip_key] + ([] if known is not None else [int(base)])  # type: ignore
        ties.append((known, slots))
    if len(set(keys)) != len(keys):
        raise ValueError(f"drifting tie over repeated keys {keys}: expected two frames' ties")
    noise = gtsam.noiseModel.Diagonal.Sigmas(s * math.sqrt(1.0 - a * a))
    scales = (-a, 1.0)

    def error_func(this: gtsam.CustomFactor, values: gtsam.Values,
                   H: list[np.ndarray] | None) -> np.ndarray:
        out = np.zeros(6)
        for (known, slots), scale in zip(ties, scales, strict=True):
            base = known if known is not None else values.atPose3(keys[slots[2]])
            r, h_base, h_x, h_tip = segment_tie_residual(
                base, values.atVector(keys[slots[0]]), values.atPose3(keys[slots[1]]), bending,
                segment, jacobians=H is not None)
            out += scale * r
            if H is not None:
                H[slots[0]], H[slots[1]] = scale * h_x, scale * h_tip
                if known is None:
                    H[slots[2]] = scale * h_base
        return out

    return gtsam.CustomFactor(noise, keys, error_func)
