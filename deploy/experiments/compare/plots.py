"""One figure of every strategy's run on the same scenario (``umay compare``'s overlay.png).

Four panels from the recordings (:func:`deploy.recording.plots.load_series`): the hand
marker's centre in the image (the thesis's Figs. 5.10-5.17 put one strategy per figure; here
they share one, over the green start square and the red target square), the feature error over
time (log scale, with the convergence threshold), the commanded end-effector speed over time,
and how far the hand strays from the straight line between its start and its end in 3-D
(ground truth): what the path ratio sums up, and what the image alone does not show.

Colours are Okabe-Ito (distinguishable with the common colour-vision deficiencies), kept away
from the markers' green and red, and every strategy also has its own line style and marker,
so the figure survives greyscale printing. Drawing uses the Agg canvas directly, never pyplot.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from deploy.recording.plots import HAND_GREEN, TARGET_RED, RunSeries

OVERLAY_DPI = 100
MARGIN_PX = 25.0  # around the trails in the zoomed image panel
# mode → (colour, line style, marker); unknown modes cycle through FALLBACK.
STRATEGY_STYLES: dict[str, tuple[str, str, str]] = {
    "constant": ("#E69F00", "-", "o"),  # orange
    "dynamic": ("#0072B2", "--", "s"),  # blue
    "pmj": ("#CC79A7", "-.", "^"),  # reddish purple
    "mpj": ("#56B4E9", ":", "D"),  # sky blue
    "points3d": ("#000000", "-", "v"),  # black
}
FALLBACK: tuple[tuple[str, str, str], ...] = (("#F0E442", "-", "P"), ("#D55E00", "--", "X"))


def strategy_style(mode: str, index: int = 0) -> tuple[str, str, str]:
    return STRATEGY_STYLES.get(mode, FALLBACK[index % len(FALLBACK)])


def _closed(corners: np.ndarray) -> np.ndarray:
    return np.vstack([corners, corners[:1]])


def _style(ax: Axes) -> None:
    ax.grid(True, alpha=0.35, linewidth=0.6)


def _image_panel(ax: Axes, series: Mapping[str, RunSeries]) -> None:
    first = next(iter(series.values()))
    points = []
    for i, (mode, s) in enumerate(series.items()):
        colour, line, marker = strategy_style(mode, i)
        hand = s.hand_px[s.hand_visible]
        if not len(hand):
            continue
        centre = hand.mean(axis=1)
        points.append(centre)
        ax.plot(
            centre[:, 0],
            centre[:, 1],
            color=colour,
            linestyle=line,
            linewidth=1.4,
            marker=marker,
            markersize=2.2,
            markevery=3,
            label=mode,
        )
        ax.plot(*centre[-1], marker=marker, color=colour, markersize=7, markeredgecolor="white")
    start = first.hand_px[first.hand_visible]
    if len(start):
        square = _closed(start[0])
        ax.plot(square[:, 0], square[:, 1], color=HAND_GREEN, linewidth=2.0, label="hand, start")
        points.append(start[0])
    if first.target_visible.any():
        target = _closed(first.target_px[first.target_visible][0])
        ax.plot(target[:, 0], target[:, 1], color=TARGET_RED, linewidth=2.4, label="target")
        points.append(target)
    if points:
        everything = np.vstack(points)
        lo, hi = everything.min(axis=0) - MARGIN_PX, everything.max(axis=0) + MARGIN_PX
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(hi[1], lo[1])  # v points down
    ax.set_aspect("equal", adjustable="box")  # keep the zoom: the box takes its shape
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    size = f" of {first.image_size_px[0]}×{first.image_size_px[1]}" if first.image_size_px else ""
    ax.set_title(f"hand-marker centre in the image (zoomed{size})", fontsize=10)
    _style(ax)
    ax.legend(loc="best", fontsize=7, framealpha=0.9)


def _error_panel(ax: Axes, series: Mapping[str, RunSeries], converged_px: float | None) -> None:
    for i, (mode, s) in enumerate(series.items()):
        colour, line, _ = strategy_style(mode, i)
        valid = s.twist_valid & (s.error_px_rms > 0.0)
        ax.semilogy(
            s.twist_t_s,
            np.where(valid, s.error_px_rms, np.nan),
            color=colour,
            linestyle=line,
            linewidth=1.5,
            label=mode,
        )
    if converged_px:
        ax.axhline(
            converged_px,
            color="0.35",
            linestyle=(0, (1, 2)),
            linewidth=1.0,
            label=f"threshold {converged_px:g} px",
        )
    ax.set_xlabel("simulated time (s)")
    ax.set_ylabel("feature error RMS (px)")
    ax.set_title("feature error", fontsize=10)
    _style(ax)
    ax.legend(loc="upper right", fontsize=7, framealpha=0.9)


def _speed_panel(ax: Axes, series: Mapping[str, RunSeries]) -> None:
    for i, (mode, s) in enumerate(series.items()):
        colour, line, _ = strategy_style(mode, i)
        speed = np.linalg.norm(s.linear_m_s, axis=1) if len(s.linear_m_s) else np.empty(0)
        ax.plot(s.twist_t_s, speed, color=colour, linestyle=line, linewidth=1.5, label=mode)
    ax.set_xlabel("simulated time (s)")
    ax.set_ylabel("commanded hand speed (m/s)")
    ax.set_title("end-effector linear speed", fontsize=10)
    ax.set_ylim(bottom=0.0)
    _style(ax)
    ax.legend(loc="upper right", fontsize=7, framealpha=0.9)


def path_deviation_mm(ee_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(progress along the start-end line in %, distance from that line in mm) of a 3-D path
    (N×3, metres); empty arrays for a path too short to have a line."""
    if len(ee_m) < 2:
        return np.empty(0), np.empty(0)
    chord = ee_m[-1] - ee_m[0]
    length = float(np.linalg.norm(chord))
    if length < 1e-6:
        return np.empty(0), np.empty(0)
    axis = chord / length
    rel = ee_m - ee_m[0]
    along = rel @ axis
    off = np.linalg.norm(rel - np.outer(along, axis), axis=1)
    return 100.0 * along / length, 1000.0 * off


