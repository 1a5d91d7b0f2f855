"""The default smoother under faults: each fault of ``apcc-graph bench reliability``, shortened
(210 frames, the fault from frame 70). Each must recover within 30 frames to within 2x the
undisturbed error, or say that it cannot; sigmas must cover the errors where it claims them.

Two faults are known failures today and marked so, with what was measured: the smoother does
not get the absolute angles back after every camera went blind, and after one camera's
blindness its segment keeps an offset.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from apcc_graph.bench.reliability import (
    FaultCase,
    FaultRun,
    fault_cases,
    format_reliability,
    run_case,
)
from apcc_graph.bench.smoother import NOISE_PX, THETA0_SIGMA
from apcc_graph.estimation.blackout import BlackoutWarning, Reacquired, Reacquisition
from apcc_graph.estimation.methods import ObservationWarning, estimate
from apcc_graph.estimation.smoother.restarts import Recovery
from apcc_graph.estimation.start_check import StartWarning, start_chi2
from apcc_graph.evaluation.recovery import sigma_honesty
from apcc_graph.evaluation.sequence_bound import sequence_bound
from apcc_graph.model.arrays import rms

FRAMES = 210


@pytest.fixture(scope="module")
def cases() -> dict[str, FaultCase]:
    return {case.name: case for case in fault_cases(FRAMES, seed=1)}


@pytest.fixture(scope="module")
def undisturbed(cases: dict[str, FaultCase]) -> tuple[FaultRun, np.ndarray]:
    return run_case(cases["none"])


def _run(cases: dict[str, FaultCase], undisturbed: tuple[FaultRun, np.ndarray], name: str
         ) -> tuple[FaultRun, tuple[str, ...]]:
    """The row and the warnings the run gave (``"Category: message"``)."""
    row, _ = run_case(cases[name], undisturbed[1], cases["none"].simulation)
    return row, row.warnings


def test_the_undisturbed_run_is_near_its_bound_with_honest_sigmas(
        undisturbed: tuple[FaultRun, np.ndarray]) -> None:
    row = undisturbed[0]
    assert np.all(row.rms < 2.0 * row.bound), (np.degrees(row.rms), np.degrees(row.bound))
    assert row.z2 < 3.0 and row.within_3_sigma > 0.95


@pytest.mark.parametrize("name", ["robot frozen for 4 s", "segment 2 jumps 10 deg in one frame",
                                  "camera 2: ids swapped for 10 frames",
                                  "camera 2: 50% outliers for 1 s"])
def test_recovers_within_30_frames(cases: dict[str, FaultCase],
                                   undisturbed: tuple[FaultRun, np.ndarray], name: str) -> None:
    row, _ = _run(cases, undisturbed, name)
    assert row.recovery is not None and row.recovery <= 30, row
    assert row.z2 < 3.0, row  # and its sigmas stay honest through the fault
    if name.startswith("robot frozen"):  # held out of the graph, and near the bound throughout
        assert "still x" in row.did and np.all(row.rms < 2.0 * row.bound), row


def test_a_camera_that_never_sees_is_estimated_from_the_next_one_and_said(
        cases: dict[str, FaultCase], undisturbed: tuple[FaultRun, np.ndarray]) -> None:
    row, caught = _run(cases, undisturbed, "camera 2 never sees anything")
    assert any(w.startswith(ObservationWarning.__name__) and "cam_2" in w for w in caught)
    # camera 3 carries segment 2: near the bound of that recording, with sigmas that cover it
    assert row.rms[1] < 2.0 * row.bound[1], (np.degrees(row.rms), np.degrees(row.bound))
    assert row.z2 < 3.0 and row.within_3_sigma > 0.95, row


HELD: list[dict[str, object]] = []
"""What the window held right after each restart of the ``blind`` run's re-acquisitions."""


