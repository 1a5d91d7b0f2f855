"""Many sequences in one command: one output folder each, a summary, failures isolated, resume,
and the Dask path equal to the serial one."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from apcc_graph.cli import main
from apcc_graph.estimation.many import DONE, estimate_many, sequence_folders
from apcc_graph.io import load_robot, load_sequence, save_sequence
from apcc_graph.io.estimates import load_theta_csv
from apcc_graph.simulation.simulator import simulate

ROOT = Path(__file__).resolve().parents[1]
ROBOT = ROOT / "data" / "robots" / "planar_three.toml"
OPTIONS = {"noise_px": 1.0, "theta0": np.zeros(3)}  # a given start: mechanics, not accuracy


@pytest.fixture(scope="module")
def recordings(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Three short simulated sequences in one parent folder, and a broken fourth."""
    parent = tmp_path_factory.mktemp("recordings")
    robot = load_robot(ROBOT)
    for seed in (1, 2, 3):
        sim = simulate(robot, 40, noise_px=1.0, outlier_fraction=0.05, seed=seed)
        save_sequence(sim.sequence, parent / f"seq_{seed}")
    broken = parent / "seq_4"
    save_sequence(simulate(robot, 10, seed=4).sequence, broken)
    (broken / "frames.csv").write_text("frame,timestamp\n0,abc\n")
    return parent


def thetas_of(out: Path) -> dict[str, bytes]:
    return {p.parent.name: p.read_bytes() for p in sorted(out.glob("*/theta.csv"))}


def test_serial_and_dask_agree_bit_for_bit_and_a_failure_stops_nothing(
        recordings: Path, tmp_path: Path) -> None:
    folders = sequence_folders([recordings])
    assert [f.name for f in folders] == ["seq_1", "seq_2", "seq_3", "seq_4"]
    serial = estimate_many(folders, tmp_path / "serial", "batch", OPTIONS, workers=1)
    pytest.importorskip("distributed")
    dask = estimate_many(folders, tmp_path / "dask", "batch", OPTIONS, workers=2)
    assert [r.status for r in serial] == ["ok", "ok", "ok", serial[3].status]
    assert serial[3].status.startswith("failed: ") and "frames.csv" in serial[3].status
    assert [r.status for r in dask] == [r.status for r in serial]
    assert thetas_of(tmp_path / "serial") == thetas_of(tmp_path / "dask")
    assert len(thetas_of(tmp_path / "serial")) == 3
    summary = (tmp_path / "serial" / "summary.csv").read_text().splitlines()
    assert summary[0] == ("sequence,method,frames,seconds,rms_1_deg,rms_2_deg,rms_3_deg,"
                          "status")
    assert len(summary) == 5 and summary[1].endswith(",ok") and "failed" in summary[4]
    # the RMS is that of the written estimate against the sequence's truth
    _, thetas, _ = load_theta_csv(tmp_path / "serial" / "seq_2" / "theta.csv")
    truth = load_sequence(folders[1]).thetas
    np.testing.assert_allclose(serial[1].rms, np.sqrt(np.mean((thetas - truth) ** 2, axis=0)),
                               rtol=1e-9)


def test_a_rerun_skips_complete_outputs_and_redoes_the_rest(recordings: Path,
                                                           tmp_path: Path) -> None:
    folders = sequence_folders([recordings / "seq_1", recordings / "seq_2"])
    out = tmp_path / "out"
    first = estimate_many(folders, out, "chain", {"theta0": np.zeros(3)}, workers=1)
    assert [r.status for r in first] == ["ok", "ok"]
    # seq_2's folder without its completion mark is not this tool's: the user's notes
    (out / "seq_2" / DONE).unlink()
    (out / "seq_2" / "theta.csv").unlink()
    (out / "seq_2" / "notes.txt").write_text("mine\n")
    again = estimate_many(folders, out, "chain", {"theta0": np.zeros(3)}, workers=1)
    assert [r.status for r in again] == ["skipped", again[1].status]
    assert again[1].status.startswith("failed: ") and "add --force" in again[1].status
    assert again[0].rms == pytest.approx(first[0].rms, rel=1e-6)
    assert (out / "seq_2" / "notes.txt").read_text() == "mine\n"  # kept without redo
    assert not (out / "seq_2" / "theta.csv").exists()
    redo = estimate_many(folders, out, "chain", {"theta0": np.zeros(3)}, workers=1, redo=True)
    assert [r.status for r in redo] == ["ok", "ok"]
    assert (out / "seq_2" / "theta.csv").read_text().startswith("frame,timestamp")
    assert not (out / "seq_2" / "notes.txt").exists()  # replaced whole, as --force says
    shutil.rmtree(out / "seq_1")
    (out / "seq_1").write_text("a file of the user's\n")  # not a folder: not replaced either
    again = estimate_many(folders, out, "chain", {"theta0": np.zeros(3)}, workers=1)
    assert again[0].status.startswith("failed: ") and "add --force" in again[0].status
    assert (out / "seq_1").read_text() == "a file of the user's\n"


