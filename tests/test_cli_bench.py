"""Smoke runs of ``apcc-graph bench solver`` and ``bench accuracy`` (figures, not timings)."""

from __future__ import annotations

import re

import numpy as np

from apcc_graph.cli import main


def test_bench_solver_small_run(capsys) -> None:
    assert main(["bench", "solver", "--trials", "2", "--seed", "1"]) == 0
    text = capsys.readouterr().out
    for method in ("one_point_ransac", "cv2 RANSAC + recoverPose", "cv2 USAC_DEFAULT"):
        assert text.count(method) == 6  # N = 200, 1000 x 0 / 30 / 50 % outliers
    assert re.search(r"minimal solver: [\d.]+ us per correspondence", text)
    # Our rows are the reference: ratio 1.0x in time and error.
    ours = [line for line in text.splitlines() if line.strip().startswith("one_point_ransac")]
    assert all("1.0x" in line and "1.00x" in line for line in ours)


def test_bench_accuracy_small_run(capsys) -> None:
    assert main(["bench", "accuracy", "--trials", "4", "--points", "60"]) == 0
    text = capsys.readouterr().out
    rows = [line.split() for line in text.splitlines() if line.strip().startswith(("fixed",
                                                                                  "moving"))]
    assert len(rows) == 10
    # Noise-free trials are exact; noisy ones have a finite efficiency figure.
    assert all(float(r[2]) < 1e-6 for r in rows if r[1] == "0.0px")
    assert all(r[-2] != "-" for r in rows if r[1] != "0.0px")


def test_bench_smoother_small_run(capsys) -> None:
    assert main(["bench", "smoother", "--frames", "40", "--seeds", "3", "--methods",
                 "chain,batch", "--long-frames", "0", "--memory-frames", "0"]) == 0
    lines = capsys.readouterr().out.splitlines()
    rows = {}
    for ln in lines:
        m = re.match(r"\s+(\d+)% outliers\s+3\s+(chain|batch)\s+(.*)", ln)
        if m:
            rows[m.group(1), m.group(2)] = [float(v) for v in m.group(3).split()]
    assert set(rows) == {("10", "chain"), ("10", "batch"), ("30", "chain"), ("30", "batch")}
    for cells in rows.values():
        rms, bound, ratio = cells[0:3], cells[3:6], cells[6:9]
        assert all(v > 0 for v in rms + bound)
        # The ratio column is the RMS over the bound of the same sequence (rounded values).
        for r, b, q in zip(rms, bound, ratio, strict=True):
            assert abs(r / b - q) < 0.006 + 0.0006 * r / b**2
    for rate in ("10", "30"):
        # The bound is the same for every method of a sequence; the batch beats the chain.
        assert rows[rate, "chain"][3:6] == rows[rate, "batch"][3:6]
        assert sum(rows[rate, "batch"][:3]) < sum(rows[rate, "chain"][:3])
    summary = [ln for ln in lines if re.match(r"\s+\d+% outliers\s+batch\s+[\d.]", ln)]
    assert len(summary) == 2 and all(len(ln.split()) == 2 + 1 + 12 for ln in summary)
    assert any("30% outliers / 10% outliers" in ln for ln in lines)
    assert main(["bench", "smoother", "--methods", "chain,kalman"]) == 1
    assert main(["bench", "smoother", "--long-frames", "100"]) == 1


def test_bench_tracking_small_run(capsys) -> None:
    assert main(["bench", "tracking", "--frames", "12", "--seed", "2"]) == 0
    text = capsys.readouterr().out
    rows = {ln.split("  ")[1].strip(): ln.split()[-5:] for ln in text.splitlines()
            if ln.startswith("  KLT") or ln.startswith("  ORB")}
    klt, orb = rows["KLT (ours)"], rows["ORB + BFMatcher (cross-check)"]
    # The homographies are known exactly: KLT's correspondences follow them to a tenth of a
    # pixel (measured 0.025 median); ORB's keypoints are coarser (measured 0.8).
    images_per_s, pairs, median, p95 = (float(v) for v in klt[:4])
    assert median < 0.1 and p95 < 0.5
    assert float(orb[2]) > median
    assert pairs > 100 and images_per_s > 0
    assert "x the images per second" in text
    assert main(["bench", "tracking", "--noise", "-1"]) == 1


