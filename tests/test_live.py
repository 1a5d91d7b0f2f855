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

ROOT_DATA = Path(__file__).resolve().parents[1] / "data"
ROBOT = ROOT_DATA / "robots/planar_three.toml"
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
    """A live estimator on a controlled clock whose every smoothing takes ``seconds``
    (tracking in the loop's thread: what arrived is known exactly when)."""
    clock = _Clock()
    live = LiveEstimator(load_robot(ROBOT), np.zeros(3), clock=clock, sleep=clock.sleep,
                         tracking="inline")
    process = live._process

    def busy(*args: object, **kwargs: object) -> object:
        clock.now += seconds
        return process(*args, **kwargs)  # type: ignore[arg-type]

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
    live = LiveEstimator(load_robot(ROBOT), np.zeros(3), realtime=False)
    got = list(live.run(_frames()))
    assert [e.index for e in got] == list(range(FRAMES)) and live.dropped == 0
    final = [fr.frame for e in got for fr in e.final] + [fr.frame for fr in live.finish()]
    assert final == list(range(FRAMES))
    assert np.all(np.isfinite([e.thetas for e in got]))


def test_live_with_keyframes_estimates_every_frame_once_and_says_which_wait() -> None:
    """The smoother solving at keyframes only: every frame still gets an estimate at once (a
    frame between keyframes says it waits: status "pending") and one final estimate, in
    order; fewer iSAM2 updates than frames (after the warm-up of one lag, all keyframes)."""
    from apcc_graph.estimation.keyframes import KeyframeRule
    from apcc_graph.estimation.smoother_options import SmootherOptions, WindowOptions


    frames = 24
    live = LiveEstimator(load_robot(ROBOT), np.zeros(3), realtime=False,
                         settings=SmootherOptions(window=WindowOptions(lag=0.3),
                                                  keyframes=KeyframeRule()))
    got = list(live.run(_frames(frames)))
    assert [e.index for e in got] == list(range(frames)) and live.dropped == 0
    final = [fr for e in got for fr in e.final] + list(live.finish())
    assert [fr.frame for fr in final] == list(range(frames))
    keys = live.smoother._keys
    assert keys.frames == frames and 0 < keys.keyframes < frames
    assert sum(e.pending for e in got) == frames - keys.keyframes
    assert not got[0].pending


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
    """Ctrl-C after the fifth frame (the stop event set, as the SIGINT handler sets it): the
    command stops at the next frame boundary, smooths and writes the window, prints its summary
    and exits with 130; theta.csv and the TUM files hold every frame processed."""

    run = LiveEstimator.run

    def interrupted(self: LiveEstimator, frames: object, stop: object = None
                    ) -> Iterator[object]:
        for k, est in enumerate(run(self, frames, stop)):  # type: ignore[arg-type]
            yield est
            if k == 4:
                stop.set()  # type: ignore[attr-defined]

    monkeypatch.setattr(LiveEstimator, "run", interrupted)
    monkeypatch.setattr("apcc_graph.cli.live._frames", lambda *a, **k: _frames())
    out = tmp_path / "live"
    code = main(["live", "--video", "a.mp4,b.mp4,c.mp4", "--robot", str(ROBOT), "--out",
                 str(out), "--no-realtime", "--theta0-deg", "0,0,0"])
    assert code == 130
    captured = capsys.readouterr()
    assert captured.out.startswith("interrupted: 5 frames estimated")
    assert "wrote 5 rows" in captured.out
    assert captured.err.strip().splitlines()[-1] == "apcc-graph: interrupted"
    times, thetas, _ = load_theta_csv(out / "theta.csv")
    np.testing.assert_allclose(times, np.arange(5) / 30.0)
    assert np.all(np.isfinite(thetas))
    assert load_theta_table(out / "theta.csv").thetas.shape == (5, 3)
    rows = (out / "theta.csv").read_text().splitlines()[1:]
    assert [int(r.split(",")[0]) for r in rows] == [0, 1, 2, 3, 4]
    for i in range(1, 4):
        assert (out / f"tips_seg_{i}.tum").read_text().count("\n") == 5
    now = (out / "theta_now.csv").read_text().splitlines()
    assert now[0].endswith(",estimate,latency_ms") and len(now) == 6  # each estimate out
    assert [r.split(",")[-2] for r in now[1:]] == ["filtered"] * 5  # no keyframes: solved
    monkeypatch.undo()  # the real sources again: the arguments are checked
    assert main(["live", "--video", "a.mp4", "--robot", str(ROBOT), "--out",
                 str(tmp_path / "x")]) == 1
    assert "--video names 1 files for 3 cameras" in capsys.readouterr().err


