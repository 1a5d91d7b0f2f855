"""Figures: the paper's Fig. 9, 10 and 11, and the robot drawn as arcs with its APCC links.

Every function returns a :class:`matplotlib.figure.Figure` built without pyplot's global state
(the ``Agg`` canvas), so they work headless, in tests and in notebooks alike; :func:`save_figure`
writes one atomically (temporary file, then rename). Angles are plotted in degrees, lengths in
millimetres or metres as labelled; inputs are in SI units and radians like the rest of the library.

- :func:`angles_figure`: estimated vs true angle per segment over time, with a band of
  ``n_sigma`` marginal standard deviations (Fig. 11).
- :func:`noise_figure`: the 1-point solver's error against pixel noise, fixed and moving base, with
  the Cramer-Rao bound (Fig. 10), from :func:`apcc_graph.bench.accuracy.run_accuracy_benchmark`.
- :func:`tip_trajectories_figure`: true, APCC and PCC tip trajectories of a calibration sweep and
  their errors (Fig. 9), from :func:`apcc_graph.bench.calibration.run_calibration_benchmark`.
- :func:`robot_figure`: each segment as its constant-curvature arc with the two rigid links of
  its APCC 2L-5R equivalent, in the x-z plane of the robot base.

Layer: above :mod:`apcc_graph.bench`, whose results two of the figures draw, and below the
command line. Imports the model and, for type hints only, the benchmarks' result types.
"""

from __future__ import annotations

import math
from collections.abc import Sequence as SequenceOf
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import ArrayLike

from apcc_graph.io.atomic import atomic_file
from apcc_graph.io.output_folder import check_writable
from apcc_graph.model.arrays import rms
from apcc_graph.model.joint_chain import apcc_joint_frames
from apcc_graph.model.kinematics import pcc_in_plane
from apcc_graph.model.robot import Robot

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from apcc_graph.bench.accuracy import AccuracyBenchmark
    from apcc_graph.bench.calibration import CalibrationBenchmark



