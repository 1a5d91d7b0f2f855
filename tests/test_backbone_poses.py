"""Tests of apcc_graph.io.backbone_poses: motion-capture backbone poses (docs/formats.md).

Round trips of random poses with missing markers, the two shipped recordings in data/real_tdcr/,
every refusal (file, line and column named), and picking the base, segment-end and held-out
markers.
"""

from __future__ import annotations

import re
from pathlib import Path

import gtsam
import numpy as np
import pytest

from apcc_graph.io import BackbonePoses, load_backbone_poses, save_backbone_poses
from apcc_graph.io.backbone_poses import BACKBONE_COLUMNS, segment_markers
from apcc_graph.io.poses import rotation_from_quaternion

REPO = Path(__file__).resolve().parents[1]
REAL = REPO / "data" / "real_tdcr"
ARCLENGTHS = [0.0, 0.1165, 0.233, 0.3495, 0.466]
HEADER = ",".join(BACKBONE_COLUMNS)
VALID = [HEADER,
         "0.0,0.0,0,0,0,1,0,0,0",
         "0.0,0.2,0,0,0.2,1,0,0,0",
         "0.1,0.0,0,0,0,1,0,0,0",
         "0.1,0.2,0,0,0.2,1,0,0,0"]


# ------------------------------------------------------------------------------------ helpers
def _random_poses(rng: np.random.Generator, n_samples: int, n_markers: int) -> BackbonePoses:
    """Random poses, about a third of the markers missing (every sample and marker seen once)."""
    timestamps = np.cumsum(rng.uniform(0.01, 0.2, n_samples)) + rng.uniform(-5.0, 5.0)
    arclengths = np.sort(rng.choice(1000, n_markers, replace=False) * 1e-3
                         + rng.uniform(0.0, 1e-4, n_markers))  # not round: read back exactly
    present = rng.random((n_samples, n_markers)) > 0.35
    present[np.arange(n_samples), rng.integers(0, n_markers, n_samples)] = True
    present[rng.integers(0, n_samples, n_markers), np.arange(n_markers)] = True
    poses = np.full((n_samples, n_markers, 4, 4), np.nan)
    for t, m in zip(*np.nonzero(present), strict=True):
        quat = rng.normal(size=4)
        quat /= np.linalg.norm(quat)
        rotation = gtsam.Rot3.Quaternion(*quat)
        poses[t, m] = gtsam.Pose3(rotation, rng.normal(0.0, 0.3, 3)).matrix()
    return BackbonePoses(timestamps, arclengths, poses, present)


def _assert_same(a: BackbonePoses, b: BackbonePoses) -> None:
    assert np.array_equal(a.timestamps, b.timestamps)
    assert np.array_equal(a.arclengths, b.arclengths)
    assert np.array_equal(a.present, b.present)
    assert np.array_equal(np.isnan(a.world_T_marker), np.isnan(b.world_T_marker))
    assert np.array_equal(a.positions[a.present], b.positions[b.present])
    rot_a, rot_b = a.world_T_marker[a.present, :3, :3], b.world_T_marker[b.present, :3, :3]
    assert np.abs(rot_a - rot_b).max() < 1e-12


def _write(tmp_path: Path, lines: list[str], name: str = "backbone_poses.csv") -> Path:
    path = tmp_path / name
    path.write_text("\n".join(lines) + "\n" if lines else "")
    return path


def _refusal(path: Path) -> str:
    with pytest.raises(ValueError) as info:
        load_backbone_poses(path)
    return str(info.value)


@pytest.fixture(scope="module")
def shipped() -> dict[str, BackbonePoses]:
    return {trial: load_backbone_poses(REAL / trial / "backbone_poses.csv")
            for trial in ("slow_free_space", "impulse_2")}


