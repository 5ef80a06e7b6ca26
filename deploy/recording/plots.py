"""Figures of a recorded run (MCAP), in the style of the thesis's Figs. 5.10-5.17.

The recording holds one MCAP channel per Zenoh key (topic = the full key), each message the
raw msgpack payload of the key's pydantic model. Channels are matched by key suffix, so any
prefix works; the RGB-D channel is never read.

:func:`load_series` turns a recording into plain numpy arrays (:class:`RunSeries`); one pure
function per figure draws from those arrays; :func:`plot_recording` writes them all:

- ``image_trajectory.png``: the hand marker's corner trails in the image, start, final and
  target squares (Fig. 5.10 style);
- ``ee_velocity.png``: the commanded end-effector linear and angular velocity (Fig. 5.11);
- ``feature_error.png``: pixel RMS of the feature error, log scale, with the threshold;
- ``joint_velocities.png``: the six commanded joint velocities.

Drawing uses :class:`matplotlib.figure.Figure` on the Agg canvas directly, never pyplot, so
it needs no display, touches no global backend state and is safe to call from any thread.

Usage: ``umay plot RUN.mcap --out DIR`` (:func:`deploy.recording.cli.cmd_plot`).
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TypeVar

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from pydantic import BaseModel

from common import keys as data_keys
from common.codec import DEFAULT_MAX_BYTES, MessageError, decode
from common.config import ControllerConfig, load_scenario
from common.messages import (
    EndEffectorTwist,
    Features,
)
from deploy.recording.channels import DATA_SUFFIXES
from deploy.recording.read import RecordingReader, recorded_scenario

log = logging.getLogger(__name__)

M = TypeVar("M", bound=BaseModel)

DPI = 150
DEFAULT_CONVERGED_PX: float = ControllerConfig.model_fields["converged_px"].default

# Key suffixes (see common/keys.py) of the channels read; the images are deliberately absent.
SUFFIX_FEATURES = data_keys.FEATURES
SUFFIX_TWIST = data_keys.TWIST
SUFFIX_COMMAND = data_keys.JOINT_COMMAND
SUFFIX_JOINT_STATE = data_keys.JOINT_STATE
SUFFIX_TRUTH = data_keys.TRUTH
_MODELS: dict[str, type[BaseModel]] = {
    s: DATA_SUFFIXES[s]
    for s in (SUFFIX_FEATURES, SUFFIX_TWIST, SUFFIX_COMMAND, SUFFIX_JOINT_STATE, SUFFIX_TRUTH)
}

# Colour-blind-safe corner colours (Okabe-Ito), kept away from the markers' green and red.
CORNER_COLOURS = ("#0072B2", "#E69F00", "#CC79A7", "#56B4E9")
HAND_GREEN = "#009E20"
TARGET_RED = "#D62728"
AXIS_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c")  # x, y, z
NORM_COLOUR = "black"
JOINT_COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b")


# --- data ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RunSeries:
    """Time series of one run; each group's arrays share their first dimension and are sorted
    by simulated time. Missing channels give empty arrays; ``present`` lists the key suffixes
    that had at least one valid message."""

    present: frozenset[str] = frozenset()
    # vision/features: (N,), (N, 4, 2) with NaN where the marker's corners are unknown (not
    # seen whole, nor fitted from its edges); *_visible: seen whole
    image_size_px: tuple[int, int] | None = None  # (width, height)
    feat_t_s: np.ndarray = field(default_factory=lambda: np.empty(0))
    hand_px: np.ndarray = field(default_factory=lambda: np.empty((0, 4, 2)))
    hand_visible: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=bool))
    target_px: np.ndarray = field(default_factory=lambda: np.empty((0, 4, 2)))
    target_visible: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=bool))
    target_usable: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=bool))
    # controller/twist
    twist_t_s: np.ndarray = field(default_factory=lambda: np.empty(0))
    linear_m_s: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    angular_rad_s: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    twist_valid: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=bool))
    error_px_rms: np.ndarray = field(default_factory=lambda: np.empty(0))
    converged: np.ndarray = field(default_factory=lambda: np.empty(0, dtype=bool))
    modes: tuple[str, ...] = ()  # distinct controller modes, in order of appearance
    # actuation/joint_command, deadman messages (frame_seq -1) excluded
    cmd_t_s: np.ndarray = field(default_factory=lambda: np.empty(0))
    cmd_rad_s: np.ndarray = field(default_factory=lambda: np.empty((0, 6)))
    # sim/joint_state
    js_t_s: np.ndarray = field(default_factory=lambda: np.empty(0))
    js_position_rad: np.ndarray = field(default_factory=lambda: np.empty((0, 6)))
    js_velocity_rad_s: np.ndarray = field(default_factory=lambda: np.empty((0, 6)))
    # sim/truth (evaluation only)
    truth_t_s: np.ndarray = field(default_factory=lambda: np.empty(0))
    truth_ee_m: np.ndarray = field(default_factory=lambda: np.empty((0, 3)))
    skipped: dict[str, int] = field(default_factory=dict)  # undecodable payloads per suffix
    runs: int = 1  # runs of the sim the recording holds (a restart begins one): the last drawn

    @property
    def mode_label(self) -> str | None:
        return ", ".join(self.modes) if self.modes else None


def _suffix_of(topic: str) -> str | None:
    for suffix in _MODELS:
        if topic == suffix or topic.endswith("/" + suffix):
            return suffix
    return None


def _is_plotted(topic: str) -> bool:
    return _suffix_of(topic) is not None


def _iter_payloads(path: Path) -> Iterator[tuple[str, bytes]]:
    """(suffix, payload) of every message on a wanted channel; of a recording cut short, what
    precedes the damage (with a warning)."""
    reader = RecordingReader(path)
    for _schema, channel, message in reader.messages(_is_plotted, log_time_order=False):
        yield _suffix_of(channel.topic) or "", message.data
    if reader.damage:
        log.warning("%s: %s", path, reader.damage)


def _decoded(path: Path) -> tuple[dict[str, list[BaseModel]], dict[str, int], int]:
    """The messages per suffix of the recording's last run of the sim (and those stamped with
    no run), the undecodable payloads per suffix, and how many runs it holds: the runs of a
    recording that spans a sim restart each start at 0 s, and drawn together they interleave."""
    messages: dict[str, list[BaseModel]] = {s: [] for s in _MODELS}
    skipped: Counter[str] = Counter()
    runs: dict[int, None] = {}  # in the order the recording met them
    for suffix, payload in _iter_payloads(path):
        try:
            message = decode(payload, _MODELS[suffix], DEFAULT_MAX_BYTES)
        except MessageError as exc:
            if not skipped[suffix]:
                log.warning("%s: skipping undecodable %s payload: %s", path, suffix, exc)
            skipped[suffix] += 1
            continue
        messages[suffix].append(message)
        run = message.header.run  # type: ignore[attr-defined]
        if run:
            runs.pop(run, None)  # met again: the newest is the one running last
            runs[run] = None
    if len(runs) > 1:
        last = next(reversed(runs))
        messages = {
            s: [m for m in msgs if m.header.run in (0, last)]  # type: ignore[attr-defined]
            for s, msgs in messages.items()
        }
    return messages, dict(skipped), max(1, len(runs))


def _sorted_by_time(msgs: list[M]) -> list[M]:
    return sorted(msgs, key=lambda m: m.header.sim_time_s)  # type: ignore[attr-defined]


def _times(msgs: list[BaseModel]) -> np.ndarray:
    return np.array([m.header.sim_time_s for m in msgs], dtype=float)  # type: ignore[attr-defined]


def _rows(values: list[list[float]], width: int) -> np.ndarray:
    return np.array(values, dtype=float).reshape(len(values), width)


def _corners(markers: list, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Corners (NaN where unknown), seen whole, and usable (whole or fitted) per frame."""
    visible = np.array([m.visible for m in markers], dtype=bool).reshape(n)
    usable = np.array([m.usable for m in markers], dtype=bool).reshape(n)
    px = np.array([m.corners_px for m in markers], dtype=float).reshape(n, 4, 2)
    px[~usable] = np.nan
    return px, visible, usable