def _figure(rows: int, cols: int, size: tuple[float, float], **kwargs: object) -> tuple:
    """A pyplot-free figure and its axes array (``squeeze=False``)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=size, layout="constrained")
    axes = fig.subplots(rows, cols, squeeze=False, **kwargs)
    return fig, axes


def check_figure_path(path: str | Path) -> str:
    """The image format of ``path`` (its suffix), checked before any work is done.

    Raises:
        ValueError: a suffix matplotlib cannot write, or a missing folder (named).
        OSError: a folder where no file can be written, or a folder at ``path``.
    """
    from matplotlib.figure import Figure

    path = Path(path)
    fmt = path.suffix.lstrip(".").lower()
    supported = Figure().canvas.get_supported_filetypes()
    if fmt not in supported:
        raise ValueError(f"{path}: cannot write a {fmt or 'suffix-less'} figure; use one of "
                         f"{', '.join(sorted(supported))}")
    if not path.parent.is_dir():
        raise ValueError(f"{path}: the folder {path.parent} does not exist")
    check_writable(path, folder=False)  # before the figure's data are computed
    return fmt


def save_figure(fig: Figure, path: str | Path, dpi: int = 120) -> Path:
    """Write ``fig`` to ``path`` (format from the suffix: png, pdf, svg, ...), atomically.

    Raises:
        ValueError: a suffix matplotlib cannot write, or a missing folder (named).
    """
    path = Path(path)
    fmt = check_figure_path(path)
    with atomic_file(path) as handle:  # the umask's permissions, whole or not at all
        fig.savefig(handle, format=fmt, dpi=dpi)
    return path


# ---------------------------------------------------------------------------------- Fig. 11
def angles_figure(timestamps: ArrayLike, thetas: ArrayLike, sigmas: ArrayLike | None = None,
                  truth: ArrayLike | None = None, n_sigma: float = 2.0,
                  label: str = "estimate", title: str | None = None) -> Figure:
    """Estimated angle of every segment against time, with truth and uncertainty (Fig. 11).

    Args:
        timestamps: ``(F,)`` seconds.
        thetas: ``(F, S)`` estimated angles (radians), e.g. ``Estimate.thetas``.
        sigmas: ``(F, S)`` marginal standard deviations (radians; NaN where unknown), or None.
        truth: ``(F, S)`` true angles (radians), or None; with truth a second column shows the
            error.
        n_sigma: half-width of the band in standard deviations.
        label: legend name of the estimate (e.g. the method).
        title: figure title (default: the label and, with truth, the RMS per segment).

    Raises:
        ValueError: arrays whose shapes disagree (named).
    """
    t = np.asarray(timestamps, dtype=float).reshape(-1)
    est = np.degrees(np.asarray(thetas, dtype=float))
    if est.ndim != 2 or est.shape[0] != t.shape[0]:
        raise ValueError(f"thetas has shape {est.shape}: expected ({t.shape[0]}, S), one row "
                         "per timestamp")
    n_seg = est.shape[1]
    sig = (np.full(est.shape, np.nan) if sigmas is None
           else np.degrees(np.asarray(sigmas, dtype=float)))
    true = None if truth is None else np.degrees(np.asarray(truth, dtype=float))
    for name, arr in (("sigmas", sig), ("truth", true)):
        if arr is not None and arr.shape != est.shape:
            raise ValueError(f"{name} has shape {arr.shape}, thetas {est.shape}")
    fig, axes = _figure(n_seg, 2 if true is not None else 1,
                        (10.0 if true is not None else 6.5, 2.2 * n_seg + 0.6), sharex=True)
    for i in range(n_seg):
        ax = axes[i, 0]
        band = np.isfinite(sig[:, i])
        if band.any():
            ax.fill_between(t, est[:, i] - n_sigma * sig[:, i], est[:, i] + n_sigma * sig[:, i],
                            where=band, color="C0", alpha=0.25, linewidth=0,
                            label=f"+/- {n_sigma:g} sigma")
        if true is not None:
            ax.plot(t, true[:, i], color="k", linewidth=1.2, label="ground truth")
        ax.plot(t, est[:, i], color="C0", linewidth=1.0, label=label)
        ax.set_ylabel(f"theta_{i + 1} (deg)")
        ax.grid(alpha=0.3)
        if true is not None:
            ex = axes[i, 1]
            if band.any():
                ex.fill_between(t, -n_sigma * sig[:, i], n_sigma * sig[:, i], where=band,
                                color="C0", alpha=0.25, linewidth=0)
            ex.plot(t, est[:, i] - true[:, i], color="C3", linewidth=1.0)
            ex.axhline(0.0, color="k", linewidth=0.6)
            ex.set_ylabel(f"error_{i + 1} (deg)")
            ex.grid(alpha=0.3)
    axes[0, 0].legend(loc="best", fontsize="small")
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    if title is None:
        title = f"bending angles, {label}"
        if true is not None:
            errors = rms(est - true, skip_nan=True)
            title += " (RMS " + " / ".join(f"{r:.2f}" for r in errors) + " deg)"
    fig.suptitle(title)
    return fig


# ---------------------------------------------------------------------------------- Fig. 10
def noise_figure(bench: AccuracyBenchmark) -> Figure:
    """Median and mean angle error of the 1-point solver against pixel noise (Fig. 10).

    One curve per base case (fixed, moving), with the Cramer-Rao bound on the median.
    """
    fig, axes = _figure(1, 1, (6.5, 4.2))
    ax = axes[0, 0]
    bases = sorted({row.base for row in bench.rows})
    for n, base in enumerate(bases):
        rows = sorted((r for r in bench.rows if r.base == base), key=lambda r: r.noise_px)
        noise = np.array([r.noise_px for r in rows])
        colour = f"C{n}"
        ax.plot(noise, np.degrees([r.median_error for r in rows]), "o-", color=colour,
                label=f"{base} base, median")
        ax.plot(noise, np.degrees([r.mean_error for r in rows]), "s:", color=colour,
                alpha=0.7, label=f"{base} base, mean")
        ax.plot(noise, np.degrees([r.median_bound for r in rows]), "--", color=colour,
                alpha=0.6, label=f"{base} base, Cramer-Rao (median)")
    ax.set_xlabel("pixel noise, standard deviation (px)")
    ax.set_ylabel("|theta error| (deg)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize="small")
    trials = bench.rows[0].trials if bench.rows else 0
    fig.suptitle(f"1-point solver vs pixel noise ({trials} trials per point, "
                 f"{bench.points} correspondences)")
    return fig


# ----------------------------------------------------------------------------------- Fig. 9
def tip_trajectories_figure(bench: CalibrationBenchmark) -> Figure:
    """True tip trajectory of a calibration sweep against the calibrated APCC and the best PCC
    fit, and each model's tip error along the sweep (Fig. 9)."""
    fig, axes = _figure(1, 2, (11.0, 4.4))
    traj, err = axes[0]
    truth = bench.truth_tips * 1e3
    traj.plot(truth[:, 0], truth[:, 1], "k.", markersize=5, label="true tip")
    bends = np.degrees(bench.thetas)
    for n, (name, tips) in enumerate(bench.model_tips.items()):
        mm = tips * 1e3
        traj.plot(mm[:, 0], mm[:, 1], "-", color=f"C{n}", linewidth=1.2, label=name)
        error = np.linalg.norm(mm - truth, axis=1)
        err.plot(bends, error, "-", color=f"C{n}",
                 label=f"{name}: std {np.std(error):.3f} mm")
    traj.set_aspect("equal", adjustable="datalim")
    traj.set_xlabel("x (mm)")
    traj.set_ylabel("z (mm)")
    traj.grid(alpha=0.3)
    traj.legend(fontsize="small")
    err.set_xlabel("bend theta (deg)")
    err.set_ylabel("tip position error (mm)")
    err.grid(alpha=0.3)
    err.legend(fontsize="small")
    fig.suptitle(f"tip trajectories, L = {bench.length:g} m, curvature growth "
                 f"{bench.growth:g}")
    return fig


