"""Figures (apcc_graph.plots): each writes a non-empty image and draws what it says it draws."""

from __future__ import annotations

import math
from pathlib import Path

import matplotlib.image
import numpy as np
import pytest

from apcc_graph.bench.accuracy import run_accuracy_benchmark
from apcc_graph.bench.calibration import run_calibration_benchmark
from apcc_graph.io.robot_file import load_robot
from apcc_graph.plots import (
    angles_figure,
    draw_robot,
    noise_figure,
    robot_figure,
    save_figure,
    tip_trajectories_figure,
)

REPO = Path(__file__).resolve().parents[1]
ROBOT = load_robot(REPO / "data/robots/planar_three.toml")


def _is_image(path: Path) -> None:
    assert path.stat().st_size > 5000
    pixels = matplotlib.image.imread(path)
    assert pixels.ndim == 3 and pixels.shape[0] > 100 and pixels.shape[1] > 100
    assert np.ptp(pixels[..., :3]) > 0.5  # something is drawn, not a blank canvas


def test_angles_figure_with_truth_and_band(tmp_path: Path) -> None:
    t = np.arange(50) / 30.0
    truth = np.column_stack([np.sin(t), 0.5 * np.cos(t), 0.2 * t])
    est = truth + 0.01
    sig = np.full_like(est, 0.02)
    sig[:10, 1] = np.nan  # unknown there: no band
    fig = angles_figure(t, est, sig, truth, label="smoother")
    axes = fig.axes
    assert len(axes) == 6  # angle and error per segment
    # Estimate and truth drawn in degrees; the error panel shows their difference.
    est_line = [ln for ln in axes[0].get_lines() if ln.get_label() == "smoother"][0]
    np.testing.assert_allclose(est_line.get_ydata(), np.degrees(est[:, 0]))
    err_line = axes[1].get_lines()[0]
    np.testing.assert_allclose(err_line.get_ydata(), np.degrees(0.01), rtol=1e-9)
    assert "RMS 0.57 / 0.57 / 0.57 deg" in fig._suptitle.get_text()
    _is_image(save_figure(fig, tmp_path / "angles.png"))


def test_angles_figure_without_truth_or_sigmas(tmp_path: Path) -> None:
    fig = angles_figure(np.arange(5.0), np.zeros((5, 2)))
    assert len(fig.axes) == 2
    _is_image(save_figure(fig, tmp_path / "a.png"))
    with pytest.raises(ValueError, match="truth has shape"):
        angles_figure(np.arange(5.0), np.zeros((5, 2)), truth=np.zeros((5, 3)))
    with pytest.raises(ValueError, match="thetas has shape"):
        angles_figure(np.arange(4.0), np.zeros((5, 2)))


def test_noise_figure(tmp_path: Path) -> None:
    bench = run_accuracy_benchmark(trials=3, noise_levels=(0.5, 1.0), points=40)
    fig = noise_figure(bench)
    lines = fig.axes[0].get_lines()
    assert len(lines) == 6  # median, mean, bound for fixed and moving base
    np.testing.assert_allclose(lines[0].get_xdata(), [0.5, 1.0])
    _is_image(save_figure(fig, tmp_path / "noise.png"))


def test_tip_trajectories_figure(tmp_path: Path) -> None:
    bench = run_calibration_benchmark(n_poses=11)
    fig = tip_trajectories_figure(bench)
    traj, err = fig.axes
    assert len(traj.get_lines()) == 1 + len(bench.model_tips)
    # The error panel is each model's distance to the true tips (mm), consistent with the RMS.
    for line, row in zip(err.get_lines(), bench.rows, strict=True):
        assert math.sqrt(np.mean(line.get_ydata() ** 2)) == pytest.approx(
            row.rms_position * 1e3, rel=1e-9)
    _is_image(save_figure(fig, tmp_path / "tips.png"))


def test_robot_is_drawn_where_the_kinematics_put_it(tmp_path: Path) -> None:
    import matplotlib.figure

    thetas = np.radians([40.0, -30.0, 25.0])
    fig = matplotlib.figure.Figure()
    ax = fig.add_subplot()
    draw_robot(ax, ROBOT, thetas)
    tips = ROBOT.forward(thetas)[:, :3, 3]
    markers = [ln for ln in ax.get_lines() if ln.get_marker() == "^"]
    drawn = np.array([[ln.get_xdata()[0], ln.get_ydata()[0]] for ln in markers])
    np.testing.assert_allclose(drawn, tips[:, [0, 2]], atol=1e-12)
    links = [ln for ln in ax.get_lines() if ln.get_linestyle() == "--"]
    arcs = [ln for ln in ax.get_lines() if ln.get_linestyle() == "-"]
    assert len(links) == len(arcs) == 3
    for i, (link, arc) in enumerate(zip(links, arcs, strict=True)):
        # Each segment's links end at its APCC tip; its arc starts where the segment starts and
        # has the segment's length.
        assert link.get_xdata()[-1] == pytest.approx(tips[i, 0])
        assert link.get_ydata()[-1] == pytest.approx(tips[i, 2])
        start = np.zeros(2) if i == 0 else tips[i - 1, [0, 2]]
        xy = np.column_stack([arc.get_xdata(), arc.get_ydata()])
        np.testing.assert_allclose(xy[0], start, atol=1e-12)
        length = np.sum(np.linalg.norm(np.diff(xy, axis=0), axis=1))
        assert length == pytest.approx(ROBOT.segments[i].length, rel=2e-3)
    with pytest.raises(ValueError, match="3 segments"):
        draw_robot(ax, ROBOT, [0.1, 0.2])
    _is_image(save_figure(robot_figure(ROBOT, [thetas, -thetas]), tmp_path / "robot.png"))


def test_save_figure_refuses_bad_paths_and_leaves_nothing(tmp_path: Path) -> None:
    fig = robot_figure(ROBOT, [np.zeros(3)])
    with pytest.raises(ValueError, match="cannot write a xyz figure"):
        save_figure(fig, tmp_path / "f.xyz")
    with pytest.raises(ValueError, match="does not exist"):
        save_figure(fig, tmp_path / "missing" / "f.png")
    assert list(tmp_path.iterdir()) == []
    target = tmp_path / "f.svg"
    save_figure(fig, target)
    assert target.read_text().lstrip().startswith("<?xml")
    assert [p.name for p in tmp_path.iterdir()] == ["f.svg"]  # no temporary file left
