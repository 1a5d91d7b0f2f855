"""The live loop's stages: tracking ahead of the smoother through a bounded queue
(:class:`TrackedFeed`), tracking in a process of its own (:class:`TrackingProcess`, a source read
and tracked there: :class:`ProcessSource`), and keyframes that wait while frames queue."""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from apcc_graph.bench.tracking import texture
from apcc_graph.estimation.live_feed import TrackedFeed
from apcc_graph.estimation.live_process import ProcessSource, SourceSpec
from apcc_graph.frontend.tracking import KLTTracker, TrackerOptions, away_from
from apcc_graph.frontend.tracking_process import TrackingProcess

SIZE = (640, 480)


def _images(n: int, cams: int = 2, step: int = 2) -> list[dict[int, np.ndarray]]:
    """``n`` frames of ``cams`` cameras panning across textures (``step`` pixels a frame)."""
    bases = [texture(30 + cam, (480, 640 + step * n)) for cam in range(cams)]
    return [{cam: np.ascontiguousarray(b[:, step * f:step * f + 640])
             for cam, b in enumerate(bases)} for f in range(n)]


def _source(images: list[dict[int, np.ndarray]], fps: float = 30.0
            ) -> Iterator[tuple[int, float, dict[int, np.ndarray]]]:
    for f, frame in enumerate(images):
        yield f, f / fps, frame


def _ids(images: dict[int, np.ndarray]) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """A stand-in tracker: one track whose id is the image's first pixel."""
    return {cam: (np.array([int(im[0, 0])]), np.zeros((1, 2))) for cam, im in images.items()}


def test_a_threaded_feed_tracks_ahead_in_order_and_never_holds_more_than_its_capacity() -> None:
    """A slow consumer (20 ms a frame) of a feed whose tracking takes 5 ms: every frame is
    tracked once and taken in order; the queue never holds more than its capacity and fills up
    (tracking ran ahead); tracking overlapped the consumer's work."""
    busy = threading.Event()
    overlapped = []

    def track(images: dict[int, np.ndarray]) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        time.sleep(0.005)
        overlapped.append(busy.is_set())
        return _ids(images)

    n = 15
    feed = TrackedFeed(_source([{0: np.full((2, 2), f, np.uint8)} for f in range(n)]), track,
                       realtime=False, clock=time.monotonic, sleep=time.sleep, capacity=3)
    got = []
    while (frame := feed.get()) is not None:
        busy.set()
        time.sleep(0.02)
        got.append(frame.index)
        busy.clear()
    feed.close()
    assert got == list(range(n)) and feed.tracked == n
    assert feed.deepest == 3 and feed.overflow == 0 and feed.untracked == 0
    assert any(overlapped)


def test_a_full_real_time_queue_drops_its_oldest_frame_and_keeps_the_newest() -> None:
    """Real time, a consumer that takes nothing until the source ended: the queue (capacity 2)
    keeps the two newest of 8 frames, the others counted as pushed out; all were tracked."""
    feed = TrackedFeed(_source([{0: np.full((2, 2), f, np.uint8)} for f in range(8)], 200.0),
                       _ids, realtime=True, clock=time.monotonic, sleep=time.sleep,
                       capacity=2)
    while not feed.exhausted:
        time.sleep(0.01)
    time.sleep(0.05)
    got = []
    while (frame := feed.get()) is not None:
        got.append(frame.index)
    assert got == [6, 7] and feed.overflow == 6 and feed.tracked == 8
    assert [index for _, index in feed.arrivals()] == list(range(8))


def test_a_tracking_error_reaches_the_consumer_after_the_frames_before_it() -> None:
    def track(images: dict[int, np.ndarray]) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        if int(images[0][0, 0]) == 3:
            raise ValueError("frame 3: image is 2x2 pixels, expected 640x480")
        return _ids(images)

    feed = TrackedFeed(_source([{0: np.full((2, 2), f, np.uint8)} for f in range(6)]), track,
                       realtime=False, clock=time.monotonic, sleep=time.sleep, capacity=2)
    got = [feed.get().index for _ in range(3)]  # type: ignore[union-attr]
    with pytest.raises(ValueError, match="frame 3: image is 2x2"):
        feed.get()
    assert got == [0, 1, 2]