@pytest.fixture(scope="module")
def blind(cases: dict[str, FaultCase], undisturbed: tuple[FaultRun, np.ndarray]
          ) -> tuple[FaultCase, FaultRun, np.ndarray]:
    case = cases["all cameras blind for 1 s"]
    holding = Recovery._restart_holding

    def recorded(self: Recovery, kept: Reacquisition, found: Reacquired) -> object:
        out = holding(self, kept, found)
        window = self.window
        HELD.append({
            "slots": list(kept.slots), "window": sorted(window.stamps),
            "moved": max(float(np.max(np.abs(window.thetas[h] - found.x[k])))
                         for k, h in enumerate(kept.slots) if window.inside(h)),
            "cameras": [len(self.model.tracks.live.frame_rows(h))  # type: ignore[attr-defined]
                        for h in kept.slots]})
        return out

    HELD.clear()
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(Recovery, "_restart_holding", recorded)
        return (case, *run_case(case, undisturbed[1], cases["none"].simulation))


def test_tracks_that_return_after_every_camera_went_blind_are_said(
        blind: tuple[FaultCase, FaultRun, np.ndarray],
        undisturbed: tuple[FaultRun, np.ndarray]) -> None:
    case, row, _ = blind
    said = [w for w in row.warnings if w.startswith(BlackoutWarning.__name__)]
    assert len(said) == 1 and f"frame {case.stop} " in said[0], said
    assert not any(w.startswith(BlackoutWarning.__name__) for w in undisturbed[0].warnings)
    # re-acquired by one batch over the new tracks: honest sigmas throughout (the robot moved
    # 60 deg in the dark; the smoother alone stayed tens of degrees off)
    assert row.z2 < 3.0 and row.within_3_sigma > 0.95, row


def test_the_window_restarts_holding_the_reacquired_frames(
        blind: tuple[FaultCase, FaultRun, np.ndarray]) -> None:
    """After the batch re-acquired the frames since the tracks came back, the new window holds
    every one of them (the blind frame it restarted at has left), their observations of every
    camera in its live tracks, and its estimates stay at the batch's answer (measured: within
    0.07 deg). Its first update held only the priors once: one Gauss-Newton step then pulled
    every frame onto the start prior, 17 to 49 deg from the batch's answer on the pause. A
    second round, once the frames span 2 s, holds those still inside the window likewise."""
    case = blind[0]
    assert len(HELD) == 2, HELD
    held = HELD[0]
    assert held["slots"][0] == case.stop and held["window"] == held["slots"], held
    assert held["cameras"] == [3] * len(held["slots"]), held
    second = HELD[1]
    assert second["slots"][0] == case.stop and second["slots"][-1] == second["window"][-1]
    inside = [n for h, n in zip(second["slots"], second["cameras"], strict=True)
              if h in second["window"]]
    assert set(second["window"]) <= set(second["slots"]) and inside == [3] * len(inside)
    assert held["moved"] < math.radians(0.3), math.degrees(held["moved"])
    # the second round's frames were in the window longer: measured 0.32 deg from its answer
    assert second["moved"] < math.radians(1.0), math.degrees(second["moved"])


def test_the_blind_frames_are_bridged_across_the_blackout(
        blind: tuple[FaultCase, FaultRun, np.ndarray]) -> None:
    """In the dark the segments go up to 60 / 7 / 34 deg from where they were last seen. The
    blind frames rest on the motion prior between the last frame seen and the first re-acquired
    one: measured 7.7 / 7.0 / 1.1 deg RMS, within 0.6 sigma (a straight line between the two
    cannot follow segment 2's 7 deg excursion). Dragged by the new tracks' first, wrong minimum
    they were 30-360 deg off with sigmas of 5-14 deg ((e/s)^2 up to 81 over the recording)."""
    case, _, errors = blind
    dark = slice(case.start, case.stop)
    truth = case.simulation.sequence.thetas
    went = np.max(np.abs(truth[dark] - truth[case.start - 1]), axis=0)
    assert np.all(rms(errors[dark]) < 0.5 * np.maximum(went, math.radians(20.0))), (
        np.degrees(rms(errors[dark])), np.degrees(went))


