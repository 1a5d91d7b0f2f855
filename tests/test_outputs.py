"""Outputs whole and shareable: files and folders get the umask's permissions (not a temporary
file's 0600), an output folder appears only complete (a full disk leaves no partial folder, no
staging folder, and the old output as it was), ``--force`` replaces a folder whole, and an
``--out`` that cannot be written is refused before anything is computed."""

from __future__ import annotations

import errno
import math
import os
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from apcc_graph.cli import main
from apcc_graph.io import load_robot, save_sequence
from apcc_graph.io.robot_file import save_robot
from apcc_graph.simulation.simulator import simulate

REPO = Path(__file__).resolve().parents[1]
ROBOT = REPO / "data" / "robots" / "planar_three.toml"


@pytest.fixture
def umask() -> Iterator[Any]:
    """Set the process's umask for the test (``umask(0o022)``); restored after it."""
    previous = os.umask(0o022)

    def set_mask(mask: int) -> None:
        os.umask(mask)

    yield set_mask
    os.umask(previous)


@pytest.fixture(scope="module")
def sequences(tmp_path_factory: pytest.TempPathFactory) -> dict[int, tuple[Path, str]]:
    """Two short simulated sequences (12 and 30 frames), each with its true start as a
    ``--theta0-deg`` option."""
    root = tmp_path_factory.mktemp("seqs")
    found = {}
    for frames in (12, 30):
        sim = simulate(load_robot(ROBOT), frames, noise_px=0.5, seed=frames)
        save_sequence(sim.sequence, root / f"seq_{frames}")
        start = ",".join(f"{math.degrees(t):.4f}" for t in sim.sequence.thetas[0])
        found[frames] = (root / f"seq_{frames}", f"--theta0-deg={start}")
    return found


def _estimate(sequence: tuple[Path, str], out: Path, *more: str) -> int:
    folder, theta0 = sequence
    return main(["estimate", str(folder), "--method", "chain", "--out", str(out), theta0, *more])


def _errors(err: str) -> list[str]:
    """stderr's lines but the estimator's warnings (a short sequence can earn some)."""
    lines = err.strip().splitlines()
    assert not any("Traceback" in line for line in lines)
    return [line for line in lines if not line.startswith("apcc-graph: warning:")]


