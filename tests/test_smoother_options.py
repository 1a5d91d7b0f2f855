"""The smoother's options records: validation, defaults, the flat names of earlier releases,
and how the smoother reads them."""

from __future__ import annotations

import math
import warnings
from dataclasses import FrozenInstanceError, fields, replace
from pathlib import Path

import numpy as np
import pytest

from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import (
    FLAT_FIELDS,
    RECORDS,
    FaultOptions,
    LandmarkOptions,
    SmootherOptions,
    TrackOptions,
    WindowOptions,
)
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.robot import Robot

ROBOT = Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml"

OLD_DEFAULTS = {
    "lag": 1.0, "uncertainty": True, "relinearize_threshold": 3e-4,
    "loose_sigma": math.radians(30.0), "relinearize": True, "min_live_rows": 4,
    "front_end_rows": 20, "point_iterations": 1, "commit_every": 1, "landmarks": True,
    "landmark_sigma": 10.0, "pose_sigma": 1e-4, "max_landmarks": 10, "still_frames": 10,
    "still_chi2": 18.4, "factorization": "CHOLESKY", "misfit_seconds": 2.0,
    "stagger_cuts": True, "rotation_gate": None, "reproducible": True,
}
"""The flat record's 20 defaults before it was split by concern."""


@pytest.fixture(scope="module")
def robot() -> Robot:
    return load_robot(ROBOT)


def _read(options: SmootherOptions, flat: str) -> object:
    record, inner = FLAT_FIELDS[flat]
    return getattr(getattr(options, record), inner)


def test_the_defaults_are_the_flat_records() -> None:
    options = SmootherOptions()
    assert set(FLAT_FIELDS) == set(OLD_DEFAULTS)
    for name, value in OLD_DEFAULTS.items():
        assert _read(options, name) == value, name
    # every field of every record is where exactly one flat field went
    places = {(r, f.name) for r, kind in RECORDS.items() for f in fields(kind)}
    assert sorted(places) == sorted(FLAT_FIELDS.values())
    # the records, then the keyframe rule (none: iSAM2 runs at every frame)
    assert [f.name for f in fields(SmootherOptions)] == [*RECORDS, "keyframes"]
    assert options.keyframes is None
    assert options == SmootherOptions(WindowOptions(), TrackOptions(), LandmarkOptions(),
                                      FaultOptions(), None)
    with pytest.raises(FrozenInstanceError):
        options.window = WindowOptions(lag=2.0)  # type: ignore[misc]
    with pytest.raises(FrozenInstanceError):
        options.window.lag = 2.0  # type: ignore[misc]


@pytest.mark.parametrize(("record", "field", "value"), [
    (WindowOptions, "lag", 0.0), (WindowOptions, "lag", math.inf),
    (WindowOptions, "loose_sigma", -1.0), (WindowOptions, "relinearize_threshold", math.nan),
    (WindowOptions, "factorization", "LU"),
    (TrackOptions, "min_live_rows", 1), (TrackOptions, "commit_every", 0),
    (TrackOptions, "point_iterations", 0), (TrackOptions, "front_end_rows", -1),
    (LandmarkOptions, "prior_sigma", 0.0), (LandmarkOptions, "pose_sigma", math.nan),
    (LandmarkOptions, "max_per_camera", -1),
    (FaultOptions, "still_frames", -1), (FaultOptions, "still_chi2", 0.0),
    (FaultOptions, "rotation_gate", 0.0), (FaultOptions, "misfit_seconds", -1.0),
])
def test_a_bad_value_is_refused_by_record_and_field(record: type, field: str,
                                                    value: object) -> None:
    with pytest.raises(ValueError, match=f"^{record.__name__}.{field} = "):
        record(**{field: value})


@pytest.mark.parametrize("name", list(RECORDS))
def test_a_field_of_the_wrong_record_is_refused_by_name(name: str) -> None:
    wrong = FaultOptions() if name != "faults" else WindowOptions()
    expected = RECORDS[name].__name__
    with pytest.raises(TypeError, match=f"SmootherOptions.{name}: expected {expected}, got "
                       f"{type(wrong).__name__}"):
        SmootherOptions(**{name: wrong})
    with pytest.raises(TypeError, match=f"SmootherOptions.{name}: expected {expected}, got dict"):
        SmootherOptions(**{name: {}})


def test_the_optional_fields_may_be_none() -> None:
    faults = FaultOptions(still_frames=None, rotation_gate=None, misfit_seconds=None)
    assert faults.still_frames is None and faults.misfit_seconds is None
    assert SmootherOptions(window=None).window == WindowOptions()


def test_numbers_are_stored_as_plain_types() -> None:
    window = WindowOptions(lag=np.float32(0.5), uncertainty=np.bool_(False))
    tracks = TrackOptions(min_live_rows=np.int64(3))
    faults = FaultOptions(still_frames=np.int32(5), rotation_gate=np.float64(0.02))
    assert type(window.lag) is float and type(window.uncertainty) is bool
    assert type(tracks.min_live_rows) is int and tracks.min_live_rows == 3
    assert type(faults.still_frames) is int and type(faults.rotation_gate) is float


