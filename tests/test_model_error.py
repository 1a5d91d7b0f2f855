"""A segment's model error: measured by the backbone calibration, carried by ``robot.toml``
(``robot@2``), and taken as noise by the batch and the smoother by default
(docs/estimation.md, "Model error from the calibration")."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph.bench.smoother import FPS, ROBOT_FILE
from apcc_graph.calibration.backbone_fit import fit_backbone
from apcc_graph.calibration.model_error import (
    NEGLIGIBLE,
    correlation_bend,
    departure,
    measure_model_error,
)
from apcc_graph.calibration.model_exact import model_exact_poses
from apcc_graph.cli import main
from apcc_graph.estimation.methods import estimate
from apcc_graph.estimation.model_noise import FLOOR, ROBOT, segment_sigmas
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.terms import measurement_model
from apcc_graph.estimation.terms.exact import ExactTerms
from apcc_graph.estimation.terms.noisy import NoisyTerms
from apcc_graph.io import save_sequence
from apcc_graph.io.backbone_poses import load_backbone_poses
from apcc_graph.io.robot_file import load_robot, save_robot
from apcc_graph.model.model_error import ModelError
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot
from apcc_graph.simulation.simulator import simulate

DATA = Path(__file__).resolve().parents[1] / "data"
REAL_ROBOT = DATA / "robots" / "real_tdcr.toml"
SLOW = DATA / "real_tdcr" / "slow_free_space" / "backbone_poses.csv"
ERROR = ModelError(2e-3, math.radians(1.0), 3.0, "a test")


def _with_errors(robot: Robot, *errors: ModelError | None) -> Robot:
    return Robot([replace(seg, model_error=e) for seg, e in zip(robot.segments, errors,
                                                                 strict=True)],
                 list(robot.cameras))


def _ar1(n: int, dt: float, tau: float, sigma: float, white: float, seed: int) -> np.ndarray:
    """``(n, 3)`` a Gauss-Markov process of correlation time ``tau`` and size ``sigma``, plus
    white noise of ``white``."""
    rng = np.random.default_rng(seed)
    a = math.exp(-dt / tau)
    x = np.zeros((n, 3))
    x[0] = rng.normal(0.0, sigma, 3)
    for i in range(1, n):
        x[i] = a * x[i - 1] + rng.normal(0.0, sigma * math.sqrt(1.0 - a * a), 3)
    return x + rng.normal(0.0, white, (n, 3))


# ------------------------------------------------------------------------------ measuring it
@pytest.mark.parametrize("seed", [1, 2, 3])
def test_a_persistent_departure_is_told_from_white_noise(seed: int) -> None:
    """A Gauss-Markov departure (size 1, 2 s) under white noise (0.3): its size within 25%
    (bias included: the RMS), its correlation time within a factor 1.6; white noise alone:
    zero."""
    t = np.arange(1500) * 0.06
    size, white, tau = departure(_ar1(len(t), 0.06, 2.0, 1.0, 0.3, seed), t)
    assert 0.75 < size < 1.25 * math.hypot(1.0, 0.3), size
    assert 0.2 < white < 0.45 and tau is not None and 2.0 / 1.6 < tau < 2.0 * 1.6, (white, tau)
    rng = np.random.default_rng(seed)
    assert departure(rng.normal(0.0, 1.0, (len(t), 3)), t)[0] == 0.0


@pytest.mark.parametrize("seed", range(3))
def test_the_correlation_length_in_bend_is_measured_whatever_the_order_in_time(
        seed: int) -> None:
    """A departure that is a smooth function of the bends (a random Fourier series of known
    correlation length along a path that revisits its shapes in a shuffled order): the
    correlation in time says little, the length in bend is found within a factor 1.5; white
    residuals get none."""
    rng = np.random.default_rng(seed)
    n, length = 600, 0.15
    bends = rng.uniform(-0.6, 0.6, (n, 2))
    # A squared-exponential process has correlation exp(-d^2 / (2 l^2)): 1/e at d = l sqrt(2).
    scale = length / math.sqrt(2.0)
    freqs = rng.normal(0.0, 1.0 / scale, (200, 2))
    phases = rng.uniform(0.0, 2 * math.pi, (200, 3))
    r = 1e-3 * math.sqrt(2.0 / 200) * np.cos((bends @ freqs.T)[..., None] + phases).sum(axis=1)
    found = correlation_bend(r, bends, 0.0)
    assert found is not None and length / 1.5 < found < 1.5 * length, found
    white = correlation_bend(rng.normal(0.0, 1e-3, (n, 3)), bends, 0.0)
    assert white is not None and white < 0.2 * length, white  # the first bin with pairs


def test_samples_across_a_gap_are_not_neighbours() -> None:
    """White noise whose samples jump between two levels at a gap is still white: the pairs
    across the gap are left out (paired, they would look like a persistent departure)."""
    rng = np.random.default_rng(4)
    t = np.concatenate([np.arange(300) * 0.06, 100.0 + np.arange(300) * 0.06])
    r = rng.normal(0.0, 1.0, (600, 3))
    assert departure(r, t)[0] == 0.0


def test_the_calibration_of_a_model_exact_motion_measures_no_model_error() -> None:
    """On the real robot's slow recording the calibration measures a model error of millimetres
    and degrees; on the same motion made model-exact (the calibrated model's own segment ends,
    markers with white noise), none: every segment's error is zero, for two noise seeds."""
    robot = load_robot(REAL_ROBOT)
    poses = load_backbone_poses(SLOW)
    cal = fit_backbone(poses, robot)
    for error in cal.model_errors:
        assert error.position > 1e-3 and error.rotation > math.radians(0.5), error
        assert error.correlation_time is not None and error.correlation_time > 1.0
        assert error.correlation_bend is not None
        assert math.radians(5.0) < error.correlation_bend < math.radians(30.0)  # 12 and 15
    for seed in range(2):
        itself = fit_backbone(model_exact_poses(poses, cal, robot, seed=seed), robot)
        assert all(e.is_zero for e in itself.model_errors), itself.model_errors
        assert all("negligible" in e.measured for e in itself.model_errors)