def _feature_fields(feats: list[Features]) -> dict:
    n = len(feats)
    hand_px, hand_visible, _ = _corners([f.hand for f in feats], n)
    target_px, target_visible, target_usable = _corners([f.target for f in feats], n)
    size = None
    if feats:
        k = feats[0].intrinsics
        size = (k.width_px, k.height_px)
    return {
        "image_size_px": size,
        "feat_t_s": _times(feats),
        "hand_px": hand_px,
        "hand_visible": hand_visible,
        "target_px": target_px,
        "target_visible": target_visible,
        "target_usable": target_usable,
    }


def _twist_fields(twists: list[EndEffectorTwist]) -> dict:
    return {
        "twist_t_s": _times(twists),
        "linear_m_s": _rows([t.linear_m_s for t in twists], 3),
        "angular_rad_s": _rows([t.angular_rad_s for t in twists], 3),
        "twist_valid": np.array([t.valid for t in twists], dtype=bool),
        "error_px_rms": np.array([t.error_px_rms for t in twists], dtype=float),
        "converged": np.array([t.converged for t in twists], dtype=bool),
        "modes": tuple(dict.fromkeys(t.mode for t in twists if t.mode)),
    }


def load_series(path: Path) -> RunSeries:
    """Read a recording into a :class:`RunSeries` (undecodable payloads are skipped; of a
    recording that spans a sim restart, its last run)."""
    messages, skipped, runs = _decoded(Path(path))
    feats = _sorted_by_time(messages[SUFFIX_FEATURES])
    twists = _sorted_by_time(messages[SUFFIX_TWIST])
    cmds = _sorted_by_time(
        [c for c in messages[SUFFIX_COMMAND] if c.header.frame_seq != -1]  # type: ignore[attr-defined]
    )
    states = _sorted_by_time(messages[SUFFIX_JOINT_STATE])
    truths = _sorted_by_time(messages[SUFFIX_TRUTH])
    present = {s for s, msgs in messages.items() if msgs}
    if not cmds:
        present.discard(SUFFIX_COMMAND)
    return RunSeries(
        present=frozenset(present),
        **_feature_fields(feats),  # type: ignore[arg-type]
        **_twist_fields(twists),  # type: ignore[arg-type]
        cmd_t_s=_times(cmds),
        cmd_rad_s=_rows([c.velocity_rad_s for c in cmds], 6),  # type: ignore[attr-defined]
        js_t_s=_times(states),
        js_position_rad=_rows([s.position_rad for s in states], 6),  # type: ignore[attr-defined]
        js_velocity_rad_s=_rows([s.velocity_rad_s for s in states], 6),  # type: ignore[attr-defined]
        truth_t_s=_times(truths),
        truth_ee_m=_rows([t.ee_position_m for t in truths], 3),  # type: ignore[attr-defined]
        skipped=skipped,
        runs=runs,
    )


