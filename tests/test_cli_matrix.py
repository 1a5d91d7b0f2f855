"""Every subcommand of ``apcc-graph`` on the shipped data (a smoke matrix), and every user
mistake ending in one line on stderr, exit code 1 and no traceback."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from apcc_graph.cli import main

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "data"
SAMPLE = DATA / "sequences" / "planar_three"
THETA0 = "--theta0-deg=20.466,-15.210,21.277"


@pytest.fixture(scope="module")
def estimate_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("est")
    assert main(["estimate", str(SAMPLE), "--method", "chain", "--out", str(out), THETA0]) == 0
    return out


@pytest.mark.parametrize("argv, expected", [
    (["calibrate", str(DATA / "calibration" / "paper_example.toml")], "k          = 0.22"),
    (["calibrate", str(DATA / "calibration" / "images_sweep")], "pose_04.png"),
    (["simulate", "--robot", str(DATA / "robots" / "planar_three.toml"), "--frames", "5",
      "--out", "{tmp}/sim"], "wrote"),
    (["estimate", str(SAMPLE), "--method", "smoother", "--out", "{tmp}/est", THETA0],
     "theta.csv"),
    (["evaluate", "{est}", "--truth", str(SAMPLE)], "RMS (deg)"),
    (["plot", "{est}", "--truth", str(SAMPLE), "--output", "{tmp}/angles.png"], "wrote"),
    (["plot", "{est}", "--output", "{tmp}/angles.svg"], "wrote"),
    (["bench", "accuracy", "--trials", "2", "--points", "30", "--plot", "{tmp}/fig10.png"],
     "fig10.png"),
    (["bench", "images", "--frames", "10", "--seeds", "1", "--texture", "procedural"],
     "images/s"),
    (["bench", "calibration", "--growth", "1"], "PCC"),
])
def test_every_subcommand_runs_on_the_shipped_data(argv: list[str], expected: str,
                                                    tmp_path: Path, estimate_dir: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    args = [a.format(tmp=tmp_path, est=estimate_dir) for a in argv]
    assert main(args) == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    assert expected in out
    for arg in args:
        if arg.endswith((".png", ".svg")):
            assert Path(arg).stat().st_size > 1000


def test_track_runs_on_rendered_images(tmp_path: Path, capsys) -> None:
    seq = tmp_path / "img"
    assert main(["simulate", "--robot", str(DATA / "robots" / "planar_three.toml"), "--frames",
                 "3", "--out", str(seq), "--images", "--texture", "procedural",
                 "--supersample", "1"]) == 0
    assert main(["track", str(seq)]) == 0
    assert "cam_3.csv" in capsys.readouterr().out


@pytest.mark.parametrize("argv, expected", [
    (["calibrate", "no/such/file.toml"], "no/such/file.toml"),
    (["calibrate", str(REPO / "tests")], "calibration.toml"),
    (["simulate", "--robot", "nope.toml", "--frames", "3", "--out", "{tmp}/s"], "nope.toml"),
    (["track", "{tmp}/nothing"], "nothing"),
    (["estimate", "{tmp}/nothing", "--out", "{tmp}/e"], "nothing"),
    (["estimate", str(SAMPLE), "--out", "{tmp}/e", "--theta0-deg=1,2"], "3 finite angles"),
    (["evaluate", "{tmp}/nothing", "--truth", str(SAMPLE)], "theta.csv"),
    (["evaluate", "{est}", "--truth", "{tmp}/nothing"], "nothing"),
    (["plot", "{tmp}/nothing", "--output", "{tmp}/f.png"], "theta.csv"),
    (["plot", "{est}", "--output", "{tmp}/f.xyz"], "f.xyz"),
    (["plot", "{est}", "--output", "{tmp}/no/dir/f.png"], "does not exist"),
    (["bench", "accuracy", "--trials", "2", "--plot", "{tmp}/f.jpq"], "f.jpq"),
    (["bench", "images", "--seeds", "a,b"], "--seeds"),
    (["estimate", str(SAMPLE), "--method", "magic", "--out", "{tmp}/e"], "magic"),
    (["estimate", str(SAMPLE), "--method", "chain", "--calibrate", "--out", "{tmp}/e"],
     "--calibrate"),
    (["estimate", str(SAMPLE), "--method", "smoother", "--calibrate", "--out", "{tmp}/e"],
     "--method batch"),
    (["estimate", str(SAMPLE), "--rotation-gate", "0.02", "--out", "{tmp}/e"],
     "--method smoother only"),
    (["estimate", str(SAMPLE), "--method", "smoother", "--rotation-gate", "-1", "--out",
      "{tmp}/e"], "positive angle"),
    (["estimate", str(SAMPLE), "--factorization", "QR", "--out", "{tmp}/e"],
     "--method smoother only"),
    (["estimate", str(SAMPLE), "--method", "smoother", "--factorization", "LU", "--out",
      "{tmp}/e"], "LU"),
    (["plot"], "required"),
])
def test_user_mistakes_end_in_one_line_and_exit_1(argv: list[str], expected: str,
                                                  tmp_path: Path, estimate_dir: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    args = [a.format(tmp=tmp_path, est=estimate_dir) for a in argv]
    try:
        code = main(args)
    except SystemExit as exit_:  # argparse's own mistakes
        code = exit_.code
    assert code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "Traceback" not in err[0] and expected in err[0]
    assert not (tmp_path / "e").exists()


def test_evaluate_and_plot_refuse_a_truth_of_another_shape(tmp_path: Path, estimate_dir: Path,
                                                           capsys) -> None:
    short = tmp_path / "short"
    assert main(["simulate", "--robot", str(DATA / "robots" / "planar_three.toml"),
                 "--frames", "7", "--out", str(short)]) == 0
    capsys.readouterr()
    for argv in (["evaluate", str(estimate_dir), "--truth", str(short)],
                 ["plot", str(estimate_dir), "--truth", str(short), "--output",
                  str(tmp_path / "f.png")]):
        assert main(argv) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "beyond the last frame of" in err[0]
        assert "the truth 7 frames" in err[0]
    assert not (tmp_path / "f.png").exists()
    np.testing.assert_equal(sorted(p.name for p in tmp_path.iterdir()), ["short"])


def _subparsers(parser) -> list:  # noqa: ANN001
    import argparse

    out = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                out.append(sub)
                out.extend(_subparsers(sub))
    return out


def test_every_subcommand_has_help_with_an_example() -> None:
    from apcc_graph.cli import build_parser

    subs = _subparsers(build_parser())
    names = {p.prog for p in subs}
    for command in ("simulate", "calibrate", "track", "estimate", "evaluate", "plot", "bench"):
        assert f"apcc-graph {command}" in names
    for sub in subs:
        text = sub.format_help()
        assert "example" in text and "  apcc-graph " in text.split("example")[-1], sub.prog


def test_estimate_calibrate_writes_the_calibrated_robot(tmp_path: Path, capsys) -> None:
    from apcc_graph.io.robot_file import load_robot

    out = tmp_path / "est"
    assert main(["estimate", str(SAMPLE), "--method", "batch", "--calibrate", "--out",
                 str(out), THETA0, "--noise-px", "0.5"]) == 0
    text = capsys.readouterr().out
    assert "robot_calibrated.toml" in text
    lines = [ln for ln in text.splitlines() if ln.startswith("segment ") and "k = " in ln]
    assert len(lines) == 3 and all("+/-" in ln and "delta_max" in ln for ln in lines)
    robot = load_robot(out / "robot_calibrated.toml")
    shipped = load_robot(DATA / "robots" / "planar_three.toml")
    assert robot.n_segments == 3
    # The shipped sample was simulated with the shipped robot: the calibration stays near it.
    for a, b in zip(robot.segments, shipped.segments, strict=True):
        assert abs(a.k - b.k) < 0.05 and abs(a.delta_max - b.delta_max) < 0.05
        assert a.length == b.length
    # By default the mounts are calibrated too, and reported with what the images leave open.
    mounts = [ln for ln in text.splitlines() if ln.startswith("camera on segment ")]
    assert len(mounts) == 3 and all("+/-" in ln for ln in mounts)
    assert "the images do not tell its translation y" in text  # a planar robot's blind axis
    assert "RMS angle sigma with the calibration" in text


def test_estimate_calibrate_mounts_keeps_the_models(tmp_path: Path, capsys) -> None:
    from apcc_graph.estimation.model_calibration import mount_error
    from apcc_graph.io.robot_file import load_robot

    out = tmp_path / "est"
    assert main(["estimate", str(SAMPLE), "--method", "batch", "--calibrate", "mounts",
                 "--out", str(out), THETA0]) == 0
    text = capsys.readouterr().out
    assert "k = " not in text and text.count("camera on segment ") == 3
    robot = load_robot(out / "robot_calibrated.toml")
    shipped = load_robot(DATA / "robots" / "planar_three.toml")
    assert robot.segments == shipped.segments
    moved = [mount_error(a.tip_T_cam, b.tip_T_cam)
             for a, b in zip(robot.cameras, shipped.cameras, strict=True)]
    # Simulated with the shipped mounts: they stay within a degree and a few mm, but move.
    assert all(rot < math.radians(1.0) and pos < 0.005 for rot, pos in moved), moved
    assert any(rot > 0.0 for rot, _ in moved)
