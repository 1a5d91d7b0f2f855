"""Smoke runs of ``apcc-graph bench solver`` and ``bench accuracy`` (figures, not timings)."""

from __future__ import annotations

import re

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
    assert main(["bench", "smoother", "--frames", "40", "--long-frames", "400",
                 "--memory-frames", "1000", "--no-batch"]) == 0
    text = capsys.readouterr().out
    lines = text.splitlines()
    # Accuracy: chain and smoother rows for both outlier levels; the chain is the reference.
    rows = {(ln.split()[0] + ln.split()[1], ln.split()[2]): ln.split()
            for ln in lines if re.match(r"\s+(10|30)% outliers\s+(chain|smoother)\s", ln)}
    assert set(rows) == {("10%outliers", "chain"), ("10%outliers", "smoother"),
                         ("30%outliers", "chain"), ("30%outliers", "smoother")}
    for (case, _method), cells in rows.items():
        rms = [float(v) for v in cells[3:6]]
        ratio = [float(v) for v in cells[7:10]]
        chain = [float(v) for v in rows[(case, "chain")][3:6]]
        assert all(v > 0 for v in rms)
        # The ratio column is this method's RMS over the chain's (printed values rounded).
        for r, c, q in zip(rms, chain, ratio, strict=True):
            assert abs(r / c - q) < 0.01 + 0.0006 * r / c**2
    # Drift rows: late / early is the ratio of the two printed windows.
    for method in ("smoother", "chain"):
        cells = next(ln.split() for ln in lines if ln.strip().startswith(method + " ")
                     and "outliers" not in ln and len(ln.split()) == 4)
        early, late, ratio = (float(v) for v in cells[1:])
        assert abs(late / early - ratio) < 0.011
    # Speed of both gtsam backends, and the memory and self-calibration sections.
    assert re.search(r"incremental \(iSAM2\)\s+400\s+[\d.]+ms\s+[\d.]+ms", text)
    assert re.search(r"batch \(LM over the window\)\s+150\s+[\d.]+ms", text)
    assert re.search(r"after 1,000 frames\s+[\d.]+ MB; after 1,000 frames\s+[\d.]+ MB; "
                     r"ratio 1\.\d{3}", text)
    assert text.count("segment ") >= 3 and "self-calibration" in text
    assert re.search(r"segment 1: k 0\.\d{4} \(true 0\.2500\)", text)


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