# ----------------------------------------------------------------------------------- round trip
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_round_trip_of_random_poses_with_missing_markers(tmp_path: Path, seed: int) -> None:
    rng = np.random.default_rng(seed)
    n_samples, n_markers = int(rng.integers(5, 40)), int(rng.integers(1, 7))
    poses = _random_poses(rng, n_samples, n_markers)
    assert not poses.present.all() or poses.n_markers == 1
    path = tmp_path / "sub" / "backbone_poses.csv"
    save_backbone_poses(poses, path)
    again = load_backbone_poses(path)
    _assert_same(poses, again)
    assert again.source == str(path)
    save_backbone_poses(again, tmp_path / "again.csv")
    _assert_same(poses, load_backbone_poses(tmp_path / "again.csv"))


def test_saved_rows_are_the_present_markers_in_time_then_arclength_order(tmp_path: Path) -> None:
    poses = _random_poses(np.random.default_rng(7), n_samples=12, n_markers=4)
    path = tmp_path / "p.csv"
    save_backbone_poses(poses, path)
    lines = path.read_text().splitlines()
    assert lines[0] == HEADER
    rows = np.array([[float(v) for v in line.split(",")] for line in lines[1:]])
    assert len(rows) == poses.present.sum()
    t_index = np.searchsorted(poses.timestamps, rows[:, 0])
    m_index = np.searchsorted(poses.arclengths, rows[:, 1])
    assert np.array_equal(t_index * 4 + m_index, np.sort(np.flatnonzero(poses.present)))
    assert np.allclose(np.linalg.norm(rows[:, 5:9], axis=1), 1.0, atol=1e-14)


def test_quaternions_are_read_in_wxyz_order_and_normalised(tmp_path: Path) -> None:
    half = float(np.sqrt(0.5)) * (1.0 + 4e-4)  # 90 deg about z, norm 1.0004: normalised
    path = _write(tmp_path, [HEADER, f"0.5,0.1,1,2,3,{half!r},0,0,{half!r}"])
    poses = load_backbone_poses(path)
    expected = np.array([[0.0, -1.0, 0.0, 1.0], [1.0, 0.0, 0.0, 2.0], [0.0, 0.0, 1.0, 3.0],
                         [0.0, 0.0, 0.0, 1.0]])
    assert np.abs(poses.world_T_marker[0, 0] - expected).max() < 1e-15
    assert poses.timestamps.tolist() == [0.5] and poses.arclengths.tolist() == [0.1]


