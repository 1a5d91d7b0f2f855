"""KLT tracking on synthetic textured images with known motion."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from apcc_graph.bench.tracking import texture
from apcc_graph.frontend.tracking import KLTTracker, TrackerOptions, track_images

ROBOT = Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml"


def warp(image: np.ndarray, H: np.ndarray) -> np.ndarray:
    return cv2.warpPerspective(image, H, (image.shape[1], image.shape[0]),
                               flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)


def apply(H: np.ndarray, uv: np.ndarray) -> np.ndarray:
    p = np.column_stack([uv, np.ones(len(uv))]) @ H.T
    return p[:, :2] / p[:, 2:]


def test_tracks_follow_a_known_homography_within_half_a_pixel() -> None:
    base = texture(1)
    H = np.array([[1.0, 0.01, 3.2], [-0.008, 1.0, -2.1], [1e-5, -1e-5, 1.0]])
    tracker = KLTTracker((640, 480))
    ids0, uv0 = tracker.update(base)
    ids1, uv1 = tracker.update(warp(base, H))
    assert len(ids0) >= 250  # detection fills max_tracks on a rich texture
    common, i0, i1 = np.intersect1d(ids0, ids1, return_indices=True)
    assert len(common) > 0.8 * len(ids0)
    error = np.linalg.norm(uv1[i1] - apply(H, uv0[i0]), axis=1)
    assert np.median(error) < 0.1
    assert np.mean(error < 0.5) > 0.95


def test_forward_backward_check_ends_tracks_on_occluded_content() -> None:
    base = texture(2)
    moved = base.copy()
    moved[100:300, 200:450] = texture(3)[100:300, 200:450]  # a new object covers this area
    tracker = KLTTracker((640, 480))
    ids0, uv0 = tracker.update(base)
    ids1, _ = tracker.update(moved)
    occluded = ((uv0[:, 0] > 215) & (uv0[:, 0] < 435) & (uv0[:, 1] > 115) & (uv0[:, 1] < 285))
    assert occluded.sum() > 20
    survived = np.isin(ids0[occluded], ids1)
    assert survived.mean() < 0.2
    assert np.isin(ids0[~occluded], ids1).mean() > 0.8


def test_new_tracks_fill_in_with_fresh_ids_when_old_ones_leave() -> None:
    base = texture(4, (480, 1200))
    options = TrackerOptions(max_tracks=200, min_tracks=150)
    tracker = KLTTracker((640, 480), options)
    seen: set[int] = set()
    counts = []
    for step in range(12):  # pan right by 25 px per frame: old tracks leave on the left
        ids, uv = tracker.update(np.ascontiguousarray(base[:, 25 * step:25 * step + 640]))
        counts.append(len(ids))
        assert len(np.unique(ids)) == len(ids)
        assert np.all((uv >= 0) & (uv <= [639, 479]))
        seen |= set(ids.tolist())
    assert min(counts[1:]) >= 100  # re-detection keeps the tracks up
    assert len(seen) > 250  # ids are never reused: many tracks started


def test_track_images_returns_sequence_tracks_in_frame_order() -> None:
    base = texture(5)
    shifts = [np.array([[1, 0, 1.5 * k], [0, 1, -0.7 * k], [0, 0, 1.0]]) for k in range(5)]
    tracks = track_images([warp(base, H) for H in shifts], (640, 480))
    assert np.all(np.diff(tracks.frames) >= 0) and tracks.frames.max() == 4
    # A track seen in frames 0 and 4 moved by the known shift.
    first = {int(i): uv for i, uv in zip(tracks.track_ids[tracks.frames == 0],
                                         tracks.uv[tracks.frames == 0], strict=True)}
    last = {int(i): uv for i, uv in zip(tracks.track_ids[tracks.frames == 4],
                                        tracks.uv[tracks.frames == 4], strict=True)}
    both = sorted(set(first) & set(last))
    assert len(both) > 100
    moved = np.array([last[i] - first[i] for i in both])
    assert np.median(np.abs(moved - [6.0, -2.8]), axis=0).max() < 0.1


def test_bad_images_are_refused_with_the_frame_named() -> None:
    tracker = KLTTracker((640, 480))
    with pytest.raises(ValueError, match=r"frame 0: image is 320x240 pixels, expected 640x480"):
        tracker.update(np.zeros((240, 320), np.uint8))
    with pytest.raises(ValueError, match="frame 0: image of shape"):
        tracker.update(np.zeros((480, 640, 2), np.uint8))
    with pytest.raises(ValueError, match="min_tracks"):
        TrackerOptions(min_tracks=0)
    with pytest.raises(ValueError, match="odd"):
        TrackerOptions(window=20)


# ------------------------------------------------------------------ a sequence folder of images
@pytest.fixture()
def image_folder(tmp_path):
    """A 6-frame sequence folder whose camera 1 images pan across a texture (no tracks yet)."""
    from apcc_graph.io.robot_file import load_robot
    from apcc_graph.io.sequence_folder import save_sequence
    from apcc_graph.model.sequence import Sequence

    robot = load_robot(ROBOT)
    source = tmp_path / "source"
    source.mkdir()
    base = texture(6, (480, 700))
    files = {}
    for f in range(6):
        path = source / f"{f:06d}.png"
        cv2.imwrite(str(path), np.ascontiguousarray(base[:, 4 * f:4 * f + 640]))
        files[f] = path
    seq = Sequence(robot, np.arange(6) / 30.0, images={0: files})
    folder = tmp_path / "seq"
    save_sequence(seq, folder)
    return folder


def test_track_sequence_writes_tracks_that_load_back(image_folder) -> None:
    from apcc_graph.frontend.tracking import track_sequence
    from apcc_graph.io.sequence_folder import load_sequence

    written = track_sequence(image_folder)
    assert written == [image_folder / "tracks" / "cam_1.csv"]
    seq = load_sequence(image_folder)
    corr = seq.correspondences(0, 0, 5)
    assert len(corr) > 150
    # The images pan by 4 px per frame: u decreases by 20 px over 5 frames, v stays.
    shift = np.median(corr.uv_b - corr.uv_a, axis=0)
    assert abs(shift[0] + 20.0) < 0.1 and abs(shift[1]) < 0.1
    # Tracks are there now: a second run refuses unless forced.
    with pytest.raises(ValueError, match="cam_1.csv: already holds .* use --force"):
        track_sequence(image_folder)
    assert track_sequence(image_folder, force=True) == written


def test_track_sequence_names_the_bad_image_and_writes_nothing(image_folder) -> None:
    from apcc_graph.frontend.tracking import track_sequence

    bad = image_folder / "images" / "cam_1" / "000003.png"
    bad.write_bytes(b"not a png")
    with pytest.raises(ValueError, match="000003.png: not a readable image"):
        track_sequence(image_folder)
    cv2.imwrite(str(bad), np.zeros((240, 320), np.uint8))
    with pytest.raises(ValueError, match="000003.png: frame 3: image is 320x240 pixels"):
        track_sequence(image_folder)
    bad.unlink()
    with pytest.raises(ValueError, match="000003.png: missing"):
        track_sequence(image_folder)
    tracks = image_folder / "tracks" / "cam_1.csv"
    assert not tracks.exists() or tracks.read_text().count("\n") == 1  # header only, as saved


def test_track_command(image_folder, capsys) -> None:
    from apcc_graph.cli import main

    assert main(["track", str(image_folder)]) == 0
    assert "cam_1.csv" in capsys.readouterr().out
    assert main(["track", str(image_folder)]) == 1
    assert "use --force" in capsys.readouterr().err
    assert main(["track", str(image_folder), "--force"]) == 0
