"""``umay bench --figure``'s picture of a run, frame by frame: the distributed latency as the
stack of its stages, and the in-process functions on the same frames as a line (also drawn by
``umay docs`` into docs/figures/bench_stages.png from the JSON it comes from). Drawn in the
style of the run figures (:mod:`deploy.recording.plots`), on the Agg canvas, never pyplot."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure

from deploy.recording.plots import DPI, new_figure, style_axes


def bench_figure(result: dict) -> Figure | None:
    """``umay bench``'s frames one by one: the distributed latency (frame captured → command
    applied) as a stack of its stages, and the in-process functions' time on the same frames
    as a line (lockstep only: a realtime run's frames are not the baseline's). None when the
    result has no frame rows (e.g. a medians-of-runs result)."""
    frames = result.get("distributed", {}).get("frames_ms") or []
    if not frames:
        return None
    fig, (ax,) = new_figure(9.0, 4.2)
    seqs = np.array([f["frame_seq"] for f in frames])
    # The rows hold the stages in loop order; the render is not part of the latency.
    stages = [k for k in frames[0] if k not in ("frame_seq", "latency_ms", "render")]
    colours = colormaps["tab10"].colors
    bottom = np.zeros(len(frames))
    for i, stage in enumerate(stages):
        height = np.array([f.get(stage, 0.0) for f in frames])
        label = stage.replace("_", " ")
        ax.bar(seqs, height, bottom=bottom, width=0.85, color=colours[i % 10], label=label)
        bottom += height
    cfg = result.get("config", {})
    lockstep = cfg.get("clock") == "lockstep"  # else the baseline's frames are other frames
    ratio = result.get("ratio", {}).get("p50") if lockstep else None
    inprocess = result["inprocess"].get("frames_ms", [])  # in frame order
    if inprocess and lockstep:
        ax.plot(
            [f["frame_seq"] for f in inprocess],
            [f["latency_ms"] for f in inprocess],
            color="black",
            linewidth=1.4,
            marker=".",
            label="in-process functions",
        )
    ax.set_title(
        "frame captured → command applied, render excluded\n"
        f"{cfg.get('width_px')}×{cfg.get('height_px')} {cfg.get('clock')}, {cfg.get('transport')}"
        + ("" if ratio is None else f"; distributed / in-process p50 {ratio:.2f}"),
        fontsize=10,
    )
    ax.set_xlabel("camera frame")
    ax.set_ylabel("ms")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize=8)
    style_axes(ax)
    return fig


def bench_png(result: dict) -> bytes | None:
    """:func:`bench_figure` as PNG bytes (what ``umay docs`` compares with the file it keeps);
    None when there is nothing to draw."""
    fig = bench_figure(result)
    if fig is None:
        return None
    out = io.BytesIO()
    fig.savefig(out, format="png", dpi=DPI)
    return out.getvalue()


def write_bench_figure(result: dict, path: Path) -> bool:
    """:func:`bench_figure` as a PNG at ``path``; False when there is nothing to draw."""
    fig = bench_figure(result)
    if fig is None:
        return False
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=DPI)
    return True
