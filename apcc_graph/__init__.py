"""apcc_graph: a continuum robot's shape from the cameras at its segment tips.

APCC 2L-5R kinematics (two rigid links and five revolute joints per segment), deviation
calibration, a 1-point generalized-epipolar front end and a GTSAM factor-graph back end.

The package is a stack of layers, each a subpackage that imports only the ones before it:
``model`` (the robot's maths), ``io`` (file formats), ``frontend`` (two-view geometry, the
1-point solver, tracking), ``calibration``, ``simulation``, then ``factors`` (GTSAM factors),
``estimation`` (chain, batch, smoother), ``evaluation`` (accuracy and the Cramér-Rao bounds),
``bench``, ``plots`` and ``cli``. ``tests/test_layers.py`` checks it.

Public names are re-exported lazily (module-level ``__getattr__``) so that importing a submodule,
or ``apcc_graph.factors``, never pulls in the estimators.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_EXPORTS = {
    "Segment": "apcc_graph.model.segment",
    "TipCamera": "apcc_graph.model.camera",
    "Robot": "apcc_graph.model.robot",
    "load_robot": "apcc_graph.io.robot_file",
    "save_robot": "apcc_graph.io.robot_file",
    "pcc_transform": "apcc_graph.model.kinematics",
    "apcc_transform": "apcc_graph.model.kinematics",
    "calibrate_from_tip": "apcc_graph.calibration.closed_form",
    "fit_segment": "apcc_graph.calibration.fit",
    "estimate": "apcc_graph.estimation.methods",
    "Estimate": "apcc_graph.estimation.result",
    "find_start": "apcc_graph.estimation.start_search",
    "check_model_fit": "apcc_graph.estimation.model_fit",
    "ModelFitWarning": "apcc_graph.estimation.model_fit",
    "UnknownStartError": "apcc_graph.estimation.start_search",
    "FixedLagSmoother": "apcc_graph.estimation.smoother",
    "GraphOptions": "apcc_graph.estimation.options",
    "Robustness": "apcc_graph.estimation.options",
    "ChainOptions": "apcc_graph.estimation.options",
    "BatchOptions": "apcc_graph.estimation.options",
    "SmootherOptions": "apcc_graph.estimation.smoother_options",
    "WindowOptions": "apcc_graph.estimation.smoother_options",
    "TrackOptions": "apcc_graph.estimation.smoother_options",
    "LandmarkOptions": "apcc_graph.estimation.smoother_options",
    "FaultOptions": "apcc_graph.estimation.smoother_options",
    "FrameObservations": "apcc_graph.model.sequence",
    "Sequence": "apcc_graph.model.sequence",
    "load_sequence": "apcc_graph.io.sequence_folder",
    "save_sequence": "apcc_graph.io.sequence_folder",
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