def test_below_the_negligible_size_the_error_is_zero() -> None:
    """A persistent departure under :data:`NEGLIGIBLE` in both parts is zero; above it in one
    part, both are kept."""
    t = np.arange(800) * 0.06
    small = _ar1(len(t), 0.06, 2.0, 0.5 * NEGLIGIBLE[0], 0.0, 5)
    turn = _ar1(len(t), 0.06, 2.0, 0.5 * NEGLIGIBLE[1], 0.0, 6)
    assert measure_model_error(small, turn, t, "x").is_zero
    big = measure_model_error(small, 4.0 * turn, t, "x")
    assert big.rotation > NEGLIGIBLE[1] and big.position > 0.0


# ---------------------------------------------------------------------------- the robot file
@settings(max_examples=30, deadline=None)
@given(position=st.floats(0.0, 0.05), rotation=st.floats(0.0, 0.2),
       tau=st.one_of(st.none(), st.floats(0.01, 100.0)), measured=st.text(max_size=40),
       length=st.one_of(st.none(), st.floats(1e-4, 3.0)))
def test_a_model_error_round_trips_through_robot_toml(tmp_path_factory: pytest.TempPathFactory,
                                                      position: float, rotation: float,
                                                      tau: float | None, measured: str,
                                                      length: float | None) -> None:
    """Written as ``robot@2``; read back equal to within the file's digits; saved again, the
    same bytes."""
    path = tmp_path_factory.mktemp("robot") / "robot.toml"
    robot = _with_errors(load_robot(REAL_ROBOT),
                         ModelError(position, rotation, tau, measured, length), None)
    save_robot(robot, path)
    text = path.read_text()
    assert 'format = "apcc-graph/robot@2"' in text and "[segments.model_error]" in text
    back = load_robot(path)
    got = back.segments[0].model_error
    assert got is not None and back.segments[1].model_error is None
    assert got.position == pytest.approx(position, rel=1e-12, abs=1e-15)
    assert got.rotation == pytest.approx(rotation, rel=1e-12, abs=1e-15)
    assert (got.correlation_time is None) == (tau is None) and got.measured == measured
    if tau is not None:
        assert got.correlation_time == pytest.approx(tau, rel=1e-5)
    assert (got.correlation_bend is None) == (length is None)
    if length is not None:
        assert got.correlation_bend == pytest.approx(length, rel=1e-12)
    save_robot(back, path)
    assert path.read_text() == text


