"""The smoothers' options records: validation, and how the constructors build them."""

from __future__ import annotations

import math
from dataclasses import FrozenInstanceError
from pathlib import Path

import numpy as np
import pytest

from apcc_graph.estimation.projection_smoother import ProjectionFixedLagSmoother
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import (
    EpipolarSmootherOptions,
    ProjectionSmootherOptions,
    SmootherOptions,
)
from apcc_graph.io.robot_file import load_robot
from apcc_graph.model.robot import Robot

ROBOT = Path(__file__).resolve().parents[1] / "data/robots/planar_three.toml"


@pytest.fixture(scope="module")
def robot() -> Robot:
    return load_robot(ROBOT)


def test_defaults_and_shared_fields() -> None:
    epipolar, projection = EpipolarSmootherOptions(), ProjectionSmootherOptions()
    assert isinstance(epipolar, SmootherOptions) and isinstance(projection, SmootherOptions)
    assert epipolar.lag == projection.lag == 1.0
    assert epipolar.relinearize_threshold == 1e-3 and projection.relinearize_threshold == 3e-4
    assert epipolar.loose_sigma == projection.loose_sigma == math.radians(30.0)
    with pytest.raises(FrozenInstanceError):
        epipolar.lag = 2.0  # type: ignore[misc]


@pytest.mark.parametrize(("kind", "field", "value"), [
    (EpipolarSmootherOptions, "lag", 0.0), (ProjectionSmootherOptions, "lag", math.inf),
    (EpipolarSmootherOptions, "loose_sigma", -1.0),
    (EpipolarSmootherOptions, "relinearize_threshold", math.nan),
    (EpipolarSmootherOptions, "backend", "kalman"),
    (EpipolarSmootherOptions, "linearization", "second-estimate"),
    (EpipolarSmootherOptions, "calibration_sigmas", (0.05, 0.0)),
    (EpipolarSmootherOptions, "marginalise_every", 0),
    (EpipolarSmootherOptions, "iterations", 0),
    (EpipolarSmootherOptions, "keyframes", -1),
    (EpipolarSmootherOptions, "agreement", 1.5),
    (ProjectionSmootherOptions, "min_live_rows", 1),
    (ProjectionSmootherOptions, "commit_every", 0),
    (ProjectionSmootherOptions, "landmark_sigma", 0.0),
])
def test_bad_fields_are_refused_by_name(kind: type, field: str, value: object) -> None:
    with pytest.raises(ValueError, match=f"{kind.__name__}.{field} = "):
        kind(**{field: value})


def test_numbers_are_stored_as_plain_types() -> None:
    options = EpipolarSmootherOptions(iterations=np.int64(2), lag=np.float32(0.5))
    assert type(options.iterations) is int and type(options.lag) is float


def test_keywords_build_the_record_and_read_back(robot: Robot) -> None:
    smoother = FixedLagSmoother(robot, lag=0.5, iterations=2, calibrate=True)
    assert smoother.settings == EpipolarSmootherOptions(lag=0.5, iterations=2, calibrate=True)
    assert smoother.lag == 0.5 and smoother.iterations == 2 and smoother.calibrate
    projection = ProjectionFixedLagSmoother(robot, landmarks=False)
    assert projection.settings == ProjectionSmootherOptions(landmarks=False)
    assert projection.loose_sigma == math.radians(30.0) and not projection.landmarks
    with pytest.raises(AttributeError):
        _ = projection.no_such_field


def test_a_whole_record_with_keywords_overriding_it(robot: Robot) -> None:
    base = EpipolarSmootherOptions(lag=0.5, backend="batch")
    assert FixedLagSmoother(robot, settings=base).settings is base
    smoother = FixedLagSmoother(robot, settings=base, lag=2.0, seed=3)
    assert smoother.settings == EpipolarSmootherOptions(lag=2.0, backend="batch", seed=3)
    with pytest.raises(TypeError, match="settings"):
        FixedLagSmoother(robot, settings=ProjectionSmootherOptions())  # type: ignore[arg-type]


def test_unknown_keywords_are_refused(robot: Robot) -> None:
    with pytest.raises(TypeError, match="landmarks"):
        FixedLagSmoother(robot, landmarks=True)
    with pytest.raises(TypeError, match="backend"):
        ProjectionFixedLagSmoother(robot, backend="batch")
