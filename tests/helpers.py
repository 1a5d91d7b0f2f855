"""Helpers shared by the tests (importable: pytest puts this folder on sys.path)."""

from __future__ import annotations

import re
from functools import cache
from pathlib import Path

import gtsam
import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def run_python_blocks(page: Path, folder: Path, monkeypatch) -> dict:  # noqa: ANN001
    """Run every fenced ``python`` block of ``page`` as written, in order, in one namespace,
    from ``folder`` (which gets a link to the repository's ``data/``, so files the examples
    write land there); returns the namespace. Fails when the page has fewer than four blocks."""
    blocks = re.findall(r"```python\n(.*?)```", page.read_text(encoding="utf-8"), re.S)
    assert len(blocks) >= 4, f"{page.name}: expected at least four Python examples"
    (folder / "data").symlink_to(ROOT / "data")
    monkeypatch.chdir(folder)
    namespace: dict = {}
    for block in blocks:
        exec(compile(block, page.name, "exec"), namespace)  # noqa: S102
    return namespace


def one_line_error(capsys) -> str:  # noqa: ANN001 - pytest's CaptureFixture
    """What the command line printed on stderr, checked to be one error line, no traceback."""
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err, err
    assert err.startswith("apcc-graph: error: "), err
    return err


def random_pose(rng: np.random.Generator, rot: float, trans: float) -> np.ndarray:
    """A random 4x4 pose: rotation vector ~ N(0, rot) rad, translation ~ N(0, trans) m."""
    rotation = gtsam.Rot3.Expmap(rng.normal(0.0, rot, 3))
    return gtsam.Pose3(rotation, rng.normal(0.0, trans, 3)).matrix()


def factor_hessian(factor: gtsam.NonlinearFactor, values: gtsam.Values
                   ) -> tuple[np.ndarray, np.ndarray]:
    """gtsam's information matrix and information vector of one factor linearised at
    ``values``, in the order of the factor's keys (gtsam's ``eta`` is minus the gradient)."""
    graph = gtsam.GaussianFactorGraph()
    graph.push_back(factor.linearize(values))
    ordering = gtsam.Ordering()
    for k in factor.keys():
        ordering.push_back(k)
    return graph.hessian(ordering)


@cache
def slow_recording_calibrated():  # -> (calibrated Robot, MeasuredEnds)
    """The shipped slow real-robot recording's calibrated model and measured segment ends
    (the calibration takes seconds: computed once per test process)."""
    return recording_calibrated("slow_free_space")


@cache
def recording_calibrated(recording: str):  # -> (calibrated Robot, MeasuredEnds)
    """A shipped real-robot recording's (a folder of ``data/real_tdcr``) calibrated model,
    its model error in its segments, and measured segment ends, as ``apcc-graph bench real``
    calibrates."""
    from apcc_graph.calibration.backbone_fit import fit_backbone
    from apcc_graph.io import load_robot
    from apcc_graph.io.backbone_poses import load_backbone_poses
    from apcc_graph.simulation.replay import measured_ends

    robot = load_robot(ROOT / "data" / "robots" / "real_tdcr.toml")
    poses = load_backbone_poses(ROOT / "data" / "real_tdcr" / recording / "backbone_poses.csv")
    cal = fit_backbone(poses, robot)
    model = cal.robot(robot)
    markers = dict(zip(cal.marker_arclengths.tolist(), cal.backbone_T_marker, strict=True))
    return model, measured_ends(poses, model, markers)


def replayed_stretches(recording: str, seeds: list[int], stretches: list[int] | None = None):
    """Per seed and stretch of at least the benchmark's 2 s (``stretches``: only these,
    0-based), ``(model, seed, stretch, sequence, floor)``: the real motion replayed as
    ``apcc-graph bench real`` does (1 px, 10% outliers, the seed's room) and the floor over
    it; for the sweeps ``tests/real_*_sweep.py``."""
    from apcc_graph.bench.real_robot import MIN_STRETCH
    from apcc_graph.evaluation.tip_floor import tip_floor
    from apcc_graph.simulation.replay import motion_stretches, replay_motion

    model, ends = recording_calibrated(recording)
    kept = [k for k, (a, b, _) in enumerate(motion_stretches(ends)) if b - a >= MIN_STRETCH
            and (stretches is None or k in stretches)]
    for seed in seeds:
        for k in kept:
            seq = replay_motion(model, ends, stretch=k, noise_px=1.0, outlier_fraction=0.1,
                                seed=seed).simulation.sequence
            yield model, seed, k, seq, tip_floor(model, seq.truth_tips)