def test_a_robot_without_model_errors_stays_version_1(tmp_path: Path) -> None:
    path = tmp_path / "robot.toml"
    save_robot(load_robot(REAL_ROBOT), path)
    assert 'format = "apcc-graph/robot@1"' in path.read_text()


@pytest.mark.parametrize(("edit", "named"), [
    (lambda t: t.replace("theta_max_deg = 120.0\n",
                         "theta_max_deg = 120.0\n\n[segments.model_error]\nposition_mm = 1.0\n"
                         "rotation_deg = 0.5\n", 1), "segments[0].model_error"),
    (lambda t: t.replace("robot@1", "robot@2").replace(
        "theta_max_deg = 120.0\n", "theta_max_deg = 120.0\n\n[segments.model_error]\n"
        "position_mm = -1.0\nrotation_deg = 0.5\n", 1), "segments[0].model_error"),
    (lambda t: t.replace("robot@1", "robot@2").replace(
        "theta_max_deg = 120.0\n", "theta_max_deg = 120.0\n\n[segments.model_error]\n"
        "rotation_deg = 0.5\n", 1), "segments[0].model_error.position_mm"),
], ids=["needs-version-2", "negative", "missing-position"])
def test_a_bad_model_error_names_the_file_and_the_key(tmp_path: Path, edit: object,
                                                      named: str) -> None:
    path = tmp_path / "robot.toml"
    path.write_text(edit(REAL_ROBOT.read_text()))  # type: ignore[operator]
    with pytest.raises(ValueError) as info:
        load_robot(path)
    assert str(path) in str(info.value) and named in str(info.value), info.value


# ---------------------------------------------------------------------------- the default
def test_the_default_noise_is_the_robot_files() -> None:
    """``"robot"``: each segment's error (a zero or missing one at the floor while another
    segment has one); the exact model when no segment has one; ``None`` is exact whatever the
    file says; a pair is every segment's; one pair per segment must match the robot."""
    robot = load_robot(REAL_ROBOT)
    assert segment_sigmas(ROBOT, robot) is None
    assert segment_sigmas(ROBOT, _with_errors(robot, ModelError(0.0, 0.0), None)) is None
    noisy = _with_errors(robot, ERROR, None)
    assert segment_sigmas(ROBOT, noisy) == ((ERROR.position, ERROR.rotation), FLOOR)
    assert segment_sigmas(None, noisy) is None
    assert segment_sigmas((1e-3, 0.01), noisy) == ((1e-3, 0.01),) * 2
    with pytest.raises(ValueError, match="3 segments' model noise for a robot of 2"):
        segment_sigmas(((1e-3, 0.01),) * 3, noisy)
    assert GraphOptions().model_sigma == ROBOT


