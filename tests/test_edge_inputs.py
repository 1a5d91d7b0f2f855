"""Inputs at the edges a new user meets: byte-order marks, huge files, estimates and truths that
do not match frame for frame, options that are not numbers. Each is read, refused or warned
about by name (no traceback, no silent nonsense). Implausible values (units, quaternion order,
distortions, cameras that see almost nothing): tests/test_implausible_inputs.py."""

from __future__ import annotations

import codecs
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from helpers import one_line_error

from apcc_graph.cli import main
from apcc_graph.io import load_robot, load_sequence
from apcc_graph.io.csv_table import read_table
from apcc_graph.io.text_files import MAX_LINE_BYTES

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "data" / "sequences" / "planar_three"


# ----------------------------------------------------------------------------- byte-order marks
@pytest.mark.parametrize("name", ["frames.csv", "tracks/cam_1.csv", "robot.toml"])
def test_a_utf8_byte_order_mark_is_read(sample_copy: Path, name: str) -> None:
    path = sample_copy / name
    path.write_bytes(codecs.BOM_UTF8 + path.read_bytes())
    seq = load_sequence(sample_copy)
    ref = load_sequence(SAMPLE)
    assert np.array_equal(seq.timestamps, ref.timestamps)
    assert np.array_equal(seq.tracks[0].uv, ref.tracks[0].uv)
    assert seq.robot == ref.robot


@pytest.mark.parametrize(("codec", "name"), [("utf-16", "UTF-16"), ("utf-32", "UTF-32")])
@pytest.mark.parametrize("file", ["frames.csv", "robot.toml"])
def test_another_encodings_byte_order_mark_is_named(sample_copy: Path, codec: str, name: str,
                                                    file: str) -> None:
    path = sample_copy / file
    path.write_bytes(path.read_text(encoding="utf-8").encode(codec))  # Python writes the BOM
    with pytest.raises(ValueError, match=rf"^{path}: the file is {name} .*expected UTF-8"):
        load_sequence(sample_copy)


def test_cli_names_a_utf16_frames_file(sample_copy: Path, tmp_path: Path,
                                       capsys: pytest.CaptureFixture[str]) -> None:
    path = sample_copy / "frames.csv"
    path.write_bytes(path.read_text(encoding="utf-8").encode("utf-16"))
    assert main(["estimate", str(sample_copy), "--method", "chain",
                 "--out", str(tmp_path / "est")]) == 1
    assert f"{path}: the file is UTF-16 (little-endian) text" in one_line_error(capsys)
    assert not (tmp_path / "est").exists()


def test_a_byte_order_mark_in_theta_csv_and_backbone_poses_is_read(tmp_path: Path) -> None:
    from apcc_graph.io.backbone_poses import load_backbone_poses
    from apcc_graph.io.estimates import load_theta_table

    theta = tmp_path / "theta.csv"
    theta.write_bytes(codecs.BOM_UTF8 + b"frame,timestamp,theta_1,sigma_1\n0,0.0,0.1,nan\n")
    assert load_theta_table(theta).thetas.tolist() == [[0.1]]
    source = ROOT / "data" / "real_tdcr" / "slow_free_space" / "backbone_poses.csv"
    poses = tmp_path / "backbone_poses.csv"
    poses.write_bytes(codecs.BOM_UTF8 + source.read_bytes())
    assert np.array_equal(load_backbone_poses(poses).arclengths,
                          load_backbone_poses(source).arclengths)