def test_bench_smoother_prints_the_lag_bound_for_the_smoother(capsys) -> None:
    assert main(["bench", "smoother", "--frames", "60", "--seeds", "1", "--outliers", "0.1",
                 "--methods", "smoother", "--long-frames", "0", "--memory-frames", "0"]) == 0
    out = capsys.readouterr().out
    assert "bound of a 1 s fixed lag" in out
    row = [ln for ln in out.splitlines()
           if re.match(r"\s+10% outliers\s+smoother\s+[\d.]", ln)]
    assert len(row) == 2  # the summary row and the lag-bound row
    assert "30% outliers" not in out
    assert main(["bench", "smoother", "--outliers", "0.1,1.5"]) == 1


def test_bench_smoother_prints_keyframes_beside_every_frame(capsys) -> None:
    """The keyframe row's ratios are the per-seed rows' RMS over each other (rounded)."""
    assert main(["bench", "smoother", "--frames", "60", "--seeds", "2", "--outliers", "0.1",
                 "--methods", "smoother,smoother-keyframes", "--long-frames", "0",
                 "--memory-frames", "0"]) == 0
    lines = capsys.readouterr().out.splitlines()
    rms = {}
    for ln in lines:
        m = re.match(r"\s+10% outliers\s+2\s+(smoother|smoother-keyframes)\s+(.*)", ln)
        if m:
            rms[m.group(1)] = np.array([float(v) for v in m.group(2).split()[:3]])
    assert set(rms) == {"smoother", "smoother-keyframes"}
    at = next(i for i, ln in enumerate(lines) if ln.startswith("smoother-keyframes / smoother"))
    cells = [float(v) for v in lines[at + 1].split()[2:]]
    median, worst, seconds = cells[:3], cells[3:6], cells[6]
    assert median == worst  # one seed
    ratio = rms["smoother-keyframes"] / rms["smoother"]
    assert np.allclose(median, ratio, atol=0.01 + 0.001 * ratio / rms["smoother"]), (median, ratio)
    assert 0.0 < seconds < 1.5


