"""Output folders at their edges: Ctrl-C in the middle of swapping an old output for a new
one, an existing empty folder (or a symlink to one) as the destination, and a destination whose
parent cannot be written."""

from __future__ import annotations

import os
import signal
import threading
from pathlib import Path
from typing import Any

import pytest

from apcc_graph.io import output_folder
from apcc_graph.io.output_folder import check_writable, staged_folder


class _NativeThread(threading.Thread):
    """A thread started before the swap (as BLAS starts its threads early, with no signal
    blocked) that, once told, takes a SIGINT: the main thread's signal mask does not hold it
    back, and Python runs its handler in the main thread at the next chance."""

    def __init__(self) -> None:
        super().__init__(daemon=True)
        self.go, self.sent = threading.Event(), threading.Event()

    def run(self) -> None:
        self.go.wait()
        signal.raise_signal(signal.SIGINT)
        self.sent.set()

    def interrupt(self) -> None:
        self.go.set()
        self.sent.wait(timeout=30.0)


@pytest.fixture
def interrupted_renames(monkeypatch: pytest.MonkeyPatch) -> list[Any]:
    """The sources of every ``os.rename`` the staging code makes; a SIGINT arrives (from a
    thread started beforehand) right after the first one."""
    real = os.rename
    calls: list[Any] = []
    native = _NativeThread()
    native.start()

    def rename(source: Any, target: Any) -> None:
        real(source, target)
        calls.append(source)
        if len(calls) == 1:
            native.interrupt()

    monkeypatch.setattr(output_folder.os, "rename", rename)
    return calls


