"""Inputs a new user gets wrong, each refused with a message that says what is wrong (no
traceback on the command line, nothing written)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import apcc_graph
from apcc_graph import FixedLagSmoother
from apcc_graph.cli import main
from apcc_graph.io import load_sequence

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "sequences" / "planar_three"
THETA0_DEG = "--theta0-deg=20.466,-15.210,21.277"


@pytest.fixture(scope="module")
def sample() -> apcc_graph.Sequence:
    return load_sequence(SAMPLE)


def test_a_path_instead_of_a_sequence(sample: apcc_graph.Sequence) -> None:
    with pytest.raises(TypeError, match=r"got PosixPath .*load_sequence"):
        apcc_graph.estimate(SAMPLE, method="chain")
    with pytest.raises(TypeError, match=r"got str .*load_sequence"):
        apcc_graph.estimate(str(SAMPLE), method="batch")


@pytest.mark.parametrize("method", ["chain", "batch", "smoother"])
def test_a_start_in_degrees_where_radians_are_expected(sample: apcc_graph.Sequence,
                                                       method: str) -> None:
    degrees = np.degrees(sample.thetas[0])  # 20.5, -15.2, 21.3: beyond 60 deg as radians
    with pytest.raises(ValueError, match=r"theta0\[0\] = 20.4.* beyond segment 1's theta_max "
                       r"of 60.0 deg \(angles are in radians\)"):
        apcc_graph.estimate(sample, method=method, theta0=degrees)


def test_a_start_that_is_not_finite_or_has_the_wrong_length(sample: apcc_graph.Sequence) -> None:
    with pytest.raises(ValueError, match=r"theta0\[1\] = nan: expected a finite angle"):
        apcc_graph.estimate(sample, method="chain", theta0=[0.1, np.nan, 0.0])
    with pytest.raises(ValueError, match=r"theta0 has shape \(2,\): expected \(3,\)"):
        apcc_graph.estimate(sample, method="chain", theta0=[0.1, 0.2])


def test_the_smoother_refuses_a_start_beyond_the_limits(sample: apcc_graph.Sequence) -> None:
    with pytest.raises(ValueError, match=r"FixedLagSmoother.theta0\[2\] = -3.0 rad .* segment "
                       r"3's theta_max"):
        FixedLagSmoother(sample.robot, theta0=[0.0, 0.0, -3.0])


def one_line_error(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "Traceback" not in err
    return err


def test_cli_start_beyond_theta_max(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["estimate", str(SAMPLE), "--method", "chain", "--out", str(tmp_path / "e"),
                 "--theta0-deg=500,0,0"]) == 1
    assert "500 deg is beyond segment 1's theta_max of 60 deg" in one_line_error(capsys)
    assert not (tmp_path / "e").exists()


def test_cli_a_fraction_where_an_integer_is_expected(capsys: pytest.CaptureFixture[str]
                                                     ) -> None:
    with pytest.raises(SystemExit) as stop:
        main(["bench", "solver", "--trials", "2.5"])
    assert stop.value.code == 1
    assert "'2.5' is not an integer" in one_line_error(capsys)


def test_cli_estimate_refuses_a_folder_in_use_without_force_and_replaces_it_whole_with(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "est"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    args = ["estimate", str(SAMPLE), "--method", "chain", "--out", str(out), THETA0_DEG]
    assert main(args) == 1
    assert "exists and is not empty; choose another --out or add --force" in one_line_error(
        capsys)
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
    assert main([*args, "--force"]) == 0  # replaces the folder whole: nothing old stays
    assert sorted(p.name for p in out.iterdir()) == [
        "theta.csv", "tips_seg_1.tum", "tips_seg_2.tum", "tips_seg_3.tum"]


def without_camera(sequence: apcc_graph.Sequence, cams: set[int]) -> apcc_graph.Sequence:
    tracks = {cam: t for cam, t in sequence.tracks.items() if cam not in cams}
    return apcc_graph.Sequence(sequence.robot, sequence.timestamps, tracks,
                               world_T_base=sequence.world_T_base, thetas=sequence.thetas)


def test_a_camera_that_never_sees_anything_is_named(sample: apcc_graph.Sequence) -> None:
    from apcc_graph.estimation.methods import ObservationWarning

    blind = without_camera(sample, {1})
    with pytest.warns(ObservationWarning, match=r"camera cam_2 \(segment 2\) observed nothing"):
        apcc_graph.estimate(blind, method="chain", theta0=sample.thetas[0])


def test_a_sequence_without_observations_is_refused(sample: apcc_graph.Sequence) -> None:
    with pytest.raises(ValueError, match=r"no observations.*apcc-graph track"):
        apcc_graph.estimate(without_camera(sample, {0, 1, 2}), method="batch")


def test_cli_warns_in_one_line_naming_the_camera(tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    import shutil

    folder = tmp_path / "seq"
    shutil.copytree(SAMPLE, folder)
    (folder / "tracks" / "cam_3.csv").unlink()
    assert main(["estimate", str(folder), "--method", "chain", "--out", str(tmp_path / "e"),
                 THETA0_DEG]) == 0
    err = capsys.readouterr().err  # also the progress bars
    warned = [line for line in err.splitlines() if line.startswith("apcc-graph: warning:")]
    assert len(warned) == 1 and "camera cam_3 (segment 3) observed nothing" in warned[0]
    assert "Traceback" not in err and "UserWarning" not in err
    shutil.rmtree(folder / "tracks")
    assert main(["estimate", str(folder), "--method", "chain", "--out", str(tmp_path / "f"),
                 THETA0_DEG]) == 1
    assert "no observations" in one_line_error(capsys)


def test_every_command_that_writes_needs_force_to_replace(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """One rule: ``simulate`` and ``estimate`` refuse a non-empty folder, ``calibrate`` and
    ``plot`` an existing file, unless ``--force``; the file is left as it was."""
    paper = str(SAMPLE.parents[1] / "calibration" / "paper_example.toml")
    robot = tmp_path / "robot.toml"
    robot.write_text("mine")
    assert main(["calibrate", paper, "--output", str(robot)]) == 1
    assert "robot.toml: exists; choose another path or add --force" in one_line_error(capsys)
    assert robot.read_text() == "mine"
    assert main(["calibrate", paper, "--output", str(robot), "--force"]) == 0
    assert robot.read_text().startswith("format")
    est = tmp_path / "est"
    assert main(["estimate", str(SAMPLE), "--method", "chain", "--out", str(est),
                 THETA0_DEG]) == 0
    figure = tmp_path / "angles.png"
    figure.write_bytes(b"mine")
    capsys.readouterr()
    assert main(["plot", str(est), "--output", str(figure)]) == 1
    assert "angles.png: exists" in one_line_error(capsys)
    assert figure.read_bytes() == b"mine"
    assert main(["plot", str(est), "--output", str(figure), "--force"]) == 0
    assert figure.stat().st_size > 1000
