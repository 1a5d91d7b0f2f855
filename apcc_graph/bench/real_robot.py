"""``apcc-graph bench real``: the estimators on a real robot's motion, beside the floor
(docs/estimation.md, "Replaying a real robot's motion").

For each recording: calibrate the robot from its backbone poses (k, delta_max, marker offsets
and each segment's model error), replay the measured motion with tip cameras seeing a simulated
room, and estimate from the floor's first configuration (the start given, with a prior) with the
chain, the batch and the smoother as a user gets them (``batch``, ``smoother``: the calibrated
robot file, whose model errors they take as noise), the same with the exact model forced
(``batch-exact``, ``smoother-exact``), and with the bench's own model noise (``noise``,
``smoother-noise``). The model-exact version of the motion gets the model errors that the
calibration of the model's own motion (with white marker noise) measures:
:func:`~apcc_graph.calibration.model_exact.model_exact_poses`. A last row, ``noise@floor``, is
a yardstick rather than an estimator: the batch with model noise started at the floor's bends of
every frame, i.e. what the model-noise problem gives when its start is in the right basin.
Each estimate's tips are compared with the measured tips beside the floor (the model's tips at the
bends that best fit them) and the rotation floor (at the bends whose tip rotations best fit the
measured ones, what tip cameras can deliver: :func:`~apcc_graph.evaluation.tip_floor.
rotation_floor`); then the same for the model-exact version of the motion (the model's
own tips at the floor's bends), where the floor is zero and the yardstick is the Cramer-Rao
bound of the tips (:mod:`~apcc_graph.evaluation.tip_bound`): ``bound``, of the whole stretch
(a batch's), and, when a smoother runs, ``lag bound``, of its final estimates with its lag.

The motion capture lost the robot now and then; nothing is made up across those gaps, so each
stretch between them of at least ``MIN_STRETCH`` seconds is replayed and estimated on its own
(its start given), and the RMS is over the frames of all of them. The table also gives how far
the tip cameras turn from frame to frame (95th percentile), the front end's hardest input.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from apcc_graph.bench.real_honesty import Honesty, honesty, pooled_honesty
from apcc_graph.calibration.backbone_fit import BackboneCalibration, fit_backbone
from apcc_graph.calibration.model_exact import model_exact_poses
from apcc_graph.estimation.batch import batch_estimate
from apcc_graph.estimation.keyframes import KeyframeRule
from apcc_graph.estimation.methods import estimate
from apcc_graph.estimation.model_fit import ModelFitWarning
from apcc_graph.estimation.model_noise import (
    ROBOT,
    describe,
    segment_correlations,
    segment_sigmas,
)
from apcc_graph.estimation.options import BatchOptions, GraphOptions
from apcc_graph.estimation.result import Estimate
from apcc_graph.estimation.smoother_options import FaultOptions, SmootherOptions, WindowOptions
from apcc_graph.estimation.window import RestartWarning
from apcc_graph.evaluation.noise_bound import model_noise_tip_bound
from apcc_graph.evaluation.tip_bound import tip_bound
from apcc_graph.evaluation.tip_floor import (
    TipErrors,
    TipFloor,
    rotation_floor,
    tip_errors,
    tip_floor,
)
from apcc_graph.io.backbone_poses import BackbonePoses, load_backbone_poses
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import Sequence
from apcc_graph.simulation.replay import measured_ends, motion_stretches, replay_motion
from apcc_graph.simulation.simulator import Simulation

RECORDINGS = ("slow_free_space", "impulse_2")
PEERS = {"smoother-qr": SmootherOptions(window=WindowOptions(factorization="QR")),
         "smoother-gate": SmootherOptions(faults=FaultOptions(rotation_gate=0.02)),
         "smoother-keyframes": SmootherOptions(keyframes=KeyframeRule())}
"""Smoother variants the bench can run beside the default: ``smoother-qr`` factors its window
by QR, ``smoother-gate`` adds the model-free outlier gate (0.02 rad), ``smoother-keyframes``
solves at keyframes only (the default rule)."""
EXACT = ("batch-exact", "smoother-exact")
"""The batch and the smoother with the exact model forced (``--exact-model``)."""
INDEPENDENT = ("batch-independent", "smoother-independent")
"""The batch and the smoother with the robot file's model error independent per frame
(``GraphOptions.model_correlation = 0``) instead of drifting along the bends over the length
the calibration measured (the default)."""
METHODS = ("chain", "batch", "smoother", "batch-exact", "smoother-exact", "noise",
           "smoother-noise", "noise@floor", "batch-chain", *INDEPENDENT, *PEERS)
"""Every method the bench knows. ``batch`` and ``smoother`` are the defaults: the robot file
from the calibration, with its model errors; ``noise`` and ``smoother-noise`` take the bench's
``model_sigma`` instead; ``batch-chain`` is ``batch`` started from the chain rather than from
the cameras' rotations. The :data:`PEERS` are not in the default list."""
SMOOTHERS = ("smoother", "smoother-exact", "smoother-noise", "smoother-independent", *PEERS)
"""The methods whose yardstick on the model-exact motion is the lag bound."""
MODEL_SIGMA = (1e-3, math.radians(0.5))
"""The benchmark's model noise (position m, rotation rad) for ``noise`` and ``noise@floor``."""
MIN_STRETCH = 2.0
"""Stretches between gaps shorter than this (seconds) are left out of the benchmark."""
BOUND_STEP = 20
"""Frames between the samples of the tips' bounds on the model-exact motion (each sample of the
lag bound builds and factors one information matrix)."""
NOISE_BOUND_LINE = (
    "noise bound: the Cramer-Rao bound of the segment ends on the measured motion (every "
    f"{BOUND_STEP}th frame) with the calibration's model error as noise, correlated along the "
    "bends as the calibration measured it: what the images and the approximate model together "
    "tell")
