"""One smoother, two measurement models: the stages of an update in their order, the model
chosen in one place, the fault handling and live working for the model-noise model too, the
detectors pure, and iSAM2 called by its owner alone."""

from __future__ import annotations

import ast
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

from apcc_graph.bench.smoother import FPS, ROBOT_FILE
from apcc_graph.estimation.blackout import BlackoutWarning
from apcc_graph.estimation.live import LiveEstimator
from apcc_graph.estimation.methods import estimate
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.smoother import FixedLagSmoother, gaps
from apcc_graph.estimation.start_check import StartWarning
from apcc_graph.io.robot_file import load_robot
from apcc_graph.simulation import faults
from apcc_graph.simulation.simulator import simulate

NOISE = GraphOptions(model_sigma=(0.3e-3, math.radians(0.2)))
ESTIMATION = Path(__file__).resolve().parents[1] / "apcc_graph" / "estimation"


def _simulation(frames: int, seed: int):  # noqa: ANN202
    return simulate(load_robot(ROBOT_FILE), frames, noise_px=1.0, outlier_fraction=0.1,
                    seed=seed, fps=FPS, scene="room", n_points=1000)


@pytest.mark.parametrize("options", [GraphOptions(), NOISE], ids=["exact", "model noise"])
def test_an_update_runs_its_stages_in_order(options: GraphOptions) -> None:
    seq = _simulation(6, 3).sequence
    smoother = FixedLagSmoother(seq.robot, theta0=seq.thetas[0], options=options)
    calls: list[str] = []
    model = smoother._model
    for name in ("judge", "make_room", "retire", "associate", "known_rows", "enter", "observe",
                 "replaceable", "read"):
        method = getattr(model, name)

        def spy(*args: object, _name: str = name, _method: object = method) -> object:
            calls.append(_name)
            return _method(*args)  # type: ignore[operator]

        setattr(model, name, spy)
    for f in range(4):
        calls.clear()
        smoother.update(seq.frame(f))
    assert calls == ["judge", "make_room", "retire", "associate", "known_rows", "enter",
                     "observe", "replaceable", "read"]
    # the default: the robot file's model error, none here: the exact model
    assert smoother.measurement_model == ("model noise" if options is NOISE else "exact")


def test_exact_against_model_noise_is_decided_in_one_place() -> None:
    """Only the two choosers read ``model_sigma`` to pick a measurement model (the batch's and
    the smoother's); the options record validates it and the chain refuses it."""
    readers = []
    for path in sorted(ESTIMATION.rglob("*.py")):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if (isinstance(node, ast.Compare) and isinstance(node.left, ast.Attribute)
                    and node.left.attr == "model_sigma"
                    and any(isinstance(c, ast.Constant) and c.value is None
                            for c in node.comparators)):
                readers.append(path.relative_to(ESTIMATION).as_posix())
    # the two choosers; the record's validation; the chain's refusal; the noisy model's check
    assert set(readers) <= {"smoother/measurement.py", "terms/__init__.py", "options.py",
                            "methods.py", "smoother/noisy.py"}, readers


def test_isam2_is_called_by_its_owner_alone() -> None:
    """``update`` and ``calculateEstimate`` of gtsam's window appear in the solver only."""
    callers = set()
    for path in sorted(ESTIMATION.rglob("*.py")):
        text = path.read_text()
        if ".window.update(" in text or "calculateEstimate()" in text or "ISAM2(" in text:
            callers.add(path.relative_to(ESTIMATION).as_posix())
    assert callers <= {"smoother/solver.py", "smoother/fixed_lag.py"}, callers


def test_no_mixin_and_no_smoother_module_over_400_lines() -> None:
    core = (ESTIMATION / "smoother" / "core.py").read_text()
    assert "class FixedLagSmoother:" in core
    for path in (ESTIMATION / "smoother").glob("*.py"):
        assert len(path.read_text().splitlines()) <= 400, path


