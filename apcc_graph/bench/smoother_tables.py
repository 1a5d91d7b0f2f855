"""The tables ``apcc-graph bench smoother`` prints (:func:`format_smoother_benchmark`) from a
:class:`~apcc_graph.bench.smoother.SmootherBenchmark`: per seed, the summary over seeds beside
the Cramer-Rao bound, the smoothers beside the bound of a 1 s lag, the smoother at keyframes
beside the one at every frame, the outlier cases' ratio, speed and memory."""

from __future__ import annotations

import math

import numpy as np

from apcc_graph.bench import table_cells as _cells
from apcc_graph.bench.engines import format_engine_times, format_window_times
from apcc_graph.bench.smoother import (
    FPS,
    KEYFRAMES,
    LAG,
    LAG_STEP,
    MODEL_NOISE,
    NOISE_PX,
    SMOOTHERS,
    WINDOW,
    SmootherBenchmark,
)


def _per_seed(r: SmootherBenchmark) -> list[str]:
    deg = np.degrees
    out = ["per seed: RMS per segment (deg), the Cramer-Rao bound of the same sequence, "
           "RMS / bound",
           f"  {'case':<13} {'seed':>4} {'method':<18} {'RMS seg 1..3':>23}   "
           f"{'bound seg 1..3':>23}   {'RMS / bound':>17}  {'seconds':>8}  {'update ms':>9}"]
    for run in r.runs:
        out.append(f"  {run.case:<13} {run.seed:>4} {run.method:<18} "
                   f"{_cells(deg(run.rms), '7.3f')}   "
                   f"{_cells(deg(run.bound), '7.3f')}   {_cells(run.ratio, '5.2f')}  "
                   f"{run.seconds:8.1f}  "
                   + (f"{run.update_median * 1e3:9.1f}" if run.update_median is not None
                      else ""))
    if r.model_sigma is not None:
        out.append(f"  ({MODEL_NOISE}: the smoother with model error as noise, "
                   f"{r.model_sigma[0] * 1e3:g} mm / {math.degrees(r.model_sigma[1]):g} deg)")
    return out


def _summary(r: SmootherBenchmark, cases: list[str], methods: list[str]) -> list[str]:
    out = ["", "summary over seeds: RMS / bound per segment (median, worst seed), the worst "
           f"{WINDOW}-frame window / its bound, mean (error / sigma)^2",
           f"  {'case':<13} {'method':<18} {'median':>17}   {'worst seed':>17}   "
           f"{'worst window':>17}   {'(e/s)^2':>17}"]
    for case in cases:
        for method in methods:
            rows = [run for run in r.runs if run.case == case and run.method == method]
            ratios = np.array([run.ratio for run in rows])
            windows = np.max([run.worst_window for run in rows], axis=0)
            nees = [run.nees for run in rows if run.nees is not None]
            honesty = _cells(np.mean(nees, axis=0), "5.2f") if nees else f"{'-':>17}"
            out.append(f"  {case:<13} {method:<18} {_cells(np.median(ratios, axis=0), '5.2f')}"
                       f"   {_cells(ratios.max(axis=0), '5.2f')}   {_cells(windows, '5.2f')}   "
                       f"{honesty}")
    return out


def _lag_rows(r: SmootherBenchmark, cases: list[str]) -> list[str]:
    lagged = [run for run in r.runs if run.lag_ratio is not None]
    if not lagged:
        return []
    out = ["", f"the smoother against the bound of a {LAG:g} s fixed lag (frames sampled every "
           f"{LAG_STEP}; no estimate of frame f may use frames after f + lag): RMS / lag "
           "bound (median, worst seed), worst window"]
    for case in cases:
        for method in SMOOTHERS:
            rows = [run for run in lagged if run.case == case and run.method == method]
            if not rows:
                continue
            ratios = np.array([run.lag_ratio for run in rows])
            windows = np.max([run.lag_window for run in rows], axis=0)
            out.append(f"  {case:<13} {method:<18} {_cells(np.median(ratios, axis=0), '5.2f')}"
                       f"   {_cells(ratios.max(axis=0), '5.2f')}   {_cells(windows, '5.2f')}")
    return out