"""The table's note on the noise bound."""


@dataclass(frozen=True)
class RealRow:
    """One estimate's tip errors (metres, radians) on one version of one recording.

    Attributes:
        frames: frames scored (over the stretches replayed).
        turn: ``(S,)`` 95th percentile of the tip cameras' rotation from frame to frame (rad).
        nees: ``(S,)`` mean ``(e / sigma)^2`` of each segment's bend, ``e`` against the floor's
            bends (the bending vector's error and sigma; NaN without sigmas): whether the
            sigmas cover the errors (about 1 when they do).
        misfit: ``(S,)`` the residual test's share of each camera's model-free inliers that the
            model rejects at the estimate (:mod:`~apcc_graph.estimation.model_fit`; NaN
            where it was not run).
        warned: in how many of the stretches the residual test warned.
        stretches: how many stretches the row pools.
        restarts: how many times gtsam failed on a smoother's window (it restarted).
        model: the measurement model the calibrated robot file gives ``batch`` and
            ``smoother`` on this version of the motion.
    """

    recording: str
    version: str
    method: str
    position: np.ndarray
    tangent: np.ndarray
    seconds: float
    frames: int = 0
    turn: np.ndarray | None = None
    nees: np.ndarray | None = None
    misfit: np.ndarray | None = None
    warned: int = 0
    stretches: int = 0
    restarts: int = 0
    model: str = ""


def _pooled(errors: list[TipErrors]) -> TipErrors:
    return TipErrors(np.concatenate([e.position for e in errors]),
                     np.concatenate([e.tangent for e in errors]))


def _turns(tips: FloatArray) -> FloatArray:
    """``(F - 1, S)`` rotation of each tip from one frame to the next (radians)."""
    rel = np.swapaxes(tips[:-1, :, :3, :3], -1, -2) @ tips[1:, :, :3, :3]
    return Rotation.from_matrix(rel.reshape(-1, 3, 3)).magnitude().reshape(rel.shape[:2])


def _estimate(seq: Sequence, method: str, floor: TipFloor, start_sigma: float, noise_px: float,
              model_sigma: tuple[float, float]) -> Estimate:
    """One row's estimate, from the floor's first configuration (``noise@floor``: from the
    floor's bends of every frame)."""
    if method == "noise@floor":
        bending = Bending.free(seq.robot.segments)
        return batch_estimate(seq, floor.thetas[0], psi0=floor.psis[0], spatial=True,
                              initial=bending.vector(floor.thetas, floor.psis), marginals=False,
                              options=GraphOptions(threshold_px=noise_px,
                                                   theta0_sigma=start_sigma,
                                                   model_sigma=model_sigma))
    graph = (GraphOptions(model_sigma=model_sigma) if method in ("noise", "smoother-noise")
             else GraphOptions(model_sigma=None) if method in EXACT
             else GraphOptions(model_correlation=0.0) if method in INDEPENDENT else None)
    if method in ("smoother-exact", "smoother-independent"):
        method = "smoother"
    if method in SMOOTHERS and method != "smoother":
        return estimate(seq, method="smoother", spatial=True, theta0=floor.thetas[0],
                        psi0=floor.psis[0], theta0_sigma=start_sigma, noise_px=noise_px,
                        settings=PEERS.get(method), graph=graph)
    settings = BatchOptions(init="chain") if method == "batch-chain" else None
    batches = ("noise", "batch-exact", "batch-chain", "batch-independent")
    return estimate(seq, method="batch" if method in batches else method,
                    settings=settings, spatial=True, theta0=floor.thetas[0],
                    psi0=floor.psis[0], theta0_sigma=start_sigma, noise_px=noise_px, graph=graph)


