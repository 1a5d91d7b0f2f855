"""``apcc_graph.estimate``, estimate files (theta.csv, TUM), evaluation, and the two commands."""

from __future__ import annotations

import math
from pathlib import Path

import gtsam
import numpy as np
import pytest

import apcc_graph
from apcc_graph.cli import main
from apcc_graph.evaluation.accuracy import compare
from apcc_graph.io.estimates import load_theta_csv, save_estimate
from apcc_graph.io.robot_file import load_robot
from apcc_graph.io.sequence_folder import save_sequence
from apcc_graph.simulation.simulator import simulate_sequence

ROBOT = Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml"


@pytest.fixture(scope="module")
def sequence():
    return simulate_sequence(load_robot(ROBOT), 15, noise_px=0.5, seed=9, moving_base=True)


def test_estimate_dispatches_and_refuses_unknown_methods(sequence) -> None:
    est = apcc_graph.estimate(sequence, method="chain", theta0=sequence.thetas[0])
    assert est.method == "chain" and est.thetas.shape == (15, 3)
    with pytest.raises(ValueError, match="chain, batch"):
        apcc_graph.estimate(sequence, method="kalman")


def test_estimator_never_reads_the_truth(sequence) -> None:
    """Same result whether or not the sequence carries ground truth."""
    from apcc_graph.model.sequence import Sequence

    blind = Sequence(sequence.robot, sequence.timestamps, sequence.tracks,
                     world_T_base=sequence.world_T_base)
    a = apcc_graph.estimate(sequence, method="chain", theta0=sequence.thetas[0])
    b = apcc_graph.estimate(blind, method="chain", theta0=sequence.thetas[0])
    np.testing.assert_array_equal(a.thetas, b.thetas)


def test_theta_csv_and_tum_files(sequence, tmp_path: Path) -> None:
    est = apcc_graph.estimate(sequence, method="chain", theta0=sequence.thetas[0])
    written = save_estimate(est, tmp_path)
    assert [p.name for p in written] == ["theta.csv", "tips_seg_1.tum", "tips_seg_2.tum",
                                         "tips_seg_3.tum"]
    header = (tmp_path / "theta.csv").read_text().splitlines()[0]
    assert header == "frame,timestamp,theta_1,theta_2,theta_3,sigma_1,sigma_2,sigma_3"
    timestamps, thetas, sigmas = load_theta_csv(tmp_path / "theta.csv")
    np.testing.assert_array_equal(thetas, est.thetas)
    np.testing.assert_array_equal(timestamps, est.timestamps)
    assert np.all(np.isnan(sigmas))  # the chain gives no uncertainty
    # TUM: timestamp tx ty tz qx qy qz qw, the tip pose in the world frame.
    rows = np.loadtxt(tmp_path / "tips_seg_3.tum")
    assert rows.shape == (15, 8)
    tips = est.world_T_tip()[:, 2]
    np.testing.assert_allclose(rows[:, 1:4], tips[:, :3, 3], atol=1e-15)
    for row, pose in zip(rows, tips, strict=True):
        q = gtsam.Rot3.Quaternion(row[7], row[4], row[5], row[6]).matrix()
        np.testing.assert_allclose(q, pose[:3, :3], atol=1e-12)


def test_theta_csv_errors_name_the_line(tmp_path: Path) -> None:
    path = tmp_path / "theta.csv"
    path.write_text("frame,timestamp,theta_1,sigma_1\n0,0.0,0.1,nan\n0,0.1,0.2,nan\n")
    with pytest.raises(ValueError, match="line 3, column 'frame'"):  # frames may skip, not repeat
        load_theta_csv(path)
    path.write_text("frame,timestamp,theta_1,sigma_1\n0,0.0,nan,nan\n")
    with pytest.raises(ValueError, match="line 2, column 'theta_1'"):
        load_theta_csv(path)


def test_compare_reports_drift_per_window() -> None:
    truth = np.zeros((300, 2))
    est = np.zeros((300, 2))
    est[:, 0] = np.linspace(0, 0.3, 300)  # drifting segment
    est[:, 1] = 0.01  # constant offset
    report = compare(est, truth, window=100)
    assert report.window_rms.shape == (3, 2)
    assert report.window_rms[2, 0] > 3 * report.window_rms[0, 0]
    np.testing.assert_allclose(report.window_rms[:, 1], 0.01)
    assert report.max_abs[0] == pytest.approx(0.3)
    with pytest.raises(ValueError, match="same"):
        compare(est, truth[:10])


def test_estimate_and_evaluate_commands(sequence, tmp_path: Path, capsys) -> None:
    seq_dir, out = tmp_path / "seq", tmp_path / "est"
    save_sequence(sequence, seq_dir)
    deg = ",".join(f"{math.degrees(v):.6f}" for v in sequence.thetas[0])
    assert main(["estimate", str(seq_dir), "--method", "chain", "--out", str(out),
                 f"--theta0-deg={deg}"]) == 0
    assert "RMS error vs the sequence's ground truth" in capsys.readouterr().out
    assert main(["evaluate", str(out), "--truth", str(seq_dir), "--window", "5"]) == 0
    text = capsys.readouterr().out
    assert "RMS (deg)" in text
    assert sum(line.startswith("  frames") for line in text.splitlines()) == 3
    # User mistakes: one line, exit 1.
    assert main(["estimate", str(seq_dir), "--out", str(out), "--theta0-deg", "1,2"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "3 finite angles" in err[0]
    assert main(["evaluate", str(tmp_path / "nothing"), "--truth", str(seq_dir)]) == 1
    assert "theta.csv" in capsys.readouterr().err