def _mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def _tree(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (hidden ones included) and its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


def test_files_and_folders_get_the_umask_permissions(sequences, tmp_path: Path, umask,
                                                     capsys) -> None:
    est = tmp_path / "est"
    assert _estimate(sequences[12], est) == 0
    assert _mode(est) == 0o755
    for name in ("theta.csv", "tips_seg_1.tum", "tips_seg_3.tum"):
        assert _mode(est / name) == 0o644, name

    sim = tmp_path / "sim"
    assert main(["simulate", "--robot", str(ROBOT), "--frames", "3", "--out", str(sim)]) == 0
    assert {_mode(p) for p in sim.rglob("*") if p.is_file()} == {0o644}
    assert {_mode(p) for p in [sim, *sim.rglob("*")] if p.is_dir()} == {0o755}

    save_robot(load_robot(ROBOT), tmp_path / "robot.toml")
    assert _mode(tmp_path / "robot.toml") == 0o644
    assert main(["plot", str(est), "--output", str(tmp_path / "angles.png")]) == 0
    assert _mode(tmp_path / "angles.png") == 0o644

    many = tmp_path / "many"
    folder, theta0 = sequences[12]
    assert main(["estimate", str(folder), str(sequences[30][0]), "--method", "chain",
                 "--workers", "1", "--out", str(many), theta0]) == 0
    assert _mode(many / "summary.csv") == 0o644
    assert _mode(many / "seq_12" / "done.txt") == 0o644
    assert _mode(many / "seq_30") == 0o755

    umask(0o027)  # another umask, other modes: they follow it
    assert _estimate(sequences[12], tmp_path / "est_027") == 0
    assert _mode(tmp_path / "est_027" / "theta.csv") == 0o640
    assert _mode(tmp_path / "est_027") == 0o750
    capsys.readouterr()


class _FullDisk:
    """A file handle whose writes fail as on a full disk."""

    def __init__(self, handle: Any) -> None:
        self.handle = handle

    def write(self, data: bytes) -> int:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def __getattr__(self, name: str) -> Any:
        return getattr(self.handle, name)

    def __enter__(self) -> _FullDisk:
        return self

    def __exit__(self, *exc: object) -> None:
        self.handle.close()


@pytest.fixture
def full_disk_at(monkeypatch: pytest.MonkeyPatch) -> Any:
    """``full_disk_at("tips_seg_2")``: every file written whose name holds that text fails
    with ENOSPC at its first write (a disk that fills up after theta.csv and tips_seg_1.tum
    were written)."""

    def install(fragment: str) -> None:
        real = os.fdopen

        def fdopen(fd: int, *args: Any, **kwargs: Any) -> Any:
            name = os.readlink(f"/proc/self/fd/{fd}")
            handle = real(fd, *args, **kwargs)
            return _FullDisk(handle) if fragment in Path(name).name else handle

        monkeypatch.setattr(os, "fdopen", fdopen)

    return install


def test_a_full_disk_leaves_no_partial_folder_and_the_old_output_untouched(
        sequences, tmp_path: Path, full_disk_at, capsys) -> None:
    new, old = tmp_path / "new", tmp_path / "old"
    assert _estimate(sequences[30], old) == 0
    before = _tree(old)
    capsys.readouterr()
    full_disk_at("tips_seg_2")

    assert _estimate(sequences[12], new) == 1
    err = _errors(capsys.readouterr().err)
    assert len(err) == 1, err
    assert "new/tips_seg_2.tum: no space left on device" in err[0]
    assert "partial" not in err[0]  # the destination is named, not the staging folder
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old"]

    assert _estimate(sequences[12], old, "--force") == 1
    assert "old/tips_seg_2.tum: no space left on device" in capsys.readouterr().err
    assert _tree(old) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old"]


def test_a_full_disk_in_a_many_sequence_run_fails_that_sequence_only(
        sequences, tmp_path: Path, full_disk_at, capsys) -> None:
    full_disk_at("tips_seg_2")
    folder, theta0 = sequences[12]
    out = tmp_path / "many"
    assert main(["estimate", str(folder), str(sequences[30][0]), "--method", "chain",
                 "--workers", "1", "--out", str(out), theta0]) == 0
    assert "2 failed" in capsys.readouterr().out
    assert sorted(p.name for p in out.iterdir()) == ["summary.csv"]  # no partial folder
    assert "no space left on device" in (out / "summary.csv").read_text()


def test_force_replaces_the_folder_whole(sequences, tmp_path: Path, capsys) -> None:
    out = tmp_path / "est"
    assert _estimate(sequences[30], out) == 0
    (out / "notes.txt").write_text("the old run's\n")
    assert _estimate(sequences[12], out) == 1  # not without --force
    assert "--force" in capsys.readouterr().err
    assert _estimate(sequences[12], out, "--force") == 0
    assert sorted(p.name for p in out.iterdir()) == [
        "theta.csv", "tips_seg_1.tum", "tips_seg_2.tum", "tips_seg_3.tum"]
    assert len((out / "theta.csv").read_text().splitlines()) == 1 + 12
    for i in (1, 2, 3):
        assert len((out / f"tips_seg_{i}.tum").read_text().splitlines()) == 12
    assert [p.name for p in tmp_path.iterdir()] == ["est"]  # nothing left beside it


def test_force_never_replaces_an_input(sequences, tmp_path: Path, capsys) -> None:
    folder, _ = sequences[12]
    before = _tree(folder)
    assert _estimate(sequences[12], folder.parent, "--force") == 1
    assert "holds the input" in capsys.readouterr().err
    assert _estimate(sequences[12], folder, "--force") == 1
    assert _tree(folder) == before


@pytest.fixture
def no_estimate(monkeypatch: pytest.MonkeyPatch) -> None:
    """Any estimate fails the test: the refusal must come before computing."""

    def estimate(*args: object, **kwargs: object) -> None:
        pytest.fail("the estimator ran before --out was checked")

    monkeypatch.setattr("apcc_graph.estimation.methods.estimate", estimate)


@pytest.mark.parametrize("out, expected", [
    ("{file}/est", "is a file, not a folder"),
    ("{file}", "is a file, expected a folder"),
    ("/proc/self/est", "no new file can be made in /proc/self"),
])
def test_an_unwritable_out_is_refused_before_computing(out: str, expected: str, sequences,
                                                       tmp_path: Path, no_estimate,
                                                       capsys) -> None:
    (tmp_path / "file").write_text("x\n")
    out = out.format(file=tmp_path / "file")
    assert _estimate(sequences[12], Path(out), "--force") == 1
    err = _errors(capsys.readouterr().err)
    assert len(err) == 1 and expected in err[0], err
    folder, theta0 = sequences[12]  # several sequences: the same check
    assert main(["estimate", str(folder), str(sequences[30][0]), "--out", out, theta0,
                 "--workers", "1"]) == 1
    assert expected in capsys.readouterr().err


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a read-only folder")
def test_a_read_only_parent_is_refused_before_computing(sequences, tmp_path: Path,
                                                        no_estimate, capsys) -> None:
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o555)
    try:
        assert _estimate(sequences[12], locked / "est") == 1
    finally:
        locked.chmod(0o755)
    assert "cannot be written" in capsys.readouterr().err