# ------------------------------------------------------------------------------------ huge files
def _long_line_file(path: Path, megabytes: int, newline_at: int | None = None) -> None:
    """A header and then ``megabytes`` MB of digits and commas with no line break (or one after
    ``newline_at`` bytes)."""
    block = b"1234567," * (1 << 17)  # 1 MB
    with path.open("wb") as fh:
        fh.write(b"frame,track_id,u,v\n")
        if newline_at is not None:
            fh.write(b"0,1,2.0,3.0\n" * (newline_at // 12))
        for _ in range(megabytes):
            fh.write(block)


@pytest.mark.parametrize("rows_before", [None, 300_000])
def test_a_huge_line_is_refused_with_bounded_memory_and_message(tmp_path: Path,
                                                                rows_before: int | None) -> None:
    path = tmp_path / "cam_1.csv"
    _long_line_file(path, 40, rows_before)
    line = 2 if rows_before is None else 2 + rows_before // 12
    tracemalloc.start()
    try:
        with pytest.raises(ValueError) as info:
            read_table(path, ["frame", "track_id", "u", "v"])
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    message = str(info.value)
    assert message.startswith(f"{path}: line {line}: longer than {MAX_LINE_BYTES} bytes "
                              "(starts '1234567,1234567,")
    assert len(message) < len(str(path)) + 200
    assert peak < 8 * (1 << 20), f"peak {peak / 2**20:.1f} MB for a 40 MB line"


def test_a_huge_header_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "frames.csv"
    path.write_bytes(b"frame," * 20_000)
    with pytest.raises(ValueError, match=rf"^{path}: line 1: longer than {MAX_LINE_BYTES} bytes "
                       r"\(starts 'frame,frame,.{40,60}'\.\.\.\)"):
        read_table(path, ["frame", "timestamp"])


def test_a_long_field_is_quoted_short(tmp_path: Path) -> None:
    path = tmp_path / "cam_1.csv"
    path.write_text("frame,track_id,u,v\n0,1,2," + "x" * 5000 + "\n")
    with pytest.raises(ValueError) as info:
        read_table(path, ["frame", "track_id", "u", "v"])
    assert str(info.value) == (f"{path}: line 2, column 'v': '{'x' * 60}'... is not a number")


def test_a_huge_toml_file_is_refused_unread(tmp_path: Path) -> None:
    path = tmp_path / "robot.toml"
    with path.open("wb") as fh:
        fh.write(b"# " + b"x" * (17 << 20) + b"\n")
    with pytest.raises(ValueError, match=rf"^{path}: larger than 16 MB; expected a TOML file"):
        load_robot(path)


def test_cli_refuses_a_huge_tracks_line_in_one_short_line(
        sample_copy: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = sample_copy / "tracks" / "cam_2.csv"
    _long_line_file(path, 4)
    assert main(["estimate", str(sample_copy), "--method", "chain",
                 "--out", str(tmp_path / "est")]) == 1
    err = one_line_error(capsys)
    assert f"{path}: line 2: longer than" in err and len(err) < len(str(path)) + 250


# ---------------------------------------------------------------------------- option values
@pytest.mark.parametrize("command", ["track", "live"])
@pytest.mark.parametrize("value", ["-1", "nan", "inf", "-0.5", "soon"])
def test_sync_tolerance_is_checked_when_parsed(tmp_path: Path, command: str, value: str,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    argv = [command, str(SAMPLE), f"--sync-tolerance={value}", "--out", str(tmp_path / "o")]
    with pytest.raises(SystemExit) as stop:  # argparse's own mistakes
        main(argv)
    assert stop.value.code == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith(f"apcc-graph {command}: error: ")
    assert f"argument --sync-tolerance: '{value}'" in err
    assert ("expected a number >= 0" in err) or ("is not a number" in err)
    assert not (tmp_path / "o").exists()


_NAN, _INF = float("nan"), float("inf")


@pytest.mark.parametrize(("keywords", "error", "message"), [
    ({"noise_px": _NAN}, ValueError, "noise_px = nan: expected a finite number > 0 (pixels)"),
    ({"noise_px": _INF}, ValueError, "noise_px = inf: expected a finite number > 0 (pixels)"),
    ({"noise_px": -1.0}, ValueError, "noise_px = -1.0: expected a finite number > 0 (pixels)"),
    ({"noise_px": 0}, ValueError, "noise_px = 0: expected a finite number > 0 (pixels)"),
    ({"noise_px": "1"}, TypeError, "noise_px = '1': expected a number (pixels), got str"),
    ({"noise_px": True}, TypeError, "noise_px = True: expected a number (pixels), got bool"),
    ({"theta0_sigma": _NAN}, ValueError, "theta0_sigma = nan: expected a finite number > 0 "
     "(radians)"),
    ({"theta0_sigma": -0.1}, ValueError, "theta0_sigma = -0.1: expected a finite number > 0"),
    ({"theta0_sigma": _INF}, ValueError, "theta0_sigma = inf: expected a finite number > 0"),
    ({"theta0_sigma": "0.1"}, TypeError, "theta0_sigma = '0.1': expected a number (radians)"),
    ({"spatial": "yes"}, TypeError, "spatial = 'yes': expected True or False"),
    ({"progress": "no"}, TypeError, "progress = 'no': expected True or False"),
    ({"method": "Chain"}, ValueError, "method = 'Chain': expected one of chain, batch"),
    ({"theta0": [0.1, _NAN, 0.0]}, ValueError, "theta0[1] = nan: expected a finite angle"),
    ({"theta0": [0.1, 0.1, _INF]}, ValueError, "theta0[2] = inf: expected a finite angle"),
    ({"spatial": True, "psi0": [_NAN, 0.0, 0.0]}, ValueError, "psi0[0] = nan: expected a "
     "finite angle"),
])
def test_estimate_names_each_keyword_as_written(keywords: dict, error: type[Exception],
                                                message: str) -> None:
    import apcc_graph

    sample = load_sequence(SAMPLE)
    args = {"method": "chain", "theta0": sample.thetas[0], **keywords}
    with pytest.raises(error) as info:
        apcc_graph.estimate(sample, **args)
    assert str(info.value).startswith(message), str(info.value)
    assert "GraphOptions" not in str(info.value)


@pytest.mark.parametrize("value", ["nan", "-1", "0", "inf"])
def test_cli_names_noise_px_as_the_flag(tmp_path: Path, value: str,
                                        capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["estimate", str(SAMPLE), "--method", "chain", f"--noise-px={value}",
                 "--out", str(tmp_path / "est")]) == 1
    err = one_line_error(capsys)
    assert "--noise-px" in err and "GraphOptions" not in err and "noise_px" not in err


# ------------------------------------------------------------- estimates against their truth
def _theta_file(folder: Path, frames: list[int], offset: float = 0.0,
                times: np.ndarray | None = None) -> Path:
    """A theta.csv of the sample's true angles (plus ``offset`` rad) at ``frames``."""
    truth = load_sequence(SAMPLE)
    ts = truth.timestamps if times is None else times
    folder.mkdir(parents=True, exist_ok=True)
    lines = ["frame,timestamp,theta_1,theta_2,theta_3,sigma_1,sigma_2,sigma_3"]
    for f in frames:
        values = [*(truth.thetas[f] + offset).tolist(), 0.01, 0.01, 0.01]
        lines.append(f"{f},{float(ts[f])!r}," + ",".join(repr(v) for v in values))
    (folder / "theta.csv").write_text("\n".join(lines) + "\n")
    return folder


def test_theta_csv_with_skipped_frames_is_read(tmp_path: Path) -> None:
    from apcc_graph.io.estimates import load_theta_table

    est = _theta_file(tmp_path / "est", [0, 1, 5, 6, 9])
    table = load_theta_table(est / "theta.csv")
    assert table.frames.tolist() == [0, 1, 5, 6, 9]
    assert table.frame_numbers().tolist() == [0, 1, 5, 6, 9]


@pytest.mark.parametrize(("frames", "line", "message"), [
    ([0, 1, 1, 2], 4, "frame 1 after frame 1; expected strictly increasing frame numbers"),
    ([0, 3, 2], 4, "frame 2 after frame 3; expected strictly increasing"),
])
def test_theta_csv_frames_must_increase(tmp_path: Path, frames: list[int], line: int,
                                        message: str) -> None:
    from apcc_graph.io.estimates import load_theta_table

    est = _theta_file(tmp_path / "est", frames)
    with pytest.raises(ValueError, match=rf"theta.csv: line {line}, column 'frame': {message}"):
        load_theta_table(est / "theta.csv")


def test_evaluate_and_plot_read_an_estimate_with_gaps(tmp_path: Path,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    kept = [0, 1] + list(range(5, 200, 2))
    est = _theta_file(tmp_path / "est", kept, offset=np.radians(0.5))
    assert main(["evaluate", str(est), "--truth", str(SAMPLE), "--window", "50"]) == 0
    out = capsys.readouterr().out
    assert f"compared on the {len(kept)} frames the estimate has, of the truth's 200" in out
    rms = [float(v) for v in out.splitlines()[2].split()[2:]]
    np.testing.assert_allclose(rms, 0.5, atol=1e-4)  # every row against its own frame
    assert "frames      0-99" in out  # window labels are the estimate's frame numbers
    assert main(["plot", str(est), "--truth", str(SAMPLE), "--output",
                 str(tmp_path / "f.png")]) == 0
    assert (tmp_path / "f.png").stat().st_size > 0


def test_evaluate_refuses_a_truth_at_another_frame_rate(tmp_path: Path,
                                                        capsys: pytest.CaptureFixture[str]
                                                        ) -> None:
    truth = load_sequence(SAMPLE)
    est = _theta_file(tmp_path / "est", list(range(truth.n_frames)),
                      times=truth.timestamps / 2)
    for argv in (["evaluate", str(est), "--truth", str(SAMPLE)],
                 ["plot", str(est), "--truth", str(SAMPLE), "--output", str(tmp_path / "f.png")]):
        assert main(argv) == 1
        err = one_line_error(capsys)
        assert f"{est / 'theta.csv'}: line 3: frame 1 is at" in err
        assert f"but {SAMPLE / 'frames.csv'} has frame 1 at {float(truth.timestamps[1])!r} s" in err
        assert "another frame rate" in err
    assert not (tmp_path / "f.png").exists()


def test_match_frames_matches_by_number_and_time() -> None:
    from apcc_graph.evaluation.frame_match import match_frames

    truth = np.arange(10) / 30.0
    match = match_frames([0, 2, 7], truth[[0, 2, 7]], truth, "e", "t")
    assert match.frames.tolist() == [0, 2, 7] and not match.complete
    with pytest.raises(ValueError, match=r"^e: line 3: frame 3 is at"):
        match_frames([0, 3], truth[[0, 2]], truth, "e", "t")  # frame 3 labelled at frame 2's time
    with pytest.raises(ValueError, match=r"^e: line 2: frame 12 is beyond the last frame of t"):
        match_frames([12], [0.4], truth, "e", "t")


def _reference_scan(raw: bytes) -> tuple[bool, int | None]:
    """What ``_scan_lines`` must answer, the simple way: whether a non-blank line follows the
    header, and the first blank line (empty or a lone CR) that a non-blank line follows."""
    lines = raw.split(b"\n")
    blank = [line in (b"", b"\r") for line in lines]
    full = [n + 1 for n, b in enumerate(blank) if not b]
    last = max(full, default=0)
    first_blank = next((n + 1 for n, b in enumerate(blank) if b and n > 0), None)
    return last > 1, first_blank if first_blank is not None and first_blank < last else None


@pytest.mark.parametrize("chunk", [1, 2, 3, 7, 1 << 20])
def test_the_chunked_scan_finds_rows_and_blank_lines_across_chunk_borders(
        tmp_path: Path, chunk: int, monkeypatch: pytest.MonkeyPatch) -> None:
    from apcc_graph.io import csv_table

    monkeypatch.setattr(csv_table, "_CHUNK", chunk)
    rng = np.random.default_rng(chunk)
    pieces = [b"1,2", b"", b"\r", b"3,4\r", b" ", b"5"]
    for case in range(60):
        body = b"\n".join(pieces[i] for i in rng.integers(0, len(pieces), rng.integers(0, 6)))
        raw = b"a,b\n" + body + (b"\n" if case % 2 else b"")
        path = tmp_path / f"{case}.csv"
        path.write_bytes(raw)
        assert csv_table._scan_lines(path) == _reference_scan(raw), raw


def test_evaluate_compares_measured_tips_on_the_frames_an_estimate_has(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    from apcc_graph.io import save_sequence
    from apcc_graph.model.sequence import Sequence

    full = load_sequence(SAMPLE).head(40)
    tips = full.robot.forward(full.thetas, None, full.world_T_base)
    truth = tmp_path / "truth"
    save_sequence(Sequence(full.robot, full.timestamps, full.tracks, full.world_T_base,
                           truth_tips=tips), truth)
    kept = [0, 1, 5, 6, 20, 39]
    est = _theta_file(tmp_path / "est", kept)
    assert main(["evaluate", str(est), "--truth", str(truth)]) == 0
    out = capsys.readouterr().out
    assert "compared on the 6 frames the estimate has, of the truth's 40 (15.0%)" in out
    assert "RMS over 6 frames" in out
    rows = [line.split() for line in out.splitlines() if line.strip()[:1] in "123"]
    assert len(rows) == 3 and all(float(r[1]) < 1e-6 for r in rows)  # each row on its own tip