def test_after_every_camera_went_blind_a_second_later_within_twice_the_bound(
        blind: tuple[FaultCase, FaultRun, np.ndarray]) -> None:
    """Measured: 0.58 / 0.16 / 0.08 deg RMS from two seconds after the tracks came back, against
    twice the bound of 1.17 / 0.27 / 0.19 (0.72 / 0.20 / 0.09 while the window restarted from
    one frame and a prior). It was 2.1 deg on segment 1 while the window's
    restart after the re-acquisition forgot the newest frame's observations (the new track
    pieces then started a frame later, and gtsam failed twice on the window)."""
    case, _, errors = blind
    later = slice(case.stop + 60, None)
    bound = sequence_bound(case.simulation, NOISE_PX, THETA0_SIGMA).sigmas[later]
    assert np.all(rms(errors[later]) < 2.0 * rms(bound)), (np.degrees(rms(errors[later])),
                                                           np.degrees(rms(bound)))


def test_the_lag_bound_says_which_recovery_no_smoother_can_make(
        blind: tuple[FaultCase, FaultRun, np.ndarray], cases: dict[str, FaultCase],
        undisturbed: tuple[FaultRun, np.ndarray]) -> None:
    """The yardstick of the 30-frame target: the bound of a 1 s lag 30 frames after the fault
    ends, beside the undisturbed recording's at that frame. Every camera's blackout raises it
    more than twice on segment 1 (being back within twice the undisturbed error by then asks
    more than the images allow); ten frames of swapped ids leave it as it was."""
    case, row, _ = blind
    assert row.lag_after is not None and row.lag_clean is not None
    assert np.all(np.isfinite(row.lag_after))  # the blind frames are left out, not inf
    assert row.beyond_bound and row.lag_after[0] > 2.0 * row.lag_clean[0], (
        np.degrees(row.lag_after), np.degrees(row.lag_clean))
    swapped, _ = _run(cases, undisturbed, "camera 2: ids swapped for 10 frames")
    assert swapped.lag_after is not None and swapped.lag_clean is not None
    np.testing.assert_allclose(swapped.lag_after, swapped.lag_clean, rtol=0.2)
    assert not swapped.beyond_bound
    assert undisturbed[0].lag_after is None  # nothing to recover from
    table = format_reliability([undisturbed[0], row, swapped], FRAMES)
    ratio = " ".join(f"{v:4.1f}" for v in row.lag_after / row.lag_clean) + "*"
    assert "lag bound +30" in table and ratio in table, table


def test_a_start_that_contradicts_the_images_is_said_and_replaced(
        cases: dict[str, FaultCase], undisturbed: tuple[FaultRun, np.ndarray]) -> None:
    """Measured (300 frames): with the start kept, RMS 4.6 / 1.3 / 1.5 deg and (e/s)^2 1866;
    replaced by the start search over the first second, 0.52 / 0.20 / 0.19 deg, (e/s)^2 3.0.
    The first second's images tell segment 1 to 1.5 deg only (the search's sigma, honest to a
    few percent), so frame 0 stays about that far off."""
    case = cases["start 5 deg off"]
    row, errors = run_case(case, undisturbed[1])
    said = [w for w in row.warnings if w.startswith(StartWarning.__name__)]
    assert len(said) == 1 and "contradicts the images" in said[0]
    assert "replaced by the unknown-start search's answer" in said[0], said
    assert np.all(rms(errors) < math.radians(1.0)), np.degrees(rms(errors))
    assert row.z2 < 5.0, row  # honest again, where the kept start claimed 0.1 deg
    # and a start that agrees is not flagged (the undisturbed run used the true start)
    assert not any(w.startswith(StartWarning.__name__) for w in undisturbed[0].warnings)


