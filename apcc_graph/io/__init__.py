"""File formats: reading and writing what the user gives and gets (``docs/formats.md``).

Holds CSV tables with errors that name file, line and column (:mod:`~apcc_graph.io.csv_table`),
typed TOML fields (:mod:`~apcc_graph.io.toml_fields`), ``robot.toml``
(:mod:`~apcc_graph.io.robot_file`), sequence folders (:mod:`~apcc_graph.io.sequence_folder`),
estimates: ``theta.csv`` and TUM tip trajectories (:mod:`~apcc_graph.io.estimates`), pose
fields (:mod:`~apcc_graph.io.poses`), motion-capture backbone poses ``backbone_poses.csv``
(:mod:`~apcc_graph.io.backbone_poses`) and atomic writes: a temporary file, then a rename
(:mod:`~apcc_graph.io.atomic`).

May import: :mod:`apcc_graph.model`. Nothing here estimates anything.
"""

from apcc_graph.io.backbone_poses import (
    BackbonePoses,
    load_backbone_poses,
    save_backbone_poses,
)
from apcc_graph.io.robot_file import load_robot, save_robot
from apcc_graph.io.sequence_folder import load_sequence, save_sequence

__all__ = [
    "BackbonePoses",
    "load_backbone_poses",
    "load_robot",
    "load_sequence",
    "save_backbone_poses",
    "save_robot",
    "save_sequence",
]