@cache
def fast_stretch_replay(frames: int, exact: bool):  # -> (Robot, Sequence, truth tips, TipFloor)
    """The first ``frames`` frames of the fast stretch of the shipped slow real-robot recording
    (cameras on the measured segment ends, 1 px, 10% outliers; ``exact``: on the calibrated
    model's tips at the floor's bends instead), with the calibrated model, the measured tips
    and the floor over those frames."""
    from apcc_graph.evaluation.tip_floor import tip_floor
    from apcc_graph.simulation.replay import replay_motion

    model, ends = slow_recording_calibrated()
    options = dict(noise_px=1.0, outlier_fraction=0.1, seed=0, stretch=1)
    seq = replay_motion(model, ends, **options).simulation.sequence
    floor = tip_floor(model, seq.truth_tips)
    if exact:
        seq = replay_motion(model, ends, model_tips=floor.tips, bends=floor.bends,
                            **options).simulation.sequence
    truth = seq.truth_tips[:frames]
    return model, seq.head(frames), truth, tip_floor(model, truth)


def simulation_head(simulation, frames: int):  # -> Simulation
    """The first ``frames`` frames of a simulation (its sequence's head, the truth and the
    rows of those frames), for a bound over a shortened replay."""
    import dataclasses

    seq = simulation.sequence
    keep = {c: seq.tracks[c].frames < frames for c in seq.tracks}
    return dataclasses.replace(
        simulation, sequence=seq.head(frames),
        landmarks={c: v[keep[c]] for c, v in simulation.landmarks.items()},
        clean_uv={c: v[keep[c]] for c, v in simulation.clean_uv.items()},
        outliers={c: v[keep[c]] for c, v in simulation.outliers.items()},
        world_T_cam={c: v[:frames] for c, v in simulation.world_T_cam.items()},
        world_T_tip=simulation.world_T_tip[:frames])


def fast_stretch_bound(frames: int, model_sigma: tuple[float, float] | str, start_sigma: float,
                       drifting: bool = False) -> np.ndarray:
    """``(S,)`` the RMS over the first ``frames`` frames of the fast stretch's replay (as
    :func:`fast_stretch_replay`) of the Cramer-Rao bound of the segment ends (metres) with the
    model error ``model_sigma`` (position m, rotation rad; ``"robot"``: the calibration's, per
    segment) as noise on every segment, the start prior ``start_sigma`` (radians) and 1 px;
    ``drifting``: correlated along the bends as the calibration measured."""
    from apcc_graph.estimation.model_noise import segment_correlations, segment_sigmas
    from apcc_graph.evaluation.noise_bound import model_noise_tip_bound
    from apcc_graph.evaluation.tip_floor import tip_floor
    from apcc_graph.model.parameterisation import Bending
    from apcc_graph.simulation.replay import replay_motion

    model, ends = slow_recording_calibrated()
    replay = replay_motion(model, ends, noise_px=1.0, outlier_fraction=0.1, seed=0,
                           stretch=1).simulation
    whole = tip_floor(model, replay.sequence.truth_tips)
    bending = Bending.free(model.segments)
    bound = model_noise_tip_bound(
        simulation_head(replay, frames),
        bending.vector(whole.thetas[:frames], whole.psis[:frames]), bending,
        segment_sigmas(model_sigma, model), 1.0, start_sigma, 1,  # type: ignore[arg-type]
        segment_correlations("robot", model) if drifting else ())
    return np.sqrt(np.mean(bound.sigmas ** 2, axis=0))


def bearings_between(chain, x_a: np.ndarray, x_b: np.ndarray, a: int, b: int,
                     local: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit bearings ``(N, 3)`` of points ``local`` (given in the camera's frame at frame
    ``a``) from the camera of ``chain`` at frames a and b, with frame vectors ``x_a``,
    ``x_b``."""
    A = chain.poses(np.asarray(x_a, dtype=float)[None], a, False)[0][0]
    B = chain.poses(np.asarray(x_b, dtype=float)[None], b, False)[0][0]
    world = local @ A[:3, :3].T + A[:3, 3]
    seen = (world - B[:3, 3]) @ B[:3, :3]
    return (local / np.linalg.norm(local, axis=1, keepdims=True),
            seen / np.linalg.norm(seen, axis=1, keepdims=True))
