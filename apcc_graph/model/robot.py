"""A continuum robot: a chain of APCC segments, each optionally carrying a tip camera.

Segment ``i + 1``'s base frame is segment ``i``'s tip frame (docs/estimation.md, "Conventions").
Segment indices are 0-based in code; files number cameras 1..S (``cam_<i>.csv`` rides on segment
``i``). Poses are ``(..., 4, 4)`` homogeneous arrays named ``a_T_b`` (maps points in b to a).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.model.arrays import FloatArray
from apcc_graph.model.camera import TipCamera
from apcc_graph.model.kinematics import apcc_in_plane, bend_rotation_entries
from apcc_graph.model.segment import Segment

_CHUNK = 4096
"""Frames per block in :meth:`Robot.forward`: one block's working set stays in the L2 cache."""

_WORKERS = min(2, os.cpu_count() or 1)
"""Threads for large :meth:`Robot.forward` calls."""


class Robot:
    """Segments from base to tip, and the camera riding on each segment's tip (or ``None``).

    Args:
        segments: the segments, base first; at least one.
        cameras: one entry per segment, a :class:`TipCamera` or ``None``; default no cameras.

    Raises:
        ValueError: no segments, a non-``Segment`` entry, or a camera list of the wrong length.
    """

    def __init__(
        self, segments: Sequence[Segment], cameras: Sequence[TipCamera | None] | None = None
    ) -> None:
        segments = tuple(segments)
        if not segments:
            raise ValueError("Robot.segments: expected at least one segment")
        for i, seg in enumerate(segments):
            if not isinstance(seg, Segment):
                raise ValueError(
                    f"Robot.segments[{i}]: expected a Segment, got {type(seg).__name__}"
                )
        cams = (None,) * len(segments) if cameras is None else tuple(cameras)
        if len(cams) != len(segments):
            raise ValueError(
                f"Robot.cameras has {len(cams)} entries: expected one per segment "
                f"({len(segments)}), None where a segment has no camera"
            )
        for i, cam in enumerate(cams):
            if cam is not None and not isinstance(cam, TipCamera):
                raise ValueError(
                    f"Robot.cameras[{i}]: expected a TipCamera or None, got {type(cam).__name__}"
                )
        self._segments = segments
        self._cameras = cams

    @property
    def segments(self) -> tuple[Segment, ...]:
        """The segments, base first."""
        return self._segments

    @property
    def cameras(self) -> tuple[TipCamera | None, ...]:
        """One entry per segment: its tip camera or ``None``."""
        return self._cameras

    @property
    def n_segments(self) -> int:
        """Number of segments S."""
        return len(self._segments)

    @property
    def camera_segments(self) -> tuple[int, ...]:
        """0-based indices of the segments that carry a camera."""
        return tuple(i for i, cam in enumerate(self._cameras) if cam is not None)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Robot):
            return NotImplemented
        return self._segments == other._segments and self._cameras == other._cameras

    def __hash__(self) -> int:
        return hash((self._segments, self._cameras))

    def __repr__(self) -> str:
        return f"Robot(segments={list(self._segments)!r}, cameras={list(self._cameras)!r})"

    def _angles(self, name: str, values: ArrayLike) -> FloatArray:
        arr = np.asarray(values, dtype=float)
        if arr.ndim == 0 or arr.shape[-1] != self.n_segments:
            raise ValueError(
                f"{name} has shape {arr.shape}: expected (..., {self.n_segments}), one angle per "
                "segment in radians"
            )
        return arr

    def configuration(self, values: ArrayLike | None, name: str = "theta0") -> FloatArray:
        """``values`` checked as one configuration: ``(S,)`` finite angles in radians within
        each segment's ``[-theta_max, theta_max]``; ``None`` is the straight robot.

        Raises:
            ValueError: the message names ``name``, what is wrong and, for an angle out of
                range, the segment (1-based, as in files) and its limit in degrees (angles in
                degrees given where radians are expected usually land here).
        """
        if values is None:
            return np.zeros(self.n_segments)
        try:
            arr = np.asarray(values, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"{name} = {values!r}: expected {self.n_segments} angles in "
                             "radians") from None
        if arr.shape != (self.n_segments,):
            raise ValueError(f"{name} has shape {arr.shape}: expected ({self.n_segments},), "
                             "one angle per segment in radians")
        for i, (value, seg) in enumerate(zip(arr.tolist(), self._segments, strict=True)):
            if not np.isfinite(value):
                raise ValueError(f"{name}[{i}] = {value!r}: expected a finite angle (radians)")
            if abs(value) > seg.theta_max:
                raise ValueError(
                    f"{name}[{i}] = {value!r} rad ({np.degrees(value):.1f} deg) is beyond "
                    f"segment {i + 1}'s theta_max of {np.degrees(seg.theta_max):.1f} deg "
                    "(angles are in radians)")
        return arr

    def forward(
        self,
        thetas: ArrayLike,
        psis: ArrayLike | None = None,
        world_T_base: ArrayLike | None = None,
    ) -> FloatArray:
        """Every segment's tip pose ``world_T_tip``, vectorised over frames.

        Args:
            thetas: ``(..., S)`` bending angles in radians (e.g. ``(F, S)`` for F frames).
            psis: ``(..., S)`` bending-plane angles in radians, broadcast against ``thetas``;
                ``None`` for a planar robot (all zero).
            world_T_base: the robot base pose, ``(4, 4)`` or ``(..., 4, 4)`` broadcast against the
                frames; ``None`` for the identity.

        Returns:
            ``(..., S, 4, 4)``: entry ``[..., i, :, :]`` is segment i's tip in the world frame.
        """
        thetas = self._angles("thetas", thetas)
        if psis is not None:
            psis = self._angles("psis", psis)
            thetas, psis = np.broadcast_arrays(thetas, psis)
        lead = thetas.shape[:-1]
        base = None
        if world_T_base is not None:
            base = np.asarray(world_T_base, dtype=float)
            if base.ndim < 2 or base.shape[-2:] != (4, 4):
                raise ValueError(f"world_T_base has shape {base.shape}: expected (..., 4, 4)")
            lead = np.broadcast_shapes(lead, base.shape[:-2])
            base = np.broadcast_to(base, lead + (4, 4)).reshape(-1, 4, 4)
        n_seg = self.n_segments
        th = np.broadcast_to(thetas, lead + (n_seg,)).reshape(-1, n_seg)
        ps = None if psis is None else np.broadcast_to(psis, lead + (n_seg,)).reshape(-1, n_seg)
        out = np.empty(lead + (n_seg, 4, 4))
        flat = out.reshape(-1, n_seg, 4, 4)  # a view: ``out`` is contiguous

        def run(start: int) -> None:
            stop = start + _CHUNK
            self._forward_chunk(
                th[start:stop],
                None if ps is None else ps[start:stop],
                None if base is None else base[start:stop],
                flat[start:stop],
            )

        starts = range(0, flat.shape[0], _CHUNK)
        if len(starts) >= 4 and _WORKERS > 1:
            # numpy releases the GIL inside its loops, so chunks run in parallel.
            with ThreadPoolExecutor(max_workers=_WORKERS) as pool:
                list(pool.map(run, starts))
        else:
            for start in starts:
                run(start)
        return out

    def _forward_chunk(
        self,
        thetas: FloatArray,
        psis: FloatArray | None,
        base: FloatArray | None,
        out: FloatArray,
    ) -> None:
        """Compose the chain for a cache-sized block of frames, entry by entry.

        ``rot[r][c]`` and ``pos[r]`` hold the accumulated ``world_T_tip`` as separate contiguous
        arrays (or scalars while they are still the identity), so every step is a few vectorised
        multiply-adds and the output is written once per segment.
        """
        rot: list[list[FloatArray | float]]
        if base is None:
            rot = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
            pos: list[FloatArray | float] = [0.0, 0.0, 0.0]
        else:
            rot = [[base[:, r, c] for c in range(3)] for r in range(3)]
            pos = [base[:, r, 3] for r in range(3)]
        block = np.empty((16, len(thetas)))
        block[12:15] = 0.0
        block[15] = 1.0
        for i, seg in enumerate(self._segments):
            planar = apcc_in_plane(thetas[:, i], seg)
            if psis is None:
                cb, sb = np.cos(planar.beta), np.sin(planar.beta)
                # world_T_tip <- world_T_tip [Ry(beta) | (px, 0, pz)]
                for r in range(3):
                    r0, r2 = rot[r][0], rot[r][2]
                    pos[r] = pos[r] + planar.px * r0 + planar.pz * r2
                    rot[r][0] = cb * r0 - sb * r2
                    rot[r][2] = sb * r0 + cb * r2
            else:
                # world_T_tip <- world_T_tip Rz(psi) [Ry(beta) | (px, 0, pz)] Rz(-psi)
                psi = psis[:, i]
                local = bend_rotation_entries(planar.beta, psi)
                lx, ly = np.cos(psi) * planar.px, np.sin(psi) * planar.px
                for r in range(3):
                    a0, a1, a2 = rot[r]
                    pos[r] = pos[r] + a0 * lx + a1 * ly + a2 * planar.pz
                    rot[r] = [
                        a0 * local[0][c] + a1 * local[1][c] + a2 * local[2][c] for c in range(3)
                    ]
            for r in range(3):
                for c in range(3):
                    block[4 * r + c] = rot[r][c]
                block[4 * r + 3] = pos[r]
            out[:, i] = block.T.reshape(-1, 4, 4)

    def camera_poses(
        self,
        thetas: ArrayLike,
        psis: ArrayLike | None = None,
        world_T_base: ArrayLike | None = None,
    ) -> dict[int, FloatArray]:
        """``world_T_cam = world_T_tip @ tip_T_cam`` for every segment that carries a camera.

        Args:
            thetas, psis, world_T_base: as in :meth:`forward`.

        Returns:
            A dict from 0-based segment index to ``(..., 4, 4)`` camera poses.
        """
        tips = self.forward(thetas, psis, world_T_base)
        return {
            i: tips[..., i, :, :] @ cam.tip_T_cam
            for i, cam in enumerate(self._cameras)
            if cam is not None
        }
