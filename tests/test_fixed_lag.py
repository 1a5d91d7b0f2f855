"""The fixed-lag smoother over iSAM2 (:class:`~apcc_graph.estimation.smoother.fixed_lag.
FixedLagISAM2`)
against gtsam's own ``IncrementalFixedLagSmoother``, and its marginalisation's pitfalls."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from apcc_graph.estimation.smoother.fixed_lag import FixedLagISAM2

LAG, DT = 0.5, 0.1


def _params() -> gtsam.ISAM2Params:
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(1e-3)
    params.relinearizeSkip = 1
    params.findUnusedFactorSlots = True
    return params


def _step(k: int, rng: np.random.Generator, landmarks: bool
          ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, dict[int, float]]:
    """Frame ``k`` of a walk of 2-vectors measured each frame, and a landmark-like 2-vector
    variable every third frame that the next four frames observe relative to theirs (a graph
    whose cliques mix leaving and kept variables)."""
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    x, t = gtsam.symbol("x", k), k * DT
    values.insert(x, rng.normal(size=2))
    stamps = {x: t}
    if k == 0:
        graph.add(gtsam.PriorFactorVector(x, np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(2, 1.0)))
    else:
        graph.add(gtsam.BetweenFactorVector(gtsam.symbol("x", k - 1), x, rng.normal(size=2) * 0.1,
                                            gtsam.noiseModel.Isotropic.Sigma(2, 0.1)))
    if k % 2 == 0:  # some frames see nothing but the walk
        graph.add(gtsam.PriorFactorVector(x, rng.normal(size=2),
                                          gtsam.noiseModel.Isotropic.Sigma(2, 0.5)))
    if landmarks:
        if k % 3 == 0:
            lm = gtsam.symbol("l", k)
            values.insert(lm, rng.normal(size=2))
            graph.add(gtsam.PriorFactorVector(lm, np.zeros(2),
                                              gtsam.noiseModel.Isotropic.Sigma(2, 10.0)))
            stamps[lm] = t
        for j in range(max(0, k - 4), k + 1):
            if j % 3 == 0:
                lm = gtsam.symbol("l", j)
                graph.add(gtsam.BetweenFactorVector(x, lm, rng.normal(size=2) * 0.05,
                                                    gtsam.noiseModel.Isotropic.Sigma(2, 0.05)))
                stamps[lm] = t  # seen now: kept while seen
    return graph, values, stamps


def _run(smoother: object, frames: int, landmarks: bool, gtsam_stamps: bool) -> list[np.ndarray]:
    rng = np.random.default_rng(7)
    out = []
    for k in range(frames):
        graph, values, stamps = _step(k, rng, landmarks)
        if gtsam_stamps:
            ts = gtsam.FixedLagSmootherKeyTimestampMap()
            for key, s in stamps.items():
                ts.insert((key, s))
            smoother.update(graph, values, ts)  # type: ignore[attr-defined]
        else:
            smoother.update(graph, values, stamps)  # type: ignore[attr-defined]
        x = gtsam.symbol("x", k)
        out.append(np.concatenate([smoother.calculateEstimate().atVector(x),  # type: ignore
                                   np.ravel(smoother.marginalCovariance(x))]))  # type: ignore
    return out


@pytest.mark.parametrize("landmarks", [False, True])
def test_it_estimates_what_gtsams_fixed_lag_smoother_does(landmarks: bool) -> None:
    ours = _run(FixedLagISAM2(LAG, _params(), slack=0.0), 40, landmarks, False)
    theirs = _run(gtsam.IncrementalFixedLagSmoother(LAG, _params()), 40, landmarks, True)
    np.testing.assert_allclose(np.array(ours), np.array(theirs), rtol=1e-6, atol=1e-9)


def test_it_marginalises_what_left_the_lag_and_keeps_the_rest() -> None:
    """Including frames held by the walk alone, and a landmark whose only factor left is its
    prior once its observers are gone."""
    smoother = FixedLagISAM2(LAG, _params(), slack=0.0)
    rng = np.random.default_rng(7)
    for k in range(30):
        smoother.update(*_step(k, rng, True))
    estimate = smoother.calculateEstimate()
    now = 29 * DT
    for key, stamp in smoother.stamps.items():
        assert stamp >= now - LAG - 1e-12 and estimate.exists(key)
    assert not estimate.exists(gtsam.symbol("x", 20))  # 0.9 s old
    assert estimate.exists(gtsam.symbol("x", 25)) and estimate.exists(gtsam.symbol("x", 29))
    assert estimate.size() == len(smoother.stamps)


def test_it_marginalises_in_blocks_once_the_oldest_is_slack_past_the_lag() -> None:
    slack = 0.25
    smoother = FixedLagISAM2(LAG, _params(), slack=slack)
    rng = np.random.default_rng(7)
    blocks = 0
    for k in range(60):
        held = len(smoother.stamps)
        smoother.update(*_step(k, rng, True))
        now = k * DT
        oldest = min(smoother.stamps.values())
        assert oldest >= now - LAG - slack - 1e-12  # never longer than lag + slack
        if len(smoother.stamps) < held:  # a block left: everything past the lag
            blocks += 1
            assert oldest >= now - LAG - 1e-12
    assert 60 * DT / (LAG + slack) - 2 <= blocks <= 60 * DT / slack


def test_it_gives_the_same_bytes_twice() -> None:
    a = _run(FixedLagISAM2(LAG, _params()), 60, True, False)
    b = _run(FixedLagISAM2(LAG, _params()), 60, True, False)
    assert np.array(a).tobytes() == np.array(b).tobytes()


def test_the_result_is_asked_for_only_after_an_update() -> None:
    with pytest.raises(RuntimeError, match="no update yet"):
        FixedLagISAM2(LAG, _params()).getISAM2Result()


def test_the_bench_times_both_windows_on_one_recording() -> None:
    """The speed peer of ``bench smoother``: the smoother with each window solver on the same
    frames; the two estimate the same angles (they differ only in when they marginalise)."""
    from pathlib import Path

    from apcc_graph.bench.engines import format_window_times, window_times
    from apcc_graph.estimation.smoother_options import SmootherOptions, WindowOptions
    from apcc_graph.io.sequence_folder import load_sequence

    sample = load_sequence(Path(__file__).resolve().parents[1] / "data/sequences/planar_three")
    rows = window_times(sample.head(45), SmootherOptions(window=WindowOptions(uncertainty=False)))
    assert [r.window for r in rows] == ["reproducible", "gtsam"]
    assert all(0.0 < r.update_median <= r.update_p95 for r in rows)
    assert np.max(np.abs(rows[0].thetas - rows[1].thetas)) < np.radians(0.05)
    text = "\n".join(format_window_times(rows))
    assert "ours / gtsam's: update median" in text and "largest angle difference" in text


def test_the_smoother_chooses_its_window_by_its_options() -> None:
    from apcc_graph.bench.smoother import ROBOT_FILE
    from apcc_graph.estimation.smoother import FixedLagSmoother
    from apcc_graph.estimation.smoother.fixed_lag import GtsamFixedLag
    from apcc_graph.estimation.smoother_options import SmootherOptions, WindowOptions
    from apcc_graph.io.robot_file import load_robot

    robot = load_robot(ROBOT_FILE)
    assert isinstance(FixedLagSmoother(robot)._smoother, FixedLagISAM2)
    gtsam_window = SmootherOptions(window=WindowOptions(reproducible=False))
    peer = FixedLagSmoother(robot, settings=gtsam_window)
    assert isinstance(peer._smoother, GtsamFixedLag)
