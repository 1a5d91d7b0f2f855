"""A restarted smoother window takes trust-region steps (smoother/solver.py): a Gauss-Newton
step that the cost does not confirm is not taken, where an undisturbed window's iSAM2 takes it
whole."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest

from apcc_graph.estimation.smoother.solver import Additions, Solver, damped, new_window
from apcc_graph.factors.keys import frame_key

KEY = frame_key(0)
TARGET = math.log(1000.0)


def _exp_factor() -> gtsam.CustomFactor:
    """``r = exp(x) - 1000``: from 0 its Gauss-Newton step is 999 (the root is 6.9)."""

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H: list | None) -> np.ndarray:
        x = float(values.atVector(KEY)[0])
        if H is not None:
            H[0] = np.array([[math.exp(x)]])
        return np.array([math.exp(x) - 1000.0])

    return gtsam.CustomFactor(gtsam.noiseModel.Unit.Create(1), [KEY], error)


def _additions() -> Additions:
    add = Additions()
    add.graph.add(_exp_factor())
    add.variable(KEY, np.zeros(1), 0.0)
    return add


def test_a_restarted_window_takes_steps_its_cost_confirms() -> None:
    """iSAM2's Gauss-Newton step from 0 goes to 999; the restarted window's step stays
    downhill, short of the root, and its steps reach the root."""
    make = lambda: new_window(1.0, 1e-3)  # noqa: E731
    plain = Solver(make)
    assert plain.update(_additions())
    assert float(plain.estimate().atVector(KEY)[0]) > 900.0
    restarted = Solver(make)
    assert restarted.restart(_additions())
    assert 0.0 < float(restarted.estimate().atVector(KEY)[0]) <= TARGET + 1e-9
    assert restarted.relinearise(30)
    assert float(restarted.estimate().atVector(KEY)[0]) == pytest.approx(TARGET, abs=1e-6)


@pytest.mark.parametrize("reproducible", [True, False])
def test_damped_windows_of_either_kind_keep_their_settings(reproducible: bool) -> None:
    window = damped(new_window(2.0, 1e-3, "QR", reproducible=reproducible), 0.3)
    isam = window.isam if reproducible else window.inner.getISAM2()
    assert isam.params().getFactorization() == "QR"
    add = _additions()
    window.update(add.graph, add.values, add.stamps)
    assert 0.0 < float(window.calculateEstimate().atVector(KEY)[0]) <= TARGET + 1e-9
