"""The backbone-pose reader's quaternion-order check, swept over seeded synthetic recordings.

``python tests/test_quaternion_order.py [N [MOUNT_DEG]]`` prints the full sweep's figures: N
synthetic recordings (seeds 0 to N-1, 200 by default; markers mounted with rotations of ~MOUNT_DEG,
3 by default) and 50 random windows of 1-5 s of each shipped real recording, in both orders.
"""

from __future__ import annotations

import sys
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from apcc_graph.io.backbone_poses import (
    BackbonePoses,
    load_backbone_poses,
    save_backbone_poses,
)
from apcc_graph.io.quaternion_order import (
    MIN_TELLING_PAIRS,
    OrderEvidence,
    _arc_ends,
    quaternion_order_evidence,
)
from apcc_graph.io.units import UnitsWarning
from apcc_graph.model.kinematics import pcc_transform

REAL = Path(__file__).resolve().parent.parent / "data" / "real_tdcr"
ARCS = {name: np.array([0.0, 0.1165, 0.233, 0.3495, 0.466])
        for name in ("slow_free_space", "impulse_2")}


def _rotvec(v: np.ndarray) -> np.ndarray:
    """``(..., 3, 3)`` rotation matrices of rotation vectors ``(..., 3)`` (Rodrigues)."""
    v = np.asarray(v, dtype=float)
    angle = np.linalg.norm(v, axis=-1)[..., None, None]
    k = np.zeros((*v.shape[:-1], 3, 3))
    k[..., 0, 1], k[..., 0, 2], k[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    k = k - np.swapaxes(k, -1, -2)
    safe = np.where(angle > 1e-12, angle, 1.0)
    s = np.where(angle > 1e-12, np.sin(angle) / safe, 1.0)
    c = np.where(angle > 1e-12, (1.0 - np.cos(angle)) / safe ** 2, 0.5)
    return np.eye(3) + s * k + c * (k @ k)


@dataclass
class Recording:
    """A synthetic recording: marker arc lengths, poses ``(T, M, 4, 4)``, present ``(T, M)``,
    and how bent it is (the largest bend between neighbouring markers, radians)."""

    arclengths: np.ndarray
    poses: np.ndarray
    present: np.ndarray
    max_bend: float
    kind: str
    clean: np.ndarray


def synthetic_recording(seed: int, mount_deg: float = 3.0) -> Recording:
    """A seeded motion-capture recording of a 1-3 segment constant-curvature robot.

    Markers at the base and 1-3 places per segment (evenly, the last at the segment's end; the
    shipped recordings have 2), 20-800 samples at 16.7 Hz, each segment's bend following a slow
    sinusoid whose size is drawn from "nearly straight" (< 1.5 deg), "small" (3-15 deg) or
    "large" (15-120 deg), its bending plane drifting. Every marker has a fixed mounting offset
    (~N(0, 2 mm) per axis, a rotation of ~N(0, 3 deg) about a random axis); per sample, position
    noise of 0.5-2 mm and rotation noise of 0.5-2 deg (per recording) and ~2% occlusions. The
    robot's base sits near the world origin (as in the shipped recordings) or, one time in
    four, in an arbitrary orientation.
    """
    rng = np.random.default_rng(seed)
    n_seg = int(rng.integers(1, 4))
    lengths = rng.uniform(0.08, 0.3, n_seg)
    per_seg = int(rng.integers(1, 4))
    kind = str(rng.choice(["straight", "small", "large"], p=[0.2, 0.3, 0.5]))
    top = {"straight": 1.5, "small": 15.0, "large": 120.0}[kind]
    low = {"straight": 0.0, "small": 3.0, "large": 15.0}[kind]
    n_t = int(rng.integers(20, 801))
    t = np.arange(n_t) / 16.7
    theta = np.empty((n_t, n_seg))
    psi = np.empty((n_t, n_seg))
    for i in range(n_seg):
        amp = np.radians(rng.uniform(low, top))
        mean = rng.uniform(0.0, 1.0) * amp
        freq = rng.uniform(0.02, 0.5)
        theta[:, i] = mean + (amp - mean) * np.sin(2 * np.pi * freq * t + rng.uniform(0, 6.3))
        psi[:, i] = rng.uniform(-np.pi, np.pi) + rng.uniform(0, 2.0) * np.sin(
            2 * np.pi * rng.uniform(0.01, 0.2) * t)
    if rng.uniform() < 0.75:
        base = np.eye(4)
        base[:3, :3] = _rotvec(rng.normal(0, np.radians(2.0), 3))
        base[:3, 3] = rng.normal(0, 0.003, 3)
    else:
        base = np.eye(4)
        base[:3, :3] = _rotvec(rng.normal(0, 2.0, 3))
        base[:3, 3] = rng.normal(0, 0.5, 3)
    arcs, frames = [0.0], [np.broadcast_to(base, (n_t, 4, 4))]
    here = np.broadcast_to(base, (n_t, 4, 4))
    for i in range(n_seg):
        # not quite an arc: the curvature changes linearly along the segment by up to +-60 %
        slope, steps = rng.uniform(-0.6, 0.6), 8 * per_seg
        centres = (np.arange(steps) + 0.5) / steps
        share = (1.0 + slope * (centres - 0.5)) / steps
        for k in range(steps):
            step = pcc_transform(theta[:, i] * share[k], lengths[i] / steps, psi[:, i])
            here = here @ step
            if (k + 1) % 8 == 0:
                frames.append(here)
                arcs.append(float(np.sum(lengths[:i]) + lengths[i] * (k + 1) / steps))
    poses = np.stack(frames, axis=1).copy()  # (T, M, 4, 4) backbone frames
    n_m = poses.shape[1]
    mount = np.tile(np.eye(4), (n_m, 1, 1))
    mount[:, :3, :3] = _rotvec(_random_directions(rng, n_m)
                               * rng.normal(0, np.radians(mount_deg), (n_m, 1)))
    mount[:, :3, 3] = rng.normal(0, 0.002, (n_m, 3))
    clean = poses.copy()
    poses = poses @ mount
    sigma_p, sigma_r = rng.uniform(0.0005, 0.002), np.radians(rng.uniform(0.5, 2.0))
    poses[..., :3, 3] += rng.normal(0, sigma_p, (n_t, n_m, 3))
    poses[..., :3, :3] = poses[..., :3, :3] @ _rotvec(rng.normal(0, sigma_r / np.sqrt(3),
                                                                 (n_t, n_m, 3)))
    present = rng.uniform(size=(n_t, n_m)) > 0.02
    bends = []
    for a in range(n_m - 1):
        rel = np.einsum("tji,tjk->tik", frames[a][:, :3, :3], frames[a + 1][:, :3, :3])
        bends.append(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)))
    return Recording(np.array(arcs), poses, present, float(np.max(bends)), kind, clean)