def _path_panel(ax: Axes, series: Mapping[str, RunSeries]) -> None:
    for i, (mode, s) in enumerate(series.items()):
        colour, line, _ = strategy_style(mode, i)
        progress, off = path_deviation_mm(s.truth_ee_m)
        ax.plot(progress, off, color=colour, linestyle=line, linewidth=1.5, label=mode)
    ax.set_xlabel("progress along the straight start-end line (%)")
    ax.set_ylabel("distance from that line (mm)")
    ax.set_title("hand path in 3-D (ground truth, DH-6 origin)", fontsize=10)
    ax.set_ylim(bottom=0.0)
    _style(ax)
    ax.legend(loc="upper right", fontsize=7, framealpha=0.9)


def overlay_figure(
    series: Mapping[str, RunSeries], converged_px: float | None = None, title: str = ""
) -> Figure | None:
    """Every strategy's run on one figure (``series``: mode → its run); None without data."""
    drawable = {m: s for m, s in series.items() if s.hand_visible.any() or s.twist_t_s.size}
    if not drawable:
        return None
    fig = Figure(figsize=(11.0, 8.2), dpi=OVERLAY_DPI, layout="constrained")
    FigureCanvasAgg(fig)
    (ax_image, ax_error), (ax_path, ax_speed) = fig.subplots(2, 2)
    _image_panel(ax_image, drawable)
    _error_panel(ax_error, drawable, converged_px)
    _path_panel(ax_path, drawable)
    _speed_panel(ax_speed, drawable)
    if title:
        fig.suptitle(title)
    return fig


def write_overlay(
    series: Mapping[str, RunSeries],
    path: Path,
    converged_px: float | None = None,
    title: str = "",
) -> Path | None:
    """Draw :func:`overlay_figure` of each strategy's recorded series
    (:func:`deploy.recording.plots.load_series`), save it as PNG at ``path``; None (nothing written)
    when there is nothing to draw."""
    fig = overlay_figure(series, converged_px, title)
    if fig is None:
        return None
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=OVERLAY_DPI)
    return path