def test_the_batch_and_the_smoother_take_the_robot_files_noise() -> None:
    """Where the robot file has a model error the batch's terms and the smoother's window are
    the model-noise ones, with the file's sigmas per segment; ``model_sigma=None`` forces the
    exact model; self-calibration runs the exact model."""
    sim = simulate(load_robot(ROBOT_FILE), 4, noise_px=1.0, seed=2, fps=FPS, n_points=300)
    plain = sim.sequence.robot
    errors = [ModelError(1e-3 * (j + 1), math.radians(0.3 * (j + 1))) for j in range(3)]
    robot = _with_errors(plain, *errors)
    bending = Bending.fixed(robot.segments)
    terms = measurement_model(robot, GraphOptions(), bending)
    assert isinstance(terms, NoisyTerms)
    assert [t[0] for t in terms.ties.noise] == pytest.approx([e.rotation for e in errors])
    assert [t[-1] for t in terms.ties.noise] == pytest.approx([e.position for e in errors])
    assert isinstance(measurement_model(plain, GraphOptions(), bending), ExactTerms)
    assert isinstance(measurement_model(robot, GraphOptions(model_sigma=None), bending),
                      ExactTerms)
    assert isinstance(measurement_model(robot, GraphOptions(), bending, (0.05, 0.1)),
                      ExactTerms)
    theta0 = sim.sequence.thetas[0]
    assert FixedLagSmoother(robot, theta0=theta0).measurement_model == "model noise"
    assert FixedLagSmoother(plain, theta0=theta0).measurement_model == "exact"
    assert FixedLagSmoother(robot, theta0=theta0, options=GraphOptions(model_sigma=None)
                            ).measurement_model == "exact"
    seq = sim.sequence.with_robot(robot)
    chain = estimate(seq, method="chain", theta0=theta0)  # the chain ignores the file's noise
    assert chain.n_frames == 4
    with pytest.raises(ValueError, match="the chain has the exact model"):
        estimate(seq, method="chain", theta0=theta0, graph=GraphOptions(model_sigma=(1e-3, 0.01)))


def test_the_command_line_says_which_model_ran(tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    """``estimate`` on a sequence whose robot file carries model errors runs model noise and
    says so; ``--exact-model`` runs the exact model and says so; both flags at once are
    refused."""
    sim = simulate(load_robot(ROBOT_FILE), 12, noise_px=1.0, seed=3, fps=FPS, n_points=400)
    seq = sim.sequence.with_robot(_with_errors(sim.sequence.robot, ERROR, ERROR, ERROR))
    folder = tmp_path / "seq"
    save_sequence(seq, folder)
    assert 'robot@2' in (folder / "robot.toml").read_text()
    theta0 = "--theta0-deg=" + ",".join(f"{v:.4f}" for v in np.degrees(seq.thetas[0]))
    assert main(["estimate", str(folder), "--method", "batch", theta0, "--out",
                 str(tmp_path / "a")]) == 0
    out = capsys.readouterr().out
    assert "measurement model: model error as noise: 2.00 mm / 1.00 deg" in out
    assert "the robot file's model_error" in out
    assert main(["estimate", str(folder), "--method", "batch", theta0, "--exact-model",
                 "--out", str(tmp_path / "b")]) == 0
    assert "measurement model: the exact model (--exact-model)" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["estimate", str(folder), "--exact-model", "--model-sigma", "1,0.5", "--out",
              str(tmp_path / "c")])


def test_calibrate_writes_the_model_error(tmp_path: Path,
                                          capsys: pytest.CaptureFixture[str]) -> None:
    """``apcc-graph calibrate`` on backbone poses reports each segment's model error and writes
    it into the robot file, which every estimator then reads."""
    out = tmp_path / "robot.toml"
    assert main(["calibrate", str(DATA / "real_tdcr" / "impulse_2" / "backbone_poses.csv"),
                 "--robot", str(REAL_ROBOT), "--output", str(out)]) == 0
    report = capsys.readouterr().out
    assert "model error per segment" in report
    robot = load_robot(out)
    assert all(s.model_error is not None and not s.model_error.is_zero for s in robot.segments)
    assert "impulse_2/backbone_poses.csv" in robot.segments[0].model_error.measured
