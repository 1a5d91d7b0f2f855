"""apcc_graph: a continuum robot's shape from the cameras at its segment tips.

APCC 2L-5R kinematics (two rigid links and five revolute joints per segment), deviation
calibration, a 1-point generalized-epipolar front end and a GTSAM factor-graph back end.

Public names are re-exported lazily (module-level ``__getattr__``) so that importing a submodule,
or the ``factors`` package, never pulls in the estimators.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_EXPORTS = {
    "Segment": "apcc_graph.segment",
    "TipCamera": "apcc_graph.camera",
    "Robot": "apcc_graph.robot",
    "load_robot": "apcc_graph.robot",
    "save_robot": "apcc_graph.robot",
    "pcc_transform": "apcc_graph.kinematics",
    "apcc_transform": "apcc_graph.kinematics",
    "calibrate_from_tip": "apcc_graph.calibration",
    "fit_segment": "apcc_graph.calibration",
    "estimate": "apcc_graph.api",
    "Estimate": "apcc_graph.estimation.result",
    "FixedLagSmoother": "apcc_graph.estimation.smoother",
    "ProjectionFixedLagSmoother": "apcc_graph.estimation.projection_smoother",
    "GraphOptions": "apcc_graph.estimation.options",
    "FrameObservations": "apcc_graph.sequence",
    "Sequence": "apcc_graph.sequence",
    "load_sequence": "apcc_graph.io",
    "save_sequence": "apcc_graph.io",
}

__all__ = sorted(_EXPORTS) + ["__version__"]


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'apcc_graph' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
