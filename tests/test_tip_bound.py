"""The bound of the segment ends' positions: the angles' bound through the kinematics, against
the per-angle bound, the lag's ordering and the ends' Jacobian."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from apcc_graph import Robot, Segment, TipCamera
from apcc_graph.evaluation.sequence_bound import (
    fisher_information,
    lag_bound,
    sequence_bound,
)
from apcc_graph.evaluation.tip_bound import end_jacobians, tip_bound
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.sequence import Sequence, Tracks
from apcc_graph.simulation.simulator import Simulation, simulate

SEGMENTS = (Segment(0.3, k=0.2, delta_max=0.1, theta_max=1.0),
            Segment(0.25, k=0.3, delta_max=-0.05, theta_max=1.0))
PRIOR = math.radians(0.5)


@pytest.fixture(scope="module")
def robot() -> Robot:
    return Robot(SEGMENTS, [TipCamera(500.0, 500.0, 320.0, 240.0, 640, 480),
                            TipCamera(450.0, 450.0, 330.0, 230.0, 640, 480)])


@pytest.fixture(scope="module")
def sim(robot: Robot) -> Simulation:
    return simulate(robot, 24, noise_px=1.0, seed=3, scene="room", n_points=400)


def test_the_first_end_is_its_angle_bound_through_its_lever(robot: Robot, sim: Simulation
                                                           ) -> None:
    """Segment 1's end moves with angle 1 alone, so its bound is |dp/dtheta_1| times the angle's
    bound, frame by frame (the covariance block, not only its diagonal, enters segment 2's)."""
    tips = tip_bound(sim, 1.0, PRIOR, step=5)
    angles = sequence_bound(sim, 1.0, theta0_sigma=PRIOR).sigmas[tips.frames]
    bending = Bending.fixed(robot.segments)
    assert sim.sequence.thetas is not None
    for i, f in enumerate(tips.frames.tolist()):
        J = end_jacobians(robot, bending, sim.sequence.thetas[f])
        assert np.allclose(J[0, :, 1], 0.0)  # the first end ignores the second angle
        assert tips.sigmas[i, 0] == pytest.approx(np.linalg.norm(J[0, :, 0]) * angles[i, 0],
                                                  rel=1e-6)
        # segment 2's end: at least what its own angle alone would give it, with both
        lower = np.linalg.norm(J[1, :, 1]) * angles[i, 1]
        assert tips.sigmas[i, 1] > 0.5 * lower


@pytest.mark.parametrize("lag", [None, 4])
def test_every_end_is_the_inverse_information_through_the_kinematics(
        robot: Robot, sim: Simulation, lag: int | None) -> None:
    """Against the dense inverse of the information (of the frames up to f + lag), cross terms
    between the angles included."""
    tips = tip_bound(sim, 1.0, PRIOR, lag_frames=lag, step=7)
    bending, S = Bending.fixed(robot.segments), robot.n_segments
    assert sim.sequence.thetas is not None
    for i, f in enumerate(tips.frames.tolist()):
        end = sim.sequence.n_frames - 1
        last = end if lag is None else min(f + lag, end)
        kept = (last + 1) * S
        info = fisher_information(sim, 1.0, PRIOR, last_frame=last)[:kept, :kept]
        C = np.linalg.inv(info)[f * S:(f + 1) * S, f * S:(f + 1) * S]
        J = end_jacobians(robot, bending, sim.sequence.thetas[f])
        expected = [math.sqrt(np.trace(J[j] @ C @ J[j].T)) for j in range(S)]
        assert tips.sigmas[i] == pytest.approx(expected, rel=1e-6)


def test_a_lag_longer_than_the_recording_is_the_whole_bound(sim: Simulation) -> None:
    whole = tip_bound(sim, 1.0, PRIOR, step=6)
    long = tip_bound(sim, 1.0, PRIOR, lag_frames=sim.sequence.n_frames, step=6)
    assert np.allclose(long.sigmas, whole.sigmas, rtol=1e-6)
    assert long.lag_frames == sim.sequence.n_frames and whole.lag_frames is None


def test_a_shorter_lag_knows_less(sim: Simulation) -> None:
    """The filter (lag 0) >= a lag of 5 frames >= the whole recording, at every sampled frame,
    and the lag's first end is the per-angle lag bound through the lever."""
    whole, five, zero = (tip_bound(sim, 1.0, PRIOR, lag_frames=lag, step=4)
                         for lag in (None, 5, 0))
    assert np.all(zero.sigmas >= five.sigmas * (1 - 1e-9))
    assert np.all(five.sigmas >= whole.sigmas * (1 - 1e-9))
    assert np.any(zero.sigmas > 1.2 * whole.sigmas)
    angles = lag_bound(sim, 1.0, 5, theta0_sigma=PRIOR, step=4).sigmas
    ratio = five.sigmas[:, 0] / angles[:, 0]
    assert np.all(ratio > 0.1) and np.all(ratio < 0.6)  # the lever: about the segment's length


def test_the_spatial_bound_holds_the_planar_one(robot: Robot) -> None:
    """Free bending planes add unknowns: the ends' bound can only grow."""
    sim = simulate(robot, 12, noise_px=1.0, seed=5, scene="room", n_points=400, spatial=True)
    planar_robot_sim = simulate(robot, 12, noise_px=1.0, seed=5, scene="room", n_points=400)
    spatial = tip_bound(planar_robot_sim, 1.0, PRIOR, step=3, spatial=True)
    planar = tip_bound(planar_robot_sim, 1.0, PRIOR, step=3)
    assert np.all(spatial.sigmas >= planar.sigmas * (1 - 1e-9))
    assert np.all(np.isfinite(tip_bound(sim, 1.0, PRIOR, step=4, spatial=True).sigmas))


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(-0.9, 0.9), min_size=2, max_size=2),
       st.lists(st.floats(-3.0, 3.0), min_size=2, max_size=2))
