"""What the command line draws on stderr: progress bars only on a terminal and never with
--quiet, nothing redrawn in a log, and warnings on lines of their own."""

from __future__ import annotations

import fcntl
import io
import os
import pty
import select
import struct
import subprocess
import sys
import termios
from pathlib import Path

import pytest

from apcc_graph.io import console

ROOT = Path(__file__).resolve().parents[1]
SIMULATE = [sys.executable, "-m", "apcc_graph.cli", "simulate", "--robot",
            str(ROOT / "data/robots/planar_three.toml"), "--frames", "400", "--force"]


def _on_a_pty(command: list[str]) -> tuple[int, bytes]:
    """Run ``command`` with stderr a pseudo-terminal; its exit code and what it drew there."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 24, 100, 0, 0))  # 24 x 100
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=slave, cwd=ROOT)
    os.close(slave)
    drawn = b""
    while True:
        ready, _, _ = select.select([master], [], [], 1.0)
        if ready:
            try:
                chunk = os.read(master, 65536)
            except OSError:  # the child closed the terminal
                break
            if not chunk:
                break
            drawn += chunk
        elif proc.poll() is not None:
            break
    os.close(master)
    return proc.wait(timeout=120), drawn


def test_a_log_gets_no_progress_bar_a_terminal_does_and_quiet_removes_it(
        tmp_path: Path) -> None:
    piped = subprocess.run([*SIMULATE, "--out", str(tmp_path / "a")], capture_output=True,
                           cwd=ROOT, timeout=300)
    assert piped.returncode == 0, piped.stderr
    assert b"\r" not in piped.stderr and b"it/s" not in piped.stderr
    code, drawn = _on_a_pty([*SIMULATE, "--out", str(tmp_path / "b")])
    assert code == 0 and b"\r" in drawn and b"it/s" in drawn  # a tqdm bar, redrawn
    code, drawn = _on_a_pty([sys.executable, "-m", "apcc_graph.cli", "--quiet",
                             *SIMULATE[3:], "--out", str(tmp_path / "c")])
    assert code == 0 and b"\r" not in drawn and b"it/s" not in drawn


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_a_warning_is_printed_above_the_status_line_and_it_is_drawn_again(
        monkeypatch: pytest.MonkeyPatch) -> None:
    stream = _Terminal()
    monkeypatch.setattr(sys, "stderr", stream)
    status = console.StatusLine()
    status.show("frame 12  30.0 fps")
    console.print_line("apcc-graph: warning: something")
    status.close()
    text = stream.getvalue()
    # the status line cleared, the warning on a line of its own, the status line again
    assert "\r\033[Kapcc-graph: warning: something\nframe 12  30.0 fps" in text
    assert "fps" + "apcc-graph" not in text


def test_no_status_line_in_a_log_and_none_with_quiet(monkeypatch: pytest.MonkeyPatch) -> None:
    log = io.StringIO()
    monkeypatch.setattr(sys, "stderr", log)
    status = console.StatusLine()
    status.show("frame 1")
    console.print_line("apcc-graph: warning: w")
    assert log.getvalue() == "apcc-graph: warning: w\n"
    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    console.set_quiet(True)
    try:
        console.StatusLine().show("frame 2")
        assert console.progress_bar(range(3), progress=True).disable is True
    finally:
        console.set_quiet(False)
    assert terminal.getvalue() == ""
    assert console.progress_bar(range(3), progress=True).disable is False
    assert console.progress_bar(range(3), progress=False).disable is True


def test_a_warning_during_a_progress_bar_is_not_glued_onto_it(
        monkeypatch: pytest.MonkeyPatch) -> None:
    terminal = _Terminal()
    monkeypatch.setattr(sys, "stderr", terminal)
    bar = console.progress_bar(total=10, desc="batch", progress=True)
    bar.update(3)
    console.print_line("apcc-graph: warning: w")
    bar.close()
    lines = terminal.getvalue().replace("\r", "\n").split("\n")
    assert "apcc-graph: warning: w" in lines  # a whole line of its own
