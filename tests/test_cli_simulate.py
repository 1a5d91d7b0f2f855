"""``apcc-graph simulate`` and ``apcc-graph bench sequences`` through ``cli.main``."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from apcc_graph.cli import main
from apcc_graph.io.sequence_folder import load_sequence

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
    assert main(args + ["--force"]) == 0  # replaced whole: nothing of the old stays
    assert (out / "frames.csv").exists() and not (out / "keep.txt").exists()


def test_simulate_force_never_replaces_the_recorded_poses(tmp_path: Path, capsys) -> None:
    out = tmp_path / "seq"
    out.mkdir()
    poses = out / "poses.csv"
    poses.write_text("the user's recording\n")  # checked before it is read
    assert main(["simulate", "--robot", ROBOT, "--motion", str(poses), "--out", str(out),
                 "--force"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "holds the input" in err[0] and str(poses) in err[0]
    assert poses.read_text() == "the user's recording\n"


@pytest.mark.parametrize(
    "bad",
    [["--frames", "1"], ["--outliers", "1.5"], ["--noise-px", "-1"], ["--fps", "abc"],
     ["--motion", "wobbly"]],
)
def test_simulate_rejects_bad_options(tmp_path: Path, bad: list[str], capsys) -> None:
    args = ["simulate", "--robot", ROBOT, "--frames", "3", "--out", str(tmp_path / "s")]
    with pytest.raises(SystemExit) as info:
        main(args + bad)
    assert info.value.code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "error" in err[0]


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


def test_simulate_images_then_track_then_estimate(tmp_path: Path, capsys) -> None:
    """The pixel workflow of the README: simulate --images, track, estimate, evaluate."""
    out = tmp_path / "seq"
    code = main(["simulate", "--robot", ROBOT, "--frames", "8", "--out", str(out), "--images",
                 "--texture", "procedural", "--seed", "2", "--supersample", "1"])
    assert code == 0, capsys.readouterr().err
    text = capsys.readouterr().out
    assert "rendered images" in text and f"apcc-graph track {out}" in text
    seq = load_sequence(out)
    assert seq.n_frames == 8 and seq.has_truth
    # The images are the observations: no simulated tracks, one image per frame and camera.
    assert all(len(seq.tracks.get(c, ())) == 0 for c in (0, 1, 2))
    assert {c: sorted(files) for c, files in seq.images.items()} == {
        c: list(range(8)) for c in (0, 1, 2)}
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no staging left
    assert main(["track", str(out)]) == 0
    tracked = load_sequence(out)
    assert all(len(tracked.tracks[c]) > 8 * 100 for c in (0, 1, 2))
    est = tmp_path / "est"
    theta0 = ",".join(f"{v:.6f}" for v in np.degrees(seq.thetas[0]))
    assert main(["estimate", str(out), "--method", "smoother", "--out", str(est),
                 f"--theta0-deg={theta0}"]) == 0
    capsys.readouterr()
    assert main(["evaluate", str(est), "--truth", str(out)]) == 0
    assert "RMS" in capsys.readouterr().out


def test_simulate_images_is_deterministic(tmp_path: Path) -> None:
    args = ["simulate", "--robot", ROBOT, "--frames", "2", "--images", "--texture",
            "procedural", "--seed", "4", "--image-noise", "3", "--blur", "0.5",
            "--exposure", "0.1"]
    assert main(args + ["--out", str(tmp_path / "a")]) == 0
    assert main(args + ["--out", str(tmp_path / "b")]) == 0
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*.png"))
    assert len(files) == 6
    for name in files:
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


@pytest.mark.parametrize("bad, message", [
    (["--images", "--scene", "points"], "--scene room"),
    (["--texture", "procedural"], "--texture applies to --images only"),
    (["--blur", "1"], "--blur applies to --images only"),
])
def test_simulate_images_rejects_bad_options(tmp_path: Path, bad: list[str], message: str,
                                             capsys) -> None:
    out = tmp_path / "s"
    assert main(["simulate", "--robot", ROBOT, "--frames", "3", "--out", str(out)] + bad) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0] and "Traceback" not in err[0]
    assert not out.exists()


@pytest.mark.parametrize("bad", [["--exposure", "1.5"], ["--texture", "marble"],
                                 ["--supersample", "9"], ["--image-noise", "-2"]])
def test_simulate_images_rejects_bad_values(tmp_path: Path, bad: list[str], capsys) -> None:
    out = tmp_path / "s"
    with pytest.raises(SystemExit) as info:
        main(["simulate", "--robot", ROBOT, "--frames", "3", "--out", str(out), "--images"]
             + bad)
    assert info.value.code == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and bad[0] in err[0]
    assert not out.exists()