def test_the_ends_jacobian_predicts_small_moves(thetas: list[float], psis: list[float]) -> None:
    robot = Robot(SEGMENTS, [None, None])
    bending = Bending.free(robot.segments)
    x = bending.vector(np.array(thetas), np.array(psis))
    J = end_jacobians(robot, bending, x)
    dx = np.random.default_rng(0).normal(size=x.shape) * 1e-4
    moved = robot.forward(*bending.polar(x + dx))[..., :3, 3]
    here = robot.forward(*bending.polar(x))[..., :3, 3]
    assert np.allclose(moved - here, J @ dx, atol=1e-7)


def test_bad_arguments_are_refused(sim: Simulation) -> None:
    with pytest.raises(ValueError, match="step"):
        tip_bound(sim, 1.0, PRIOR, step=0)
    with pytest.raises(ValueError, match="lag_frames"):
        tip_bound(sim, 1.0, PRIOR, lag_frames=-1)


def test_a_frame_no_camera_saw_leaves_the_bound_infinite(robot: Robot) -> None:
    """A frame without observations is undetermined (no motion prior in the bound): the whole
    bound is inf rather than an exception, and the lag bound of the frames before it is not."""
    sim = simulate(robot, 10, noise_px=1.0, seed=6, scene="room", n_points=400)
    seq, blind = sim.sequence, 6
    keep = {c: t.frames != blind for c, t in seq.tracks.items()}
    tracks = {c: Tracks(t.frames[keep[c]], t.track_ids[keep[c]], t.uv[keep[c]])
              for c, t in seq.tracks.items()}
    cut = dataclasses.replace(
        sim, sequence=Sequence(seq.robot, seq.timestamps, tracks, seq.world_T_base, seq.thetas,
                               seq.psis),
        landmarks={c: sim.landmarks[c][keep[c]] for c in keep},
        clean_uv={c: sim.clean_uv[c][keep[c]] for c in keep},
        outliers={c: sim.outliers[c][keep[c]] for c in keep})
    assert np.all(np.isinf(tip_bound(cut, 1.0, PRIOR, step=3).sigmas))
    lagged = tip_bound(cut, 1.0, PRIOR, lag_frames=1, step=1)
    assert np.all(np.isfinite(lagged.sigmas[lagged.frames < blind - 1]))
    assert np.all(np.isinf(lagged.sigmas[lagged.frames >= blind - 1]))