def test_the_writability_probe_leaves_nothing(tmp_path: Path) -> None:
    from apcc_graph.io.output_folder import check_writable

    check_writable(tmp_path / "a" / "b")
    check_writable(tmp_path / "f.png", folder=False)
    assert list(tmp_path.iterdir()) == []


def test_a_sequence_folders_tracks_are_swapped_whole(tmp_path: Path, full_disk_at,
                                                     capsys) -> None:
    seq = tmp_path / "img"
    assert main(["simulate", "--robot", str(ROBOT), "--frames", "3", "--out", str(seq),
                 "--images", "--texture", "procedural", "--supersample", "1"]) == 0
    assert main(["track", str(seq)]) == 0
    before = _tree(seq)
    full_disk_at("cam_3.csv")
    assert main(["track", str(seq), "--force"]) == 1
    assert "tracks/cam_3.csv: no space left on device" in capsys.readouterr().err
    assert _tree(seq) == before  # cam_1.csv and cam_2.csv not replaced either
    assert np.all([not p.name.startswith(".") for p in seq.rglob("*")])


def test_force_never_replaces_the_current_folder(sequences, tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch,
                                                 no_estimate, capsys) -> None:
    (tmp_path / "work").mkdir()
    (tmp_path / "work" / "notes.txt").write_text("mine\n")
    monkeypatch.chdir(tmp_path / "work")
    for out in (".", "..", str(tmp_path)):
        assert _estimate(sequences[12], Path(out), "--force") == 1
        assert "holds the current folder" in capsys.readouterr().err
    assert (tmp_path / "work" / "notes.txt").read_text() == "mine\n"


def test_a_staged_folder_appears_whole_or_not_at_all(tmp_path: Path,
                                                     monkeypatch: pytest.MonkeyPatch) -> None:
    from apcc_graph.io import output_folder
    from apcc_graph.io.output_folder import staged_folder

    out = tmp_path / "out"
    out.mkdir()
    (out / "old.txt").write_text("old\n")
    with pytest.raises(KeyboardInterrupt), staged_folder(out, replace=True) as staging:
        (staging / "new.txt").write_text("new\n")
        raise KeyboardInterrupt
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert [p.name for p in out.iterdir()] == ["old.txt"]

    with pytest.raises(OSError, match="add --force"), staged_folder(out) as staging:
        (staging / "new.txt").write_text("new\n")  # out is not empty: not replaced
    assert [p.name for p in out.iterdir()] == ["old.txt"]

    real = os.rename

    def rename(source: Any, target: Any) -> None:  # the new folder cannot be moved in
        if ".partial-" in str(source):
            raise OSError(errno.EXDEV, os.strerror(errno.EXDEV), str(source))
        real(source, target)

    monkeypatch.setattr(output_folder.os, "rename", rename)
    with pytest.raises(OSError), staged_folder(out, replace=True) as staging:
        (staging / "new.txt").write_text("new\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # the old one put back
    assert [p.name for p in out.iterdir()] == ["old.txt"]
    monkeypatch.setattr(output_folder.os, "rename", real)

    with staged_folder(out, replace=True) as staging:
        (staging / "new.txt").write_text("new\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert [p.name for p in out.iterdir()] == ["new.txt"]
