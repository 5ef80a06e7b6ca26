"""What ``umay bench`` hears of a distributed loop, and the stage durations it gives.

While the loop runs the bench listens only to the sim's timing (which also carries each
applied command's velocities); the headers' stamps of features, twists and commands are asked
from vision, controller and actuation after the run (:func:`deploy.bench.processes.collect_stamps`),
so that the measurement adds no subscriber to the loop's hops. Frames dropped per stage are
counted by ``frame_seq``. The stages are named in :mod:`deploy.bench.stages`.
"""

from __future__ import annotations

import itertools
import threading
import time
from dataclasses import dataclass, field
from typing import NamedTuple

import zenoh

from common.codec import DEFAULT_MAX_BYTES, MessageError, decode
from common.keys import FEATURES, JOINT_COMMAND, TWIST
from common.messages import AppliedCommand, PublishedStamps, SimTiming
from deploy.bench.report import FrameRow, TraceAnalysis, frames_over_goal, summary_ms
from deploy.bench.stages import LATENCY_STAGES, STAGES


class HopStamp(NamedTuple):
    """A published message's two header stamps (wall clock, Unix s)."""

    recv_time_s: float  # when its publisher received the input it answers
    send_time_s: float


@dataclass
class Trace:
    """What the bench hears (the sim's timing, Zenoh's callback thread writes) and the stamps
    the pipeline's services report; the first message per frame."""

    lock: threading.Lock = field(default_factory=threading.Lock)
    timings: dict[int, SimTiming] = field(default_factory=dict)
    applied: dict[int, AppliedCommand] = field(default_factory=dict)
    features: dict[int, HopStamp] = field(default_factory=dict)
    twists: dict[int, HopStamp] = field(default_factory=dict)
    commands: dict[int, HopStamp] = field(default_factory=dict)
    velocities: dict[int, list[float]] = field(default_factory=dict)  # as the sim applied
    rejected: int = 0
    new_timing: threading.Condition = field(default_factory=threading.Condition)

    def on_timing(self, sample: zenoh.Sample) -> None:
        try:
            t = decode(sample.payload.to_bytes(), SimTiming, DEFAULT_MAX_BYTES)
        except MessageError:
            with self.lock:
                self.rejected += 1
            return
        with self.lock:
            self.timings.setdefault(t.header.frame_seq, t)
            for a in t.applied:
                if a.frame_seq >= 0:
                    self.applied.setdefault(a.frame_seq, a)
                    if a.velocity_rad_s is not None:
                        self.velocities.setdefault(a.frame_seq, a.velocity_rad_s)
        with self.new_timing:
            self.new_timing.notify_all()

    def add_stamps(self, published: PublishedStamps) -> None:
        """Take in a service's stamps of features, twists or joint commands."""
        stores = {FEATURES: self.features, TWIST: self.twists, JOINT_COMMAND: self.commands}
        with self.lock:
            for key, stamps in published.stamps.items():
                store = stores.get(key)
                if store is None:
                    continue
                for frame_seq, recv_time_s, send_time_s in stamps:
                    if frame_seq >= 0:
                        store.setdefault(frame_seq, HopStamp(recv_time_s, send_time_s))

    def wait_for_frame(self, seq: int, timeout_s: float) -> bool:
        deadline = time.monotonic() + timeout_s
        with self.new_timing:
            while True:
                with self.lock:
                    if any(k >= seq for k in self.timings):
                        return True
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return False
                self.new_timing.wait(min(remaining, 0.2))