def _bounds(seq: Sequence, methods: tuple[str, ...]) -> dict[str, int | None]:
    """The yardsticks of the model-exact motion: ``bound`` (the whole stretch, a batch's)
    and, with a smoother, ``lag bound`` (its final estimates', with its default lag in
    frames)."""
    out: dict[str, int | None] = {"bound": None}
    if any(m in SMOOTHERS for m in methods):
        dt = float(np.median(np.diff(seq.timestamps)))
        out["lag bound"] = round(SmootherOptions().window.lag / dt)
    return out


def _model_exact_robot(poses: BackbonePoses, cal: BackboneCalibration, robot: Robot,
                       seed: int) -> Robot:
    """The model-exact motion's robot: the calibrated model, with the model error that the
    calibration of the model's own motion measures (zero where the markers' noise is white)."""
    model = cal.robot(robot)
    itself = fit_backbone(model_exact_poses(poses, cal, robot, seed=seed), robot)
    return Robot([replace(seg, model_error=error) for seg, error
                  in zip(model.segments, itself.model_errors, strict=True)],
                 list(model.cameras))


def _yardsticks(real: Simulation, exact: Simulation, floor: TipFloor,
                methods: tuple[str, ...], noise_px: float, start_sigma: float
                ) -> dict[tuple[str, str], TipErrors]:
    """One stretch's yardsticks: on the measured motion the floor, the rotation floor and,
    where the calibration measured a model error, the bound with it as noise; on the
    model-exact motion the bounds (module docstring)."""
    model = real.sequence.robot
    out = {("real", "floor"): floor.errors,
           ("real", "rot-floor"): rotation_floor(model, real.sequence.truth_tips).errors}
    noise = segment_sigmas(ROBOT, model)
    if noise is not None:  # what the images and the model with its error tell
        bending = Bending.free(model.segments)
        bound = model_noise_tip_bound(real, bending.vector(floor.thetas, floor.psis), bending,
                                      noise, noise_px, start_sigma, BOUND_STEP,
                                      segment_correlations(ROBOT, model))
        out["real", "noise bound"] = TipErrors(bound.sigmas, np.full_like(bound.sigmas, np.nan))
    for method, lag in _bounds(exact.sequence, methods).items():
        bound = tip_bound(exact, noise_px, start_sigma, lag, BOUND_STEP, spatial=True)
        out["model-exact", method] = TipErrors(bound.sigmas, np.full_like(bound.sigmas, np.nan))
    return out


