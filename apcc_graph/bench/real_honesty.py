"""Whether an estimate on a replayed real motion is honest: its sigmas against its errors, and
what its residual test said (``apcc-graph bench real``)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from apcc_graph.estimation.result import Estimate
from apcc_graph.evaluation.tip_floor import TipFloor


@dataclass(frozen=True)
class Honesty:
    """One stretch's ``(F, S)`` normalised squared errors, and its residual test."""

    nees: np.ndarray
    rejected: np.ndarray  # (S,) model-free inliers the model rejects (NaN: no test)
    accepted: np.ndarray  # (S,) model-free inliers
    warned: bool


def honesty(est: Estimate, floor: TipFloor) -> Honesty:
    """Whether an estimate's sigmas cover its errors against the floor's bends, and what its
    residual test said."""
    with np.errstate(divide="ignore", invalid="ignore"):
        nees = (est.errors(floor.thetas, floor.psis) / est.bend_sigmas()) ** 2
    S = est.thetas.shape[1]
    rejected, accepted = np.full(S, np.nan), np.zeros(S)
    fit = est.model_fit
    if fit is not None:
        for cam in fit.cameras:
            rejected[cam.camera], accepted[cam.camera] = cam.rejected, cam.accepted
    return Honesty(nees, rejected, accepted, fit is not None and not fit.explained)


def pooled_honesty(parts: list[Honesty], n_segments: int
                    ) -> tuple[np.ndarray, np.ndarray, int]:
    """Mean ``(e / sigma)^2`` per segment over every frame, the share rejected per camera over
    every stretch, and how many stretches warned."""
    if not parts:
        nan = np.full(n_segments, np.nan)
        return nan, nan, 0
    nees = np.concatenate([p.nees for p in parts])
    finite = np.isfinite(nees)
    with np.errstate(invalid="ignore"):
        mean = np.where(finite.any(axis=0), np.nansum(np.where(finite, nees, 0.0), axis=0)
                        / np.maximum(finite.sum(axis=0), 1), np.nan)
        share = (np.sum([p.rejected for p in parts], axis=0)
                 / np.sum([p.accepted for p in parts], axis=0))
    return mean, share, sum(p.warned for p in parts)