def frame_stages(
    timing: SimTiming | None,
    features: HopStamp | None,
    twist: HopStamp | None,
    command: HopStamp | None,
    applied: AppliedCommand | None,
) -> dict[str, float]:
    """The stage durations (s) of one frame that its records allow (see the module doc); a
    receive time of 0 (unknown) leaves its two stages out."""
    t: dict[str, float | None] = {
        "render_start": timing.render_start_s if timing else None,
        "capture": timing.capture_time_s if timing else None,
        "frame_send": timing.frame_send_time_s if timing else None,
        "vision_recv": features.recv_time_s if features else None,
        "vision_send": features.send_time_s if features else None,
        "controller_recv": twist.recv_time_s if twist else None,
        "controller_send": twist.send_time_s if twist else None,
        "actuation_recv": command.recv_time_s if command else None,
        "actuation_send": command.send_time_s if command else None,
        "sim_recv": applied.recv_time_s if applied else None,
        "applied": applied.applied_time_s if applied else None,
    }
    order = list(t)
    out: dict[str, float] = {}
    for stage, (a, b) in zip(STAGES, itertools.pairwise(order), strict=True):
        ta, tb = t[a], t[b]
        if ta is not None and tb is not None and ta > 0 and tb > 0:
            out[stage] = tb - ta
    return out


def analyse_trace(trace: Trace, window: list[int]) -> TraceAnalysis:
    """Per-stage statistics, end-to-end latency excluding render, drops per stage."""
    per_stage: dict[str, list[float]] = {s: [] for s in STAGES}
    latency: list[float] = []
    with trace.lock:
        timings = {k: trace.timings.get(k) for k in window}
        rows = [
            (
                timings[k],
                trace.features.get(k),
                trace.twists.get(k),
                trace.commands.get(k),
                trace.applied.get(k),
            )
            for k in window
        ]
    per_frame: list[FrameRow] = []  # the complete frames, for the figure
    for k, row in zip(window, rows, strict=True):
        stages = frame_stages(*row)
        for s, v in stages.items():
            per_stage[s].append(v)
        if all(s in stages for s in LATENCY_STAGES):
            latency.append(row[4].applied_time_s - row[0].capture_time_s)
            ms = {s: round(1000.0 * v, 4) for s, v in stages.items()}
            per_frame.append({"frame_seq": k, "latency_ms": round(1000.0 * latency[-1], 4), **ms})
    rendered = [k for k in window if timings[k] is not None]
    with trace.lock:
        have_features = [k for k in rendered if k in trace.features]
        have_twist = [k for k in have_features if k in trace.twists]
        have_command = [k for k in have_twist if k in trace.commands]
        have_applied = [k for k in have_command if k in trace.applied]
    first, last = (timings[rendered[0]], timings[rendered[-1]]) if rendered else (None, None)
    wall_s = (last.render_start_s - first.render_start_s) if first and last else 0.0
    sim_s = (last.header.sim_time_s - first.header.sim_time_s) if first and last else 0.0
    handoff = [row["publish"] + row["frame_transport"] for row in per_frame]
    return TraceAnalysis(
        frames=len(window),
        frames_complete=len(latency),
        stages_ms={s: summary_ms(v) for s, v in per_stage.items()},
        # images ready → vision has the colour frame: the camera frame's hand-off
        frame_handoff_ms=summary_ms([v / 1000.0 for v in handoff]),
        latency_ms=summary_ms(latency),
        frames_over_goal=frames_over_goal(latency),
        loop_rate_hz=round((len(rendered) - 1) / wall_s, 3) if wall_s > 0 else None,
        real_time_factor=round(sim_s / wall_s, 4) if wall_s > 0 else None,
        wall_s=round(wall_s, 3),
        dropped={
            # camera ticks the sim could not render in time (realtime), during the window
            "camera": (last.dropped_frames - first.dropped_frames) if first and last else 0,
            "sim_missing": len(window) - len(rendered),  # never heard of (should be 0)
            "vision": len(rendered) - len(have_features),
            "controller": len(have_features) - len(have_twist),
            "actuation": len(have_twist) - len(have_command),
            "apply": len(have_command) - len(have_applied),
        },
        resends=(last.resends - first.resends) if first and last else 0,
        frames_ms=per_frame,
    )
