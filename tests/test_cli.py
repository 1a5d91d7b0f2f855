"""Tests of the ``apcc-graph`` command line, run in-process through ``cli.main``."""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import numpy as np
import pytest

import apcc_graph
from apcc_graph.cli import main
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.kinematics import apcc_in_plane
from apcc_graph.model.segment import Segment

REPO = Path(__file__).resolve().parents[1]
PAPER_EXAMPLE = "data/calibration/paper_example.toml"


@pytest.fixture(autouse=True)
def _at_repo_root(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(REPO)


def _number(text: str, label: str) -> float:
    """The number after ``label =`` at the start of a line of ``text``."""
    match = re.search(rf"^\s*{re.escape(label)}\s*=\s*(-?\d+(?:\.\d+)?)", text, re.MULTILINE)
    assert match is not None, f"no '{label} =' in:\n{text}"
    return float(match.group(1))


def _residuals(text: str, model: str) -> tuple[float, float]:
    """The RMS tip position (mm) and angle (deg) of ``model``'s residual row."""
    match = re.search(rf"^\s*{model}\s+(-?[\d.]+) mm\s+(-?[\d.]+) deg", text, re.MULTILINE)
    assert match is not None, f"no {model} residual row in:\n{text}"
    return float(match.group(1)), float(match.group(2))


def _write_sweep(path: Path, segment: Segment, thetas_deg: np.ndarray) -> None:
    planar = apcc_in_plane(np.radians(thetas_deg), segment)
    lines = [
        'format = "apcc-graph/calibration@1"',
        f"length = {segment.length!r}",
        f"theta_max_deg = {math.degrees(segment.theta_max)!r}",
    ]
    for px, pz, beta in zip(planar.px, planar.pz, planar.beta, strict=True):
        lines += [
            "",
            "[[poses]]",
            f"tip_x = {float(px)!r}",
            f"tip_z = {float(pz)!r}",
            f"tip_angle_deg = {math.degrees(float(beta))!r}",
        ]
    path.write_text("\n".join(lines) + "\n")


# ----------------------------------------------------------------------------------- calibrate
def test_calibrate_the_paper_example(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["calibrate", PAPER_EXAMPLE]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    assert "1 pose(s)" in out and "closed form" in out
    assert _number(out, "k") == 0.2238
    assert _number(out, "delta_max") == 8.0
    assert _number(out, "theta_max") == 84.0
    assert _number(out, "length") == 0.496
    assert re.search(r"delta_max\s*=\s*8\.000 deg", out)
    assert re.search(r"theta_max\s*=\s*84\.000 deg", out)
    apcc_position, apcc_angle = _residuals(out, "APCC")
    pcc_position, pcc_angle = _residuals(out, "PCC")
    assert apcc_position == 0.0 and apcc_angle == 0.0
    assert pcc_position > 1.0
    assert pcc_angle > 1.0


def test_calibrate_prints_the_robot_toml_entry(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["calibrate", PAPER_EXAMPLE]) == 0
    out = capsys.readouterr().out
    entry = out.split("robot.toml entry:\n", 1)[1]
    assert entry.splitlines()[0].strip() == "[[segments]]"
    assert float(re.search(r"^  k = (\S+)$", entry, re.MULTILINE).group(1)) == pytest.approx(
        0.2238, abs=5e-5
    )
    assert re.search(r"^  delta_max_deg = 8\.0$", entry, re.MULTILINE)
    assert re.search(r"^  theta_max_deg = 84\.0$", entry, re.MULTILINE)


def test_calibrate_writes_a_robot_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    output = tmp_path / "out" / "robot.toml"
    assert main(["calibrate", PAPER_EXAMPLE, "--output", str(output)]) == 0
    out = capsys.readouterr().out
    assert f"wrote {output}" in out
    robot = load_robot(output)
    assert robot.n_segments == 1
    assert robot.cameras == (None,)
    seg = robot.segments[0]
    assert round(seg.k, 4) == _number(out, "k")
    # The full-precision k printed in the entry is the one written to the file.
    assert seg.k == float(re.search(r"^  k = (\S+)$", out, re.MULTILINE).group(1))
    assert math.degrees(seg.delta_max) == pytest.approx(8.0, abs=1e-9)
    assert math.degrees(seg.theta_max) == pytest.approx(84.0, abs=1e-9)
    assert seg.length == 0.496


def test_calibrate_a_sweep_recovers_the_segment(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    known = Segment(0.42, 0.21, math.radians(5.0), math.radians(70.0))
    path = tmp_path / "sweep.toml"
    _write_sweep(path, known, np.linspace(-70.0, 70.0, 15))
    assert main(["calibrate", str(path)]) == 0
    out = capsys.readouterr().out
    assert "15 pose(s)" in out
    assert "least squares" in out
    assert _number(out, "k") == round(known.k, 4)
    assert _number(out, "delta_max") == pytest.approx(5.0, abs=1e-3)
    assert _number(out, "theta_max") == pytest.approx(70.0, abs=1e-3)
    assert "+/-" in out  # several poses: the fit reports uncertainties
    assert _residuals(out, "APCC")[0] < 1e-3
    assert _residuals(out, "PCC")[0] > _residuals(out, "APCC")[0]


# ------------------------------------------------------------------------------ user mistakes
def _write(tmp_path: Path, name: str, text: str) -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _malformed(tmp_path: Path) -> list[str]:
    return ["calibrate", _write(tmp_path, "bad.toml", 'format = "apcc-graph/calibration@1"\nx =\n')]


def _unknown_key(tmp_path: Path) -> list[str]:
    text = (REPO / PAPER_EXAMPLE).read_text(encoding="utf-8").replace("tip_x", "tip_y", 1)
    return ["calibrate", _write(tmp_path, "unknown.toml", text)]


def _output_under_a_file(tmp_path: Path) -> list[str]:
    blocker = _write(tmp_path, "blocker", "")
    return ["calibrate", PAPER_EXAMPLE, "--output", str(Path(blocker) / "robot.toml")]


_MISTAKES = {
    "missing-file": (lambda tmp: ["calibrate", "missing.toml"], "missing.toml"),
    "malformed-toml": (_malformed, "not valid TOML"),
    "unknown-key": (_unknown_key, "poses[0].tip_y"),
    "one-pose-bench": (lambda tmp: ["bench", "calibration", "--poses", "1"], "--poses"),
    "missing-robot": (
        lambda tmp: ["bench", "kinematics", "--robot", "missing.toml"],
        "missing.toml",
    ),
    "zero-frames": (lambda tmp: ["bench", "kinematics", "--frames", "0"], "--frames"),
    "robot-is-a-calibration-file": (
        lambda tmp: ["bench", "kinematics", "--robot", PAPER_EXAMPLE],
        "unknown key",
    ),
    "output-under-a-file": (_output_under_a_file, "blocker"),
    "model-noise-for-the-chain": (
        lambda tmp: ["estimate", "data/sequences/planar_three", "--method", "chain",
                     "--model-sigma", "1,0.5", "--out", str(tmp / "out")],
        "--model-sigma applies to --method batch or smoother",
    ),
}


@pytest.mark.parametrize("name", sorted(_MISTAKES))
def test_user_mistakes_give_one_error_line_and_exit_1(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str
) -> None:
    make, expected = _MISTAKES[name]
    assert main(make(tmp_path)) == 1
    out, err = capsys.readouterr()
    assert out == ""
    assert "Traceback" not in err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("apcc-graph: error:")
    assert expected in lines[0]


@pytest.mark.parametrize(
    "argv",
    [
        ["frobnicate"],
        ["calibrate", PAPER_EXAMPLE, "--bogus"],
        ["calibrate"],
        ["bench", "kinematics", "--frames", "many"],
        [],
        ["estimate", "data/sequences/planar_three", "--method", "magic", "--out", "x"],
        ["bench"],
        ["plot", "x"],
        ["estimate", "data/sequences/planar_three", "--model-sigma", "1", "--out", "x"],
        ["bench", "real", "--model-sigma", "0,0.5"],
    ],
    ids=["unknown-subcommand", "unknown-option", "missing-argument", "bad-int", "no-command",
         "unknown-method", "no-benchmark", "plot-without-output", "model-sigma-one-number",
         "model-sigma-zero"],
)
def test_argparse_mistakes_exit_1_with_one_line(argv: list[str],
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """Usage mistakes end like every other user mistake: one line on stderr, exit code 1."""
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 1
    out, err = capsys.readouterr()
    assert out == ""
    assert "Traceback" not in err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert re.match(r"apcc-graph( \w+)*: error: .+ \(see apcc-graph( \w+)* --help\)$", lines[0])


@pytest.mark.parametrize(
    "argv",
    [
        ["--debug", "calibrate", "missing.toml"],
        ["--debug", "bench", "kinematics", "--robot", "missing.toml"],
    ],
)
def test_debug_raises_instead_of_printing(
    argv: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(ValueError, match="missing.toml: no such file"):
        main(argv)
    assert capsys.readouterr().err == ""


def test_debug_raises_the_user_error(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"poses\[0\]\.tip_y"):
        main(["--debug", *_unknown_key(tmp_path)])


# -------------------------------------------------------------------------------------- bench
def test_bench_calibration(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "calibration", "--poses", "11", "--seed", "1"]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    assert "11 poses" in out and "seed 1" in out
    match = re.search(r"PCC / APCC sweep tip error ratio: (\d+(?:\.\d+)?)x", out)
    assert match is not None, out
    assert float(match.group(1)) > 1.0


def test_bench_kinematics(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["bench", "kinematics", "--frames", "20000", "--repeats", "1"]) == 0
    out, err = capsys.readouterr()
    assert err == ""
    assert "3-segment robot" in out
    for method in (
        "Robot.forward (planar)",
        "Robot.forward (with psi)",
        "peer: joint-by-joint 4x4 matmul",
        "peer: gtsam.Pose3 Python loop",
    ):
        row = re.search(rf"^\s*{re.escape(method)}\s+(\d+)\s+[\d.]+ s", out, re.MULTILINE)
        assert row is not None, f"no row for {method}:\n{out}"
        assert 0 < int(row.group(1)) <= 20000
    match = re.search(r"largest \|difference\| to the peers: (\S+)", out)
    assert match is not None, out
    assert float(match.group(1)) < 1e-12


# ------------------------------------------------------------------------------ entry points
def _console_script() -> str | None:
    """``apcc-graph`` on PATH, else next to this interpreter (an unactivated virtualenv)."""
    found = shutil.which("apcc-graph")
    if found is None:
        found = shutil.which("apcc-graph", path=sysconfig.get_path("scripts"))
    return found


def test_console_script_help() -> None:
    script = _console_script()
    if script is None:
        pytest.skip("the apcc-graph console script is not installed on PATH")
    result = subprocess.run(
        [script, "calibrate", "--help"],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=60,
        env={**os.environ, "PYTHONWARNINGS": "ignore"},
    )
    assert result.returncode == 0, result.stderr
    assert "apcc-graph calibrate data/calibration/paper_example.toml" in result.stdout
    assert "--output" in result.stdout


def test_module_version() -> None:
    result = subprocess.run(
        [sys.executable, "-m", "apcc_graph.cli", "--version"],
        capture_output=True,
        text=True,
        cwd=REPO,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == f"apcc-graph {apcc_graph.__version__}"


def test_version_in_process(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    assert capsys.readouterr().out.strip() == f"apcc-graph {apcc_graph.__version__}"


def test_model_sigma_reaches_the_batch_and_smoother_in_metres_and_radians() -> None:
    from apcc_graph.cli.estimate import _options
    from apcc_graph.cli.main import build_parser

    args = build_parser().parse_args(["estimate", "data/sequences/planar_three",
                                      "--model-sigma", "2,0.5", "--out", "x"])
    graph = _options(args)["graph"]
    assert graph.model_sigma == pytest.approx((2e-3, math.radians(0.5)))
    args = build_parser().parse_args(["estimate", "data/sequences/planar_three", "--method",
                                      "smoother", "--model-sigma", "3,1", "--out", "x"])
    assert _options(args)["graph"].model_sigma == pytest.approx((3e-3, math.radians(1.0)))
    args = build_parser().parse_args(["bench", "real", "--model-sigma", "1.5,0.25"])
    assert args.model_sigma == pytest.approx((1.5e-3, math.radians(0.25)))


@pytest.mark.parametrize("given, expected", [([], "CHOLESKY"), (["--factorization", "QR"], "QR"),
                                             (["--factorization", "CHOLESKY"], "CHOLESKY")])
def test_factorization_reaches_the_smoother(given: list[str], expected: str) -> None:
    from apcc_graph.cli.estimate import _options
    from apcc_graph.cli.main import build_parser

    args = build_parser().parse_args(["estimate", "data/sequences/planar_three", "--method",
                                      "smoother", *given, "--out", "x"])
    assert _options(args)["settings"].window.factorization == expected


def test_keyframes_reach_the_smoother_and_only_it() -> None:
    from apcc_graph.cli.common import UserError
    from apcc_graph.cli.estimate import _options
    from apcc_graph.cli.main import build_parser
    from apcc_graph.estimation.keyframes import KeyframeRule

    parse = build_parser().parse_args
    args = parse(["estimate", "data/sequences/planar_three", "--method", "smoother",
                  "--keyframes", "--out", "x"])
    assert _options(args)["settings"].keyframes == KeyframeRule()
    args = parse(["estimate", "data/sequences/planar_three", "--method", "smoother", "--out",
                  "x"])
    assert _options(args)["settings"].keyframes is None
    args = parse(["estimate", "data/sequences/planar_three", "--keyframes", "--out", "x"])
    with pytest.raises(UserError, match="--keyframes applies to --method smoother only"):
        _options(args)


def test_a_list_option_may_start_with_a_negative_value(
        capsys: pytest.CaptureFixture[str]) -> None:
    """``--theta0-deg -15,3,4`` is the option's value, as ``--theta0-deg=-15,3,4`` is; a
    lone negative number too; something that is neither is still refused as an option."""
    from apcc_graph.cli.main import build_parser

    parser = build_parser()
    args = parser.parse_args(["estimate", "seq", "--out", "o", "--theta0-deg", "-15,3,4",
                              "--spatial", "--psi0-deg", "-.5,2,-90"])
    assert args.theta0_deg == "-15,3,4" and args.psi0_deg == "-.5,2,-90"
    args = parser.parse_args(["calibrate", "x.toml", "--bends-deg", "-80,-40,0"])
    assert args.bends_deg == "-80,-40,0"
    args = parser.parse_args(["estimate", "seq", "--out", "o", "--theta0-sigma-deg", "-2"])
    assert args.theta0_sigma_deg == -2.0  # refused later, by name, as any bad value is
    with pytest.raises(SystemExit):
        parser.parse_args(["estimate", "seq", "--out", "o", "--theta0-deg", "-x,3,4"])
    assert "expected one argument" in capsys.readouterr().err