# --- figures ---------------------------------------------------------------------------------
def new_figure(width_in: float, height_in: float, nrows: int = 1) -> tuple[Figure, list[Axes]]:
    fig = Figure(figsize=(width_in, height_in), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, 1, sharex=True, squeeze=False)[:, 0]
    return fig, list(axes)


def _title(base: str, series: RunSeries) -> str:
    return f"{base} — mode: {series.mode_label}" if series.mode_label else base


def style_axes(ax: Axes) -> None:
    ax.grid(True, which="major", alpha=0.35, linewidth=0.6)
    ax.grid(True, which="minor", alpha=0.15, linewidth=0.4)
    ax.minorticks_on()


def _draw_square(ax: Axes, corners: np.ndarray, **kw) -> None:
    closed = np.vstack([corners, corners[:1]])
    ax.plot(closed[:, 0], closed[:, 1], **kw)


def image_trajectory_figure(series: RunSeries) -> Figure | None:
    """Image plane: corner trails of the hand marker, its start/final squares, the target."""
    if series.image_size_px is None or not series.hand_visible.any():
        return None
    width, height = series.image_size_px
    hand = series.hand_px[series.hand_visible]
    fig, (ax,) = new_figure(7.2, 6.0)
    for i, colour in enumerate(CORNER_COLOURS):
        ax.plot(
            hand[:, i, 0],
            hand[:, i, 1],
            linestyle="none",
            marker="o",
            markersize=2.4,
            color=colour,
            alpha=0.85,
            label=f"corner {i + 1} trail",
        )
    _draw_square(
        ax,
        hand[0],
        color=HAND_GREEN,
        linewidth=2.0,
        marker="s",
        markersize=5,
        label="hand marker, start",
    )
    _draw_square(
        ax,
        hand[-1],
        color=HAND_GREEN,
        linewidth=1.6,
        linestyle="--",
        zorder=4,  # above the target square it ends on
        label="hand marker, final",
    )
    for i, (u, v) in enumerate(hand[0]):
        ax.annotate(
            str(i + 1),
            (u, v),
            xytext=(5, 5),
            textcoords="offset points",
            fontsize=8,
            color=HAND_GREEN,
            fontweight="bold",
        )
    # The target as first seen whole; else (the hand over it from the start) as first fitted
    # from its visible edges.
    seen = series.target_visible if series.target_visible.any() else series.target_usable
    if seen.any():
        fitted = "" if series.target_visible.any() else ", fitted from its edges"
        _draw_square(
            ax,
            series.target_px[seen][0],
            color=TARGET_RED,
            linewidth=3.0,
            alpha=0.8,
            marker="s",
            markersize=6,
            zorder=1.5,
            label=f"target marker (red square{fitted})",
        )
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)  # v points down
    ax.set_aspect("equal")
    ax.set_xlabel("u (px)")
    ax.set_ylabel("v (px)")
    ax.set_title(_title(f"Image-plane trajectory ({width}×{height} px)", series))
    style_axes(ax)
    ax.legend(loc="best", fontsize=8, framealpha=0.9)
    return fig


