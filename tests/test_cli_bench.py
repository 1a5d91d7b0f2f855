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
