"""Implausible inputs, refused or warned about by name: lengths in millimetres where metres are
expected, backbone quaternions written in another order, a camera distortion that cannot be
inverted over the image, a camera that keeps almost nothing of what it sees."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from helpers import one_line_error

from apcc_graph.cli import main
from apcc_graph.io import load_robot, load_sequence

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "data" / "sequences" / "planar_three"


# ------------------------------------------------------------------- cameras that see nothing
def _replace_nth(text: str, old: str, new: str, n: int) -> str:
    parts = text.split(old)
    assert len(parts) > n + 1
    return old.join(parts[:n + 1]) + new + old.join(parts[n + 1:])


@pytest.mark.parametrize("distortion", ["[1e6, -1e6, 0, 0]", "[-0.3, 0.0, 0.0, 0.0]",
                                        "[0.5, -3.0, 0.0, 0.0]"])
def test_a_distortion_that_cannot_be_inverted_is_refused_at_load(
        sample_copy: Path, tmp_path: Path, distortion: str,
        capsys: pytest.CaptureFixture[str]) -> None:
    path = sample_copy / "robot.toml"
    path.write_text(_replace_nth(path.read_text(), "distortion = []",
                                 f"distortion = {distortion}", 1))
    expected = f"{path}: segments[1].camera.distortion: TipCamera.distortion = "
    with pytest.raises(ValueError, match=r"not invertible over the 640x480 image") as info:
        load_robot(path)
    assert str(info.value).startswith(expected)
    assert main(["estimate", str(sample_copy), "--method", "chain",
                 "--out", str(tmp_path / "est")]) == 1
    err = one_line_error(capsys)
    assert expected in err and "several rays" in err
    assert not (tmp_path / "est").exists()


@pytest.mark.parametrize("distortion", [(-0.3, 0.1, 0.0, 0.0), (-0.28, 0.07, 0.001, -0.001,
                                                                 -0.008),
                                        (0.1, 0.01, 0.001, 0.001), (-0.1, 0.0, 0.0, 0.0)])
def test_ordinary_distortions_are_accepted_and_invert(distortion: tuple[float, ...]) -> None:
    from apcc_graph.model.camera import TipCamera

    cam = TipCamera(500.0, 500.0, 320.0, 240.0, 640, 480, distortion)
    grid = np.stack(np.meshgrid(np.linspace(0, 639, 5), np.linspace(0, 479, 5)), -1).reshape(-1, 2)
    back = cam.project(np.column_stack([cam.normalized(grid), np.ones(len(grid))]))
    np.testing.assert_allclose(back, grid, atol=1e-6)


def _sparse_sequence(keep_every: int | None, scramble: bool):  # -> Sequence
    """The sample, camera 2 keeping one track row in ``keep_every`` (or all), its pixels
    scrambled between frames when ``scramble`` (no consistent motion to find)."""
    from apcc_graph.model.sequence import Sequence, Tracks

    seq = load_sequence(SAMPLE).head(60)
    trk = seq.tracks[1]
    rows = np.arange(len(trk)) if keep_every is None else np.arange(0, len(trk), keep_every)
    uv = trk.uv[rows]
    if scramble:
        uv = np.random.default_rng(0).permutation(uv)
    tracks = dict(seq.tracks)
    tracks[1] = Tracks(trk.frames[rows], trk.track_ids[rows], uv)
    return Sequence(seq.robot, seq.timestamps, tracks, world_T_base=seq.world_T_base)


def test_a_camera_with_almost_no_tracks_is_warned_about() -> None:
    import apcc_graph
    from apcc_graph.estimation.methods import ObservationWarning, check_observations

    seq = _sparse_sequence(keep_every=200, scramble=False)
    with pytest.warns(ObservationWarning, match=r"camera cam_2 \(segment 2\) has \d+ "
                      r"observations in 60 frames .*fewer than 5 per frame"):
        check_observations(seq)
    with pytest.warns(ObservationWarning, match="cam_2"):
        apcc_graph.estimate(seq, method="chain", theta0=load_sequence(SAMPLE).thetas[0])


def test_the_chain_warns_when_a_camera_keeps_almost_no_inliers() -> None:
    import warnings

    import apcc_graph
    from apcc_graph.estimation.methods import ObservationWarning

    theta0 = load_sequence(SAMPLE).thetas[0]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        apcc_graph.estimate(_sparse_sequence(None, scramble=False), method="chain",
                            theta0=theta0)
    assert not [w for w in caught if issubclass(w.category, ObservationWarning)]
    with pytest.warns(ObservationWarning, match=r"chain: camera cam_2 \(segment 2\) kept .* "
                      r"correspondences per frame pair, 3% of what its tracks offer "
                      r".*may drift far"):
        apcc_graph.estimate(_sparse_sequence(None, scramble=True), method="chain",
                            theta0=theta0)


def test_a_segment_standing_still_is_not_warned_about() -> None:
    """Frame pairs where a segment did not move (``no-motion``) keep no inliers by nature:
    only the pairs the RANSAC solved are judged."""
    import warnings

    from apcc_graph.estimation.observation_checks import ObservationWarning, warn_few_inliers

    seq = load_sequence(SAMPLE)
    n, s = seq.n_frames, seq.robot.n_segments
    inliers = np.full((n, s), 50, dtype=np.int64)
    inliers[:, 0] = 0
    status = np.full((n, s), "ok", dtype="<U24")
    status[0] = "initial"
    status[:, 0] = "no-motion"
    status[3, 0] = "ok"  # one solved pair of segment 1, with its inliers
    inliers[3, 0] = 60
    with warnings.catch_warnings():
        warnings.simplefilter("error", ObservationWarning)
        warn_few_inliers(seq, inliers, status)
    status[:, 0] = "ok"  # the same zeros where the RANSAC had to solve: warned
    with pytest.warns(ObservationWarning, match=r"chain: camera cam_1 \(segment 1\) kept"):
        warn_few_inliers(seq, inliers, status)


# ---------------------------------------------------------------------------- implausible units
def test_a_robot_file_in_millimetres_is_warned_about_by_key(sample_copy: Path) -> None:
    from apcc_graph.io.units import UnitsWarning

    path = sample_copy / "robot.toml"
    text = path.read_text()
    assert "length = 0.496" not in text
    lengths = [line for line in text.splitlines() if line.startswith("length = ")]
    mm = float(lengths[1].split("=")[1]) * 1000.0
    path.write_text(_replace_nth(text, lengths[1], f"length = {mm!r}", 0
                                 if lengths[0] != lengths[1] else 1))
    with pytest.warns(UnitsWarning, match=rf"^{path}: segments\[1\].length = {mm!r} m: a "
                      r"continuum-robot segment of more than 5 m is implausible; lengths are "
                      rf"in metres \(if this is millimetres, write {mm / 1000:g}\)"):
        robot = load_robot(path)
    assert robot.segments[1].length == mm  # read as written


def test_a_calibration_file_in_millimetres_is_warned_about_once(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import warnings

    from apcc_graph.calibration.files import load_tip_measurements
    from apcc_graph.io.units import UnitsWarning

    source = (ROOT / "data" / "calibration" / "paper_example.toml").read_text()
    mm = tmp_path / "mm.toml"
    mm.write_text(source.replace("length = 0.496", "length = 496")
                  .replace("tip_x = 0.3079719063693426", "tip_x = 307.9719063693426")
                  .replace("tip_z = 0.3420374534295963", "tip_z = 342.0374534295963"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_tip_measurements(mm)
    units = [str(w.message) for w in caught if issubclass(w.category, UnitsWarning)]
    assert units == [f"{mm}: length = 496 m: a continuum-robot segment of more than 5 m is "
                     "implausible; lengths are in metres (if this is millimetres, write 0.496)"]
    only_tips = tmp_path / "tips.toml"
    only_tips.write_text(source.replace("tip_z = 0.3420374534295963", "tip_z = 342.04"))
    with pytest.warns(UnitsWarning, match=rf"^{only_tips}: poses\[0\].tip_z = 342.04 m: a tip "
                      "position of more than 5 m"):
        load_tip_measurements(only_tips)
    assert main(["calibrate", str(mm)]) == 0
    err = capsys.readouterr().err
    assert err.count("apcc-graph: warning: ") == 1 and "length = 496 m" in err
    assert "Traceback" not in err


@pytest.mark.parametrize("recording", ["impulse_2", "slow_free_space"])
def test_backbone_quaternions_written_scalar_last_are_named(tmp_path: Path,
                                                            recording: str) -> None:
    import warnings

    from apcc_graph.io.backbone_poses import load_backbone_poses
    from apcc_graph.io.units import UnitsWarning

    source = ROOT / "data" / "real_tdcr" / recording / "backbone_poses.csv"
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnitsWarning)
        load_backbone_poses(source)  # the shipped order: no warning
    lines = source.read_text().splitlines()
    swapped = [lines[0]]
    for line in lines[1:]:
        f = line.split(",")
        swapped.append(",".join(f[:5] + [f[6], f[7], f[8], f[5]]))  # x, y, z, w
    path = tmp_path / "backbone_poses.csv"
    path.write_text("\n".join(swapped) + "\n")
    with pytest.warns(UnitsWarning, match=rf"^{path}: the quaternion columns qw,qx,qy,qz look "
                      r"written in the order x, y, z, w: .* move the w column first"):
        load_backbone_poses(path)



def test_a_camera_offset_in_millimetres_is_warned_about(sample_copy: Path) -> None:
    from apcc_graph.io.units import UnitsWarning

    path = sample_copy / "robot.toml"
    text = path.read_text()
    start = text.index("translation = [", text.index("[segments.camera.tip_T_cam]"))
    end = text.index("]", start) + 1
    path.write_text(text[:start] + "translation = [0.0, 0.012, 30.0]" + text[end:])
    with pytest.warns(UnitsWarning, match=rf"^{path}: segments\[0\].camera.tip_T_cam."
                      r"translation\[2\] = 30.0 m: an offset of more than 5 m .*write 0.03\)"):
        load_robot(path)