def bench_recording(poses_path: Path, robot: Robot, *, noise_px: float, outliers: float,
                    seed: int, start_sigma: float, methods: tuple[str, ...],
                    model_sigma: tuple[float, float] = MODEL_SIGMA,
                    fps: float | None = None) -> list[RealRow]:
    """Calibrate, replay (at ``fps``, interpolated; ``None``: at the recording's own sample
    times), estimate and score one recording (module docstring)."""
    name = poses_path.parent.name
    poses = load_backbone_poses(poses_path)
    cal = fit_backbone(poses, robot)
    model = cal.robot(robot)
    exact_model = _model_exact_robot(poses, cal, robot, seed)
    markers = dict(zip(cal.marker_arclengths.tolist(), cal.backbone_T_marker, strict=True))
    ends = measured_ends(poses, model, markers)
    options = dict(noise_px=noise_px, outlier_fraction=outliers, seed=seed, fps=fps)
    kept = [k for k, (a, b, _) in enumerate(motion_stretches(ends)) if b - a >= MIN_STRETCH]
    errors: dict[tuple[str, str], list[TipErrors]] = {}
    seconds: dict[tuple[str, str], float] = {}
    honest: dict[tuple[str, str], list[Honesty]] = {}
    restarts: dict[tuple[str, str], int] = {}
    models = {version: describe(segment_sigmas(ROBOT, r))
              for version, r in (("real", model), ("model-exact", exact_model))}
    turns = []
    for k in kept:
        real_sim = replay_motion(model, ends, stretch=k, **options).simulation
        real = real_sim.sequence
        floor = tip_floor(model, real.truth_tips)
        exact_sim = replay_motion(exact_model, ends, model_tips=floor.tips, bends=floor.bends,
                                  stretch=k, **options).simulation
        exact = exact_sim.sequence
        for key, found in _yardsticks(real_sim, exact_sim, floor, methods, noise_px,
                                      start_sigma).items():
            errors.setdefault(key, []).append(found)
        turns.append(_turns(real.truth_tips))
        for version, seq in (("real", real), ("model-exact", exact)):
            for method in methods:
                start = time.perf_counter()
                with warnings.catch_warnings(record=True) as caught:  # the table counts them
                    warnings.simplefilter("always")
                    est = _estimate(seq, method, floor, start_sigma, noise_px, model_sigma)
                for w in caught:
                    if not issubclass(w.category, ModelFitWarning | RestartWarning):
                        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
                restarts[version, method] = restarts.get((version, method), 0) + sum(
                    issubclass(w.category, RestartWarning) for w in caught)
                errors.setdefault((version, method), []).append(
                    tip_errors(model.forward(est.thetas, est.psis), seq.truth_tips))
                honest.setdefault((version, method), []).append(honesty(est, floor))
                seconds[version, method] = (seconds.get((version, method), 0.0)
                                            + time.perf_counter() - start)
    turn = np.percentile(np.concatenate(turns), 95, axis=0) if turns else None
    rows = []
    for (version, method), errs in errors.items():
        pooled = _pooled(errs)
        nees, misfit, warned = pooled_honesty(honest.get((version, method), []),
                                               len(pooled.rms_position))
        rows.append(RealRow(name, version, method, pooled.rms_position, pooled.rms_tangent,
                            seconds.get((version, method), 0.0), len(pooled.position), turn,
                            nees, misfit, warned, len(errs),
                            restarts.get((version, method), 0), models[version]))
    return rows


def _yardstick(rows: list[RealRow], row: RealRow) -> np.ndarray | None:
    """``row``'s yardstick among ``rows`` (module docstring), ``None`` for a yardstick."""
    if row.method in ("floor", "bound", "lag bound", "noise bound"):
        return None
    if row.version != "model-exact":
        name = "floor"
    else:
        name = "lag bound" if row.method in SMOOTHERS else "bound"
    found = [r.position for r in rows if r.recording == row.recording and r.method == name
             and (r.version == row.version or name == "floor")]
    return found[0] if found else None


def run_real_bench(data: Path, robot: Robot, *, noise_px: float = 1.0, outliers: float = 0.1,
                   seed: int = 0, start_sigma: float = math.radians(2.0),
                   methods: tuple[str, ...] = METHODS,
                   recordings: tuple[str, ...] = RECORDINGS,
                   model_sigma: tuple[float, float] = MODEL_SIGMA,
                   fps: float | None = None) -> list[RealRow]:
    """:func:`bench_recording` of each recording ``data/<name>/backbone_poses.csv``, replayed
    at ``fps`` (``None``: the recording's own sample times).

    Raises:
        ValueError: a recording's file is missing (named).
    """
    rows = []
    for name in recordings:
        path = Path(data) / name / "backbone_poses.csv"
        if not path.is_file():
            raise ValueError(f"{path}: no such file; --data names the folder of the real-robot "
                             "recordings (data/real_tdcr in the repository)")
        rows += bench_recording(path, robot, noise_px=noise_px, outliers=outliers, seed=seed,
                                start_sigma=start_sigma, methods=methods,
                                model_sigma=model_sigma, fps=fps)
    return rows


