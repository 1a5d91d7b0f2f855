"""Backbone poses of a robot that obeys its calibrated model exactly: the yardstick against which
a model error is measured (``docs/estimation.md``, "Model error from the calibration").

:func:`model_exact_poses` replaces every measured segment-end marker by where the calibrated model
puts it, at the bends the calibration fitted to that sample and with the calibrated marker
offsets, chained from the measured base marker, then adds white marker noise. Calibrating these
poses should find no model error (the markers' noise is white), and a replay of them is the
model-exact version of a real motion.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from apcc_graph.calibration.backbone_fit import BackboneCalibration
from apcc_graph.calibration.backbone_model import rigid_inverse, segment_transform
from apcc_graph.io.backbone_poses import BackbonePoses, segment_markers
from apcc_graph.model.robot import Robot

MARKER_NOISE = (1e-4, np.radians(0.05))
"""The white noise added to each marker (position m, rotation rad, per component): the white
part the calibration of a real recording measured is 0.02-0.1 mm and 0.01-0.1 deg."""


def model_exact_poses(poses: BackbonePoses, calibration: BackboneCalibration, robot: Robot,
                      noise: tuple[float, float] = MARKER_NOISE, seed: int = 0
                      ) -> BackbonePoses:
    """``poses`` with each calibrated sample's segment-end markers where ``calibration``'s
    model puts them (module docstring); the samples it did not fit and the held-out markers
    are left out (not present)."""
    base, ends, _ = segment_markers(poses, [seg.length for seg in robot.segments])
    times = calibration.sample_times
    rows = np.flatnonzero(np.isin(poses.timestamps, times))
    offsets = calibration.backbone_T_marker
    world = np.full_like(poses.world_T_marker, np.nan)
    present = np.zeros_like(poses.present)
    chain = poses.world_T_marker[rows, base]
    world[rows, base], present[rows, base] = chain, True
    for i, seg in enumerate(calibration.segments):
        body = segment_transform(calibration.apcc[i].bends, seg, seg.length)
        chain = chain @ rigid_inverse(offsets[i]) @ body @ offsets[i + 1]
        world[rows, ends[i]], present[rows, ends[i]] = chain, True
    rng = np.random.default_rng(seed)
    marked = np.argwhere(present)
    turn = Rotation.from_rotvec(rng.normal(0.0, noise[1], (len(marked), 3))).as_matrix()
    jitter = np.tile(np.eye(4), (len(marked), 1, 1))
    jitter[:, :3, :3] = turn
    jitter[:, :3, 3] = rng.normal(0.0, noise[0], (len(marked), 3))
    world[marked[:, 0], marked[:, 1]] = world[marked[:, 0], marked[:, 1]] @ jitter
    return BackbonePoses(poses.timestamps.copy(), poses.arclengths.copy(), world, present,
                         f"{poses.source} (the calibrated model's own motion)")