def test_the_detectors_are_pure_functions_of_what_they_see() -> None:
    rows = {0: (np.array([5, 6]), np.zeros((2, 2)), np.zeros((2, 2, 2)))}
    none_known = lambda cam, ids: np.zeros(len(ids), dtype=bool)  # noqa: E731
    x = np.array([0.1, 0.2, 0.3])
    small = lambda: np.full(3, 0.01)  # noqa: E731
    plan = gaps.blackout(10, rows, {}, True, none_known, x, small, 0.1)
    assert plan is not None and plan.kind == "blackout" and plan.restart_at == 9
    assert gaps.blackout(10, rows, rows, True, none_known, x, small, 1.0) is None
    all_known = lambda cam, ids: np.ones(len(ids), dtype=bool)  # noqa: E731
    # returning ids are taken for a tie across a short blackout, not across a long one
    assert gaps.blackout(10, rows, {}, True, all_known, x, small, 0.2) is None
    assert gaps.blackout(10, rows, {}, True, all_known, x, small, 1.0) is not None
    paused, plan = gaps.pause(3.0, 1.5, 1.0, rows, none_known, x, 0.5)
    assert paused and plan is not None and plan.then == gaps.SECOND_ROUND
    assert plan.sigma == pytest.approx(min(gaps.LOOSE, 0.5 * math.sqrt(1.5)))
    assert gaps.pause(3.0, 1.5, 1.0, rows, all_known, x, 0.5) == (True, None)
    assert gaps.pause(3.0, 2.9, 1.0, rows, none_known, x, 0.5) == (False, None)
    lost = gaps.lost_camera(rows, {1: rows[0]}, none_known, {}, lambda h: False,
                            lambda: np.diag([1e-6, 1.0, 1e-6]), x, 1)
    assert lost is None  # camera 0's segment is known to 1 mrad
    lost = gaps.lost_camera(rows, {1: rows[0]}, none_known, {}, lambda h: False,
                            lambda: np.diag([1.0, 1e-6, 1e-6]), x, 1)
    assert lost is not None and lost.camera == 0 and lost.since == 0


def test_rounds_go_on_while_the_batch_is_unsure() -> None:
    """After a gap the frames are re-acquired over one lag, then over the second round's span,
    then over twice the last span while the batch's newest sigma exceeds SURE, up to
    LONGEST; a one-round plan (a lost camera, a contradicted start) stops after one."""
    unsure, sure = 2.0 * gaps.SURE, 0.5 * gaps.SURE
    assert gaps.next_round(None, None, unsure, 1.0) is None  # a one-round plan
    assert gaps.next_round(None, 2.0, sure, 1.0) == 2.0  # the second round, sure or not
    assert gaps.next_round(2.0, None, sure, 1.0) is None
    assert gaps.next_round(2.0, None, unsure, 1.0) == 4.0
    assert gaps.next_round(2.0, None, math.nan, 1.0) == 4.0  # no sigma: not sure
    assert gaps.next_round(None, 2.0, unsure, 2.0) == 4.0  # a 2 s lag: its first was 2 s
    assert gaps.next_round(None, 2.0, sure, 3.0) is None
    assert gaps.next_round(0.75 * gaps.LONGEST, None, unsure, 1.0) == gaps.LONGEST
    assert gaps.next_round(gaps.LONGEST, None, unsure, 1.0) is None
    spans, span, then = [], None, 2.0  # a batch that never becomes sure
    while (nxt := gaps.next_round(span, then, unsure, 1.0)) is not None:
        spans.append(nxt)
        span, then = nxt, None
    assert spans == [2.0, 4.0, gaps.LONGEST]


@pytest.fixture(scope="module")
def blackout_with_model_noise() -> tuple[object, object, list[warnings.WarningMessage]]:
    """Every camera blind for half a second, tracks back under new ids, the model-noise
    smoother."""
    seq = faults.blind(_simulation(75, 4), [0, 1, 2], 25, 40).sequence
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        est = estimate(seq, method="smoother", theta0=seq.thetas[0], noise_px=1.0, graph=NOISE)
    return seq, est, caught


def test_a_segment_seen_only_through_the_cameras_beyond_it_gets_a_longer_window() -> None:
    seen = {0: 9.9, 2: 9.95}  # camera 1 (index 1) never saw
    assert gaps.weakly_seen(seen, (0, 1, 2), 10.0, 1.0)  # camera 3 sees beyond it
    assert not gaps.weakly_seen({0: 9.9, 1: 9.9, 2: 9.9}, (0, 1, 2), 10.0, 1.0)
    assert not gaps.weakly_seen({0: 9.9, 1: 9.9, 2: 8.0}, (0, 1, 2), 10.0, 1.0)  # the last
    assert gaps.weakly_seen({0: 8.5, 1: 9.9, 2: 9.9}, (0, 1, 2), 10.0, 1.0)