def _plot_vector(ax: Axes, t: np.ndarray, values: np.ndarray, symbol: str, unit: str) -> None:
    for i, (axis, colour) in enumerate(zip("xyz", AXIS_COLOURS, strict=True)):
        ax.plot(t, values[:, i], color=colour, linewidth=1.3, label=f"${symbol}_{axis}$")
    norm = np.linalg.norm(values, axis=1)
    ax.plot(t, norm, color=NORM_COLOUR, linewidth=1.6, linestyle="--", label=rf"$\|{symbol}\|$")
    ax.axhline(0.0, color="0.4", linewidth=0.6)
    ax.set_ylabel(f"{unit}")
    style_axes(ax)
    ax.legend(loc="upper right", fontsize=8, ncols=4, framealpha=0.9)


def ee_velocity_figure(series: RunSeries) -> Figure | None:
    """Commanded end-effector linear (m/s) and angular (rad/s) velocity over time."""
    if not series.twist_t_s.size:
        return None
    fig, (ax_v, ax_w) = new_figure(7.2, 5.6, nrows=2)
    _plot_vector(ax_v, series.twist_t_s, series.linear_m_s, "v", "linear velocity (m/s)")
    _plot_vector(
        ax_w, series.twist_t_s, series.angular_rad_s, r"\omega", "angular velocity (rad/s)"
    )
    ax_v.set_title("linear (DH-6 origin, base frame)", fontsize=10)
    ax_w.set_title("angular (base frame)", fontsize=10)
    ax_w.set_xlabel("simulated time (s)")
    fig.suptitle(_title("Commanded end-effector velocity", series))
    return fig


def _mark_convergence(ax: Axes, series: RunSeries) -> None:
    done = series.converged & series.twist_valid
    if done.any():
        t = float(series.twist_t_s[np.argmax(done)])
        ax.axvline(t, color="0.3", linestyle=":", linewidth=1.2, label=f"converged, t = {t:.2f} s")