def test_ctrl_c_between_the_two_renames_leaves_one_output_whole(
        tmp_path: Path, interrupted_renames: list[Any]) -> None:
    """The SIGINT comes just after the old output was moved aside."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "old.txt").write_text("old\n")
    calls = interrupted_renames
    with pytest.raises(KeyboardInterrupt), staged_folder(out, replace=True) as staging:
        (staging / "new.txt").write_text("new\n")
    assert len(calls) == 2  # both renames were done before the interruption was raised
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]  # no .old-, no staging
    assert [p.name for p in out.iterdir()] in (["new.txt"], ["old.txt"])
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored


def test_writing_tracks_keeps_everything_else_in_the_tracks_folder(tmp_path: Path) -> None:
    from apcc_graph.frontend.tracking import _write_tracks

    tracks = tmp_path / "tracks"
    (tracks / "notes" / "deeper").mkdir(parents=True)
    (tracks / "notes" / "deeper" / "a.txt").write_text("a\n")
    (tracks / ".hidden").write_text("h\n")
    (tracks / "other.csv").write_text("o\n")
    (tracks / "link").symlink_to("other.csv")
    (tracks / "cam_1.csv").write_text("old\n")
    _write_tracks(tracks, {"cam_1.csv": "new\n"})
    assert (tracks / "cam_1.csv").read_text() == "new\n"
    assert (tracks / "notes" / "deeper" / "a.txt").read_text() == "a\n"
    assert (tracks / ".hidden").read_text() == "h\n"
    assert (tracks / "other.csv").read_text() == "o\n"
    assert (tracks / "link").is_symlink() and os.readlink(tracks / "link") == "other.csv"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tracks"]


@pytest.fixture
def read_only_parent(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """``tmp_path/parent``, in which no new file, folder or rename can be made (a bind-mounted
    ``/out`` whose parent is read-only; made up, since root would write anyway)."""
    import errno
    import tempfile

    parent = tmp_path / "parent"
    parent.mkdir()

    def refused(where: Any) -> None:
        if Path(where).parent == parent:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(where))

    real_mkstemp, real_mkdtemp, real_rename = tempfile.mkstemp, tempfile.mkdtemp, os.rename

    def mkstemp(*args: Any, dir: Any = None, **kwargs: Any) -> Any:  # noqa: A002
        refused(Path(dir) / "x")
        return real_mkstemp(*args, dir=dir, **kwargs)

    def mkdtemp(*args: Any, dir: Any = None, **kwargs: Any) -> Any:  # noqa: A002
        refused(Path(dir) / "x")
        return real_mkdtemp(*args, dir=dir, **kwargs)

    def rename(source: Any, target: Any) -> None:
        refused(source)
        refused(target)
        real_rename(source, target)

    monkeypatch.setattr(output_folder.tempfile, "mkstemp", mkstemp)
    monkeypatch.setattr(output_folder.tempfile, "mkdtemp", mkdtemp)
    monkeypatch.setattr(output_folder.os, "rename", rename)
    return parent


def test_an_empty_out_in_a_read_only_parent_is_written_into(read_only_parent: Path) -> None:
    out = read_only_parent / "out"
    out.mkdir(mode=0o750)
    out.chmod(0o750)
    inode = out.stat().st_ino
    assert check_writable(out) == out  # probed inside it
    with pytest.raises(OSError, match="cannot be written"):
        check_writable(read_only_parent / "new")  # a new folder there cannot be made
    with staged_folder(out) as staging:
        (staging / "theta.csv").write_text("new\n")
        (staging / "sub").mkdir()
        (staging / "sub" / "a.txt").write_text("a\n")
    assert sorted(p.name for p in out.iterdir()) == ["sub", "theta.csv"]  # no hidden folder
    assert (out / "sub" / "a.txt").read_text() == "a\n"
    assert out.stat().st_ino == inode and (out.stat().st_mode & 0o777) == 0o750  # the same
    assert sorted(p.name for p in read_only_parent.iterdir()) == ["out"]


def test_a_symlink_to_an_empty_folder_stays_a_symlink(tmp_path: Path) -> None:
    real = tmp_path / "real"
    real.mkdir()
    link = tmp_path / "out"
    link.symlink_to(real)
    with pytest.raises(RuntimeError), staged_folder(link) as staging:  # a failure: nothing
        (staging / "half.csv").write_text("half\n")
        raise RuntimeError
    assert link.is_symlink() and list(real.iterdir()) == []
    with staged_folder(link) as staging:
        (staging / "theta.csv").write_text("new\n")
    assert link.is_symlink() and os.readlink(link) == str(real)
    assert [p.name for p in real.iterdir()] == ["theta.csv"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "real"]


def test_ctrl_c_while_moving_up_leaves_all_or_nothing(tmp_path: Path,
                                                      interrupted_renames: list[Any]) -> None:
    """The SIGINT comes just after the first of three files was moved up."""
    out = tmp_path / "out"
    out.mkdir()
    with pytest.raises(KeyboardInterrupt), staged_folder(out) as staging:
        for name in ("a.csv", "b.csv", "c.csv"):
            (staging / name).write_text(name)
    assert sorted(p.name for p in out.iterdir()) == ["a.csv", "b.csv", "c.csv"]


def test_calibrate_render_force_never_replaces_the_current_folder(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    from apcc_graph.cli import main

    here = tmp_path / "here"
    here.mkdir()
    (here / "notes.txt").write_text("mine\n")
    monkeypatch.chdir(here)
    assert main(["calibrate", str(here), "--render", "--length", "0.4", "--k", "0.2",
                 "--bends-deg", "30", "--force"]) == 1
    assert "holds the current folder" in capsys.readouterr().err
    assert [p.name for p in here.iterdir()] == ["notes.txt"]


def test_force_on_a_symlink_replaces_what_it_points_to(tmp_path: Path) -> None:
    real = tmp_path / "real"
    real.mkdir()
    (real / "old.txt").write_text("old\n")
    link = tmp_path / "out"
    link.symlink_to(real)
    check_writable(link)
    with staged_folder(link, replace=True) as staging:
        (staging / "new.txt").write_text("new\n")
    assert link.is_symlink() and os.readlink(link) == str(real)
    assert [p.name for p in real.iterdir()] == ["new.txt"]  # the old one replaced whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out", "real"]


def test_force_refuses_a_mount_point_that_holds_something(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from apcc_graph.io.output_folder import replace_refusal

    mount = tmp_path / "mnt"
    mount.mkdir()
    real = os.path.ismount
    monkeypatch.setattr(output_folder.os.path, "ismount",
                        lambda path: Path(path) == mount or real(path))
    assert replace_refusal(mount) is None  # empty: written into, see above
    (mount / "old.txt").write_text("old\n")
    assert "mount point" in (replace_refusal(mount) or "")