def test_bench_selfcal_small_run(capsys) -> None:
    assert main(["bench", "selfcal", "--frames", "40", "--seeds", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    row = next(ln for ln in lines if re.match(r"\s+1\s+[\d.]+", ln))
    cells = [float(v) for v in row.split()[1:]]
    true, wrong, cal, known, unknown = (cells[3 * i:3 * i + 3] for i in range(5))
    # Wrong models cost more than calibrating them away; the unknown-model bound is above the
    # known-model one.
    assert sum(wrong) > sum(cal) and sum(wrong) > sum(true)
    assert all(u >= k for u, k in zip(unknown, known, strict=True))
    found = [ln for ln in lines if ln.strip().startswith("seed 1 segment")]
    assert len(found) == 3 and all("+/-" in ln for ln in found)
    assert main(["bench", "selfcal", "--outliers", "1.5"]) == 1


def test_bench_mounts_small_run(capsys) -> None:
    assert main(["bench", "mounts", "--frames", "60", "--seeds", "1"]) == 0
    lines = capsys.readouterr().out.splitlines()
    row = next(ln for ln in lines if re.match(r"\s+1\s+[\d.]+", ln))
    cells = [float(v) for v in row.split()[1:]]
    true, wrong, mounts, _, known, unknown, _ = (cells[3 * i:3 * i + 3] for i in range(7))
    # Wrong mounts cost more than calibrating them away; unknown mounts bound above known.
    assert sum(wrong) > sum(mounts) and sum(wrong) > sum(true)
    assert all(u >= k for u, k in zip(unknown, known, strict=True))
    found = [ln for ln in lines if ln.strip().startswith("seed 1 camera")]
    assert len(found) == 3 and all(ln.count("[") == 6 for ln in found)
    assert any("reported sigma / bound" in ln for ln in lines)
    assert main(["bench", "mounts", "--outliers", "1.5"]) == 1


def test_bench_spatial_solver_small_run(capsys) -> None:
    assert main(["bench", "spatial-solver", "--cases", "30", "--trials", "3", "--seed", "2"]) == 0
    text = capsys.readouterr().out
    found, cases = (int(v) for v in re.search(r"true bend among the roots in (\d+) of (\d+)",
                                               text).groups())
    assert cases == 30 and found >= 29
    rows = {}
    for method in ("two_point_ransac", "cv2.findEssentialMat RANSAC", "cv2 RANSAC + recoverPose"):
        line = next(ln for ln in text.splitlines() if ln.strip().startswith(method))
        cells = re.search(r"([\d.]+) ms\s+(\S+)(?: deg)?\s+([\d.]+)x\s+(\d+)\s+(\S+)$", line)
        rows[method] = cells.groups()
    ours = rows["two_point_ransac"]
    assert ours[2] == "1.0" and float(ours[0]) > 0.0
    # Noise of 0.5 px: ours is within a degree of the truth; OpenCV's error is a number (its
    # twisted-pair flips are counted in the last column).
    assert float(ours[1]) < 1.0 and ours[4] == "0"
    assert float(rows["cv2 RANSAC + recoverPose"][1]) >= 0.0
    assert re.search(r"speed: cv2.findEssentialMat / two_point_ransac = [\d.]+x", text)
    assert re.search(r"minimal solver: median \d+ us per two_point call \(30 calls\)", text)


def test_bench_spatial_small_run(capsys) -> None:
    assert main(["bench", "spatial", "--frames", "45", "--seeds", "3", "--outliers", "0"]) == 0
    text = capsys.readouterr().out
    lines = text.splitlines()

    def row(label: str, after: str) -> list[float]:
        start = next(i for i, ln in enumerate(lines) if ln.startswith(after))
        line = next(ln for ln in lines[start:] if ln.strip().startswith(label))
        return [float(v) for v in line.split()[-3:]]

    bound = row("bound, RMS over frames", "spatial robot")
    assert all(0.0 < b < 1.0 for b in bound)  # degrees
    chain = row("RMS / bound, median", "chain")
    batch = row("RMS / bound, median", "batch")
    assert max(batch) < 2.0 and max(chain) > max(batch)
    honest = row("mean (error / sigma)^2", "batch")
    assert all(0.05 < v < 5.0 for v in honest)
    assert re.search(r"batch: every seed and segment within 2x of the bound: (yes|NO)", text)
    smoother = row("RMS / bound, median", "smoother")
    assert max(smoother) < 3.0 and max(chain) > max(smoother)
    assert re.search(r"smoother: every seed and segment within 3x of the bound: (yes|NO)", text)
    assert main(["bench", "spatial", "--methods", "kalman"]) == 1
    assert main(["bench", "spatial", "--outliers", "1.5"]) == 1


def test_young_share_counts_each_tracks_second_and_third_observation() -> None:
    from apcc_graph import Robot, Segment, TipCamera
    from apcc_graph.bench.young_tracks import young_share
    from apcc_graph.model.sequence import Sequence, Tracks

    camera = TipCamera(500.0, 500.0, 320.0, 240.0, 640, 480)
    robot = Robot([Segment(0.3)], [camera])
    # Track 7 seen in frames 0-4 (rows 2, 3 young), track 8 in frames 3-4 (row 2 young),
    # track 9 in frame 4 only: 3 young of 8 observations.
    frames = [0, 1, 2, 3, 3, 4, 4, 4]
    ids = [7, 7, 7, 7, 8, 7, 8, 9]
    tracks = Tracks(frames, ids, np.full((8, 2), 100.0))
    seq = Sequence(robot, np.arange(5) / 30.0, {0: tracks})
    assert young_share(seq) == 3 / 8


def test_bench_young_tracks_small_run(capsys) -> None:
    assert main(["bench", "young-tracks", "--frames", "30", "--seeds", "1"]) == 0
    out = capsys.readouterr().out
    lines = out.splitlines()
    assert "1 seeds x 30 frames" in out and "of the observations are" in out
    rows = [line for line in lines if line.strip().startswith(("4 |", "2 |"))]
    assert len(rows) == 2, out
    # The first row is the reference: its ratios are exactly 1.
    assert "(x1.00 / 1.00 / 1.00)" in rows[0]
    assert main(["bench", "young-tracks", "--outliers", "1.5"]) == 1
