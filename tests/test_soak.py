"""A shortened soak: the default smoother over a stream generated on the fly keeps bounded
state. (``apcc-graph bench soak`` runs 100,000 frames and measures memory and update time;
here nothing is timed: the test checks what must not grow.)"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from apcc_graph.cli import main
from apcc_graph.estimation.smoother import FixedLagSmoother
from apcc_graph.estimation.smoother_options import SmootherOptions, WindowOptions
from apcc_graph.io import load_robot
from apcc_graph.simulation.stream import SimulatedStream

ROBOT = Path(__file__).resolve().parents[1] / "data" / "robots" / "planar_three.toml"
FRAMES = 360


def _state(sm: FixedLagSmoother) -> dict[str, int]:
    """Sizes of everything a long stream could make grow."""
    w = sm._window
    graph = sm._smoother.getFactors()
    return {"gtsam factor slots": graph.size(), "gtsam factors": graph.nrFactors(),
            "frames in the window": len(w.stamps), "unreturned finals": len(w.final),
            "landmark points": len(sm._model.landmarks.points),  # type: ignore[attr-defined]
            "track bases": len(sm._model.tracks.bases)}  # type: ignore[attr-defined]


def test_a_long_stream_keeps_bounded_state() -> None:
    robot = load_robot(ROBOT)
    stream = SimulatedStream(robot, noise_px=1.0, outlier_fraction=0.1, seed=5, n_points=3000)
    sm = FixedLagSmoother(robot, lag=1.0, theta0=stream.thetas(0),
                          settings=SmootherOptions(window=WindowOptions(uncertainty=False)))
    truth: dict[int, np.ndarray] = {}
    returned, errors, sizes = [], [], {}
    for f in range(FRAMES):
        obs, truth[f] = stream.next_frame()
        sm.update(obs)
        for done in sm.pop_final():
            returned.append(done.frame)
            errors.append(done.thetas - truth.pop(done.frame))
        if f + 1 in (FRAMES // 2, FRAMES):
            sizes[f + 1] = _state(sm)
    for size in sizes.values():
        # iSAM2 used to keep a slot for every factor ever removed (45 a frame: 16,000 slots
        # by now); reused, the slots stay at the most factors the window ever held at once
        assert size["gtsam factor slots"] <= 3 * size["gtsam factors"], size
        assert size["frames in the window"] <= 32 and size["track bases"] <= 32, size
        assert size["landmark points"] <= 3 * sm.settings.landmarks.max_per_camera, size
        assert size["unreturned finals"] == 0
    assert returned == list(range(len(returned))) and len(returned) >= FRAMES - 35
    assert len(truth) <= 35  # only frames still in the window wait for their estimate
    rms = np.degrees(np.sqrt(np.mean(np.square(errors[-200:]), axis=0)))
    assert np.all(rms < 0.3), rms
    assert sm.recoveries == 0


@pytest.mark.parametrize("argv", [["bench", "soak", "--frames", "1999"],
                                  ["bench", "reliability", "--frames", "239"]])
def test_the_benches_refuse_runs_too_short_for_their_targets(argv: list[str], capsys) -> None:
    with pytest.raises(SystemExit) as stop:
        main(argv)
    assert stop.value.code != 0
    assert "expected an integer >=" in capsys.readouterr().err
