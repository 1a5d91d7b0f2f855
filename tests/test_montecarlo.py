"""``apcc-graph montecarlo``: seeds simulated, bounded and estimated, in process and on Dask
with the same bits; an interrupted study resumes; a failing seed stops nothing."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from apcc_graph.bench import ROBOT_FILE
from apcc_graph.cli import main
from apcc_graph.evaluation.montecarlo import run_montecarlo, summarise

FRAMES = 40


def _table(folder: Path) -> list[dict[str, str]]:
    lines = (folder / "montecarlo.csv").read_text().splitlines()
    head = lines[0].split(",")
    return [dict(zip(head, line.split(","), strict=True)) for line in lines[1:]]


def test_a_study_writes_each_seed_beside_its_bound_and_resumes(tmp_path: Path) -> None:
    out = tmp_path / "mc"
    runs = run_montecarlo(ROBOT_FILE, 2, FRAMES, out, "batch", first_seed=5, workers=1)
    assert [r.seed for r in runs] == [5, 6] and all(r.run.status == "ok" for r in runs)
    rows = _table(out)
    assert [row["seed"] for row in rows] == ["5", "6"]
    for r, row in zip(runs, rows, strict=True):
        assert len(r.run.rms) == len(r.bound) == 3
        assert np.allclose([float(row[f"rms_deg_{i}"]) for i in (1, 2, 3)],
                           np.degrees(r.run.rms), atol=1e-6)
        # 40 frames from a 0.1 deg start prior: the bound grows with the motion, not far
        assert all(math.radians(0.02) < b < math.radians(0.5) for b in r.bound), r.bound
        assert (out / f"seed_{r.seed:04d}" / "sequence" / "tracks").is_dir()
    # done.txt names the sequence where it is now, not the staging folder it was made in
    done = (out / "seed_0005" / "estimate" / "done.txt").read_text()
    assert str(out / "seed_0005" / "sequence") in done and ".partial-" not in done
    first = (out / "seed_0005" / "estimate" / "theta.csv").read_bytes()
    again = run_montecarlo(ROBOT_FILE, 3, FRAMES, out, "batch", first_seed=5, workers=1)
    assert [r.run.status for r in again] == ["skipped", "skipped", "ok"]
    assert np.allclose([r.run.rms for r in again[:2]], [r.run.rms for r in runs], atol=1e-7)
    assert np.allclose([r.bound for r in again[:2]], [r.bound for r in runs], atol=1e-7)
    redo = run_montecarlo(ROBOT_FILE, 1, FRAMES, out, "batch", first_seed=5, workers=1,
                          redo=True)
    assert redo[0].run.status == "ok"
    assert (out / "seed_0005" / "estimate" / "theta.csv").read_bytes() == first  # seeded
    error, bound, n = summarise(again)
    assert n == 3 and error.shape == bound.shape == (3,)


def test_a_seed_that_fails_is_a_row_and_stops_nothing(tmp_path: Path) -> None:
    runs = run_montecarlo(tmp_path / "missing.toml", 2, FRAMES, tmp_path / "mc", workers=1)
    assert all(r.run.status.startswith("failed: ") and "missing.toml" in r.run.status
               for r in runs)
    assert [row["status"][:7] for row in _table(tmp_path / "mc")] == ["failed:"] * 2
    assert summarise(runs)[2] == 0
    with pytest.raises(ValueError, match="outliers = 1.5"):
        run_montecarlo(ROBOT_FILE, 1, FRAMES, tmp_path / "x", outliers=1.5, workers=1)


def test_a_failed_seed_names_its_files_where_they_would_be(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import apcc_graph.io

    def load_sequence(folder: object) -> None:
        raise ValueError(f"{folder}/frames.csv: line 2: bad")

    monkeypatch.setattr(apcc_graph.io, "load_sequence", load_sequence)
    runs = run_montecarlo(ROBOT_FILE, 1, FRAMES, tmp_path / "mc", workers=1)
    status = runs[0].run.status
    assert status.startswith("failed: ") and ".partial-" not in status
    assert str(tmp_path / "mc" / "seed_0001" / "sequence" / "frames.csv") in status
    assert runs[0].run.sequence == str(tmp_path / "mc" / "seed_0001" / "sequence")


def test_dask_gives_the_bits_of_the_serial_run(tmp_path: Path) -> None:
    pytest.importorskip("distributed")
    serial = run_montecarlo(ROBOT_FILE, 2, FRAMES, tmp_path / "serial", "smoother", workers=1)
    dask = run_montecarlo(ROBOT_FILE, 2, FRAMES, tmp_path / "dask", "smoother", workers=2)
    assert [r.run.status for r in dask] == ["ok", "ok"]
    for seed in (1, 2):
        name = Path(f"seed_{seed:04d}") / "estimate" / "theta.csv"
        assert (tmp_path / "serial" / name).read_bytes() == (tmp_path / "dask" / name).read_bytes()
    assert [r.bound for r in serial] == [r.bound for r in dask]


def test_the_command_refuses_a_folder_of_something_else(tmp_path: Path, capsys) -> None:
    (tmp_path / "notes.txt").write_text("mine")
    argv = ["montecarlo", "--runs", "1", "--frames", "20", "--workers", "1",
            "--out", str(tmp_path)]
    assert main(argv) == 1
    assert "holds something other than a Monte Carlo study" in capsys.readouterr().err
    assert (tmp_path / "notes.txt").read_text() == "mine"
    assert main([*argv, "--force"]) == 0
    report = capsys.readouterr().out
    assert "1 seeds, batch" in report and "bound (deg)" in report
    with pytest.raises(SystemExit):  # a usage error, before anything runs
        main(["montecarlo", "--runs", "1", "--outliers", "2", "--out", str(tmp_path)])
    assert "--outliers: '2': expected a fraction" in capsys.readouterr().err