def test_rotations_match_gtsam_for_random_quaternions(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    quats = rng.normal(size=(50, 4))
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    lines = [HEADER] + [f"{i}.0,0.0,0,0,0," + ",".join(repr(float(v)) for v in q)
                        for i, q in enumerate(quats)]
    poses = load_backbone_poses(_write(tmp_path, lines))
    for i, q in enumerate(quats):  # bit for bit the rotation apcc_graph.io.poses reads
        assert np.array_equal(poses.world_T_marker[i, 0, :3, :3], rotation_from_quaternion(q))
        assert np.abs(poses.world_T_marker[i, 0, :3, :3]
                      - gtsam.Rot3.Quaternion(*q).matrix()).max() < 1e-15


# ---------------------------------------------------------------------------- shipped recordings
@pytest.mark.parametrize(("trial", "samples", "missing"), [
    ("slow_free_space", 769, [0, 0, 0, 5, 0]),
    ("impulse_2", 381, [0, 3, 38, 25, 0]),
])
def test_shipped_recordings(shipped: dict[str, BackbonePoses], trial: str, samples: int,
                            missing: list[int]) -> None:
    poses = shipped[trial]
    assert poses.n_samples == samples
    assert poses.arclengths.tolist() == ARCLENGTHS and poses.n_markers == 5
    assert (~poses.present).sum(axis=0).tolist() == missing
    assert poses.world_T_marker.shape == (samples, 5, 4, 4)
    assert poses.positions.shape == (samples, 5, 3)
    assert np.isnan(poses.positions[~poses.present]).all()
    assert np.isfinite(poses.positions[poses.present]).all()
    assert poses.timestamps[0] == 0.0 and np.diff(poses.timestamps).max() < 0.95
    # The tip is about a backbone length from the base.
    reach = np.linalg.norm(poses.positions[:, 4] - poses.positions[:, 0], axis=1)
    assert 0.3 < np.nanmin(reach) and np.nanmax(reach) < 0.47
    assert segment_markers(poses, [0.233, 0.233]) == (0, [2, 4], [1, 3])


def test_shipped_recording_round_trip(shipped: dict[str, BackbonePoses], tmp_path: Path) -> None:
    poses = shipped["impulse_2"]
    save_backbone_poses(poses, tmp_path / "p.csv")
    _assert_same(poses, load_backbone_poses(tmp_path / "p.csv"))


# ------------------------------------------------------------------------------------- refusals
REFUSALS = {
    "wrong header": (0, HEADER.replace("qw,qx,qy,qz", "qx,qy,qz,qw"), 1, "'qw'"),
    "not a number": (2, "0.0,0.2,0,abc,0.2,1,0,0,0", 3, "column 'y'"),
    "nan": (3, "0.1,0.0,nan,0,0,1,0,0,0", 4, "column 'x'"),
    "infinite": (4, "0.1,0.2,0,0,inf,1,0,0,0", 5, "column 'z'"),
    "negative arclength": (4, "0.1,-0.2,0,0,0.2,1,0,0,0", 5, "column 'arclength'"),
    "time going back": (4, "0.05,0.2,0,0,0.2,1,0,0,0", 5, "column 'timestamp'"),
    "duplicate": (4, "0.1,0.0,0,0,0.2,1,0,0,0", 5, "column 'arclength'"),
    "duplicate after rounding": (4, "0.1,0.0000004,0,0,0.2,1,0,0,0", 5, "column 'arclength'"),
    "non-unit quaternion": (2, "0.0,0.2,0,0,0.2,1.01,0,0,0", 3, "column 'qw'"),
    "zero quaternion": (3, "0.1,0.0,0,0,0,0,0,0,0", 4, "column 'qw'"),
    "blank line": (2, "", 3, "blank line"),
    "too few fields": (3, "0.1,0.0,0,0,0,1,0,0", 4, "expected 9 fields"),
}


@pytest.mark.parametrize("case", sorted(REFUSALS))
def test_refusals_name_file_line_and_column(tmp_path: Path, case: str) -> None:
    index, text, line, column = REFUSALS[case]
    lines = list(VALID)
    lines[index] = text
    path = _write(tmp_path, lines)
    message = _refusal(path)
    assert re.match(rf"{re.escape(str(path))}: line {line}\b", message), message
    assert column in message, message


def test_refusal_messages_say_what_was_expected(tmp_path: Path) -> None:
    def refused(index: int, text: str) -> str:
        lines = list(VALID)
        lines[index] = text
        return _refusal(_write(tmp_path, lines))

    assert "timestamps must not decrease; rows of one sample time are adjacent" in refused(
        4, "0.05,0.2,0,0,0.2,1,0,0,0")
    duplicate = refused(4, "0.1,0.0,0,0,0.2,1,0,0,0")
    assert "line 5" in duplicate and "already given on line 4" in duplicate
    assert ">= 0" in refused(4, "0.1,-0.2,0,0,0.2,1,0,0,0")
    assert "finite" in refused(3, "0.1,0.0,nan,0,0,1,0,0,0")
    assert "unit quaternion" in refused(2, "0.0,0.2,0,0,0.2,1.01,0,0,0")


@pytest.mark.parametrize(("lines", "line"), [([HEADER], 2), ([], 1)])
def test_empty_files_are_refused(tmp_path: Path, lines: list[str], line: int) -> None:
    path = _write(tmp_path, lines)
    message = _refusal(path)
    assert message.startswith(f"{path}: line {line}:"), message
    assert "empty" in message or "no data rows" in message


def test_a_missing_file_is_refused(tmp_path: Path) -> None:
    assert str(tmp_path / "nope.csv") in _refusal(tmp_path / "nope.csv")


@pytest.mark.parametrize(("field", "change"), [
    ("timestamps", lambda f: {**f, "timestamps": f["timestamps"][::-1].copy()}),
    ("timestamps", lambda f: {**f, "timestamps": f["timestamps"][:, None]}),
    ("arclengths", lambda f: {**f, "arclengths": np.array([0.2, 0.2 + 1e-8])}),
    ("arclengths", lambda f: {**f, "arclengths": np.array([-0.1, 0.2])}),
    ("world_T_marker", lambda f: {**f, "world_T_marker": f["world_T_marker"][:, :1]}),
    ("world_T_marker", lambda f: {**f, "world_T_marker": f["world_T_marker"] * 2.0}),
    ("world_T_marker", lambda f: {**f, "present": np.zeros((2, 2), dtype=bool)}),
    ("present", lambda f: {**f, "present": np.ones((2, 3), dtype=bool)}),
])
def test_the_dataclass_refuses_broken_fields(field: str, change) -> None:
    fields = {"timestamps": np.array([0.0, 0.1]), "arclengths": np.array([0.0, 0.2]),
              "world_T_marker": np.tile(np.eye(4), (2, 2, 1, 1)),
              "present": np.ones((2, 2), dtype=bool)}
    BackbonePoses(**fields)
    with pytest.raises(ValueError, match=f"BackbonePoses.{field}"):
        BackbonePoses(**change(fields))


def test_the_dataclass_fields_are_read_only_copies() -> None:
    times = np.array([0.0, 0.1])
    poses = BackbonePoses(times, np.array([0.0]), np.tile(np.eye(4), (2, 1, 1, 1)),
                          np.ones((2, 1), dtype=bool))
    times[0] = -1.0
    assert poses.timestamps[0] == 0.0 and poses.source == "<memory>"
    with pytest.raises(ValueError):
        poses.timestamps[0] = 5.0


# ------------------------------------------------------------------------------------- markers
def test_marker_found_and_missing(shipped: dict[str, BackbonePoses]) -> None:
    poses = shipped["slow_free_space"]
    assert [poses.marker(s) for s in ARCLENGTHS] == [0, 1, 2, 3, 4]
    assert poses.marker(0.2335) == 2 and poses.marker(0.2345, tolerance=0.002) == 2
    with pytest.raises(ValueError) as info:
        poses.marker(0.2345)
    message = str(info.value)
    assert "0.2345" in message and poses.source in message
    assert "0, 0.1165, 0.233, 0.3495, 0.466 m" in message


def test_segment_markers_with_one_segment_holds_out_the_rest(
        shipped: dict[str, BackbonePoses]) -> None:
    assert segment_markers(shipped["impulse_2"], [0.466]) == (0, [4], [1, 2, 3])
    assert segment_markers(shipped["impulse_2"], [0.1165] * 4) == (0, [1, 2, 3, 4], [])


def test_segment_markers_missing_segment_end(shipped: dict[str, BackbonePoses]) -> None:
    poses = shipped["slow_free_space"]
    with pytest.raises(ValueError) as info:
        segment_markers(poses, [0.233, 0.3])
    message = str(info.value)
    assert "arc length 0.533 m" in message and "segment 2" in message
    assert poses.source in message and "0, 0.1165, 0.233, 0.3495, 0.466 m" in message


def test_segment_markers_missing_base(tmp_path: Path) -> None:
    path = _write(tmp_path, [HEADER, "0.0,0.1,0,0,0.1,1,0,0,0", "0.0,0.2,0,0,0.2,1,0,0,0"])
    with pytest.raises(ValueError) as info:
        segment_markers(load_backbone_poses(path), [0.1])
    message = str(info.value)
    assert "arc length 0 m" in message and "segment 1" in message
    assert str(path) in message and "0.1, 0.2 m" in message


@pytest.mark.parametrize("lengths", [[], [0.233, 0.0], [0.233, -0.1], [float("nan")]])
def test_segment_markers_refuses_bad_lengths(shipped: dict[str, BackbonePoses],
                                             lengths: list[float]) -> None:
    with pytest.raises(ValueError, match="segment lengths"):
        segment_markers(shipped["impulse_2"], lengths)
