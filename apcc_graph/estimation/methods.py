"""``apcc_graph.estimate``: one entry point for every estimator."""

from __future__ import annotations

import math
import warnings
from dataclasses import replace
from numbers import Real
from os import PathLike

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.estimation.limit_check import at_the_limits, flag_misfits, wrong_basin
from apcc_graph.estimation.model_fit import ModelFit
from apcc_graph.estimation.model_noise import ROBOT
from apcc_graph.estimation.observation_checks import (  # noqa: F401 - part of this API
    FEW_TRACKS_PER_FRAME,
    ObservationWarning,
    check_observations,
)
from apcc_graph.estimation.options import BatchOptions, ChainOptions, GraphOptions, Robustness
from apcc_graph.estimation.result import Estimate, StartReport
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.sequence import Sequence

METHODS = ("chain", "batch", "smoother")
"""Estimators available."""

MethodOptions = ChainOptions | BatchOptions | SmootherOptions
"""A method's own options record."""

RECORDS: dict[str, type] = {"chain": ChainOptions, "batch": BatchOptions,
                            "smoother": SmootherOptions}
"""Each method's options record."""


def estimate(sequence: Sequence, method: str = "batch", theta0: ArrayLike | None = None,
             theta0_sigma: float | None = None, *, psi0: ArrayLike | None = None,
             spatial: bool = False, noise_px: float | None = None,
             graph: GraphOptions | None = None, robustness: Robustness | None = None,
             settings: MethodOptions | None = None, progress: bool = False) -> Estimate:
    """Estimate every frame's segment bends.

    Args:
        sequence: the sequence; ground-truth columns are never read.
        method: ``"chain"`` (the paper's front end), ``"batch"`` (factor graph, whole
            sequence) or ``"smoother"`` (fixed-lag smoother, frame by frame).
        theta0: ``(S,)`` starting configuration in radians; ``None`` (default) when it is
            unknown: the estimator then finds it from the first second of images, or from
            more if the robot barely moved (:mod:`~apcc_graph.estimation.start_search`), and
            the estimate's ``start`` says where and how well.
        theta0_sigma: standard deviation of the prior on ``theta0`` (radians; default
            ``graph.theta0_sigma``, 0.1 deg); batch and smoother only (the chain starts
            exactly at ``theta0``), and only with ``theta0``.
        psi0: ``(S,)`` the bending planes at frame 0 (radians; default 0); ``spatial`` and
            ``theta0`` only.
        spatial: the robot bends in 3-D: estimate every segment's bending plane ``psi`` too
            (the estimate's ``psis`` and ``psi_sigmas``), in bending vectors smooth through
            straight (:mod:`~apcc_graph.estimation.bends`); every method, and the unknown
            start too (the search then finds the planes at frame 0).
        noise_px: the tracks' pixel noise (pixels; default ``graph.threshold_px``, 1); for
            the chain, its RANSAC inlier threshold.
        graph: the measurement model (:class:`~apcc_graph.estimation.options.GraphOptions`:
            noise, priors, joint limits, tracks).
        robustness: how outliers are decided
            (:class:`~apcc_graph.estimation.options.Robustness`); batch and smoother.
        settings: the method's own options: :class:`~apcc_graph.estimation.options.
            ChainOptions`, :class:`~apcc_graph.estimation.options.BatchOptions` (e.g.
            ``BatchOptions(calibrate=True)``, self-calibration of each segment's k and
            delta_max) or :class:`~apcc_graph.estimation.smoother_options.SmootherOptions`
            (e.g. the lag); default the record's defaults.
        progress: show progress bars.

    Raises:
        TypeError: ``sequence`` is not a :class:`~apcc_graph.model.sequence.Sequence` (a path
            must be loaded first, with ``apcc_graph.load_sequence``); an options record of
            the wrong kind (named), or an argument this function does not take (named); a
            ``noise_px`` or ``theta0_sigma`` that is not a number, a ``spatial`` or
            ``progress`` that is not a bool (named).
        ValueError: an unknown method; a ``noise_px`` or ``theta0_sigma`` that is not finite
            and > 0 (named as the keyword); ``theta0`` not one finite angle per segment within its
            ``theta_max`` (radians); a sequence without a single observation;
            ``theta0_sigma`` or ``psi0`` without ``theta0``; ``psi0`` without ``spatial``.
        UnknownStartError: (a ``ValueError``) no ``theta0``, and the recording never tells
            the start (the robot never moved enough; the message says which segment), or the
            start it told led the bends to their joint limits (a wrong basin:
            :func:`~apcc_graph.estimation.limit_check.wrong_basin`).

    Warns:
        ObservationWarning: a camera observed nothing in the whole sequence, or fewer than
            :data:`FEW_TRACKS_PER_FRAME` tracks per frame (the chain: RANSAC inliers) (named).
        ModelFitWarning: the batch's or the smoother's estimate fails the residual test
            (:mod:`~apcc_graph.estimation.model_fit`, kept as the estimate's ``model_fit``;
            ``Robustness(misfit_alarm=None)`` skips it): the images contradict the estimate,
            so its sigmas are too small.
    """
    if not isinstance(sequence, Sequence):
        hint = (" (a path: load it first, apcc_graph.load_sequence(path))"
                if isinstance(sequence, str | PathLike) else "")
        raise TypeError(f"sequence: expected a Sequence, got {type(sequence).__name__}{hint}")
    if method not in METHODS:
        raise ValueError(f"method = {method!r}: expected one of {', '.join(METHODS)}")
    _check_keywords(noise_px=(noise_px, "pixels"), theta0_sigma=(theta0_sigma, "radians"))
    for name, flag in (("spatial", spatial), ("progress", progress)):
        if not isinstance(flag, bool | np.bool_):
            raise TypeError(f"{name} = {flag!r}: expected True or False")
    graph, robustness, settings = _records(method, graph, robustness, settings)
    if noise_px is not None:
        graph = replace(graph, threshold_px=float(noise_px))
    if theta0 is not None:
        sequence.robot.configuration(theta0)
    check_observations(sequence)
    if psi0 is not None and not spatial:
        raise ValueError("psi0 is given but spatial is False: bending planes are estimated "
                         "only for a spatial robot (spatial=True)")
    start = None
    if theta0 is None:
        if theta0_sigma is not None or psi0 is not None:
            raise ValueError(f"{'theta0_sigma' if theta0_sigma is not None else 'psi0'} "
                             "without theta0: with an unknown start the search finds the "
                             "start and its uncertainty itself; give theta0 too, or neither")
        theta0, theta0_sigma, start = _unknown_start(sequence, method, graph, robustness,
                                                     spatial)
        psi0 = start.psi0
    if theta0_sigma is not None:
        graph = replace(graph, theta0_sigma=float(theta0_sigma))
    result = _run(sequence, theta0, psi0, spatial, graph, robustness, settings, progress)
    result = at_the_limits(result, graph.limit_sigma)
    if start is not None and (why := wrong_basin(result)) is not None:
        from apcc_graph.estimation.start_search import UnknownStartError

        raise UnknownStartError(why)
    if method != "chain" and robustness.misfit_alarm is not None:
        fit = _model_fit(sequence, result, graph, robustness, theta0, psi0)
        result = flag_misfits(replace(result, model_fit=fit), fit)
    return result if start is None else replace(result, start=start)


