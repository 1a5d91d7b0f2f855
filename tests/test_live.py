"""The live loop: frames tracked and smoothed as they arrive, dropped under overload by its
policy, the final estimates appended and flushed, and a run interrupted mid-way leaving
complete, readable outputs."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from apcc_graph.bench.tracking import texture
from apcc_graph.cli import main
from apcc_graph.estimation.live import LiveEstimator, recording_frames
from apcc_graph.frontend.recordings import CameraStream
from apcc_graph.io.estimates import AppendedEstimate, load_theta_csv, load_theta_table
from apcc_graph.io.robot_file import load_robot

ROBOT = Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml"
FRAMES = 12


def _frames(n: int = FRAMES) -> Iterator[tuple[int, float, dict[int, np.ndarray]]]:
    """Frames at 30 fps whose three images pan across textures."""
    bases = [texture(20 + cam, (480, 700)) for cam in range(3)]
    for f in range(n):
        yield f, f / 30.0, {cam: np.ascontiguousarray(b[:, 2 * f:2 * f + 640])
                            for cam, b in enumerate(bases)}


class _Clock:
    """Wall time that moves only when told: each processed frame takes ``busy`` seconds."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now

    def sleep(self, seconds: float) -> None:
        self.now += seconds


def _busy_estimator(seconds: float) -> LiveEstimator:
    """A live estimator on a controlled clock whose every smoothing takes ``seconds``."""
    clock = _Clock()
    live = LiveEstimator(load_robot(ROBOT), clock=clock, sleep=clock.sleep)
    process = live._process

    def busy(*args: object) -> object:
        clock.now += seconds
        return process(*args)  # type: ignore[arg-type]

    live._process = busy  # type: ignore[method-assign]
    return live


def test_under_overload_the_newest_frame_is_taken_and_the_others_dropped() -> None:
    """Smoothing takes 0.1 s while frames arrive every 1/30 s: the frames that arrive meanwhile
    are tracked but not smoothed, but the newest (0, then 3, 6, 9, 12), each estimated 0.1 s
    after it arrived; nothing queues up."""
    live = _busy_estimator(0.1)
    got = list(live.run(_frames(13)))
    assert [e.index for e in got] == [0, 3, 6, 9, 12]
    assert [e.dropped for e in got] == [0, 2, 4, 6, 8] and live.dropped == 8
    assert all(e.latency == pytest.approx(0.1) for e in got)
    final = [fr.frame for e in got for fr in e.final] + [fr.frame for fr in live.finish()]
    assert final == [0, 3, 6, 9, 12]  # every processed frame once, numbered by the source
    assert all(t._frame == 13 for t in live.trackers.values())  # every frame was tracked


def test_without_real_time_every_frame_is_estimated() -> None:
    live = LiveEstimator(load_robot(ROBOT), realtime=False)
    got = list(live.run(_frames()))
    assert [e.index for e in got] == list(range(FRAMES)) and live.dropped == 0
    final = [fr.frame for e in got for fr in e.final] + [fr.frame for fr in live.finish()]
    assert final == list(range(FRAMES))
    assert np.all(np.isfinite([e.thetas for e in got]))


def test_frames_of_a_recording_are_read_in_order_with_every_camera() -> None:
    images = {cam: [np.full((4, 4), 10 * cam + f, np.uint8) for f in range(5)] for cam in range(2)}

    def stream(cam: int, stamps: np.ndarray) -> CameraStream:
        return CameraStream(f"cam{cam}", stamps, lambda: iter(enumerate(images[cam])))

    t = np.arange(5) / 30.0
    frames = list(recording_frames([stream(0, t), stream(1, t + 0.002)], [0, 2]))
    assert [f for f, _, _ in frames] == list(range(5))
    assert all(set(imgs) == {0, 2} and imgs[2][0, 0] == 10 + f for f, _, imgs in frames)


def test_appended_estimates_are_readable_at_every_row(tmp_path: Path) -> None:
    robot = load_robot(ROBOT)
    out = AppendedEstimate(tmp_path, 3, robot.forward)
    for f in range(3):
        out.append(f, f / 30.0, np.radians([10.0 + f, -5.0, 3.0]), np.full(3, 1e-3))
        times, thetas, _ = load_theta_csv(tmp_path / "theta.csv")  # while it is open
        assert len(times) == f + 1 and np.degrees(thetas[-1, 0]) == pytest.approx(10.0 + f)
        assert (tmp_path / "tips_seg_3.tum").read_text().count("\n") == f + 1
    out.close()


def test_live_interrupted_mid_run_leaves_complete_readable_outputs(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """Ctrl-C after the fifth frame: the command ends cleanly, and theta.csv and the TUM files
    hold every frame processed (the window's too, smoothed at the end)."""
    from apcc_graph.estimation import live as live_module

    run = LiveEstimator.run

    def interrupted(self: LiveEstimator, frames: object) -> Iterator[object]:
        for k, est in enumerate(run(self, frames)):  # type: ignore[arg-type]
            yield est
            if k == 4:
                raise KeyboardInterrupt

    monkeypatch.setattr(LiveEstimator, "run", interrupted)
    monkeypatch.setattr(live_module, "recording_frames", lambda *a, **k: _frames())
    monkeypatch.setattr("apcc_graph.frontend.recordings.video_streams", lambda files: [])
    out = tmp_path / "live"
    code = main(["live", "--video", "a.mp4,b.mp4,c.mp4", "--robot", str(ROBOT), "--out",
                 str(out), "--no-realtime"])
    assert code == 0
    text = capsys.readouterr().out
    assert text.startswith("interrupted: 5 frames estimated") and "wrote 5 rows" in text
    times, thetas, _ = load_theta_csv(out / "theta.csv")
    np.testing.assert_allclose(times, np.arange(5) / 30.0)
    assert np.all(np.isfinite(thetas))
    assert load_theta_table(out / "theta.csv").thetas.shape == (5, 3)
    rows = (out / "theta.csv").read_text().splitlines()[1:]
    assert [int(r.split(",")[0]) for r in rows] == [0, 1, 2, 3, 4]
    for i in range(1, 4):
        assert (out / f"tips_seg_{i}.tum").read_text().count("\n") == 5
    assert main(["live", "--video", "a.mp4", "--robot", str(ROBOT), "--out",
                 str(tmp_path / "x")]) == 1
    assert "--video names 1 files for 3 cameras" in capsys.readouterr().err


def test_a_machine_that_does_not_keep_up_is_warned_about() -> None:
    """Once more frames were dropped than smoothed (after 30 smoothed), a LiveWarning says so,
    once; a run that keeps up says nothing."""
    from apcc_graph.estimation.live import LiveWarning

    def many() -> Iterator[tuple[int, float, dict[int, np.ndarray]]]:
        frames = list(_frames(25))
        for f in range(120):
            yield f, f / 30.0, frames[f % 25][2]

    live = _busy_estimator(0.1)
    with pytest.warns(LiveWarning, match=r"frames were dropped and 30 smoothed") as caught:
        list(live.run(many()))
    assert len([w for w in caught if w.category is LiveWarning]) == 1
