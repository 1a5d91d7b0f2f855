"""Calibration: the paper's numbers, exact round trips, the sweep fit and its error messages."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import scipy.optimize
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph.calibration.closed_form import calibrate_from_tip
from apcc_graph.calibration.files import calibrate_measurements, load_tip_measurements
from apcc_graph.calibration.fit import fit_segment, fit_thetas
from apcc_graph.model.kinematics import apcc_in_plane, pcc_in_plane
from apcc_graph.model.segment import Segment
from apcc_graph.simulation.planar_curves import growing_curvature_tip


def paper_tip() -> tuple[float, float]:
    """The tip on the 42 deg chord whose ellipse (major axis 49.6) meets the axis at |OP| = 11.1."""
    L, OP, chord = 0.496, 0.111, math.radians(42.0)
    b = -2 * OP * math.cos(chord)
    c = OP**2 - (L - OP) ** 2
    r = (-b + math.sqrt(b * b - 4 * c)) / 2
    return r * math.sin(chord), r * math.cos(chord)


def test_paper_numbers() -> None:
    """The paper's example (docs/estimation.md, "Calibrating a segment"): chord 42, tip 76 ->
    delta_max 8 deg; k = 11.1 / 49.6 = 0.224."""
    cal = calibrate_from_tip(paper_tip(), math.radians(76.0), 0.496)
    assert math.degrees(cal.theta_max) == pytest.approx(84.0, abs=1e-9)
    assert math.degrees(cal.delta_max) == pytest.approx(8.0, abs=1e-9)
    assert cal.k == pytest.approx(11.1 / 49.6, abs=1e-12)
    assert round(cal.k, 3) == 0.224
    delta_60 = math.degrees(float(cal.segment.delta(math.radians(60))))
    assert delta_60 == pytest.approx(5.714, abs=1e-3)


def test_shipped_paper_example_file() -> None:
    report = calibrate_measurements(load_tip_measurements(
        Path(__file__).resolve().parents[1] / "data/calibration/paper_example.toml"))
    assert report.method == "one-pose"
    assert report.segment.k == pytest.approx(11.1 / 49.6, abs=1e-9)
    assert math.degrees(report.segment.delta_max) == pytest.approx(8.0, abs=1e-9)
    assert report.apcc.rms_position < 1e-9
    assert report.pcc.rms_position > 1e-3  # PCC cannot explain a tip deviation of 8 deg


@settings(max_examples=200, deadline=None)
@given(
    length=st.floats(0.05, 2.0),
    k=st.floats(0.02, 0.48),
    theta_max=st.floats(math.radians(5), math.radians(170)),
    rate=st.floats(-0.9, 0.9),
    sign=st.sampled_from([-1.0, 1.0]),
)
def test_one_pose_round_trip(length: float, k: float, theta_max: float, rate: float,
                             sign: float) -> None:
    seg = Segment(length, k=k, delta_max=rate * theta_max, theta_max=theta_max)
    theta = sign * theta_max
    planar = apcc_in_plane(theta, seg)
    cal = calibrate_from_tip((planar.px, planar.pz), float(seg.tip_angle(theta)), length)
    assert cal.k == pytest.approx(k, abs=1e-9)
    assert cal.delta_max == pytest.approx(seg.delta_max, abs=1e-9)
    assert cal.theta_max == pytest.approx(theta_max, abs=1e-12)
    assert cal.theta == pytest.approx(theta, abs=1e-12)


def test_one_pose_below_theta_max() -> None:
    """A pose photographed at 40 deg of a segment whose limit is 80 deg: delta_max scales up."""
    seg = Segment(0.5, k=0.2, delta_max=math.radians(10), theta_max=math.radians(80))
    theta = math.radians(40)
    planar = apcc_in_plane(theta, seg)
    cal = calibrate_from_tip((planar.px, planar.pz), float(seg.tip_angle(theta)), 0.5,
                             theta_max=math.radians(80))
    assert cal.delta_max == pytest.approx(seg.delta_max, abs=1e-12)
    assert cal.k == pytest.approx(0.2, abs=1e-12)


@pytest.mark.parametrize(
    ("tip", "angle", "length", "fragment"),
    [
        ((0.5, 0.1), 0.5, 0.5, "beyond the reach"),
        ((math.nan, 0.3), 0.5, 0.5, "finite"),
        ((0.1, 0.3), math.inf, 0.5, "finite"),
        ((0.1, 0.3), 0.5, -0.5, "length"),
        ((0.1, 0.3, 0.2), 0.5, 0.5, "shape"),
        ((1e-5, 0.49), 0.0, 0.5, "bent only"),
        ((0.01, 0.05), 0.3, 0.5, "outside the APCC range"),
        ((0.2, 0.4), 2.5, 0.5, "delta_max"),
        ((0.1, -0.2), 2.5, 0.5, "180"),
    ],
)
def test_one_pose_rejects_bad_input(tip, angle, length, fragment: str) -> None:
    with pytest.raises(ValueError, match=fragment):
        calibrate_from_tip(tip, angle, length)


def sweep(seg: Segment, thetas: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    planar = apcc_in_plane(thetas, seg)
    return np.column_stack([planar.px, planar.pz]), seg.tip_angle(thetas)


def test_fit_segment_exact_on_noise_free_sweep() -> None:
    seg = Segment(0.5, k=0.18, delta_max=math.radians(15), theta_max=math.radians(70))
    thetas = np.linspace(-seg.theta_max, seg.theta_max, 15)
    pos, ang = sweep(seg, thetas)
    fit = fit_segment(pos, ang, 0.5)
    assert fit.k == pytest.approx(0.18, abs=1e-9)
    assert fit.delta_max == pytest.approx(seg.delta_max, abs=1e-9)
    assert fit.theta_max == pytest.approx(seg.theta_max, abs=1e-9)
    np.testing.assert_allclose(fit.thetas, thetas, atol=1e-9)
    assert fit.apcc.rms_position < 1e-10 and fit.apcc.rms_angle < 1e-10
    assert fit.pcc.rms_position > 1e-3


def test_fit_segment_noisy_sweeps_are_consistent_with_their_std() -> None:
    """Over seeds, the errors of k and delta_max are of the size of the reported std."""
    seg = Segment(0.5, k=0.22, delta_max=math.radians(8), theta_max=math.radians(60))
    thetas = np.linspace(-seg.theta_max, seg.theta_max, 25)
    pos, ang = sweep(seg, thetas)
    sigma_p, sigma_a = 0.0005, math.radians(0.3)
    z_k, z_d = [], []
    for seed in range(12):
        rng = np.random.default_rng(seed)
        fit = fit_segment(pos + rng.normal(0, sigma_p, pos.shape),
                          ang + rng.normal(0, sigma_a, ang.shape), 0.5,
                          theta_max=seg.theta_max, position_sigma=sigma_p, angle_sigma=sigma_a)
        assert abs(fit.k - 0.22) < 0.01
        assert abs(math.degrees(fit.delta_max - seg.delta_max)) < 0.5
        z_k.append((fit.k - 0.22) / fit.k_std)
        z_d.append((fit.delta_max - seg.delta_max) / fit.delta_max_std)
    # Roughly unit scatter: a std off by 3x either way fails.
    assert 0.33 < np.sqrt(np.mean(np.square(z_k))) < 3.0
    assert 0.33 < np.sqrt(np.mean(np.square(z_d))) < 3.0


def test_fit_segment_beats_pcc_when_curvature_grows() -> None:
    thetas = np.linspace(-1.2, 1.2, 31)
    x, z, ang = growing_curvature_tip(thetas, 0.5, growth=2.0)
    fit = fit_segment(np.column_stack([x, z]), ang, 0.5)
    assert fit.apcc.rms_position < 0.2 * fit.pcc.rms_position
    assert fit.k > 0.25  # curvature toward the tip pushes the joint outward


def test_fit_thetas_for_pcc_and_for_a_calibrated_segment() -> None:
    thetas = np.linspace(-1.0, 1.0, 9)
    px, pz = pcc_in_plane(thetas, 0.4)
    pcc = fit_thetas(None, np.column_stack([px, pz]), thetas, length=0.4)
    np.testing.assert_allclose(pcc.thetas, thetas, atol=1e-9)
    assert pcc.rms_position < 1e-10
    seg = Segment(0.4, k=0.3, delta_max=-0.1, theta_max=1.0)
    pos, ang = sweep(seg, thetas)
    fit = fit_thetas(seg, pos, ang)
    np.testing.assert_allclose(fit.thetas, thetas, atol=1e-9)
    with pytest.raises(ValueError, match="length"):
        fit_thetas(None, pos, ang)


SINGLE_POSE_TRUTH = Segment(0.4, k=0.21, delta_max=math.radians(7.0), theta_max=math.radians(80.0))


@pytest.mark.parametrize("perturbed", [False, True], ids=["exact", "perturbed"])
@pytest.mark.parametrize("model", ["apcc", "pcc"])
@pytest.mark.parametrize("bend_deg", [-80.0, -40.0, -10.0, 10.0, 40.0, 80.0])
def test_fit_thetas_of_a_single_pose(bend_deg: float, model: str, perturbed: bool) -> None:
    """One pose (one unknown) is fitted like any pose of a sweep.

    Regression: scipy's ``trf`` with a sparse Jacobian (``lsmr``) raised IndexError in
    ``solve_trust_region_2d`` for one unknown, e.g. the PCC fit of one APCC pose bent 40 deg.
    """
    seg = SINGLE_POSE_TRUTH
    sigma_p, sigma_a = 0.002 * seg.length, math.radians(0.5)  # fit_thetas' defaults
    pos, ang = sweep(seg, np.array([math.radians(bend_deg)]))
    if perturbed:  # a measured tip that no theta explains exactly
        pos, ang = pos + [[5e-4, -3e-4]], ang + math.radians(0.2)
    fitted = None if model == "pcc" else seg

    def tip(theta: float) -> tuple[float, float, float]:
        if fitted is None:
            px, pz = pcc_in_plane(np.array([theta]), seg.length)
            return float(px[0]), float(pz[0]), theta
        planar = apcc_in_plane(np.array([theta]), seg)
        return float(planar.px[0]), float(planar.pz[0]), float(seg.tip_angle(theta))

    def cost(theta: float) -> float:
        x, z, a = tip(theta)
        return (((x - pos[0, 0]) ** 2 + (z - pos[0, 1]) ** 2) / sigma_p**2
                + ((a - ang[0]) / sigma_a) ** 2)

    fit = fit_thetas(fitted, pos, ang, length=seg.length)
    assert fit.thetas.shape == fit.position_residuals.shape == fit.angle_residuals.shape == (1,)
    theta = float(fit.thetas[0])
    # The reported residuals are those of the model tip at the fitted theta.
    x, z, a = tip(theta)
    assert fit.position_residuals[0] == pytest.approx(
        math.hypot(x - pos[0, 0], z - pos[0, 1]), abs=1e-12)
    assert fit.angle_residuals[0] == pytest.approx(a - ang[0], abs=1e-12)
    # The fitted theta is the optimum: an independent 1-D minimisation of the same cost ...
    best = scipy.optimize.minimize_scalar(cost, bounds=(theta - 0.3, theta + 0.3),
                                          method="bounded", options={"xatol": 1e-12})
    assert theta == pytest.approx(best.x, abs=1e-8)
    assert cost(theta) <= cost(best.x) + 1e-9
    # ... and the same pose fitted within a sweep (the per-pose fits are independent; they agree
    # to the solver's tolerance, ~1e-9 rad).
    others, others_ang = sweep(seg, np.radians([-60.0, 25.0]))
    within = fit_thetas(fitted, np.vstack([pos, others]), np.concatenate([ang, others_ang]),
                        length=seg.length)
    assert theta == pytest.approx(float(within.thetas[0]), abs=1e-8)
    assert fit.position_residuals[0] == pytest.approx(within.position_residuals[0], abs=1e-9)
    if model == "apcc" and not perturbed:  # the calibrated model reproduces its own tip
        assert theta == pytest.approx(math.radians(bend_deg), abs=1e-12)
        assert fit.position_residuals[0] < 1e-12 and abs(fit.angle_residuals[0]) < 1e-12
    if model == "pcc":  # PCC cannot explain the APCC tip: a real, millimetre-size residual
        assert fit.position_residuals[0] > 1e-4


@pytest.mark.parametrize(
    ("positions", "angles", "fragment"),
    [
        (np.array([[0.1, 0.45]]), np.array([0.4]), "at least 2 poses"),
        (np.array([[0.1, 0.45], [0.2, 0.4]]), np.array([0.4]), "one angle per pose"),
        (np.array([[0.1, 0.45], [np.nan, 0.4]]), np.array([0.4, 0.8]), "finite"),
        (np.array([[0.1, 0.45], [0.5, 0.4]]), np.array([0.4, 0.8]), "beyond the reach"),
        (np.array([[1e-4, 0.5], [-1e-4, 0.5]]), np.array([0.0, 0.0]), "not observable"),
        (np.array([0.1, 0.45]), np.array([0.4]), "shape"),
    ],
)
def test_fit_segment_rejects_bad_input(positions, angles, fragment: str) -> None:
    with pytest.raises(ValueError, match=fragment):
        fit_segment(positions, angles, 0.5)


def test_calibration_file_errors_name_file_and_key(tmp_path) -> None:
    path = tmp_path / "cal.toml"
    path.write_text('format = "apcc-graph/calibration@1"\nlength = 0.5\n'
                    "[[poses]]\ntip_x = 0.1\ntip_z = 0.4\n")
    with pytest.raises(ValueError, match=r"cal.toml: poses\[0\].tip_angle_deg: missing"):
        load_tip_measurements(path)
    path.write_text('format = "apcc-graph/calibration@1"\nlength = -0.5\n'
                    "[[poses]]\ntip_x = 0.1\ntip_z = 0.4\ntip_angle_deg = 20\n")
    with pytest.raises(ValueError, match="cal.toml: length"):
        load_tip_measurements(path)
    path.write_text('format = "apcc-graph/calibration@1"\nlength = 0.5\nmass = 2\n'
                    "[[poses]]\ntip_x = 0.1\ntip_z = 0.4\ntip_angle_deg = 20\n")
    with pytest.raises(ValueError, match="cal.toml: mass: unknown key"):
        load_tip_measurements(path)


def test_calibration_file_with_a_sweep(tmp_path) -> None:
    seg = Segment(0.5, k=0.21, delta_max=math.radians(5), theta_max=math.radians(50))
    pos, ang = sweep(seg, np.linspace(-seg.theta_max, seg.theta_max, 7))
    lines = ['format = "apcc-graph/calibration@1"', "length = 0.5", "theta_max_deg = 50.0"]
    for (x, z), a in zip(pos, ang, strict=True):
        lines += ["[[poses]]", f"tip_x = {float(x)!r}", f"tip_z = {float(z)!r}",
                  f"tip_angle_deg = {math.degrees(float(a))!r}"]
    path = tmp_path / "sweep.toml"
    path.write_text("\n".join(lines) + "\n")
    report = calibrate_measurements(load_tip_measurements(path))
    assert report.method == "sweep" and report.n_poses == 7
    assert report.segment.k == pytest.approx(0.21, abs=1e-8)
    assert report.segment.delta_max == pytest.approx(seg.delta_max, abs=1e-8)