def _model_fit(sequence: Sequence, result: Estimate, graph: GraphOptions,
               robustness: Robustness, theta0: ArrayLike, psi0: ArrayLike | None) -> ModelFit:
    """The residual test of an estimate with the robot it holds (calibrated or not) and the
    start prior it was given; warns (:class:`~apcc_graph.estimation.model_fit.
    ModelFitWarning`) when the images contradict it."""
    from apcc_graph.estimation.bends import parameterisation, start_vector
    from apcc_graph.estimation.model_fit import ModelFitWarning, check_model_fit

    assert robustness.misfit_alarm is not None
    bending = parameterisation(result.robot, result.spatial)
    held = sequence if result.robot is sequence.robot else sequence.with_robot(result.robot)
    fit = check_model_fit(held, bending.vector(result.thetas, result.psis), bending,
                          options=graph, inlier_sigmas=robustness.inlier_sigmas,
                          alarm=robustness.misfit_alarm, warn=False,
                          start=(start_vector(sequence.robot, bending, theta0, psi0),
                                 graph.theta0_sigma))
    if not fit.explained:
        warnings.warn(f"{result.method}: {fit.message()}", ModelFitWarning, stacklevel=3)
    return fit


def _check_keywords(**values: tuple[object, str]) -> None:
    """Each keyword argument ``name=(value, unit)`` is ``None`` or a finite number > 0; a
    mistake is named as the caller wrote it (the keyword, not the options record it fills)."""
    for name, (value, unit) in values.items():
        if value is None:
            continue
        if isinstance(value, bool | np.bool_) or not isinstance(value, Real):
            raise TypeError(f"{name} = {value!r}: expected a number ({unit}), got "
                            f"{type(value).__name__}")
        if not (math.isfinite(float(value)) and float(value) > 0.0):
            raise ValueError(f"{name} = {value!r}: expected a finite number > 0 ({unit})")