def test_the_start_statistic() -> None:
    sigma0, cov = math.radians(0.1), np.diag([0.5, 0.9, 0.99]) * math.radians(0.1) ** 2
    theta0 = np.zeros(3)
    # the images explain 50%, 10%, 1% of the prior's variance: a move of the size their
    # share predicts is one sigma each, so chi2 = 3
    moved = np.sqrt([0.5, 0.1, 0.01]) * sigma0
    assert start_chi2(theta0, sigma0, moved, cov) == pytest.approx(3.0)
    assert math.isnan(start_chi2(theta0, sigma0, moved, np.eye(3) * sigma0**2))


def test_a_segment_no_other_camera_sees_is_reacquired_when_its_camera_returns(
        cases: dict[str, FaultCase]) -> None:
    """Camera 3 alone sees segment 3; blind for 3 s, the segment drifts on the motion prior
    (sigma 50 deg) while the robot moves it 54 deg. Measured (these 210 frames): said at the
    return; one batch over the lag that follows re-acquires segment 3 alone (31 frames
    "reacquired", segments 1 and 2 never); from the return on 0.04 / 0.10 / 0.20 deg RMS against
    a bound of 0.10 / 0.07 / 0.12, (e/s)^2 at most 0.63; the blind frames bridged to 18 deg RMS.
    Without the re-acquisition segment 3 ended 63 deg off ((e/s)^2 27000) and its blind frames
    50 deg."""
    case = cases["camera 3 blind for 3 s"]
    seq = case.simulation.sequence
    assert seq.thetas is not None
    with pytest.warns(BlackoutWarning) as said:
        result = estimate(seq, method="smoother", theta0=case.theta0,
                          theta0_sigma=THETA0_SIGMA, noise_px=NOISE_PX)
    lost = [str(w.message) for w in said if "cam_3's tracks came back all new" in str(w.message)]
    assert len(lost) == 1 and lost[0].startswith(f"frame {case.stop} "), lost
    reacquired = result.status == "reacquired"
    assert reacquired[:, 2].sum() >= 20 and not reacquired[:, :2].any()
    errors, after = result.errors(seq.thetas), slice(case.stop, None)
    bound = sequence_bound(case.simulation, NOISE_PX, THETA0_SIGMA).sigmas[after]
    assert np.all(rms(errors[after]) < 2.0 * rms(bound)), (np.degrees(rms(errors[after])),
                                                           np.degrees(rms(bound)))
    z2, _ = sigma_honesty(errors[after], result.sigmas[after])
    assert np.all(z2 < 3.0), z2
    dark = slice(case.start, case.stop)
    went = np.max(np.abs(seq.thetas[dark, 2] - seq.thetas[case.start - 1, 2]))
    assert rms(errors[dark, 2]) < 0.5 * went, (np.degrees(rms(errors[dark, 2])), went)


def _known_failure(prefix: str, reason: str) -> object:
    return pytest.param(prefix, marks=pytest.mark.xfail(strict=False, reason=reason), id=prefix)


@pytest.mark.parametrize("prefix", [
    _known_failure("all cameras blind", "no estimator can: after the blackout the Cramer-Rao "
                   "bound of segment 1 is 0.58 deg with every frame of these 210 (the robot "
                   "moved 60 deg in the dark), above 2x the undisturbed error (0.09 deg); whether "
                   "the re-acquired smoother gets within twice the bound a second later is "
                   "tested above"),
    _known_failure("camera 2 blind", "recovers on these 210 frames, but the benchmark's "
                   "450-frame run took 254 frames (segment 2 RMS 0.20 deg, 2.3x the undisturbed "
                   "run), where the 1 s lag bound of segment 2 is 0.13 deg 30 frames after the "
                   "blackout and 0.09 after 60: an efficient smoother would be back in 30-60"),
])
def test_known_failures_recover_within_30_frames(
        cases: dict[str, FaultCase], undisturbed: tuple[FaultRun, np.ndarray],
        prefix: str) -> None:
    name = next(n for n in cases if n.startswith(prefix))
    row, _ = _run(cases, undisturbed, name)
    assert row.recovery is not None and row.recovery <= 30, row


