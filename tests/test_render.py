"""Rendered tip-camera images: geometry of the ray caster, textures, sensor, tracking on pixels."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph.frontend.tracking import track_images
from apcc_graph.model.camera import TipCamera
from apcc_graph.simulation.render import (
    TEXTURE_SIZE,
    SensorModel,
    TexturedRoom,
    procedural_textures,
    render_images,
    textured_room,
    write_sequence_images,
)

CAMERA = TipCamera(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480)


@pytest.fixture(scope="module")
def room() -> TexturedRoom:
    return textured_room(np.array([0.0, 0.0, 0.45]), np.array([2.0, 2.0, 1.5]), "procedural",
                         seed=3)


def pose(rotvec: tuple[float, float, float], position: tuple[float, float, float]) -> np.ndarray:
    out = np.eye(4)
    out[:3, :3] = cv2.Rodrigues(np.asarray(rotvec, dtype=float))[0]
    out[:3, 3] = position
    return out


# ----------------------------------------------------------------------------------- geometry
@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3),
       st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3).filter(
           lambda d: np.linalg.norm(d) > 1e-3))
def test_rays_hit_the_nearest_wall(origin: list[float], direction: list[float]) -> None:
    room = TexturedRoom(np.array([0.1, -0.2, 0.3]), np.array([1.5, 1.2, 1.1]),
                        procedural_textures(0))
    p = room.centre + np.asarray(origin) * (room.half_size - 0.05)
    d = np.asarray(direction)[:, None]
    t, wall = room.intersect(p, d)
    hit = p + t[0] * d[:, 0]
    axis, side = divmod(int(wall[0]), 2)
    assert t[0] > 0
    # On the wall it names, inside the box everywhere else.
    expected = room.centre[axis] + (1 if side else -1) * room.half_size[axis]
    assert hit[axis] == pytest.approx(expected, abs=1e-9)
    assert np.all(np.abs(hit - room.centre) <= room.half_size + 1e-9)
    # No wall is hit earlier: the segment up to the hit stays inside.
    for s in np.linspace(0.0, 0.999, 7):
        assert np.all(np.abs(p + s * t[0] * d[:, 0] - room.centre) < room.half_size + 1e-12)


def test_render_projects_the_texture_where_the_camera_model_says(room: TexturedRoom) -> None:
    """A pixel shows the texture at the wall point its ray hits: sample the texture there
    (independently of the renderer's atlas maps) and compare at random pixels."""
    world_T_cam = pose((0.3, -0.2, 0.1), (0.2, -0.1, 0.6))
    image = room.render(CAMERA, world_T_cam, supersample=1)
    assert image.shape == (480, 640) and image.dtype == np.float32
    rng = np.random.default_rng(0)
    uv = rng.uniform([5, 5], [635, 475], (200, 2)).round()
    points = room.backproject(CAMERA, world_T_cam, uv)
    _, wall = room.intersect(world_T_cam[:3, 3], (points - world_T_cam[:3, 3]).T)
    expected = np.array([_texel(room, q, int(w)) for q, w in zip(points, wall, strict=True)])
    got = image[uv[:, 1].astype(int), uv[:, 0].astype(int)]
    assert np.median(np.abs(got - expected)) < 0.01
    assert np.mean(np.abs(got - expected) < 0.03) > 0.95


def _texel(room: TexturedRoom, point: np.ndarray, wall: int) -> float:
    """Bilinear lookup in the wall's own tile, written out here (not the renderer's code)."""
    axis = wall // 2
    a, b = [k for k in range(3) if k != axis]
    lo = room.centre - room.half_size
    c = (point[a] - lo[a]) * room.texels_per_metre % TEXTURE_SIZE
    r = (point[b] - lo[b]) * room.texels_per_metre % TEXTURE_SIZE
    tile = room.textures[wall]
    c0, r0 = int(math.floor(c)), int(math.floor(r))
    fc, fr = c - c0, r - r0
    n = TEXTURE_SIZE

    def at(rr: int, cc: int) -> float:
        return float(tile[rr % n, cc % n])

    return ((1 - fr) * ((1 - fc) * at(r0, c0) + fc * at(r0, c0 + 1))
            + fr * ((1 - fc) * at(r0 + 1, c0) + fc * at(r0 + 1, c0 + 1)))


def test_camera_outside_the_room_is_refused(room: TexturedRoom) -> None:
    with pytest.raises(ValueError, match="outside the room"):
        room.render(CAMERA, pose((0, 0, 0), (5.0, 0.0, 0.0)))
    with pytest.raises(ValueError, match="supersample"):
        room.render(CAMERA, pose((0, 0, 0), (0.0, 0.0, 0.0)), supersample=0)


@pytest.mark.parametrize("kwargs, field", [
    ({"half_size": np.array([1.0, -1.0, 1.0])}, "half_size"),
    ({"centre": np.array([0.0, np.nan, 0.0])}, "centre"),
    ({"textures": procedural_textures(0)[:5]}, "textures"),
    ({"texels_per_metre": 0.0}, "texels_per_metre"),
])
def test_room_validates_its_fields(kwargs: dict, field: str) -> None:
    args = {"centre": np.zeros(3), "half_size": np.ones(3), "textures": procedural_textures(0)}
    args.update(kwargs)
    with pytest.raises(ValueError, match=field):
        TexturedRoom(**args)


def test_lens_distortion_is_rendered_as_the_camera_projects() -> None:
    """With distortion, a wall point projects (OpenCV) to where the renderer drew it: compare
    the distorted render with the pinhole render warped by the distortion model."""
    room = textured_room(np.zeros(3), np.array([2.0, 2.0, 2.0]), "procedural", seed=1)
    distorted = TipCamera(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480,
                          distortion=(-0.2, 0.05, 0.0, 0.0))
    world_T_cam = pose((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    img = room.render(distorted, world_T_cam, supersample=1)
    pin = room.render(CAMERA, world_T_cam, supersample=1)
    # Where does distorted pixel (u, v) look? Its bearing, projected with the pinhole camera.
    vv, uu = np.mgrid[0:480:8, 0:640:8]
    uv = np.column_stack([uu.ravel(), vv.ravel()]).astype(float)
    pin_uv = CAMERA.project(distorted.bearings(uv))
    inside = CAMERA.in_image(pin_uv)
    warped = cv2.remap(pin, pin_uv[:, 0].reshape(vv.shape).astype(np.float32),
                       pin_uv[:, 1].reshape(vv.shape).astype(np.float32), cv2.INTER_LINEAR)
    diff = np.abs(img[vv, uu] - warped).ravel()[inside]
    assert np.median(diff) < 0.02
    assert np.median(np.abs(img - pin)) > 0.05  # the distortion is visible at all


# ----------------------------------------------------------------------------------- textures
def test_procedural_textures_are_seeded_and_tile_without_a_seam() -> None:
    a, b, c = procedural_textures(1), procedural_textures(1), procedural_textures(2)
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert not np.array_equal(a[0], c[0])
    for tile in a:
        assert tile.shape == (TEXTURE_SIZE, TEXTURE_SIZE) and tile.dtype == np.float32
        assert 0.0 <= tile.min() and tile.max() <= 1.0 and tile.std() > 0.1
        # Periodic: the step across the wrap is like a step inside the tile.
        inner = np.mean(np.abs(np.diff(tile, axis=1)))
        seam = np.mean(np.abs(tile[:, 0] - tile[:, -1]))
        assert seam < 3 * inner


def test_skimage_textures_load_offline() -> None:
    pytest.importorskip("skimage")
    room = textured_room(np.zeros(3), np.ones(3) * 2, "skimage")
    assert len(room.textures) == 6
    assert all(t.std() > 0.1 for t in room.textures)
    # Six different images.
    assert len({t.tobytes() for t in room.textures}) == 6


def test_unknown_texture_source() -> None:
    with pytest.raises(ValueError, match="texture_source"):
        textured_room(np.zeros(3), np.ones(3), "bricks")


# ------------------------------------------------------------------------------------- sensor
def test_sensor_noise_blur_and_exposure() -> None:
    flat = np.full((100, 120), 0.5, np.float32)
    rng = np.random.default_rng(0)
    noisy = SensorModel(noise_grey=3.0).expose(flat, rng)
    assert noisy.dtype == np.uint8
    assert abs(noisy.astype(float).mean() - 110.0) < 0.5
    assert noisy.astype(float).std() == pytest.approx(3.0, rel=0.1)
    clean = SensorModel(noise_grey=0.0).expose(flat, rng, gain=1.2)
    assert np.all(clean == 132)
    edge = np.zeros((50, 50), np.float32)
    edge[:, 25:] = 1.0
    blurred = SensorModel(noise_grey=0.0, blur_sigma=2.0).expose(edge, rng)
    assert 0 < blurred[0, 24] < 220 and 0 < blurred[0, 25] < 220
    gains = SensorModel(exposure_change=0.2).gains(300, np.random.default_rng(1))
    assert np.all(np.abs(gains - 1.0) <= 0.2 + 1e-12) and np.ptp(gains) > 0.2
    assert np.max(np.abs(np.diff(gains))) < 0.02  # smooth, frame to frame
    assert np.all(SensorModel().gains(10, rng) == 1.0)
    for bad in ({"noise_grey": -1.0}, {"blur_sigma": math.nan}, {"exposure_change": 1.0},
                {"brightness": 0.0}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            SensorModel(**bad)


# ---------------------------------------------------------------------------------- tracking
def test_tracking_on_a_rendered_pair_recovers_the_true_correspondences(
        room: TexturedRoom) -> None:
    """KLT on two rendered views; the truth of a tracked pixel in view a is the wall point it
    shows, projected into view b. Most tracks agree within 0.5 px."""
    a = pose((0.05, 0.02, 0.0), (0.1, 0.0, 0.5))
    b = pose((0.08, 0.0, 0.03), (0.12, 0.01, 0.52))
    images = list(render_images(room, CAMERA, np.stack([a, b]), SensorModel(noise_grey=2.0),
                                seed=0))
    tracks = track_images(images, (640, 480))
    first, second = tracks.frames == 0, tracks.frames == 1
    ids, ia, ib = np.intersect1d(tracks.track_ids[first], tracks.track_ids[second],
                                 return_indices=True)
    assert len(ids) > 150
    uv_a = tracks.uv[first][ia]
    uv_b = tracks.uv[second][ib]
    points = room.backproject(CAMERA, a, uv_a)
    in_b = (points - b[:3, 3]) @ b[:3, :3]
    truth_b = CAMERA.project(in_b)
    err = np.linalg.norm(uv_b - truth_b, axis=1)
    assert np.median(err) < 0.15  # measured 0.04-0.06
    assert np.mean(err < 0.5) > 0.9


def test_write_sequence_images_is_atomic_and_deterministic(tmp_path: Path,
                                                           room: TexturedRoom) -> None:
    poses = {0: np.stack([pose((0, 0, 0), (0, 0, 0.3 + 0.01 * f)) for f in range(3)])}
    cameras = {0: TipCamera(fx=100.0, fy=100.0, cx=32.0, cy=24.0, width=64, height=48)}
    out = write_sequence_images(tmp_path / "a", room, cameras, poses, seed=5)
    files = sorted(p.relative_to(out).as_posix() for p in out.rglob("*.png"))
    assert files == ["cam_1/000000.png", "cam_1/000001.png", "cam_1/000002.png"]
    again = write_sequence_images(tmp_path / "b", room, cameras, poses, seed=5)
    for name in files:
        assert (out / name).read_bytes() == (again / name).read_bytes()
    # No staging folder is left behind; a failure leaves the previous images as they were.
    assert [p.name for p in (tmp_path / "a").iterdir()] == ["images"]
    before = (out / files[0]).read_bytes()
    bad = {0: np.stack([pose((0, 0, 0), (0, 0, 0.3)), pose((0, 0, 0), (9.0, 0, 0))])}
    with pytest.raises(ValueError, match="outside the room"):
        write_sequence_images(tmp_path / "a", room, cameras, bad, seed=5)
    assert [p.name for p in (tmp_path / "a").iterdir()] == ["images"]
    assert (out / files[0]).read_bytes() == before
    assert len(list(out.rglob("*.png"))) == 3


# -------------------------------------------------------------------------------- end to end
def test_images_to_tracks_to_smoother_end_to_end() -> None:
    """The end-to-end target on a CI-sized rendered sequence (40 frames, 3 cameras):
    every segment under 1 deg and at most 1.5x the same pipeline fed with simulated 1 px tracks
    of the same motion. Measured (seed 1): 0.05 / 0.04 / 0.03 deg against 0.22 / 0.21 / 0.21."""
    pytest.importorskip("skimage")
    from apcc_graph.bench.images import format_images_benchmark, run_images_benchmark

    runs = run_images_benchmark(frames=40, seeds=(1,))
    ours = runs[0].rms[("smoother", "images")]
    peer = runs[0].rms[("smoother", "tracks")]
    assert np.all(ours < 1.0)
    assert np.all(ours <= 1.5 * peer)
    assert runs[0].tracks_per_frame["images"] > 100
    text = format_images_benchmark(runs, 40, 2.0)
    assert "all seeds: met" in text and "images/s" in text