def _model_lines(rows: list[RealRow]) -> list[str]:
    """What the default batch and smoother ran on each recording and motion."""
    lines, said = [], set()
    for r in rows:
        if r.model and (r.recording, r.version) not in said:
            said.add((r.recording, r.version))
            lines.append(f"batch, smoother on {r.recording}, {r.version} motion: {r.model} "
                         "(the calibration's robot file)")
    if any(r.method in EXACT for r in rows):
        lines.append("batch-exact, smoother-exact: the exact model forced (--exact-model)")
    return lines


def format_real_bench(rows: list[RealRow]) -> str:
    """The table: RMS tip position and tangent error per segment end, and the ratio to the
    recording's yardstick: the floor on the measured motion; on the model-exact motion the
    bound (the lag bound for a smoother)."""
    n_seg = len(rows[0].position)
    head = "".join(f"{f'tip {i + 1} mm':>10}{'/yard':>8}{'deg':>7}" for i in range(n_seg))
    lines = [f"{'recording':<17}{'motion':<13}{'method':<16}{head}{'time s':>9}"]
    for r in rows:
        yard = _yardstick(rows, r)
        cells = ""
        for i in range(n_seg):
            ratio = "-" if yard is None else f"{r.position[i] / max(yard[i], 1e-12):.1f}x"
            tangent = math.degrees(r.tangent[i])
            cells += (f"{r.position[i] * 1e3:>10.2f}{ratio:>8}"
                      + (f"{tangent:>7.2f}" if math.isfinite(tangent) else f"{'-':>7}"))
        lines.append(f"{r.recording:<17}{r.version:<13}{r.method:<16}{cells}{r.seconds:>9.1f}")
    lines.append("/yard: over the yardstick of the same recording and motion: the floor on the "
                 "measured motion; on the model-exact motion the bound (the lag bound for a "
                 "smoother)")
    lines.append("floor: the calibrated model's tips at the bends that best fit the measured "
                 "tips (zero on the model-exact motion)")
    lines.append("rot-floor: the model's tips at the bends whose tip rotations best fit the "
                 "measured ones (what tip cameras measure well): the camera-based yardstick")
    if any(r.method == "noise bound" for r in rows):
        lines.append(NOISE_BOUND_LINE)
    if any(r.method == "bound" for r in rows):
        lines.append("bound, lag bound: the Cramer-Rao bound of the tips on the model-exact "
                     f"motion (every {BOUND_STEP}th frame), of the whole stretch and of a "
                     "smoother's final estimates with a "
                     f"{SmootherOptions().window.lag:g} s lag; from the "
                     "pixels and the start prior, without the motion prior the estimators add "
                     "(which can take them below it where the robot moves slowly)")
    lines += _model_lines(rows)
    if any(r.method in ("noise", "noise@floor") for r in rows):
        lines.append("noise: the batch with model error as noise; noise@floor: the same started "
                     "at the floor's bends of every frame (a yardstick: the right basin given)")
    honest = [r for r in rows if r.nees is not None and np.isfinite(r.nees).any()]
    if honest:
        lines.append("")
        lines.append("honesty: mean (e/sigma)^2 per segment against the floor's bends (about 1 "
                     "when the sigmas cover the errors), and the residual test: the share of "
                     "each camera's model-free inliers the model rejects at the estimate "
                     "(0.2% expected when the model explains the images; warns above 5%)")
        lines.append(f"{'recording':<17}{'motion':<13}{'method':<16}"
                     + "".join(f"{f'(e/s)^2 {i + 1}':>12}" for i in range(n_seg))
                     + "".join(f"{f'rejected {i + 1}':>12}" for i in range(n_seg))
                     + f"{'warned':>10}{'restarts':>10}")
        for r in honest:
            assert r.nees is not None and r.misfit is not None
            lines.append(f"{r.recording:<17}{r.version:<13}{r.method:<16}"
                         + "".join(f"{v:>12.3g}" for v in r.nees)
                         + "".join(f"{'-' if not np.isfinite(v) else f'{100 * v:.1f}%':>12}"
                                   for v in r.misfit)
                         + f"{f'{r.warned}/{r.stretches}':>10}{r.restarts:>10}")
    for r in rows:
        if r.method == "floor" and r.turn is not None:
            lines.append(f"{r.recording}: {r.frames} frames in the stretches of at least "
                         f"{MIN_STRETCH:g} s between the motion capture's gaps; the tip cameras "
                         "turn by up to " + " / ".join(f"{math.degrees(x):.1f}" for x in r.turn)
                         + " deg from frame to frame (95th percentile)")
    return "\n".join(lines)
