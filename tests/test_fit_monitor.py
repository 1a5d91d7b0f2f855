"""The live smoother's residual test, block by block (:mod:`apcc_graph.estimation.fit_monitor`),
and its factorization option."""

from __future__ import annotations

import math
import warnings
from dataclasses import replace
from functools import cache
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from apcc_graph.estimation.model_fit import ModelFitWarning
from apcc_graph.estimation.options import Robustness
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import FaultOptions, SmootherOptions, WindowOptions
from apcc_graph.io import load_robot
from apcc_graph.model.robot import Robot
from apcc_graph.model.sequence import Sequence
from apcc_graph.simulation.simulator import simulate

ROOT = Path(__file__).resolve().parents[1]


@cache
def _sequence() -> Sequence:
    robot = load_robot(ROOT / "data" / "robots" / "planar_three.toml")
    return simulate(robot, 100, noise_px=1.0, outlier_fraction=0.1, seed=3, scene="room",
                    n_points=2000).sequence


def _stream(robot: Robot, seq: Sequence, settings: SmootherOptions | None = None,
            robustness: Robustness | None = None
            ) -> tuple[FixedLagSmoother, list[warnings.WarningMessage], np.ndarray]:
    smoother = FixedLagSmoother(robot, lag=1.0, theta0=seq.thetas[0], settings=settings,
                                robustness=robustness)
    frames = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        for f in range(seq.n_frames):
            smoother.update(seq.frame(f))
            frames += smoother.pop_final()
        frames += smoother.finish()
    said = [w for w in caught if issubclass(w.category, ModelFitWarning)]
    return smoother, said, np.array([fr.thetas for fr in frames])


def _mount_off(robot: Robot, cam: int) -> Robot:
    """``robot`` with camera ``cam``'s mount turned by 2.2 deg and moved by 5 mm."""
    off = np.eye(4)
    off[:3, :3] = Rotation.from_rotvec(np.radians([2.0, 0.0, 1.0])).as_matrix()
    off[:3, 3] = [0.005, 0.0, 0.0]
    cameras = list(robot.cameras)
    camera = cameras[cam]
    assert camera is not None
    cameras[cam] = replace(camera, tip_T_cam=camera.tip_T_cam @ off)
    return Robot(robot.segments, cameras)


def test_blocks_tile_the_stream_and_stay_quiet_when_the_model_holds() -> None:
    seq = _sequence()
    smoother, said, _ = _stream(seq.robot, seq)
    assert not said
    blocks = smoother.model_fits
    # 2 s blocks at 30 fps: frames 0-59, then the rest when the stream ends
    assert [(b.first, b.last) for b in blocks] == [(0, 59), (60, 99)]
    for b in blocks:
        assert b.fit.explained
        assert b.end - b.start < 2.0
        assert {c.camera for c in b.fit.cameras} == {0, 1, 2}
        assert all(c.share < 0.02 for c in b.fit.cameras)


def test_a_mount_the_images_contradict_warns_once_and_names_its_camera() -> None:
    seq = _sequence()
    smoother, said, _ = _stream(_mount_off(seq.robot, 1), seq)
    first = smoother.model_fits[0].fit
    assert [c.camera for c in first.failing()] == [1]  # the other cameras are explained
    # one warning for the episode of failing blocks, naming where and which camera
    assert len(said) == 1
    text = str(said[0].message)
    assert text.startswith("frames 0-59 (0.00-1.97 s)") and "segment 2's camera" in text


UNMONITORED = SmootherOptions(faults=FaultOptions(misfit_seconds=None))
"""The smoother without its residual test."""


def test_the_monitor_is_off_when_asked() -> None:
    seq = _sequence().head(40)
    off = _mount_off(seq.robot, 1)
    smoother, said, _ = _stream(off, seq, settings=UNMONITORED)
    assert smoother.model_fits == [] and not said
    smoother, said, _ = _stream(off, seq, robustness=Robustness(misfit_alarm=None))
    assert smoother.model_fits == [] and not said
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ValueError, match="FaultOptions.misfit_seconds"):
            FaultOptions(misfit_seconds=bad)


def test_qr_factorization_gives_the_same_smoother() -> None:
    seq = _sequence().head(45)
    _, _, cholesky = _stream(seq.robot, seq, UNMONITORED)
    _, _, qr = _stream(seq.robot, seq, replace(UNMONITORED,
                                               window=WindowOptions(factorization="QR")))
    # the same least-squares problem solved another way: the same answer to far below the
    # noise (the angles' sigmas are about 0.1 deg here)
    assert np.degrees(np.max(np.abs(qr - cholesky))) < 1e-3
    with pytest.raises(ValueError, match="WindowOptions.factorization = 'LU': expected one of "
                       "CHOLESKY, QR"):
        WindowOptions(factorization="LU")