def test_closing_a_feed_of_an_endless_source_stops_its_thread() -> None:
    def endless() -> Iterator[tuple[int, float, dict[int, np.ndarray]]]:
        f = 0
        while True:
            yield f, f / 30.0, {0: np.zeros((2, 2), np.uint8)}
            f += 1

    feed = TrackedFeed(endless(), _ids, realtime=False, clock=time.monotonic,
                       sleep=time.sleep, capacity=2)
    assert feed.get() is not None
    feed.close()  # the thread waits for room in the queue: closing wakes and ends it
    assert feed._thread is not None and not feed._thread.is_alive()


def test_tracking_in_a_process_gives_the_tracks_of_the_same_trackers_here() -> None:
    """The same images tracked by a TrackingProcess and by KLTTrackers in this process: the
    same ids and pixels, frame by frame; a wrong image raises its ValueError here, naming the
    frame, and the process goes on."""
    frames = _images(8)
    here = {cam: KLTTracker(SIZE) for cam in frames[0]}
    with TrackingProcess({cam: SIZE for cam in frames[0]}) as process:
        for images in frames:
            there = process.track(images)
            for cam, image in images.items():
                ids, uv = here[cam].update(image)
                np.testing.assert_array_equal(there[cam][0], ids)
                np.testing.assert_array_equal(there[cam][1], uv)
        with pytest.raises(ValueError, match="frame 8: image is 100x50 pixels"):
            process.track({0: np.zeros((50, 100), np.uint8)})
        assert len(process.track(frames[0])[1][0]) > 0


def test_a_video_source_read_and_tracked_in_a_process_equals_tracking_it_here(
        tmp_path: Path) -> None:
    """Two videos described by a SourceSpec, read and tracked in a process (every frame, not
    real time): each frame's tracks equal those of KLTTrackers fed the same videos here."""
    frames = _images(10)
    files = []
    for cam in (0, 1):
        path = tmp_path / f"cam_{cam}.avi"
        writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, SIZE, False)
        for images in frames:
            writer.write(images[cam])
        writer.release()
        files.append(str(path))
    spec = SourceSpec("video", (0, 2), paths=tuple(files))
    here = {cam: KLTTracker(SIZE) for cam in (0, 2)}
    expected = [{cam: here[cam].update(images[cam]) for cam in (0, 2)}
                for _, _, images in spec.frames()]
    source = ProcessSource(spec, {0: SIZE, 2: SIZE}, realtime=False)
    try:
        got = list(source)
    finally:
        source.close()
    assert [frame.index for frame, _, _, _ in got] == list(range(10)) == list(range(len(expected)))
    assert [i for _, arrivals, _, _ in got for _, i in arrivals] == list(range(10))
    for (frame, _, untracked, overflow), tracks in zip(got, expected, strict=True):
        assert untracked == overflow == 0
        for cam in (0, 2):
            np.testing.assert_array_equal(frame.tracks[cam][0], tracks[cam][0])
            np.testing.assert_array_equal(frame.tracks[cam][1], tracks[cam][1])


def test_a_source_the_process_cannot_open_raises_here_naming_it(tmp_path: Path) -> None:
    source = ProcessSource(SourceSpec("video", (0,), paths=(str(tmp_path / "none.mp4"),)),
                           {0: SIZE}, realtime=False)
    try:
        with pytest.raises(ValueError, match="none.mp4"):
            list(source)
    finally:
        source.close()
    with pytest.raises(ValueError, match="SourceSpec.kind = 'dvd'"):
        SourceSpec("dvd", (0,))