# ------------------------------------------------------------------------------------ robot
def draw_robot(ax: Axes, robot: Robot, thetas: ArrayLike, world_T_base: ArrayLike | None = None,
               arc_points: int = 30, label: bool = True) -> None:
    """Draw the robot in the x-z plane of ``ax``: each segment's constant-curvature arc (solid)
    and the two links of its APCC equivalent (dashed, joints as dots), tips as triangles.

    Args:
        ax: matplotlib axes.
        robot: the robot.
        thetas: ``(S,)`` bending angles (radians). Bending-plane angles are taken as 0.
        world_T_base: ``(4, 4)`` base pose (default identity).
        arc_points: points per arc.
        label: add legend labels (once per kind).
    """
    thetas = np.asarray(thetas, dtype=float).reshape(-1)
    if thetas.shape != (robot.n_segments,):
        raise ValueError(f"thetas has {thetas.size} angles, the robot {robot.n_segments} "
                         "segments")
    pose = np.eye(4) if world_T_base is None else np.asarray(world_T_base, dtype=float)
    tips = robot.forward(thetas, world_T_base=pose)
    u = np.linspace(0.0, 1.0, arc_points)
    for i, seg in enumerate(robot.segments):
        # The point at arc length u L is the tip of a PCC piece of length u L bent by u theta.
        x, z = pcc_in_plane(thetas[i] * u, 1.0)
        scale = u * seg.length
        arc = np.column_stack([x * scale, np.zeros_like(x), z * scale, np.ones_like(x)])
        world = arc @ pose.T
        ax.plot(world[:, 0], world[:, 2], "-", color=f"C{i}", linewidth=3.0, alpha=0.55,
                label=f"segment {i + 1} (arc)" if label else None)
        joints = apcc_joint_frames(thetas[i], seg).points  # (3, 3): base, middle joint, tip
        links = np.column_stack([joints, np.ones(3)]) @ pose.T
        ax.plot(links[:, 0], links[:, 2], "--o", color="k", linewidth=1.0, markersize=3,
                label="APCC links" if label and i == 0 else None)
        pose = tips[i]
        ax.plot(pose[0, 3], pose[2, 3], "^", color=f"C{i}", markersize=7)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.grid(alpha=0.3)


def robot_figure(robot: Robot, configurations: SequenceOf[ArrayLike],
                 titles: SequenceOf[str] | None = None) -> Figure:
    """The robot in each of ``configurations`` (``(S,)`` angles, radians), side by side."""
    configs = [np.asarray(c, dtype=float) for c in configurations]
    if not configs:
        raise ValueError("configurations: expected at least one")
    fig, axes = _figure(1, len(configs), (3.4 * len(configs) + 0.6, 4.2))
    for n, (ax, thetas) in enumerate(zip(axes[0], configs, strict=True)):
        draw_robot(ax, robot, thetas, label=n == 0)
        ax.set_title(titles[n] if titles is not None else
                     "theta = " + ", ".join(f"{math.degrees(v):.0f}" for v in thetas) + " deg")
    axes[0, 0].legend(fontsize="small", loc="lower left")
    return fig