def _keyframe_rows(r: SmootherBenchmark, cases: list[str]) -> list[str]:
    """The smoother that solves at keyframes against the one that solves at every frame, on
    the same sequences: RMS ratio per segment and seconds ratio."""
    pairs = [(a, b) for a in r.runs for b in r.runs if a.method == KEYFRAMES
             and b.method == "smoother" and (a.case, a.seed) == (b.case, b.seed)]
    if not pairs:
        return []
    out = ["", f"{KEYFRAMES} / smoother (keyframes by the default rule against every frame, "
           "same sequences): RMS per segment (median, worst seed), seconds (median)"]
    for case in cases:
        rows = [(a, b) for a, b in pairs if a.case == case]
        if not rows:
            continue
        ratios = np.array([a.rms / b.rms for a, b in rows])
        seconds = np.median([a.seconds / b.seconds for a, b in rows])
        out.append(f"  {case:<13} {_cells(np.median(ratios, axis=0), '5.2f')}   "
                   f"{_cells(ratios.max(axis=0), '5.2f')}   {seconds:5.2f}")
    return out


def _outlier_ratio(r: SmootherBenchmark, cases: list[str], methods: list[str]) -> list[str]:
    if len(cases) != 2:
        return []
    out = ["", f"{cases[1]} / {cases[0]}: median RMS per segment"]
    for method in methods:
        a = np.median([run.rms for run in r.runs if run.case == cases[0]
                       and run.method == method], axis=0)
        b = np.median([run.rms for run in r.runs if run.case == cases[1]
                       and run.method == method], axis=0)
        out.append(f"  {method:<18} {_cells(b / a, '5.2f')}")
    return out


def _speed_and_memory(r: SmootherBenchmark) -> list[str]:
    deg = np.degrees
    out = []
    if r.long_frames:
        out += ["", f"drift over {r.long_frames} frames (smoother, 10% outliers), RMS over all "
                "segments (deg)",
                f"  frames 100-400 {deg(r.drift_early):.3f}; last 300 {deg(r.drift_late):.3f}; "
                f"late / early {r.drift_late / r.drift_early:.2f}",
                "", "speed: the smoother's update per frame, 3 cameras, lag 1 s",
                f"  median {r.update_median * 1e3:.2f} ms, 95th percentile "
                f"{r.update_p95 * 1e3:.2f} ms ({1.0 / FPS / r.update_median:.2f}x real time)"]
    batch = [run.seconds for run in r.runs if run.method == "batch"]
    if batch:
        out.append(f"  batch of {r.frames} frames (from the chain): median "
                   f"{np.median(batch):.1f} s")
    if r.engines:
        out += format_engine_times(list(r.engines), r.frames)
    if r.windows:
        out += format_window_times(list(r.windows))
    if r.memory_frames:
        mb = 1024.0**2
        out += ["", "memory: resident set size of a stream (finished frames taken out)",
                f"  after 1,000 frames {r.rss_small / mb:8.1f} MB; after {r.memory_frames:,} "
                f"frames {r.rss_large / mb:8.1f} MB; ratio {r.rss_large / r.rss_small:.3f}"]
    return out


def format_smoother_benchmark(r: SmootherBenchmark) -> str:
    """The benchmark as the table ``apcc-graph bench smoother`` prints."""
    cases = list(dict.fromkeys(run.case for run in r.runs))
    methods = list(dict.fromkeys(run.method for run in r.runs))
    out = [f"bench smoother: 3 x 0.3 m segments, room scene, ~{r.tracks_per_camera:.0f} tracks "
           f"per camera and frame, {NOISE_PX:g} px noise, {FPS:.0f} fps, lag {LAG:g} s, start "
           f"prior 0.1 deg, {r.frames} frames, seeds {', '.join(map(str, r.seeds))}", ""]
    out += _per_seed(r)
    out += _summary(r, cases, methods)
    out += _lag_rows(r, cases)
    out += _keyframe_rows(r, cases)
    out += _outlier_ratio(r, cases, methods)
    out += _speed_and_memory(r)
    return "\n".join(out)
