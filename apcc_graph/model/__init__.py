"""The robot model: the maths of a continuum robot, with no files and no estimation.

Holds a segment and its APCC 2L-5R parameters (:mod:`~apcc_graph.model.segment`), the
vectorised segment transforms and their derivatives (:mod:`~apcc_graph.model.kinematics`), a
spatial segment's bend as one vector, smooth through straight
(:mod:`~apcc_graph.model.bending`), the one parameterisation every estimator solves for, angles
in fixed bending planes or bending vectors (:mod:`~apcc_graph.model.parameterisation`), the
transform for one scalar angle, the factors' fast path
(:mod:`~apcc_graph.model.scalar_kinematics`), the chain built joint by joint, for drawing
(:mod:`~apcc_graph.model.joint_chain`), a tip camera (:mod:`~apcc_graph.model.camera`), the
robot as a chain of segments with optional tip cameras (:mod:`~apcc_graph.model.robot`), the
in-memory recording every layer above reads: tracks per camera, timestamps, base poses and
ground truth (:mod:`~apcc_graph.model.sequence`; it lives here rather than in ``io`` because the
simulator, the front end and the estimators all build or read it without touching a file) and
the shared array aliases (:mod:`~apcc_graph.model.arrays`).

May import: numpy, scipy and nothing else of apcc_graph. Loading and saving live in
:mod:`apcc_graph.io`. Conventions are in ``docs/estimation.md`` ("Conventions").
"""

from apcc_graph.model.camera import TipCamera
from apcc_graph.model.robot import Robot
from apcc_graph.model.segment import Segment
from apcc_graph.model.sequence import Sequence

__all__ = ["Robot", "Segment", "Sequence", "TipCamera"]
