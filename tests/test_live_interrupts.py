"""Stopping live: Ctrl-C deferred to a frame boundary, every final row kept unchanged, and the
frames kept for the start search written when it comes before the start is found."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from apcc_graph.estimation.live import LiveEstimator
from apcc_graph.io.estimates import load_theta_table
from apcc_graph.io.robot_file import load_robot

ROBOT = Path(__file__).resolve().parents[1] / "data" / "robots/planar_three.toml"


SIGINT_SCRIPT = """
import sys
import numpy as np
from apcc_graph.bench.tracking import texture
from apcc_graph.cli import main

def frames(*args, **kwargs):
    bases = [texture(20 + cam, (480, 700)) for cam in range(3)]
    for f in range(100000):
        x = 2 * (f % 30 if (f // 30) % 2 == 0 else 29 - f % 30)
        yield f, f / 30.0, {cam: np.ascontiguousarray(b[:, x:x + 640])
                            for cam, b in enumerate(bases)}

import apcc_graph.cli.live as live_cli
live_cli._frames = frames
sys.exit(main(["live", "--video", "a.mp4,b.mp4,c.mp4", "--robot", sys.argv[1], "--out",
               sys.argv[2], "--no-realtime", "--theta0-deg", "0,0,0", "--lag", "0.3"]))
"""


def _rows(path: Path) -> int:
    try:
        return max(path.read_text().count("\n") - 1, 0)
    except FileNotFoundError:
        return 0


def _whole_lines(path: Path) -> str:
    """The text of ``path`` up to its last complete line ("" if it does not exist)."""
    try:
        text = path.read_text()
    except FileNotFoundError:
        return ""
    return text[:text.rfind("\n") + 1]


@pytest.mark.parametrize("rows_before", [1, 8, 20])
def test_sigint_to_live_keeps_every_final_row(tmp_path: Path, rows_before: int) -> None:
    """SIGINT to a running ``apcc-graph live --no-realtime`` (a subprocess) once theta.csv has
    ``rows_before`` rows: it stops at a frame boundary (never inside a gtsam update), smooths
    the window and writes it, prints one line on stderr and exits 130; every row written
    before the signal is in theta.csv unchanged (and in the TUM files), which reads back, as
    many TUM lines as rows."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out = tmp_path / "live"
    script = tmp_path / "run_live.py"
    script.write_text(SIGINT_SCRIPT)
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    proc = subprocess.Popen([sys.executable, str(script), str(ROBOT), str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.monotonic() + 240
    while _rows(out / "theta.csv") < rows_before and proc.poll() is None:
        assert time.monotonic() < deadline, "no rows written in time"
        time.sleep(0.02)
    files = [out / "theta.csv", *(out / f"tips_seg_{i}.tum" for i in range(1, 4))]
    before = [_whole_lines(f) for f in files]  # every complete row written so far
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr
    assert stderr.strip().splitlines()[-1] == "apcc-graph: interrupted"
    assert stdout.startswith("interrupted: ")
    table = load_theta_table(out / "theta.csv")
    after = [f.read_text() for f in files]
    for path, was, now in zip(files, before, after, strict=True):
        assert now.startswith(was), f"{path.name}: a row written before the signal changed"
    seen = max(before[0].count("\n") - 1, 0)
    assert len(table.timestamps) > seen  # the window's frames too, smoothed at the end
    frames = table.frame_numbers()
    assert np.all(np.diff(frames) > 0) and np.all(np.isfinite(table.thetas))
    for i in range(1, 4):
        assert (out / f"tips_seg_{i}.tum").read_text().count("\n") == len(frames)


def test_ctrl_c_is_deferred_once_and_a_second_one_raises() -> None:
    import signal

    from apcc_graph.estimation.live_guards import deferred_interrupts

    before = signal.getsignal(signal.SIGINT)
    with deferred_interrupts() as stop:
        signal.raise_signal(signal.SIGINT)  # the first: a flag, no exception
        assert stop.is_set()
        with pytest.raises(KeyboardInterrupt):
            signal.raise_signal(signal.SIGINT)
    assert signal.getsignal(signal.SIGINT) is before


def test_stopped_during_the_start_search_the_kept_frames_are_searched_and_given(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """No theta0, stopped (Ctrl-C's event) after 20 frames, inside the first second the start
    is searched in: the start is searched in those 20 frames and each of them is given its
    estimate, near the truth, rather than nothing."""
    import threading

    from apcc_graph.simulation.simulator import simulate

    robot = load_robot(ROBOT)
    sim = simulate(robot, 45, noise_px=0.5, outlier_fraction=0.0, seed=1)
    truth = sim.sequence.thetas
    assert truth is not None
    stop = threading.Event()

    def frames() -> Iterator[tuple[int, float, dict[int, object]]]:
        for f in range(sim.sequence.n_frames):
            if f == 20:
                stop.set()  # while frame 19 is tracked: the loop stops before frame 20
            yield f, float(sim.sequence.timestamps[f]), {-1: sim.sequence.frame(f)}

    live = LiveEstimator(robot, realtime=False, tracking="inline")  # frame 20 not read ahead
    monkeypatch.setattr(live, "_track", lambda images: dict(images[-1].tracks))
    got = list(live.run(frames(), stop))
    assert live.interrupted
    final = {fr.frame: fr.thetas for e in got for fr in e.final}
    final.update({fr.frame: fr.thetas for fr in live.finish()})
    assert sorted(final) == list(range(20))
    assert live.start_search is not None
    assert live.start_search.startswith("start searched in the first 0.63 s")
    errors = np.degrees(np.array([final[f] for f in range(20)]) - truth[:20])
    assert np.abs(errors).max() < 2.0, np.abs(errors).max(axis=0)


SEARCH_SCRIPT = SIGINT_SCRIPT.replace(
    "        yield f, f / 30.0,", "        if f == 10:\n"
    "            open(sys.argv[3], 'w').close()  # inside the start search's first second\n"
    "        if f >= 10:\n"
    "            import time; time.sleep(0.1)\n"
    "        yield f, f / 30.0,").replace('"--theta0-deg", "0,0,0", ', "")


def test_sigint_during_the_start_search_writes_the_kept_frames(tmp_path: Path) -> None:
    """SIGINT to ``apcc-graph live`` without --theta0-deg while its first second of frames is
    kept for the start search: exit 130, and theta.csv holds those frames (0, 1, 2, ...: each
    tracked frame once), as many TUM lines, where the command wrote nothing before."""
    import os
    import signal
    import subprocess
    import sys
    import time

    out, marker = tmp_path / "live", tmp_path / "searching"
    script = tmp_path / "run_live.py"
    script.write_text(SEARCH_SCRIPT)
    assert "theta0" not in SEARCH_SCRIPT and "sleep(0.1)" in SEARCH_SCRIPT
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    proc = subprocess.Popen([sys.executable, str(script), str(ROBOT), str(out), str(marker)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    deadline = time.monotonic() + 240
    while not marker.exists() and proc.poll() is None:
        assert time.monotonic() < deadline, "the source never reached frame 10"
        time.sleep(0.02)
    assert _rows(out / "theta.csv") == 0  # nothing is final while the start is searched
    proc.send_signal(signal.SIGINT)
    stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr and stdout.startswith("interrupted: ")
    frames = load_theta_table(out / "theta.csv").frame_numbers()
    assert 10 <= len(frames) < 30 and frames.tolist() == list(range(len(frames)))
    for i in range(1, 4):
        assert (out / f"tips_seg_{i}.tum").read_text().count("\n") == len(frames)
