"""Issue 26's goals on the figures of the default lockstep loop (640×480 colour and depth at
30 Hz, no Kinect model) that depend on the host: the real-time factor, the frame's hand-off, the
latency and what distribution adds; and how a bench report, in its JSON form, gives each figure.
``umay bench`` prints its run against them, ``umay docs`` counts the kept runs within them."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Goal:
    """One of issue 26's goals on a figure: its limit and which side of it is within."""

    limit: float
    at_least: bool = False  # a rate (≥), else a time (≤)
    written: str = ""  # the limit as the tables write it, where not ``format(limit, "g")``

    def __str__(self) -> str:
        return f"{'≥' if self.at_least else '≤'} {self.written or format(self.limit, 'g')}"

    def met(self, value: float | None) -> bool:
        """Whether ``value`` is within the goal (a figure not measured is not)."""
        if value is None:
            return False
        return value >= self.limit if self.at_least else value <= self.limit

    def shown(self, value: float | None) -> str:
        """``value`` to two decimals, or more where two would put it on the other side of the
        limit (0.5041 is "0.504" against ≤ 0.5, not "0.50")."""
        if value is None:
            return "–"
        for decimals in (2, 3, 4, 5):
            text = format(value, f".{decimals}f")
            if self.met(float(text)) == self.met(value):
                return text
        return format(value, ".6f")


REAL_TIME_GOAL = Goal(2.5, at_least=True)  # lockstep, the four-process loop
HANDOFF_GOAL = Goal(0.5)  # frame publish + transport p50 (ms)
LATENCY_P50_GOAL = Goal(6.0)  # frame captured → command applied (ms)
LATENCY_P99_GOAL = Goal(9.0)
ADDS_GOAL = Goal(2.0, written="2.0")  # what distribution adds, p50 (ms)


def latency(data: Mapping[str, Any]) -> tuple[Mapping[str, Any], int]:
    """(latency summary, frames over the goal): over all frames of all runs when repeated."""
    d = data["distributed"]
    pooled = d.get("pooled")
    if pooled:
        return pooled["latency_ms"], pooled["frames_over_goal"]
    return d["latency_ms"], d["frames_over_goal"]


def frame_handoff_ms(data: Mapping[str, Any]) -> float | None:
    """Frame publish + transport, p50 (the sum of the two stages' p50)."""
    st = data["distributed"]["stages_ms"]
    a, b = st["publish"]["p50"], st["frame_transport"]["p50"]
    return None if a is None or b is None else a + b


@dataclass(frozen=True)
class HostFigure:
    """A figure of a run, its goal, and how the run's JSON gives it."""

    words: str
    goal: Goal
    of: Callable[[Mapping[str, Any]], float | None]
    unit: str = " ms"


HOST_FIGURES: tuple[HostFigure, ...] = (
    HostFigure(
        "real-time factor", REAL_TIME_GOAL, lambda d: d["distributed"]["real_time_factor"], ""
    ),
    HostFigure("frame publish + transport", HANDOFF_GOAL, frame_handoff_ms),
    HostFigure("latency p50", LATENCY_P50_GOAL, lambda d: latency(d)[0]["p50"]),
    HostFigure("latency p99", LATENCY_P99_GOAL, lambda d: latency(d)[0]["p99"]),
    HostFigure("what distribution adds", ADDS_GOAL, lambda d: d["distribution_adds_ms"]["p50"]),
)


# Scenario fields a report's config gives by value (the bench sets some of them itself, from
# --size and --mode): judged by their values, not as overrides.
CONFIG_FIELDS = frozenset(
    {
        "camera.width_px",
        "camera.height_px",
        "camera.depth_width_px",
        "camera.depth_height_px",
        "camera.rgb_hz",
        "run.clock",
    }
)


def not_the_goals_loop(data: Mapping[str, Any]) -> str:
    """Why the run is not the loop the goals are stated for ("": it is): lockstep, 640×480
    colour and depth at 30 Hz, OpenGL, frames by reference, no live view, the scenario as it
    is but for the supervisor's settings (which change the host, not the loop)."""
    c = data["config"]
    size = (c["width_px"], c["height_px"], c["depth_width_px"], c["depth_height_px"])
    loop_overrides = [
        o
        for o in c.get("overrides", [])
        if not o.startswith("supervisor.") and o.split("=")[0].strip() not in CONFIG_FIELDS
    ]
    sizes = (
        f"{c['width_px']}x{c['height_px']} colour, "
        f"{c['depth_width_px']}x{c['depth_height_px']} depth"
    )
    reasons = [
        (c["clock"] != "lockstep", f"the {c['clock']} clock"),
        (size != (640, 480, 640, 480), sizes),
        (c["rgb_hz"] != 30.0, f"{c['rgb_hz']:g} Hz"),
        (c["renderer"] != "gl", f"the {c['renderer']} renderer"),
        (c["transport"] != "shm", f"frames over {c['transport']}"),
        (bool(c.get("view")), "a live view"),
        (bool(loop_overrides), "--set " + " --set ".join(loop_overrides)),
    ]
    return "; ".join(why for differs, why in reasons if differs)


def against_goals(data: Mapping[str, Any]) -> list[str]:
    """A run (a bench report's JSON form) against the goals, a line each, when it is the loop
    they are stated for; else one line saying why it is not judged."""
    differs = not_the_goals_loop(data)
    if differs:
        return [
            "issue 26's goals are stated for the default loop (lockstep, 640x480 at 30 Hz, "
            f"OpenGL, frames by reference): this run ({differs}) is not judged against them"
        ]
    host = [o for o in data["config"].get("overrides", []) if o.startswith("supervisor.")]
    held = f"; --set {' --set '.join(host)}" if host else ""
    lines = [f"against issue 26's goals (the default loop, 640x480 at 30 Hz{held}):"]
    for f in HOST_FIGURES:
        value = f.of(data)
        verdict = "met" if f.goal.met(value) else "missed"
        lines.append(
            f"  {f.words:<26} {f.goal.shown(value) + f.unit:>10}   {str(f.goal) + f.unit:<9} "
            f"{verdict}"
        )
    return lines
