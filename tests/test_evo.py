"""Estimates' tip trajectories are read by evo (``evo_traj tum ...``) as the poses we wrote."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from apcc_graph import estimate
from apcc_graph.io.estimates import save_estimate
from apcc_graph.io.sequence_folder import load_sequence

file_interface = pytest.importorskip("evo.tools.file_interface")

SAMPLE = Path(__file__).resolve().parents[1] / "data" / "sequences" / "planar_three"


def test_evo_reads_the_tip_trajectories(tmp_path: Path) -> None:
    seq = load_sequence(SAMPLE)
    est = estimate(seq, method="chain", theta0=seq.thetas[0])
    written = save_estimate(est, tmp_path)
    tums = sorted(p for p in written if p.suffix == ".tum")
    assert [p.name for p in tums] == ["tips_seg_1.tum", "tips_seg_2.tum", "tips_seg_3.tum"]
    tips = seq.robot.forward(est.thetas)  # (F, S, 4, 4): what the files should hold
    for i, path in enumerate(tums):
        traj = file_interface.read_tum_trajectory_file(str(path))
        assert traj.num_poses == seq.n_frames
        np.testing.assert_allclose(traj.timestamps, seq.timestamps, atol=1e-9)
        np.testing.assert_allclose(traj.positions_xyz, tips[:, i, :3, 3], atol=1e-6)
        # evo's poses (wxyz internally) are the same rotations as our tip frames.
        np.testing.assert_allclose(np.array(traj.poses_se3)[:, :3, :3], tips[:, i, :3, :3],
                                   atol=1e-6)
