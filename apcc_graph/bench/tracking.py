"""``apcc-graph bench tracking``: the KLT tracker against ORB matching on images with known motion.

Images: a seeded multi-scale random texture (640x480, 8-bit), each frame the previous one moved
by a known homography (a pan of a few pixels, a slight rotation and perspective), with Gaussian
sensor noise. Since every pixel's motion is known, each method's correspondences between
consecutive frames are scored against the truth:

- KLT (:class:`apcc_graph.frontend.tracking.KLTTracker`): Shi-Tomasi corners, pyramidal
  Lucas-Kanade, forward-backward check, re-detection;
- ORB: ``cv2.ORB_create`` keypoints and descriptors in every frame, brute-force Hamming matching
  with cross-check between consecutive frames (the usual detector-descriptor peer).

Reported: images per second (all work per image included), correspondences per frame pair, the
median and 95th-percentile error against the true motion (pixels), and the fraction within 1 px.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from apcc_graph.frontend.tracking import KLTTracker

SIZE = (640, 480)


@dataclass(frozen=True)
class TrackingRow:
    """One method's figures."""

    method: str
    images_per_second: float
    pairs_per_frame: float
    median_error: float  # pixels
    p95_error: float  # pixels
    within_1px: float  # fraction


def texture(seed: int, shape: tuple[int, int] = (480, 640)) -> np.ndarray:
    """A seeded random texture with structure at 4, 16 and 64 pixels (8-bit grey)."""
    rng = np.random.default_rng(seed)
    out = np.zeros(shape)
    for scale in (4, 16, 64):
        small = rng.random((shape[0] // scale + 2, shape[1] // scale + 2))
        big = cv2.resize(small, (shape[1] + 2 * scale, shape[0] + 2 * scale),
                         interpolation=cv2.INTER_CUBIC)
        out += big[scale:scale + shape[0], scale:scale + shape[1]]
    out = cv2.GaussianBlur(out, (0, 0), 1.0)
    return ((out - out.min()) / (out.max() - out.min()) * 255).astype(np.uint8)


def _sequence(frames: int, seed: int, noise: float) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Images and the homography from each frame to the next (pixels)."""
    rng = np.random.default_rng(seed)
    world = texture(seed, (SIZE[1] * 2, SIZE[0] * 2))
    offset = np.array([[1, 0, -SIZE[0] / 2], [0, 1, -SIZE[1] / 2], [0, 0, 1.0]])
    images, steps, H = [], [], np.eye(3)
    for _ in range(frames):
        view = cv2.warpPerspective(world, H @ offset, SIZE, flags=cv2.INTER_LINEAR)
        noisy = view + rng.normal(0.0, noise, view.shape)
        images.append(np.clip(noisy, 0, 255).astype(np.uint8))
        angle = rng.normal(0.0, 0.003)
        step = np.array([[np.cos(angle), -np.sin(angle), rng.normal(3.0, 1.0)],
                         [np.sin(angle), np.cos(angle), rng.normal(0.0, 1.0)],
                         [rng.normal(0, 2e-6), rng.normal(0, 2e-6), 1.0]])
        steps.append(step)
        H = step @ H
    return images, steps[:-1]


def _apply(H: np.ndarray, uv: np.ndarray) -> np.ndarray:
    p = np.column_stack([uv, np.ones(len(uv))]) @ H.T
    return p[:, :2] / p[:, 2:]


def _row(method: str, seconds: float, n_images: int, errors: list[np.ndarray]) -> TrackingRow:
    e = np.concatenate(errors) if errors else np.zeros(0)
    return TrackingRow(method, n_images / seconds, len(e) / max(len(errors), 1),
                       float(np.median(e)) if len(e) else float("nan"),
                       float(np.percentile(e, 95)) if len(e) else float("nan"),
                       float(np.mean(e < 1.0)) if len(e) else float("nan"))


def run_tracking_benchmark(frames: int = 200, seed: int = 0,
                           noise: float = 2.0) -> tuple[TrackingRow, ...]:
    """Run both methods on the same images (see the module docstring)."""
    images, steps = _sequence(frames, seed, noise)
    # KLT
    tracker = KLTTracker(SIZE)
    start = time.perf_counter()
    outputs = [tracker.update(image) for image in images]
    klt_seconds = time.perf_counter() - start
    errors = []
    for f, H in enumerate(steps):
        (ids_a, uv_a), (ids_b, uv_b) = outputs[f], outputs[f + 1]
        _, ia, ib = np.intersect1d(ids_a, ids_b, return_indices=True)
        errors.append(np.linalg.norm(uv_b[ib] - _apply(H, uv_a[ia]), axis=1))
    rows = [_row("KLT (ours)", klt_seconds, len(images), errors)]
    # ORB + brute-force matching
    orb = cv2.ORB_create(nfeatures=500)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
    start = time.perf_counter()
    detected = [orb.detectAndCompute(image, None) for image in images]
    matches = [matcher.match(detected[f][1], detected[f + 1][1])
               if detected[f][1] is not None and detected[f + 1][1] is not None else []
               for f in range(len(steps))]
    orb_seconds = time.perf_counter() - start
    errors = []
    for f, H in enumerate(steps):
        kp_a, kp_b = detected[f][0], detected[f + 1][0]
        if not matches[f]:
            continue
        uv_a = np.array([kp_a[m.queryIdx].pt for m in matches[f]])
        uv_b = np.array([kp_b[m.trainIdx].pt for m in matches[f]])
        errors.append(np.linalg.norm(uv_b - _apply(H, uv_a), axis=1))
    rows.append(_row("ORB + BFMatcher (cross-check)", orb_seconds, len(images), errors))
    return tuple(rows)


def format_tracking_benchmark(rows: tuple[TrackingRow, ...], frames: int, noise: float) -> str:
    """The table ``apcc-graph bench tracking`` prints."""
    out = [f"bench tracking: {frames} images of {SIZE[0]}x{SIZE[1]}, known homographies "
           f"between frames, {noise:g} grey levels of noise",
           f"  {'method':<30} {'images/s':>9} {'pairs/frame':>12} {'median px':>10} "
           f"{'p95 px':>8} {'< 1 px':>7}"]
    for r in rows:
        out.append(f"  {r.method:<30} {r.images_per_second:9.1f} {r.pairs_per_frame:12.1f} "
                   f"{r.median_error:10.3f} {r.p95_error:8.3f} {r.within_1px:7.1%}")
    ours = rows[0]
    for r in rows[1:]:
        out.append(f"  ours vs {r.method}: {ours.images_per_second / r.images_per_second:.1f}x "
                   f"the images per second, {r.median_error / ours.median_error:.1f}x smaller "
                   "median error")
    return "\n".join(out)
