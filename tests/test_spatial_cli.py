"""A spatial robot through files and the command line: theta.csv with psi columns (round trip,
bad values), TUM tips from (theta, psi), ``apcc-graph estimate --spatial`` and ``evaluate``, and
the command line's refusals."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from apcc_graph.cli import main
from apcc_graph.estimation.result import Estimate
from apcc_graph.io import save_sequence
from apcc_graph.io.estimates import load_theta_csv, load_theta_table, save_estimate
from apcc_graph.io.robot_file import load_robot
from apcc_graph.simulation.simulator import simulate

ROBOT = Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml"


@pytest.fixture(scope="module")
def robot():
    return load_robot(ROBOT)


def _estimate(robot, rng: np.random.Generator, n_frames: int = 7) -> Estimate:
    shape = (n_frames, robot.n_segments)
    psi_sigmas = rng.uniform(0.01, 0.2, shape)
    thetas = rng.uniform(0.0, 0.8, shape)
    thetas[2, 1] = 0.0
    psi_sigmas[2, 1] = math.inf  # exactly straight: psi undefined
    return Estimate(method="batch", robot=robot, timestamps=np.arange(n_frames) / 30.0,
                    thetas=thetas, sigmas=rng.uniform(1e-4, 1e-2, shape),
                    status=np.full(shape, "ok"), inliers=np.zeros(shape, dtype=np.int64),
                    psis=rng.uniform(-math.pi, math.pi, shape), psi_sigmas=psi_sigmas)


def test_theta_csv_round_trip_with_psi(robot, tmp_path: Path) -> None:
    est = _estimate(robot, np.random.default_rng(0))
    written = save_estimate(est, tmp_path)
    header = (tmp_path / "theta.csv").read_text().splitlines()[0].split(",")
    assert header[-6:] == ["psi_1", "psi_2", "psi_3", "psi_sigma_1", "psi_sigma_2",
                           "psi_sigma_3"]
    table = load_theta_table(tmp_path / "theta.csv")
    np.testing.assert_array_equal(table.thetas, est.thetas)
    np.testing.assert_array_equal(table.sigmas, est.sigmas)
    np.testing.assert_array_equal(table.psis, est.psis)
    np.testing.assert_array_equal(table.psi_sigmas, est.psi_sigmas)
    # The three-column reader still reads it; a planar file has no psi.
    _, thetas, sigmas = load_theta_csv(tmp_path / "theta.csv")
    np.testing.assert_array_equal(thetas, est.thetas)
    np.testing.assert_array_equal(sigmas, est.sigmas)
    # The tips are those of the bends (theta, psi), not of theta alone.
    tips = robot.forward(est.thetas, est.psis)
    text = (tmp_path / "tips_seg_3.tum").read_text().split()
    assert [float(v) for v in text[1:4]] == pytest.approx(tips[0, 2, :3, 3].tolist(), abs=1e-12)
    planar_tip = robot.forward(est.thetas)[0, 2, :3, 3]
    assert np.linalg.norm(planar_tip - tips[0, 2, :3, 3]) > 1e-3
    assert len(written) == 4


def test_a_non_finite_psi_is_named(robot, tmp_path: Path) -> None:
    est = _estimate(robot, np.random.default_rng(1))
    save_estimate(est, tmp_path)
    path = tmp_path / "theta.csv"
    lines = path.read_text().splitlines()
    fields = lines[4].split(",")
    fields[2 + 2 * 3 + 1] = "nan"  # psi_2 of frame 3
    lines[4] = ",".join(fields)
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=r"theta\.csv: line 5.*psi_2.*finite angle"):
        load_theta_table(path)


@pytest.fixture(scope="module")
def spatial_folder(robot, tmp_path_factory) -> tuple[Path, object]:
    sim = simulate(robot, 40, noise_px=1.0, seed=7, scene="room", spatial=True, fps=10.0)
    folder = tmp_path_factory.mktemp("spatial") / "seq"
    save_sequence(sim.sequence, folder)
    return folder, sim.sequence


def _degrees(values: np.ndarray) -> str:
    return "=" + ",".join(f"{v:.6f}" for v in np.degrees(values))


@pytest.mark.parametrize("method", ["batch", "chain", "smoother"])
def test_cli_estimate_spatial_and_evaluate(spatial_folder, tmp_path: Path, method: str,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    folder, seq = spatial_folder
    out = tmp_path / "est"
    argv = ["estimate", str(folder), "--spatial", "--out", str(out), "--method", method,
            "--theta0-deg" + _degrees(seq.thetas[0]), "--psi0-deg" + _degrees(seq.psis[0])]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "RMS error (bending vector)" in text
    table = load_theta_table(out / "theta.csv")
    assert table.psis is not None and np.all(table.thetas >= 0.0)
    b_est = table.thetas[..., None] * np.stack([np.cos(table.psis), np.sin(table.psis)], -1)
    b_true = seq.thetas[..., None] * np.stack([np.cos(seq.psis), np.sin(seq.psis)], -1)
    err = np.linalg.norm(b_est - b_true, axis=-1)
    assert np.degrees(np.sqrt(np.mean(err**2, axis=0))).max() < (30.0 if method == "chain"
                                                                 else 0.5)
    assert main(["evaluate", str(out), "--truth", str(folder)]) == 0
    report = capsys.readouterr().out
    assert "bending vector" in report
    rms_line = next(line for line in report.splitlines() if line.startswith("RMS (deg)"))
    np.testing.assert_allclose([float(v) for v in rms_line.split()[2:]],
                               np.degrees(np.sqrt(np.mean(err**2, axis=0))), atol=1e-4)


def test_cli_spatial_without_a_start_finds_it(spatial_folder, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    """--spatial without --theta0-deg: the search finds the bends and the planes at frame 0,
    and the summary says where."""
    folder, seq = spatial_folder
    out = tmp_path / "est"
    assert main(["estimate", str(folder), "--spatial", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    found = next(line for line in text.splitlines() if line.startswith("start found"))
    planes = next(line for line in text.splitlines() if "in the bending planes" in line)
    thetas = [float(v.split("+/-")[0]) for v in found.split("frames): ")[1][:-4].split(", ")]
    psis = [float(v) for v in planes.split("planes ")[1].split(" deg")[0].split(", ")]
    b_found = np.radians(thetas)[:, None] * np.stack([np.cos(np.radians(psis)),
                                                      np.sin(np.radians(psis))], -1)
    b_true = seq.thetas[0][:, None] * np.stack([np.cos(seq.psis[0]), np.sin(seq.psis[0])], -1)
    assert np.degrees(np.linalg.norm(b_found - b_true, axis=-1)).max() < 2.0


@pytest.mark.parametrize(("extra", "expected"), [
    (["--psi0-deg=0,0,0"], "--psi0-deg applies to --spatial only"),
    (["--spatial", "--psi0-deg=0,0,0"], "--psi0-deg applies to a given start"),
    (["--spatial", "--theta0-deg=0,0,0", "--psi0-deg=1,2"], "--psi0-deg '1,2': expected"),
], ids=["psi0-without-spatial", "psi0-without-theta0", "psi0-count"])
def test_cli_spatial_refusals(spatial_folder, tmp_path: Path, extra: list[str], expected: str,
                              capsys: pytest.CaptureFixture[str]) -> None:
    folder, _ = spatial_folder
    out = tmp_path / "est"
    assert main(["estimate", str(folder), "--out", str(out), *extra]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and expected in err[0], err
    assert not out.exists()  # nothing half-written