def test_the_model_noise_smoother_reacquires_after_a_blackout(
        blackout_with_model_noise: tuple) -> None:
    """It says so and re-acquires the frames after it with its own batch, as the exact
    smoother does."""
    seq, est, caught = blackout_with_model_noise
    said = [str(w.message) for w in caught if issubclass(w.category, BlackoutWarning)]
    assert any(m.startswith("frame 40") for m in said), said
    assert "reacquired" in set(est.status[40:].ravel())
    assert np.all(np.isfinite(est.thetas)) and np.all(np.isfinite(est.sigmas))


@pytest.mark.xfail(strict=True, reason="known fault of model error as independent per-frame "
                   "noise: the first frames are 1.8-2.0 deg off (they get no image information "
                   "until a track has 3 rows and 1 deg of parallax, and per-frame tip noise lets "
                   "the wrong guesses stay), and the start check calls the right start "
                   "contradicted (chi-square 69 against 21: the images pulled frame 0 by 0.14 "
                   "deg where its marginal allows 0.04); the search then keeps it")
def test_the_model_noise_smoother_keeps_a_right_start_before_a_blackout(
        blackout_with_model_noise: tuple) -> None:
    seq, est, _ = blackout_with_model_noise
    err = np.degrees(np.abs(est.thetas - seq.thetas))
    assert np.max(err[:25]) < 1.0, np.max(err[:25])


@pytest.fixture(scope="module")
def pause_with_model_noise() -> tuple[object, object]:
    """Half a second of frames never received while the robot moved on, every track after it
    new, the model-noise smoother."""
    sim = _simulation(75, 5)
    seq = faults.paused(faults.blind(sim, [0, 1, 2], 30, 45), 30, 45).sequence
    with pytest.warns(BlackoutWarning, match=r"frame 30 .* paused for 0\.5\d s"):
        est = estimate(seq, method="smoother", theta0=seq.thetas[0], noise_px=1.0,
                       graph=NOISE)
    return seq, est


def test_the_model_noise_smoother_reacquires_after_a_pause(pause_with_model_noise: tuple
                                                           ) -> None:
    """Said, and every frame after it re-acquired by the model-noise batch (the last round
    when the recording ends)."""
    seq, est = pause_with_model_noise
    assert (est.status[30:] == "reacquired").all()
    assert np.all(np.isfinite(est.thetas)) and np.all(np.isfinite(est.sigmas))


def test_the_model_noise_smoother_is_honest_after_a_pause(pause_with_model_noise: tuple
                                                          ) -> None:
    """After the pause its sigmas cover its errors. Measured: max |e|/sigma 2.5 per segment
    here (seeds 6 and 7: 1.8 and 3.0), errors up to 5.7, 6.7 and 14.9 deg. (With each point a
    variable under a prior, 9.1 deg off with a sigma of 0.24: |e|/sigma 39.)"""
    seq, est = pause_with_model_noise
    z = np.abs(est.thetas[30:] - seq.thetas[30:]) / est.sigmas[30:]
    assert np.max(z) < 5.0, np.max(z, axis=0)


@pytest.mark.xfail(strict=True, reason="known fault: the start check does not call the wrong "
                   "start contradicted with model noise (no warning on seeds 6, 7 and 8; the "
                   "first 30 frames stay 5.1-5.7 deg off). Before the window's points were "
                   "eliminated, gtsam failed at frame 13 and frame 0 left unchecked")
def test_the_model_noise_smoother_replaces_a_contradicted_start() -> None:
    """A start 5 deg off on segment 1 under a 0.1 deg prior: the start check says so and the
    search over the first second replaces it, as for the exact model."""
    seq = _simulation(60, 6).sequence
    wrong = seq.thetas[0] + np.radians([5.0, 0.0, 0.0])
    with pytest.warns(StartWarning, match="replaced by the unknown-start search's answer"):
        est = estimate(seq, method="smoother", theta0=wrong, noise_px=1.0, graph=NOISE)
    err = np.degrees(np.abs(est.thetas[:30, 0] - seq.thetas[:30, 0]))
    assert np.max(err) < 2.5, err


def test_the_model_noise_smoother_runs_live() -> None:
    from test_live import _frames  # the live tests' panning textures

    live = LiveEstimator(load_robot(ROBOT_FILE), np.zeros(3), realtime=False, graph=NOISE)
    assert live.smoother is not None and live.smoother.measurement_model == "model noise"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        got = list(live.run(_frames(8)))
        final = [fr.frame for e in got for fr in e.final] + [fr.frame for fr in live.finish()]
    assert final == list(range(8))
    assert np.all(np.isfinite([e.thetas for e in got]))
