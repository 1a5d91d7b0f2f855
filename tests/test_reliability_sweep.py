"""``apcc-graph bench reliability``'s sweep: its cases, each row's target on each seed, and its
tables, on short recordings and made-up errors (no estimator runs here: the smoother under
each fault is tested in tests/test_faults.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from apcc_graph.bench import reliability as rel
from apcc_graph.bench import reliability_sweep
from apcc_graph.bench.reliability import (
    KEPT,
    NEVER,
    PAUSED,
    SETTLE,
    CaseRun,
    FaultCase,
    fault_cases,
)
from apcc_graph.bench.reliability_sweep import SeedRow, Sweep, format_sweep, seed_row, selected
from apcc_graph.cli import main

FRAMES = 240  # the shortest the command takes: the faults from frame 80
S = 3


@pytest.fixture(scope="module")
def cases() -> dict[str, FaultCase]:
    return {c.name: c for c in fault_cases(FRAMES, seed=3)}


def _run(case: FaultCase, errors: np.ndarray, **kwargs: object) -> CaseRun:
    return CaseRun(7, case.name, errors, np.full_like(errors, 0.01), "-", **kwargs)


def test_every_fault_that_hides_the_tracks_comes_with_the_ids_kept(
        cases: dict[str, FaultCase]) -> None:
    hiding = [name for name, c in cases.items() if c.hides]
    assert sorted(hiding) == sorted(
        [f"{base}{kept}" for base in ("camera 2 blind for 1 s", "camera 3 blind for 3 s",
                                      "all cameras blind for 1 s", PAUSED)
         for kept in ("", KEPT)])
    for name in hiding:
        if name.endswith(KEPT):
            continue
        lost, kept = cases[name].simulation.sequence, cases[name + KEPT].simulation.sequence
        assert lost.n_frames == kept.n_frames
        stop = cases[name].stop
        hidden = [cam for cam in kept.tracks if not kept.tracks[cam].equals(lost.tracks[cam])]
        assert hidden == ([1] if "camera 2" in name else [2] if "camera 3" in name
                          else [0, 1, 2]), name
        for cam in hidden:
            before = set(kept.tracks[cam].track_ids[kept.tracks[cam].frames < stop].tolist())
            for seq, shared in ((kept, True), (lost, False)):
                t = seq.tracks[cam]
                after = set(t.track_ids[t.frames >= stop].tolist())
                assert bool(after & before) == shared, (name, cam)


def test_the_pause_is_compared_with_the_undisturbed_frames_of_the_same_instants(
        cases: dict[str, FaultCase]) -> None:
    clean = cases["none"].simulation.sequence
    for name in (PAUSED, PAUSED + KEPT):
        case = cases[name]
        seq = case.simulation.sequence
        assert case.clean_frames is not None and case.start == case.stop == FRAMES // 3
        assert seq.n_frames == FRAMES - rel.PAUSE == len(case.clean_frames)
        np.testing.assert_array_equal(seq.thetas, clean.thetas[case.clean_frames])
        np.testing.assert_array_equal(seq.timestamps, clean.timestamps[case.clean_frames])


def _errors(n: int, deg: float) -> np.ndarray:
    return np.full((n, S), math.radians(deg))


def test_a_fault_that_hides_the_tracks_against_its_target(cases: dict[str, FaultCase]) -> None:
    case = cases["camera 3 blind for 3 s"]
    n, later = case.simulation.sequence.n_frames, case.stop + SETTLE
    undisturbed = _errors(n, 0.1)
    errors = _errors(n, 0.15)
    errors[case.start:later] = math.radians(3.0)  # off until 2 s after the return: not counted
    row = seed_row(case, _run(case, errors), undisturbed)
    assert row.target == "return" and row.passed
    np.testing.assert_allclose(row.after, math.radians(0.15))
    np.testing.assert_allclose(row.allowed, math.radians(0.2))
    assert row.measure == pytest.approx(0.75) and row.back_max == pytest.approx(math.radians(3))
    # 2.5x the undisturbed error fails, unless the bound of a 1 s lag there allows it
    errors[later:] = math.radians(0.25)
    assert not seed_row(case, _run(case, errors), undisturbed).passed
    lagged = seed_row(case, _run(case, errors, lag_return=np.radians([0.3, 0.3, 0.3])),
                      undisturbed)
    assert lagged.passed and lagged.measure == pytest.approx(0.25 / 0.3)
    # one frame more than 5 deg off once the tracks are back fails, however good the rest
    errors[later:] = math.radians(0.1)
    errors[case.stop + 3, 2] = math.radians(-5.5)
    row = seed_row(case, _run(case, errors), undisturbed)
    assert row.measure < 1.0 and not row.passed


def test_the_pause_is_held_to_the_undisturbed_error_after_it(cases: dict[str, FaultCase]
                                                              ) -> None:
    case = cases[PAUSED]
    n = case.simulation.sequence.n_frames
    undisturbed = _errors(FRAMES, 0.1)
    undisturbed[case.stop:case.stop + rel.PAUSE] = 1.0  # frames the pause dropped: unused
    row = seed_row(case, _run(case, _errors(n, 0.19)), undisturbed)
    assert row.passed and row.measure == pytest.approx(0.95)


def test_a_camera_that_never_sees_is_held_to_the_batch(cases: dict[str, FaultCase]) -> None:
    case = cases[NEVER]
    errors = np.tile(np.radians([5.0, 0.3, 0.1]), (FRAMES, 1))
    row = seed_row(case, _run(case, errors, batch=np.radians([0.1, 0.2, 0.1])),
                   _errors(FRAMES, 0.1))
    assert row.target == "batch" and row.measure == pytest.approx(1.5) and row.passed
    worse = seed_row(case, _run(case, errors, batch=np.radians([0.1, 0.1, 0.1])),
                     _errors(FRAMES, 0.1))
    assert worse.measure == pytest.approx(3.0) and not worse.passed


def test_other_faults_are_held_to_the_recovery(cases: dict[str, FaultCase]) -> None:
    case = cases["camera 2: 50% outliers for 1 s"]
    errors = _errors(FRAMES, 0.1)
    errors[case.stop:case.stop + 40, 1] = math.radians(1.0)  # back 40 frames after the end
    row = seed_row(case, _run(case, errors), _errors(FRAMES, 0.1))
    assert row.target == "recovery" and row.recovery is not None
    assert 31 <= row.recovery <= 40 and not row.passed
    assert seed_row(case, _run(case, _errors(FRAMES, 0.1)), _errors(FRAMES, 0.1)).passed
    assert seed_row(cases["none"], _run(cases["none"], _errors(FRAMES, 0.1)),
                    _errors(FRAMES, 0.1)).passed is None


def test_the_rows_asked_for_always_with_the_undisturbed_run() -> None:
    names = ["none", "camera 2 blind for 1 s", "camera 2 blind for 1 s" + KEPT, PAUSED, NEVER]
    assert selected(names, None) == [0, 1, 2, 3, 4]
    assert selected(names, ["BLIND"]) == [0, 1, 2]
    assert selected(names, ["paused", "never"]) == [0, 3, 4]


def test_the_sweep_table() -> None:
    deg = np.radians
    rows = {
        "none": [SeedRow(1, deg([0.04, 0.09, 0.07])), SeedRow(2, deg([0.05, 0.08, 0.06])),
                 SeedRow(3, deg([0.03, 0.10, 0.08]))],
        "camera 2 blind for 1 s": [
            SeedRow(s, deg(r), after=deg([0.1, a, 0.1]), allowed=deg([0.2, 0.2, 0.2]),
                    back_max=deg(b), target="return")
            for s, r, a, b in ((1, [0.04, 0.2, 0.1], 0.1, 1.0), (2, [0.05, 0.9, 0.1], 0.5, 6.0),
                               (3, [0.04, 0.3, 0.1], 0.19, 2.0))],
        NEVER: [SeedRow(s, deg([0.04, v, 0.1]), batch=deg([0.04, 0.2, 0.1]), target="batch")
                for s, v in ((1, 0.3), (2, 0.2), (3, 0.35))],
    }
    table = format_sweep(Sweep(rows, [], 300, (1, 2, 3), "points"))
    assert "the exact model), scene points, 300 frames, seeds 1,2,3; faults from frame 100" in (
        table)
    lines = {line.split("  ")[0]: line for line in table.splitlines()}
    first = [line for line in table.splitlines() if line.startswith("camera 2 blind")]
    per_seed, summary = first
    assert "0.040  0.200  0.100" in per_seed and "0.050  0.900  0.100" in per_seed
    # median per segment, the worst seed (2: 3x the median on segment 2), each seed's figure
    assert "0.040  0.300  0.100" in summary and "2:  0.050  0.900  0.100" in summary
    assert "0.50 (1.0)" in summary and "2.50 (6.0)" in summary and "0.95 (2.0)" in summary
    assert summary.rstrip().endswith("FAIL 1/3")
    never = [line for line in table.splitlines() if line.startswith(NEVER)][1]
    assert "1.50" in never and "1.00" in never and "1.75" in never
    assert never.rstrip().endswith("pass")
    assert lines["none"].rstrip().endswith("-")
    assert "seed 1 in full" in table
    with_noise = format_sweep(Sweep(rows, [], 300, (1, 2, 3), model_sigma=(1e-3,
                                                                           math.radians(0.5))))
    assert "model error as noise (1 mm, 0.5 deg)" in with_noise


def test_the_command_line_options(monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    asked: dict[str, object] = {}

    def fake_run(frames: int, seeds: list[int], scene: str, model_sigma: object,
                 only: object, workers: int, progress: bool) -> Sweep:
        asked.update(frames=frames, seeds=seeds, scene=scene, model_sigma=model_sigma,
                     only=only, workers=workers)
        return Sweep({"none": [SeedRow(s, np.radians([0.1, 0.1, 0.1])) for s in seeds]}, [],
                     frames, tuple(seeds), scene, model_sigma)

    monkeypatch.setattr(reliability_sweep, "run_sweep", fake_run)
    main(["bench", "reliability"])
    assert asked == {"frames": 450, "seeds": list(rel.SEEDS), "scene": "room",
                     "model_sigma": None, "only": None, "workers": 1}
    main(["bench", "reliability", "--seeds", "11,12,13", "--scene", "points", "--frames",
          "240", "--model-sigma", "1,0.5", "--only", "blind, paused", "--workers", "2"])
    assert asked["seeds"] == [11, 12, 13] and asked["scene"] == "points"
    assert asked["model_sigma"] == pytest.approx((1e-3, math.radians(0.5)))
    assert asked["only"] == ["blind", "paused"] and asked["workers"] == 2
    assert "seeds 11,12,13" in capsys.readouterr().out
    with pytest.raises(SystemExit):
        main(["bench", "reliability", "--frames", "239"])
