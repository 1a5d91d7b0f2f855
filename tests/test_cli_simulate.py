"""``apcc-graph simulate`` and ``apcc-graph bench sequences`` through ``cli.main``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from apcc_graph.cli import main
from apcc_graph.io import load_sequence

REPO = Path(__file__).resolve().parents[1]
ROBOT = str(REPO / "data/robots/planar_three.toml")


def test_simulate_writes_a_loadable_sequence(tmp_path: Path, capsys) -> None:
    out = tmp_path / "seq"
    code = main(["simulate", "--robot", ROBOT, "--frames", "12", "--out", str(out),
                 "--noise-px", "0.3", "--outliers", "0.1", "--seed", "3", "--moving-base"])
    assert code == 0
    text = capsys.readouterr().out
    assert "wrote" in text and "cam_3" in text
    seq = load_sequence(out)
    assert seq.n_frames == 12 and seq.has_truth and seq.world_T_base is not None
    assert set(seq.cameras) == {0, 1, 2}
    np.testing.assert_allclose(np.diff(seq.timestamps), 1 / 30.0)


def test_simulate_refuses_a_non_empty_folder_unless_forced(tmp_path: Path, capsys) -> None:
    out = tmp_path / "seq"
    out.mkdir()
    (out / "keep.txt").write_text("user data")
    args = ["simulate", "--robot", ROBOT, "--frames", "3", "--out", str(out)]
    assert main(args) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "not empty" in err[0] and "Traceback" not in err[0]
    assert (out / "keep.txt").read_text() == "user data"
    assert not (out / "frames.csv").exists()
    assert main(args + ["--force"]) == 0
    assert (out / "frames.csv").exists() and (out / "keep.txt").exists()


@pytest.mark.parametrize(
    "bad",
    [["--frames", "1"], ["--outliers", "1.5"], ["--noise-px", "-1"], ["--fps", "abc"],
     ["--motion", "wobbly"]],
)
def test_simulate_rejects_bad_options(tmp_path: Path, bad: list[str], capsys) -> None:
    args = ["simulate", "--robot", ROBOT, "--frames", "3", "--out", str(tmp_path / "s")]
    with pytest.raises(SystemExit) as info:
        main(args + bad)
    assert info.value.code == 2
    assert "error" in capsys.readouterr().err


def test_simulate_with_a_broken_robot_file(tmp_path: Path, capsys) -> None:
    robot = tmp_path / "robot.toml"
    robot.write_text('format = "apcc-graph/robot@1"\n[[segments]]\nlength = -1\n')
    code = main(["simulate", "--robot", str(robot), "--frames", "3", "--out",
                 str(tmp_path / "s")])
    assert code == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("apcc-graph: error:") and "robot.toml" in err


def test_bench_sequences_small_run(capsys) -> None:
    code = main(["bench", "sequences", "--robot", ROBOT, "--frames", "20", "--rows", "20000",
                 "--repeats", "1"])
    assert code == 0
    text = capsys.readouterr().out
    for label in ("simulate", "save_sequence", "load_sequence", "numpy.loadtxt", "csv module"):
        assert label in text
    assert "per million track rows" in text