def test_force_never_replaces_the_current_folder_as_a_sequences_output(
        recordings: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "runs"
    (out / "seq_1").mkdir(parents=True)
    (out / "seq_1" / "notes.txt").write_text("mine\n")
    monkeypatch.chdir(out / "seq_1")
    assert main(["estimate", str(recordings / "seq_1"), str(recordings / "seq_2"),
                 "--method", "chain", "--out", str(out), "--workers", "1", "--force"]) == 1
    assert "holds the current folder" in capsys.readouterr().err
    assert (out / "seq_1" / "notes.txt").read_text() == "mine\n"
    assert sorted(p.name for p in out.iterdir()) == ["seq_1"]  # nothing computed


def test_the_command_line_runs_a_parent_folder(recordings: Path, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "runs"
    assert main(["estimate", str(recordings), "--method", "chain", "--out", str(out),
                 "--workers", "1", "--theta0-deg=0,0,0"]) == 0
    text = capsys.readouterr().out
    assert "4 sequences" in text and "3 estimated" in text and "1 failed" in text
    assert "seq_4" in text and (out / "summary.csv").is_file()
    assert main(["estimate", str(recordings / "seq_1"), "--out", str(tmp_path / "one"),
                 "--workers", "2"]) == 1
    assert "--workers and --scheduler apply to several sequences only" in capsys.readouterr().err


def test_one_sequence_never_imports_dask(tmp_path: Path) -> None:
    code = ("import sys; from apcc_graph.cli import main; "
            f"code = main(['estimate', {str(ROOT / 'data' / 'sequences' / 'planar_three')!r}, "
            f"'--method', 'chain', '--out', {str(tmp_path / 'e')!r}]); "
            "assert code == 0; assert 'distributed' not in sys.modules and "
            "'dask' not in sys.modules, 'dask imported'")
    subprocess.run([sys.executable, "-c", code], check=True, capture_output=True)


def test_a_worker_killed_mid_run_loses_no_sequence(recordings: Path, tmp_path: Path) -> None:
    """Dask reruns the tasks of a lost worker: every sequence comes back once, complete."""
    import os
    import signal
    import threading

    distributed = pytest.importorskip("distributed")
    folders = sequence_folders([recordings])[:3]
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, \
            distributed.Client(cluster) as client:
        pids = list(client.run(os.getpid).values())
        finished, killed_mid_run = threading.Event(), []

        def kill_one() -> None:
            # once the first sequence is under way on some worker
            while not any(client.processing().values()):
                threading.Event().wait(0.05)
            threading.Event().wait(0.5)
            killed_mid_run.append(not finished.is_set())
            os.kill(pids[0], signal.SIGKILL)

        killer = threading.Thread(target=kill_one)
        killer.start()
        runs = estimate_many(folders, tmp_path / "out", "batch", OPTIONS,
                             scheduler=cluster.scheduler_address)
        finished.set()
        killer.join()
    assert killed_mid_run == [True]
    assert [r.status for r in runs] == ["ok", "ok", "ok"]
    assert sorted(p.parent.name for p in (tmp_path / "out").glob(f"*/{DONE}")) == [
        "seq_1", "seq_2", "seq_3"]
    rows = (tmp_path / "out" / "summary.csv").read_text().splitlines()[1:]
    assert sorted(row.split(",")[0].rsplit("/", 1)[-1] for row in rows) == [
        "seq_1", "seq_2", "seq_3"]


def test_the_many_sequences_benchmark_compares_dask_with_the_serial_run(
        capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("distributed")
    assert main(["bench", "many", "--sequences", "3", "--frames", "20", "--method", "chain",
                 "--workers", "2", "--robot", str(ROBOT)]) == 0
    text = capsys.readouterr().out
    assert "3 sequences x 20 frames, method chain" in text
    assert "identical theta.csv files: yes; failed sequences: 0" in text
    assert "local Dask cluster, 2 workers" in text and "target: at least 1.7x" in text


def test_several_workers_without_dask_run_here_with_a_note(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """Without Dask installed, asking for several workers runs every job in this process,
    in order, with a one-line warning that says so; a scheduler still needs Dask."""
    import importlib.util

    from apcc_graph.estimation import many

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == "distributed" else real(name, *a))
    monkeypatch.setitem(sys.modules, "distributed", None)  # its import fails too
    with pytest.warns(UserWarning, match=r"Dask is not installed .* this process \(3 workers"):
        assert many.map_tasks(pow, [(2, 3), (3, 2)], workers=3) == [8, 9]
    with pytest.raises(ValueError, match="a Dask scheduler needs Dask"):
        many.map_tasks(pow, [(2, 3)], scheduler="tcp://127.0.0.1:1")


def test_a_dask_run_leaves_this_processs_settings_as_they_were(
        monkeypatch: pytest.MonkeyPatch) -> None:
    pytest.importorskip("distributed")
    import logging
    import math
    import os

    from apcc_graph.estimation import many

    monkeypatch.setenv("PYTHONWARNINGS", "default")
    levels = {name: logging.getLogger(name).level for name in many.DASK_LOGGERS}
    assert many.map_tasks(math.sqrt, [(4.0,), (9.0,)], workers=2) == [2.0, 3.0]
    assert os.environ["PYTHONWARNINGS"] == "default"

    class Interrupted:  # Ctrl-C as the first result comes in
        def update(self) -> None:
            raise KeyboardInterrupt

        def close(self) -> None:
            pass

    monkeypatch.setattr(many, "progress_bar", lambda **kwargs: Interrupted())
    with pytest.raises(KeyboardInterrupt):
        many.map_tasks(math.sqrt, [(4.0,)], workers=2)
    assert os.environ["PYTHONWARNINGS"] == "default"
    assert {name: logging.getLogger(name).level for name in many.DASK_LOGGERS} == levels
