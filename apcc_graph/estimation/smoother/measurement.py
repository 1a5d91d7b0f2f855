"""The smoother's measurement models: one interface, two models, one place that chooses.

The smoother (:class:`~apcc_graph.estimation.smoother.core.FixedLagSmoother`) does the same
stages whatever the model; the model says what a frame adds, what a track's rows become and
how an estimate is read back (:class:`WindowModel`):

- the exact model (:class:`~apcc_graph.estimation.smoother.exact.ExactTracks`): every
  observation projected through the model's camera poses, each track's point eliminated;
- model error as noise (:class:`~apcc_graph.estimation.smoother.noisy.NoisyTracks`): tip poses
  tied to the kinematics with the model's noise, the same pieces projected through the tips,
  each track's point eliminated.

:func:`window_model` chooses from ``GraphOptions.model_sigma`` and the robot
(:func:`~apcc_graph.estimation.model_noise.segment_sigmas`; ``None``: exact).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, Protocol

import gtsam
import numpy as np
from numpy.typing import NDArray

from apcc_graph.estimation.initial_guess import FrameRows
from apcc_graph.estimation.model_noise import segment_sigmas
from apcc_graph.estimation.options import GraphOptions
from apcc_graph.estimation.projection_tracks import Rows
from apcc_graph.estimation.smoother.solver import Additions
from apcc_graph.estimation.smoother_options import SmootherOptions
from apcc_graph.estimation.window import Window
from apcc_graph.factors.keys import frame_key
from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.parameterisation import Bending
from apcc_graph.model.robot import Robot

Verdicts = Mapping[int, NDArray[np.int8]]
"""camera -> the rotation gate's verdict on each of a frame's rows."""


class WindowModel(Protocol):
    """What the smoother asks of a measurement model, stage by stage."""

    name: str
    refines: bool  # a new frame's guess is refined against its rows of known points
    final_steps: int  # Gauss-Newton steps of the whole window at the end of the stream
    default_gate: float | None  # the rotation gate's threshold when the settings name none
    elimination: Callable[[int], int] | None  # the window's elimination groups, if any
    trust_region: bool  # iSAM2's steps are dogleg steps in a trust region (else Gauss-Newton)

    @property
    def committed(self) -> int:
        """Observations that entered the graph so far."""

    @property
    def outliers(self) -> int:
        """Observations left out so far."""

    def known(self, cam: int, ids: NDArray[np.int64]) -> NDArray[np.bool_]:
        """Which of a camera's track ids the window knows."""

    def judge(self, frame: int, agreed: Mapping[int, tuple[NDArray[np.int64],
                                                           NDArray[np.bool_]]]) -> None:
        """The next frame agrees with frame ``frame``'s rows of these track ids where
        ``True`` (camera -> (ids, agree)): they are kept whatever their own pair said."""

    def make_room(self, add: Additions, f: int, t: float, rows: Rows, leaving: list[int],
                  first_kept: int, commit: bool) -> None:
        """Before frame ``f`` enters: commit what must be, before ``leaving`` leave."""

    def retire(self, leaving: list[int], first_kept: int) -> None:
        """Frames ``leaving`` left the window."""

    def associate(self, rows: Rows) -> Any:
        """The new frame's rows associated with what the window holds."""

    def known_rows(self, rows: Rows, marks: Any, gates: Mapping[int, FloatArray] | None = None
                   ) -> tuple[list[FrameRows], list[tuple[int, NDArray[np.bool_]]]]:
        """The new frame's rows with known points (for its initial guess), and their masks."""

    def enter(self, add: Additions, f: int, t: float, x: FloatArray,
              base: FloatArray | None) -> None:
        """Frame ``f``'s variables beyond its vector, and its base pose."""

    def observe(self, add: Additions, f: int, t: float, rows: Rows, marks: Any,
                weights: Mapping[int, FloatArray], verdicts: Verdicts,
                accepted: Mapping[int, NDArray[np.int64]]) -> None:
        """Frame ``f``'s rows into the tracks and the graph."""

    def replay(self, add: Additions, h: int, t: float, rows: Rows, verdicts: Verdicts,
               base: FloatArray | None) -> None:
        """A kept frame's rows after a restart."""

    def replaceable(self, graph: gtsam.NonlinearFactorGraph) -> list[int]:
        """Factors to replace at the next update, added to ``graph``; their positions."""

    def read(self, estimate: gtsam.Values) -> None:
        """After an update: what the model keeps of the estimate."""

    def reset(self, keep: int | None = None, base: FloatArray | None = None) -> None:
        """Forget every track (a new window holding frame ``keep``)."""

    def restart_frame(self, add: Additions, f: int, t: float, x: FloatArray,
                      base: FloatArray | None) -> None:
        """A restarted window's frame ``f`` at ``x``: its variables beyond its vector."""

    def finish(self, add: Additions, t: float) -> None:
        """The end of the stream: everything held enters the graph."""

    def base(self, g: int) -> FloatArray | None:
        """Frame ``g``'s base pose, for frames in the window."""

    def camera_rotations(self, g: int) -> dict[int, FloatArray]:
        """Camera -> its ``world_R_cam`` as frame ``g``'s estimate holds it, for a new frame's
        guess from the rotations (:func:`~apcc_graph.estimation.rotation_start.
        rotation_guess`); empty: the two-frame front end guesses instead."""


def window_model(robot: Robot, options: GraphOptions, settings: SmootherOptions,
                 window: Window, bending: Bending, inlier_sigmas: float) -> WindowModel:
    """The measurement model ``options`` names: model error as noise where its
    ``model_sigma`` gives one (by default the robot file's;
    :func:`~apcc_graph.estimation.model_noise.segment_sigmas`), else the exact model."""
    sigmas = segment_sigmas(options.model_sigma, robot)
    if sigmas is None:
        from apcc_graph.estimation.smoother.exact import ExactTracks

        return ExactTracks(robot, options, settings, window, bending, inlier_sigmas)
    from apcc_graph.estimation.smoother.noisy import NoisyTracks

    return NoisyTracks(robot, options, settings, window, bending, inlier_sigmas, sigmas)


def read_estimate(window: Window, model: WindowModel, estimate: gtsam.Values) -> None:
    """The latest estimates of the frames in the window, and the model's."""
    for g in window.stamps:
        key = frame_key(g)
        if estimate.exists(key):
            window.thetas[g] = estimate.atVector(key)
    model.read(estimate)
