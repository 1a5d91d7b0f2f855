"""The smoother's options record: validation, and how the constructor builds it."""

from __future__ import annotations

import math
from dataclasses import FrozenInstanceError
from pathlib import Path

import numpy as np
import pytest

from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.robot import Robot

ROBOT = Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml"


@pytest.fixture(scope="module")
def robot() -> Robot:
    return load_robot(ROBOT)


def test_defaults() -> None:
    options = SmootherOptions()
    assert options.lag == 1.0
    assert options.relinearize_threshold == 3e-4
    assert options.loose_sigma == math.radians(30.0)
    assert options.min_live_rows == 4 and options.landmarks
    with pytest.raises(FrozenInstanceError):
        options.lag = 2.0  # type: ignore[misc]


@pytest.mark.parametrize(("field", "value"), [
    ("lag", 0.0), ("lag", math.inf), ("loose_sigma", -1.0),
    ("relinearize_threshold", math.nan), ("min_live_rows", 1), ("commit_every", 0),
    ("landmark_sigma", 0.0), ("point_iterations", 0), ("max_landmarks", -1),
])
def test_bad_fields_are_refused_by_name(field: str, value: object) -> None:
    with pytest.raises(ValueError, match=f"SmootherOptions.{field} = "):
        SmootherOptions(**{field: value})


def test_numbers_are_stored_as_plain_types() -> None:
    options = SmootherOptions(min_live_rows=np.int64(3), lag=np.float32(0.5))
    assert type(options.min_live_rows) is int and type(options.lag) is float


def test_the_record_reads_back(robot: Robot) -> None:
    smoother = FixedLagSmoother(robot, settings=SmootherOptions(lag=0.5, landmarks=False))
    assert smoother.settings == SmootherOptions(lag=0.5, landmarks=False)
    assert smoother.lag == 0.5 and not smoother.landmarks
    assert smoother.loose_sigma == math.radians(30.0)
    with pytest.raises(AttributeError):
        _ = smoother.no_such_field


def test_a_whole_record_with_the_lag_overriding_it(robot: Robot) -> None:
    base = SmootherOptions(lag=0.5, commit_every=3)
    assert FixedLagSmoother(robot, settings=base).settings is base
    smoother = FixedLagSmoother(robot, settings=base, lag=2.0)
    assert smoother.settings == SmootherOptions(lag=2.0, commit_every=3)
    with pytest.raises(TypeError, match="settings"):
        FixedLagSmoother(robot, settings={"lag": 2.0})  # type: ignore[arg-type]


def test_unknown_and_misspelled_options_are_refused_by_name(robot: Robot) -> None:
    with pytest.raises(TypeError, match="backend"):
        FixedLagSmoother(robot, backend="batch")  # type: ignore[call-arg]
    with pytest.raises(TypeError, match="landmark_sigmas"):
        SmootherOptions(landmark_sigmas=3.0)  # type: ignore[call-arg]
    # the settings are a record, not keywords of the smoother
    with pytest.raises(TypeError, match="max_landmarks"):
        FixedLagSmoother(robot, max_landmarks=4)  # type: ignore[call-arg]