def _random_directions(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def swapped_reading(poses: np.ndarray) -> np.ndarray:
    """The poses as a reader gets them when their quaternions are written x, y, z, w."""
    out = poses.copy()
    seen = np.isfinite(poses).all(axis=(-2, -1))
    x, y, z, w = Rotation.from_matrix(poses[seen][:, :3, :3]).as_quat().T  # scalar last
    # the columns qw,qx,qy,qz hold x, y, z, w: read as w' = x, x' = y, y' = z, z' = w
    out[seen, :3, :3] = Rotation.from_quat(np.stack([y, z, w, x], axis=1)).as_matrix()
    return out


def verdicts(arclengths: np.ndarray, poses: np.ndarray, present: np.ndarray
             ) -> tuple[OrderEvidence, OrderEvidence]:
    """The check's evidence for the file written as the format says and written x, y, z, w."""
    swapped = swapped_reading(poses)
    return (quaternion_order_evidence(arclengths, poses, swapped, present),
            quaternion_order_evidence(arclengths, swapped, poses, present))



def real_windows(name: str, count: int, seed: int) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """``count`` random windows of 1-5 s of a shipped recording: (seconds, poses, present)."""
    poses = load_backbone_poses(REAL / name / "backbone_poses.csv")
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        span = rng.uniform(1.0, 5.0)
        start = rng.uniform(poses.timestamps[0], poses.timestamps[-1] - span)
        keep = (poses.timestamps >= start) & (poses.timestamps < start + span)
        out.append((span, poses.world_T_marker[keep], poses.present[keep]))
    return out


def _summary(label: str, ev: list[OrderEvidence], should_warn: bool) -> str:
    """One line: how many warn, how many were judged and the spread of written/other."""
    judged = [e for e in ev if e.telling >= MIN_TELLING_PAIRS]
    ratio = np.array([e.written / e.other for e in judged])
    warned = sum(e.looks_other for e in ev)
    wrong = len(ev) - warned if should_warn else warned
    text = (f"{label}: {len(ev)} recordings, {warned} warn "
            f"({'misses' if should_warn else 'false alarms'}: {wrong}), judged {len(judged)}")
    if len(ratio):
        q = np.percentile(ratio, [0, 5, 50, 95, 100])
        text += (", written/other over judged: min {:.3g} p5 {:.3g} median {:.3g} p95 {:.3g} "
                 "max {:.3g}").format(*q)
    return text


def main(count: int, mount_deg: float = 3.0) -> None:
    """Print the sweep's figures (see the module docstring)."""
    rows = []
    for seed in range(count):
        rec = synthetic_recording(seed, mount_deg)
        rows.append((seed, rec, *verdicts(rec.arclengths, rec.poses, rec.present), tellable(rec)))
    print(_summary("synthetic, as written", [r[2] for r in rows], False))
    print(_summary("synthetic, x,y,z,w", [r[3] for r in rows], True))
    for kind in ("straight", "small", "large"):
        sel = [r for r in rows if r[1].kind == kind]
        print(f"  {kind}: {len(sel)}; as written warn {sum(r[2].looks_other for r in sel)}, "
              f"x,y,z,w warn {sum(r[3].looks_other for r in sel)}")
    told = [r for r in rows if r[4]]
    print(f"  bent enough to tell (tellable): {len(told)}, x,y,z,w warn "
          f"{sum(r[3].looks_other for r in told)}; not tellable: {len(rows) - len(told)}, "
          f"x,y,z,w warn {sum(r[3].looks_other for r in rows if not r[4])}")
    judged = [r for r in rows if r[2].telling >= MIN_TELLING_PAIRS]
    for label, r in (("as written, highest written/other",
                      max(judged, key=lambda r: r[2].written / r[2].other)),
                     ("x,y,z,w, lowest written/other",
                      min(judged, key=lambda r: r[3].written / r[3].other))):
        print(f"  worst {label}: seed {r[0]} ({r[1].kind}, largest bend "
              f"{np.degrees(r[1].max_bend):.1f} deg): {r[2] if 'as' in label else r[3]}")
    for r in rows:
        if r[4] and not r[3].looks_other:
            print(f"  missed though tellable: seed {r[0]} {r[3]}")
    for name in ("slow_free_space", "impulse_2"):
        ev = [verdicts(ARCS[name], p, m) for _, p, m in real_windows(name, 50, 0)]
        print(_summary(f"{name} windows, as written", [e[0] for e in ev], False))
        print(_summary(f"{name} windows, x,y,z,w", [e[1] for e in ev], True))
        whole = load_backbone_poses(REAL / name / "backbone_poses.csv")
        print(f"  whole: {verdicts(whole.arclengths, whole.world_T_marker, whole.present)}")


TELL_APART_M = 0.03
"""A recording is bent enough to tell the order when, on its noise-free backbone (no mounting
offsets, no noise), the two readings put a marker more than 3 cm apart (six times the few
millimetres that noise and mounting offsets account for) at 30 or more marker-pair samples."""


def tellable(rec: Recording) -> bool:
    """Whether ``rec`` is bent enough to tell the quaternion order (:data:`TELL_APART_M`)."""
    everywhere = np.ones(rec.present.shape, dtype=bool)
    ends, _ = _arc_ends(rec.arclengths, rec.clean, everywhere)
    other, _ = _arc_ends(rec.arclengths, swapped_reading(rec.clean), everywhere)
    return int(np.sum(np.linalg.norm(ends - other, axis=1) > TELL_APART_M)) >= 30


CI_SEEDS = range(1000, 1040)
"""Seeds the check was not looked at on (the figures in docs/formats.md are seeds 0-199)."""


def test_synthetic_sweep_no_false_alarm_and_warns_when_tellable() -> None:
    told = 0
    for seed in CI_SEEDS:
        rec = synthetic_recording(seed)
        written, swapped = verdicts(rec.arclengths, rec.poses, rec.present)
        assert not written.looks_other, (seed, written)
        if tellable(rec):
            told += 1
            assert swapped.looks_other, (seed, rec.kind, swapped)
    assert told >= 15  # the sweep holds enough bent recordings to mean something


def test_nearly_straight_backbone_stays_silent_in_both_orders() -> None:
    seeds = [s for s in range(2000, 2200) if synthetic_recording(s).kind == "straight"][:8]
    checked = 0
    for seed in seeds:
        rec = synthetic_recording(seed)
        if np.abs(rec.clean[0, 0, :3, :3] - np.eye(3)).max() > 0.1:
            continue  # a base turned far from the world axes: the swapped reading's backbone
            # axis points elsewhere, so even a straight robot tells (and is warned about)
        checked += 1
        for found in verdicts(rec.arclengths, rec.poses, rec.present):
            assert not found.looks_other, (seed, found)
    assert checked >= 4


def test_exactly_straight_file_stays_silent(tmp_path: Path) -> None:
    rec = synthetic_recording(7)
    straight = np.tile(np.eye(4), (*rec.present.shape, 1, 1))
    straight[..., 2, 3] = rec.arclengths
    path = _write(tmp_path / "straight.csv", rec.arclengths, straight @ _mounts(rec), rec.present)
    swapped = _swap_columns(path, tmp_path / "straight_xyzw.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnitsWarning)
        load_backbone_poses(path)
        load_backbone_poses(swapped)


def test_file_round_trip_warns_only_on_the_swapped_columns(tmp_path: Path) -> None:
    rec = next(r for r in map(synthetic_recording, CI_SEEDS) if r.kind == "large" and tellable(r))
    path = _write(tmp_path / "bent.csv", rec.arclengths, rec.poses, rec.present)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnitsWarning)
        load_backbone_poses(path)
    swapped = _swap_columns(path, tmp_path / "bent_xyzw.csv")
    with pytest.warns(UnitsWarning, match=rf"^{swapped}: the quaternion columns qw,qx,qy,qz look "
                      r"written in the order x, y, z, w: .* move the w column first"):
        load_backbone_poses(swapped)


@pytest.mark.parametrize("name", ["slow_free_space", "impulse_2"])
def test_real_windows_never_warn_as_written_and_judged_swapped_windows_warn(name: str) -> None:
    judged = 0
    for _, poses, present in real_windows(name, 20, 1):
        written, swapped = verdicts(ARCS[name], poses, present)
        assert not written.looks_other, written
        judged += swapped.telling >= MIN_TELLING_PAIRS
        assert swapped.looks_other == (swapped.telling >= MIN_TELLING_PAIRS), swapped
    assert judged >= 2


def _mounts(rec: Recording) -> np.ndarray:
    """The recording's fixed marker mounting offsets (``poses = clean @ mounts`` less noise)."""
    rng = np.random.default_rng(0)
    mount = np.tile(np.eye(4), (len(rec.arclengths), 1, 1))
    mount[:, :3, :3] = _rotvec(rng.normal(0, np.radians(3.0), (len(rec.arclengths), 3)))
    mount[:, :3, 3] = rng.normal(0, 0.002, (len(rec.arclengths), 3))
    return mount


def _write(path: Path, arclengths: np.ndarray, poses: np.ndarray, present: np.ndarray) -> Path:
    """A backbone_poses.csv of these poses (missing markers as NaN), written as the format says."""
    poses = np.where(present[..., None, None], poses, np.nan)
    times = np.round(np.arange(len(poses)) * 0.06, 3)
    save_backbone_poses(BackbonePoses(times, arclengths, poses, present), path)
    return path


def _swap_columns(path: Path, out: Path) -> Path:
    """A copy of ``path`` whose quaternion columns hold x, y, z, w."""
    lines = path.read_text().splitlines()
    rows = [lines[0]]
    for line in lines[1:]:
        f = line.split(",")
        rows.append(",".join(f[:5] + [f[6], f[7], f[8], f[5]]))
    out.write_text("\n".join(rows) + "\n")
    return out


if __name__ == "__main__":
    main(int(sys.argv[1]) if len(sys.argv) > 1 else 200,
         float(sys.argv[2]) if len(sys.argv) > 2 else 3.0)