def feature_error_figure(
    series: RunSeries, converged_px: float | None = DEFAULT_CONVERGED_PX
) -> Figure | None:
    """RMS of the feature error (valid twists only) on a log axis, with the threshold."""
    valid = series.twist_valid & (series.error_px_rms > 0.0)  # log axis: zero not drawable
    if not valid.any():
        return None
    error = np.where(valid, series.error_px_rms, np.nan)  # NaN: a gap while holding
    fig, (ax,) = new_figure(7.2, 4.2)
    ax.semilogy(
        series.twist_t_s,
        error,
        color="#1f77b4",
        linewidth=1.5,
        marker="o",
        markersize=2.5,
        label="feature error RMS",
    )
    if converged_px is not None and converged_px > 0:
        ax.axhline(
            converged_px,
            color=TARGET_RED,
            linestyle="--",
            linewidth=1.2,
            label=f"convergence threshold ({converged_px:g} px)",
        )
    _mark_convergence(ax, series)
    ax.set_xlabel("simulated time (s)")
    ax.set_ylabel(r"RMS of $e = s - s^*$ (px)")
    ax.set_title(_title("Feature error", series))
    style_axes(ax)
    ax.legend(loc="upper right", fontsize=8, framealpha=0.9)
    return fig


def joint_velocities_figure(series: RunSeries) -> Figure | None:
    """The six commanded joint velocities (deadman stops excluded) over time."""
    if not series.cmd_t_s.size:
        return None
    fig, (ax,) = new_figure(7.2, 4.2)
    for j, colour in enumerate(JOINT_COLOURS):
        ax.plot(
            series.cmd_t_s,
            series.cmd_rad_s[:, j],
            color=colour,
            linewidth=1.3,
            label=rf"$\dot q_{j + 1}$",
        )
    ax.axhline(0.0, color="0.4", linewidth=0.6)
    ax.set_xlabel("simulated time (s)")
    ax.set_ylabel("joint velocity (rad/s)")
    ax.set_title(_title("Commanded joint velocities", series))
    style_axes(ax)
    ax.legend(loc="upper right", fontsize=8, ncols=3, framealpha=0.9)
    return fig


def recorded_converged_px(reader: RecordingReader) -> tuple[float, list[str]]:
    """The convergence threshold of the recorded run (its scenario, overrides applied), and
    notes; the default scenario's, with a note, when the recording holds no scenario or one
    that no longer loads (the line is a guide: no reason to refuse the figures)."""
    try:
        scenario, notes = recorded_scenario(reader)
    except ValueError as exc:  # ScenarioError, or overrides_json that is not JSON
        notes = [f"the recorded scenario does not load, the default one was used: {exc}"]
        scenario = load_scenario()
    return scenario.controller.converged_px, notes


def plot_recording(
    path: Path, out_dir: Path, converged_px: float | None = DEFAULT_CONVERGED_PX
) -> list[Path]:
    """Write the run's figures as PNGs into ``out_dir``; returns the paths written (figures
    whose channel is missing or empty are skipped)."""
    return plot_series(load_series(Path(path)), out_dir, converged_px, source=str(path))


FIGURE_NAMES = (
    "image_trajectory.png",
    "ee_velocity.png",
    "feature_error.png",
    "joint_velocities.png",
)


def plot_series(
    series: RunSeries,
    out_dir: Path,
    converged_px: float | None = DEFAULT_CONVERGED_PX,
    source: str = "",
) -> list[Path]:
    """:func:`plot_recording` of a recording already read (``source``: its name, for the log)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    builds: tuple[Callable[[], Figure | None], ...] = (  # in FIGURE_NAMES' order
        lambda: image_trajectory_figure(series),
        lambda: ee_velocity_figure(series),
        lambda: feature_error_figure(series, converged_px),
        lambda: joint_velocities_figure(series),
    )
    written: list[Path] = []
    for name, build in zip(FIGURE_NAMES, builds, strict=True):
        fig = build()
        if fig is None:
            log.info("%s: no data for %s, skipped", source, name)
            # One of another recording's, left there, would pass for this one's.
            (out / name).unlink(missing_ok=True)
            continue
        target = out / name
        fig.savefig(target, dpi=DPI)
        written.append(target)
    return written