def test_the_mask_of_new_corners_is_the_one_circles_draw() -> None:
    """away_from stamps the disks cv2.circle fills, points near and beyond the edges too."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        uv = rng.uniform(-20, 660, (int(rng.integers(0, 200)), 2)).astype(np.float32)
        radius = int(rng.integers(1, 16))
        drawn = np.full((480, 640), 255, np.uint8)
        for u, v in uv:
            cv2.circle(drawn, (int(round(u)), int(round(v))), radius, 0, -1)
        np.testing.assert_array_equal(away_from((480, 640), uv, radius), drawn)


def test_pyramid_levels_follow_the_motion_and_a_jump_loses_no_tracks() -> None:
    """Slow motion uses fewer pyramid levels than the most; a sudden 40-pixel jump after it is
    followed again with all of them, and the tracks survive as with a fixed pyramid."""
    tracker = KLTTracker(SIZE, TrackerOptions(motion_levels=True))
    assert tracker.levels_for(None) == tracker.options.levels
    assert tracker.levels_for(1.0) == 0 and tracker.levels_for(100.0) == tracker.options.levels
    assert tracker.levels_for(3.0) < tracker.levels_for(10.0)
    base = texture(7, (480, 800))
    shifts = [0, 1, 2, 3, 43, 44]  # a jump of 40 pixels after slow steps
    fixed = KLTTracker(SIZE, TrackerOptions(motion_levels=False))
    for x in shifts:
        ids, _ = tracker.update(base[:, x:x + 640])
        fixed_ids, _ = fixed.update(base[:, x:x + 640])
    assert tracker.refollowed == 1
    assert len(np.intersect1d(ids, fixed_ids)) >= 0.95 * len(fixed_ids)


@pytest.mark.parametrize("model_sigma", [None, (1e-3, math.radians(0.2))])
def test_both_measurement_models_run_live_with_keyframes(
        model_sigma: tuple[float, float] | None) -> None:
    """The live loop over a simulated recording's frames (their tracks handed over by a
    stand-in tracker in the tracking stage's thread), every frame, keyframes on: every frame
    comes out once and in order, the frames between keyframes say so, and the final estimates
    are near the truth: the exact model within 0.1 deg RMS (measured 0.038 / 0.042 / 0.039,
    solving at every frame 0.039 / 0.041 / 0.039), model error as noise within 2 deg (1.23 /
    0.92 / 0.76; every frame 1.40 / 0.65 / 0.61: 45 frames tell the loose model little)."""
    from apcc_graph.estimation.keyframes import KeyframeRule
    from apcc_graph.estimation.live import LiveEstimator
    from apcc_graph.estimation.options import GraphOptions
    from apcc_graph.estimation.smoother_options import SmootherOptions, WindowOptions
    from apcc_graph.io.robot_file import load_robot
    from apcc_graph.simulation.simulator import simulate

    robot = load_robot(Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml")
    sim = simulate(robot, 45, noise_px=0.5, outlier_fraction=0.0, seed=4, scene="room",
                   n_points=3000)
    seq, truth = sim.sequence, sim.sequence.thetas
    assert truth is not None
    live = LiveEstimator(robot, truth[0], SmootherOptions(window=WindowOptions(lag=0.5),
                                                          keyframes=KeyframeRule()),
                         realtime=False, graph=GraphOptions(model_sigma=model_sigma),
                         tracking="thread")
    assert live.smoother is not None
    assert live.smoother.measurement_model == ("exact" if model_sigma is None else "model noise")

    def frames() -> Iterator[tuple[int, float, dict[int, object]]]:
        for f in range(seq.n_frames):
            yield f, float(seq.timestamps[f]), {-1: seq.frame(f)}

    live._track = lambda images: dict(images[-1].tracks)  # type: ignore[method-assign]
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        got = list(live.run(frames()))
        final = [fr for e in got for fr in e.final] + live.finish()
    assert [e.index for e in got] == [fr.frame for fr in final] == list(range(45))
    assert 0 < sum(e.pending for e in got) < 45
    errors = np.array([fr.thetas for fr in final]) - truth
    limit = 0.1 if model_sigma is None else 2.0
    assert np.all(np.degrees(np.sqrt(np.mean(errors**2, axis=0))) < limit)


def test_the_command_offers_the_places_tracking_runs_that_the_loop_knows() -> None:
    from apcc_graph.cli import live as command
    from apcc_graph.estimation import live
    from apcc_graph.io.robot_file import load_robot

    assert command.TRACKING == live.TRACKING
    robot = load_robot(Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml")
    with pytest.raises(ValueError, match="tracking = 'gpu': expected one of process, thread"):
        live.LiveEstimator(robot, tracking="gpu")


def test_live_names_a_video_it_cannot_open_before_anything_runs(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``apcc-graph live --video`` with a file OpenCV cannot open: exit 1, one line naming that
    file, and no output folder made (the tracking process is never started)."""
    from apcc_graph.cli import main

    robot = Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml"
    frames = _images(3, cams=1)
    good = tmp_path / "good.avi"
    writer = cv2.VideoWriter(str(good), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, SIZE, False)
    for images in frames:
        writer.write(images[0])
    writer.release()
    bad = tmp_path / "not_a_video.mp4"
    bad.write_text("text, not a video")
    out = tmp_path / "out"
    code = main(["live", "--video", f"{good},{bad},{good}", "--robot", str(robot),
                 "--out", str(out), "--theta0-deg", "0,0,0"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and len(err) == 1
    assert "not_a_video.mp4: OpenCV cannot open it as a video" in err[0]
    assert not out.exists()