@pytest.mark.parametrize(("offset_sigmas", "replaced"), [(2.0, False), (4.0, True)])
def test_the_start_is_replaced_only_by_a_search_answer_far_from_it(
        monkeypatch: pytest.MonkeyPatch, offset_sigmas: float, replaced: bool) -> None:
    """The decision rule alone (the search stubbed): an answer within 3 combined sigmas of the
    start does not replace it (on a real robot's replay the contradiction can be the model's,
    not the start's); one further away does, and the warning says which."""
    from apcc_graph.bench import ROBOT_FILE
    from apcc_graph.estimation import start_check
    from apcc_graph.estimation.blackout import Reacquisition
    from apcc_graph.estimation.options import GraphOptions, Robustness
    from apcc_graph.estimation.start_search import Hypothesis, StartSearch
    from apcc_graph.io.robot_file import load_robot
    from apcc_graph.model.parameterisation import Bending
    from apcc_graph.model.sequence import FrameObservations

    robot = load_robot(ROBOT_FILE)
    bending = Bending.fixed(robot.segments)
    theta0, sigma0, search_sigma = np.radians([10.0, -5.0, 3.0]), math.radians(0.5), 0.02
    combined = math.hypot(search_sigma, sigma0)
    x0 = theta0 + np.array([offset_sigmas * combined, 0.0, 0.0])
    blocks = np.full((2, 3, 1, 1), search_sigma**2)
    answer = StartSearch(2, 0.1, (Hypothesis(x0, np.stack([x0, x0]), blocks, 1.0),), True, "",
                         bending)
    monkeypatch.setattr(start_check, "find_start", lambda *args, **kwargs: answer)
    kept = Reacquisition(robot, GraphOptions(), 3.0, bending, theta0, sigma0)
    first = start_check.FirstFrames(kept, False, Robustness())
    for f in range(2):
        first.keep(f, f / 30.0, FrameObservations(f / 30.0, {}), True)
    with pytest.warns(StartWarning) as said:
        assert first.check(theta0, sigma0, theta0 + 0.2, lambda: np.eye(3) * 1e-8, 1.0)
    assert (first.replacement is not None) == replaced
    message = str(said[0].message)
    assert ("replaced by the unknown-start search's answer" in message) == replaced
    assert ("within 3 sigma" in message) == (not replaced)
    if replaced:
        np.testing.assert_array_equal(first.replacement.theta0, x0)
        assert first.replacement.search is False


def test_the_pause_line_reports_both_estimators_and_their_ratio() -> None:
    from apcc_graph.bench.reliability import PauseRun

    pause = PauseRun(45, 150, np.radians([0.9, 0.2, 0.1]), np.radians([0.45, 0.1, 0.1]), True)
    np.testing.assert_allclose(pause.ratio, [2.0, 2.0, 1.0])
    table = format_reliability([], 450, pause)
    assert "1.5 s of frames dropped before frame 150" in table
    assert "smoother 0.900 / 0.200 / 0.100 deg" in table and "ratio 2.0 / 2.0 / 1.0" in table
    assert "re-acquisition said" in table
    assert "yardsticks" not in table  # none measured
    pause = PauseRun(45, 150, np.radians([0.9, 0.2, 0.1]), np.radians([0.45, 0.1, 0.1]), True,
                     np.radians([0.5, 0.1, 0.1]), np.radians([0.75, 0.2, 0.05]))
    table = format_reliability([], 450, pause)
    assert "the whole recording's bound 0.500 / 0.100 / 0.100" in table, table
    assert "a 1 s lag's 0.750 / 0.200 / 0.050" in table, table
    assert "smoother / lag bound 1.20 / 1.00 / 2.00" in table, table