def test_live_keyframes_from_the_command_line_write_every_frame(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``apcc-graph live --keyframes``: the smoother gets the keyframe rule, and theta.csv holds
    every frame once, in order; theta_now.csv holds each frame's estimate as it came out and
    says which: "fit" (with empty sigmas) for the frames between keyframes, else "filtered"."""
    from apcc_graph.estimation.keyframes import KeyframeRule

    made = []
    init = LiveEstimator.__init__

    def recorded(self: LiveEstimator, *args: object, **kwargs: object) -> None:
        init(self, *args, **kwargs)  # type: ignore[arg-type]
        made.append(self.settings)

    monkeypatch.setattr(LiveEstimator, "__init__", recorded)
    monkeypatch.setattr("apcc_graph.cli.live._frames", lambda *a, **k: _frames(20))
    out = tmp_path / "live"
    assert main(["live", "--video", "a.mp4,b.mp4,c.mp4", "--robot", str(ROBOT), "--out",
                 str(out), "--no-realtime", "--theta0-deg", "0,0,0", "--lag", "0.3",
                 "--keyframes"]) == 0
    assert made and made[0].keyframes == KeyframeRule() and made[0].window.lag == 0.3
    rows = (out / "theta.csv").read_text().splitlines()[1:]
    assert [int(r.split(",")[0]) for r in rows] == list(range(20))
    now = [r.split(",") for r in (out / "theta_now.csv").read_text().splitlines()[1:]]
    assert [int(r[0]) for r in now] == list(range(20))
    kinds = [r[-2] for r in now]
    assert "fit" in kinds and kinds[0] == "filtered" and set(kinds) == {"fit", "filtered"}
    for r in now:  # sigma_1..3 are columns 5-7: empty for the fits (not solved yet)
        assert r[-2] != "fit" or r[5:8] == ["", "", ""]
    assert all(float(v) > 0 for v in now[0][5:8])  # the first frame's, solved


def test_a_machine_that_does_not_keep_up_is_warned_about_by_rate_and_early() -> None:
    """Smoothing takes 0.1 s while frames arrive at 30 per second: once the first second of
    the recording has passed (not after 30 smoothed frames), one LiveWarning gives both rates;
    a run that keeps up (0.01 s per frame) says nothing."""
    from apcc_graph.estimation.live import LiveWarning

    def frames() -> Iterator[tuple[int, float, dict[int, np.ndarray]]]:
        images = [imgs for _, _, imgs in _frames(15)]
        for f in range(45):
            yield f, f / 30.0, images[f % 15 if (f // 15) % 2 == 0 else 14 - f % 15]

    live = _busy_estimator(0.1)
    with pytest.warns(LiveWarning, match=r"10\.\d frames per second of the recording are "
                      r"smoothed of the 30\.0 arriving") as caught:
        got = list(live.run(frames()))
    rate = [str(w.message) for w in caught if "frames per second" in str(w.message)]
    assert len(rate) == 1 and "by frame 31 " in rate[0]  # as the first second has passed
    assert len(got) < 20  # a short input: fewer than 30 smoothed frames in all

    import warnings
    with warnings.catch_warnings():
        warnings.filterwarnings("error", "live: by frame", LiveWarning)
        assert len(list(_busy_estimator(0.01).run(frames()))) == 45


def test_a_live_file_with_gaps_and_clamped_rows_is_read_by_evaluate_and_plot(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """What live writes (frames skipped, an angle clamped to its limit) reads back with its
    frame numbers and flags, and evaluate and plot take it (the frames it has)."""
    from apcc_graph.io.sequence_folder import load_sequence

    truth_folder = ROOT_DATA / "sequences/planar_three"
    truth = load_sequence(truth_folder)
    assert truth.thetas is not None
    out = AppendedEstimate(tmp_path / "live", 3, truth.robot.forward)
    kept = [0, 3, 4, 9, 15, 40]
    for f in kept:
        clamped = np.array([f == 9, False, False])
        out.append(f, float(truth.timestamps[f]), truth.thetas[f] + 1e-3, np.full(3, 1e-3),
                   clamped)
    with pytest.raises(ValueError, match="expected strictly increasing frames"):
        out.append(40, float(truth.timestamps[40]), truth.thetas[40], np.full(3, 1e-3))
    out.close()
    table = load_theta_table(tmp_path / "live" / "theta.csv")
    assert table.frame_numbers().tolist() == kept
    assert table.clamped is not None and table.clamped[:, 0].tolist() == [f == 9 for f in kept]
    assert not table.clamped[:, 1:].any()
    assert main(["evaluate", str(tmp_path / "live"), "--truth", str(truth_folder)]) == 0
    text = capsys.readouterr().out
    assert "0.057" in text  # 1e-3 rad on every segment, on the frames it has
    assert main(["plot", str(tmp_path / "live"), "--truth", str(truth_folder), "--out",
                 str(tmp_path / "fig.png")]) == 0
    assert (tmp_path / "fig.png").stat().st_size > 0


def test_joint_limits_clamp_flag_and_warn_once_per_segment() -> None:
    from apcc_graph.estimation.live_guards import LimitGuard, LiveWarning

    guard = LimitGuard(np.radians([60.0, 60.0, 90.0]))
    inside = np.radians([59.0, -60.0, 10.0])
    same, flags = guard.clamp(3, inside, final=True)
    assert not flags.any() and np.array_equal(same, inside) and guard.rows == 0
    with pytest.warns(LiveWarning, match=r"frame 7: segment 1's estimate 103\.0 deg is beyond "
                      r"its limit of 60\.0 deg") as caught:
        clamped, flags = guard.clamp(7, np.radians([103.0, 10.0, -171.0]), final=True)
    assert flags.tolist() == [True, False, True]
    np.testing.assert_allclose(np.degrees(clamped), [60.0, 10.0, -90.0])
    assert sorted(str(w.message)[:25] for w in caught) == ["live: frame 7: segment 1'",
                                                           "live: frame 7: segment 3'"]
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        guard.clamp(8, np.radians([100.0, 0.0, 0.0]), final=True)  # segment 1 again: quiet
        guard.clamp(9, np.radians([0.0, 300.0, 0.0]), final=False)  # a filtered one: quiet
    assert guard.rows == 2


def test_without_a_start_live_searches_it_in_the_first_second(
        monkeypatch: pytest.MonkeyPatch) -> None:
    """No theta0: the first second of frames is kept, the start searched in it as estimate
    searches it, and the smoother started there: every frame final, near the truth (the
    straight start is 20 degrees off); the frames come from a simulated sequence's tracks."""
    from apcc_graph.simulation.simulator import simulate

    robot = load_robot(ROBOT)
    sim = simulate(robot, 45, noise_px=0.5, outlier_fraction=0.0, seed=1)
    truth = sim.sequence.thetas
    assert truth is not None and np.degrees(np.abs(truth[0])).max() > 10.0
    live = LiveEstimator(robot, realtime=False)
    monkeypatch.setattr(live, "_track", lambda images: dict(images[-1].tracks))
    frames = ((f, float(sim.sequence.timestamps[f]), {-1: sim.sequence.frame(f)})
              for f in range(sim.sequence.n_frames))  # 1.5 s
    got = list(live.run(frames))
    final = {fr.frame: fr.thetas for e in got for fr in e.final}
    final.update({fr.frame: fr.thetas for fr in live.finish()})
    assert sorted(final) == list(range(45))
    assert live.start_search is not None
    assert live.start_search.startswith("start searched in the first 1.00 s")
    errors = np.degrees(np.array([final[f] for f in range(45)]) - truth)
    assert np.abs(errors).max() < 1.0, np.abs(errors).max(axis=0)


def test_live_force_empties_the_folder_first_and_refuses_one_holding_an_input(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
        capsys: pytest.CaptureFixture[str]) -> None:
    """``live --force`` into a folder of another run: the old files (a fourth segment's TUM
    file, a calibration, a subfolder) are gone and theta.csv holds this run's 12 frames only;
    a folder holding the --robot file is refused with one line, the file kept."""
    import shutil


    monkeypatch.setattr("apcc_graph.cli.live._frames", lambda *a, **k: _frames())
    out = tmp_path / "live"
    (out / "figures").mkdir(parents=True)
    (out / "figures" / "old.png").write_bytes(b"png")
    (out / "tips_seg_4.tum").write_text("0 0 0 0 0 0 0 1\n")
    (out / "robot_calibrated.toml").write_text("[robot]\n")
    (out / "theta.csv").write_text("frame,timestamp,theta_1\n" + "7,9.0,0.1\n" * 40)
    args = ["live", "--video", "a.mp4,b.mp4,c.mp4", "--robot", str(ROBOT), "--out", str(out),
            "--no-realtime", "--theta0-deg", "0,0,0"]
    assert main(args) == 1  # not empty, no --force
    assert "add --force" in capsys.readouterr().err
    assert main([*args, "--force"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["theta.csv", "theta_now.csv",
                                                     "tips_seg_1.tum", "tips_seg_2.tum",
                                                     "tips_seg_3.tum"]
    table = load_theta_table(out / "theta.csv")
    assert table.frame_numbers().tolist() == list(range(FRAMES))
    assert table.thetas.shape == (FRAMES, 3) and np.all(np.isfinite(table.thetas))
    robot = out / "robot.toml"
    shutil.copy(ROBOT, robot)
    capsys.readouterr()
    assert main([*args[:4], str(robot), *args[5:], "--force"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "holds the input" in err[0] and robot.exists()
    assert (out / "theta.csv").exists()  # refused before anything was deleted