def _records(method: str, graph: GraphOptions | None, robustness: Robustness | None,
             settings: MethodOptions | None
             ) -> tuple[GraphOptions, Robustness, MethodOptions]:
    """The options records, defaulted, each checked to be of its kind (and ``settings`` of
    ``method``'s)."""
    wanted = RECORDS[method]
    for name, value, kind in (("graph", graph, GraphOptions),
                              ("robustness", robustness, Robustness),
                              ("settings", settings, wanted)):
        if value is not None and not isinstance(value, kind):
            owner = next((m for m, k in RECORDS.items() if isinstance(value, k)), None)
            why = f" (the options of method {owner!r})" if owner else ""
            raise TypeError(f"{name}: expected {kind.__name__} for method {method!r}, got "
                            f"{type(value).__name__}{why}")
    return (graph or GraphOptions(), robustness or Robustness(), settings or wanted())


def _run(sequence: Sequence, theta0: ArrayLike, psi0: ArrayLike | None, spatial: bool,
         graph: GraphOptions, robustness: Robustness, settings: MethodOptions,
         progress: bool) -> Estimate:
    """The estimator whose options ``settings`` are, from ``theta0`` (and ``psi0``)."""
    if isinstance(settings, ChainOptions):
        from apcc_graph.estimation.chain import chain_estimate

        if graph.model_sigma not in (None, ROBOT):  # the robot file's: the chain ignores it
            raise ValueError("GraphOptions.model_sigma (model error as noise) applies to the "
                             "batch and the smoother; the chain has the exact model")

        return chain_estimate(sequence, theta0, graph.threshold_px, settings.confidence,
                              settings.seed, progress, psi0=psi0, spatial=spatial)
    if isinstance(settings, BatchOptions):
        from apcc_graph.estimation.batch import batch_estimate

        return batch_estimate(sequence, theta0, options=graph,
                              max_iterations=settings.max_iterations,
                              marginals=settings.marginals, progress=progress,
                              init=settings.init, robustness=robustness,
                              calibrate=settings.calibrate,
                              calibration_sigmas=(None if settings.calibration_sigmas is None
                                                  else tuple(settings.calibration_sigmas)),
                              mount_sigmas=(None if settings.mount_sigmas is None
                                            else tuple(settings.mount_sigmas)),
                              psi0=psi0, spatial=spatial)
    from apcc_graph.estimation.smoother_runs import smoother_estimate

    # estimate() tests the whole recording afterwards: not block by block as well
    faults = replace(settings.faults, misfit_seconds=None)
    return smoother_estimate(sequence, theta0, options=graph,
                             settings=replace(settings, faults=faults),
                             robustness=robustness, progress=progress, psi0=psi0,
                             spatial=spatial)


def _unknown_start(sequence: Sequence, method: str, graph: GraphOptions,
                   robustness: Robustness, spatial: bool
                   ) -> tuple[FloatArray, float | None, StartReport]:
    """The start found from the data (:mod:`~apcc_graph.estimation.start_search`).

    Returns:
        The configuration (bends at frame 0), the prior the estimator then holds it with, and
        the :class:`~apcc_graph.estimation.result.StartReport` (with the planes, if spatial).

    The batch keeps the search's weak prior (vision alone, over the whole recording), so a
    start the images tell at all is enough for it; the smoother (which holds the start with the
    search's largest sigma) and the chain (which starts exactly there) cannot revisit it, so
    they wait until the images tell it to :data:`~apcc_graph.estimation.start_search.FIRM_SIGMA`.
    """
    from apcc_graph.estimation.start_search import (
        FIRM_SIGMA,
        MAX_SIGMA,
        PRIOR_SIGMA,
        start_from_data,
    )

    search = start_from_data(sequence, options=graph,
                             max_sigma=MAX_SIGMA if method == "batch" else FIRM_SIGMA,
                             spatial=spatial, robustness=robustness)
    if method == "batch":
        sigma: float | None = PRIOR_SIGMA
    elif method == "smoother":
        sigma = float(np.nanmax(search.sigma0))
    else:
        sigma = None
    return search.theta0, sigma, search.report()