def test_flat_names_are_refused_with_where_they_went() -> None:
    with pytest.raises(TypeError) as info:
        SmootherOptions(lag=0.5, max_landmarks=3, still_frames=None)  # type: ignore[call-arg]
    message = str(info.value)
    assert ("SmootherOptions(window=WindowOptions(lag=0.5), landmarks=LandmarkOptions("
            "max_per_camera=3), faults=FaultOptions(still_frames=None))") in message
    assert "SmootherOptions.of" in message
    # the old switch had the name of the new record
    with pytest.raises(TypeError, match=r"landmarks=LandmarkOptions\(enabled=False\)"):
        SmootherOptions(landmarks=False)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="no field 'landmark_sigmas'; its fields are window, "
                       "tracks, landmarks, faults"):
        SmootherOptions(landmark_sigmas=3.0)  # type: ignore[call-arg]


def test_of_converts_the_flat_names_and_warns() -> None:
    with pytest.warns(DeprecationWarning, match=r"write SmootherOptions\(window=WindowOptions"
                      r"\(lag=0.5\), landmarks=LandmarkOptions\(enabled=False\)\)"):
        options = SmootherOptions.of(lag=0.5, landmarks=False)
    assert options == SmootherOptions(window=WindowOptions(lag=0.5),
                                      landmarks=LandmarkOptions(enabled=False))
    every = dict(OLD_DEFAULTS)
    every.update(lag=2.0, min_live_rows=3, landmark_sigma=5.0, max_landmarks=4,
                 rotation_gate=0.02, factorization="QR", still_frames=None)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        converted = SmootherOptions.of(**every)
        for name, value in every.items():
            assert _read(converted, name) == value, name
        with pytest.raises(ValueError, match="^LandmarkOptions.prior_sigma = -1.0"):
            SmootherOptions.of(landmark_sigma=-1.0)
        with pytest.raises(TypeError, match="no field 'backend'"):
            SmootherOptions.of(backend="batch")


def test_the_smoother_reads_the_nested_values(robot: Robot) -> None:
    settings = SmootherOptions(window=WindowOptions(lag=0.5, loose_sigma=0.2),
                               landmarks=LandmarkOptions(enabled=False, max_per_camera=3),
                               faults=FaultOptions(rotation_gate=0.03, still_frames=None))
    smoother = FixedLagSmoother(robot, settings=settings)
    assert smoother.settings is settings
    assert smoother.window.lag == 0.5 and not smoother.landmarks.enabled
    assert smoother._window.lag == 0.5  # the window itself
    assert smoother._model.landmarks is None  # disabled: tracks that outlive the window are cut
    on = FixedLagSmoother(robot, settings=replace(settings, landmarks=LandmarkOptions(
        max_per_camera=3, prior_sigma=2.0)))
    marks = on._model.landmarks
    assert marks.lag == 0.5 and marks.max_per_camera == 3 and marks.prior_sigma == 2.0
    assert smoother.gate == 0.03
    assert smoother._still.settle == math.inf
    with pytest.raises(AttributeError):
        _ = smoother.no_such_field
    default = FixedLagSmoother(robot)
    assert default._window.lag == 1.0 and default.gate == default._model.default_gate
    assert default._still.settle == 10 and default._model.landmarks.max_per_camera == 10


def test_a_whole_record_with_the_lag_overriding_it(robot: Robot) -> None:
    base = SmootherOptions(window=WindowOptions(lag=0.5), tracks=TrackOptions(commit_every=3))
    assert FixedLagSmoother(robot, settings=base).settings is base
    smoother = FixedLagSmoother(robot, settings=base, lag=2.0)
    assert smoother.settings == replace(base, window=WindowOptions(lag=2.0))
    assert smoother._window.lag == 2.0 and smoother.tracks.commit_every == 3
    with pytest.raises(ValueError, match="WindowOptions.lag = -1.0"):
        FixedLagSmoother(robot, settings=base, lag=-1.0)
    with pytest.raises(TypeError, match="settings"):
        FixedLagSmoother(robot, settings={"lag": 2.0})  # type: ignore[arg-type]


def test_unknown_and_misspelled_options_are_refused_by_name(robot: Robot) -> None:
    with pytest.raises(TypeError, match="backend"):
        FixedLagSmoother(robot, backend="batch")  # type: ignore[call-arg]
    with pytest.raises(TypeError, match="prior_sigmas"):
        LandmarkOptions(prior_sigmas=3.0)  # type: ignore[call-arg]
    # the settings are a record, not keywords of the smoother
    with pytest.raises(TypeError, match="max_landmarks"):
        FixedLagSmoother(robot, max_landmarks=4)  # type: ignore[call-arg]
