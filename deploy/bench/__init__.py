"""``umay bench``: the loop's latency and throughput, stage by stage, distributed and in-process.

Three measurements in one command, on the same scenario and image size:

1. **Distributed**: the real four services as separate OS processes (the :class:`Supervisor`
   of ``umay run``) under a unique key prefix, multicast off. Every message header carries its
   send time and the time its publisher received the input it answers
   (``Header.recv_time_s``), and the sim publishes per frame a :class:`SimTiming` (render
   start, capture, frame send time, and when it received and applied each joint command), so
   camera frame k splits exactly into consecutive stages whose sum is the end-to-end latency
   from *frame captured* (images ready) to *command applied* (motors set), render excluded:

   ======================= ==========================================================
   stage                    from → to (wall clock)
   ======================= ==========================================================
   render                   render start → images ready (not in the latency)
   publish                  images ready → colour frame header stamped (sim)
   frame_transport          colour frame header → vision receives its inputs
   vision                   vision receives → features header stamped
   features_transport       features header → controller has features and joints
   controller               → twist header stamped
   twist_transport          twist header → actuation has twist and joints
   actuation                → joint command header stamped
   command_transport        command header → the sim receives it
   apply                    the sim receives it → the motors follow it
   ======================= ==========================================================

   A "transport" stage holds the sender's message construction and encoding, Zenoh, and the
   wait for the partner message (pairing); a service stage holds the receive copy, decoding,
   queueing and the work. The camera frame's hand-off, ``frame_handoff`` (publish +
   frame_transport, frame by frame), is what frames by reference change: the sim's copy of
   the depth and colour pixels into its shared-memory ring, two small puts, and vision's
   decoding of the references into views of the slots (no copy), against two whole-frame puts
   and their copies out of Zenoh's buffers without the ring (``--no-shm``). Vision's status
   counts the frames it read by reference.

   While the loop runs the bench listens only to the sim's timing (which also carries each
   applied command's velocities); the headers' stamps of features, twists and commands are
   asked from vision, controller and actuation (their ``<prefix>/<service>/stamps``
   queryables) after the run, so that the measurement adds no subscriber to the loop's hops.
   Frames dropped per stage are counted by ``frame_seq``; CPU time and peak RSS per service
   come from ``/proc/<pid>`` of the supervisor's children.

2. **In-process baseline**: the same pipeline in this process, on the same frames (a lockstep
   run renders the same images: the loop is deterministic): :class:`services.pipeline.Pipeline`
   composes the services' own pure steps, the ones their node shells call, and times each,
   from images ready to command applied: vision (``vision_step`` and its features message),
   the controller (``control_step`` and its twist message), actuation (``actuation_step``,
   the inverse under the acceleration limit) and setting the motors. What is fair: a
   single-process program needs no transport, so the headline baseline
   (``inprocess.per_frame_ms``) is the steps alone, and the ratio distributed / in-process
   charges distribution with everything it adds, serialization included. The same loop also
   times the codec work the distributed path does per frame (the sim's messages built, every
   message encoded once and decoded where it is received); ``ratio.vs_with_codec`` divides by
   steps + codec, i.e. what is left is transport, process boundaries and scheduling. In
   lockstep the in-process commands are compared with the distributed ones (they must agree).
   Vision is also called a second time at once on the same inputs (its step is pure), outside
   the frame's time: ``stages_ms.vision_warm`` is its cost with its code and data warm,
   against ``vision``, the first call's after the render, as every service's call is after an
   idle wait.

3. **Synthetic 30 Hz source**: frames of the in-process run replayed at the camera's 30 Hz
   (as a recording replayed with ``--speed 1`` would be) into vision → controller → actuation
   running as processes, to check that none of them drops a frame at the real camera rate,
   which TinyRenderer cannot reach.

Times come from ``time.time()`` in every process, so all processes must be on one host.
"""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import platform
import threading
import time
import uuid
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import zenoh

from common.codec import DEFAULT_MAX_BYTES, FRAME_MAX_BYTES, MessageError, decode, encode
from common.config import ClockMode, Scenario
from common.keys import FEATURES, JOINT_COMMAND, SERVICES, TWIST, Keys
from common.messages import (
    DepthFrame,
    EndEffectorTwist,
    Features,
    Header,
    ImageData,
    JointState,
    JointVelocityCommand,
    PublishedStamps,
    RgbFrame,
    SimTiming,
)
from common.transport import (
    ENV_SHM,
    TypedPublisher,
    alive_services,
    free_tcp_endpoint,
    open_session,
    query_stamps,
    query_status,
    typed_publisher,
)
from deploy.launch.supervisor import Supervisor

STAGES: tuple[str, ...] = (
    "render",
    "publish",
    "frame_transport",
    "vision",
    "features_transport",
    "controller",
    "twist_transport",
    "actuation",
    "command_transport",
    "apply",
)
LATENCY_STAGES = STAGES[1:]  # they add up to frame captured → command applied
SYNTHETIC_STAGES = STAGES[2:8]  # frame published → command published (no sim)
INPROCESS_STAGES: tuple[str, ...] = ("vision", "controller", "actuation", "apply")
CODEC_STAGES: tuple[str, ...] = ("frame_codec", "features_codec", "twist_codec", "command_codec")
PIPELINE: tuple[str, ...] = ("vision", "controller", "actuation")
SYNTHETIC_HZ = 30.0
# How often a long run collects the services' stamps while it runs: well within the
# ``common.transport.STAMPS_KEPT`` messages per key they keep (2 min at 30 Hz).
STAMPS_POLL_S = 30.0
MAX_SOURCE_FRAMES = 60  # distinct frames kept for the synthetic source (cycled beyond)
JSON_VERSION = 1
LATENCY_GOAL_MS = 10.0  # issue 7's goal for the p99 at 640×480: frames over it are counted


def frames_over_goal(latencies_s: list[float]) -> int:
    """How many of the latencies (s) exceed :data:`LATENCY_GOAL_MS`."""
    return sum(1000.0 * v > LATENCY_GOAL_MS for v in latencies_s)


class BenchError(RuntimeError):
    """The benchmark could not run (a service died or did not come up, no frames...)."""


# --- statistics --------------------------------------------------------------------------
def summary_ms(values_s: list[float] | np.ndarray) -> dict[str, float | int | None]:
    """n, p50, p99, max and mean in milliseconds of durations given in seconds."""
    v = 1000.0 * np.asarray(values_s, dtype=float)
    if v.size == 0:
        return {"n": 0, "p50": None, "p99": None, "max": None, "mean": None}
    p50, p99 = np.percentile(v, [50, 99])
    return {
        "n": int(v.size),
        "p50": round(float(p50), 4),
        "p99": round(float(p99), 4),
        "max": round(float(v.max()), 4),
        "mean": round(float(v.mean()), 4),
    }


def machine_load() -> list[float]:
    """1, 5 and 15 minute load averages (what ``uptime`` shows)."""
    return [round(x, 2) for x in os.getloadavg()]


# --- /proc -------------------------------------------------------------------------------
CLOCK_TICKS_PER_S = os.sysconf("SC_CLK_TCK")


def process_cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of a process (all its threads) so far."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS_PER_S  # utime, stime


def process_memory_mb(pid: int) -> dict[str, float]:
    """``VmHWM`` (peak resident set), ``VmRSS`` and ``RssShmem`` (shared memory pages, e.g.
    Zenoh's pool, counted in the RSS) in MiB."""
    out: dict[str, float] = {}
    try:
        lines = Path(f"/proc/{pid}/status").read_text().splitlines()
    except OSError:
        return out
    for line in lines:
        name, _, value = line.partition(":")
        if name in ("VmHWM", "VmRSS", "RssShmem"):
            out[name] = round(int(value.split()[0]) / 1024.0, 1)
    return out


# --- the distributed run -----------------------------------------------------------------
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
    applied: dict[int, Any] = field(default_factory=dict)  # frame_seq → AppliedCommand
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
    applied: Any,
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


def analyse_trace(trace: Trace, window: list[int]) -> dict[str, Any]:
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
    per_frame: list[dict[str, Any]] = []  # the complete frames, for the figure
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
    return {
        "frames": len(window),
        "frames_complete": len(latency),
        "stages_ms": {s: summary_ms(v) for s, v in per_stage.items()},
        # images ready → vision has the colour frame: the camera frame's hand-off
        "frame_handoff_ms": summary_ms([v / 1000.0 for v in handoff]),
        "latency_ms": summary_ms(latency),
        "frames_over_goal": frames_over_goal(latency),
        "loop_rate_hz": round((len(rendered) - 1) / wall_s, 3) if wall_s > 0 else None,
        "real_time_factor": round(sim_s / wall_s, 4) if wall_s > 0 else None,
        "wall_s": round(wall_s, 3),
        "dropped": {
            # camera ticks the sim could not render in time (realtime), during the window
            "camera": (last.dropped_frames - first.dropped_frames) if first and last else 0,
            "sim_missing": len(window) - len(rendered),  # never heard of (should be 0)
            "vision": len(rendered) - len(have_features),
            "controller": len(have_features) - len(have_twist),
            "actuation": len(have_twist) - len(have_command),
            "apply": len(have_command) - len(have_applied),
        },
        "resends": (last.resends - first.resends) if first and last else 0,
        "frames_ms": per_frame,
    }


def _wait_for_services(
    session: zenoh.Session, keys: Keys, sup: Supervisor, names: tuple[str, ...], timeout_s: float
) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        dead = sup.exited()
        if dead:
            c = dead[0]
            raise BenchError(f"{c.name} exited ({c.exit_codes[-1]}); see {c.log_path}")
        if set(names) <= alive_services(session, keys, 0.5):
            return
        time.sleep(0.05)
    raise BenchError(f"services did not come up within {timeout_s:.0f} s: {names}")


def _service_usage(
    pids: dict[str, int | None], cpu_start: dict[str, float | None], frames: int
) -> dict[str, dict[str, float | None]]:
    out: dict[str, dict[str, float | None]] = {}
    for name, pid in pids.items():
        if pid is None:
            continue
        cpu = process_cpu_s(pid)
        start = cpu_start.get(name)
        window_cpu = None if cpu is None or start is None else cpu - start
        mem = process_memory_mb(pid)
        out[name] = {
            "pid": pid,
            "cpu_s": None if cpu is None else round(cpu, 3),
            "window_cpu_s": None if window_cpu is None else round(window_cpu, 3),
            "cpu_ms_per_frame": (
                None if window_cpu is None or frames <= 0 else round(1000 * window_cpu / frames, 2)
            ),
            "peak_rss_mb": mem.get("VmHWM"),
            "rss_mb": mem.get("VmRSS"),
            "rss_shmem_mb": mem.get("RssShmem"),
        }
    return out


def collect_stamps(
    session: zenoh.Session, keys: Keys, trace: Trace, services: tuple[str, ...] = PIPELINE
) -> None:
    """Ask ``services`` for the stamps of what they published and add them to ``trace``.
    BenchError naming the first that does not answer."""
    for name in services:
        published = query_stamps(session, keys, name)
        if published is None:
            raise BenchError(f"{name} did not answer for its stamps ({keys.stamps(name)})")
        trace.add_stamps(published)


def _status_counters(session: zenoh.Session, keys: Keys) -> dict[str, dict[str, Any]]:
    """Each service's own counters: messages received/dropped, camera frames by reference,
    by copy and fetched whole, rejected."""
    out: dict[str, dict[str, Any]] = {}
    for st in query_status(session, keys, 2.0):
        out[st.service] = {
            "received": {
                keys.relative(k): {
                    "count": v.count,
                    "dropped": v.dropped,
                    "by_ref": v.by_ref,
                    "by_copy": v.by_copy,
                    "fetched": v.fetched,
                }
                for k, v in st.received.items()
            },
            "rejected": st.rejected,
            "processing_ms_p50": st.processing_ms_p50,
            "processing_ms_p99": st.processing_ms_p99,
        }
    return out


def run_distributed(
    scenario_path: str | None,
    scenario: Scenario,
    overrides: list[str],
    frames: int,
    warmup: int,
    log_dir: Path,
    shm: bool,
    startup_timeout_s: float = 60.0,
    observer: Callable[[Keys, str, Path], AbstractContextManager[dict[str, Any]]] | None = None,
) -> dict[str, Any]:
    """Launch the four services, measure ``frames`` frames after ``warmup``, stop them.

    ``observer(keys, endpoint, log_dir)``: a context entered once the services are up and
    left after the measurement (``umay bench --view``: a live view with a client connected);
    the dict it yields goes into the result as ``observer``, filled in when it is left."""
    keys = Keys(f"bench/{uuid.uuid4().hex[:12]}")
    endpoint = free_tcp_endpoint()
    env = {} if shm else {ENV_SHM: "0"}
    if not shm:
        os.environ[ENV_SHM] = "0"  # this process's session too, so nobody uses the pool
    session = open_session(connect=[], listen=[endpoint])
    trace = Trace()
    subs = [session.declare_subscriber(keys.timing, trace.on_timing)]
    sup = Supervisor(scenario_path, keys.prefix, endpoint, log_dir, overrides, env=env)
    realtime = scenario.run.clock is ClockMode.REALTIME
    load_before = machine_load()
    bench_cpu0 = time.process_time()
    observed: dict[str, Any] | None = None
    stack = contextlib.ExitStack()
    try:
        sup.start()
        _wait_for_services(session, keys, sup, SERVICES, startup_timeout_s)
        if observer is not None:
            observed = stack.enter_context(observer(keys, endpoint, log_dir))
        ready_s = time.time()
        # The window starts after every service is up (a realtime sim renders from the start).
        while True:
            with trace.lock:
                after = [k for k, t in trace.timings.items() if t.render_start_s >= ready_s]
            if after:
                break
            if not trace.wait_for_frame(max(trace.timings, default=-1) + 1, 30.0):
                raise BenchError(f"no frame from the sim; see {log_dir}")
        start = min(after) + warmup
        window = list(range(start, start + frames))
        if not trace.wait_for_frame(start, 30.0 + 5.0 * warmup):
            raise BenchError(f"the sim stopped before frame {start}; see {log_dir}")
        pids = sup.pids()
        cpu_start = {n: process_cpu_s(p) for n, p in pids.items() if p is not None}
        # Frame start+frames+1 reports the command of the last window frame as applied.
        per_frame_limit_s = 10.0 + (2.0 if realtime else 5.0)
        end = start + frames + 1
        last_seen, last_progress = -1, time.monotonic()
        last_collected = time.monotonic()
        while not trace.wait_for_frame(end, 0.5):
            if time.monotonic() - last_collected > STAMPS_POLL_S:
                collect_stamps(session, keys, trace)
                last_collected = time.monotonic()
            dead = sup.exited()
            if dead:
                c = dead[0]
                raise BenchError(f"{c.name} exited ({c.exit_codes[-1]}); see {c.log_path}")
            newest = max(trace.timings, default=-1)
            if newest != last_seen:
                last_seen, last_progress = newest, time.monotonic()
            elif time.monotonic() - last_progress > per_frame_limit_s:
                raise BenchError(f"the loop stalled at frame {newest}; see {log_dir}")
        if realtime:
            time.sleep(0.3)  # let the last window frame's answers land
        usage = _service_usage(pids, cpu_start, frames)
        collect_stamps(session, keys, trace)
        counters = _status_counters(session, keys)
    finally:
        stack.close()
        sup.stop()
        for s in subs:
            s.undeclare()
        session.close()
        if not shm:
            os.environ.pop(ENV_SHM, None)
    result = analyse_trace(trace, window)
    vision_rgb = counters.get("vision", {}).get("received", {}).get("sim/rgb", {})
    result.update(
        {
            "prefix": keys.prefix,
            "window": [window[0], window[-1]],
            "services": usage,
            "status": counters,
            "bench_cpu_s": round(time.process_time() - bench_cpu0, 3),
            "bench_rejected": trace.rejected,
            "frames_by_ref": vision_rgb.get("by_ref"),
            "frames_received_by_vision": vision_rgb.get("count"),
            "load_before": load_before,
            "load_after": machine_load(),
            "observer": observed,
        }
    )
    result["_velocities"] = {k: trace.velocities.get(k) for k in window}
    return result


# --- the in-process baseline ---------------------------------------------------------------
@dataclass
class SourceFrame:
    """One rendered frame kept for the synthetic source."""

    rgb: np.ndarray
    depth_m: np.ndarray | None
    q_rad: np.ndarray
    qdot_rad_s: np.ndarray
    sim_time_s: float


def run_inprocess(
    scenario: Scenario, frames: int, warmup: int, keep: int
) -> tuple[dict[str, Any], list[SourceFrame]]:
    """The in-process pipeline (:class:`services.pipeline.Pipeline`, the services' pure steps)
    on the lockstep frames, timed stage by stage (see the module doc); returns the statistics
    and the first ``keep`` frames (for the synthetic source)."""
    from services.controller.step import observation
    from services.pipeline import Pipeline

    times: dict[str, list[float]] = {
        s: [] for s in ("render", *INPROCESS_STAGES, *CODEC_STAGES, "vision_warm")
    }
    per_frame: list[float] = []
    with_codec: list[float] = []
    velocities: dict[int, list[float]] = {}
    kept: list[SourceFrame] = []
    load_before = machine_load()
    clock = time.perf_counter
    warm_s = [0.0]

    def vision_again(measure: Callable[[], object]) -> None:
        # The same call again at once, outside the frame's time: vision's cost with its code
        # and data warm, against the first call's after the render (the step is pure).
        w0 = clock()
        measure()
        warm_s[0] = clock() - w0

    with Pipeline(scenario, truth=False) as pipeline:
        world = pipeline.world
        for seq in range(warmup + frames):
            f = pipeline.step(after_vision=vision_again)
            if len(kept) < keep:
                kept.append(SourceFrame(f.rgb, f.depth_m, f.q_rad, f.qdot_rad_s, f.sim_time_s))
            # The codec work the distributed path does for this frame, timed apart: the sim's
            # messages built and encoded, and each message decoded where it is received.
            header = Header(
                seq=seq, sim_time_s=f.sim_time_s, send_time_s=time.time(), frame_seq=seq
            )
            c0 = clock()
            joints = JointState(
                header=header, position_rad=f.q_rad.tolist(), velocity_rad_s=f.qdot_rad_s.tolist()
            )
            frame_payloads = [encode(joints)]
            if f.depth_m is not None:
                frame_payloads.append(
                    encode(
                        DepthFrame(
                            header=header,
                            intrinsics=world.depth_intrinsics,
                            depth_m=ImageData.view_of(f.depth_m),
                        )
                    )
                )
            frame_payloads.append(
                encode(
                    RgbFrame(
                        header=header,
                        intrinsics=world.intrinsics,
                        rgb=ImageData.view_of(f.rgb),
                        depth_frame_seq=f.depth_frame_seq,
                    )
                )
            )
            decode(frame_payloads[-1], RgbFrame, FRAME_MAX_BYTES).rgb.to_array()
            if f.depth_m is not None:
                decode(frame_payloads[1], DepthFrame, FRAME_MAX_BYTES).depth_m.to_array()
            for _ in PIPELINE[1:]:  # the controller and actuation both decode the joint state
                decode(frame_payloads[0], JointState, DEFAULT_MAX_BYTES)
            c1 = clock()
            observation(decode(encode(f.features), Features, DEFAULT_MAX_BYTES).hand)
            c2 = clock()
            decode(encode(f.twist), EndEffectorTwist, DEFAULT_MAX_BYTES)
            c3 = clock()
            command = JointVelocityCommand(
                header=header, velocity_rad_s=f.actuation.velocity_rad_s.tolist()
            )
            decode(encode(command), JointVelocityCommand, DEFAULT_MAX_BYTES)
            c4 = clock()
            if seq < warmup:
                continue
            velocities[seq] = f.actuation.velocity_rad_s.tolist()
            for name in ("render", *INPROCESS_STAGES):
                times[name].append(f.stage_s[name])
            for name, d in zip(
                (*CODEC_STAGES, "vision_warm"),
                (c1 - c0, c2 - c1, c3 - c2, c4 - c3, warm_s[0]),
                strict=True,
            ):
                times[name].append(d)
            per_frame.append(sum(f.stage_s[name] for name in INPROCESS_STAGES))
            with_codec.append(per_frame[-1] + c4 - c0)
    return {
        "frames": frames,
        "stages_ms": {s: summary_ms(v) for s, v in times.items()},
        "per_frame_ms": summary_ms(per_frame),
        "per_frame_with_codec_ms": summary_ms(with_codec),
        "frames_ms": [  # frame by frame, for the figure
            {"frame_seq": k, "latency_ms": round(1000.0 * v, 4)}
            for k, v in zip(velocities, per_frame, strict=True)
        ],
        "render_fps": round(1.0 / float(np.median(times["render"])), 3) if frames else None,
        "load_before": load_before,
        "load_after": machine_load(),
        "_velocities": velocities,
    }, kept


# --- the synthetic 30 Hz source ------------------------------------------------------------
def publish_source_frame(
    publishers: dict[str, TypedPublisher[Any]],
    frame: SourceFrame,
    seq: int,
    scenario: Scenario,
    depth_seq: int,
) -> float:
    """Publish one frame as the sim does (joint state, depth if any, colour; the images through
    the same shared-memory writer); returns the colour frame's send time."""
    cam = scenario.camera

    def header() -> Header:
        return Header(seq=seq, sim_time_s=frame.sim_time_s, send_time_s=time.time(), frame_seq=seq)

    publishers["joint_state"].put(
        JointState(
            header=header(),
            position_rad=frame.q_rad.tolist(),
            velocity_rad_s=frame.qdot_rad_s.tolist(),
        )
    )
    if frame.depth_m is not None:
        publishers["depth"].put(
            DepthFrame(
                header=header(),
                intrinsics=cam.depth_intrinsics(),
                depth_m=ImageData.view_of(frame.depth_m),
            )
        )
    rgb = RgbFrame(
        header=header(),
        intrinsics=cam.intrinsics(),
        rgb=ImageData.view_of(frame.rgb),
        depth_frame_seq=depth_seq,
    )
    publishers["rgb"].put(rgb)
    return rgb.header.send_time_s


def run_synthetic(
    scenario_path: str | None,
    scenario: Scenario,
    overrides: list[str],
    source: list[SourceFrame],
    frames: int,
    rate_hz: float,
    log_dir: Path,
    shm: bool,
    startup_timeout_s: float = 60.0,
) -> dict[str, Any]:
    """Frames at ``rate_hz`` into vision → controller → actuation (separate processes)."""
    if not source:
        raise BenchError("no frames to replay")
    keys = Keys(f"bench/{uuid.uuid4().hex[:12]}")
    endpoint = free_tcp_endpoint()
    env = {} if shm else {ENV_SHM: "0"}
    if not shm:
        os.environ[ENV_SHM] = "0"
    session = open_session(connect=[], listen=[endpoint])
    trace = Trace()
    publishers: dict[str, TypedPublisher[Any]] = {
        "joint_state": typed_publisher(session, keys.joint_state),
        "depth": typed_publisher(session, keys.depth, frames=True),
        "rgb": typed_publisher(session, keys.rgb, frames=True),
    }
    sup = Supervisor(
        scenario_path,
        keys.prefix,
        endpoint,
        log_dir,
        [*overrides, "run.clock='realtime'"],
        services=PIPELINE,
        env=env,
    )
    rgb_sent: dict[int, float] = {}
    late = 0
    load_before = machine_load()
    try:
        sup.start()
        _wait_for_services(session, keys, sup, PIPELINE, startup_timeout_s)
        time.sleep(0.3)  # let their subscriptions reach this session
        pids = sup.pids()
        cpu_start = {n: process_cpu_s(p) for n, p in pids.items() if p is not None}
        period = 1.0 / rate_hz
        started = last_collected = time.monotonic()
        depth_seq = -1
        for seq in range(frames):
            if time.monotonic() - last_collected > STAMPS_POLL_S:
                collect_stamps(session, keys, trace)
                last_collected = time.monotonic()
            due = started + seq * period
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif delay < -period / 2:
                late += 1  # this process could not keep the rate (counted, reported)
            frame = source[seq % len(source)]
            if frame.depth_m is not None:
                depth_seq = seq
            rgb_sent[seq] = publish_source_frame(publishers, frame, seq, scenario, depth_seq)
        wall_s = time.monotonic() - started
        deadline = time.monotonic() + 3.0
        while time.monotonic() < deadline:  # until the last frame's command is out
            collect_stamps(session, keys, trace, ("actuation",))
            with trace.lock:
                if frames - 1 in trace.commands:
                    break
            time.sleep(0.1)
        time.sleep(0.2)
        usage = _service_usage(pids, cpu_start, frames)
        collect_stamps(session, keys, trace)
        counters = _status_counters(session, keys)
    finally:
        sup.stop()
        for p in publishers.values():
            p.close()
        session.close()
        if not shm:
            os.environ.pop(ENV_SHM, None)
    per_stage: dict[str, list[float]] = {s: [] for s in SYNTHETIC_STAGES}
    latency: list[float] = []
    with trace.lock:
        for seq in range(frames):
            f, tw, c = trace.features.get(seq), trace.twists.get(seq), trace.commands.get(seq)
            fake = SimTiming(
                header=Header(seq=0, sim_time_s=0.0, send_time_s=1.0, frame_seq=seq),
                render_start_s=1.0,
                capture_time_s=1.0,
                frame_send_time_s=rgb_sent.get(seq, 0.0),
                with_depth=True,
            )
            stages = frame_stages(fake, f, tw, c, None)
            for s in SYNTHETIC_STAGES:
                if s in stages:
                    per_stage[s].append(stages[s])
            if c is not None and all(s in stages for s in SYNTHETIC_STAGES):
                latency.append(c.send_time_s - rgb_sent[seq])
        have_f = [k for k in range(frames) if k in trace.features]
        have_t = [k for k in have_f if k in trace.twists]
        have_c = [k for k in have_t if k in trace.commands]
    return {
        "rate_hz": rate_hz,
        "frames": frames,
        "distinct_frames": min(len(source), frames),
        "achieved_rate_hz": round((frames - 1) / wall_s, 3) if wall_s > 0 else None,
        "late_publications": late,
        "stages_ms": {s: summary_ms(v) for s, v in per_stage.items()},
        "latency_ms": summary_ms(latency),
        "dropped": {
            "vision": frames - len(have_f),
            "controller": len(have_f) - len(have_t),
            "actuation": len(have_t) - len(have_c),
        },
        "services": usage,
        "status": counters,
        "load_before": load_before,
        "load_after": machine_load(),
    }


# --- the whole benchmark ---------------------------------------------------------------------
def run_bench(
    scenario_path: str | None,
    scenario: Scenario,
    overrides: list[str],
    frames: int,
    warmup: int,
    log_dir: Path,
    shm: bool = True,
    synthetic_frames: int | None = None,
    command: str = "",
    reference_renderer: bool = True,
    view: bool = False,
) -> dict[str, Any]:
    """Distributed run, in-process baseline, synthetic 30 Hz source, and (``reference_renderer``)
    the render cost and the distributed loop again with TinyRenderer; one JSON-ready dict."""
    from deploy.bench.render import REFERENCE_RENDERER, run_render_bench

    cam = scenario.camera
    synthetic_frames = frames if synthetic_frames is None else synthetic_frames
    observer = None
    if view:
        from deploy.foxglove.bench import watched_by_a_view

        def observer(keys: Keys, endpoint: str, view_log_dir: Path):  # type: ignore[no-redef]
            return watched_by_a_view(keys, endpoint, view_log_dir, scenario_path, overrides)

    distributed = run_distributed(
        scenario_path, scenario, overrides, frames, warmup, log_dir / "distributed", shm,
        observer=observer,
    )  # fmt: skip
    render = run_render_bench(scenario, min(frames, 60), reference=reference_renderer)
    reference = None
    if reference_renderer and scenario.sim.renderer != REFERENCE_RENDERER:
        tiny = [*overrides, f"sim.renderer='{REFERENCE_RENDERER}'"]
        loop = run_distributed(
            scenario_path, scenario, tiny, frames, warmup, log_dir / "reference", shm
        )
        reference = {
            "renderer": REFERENCE_RENDERER,
            "render_ms": loop["stages_ms"]["render"],
            "latency_ms": loop["latency_ms"],
            "loop_rate_hz": loop["loop_rate_hz"],
            "real_time_factor": loop["real_time_factor"],
            "dropped": loop["dropped"],
        }
    keep = min(MAX_SOURCE_FRAMES, warmup + max(synthetic_frames, 0))
    inprocess, source = run_inprocess(scenario, frames, warmup, keep)
    synthetic = None
    if synthetic_frames > 0:
        synthetic = run_synthetic(
            scenario_path,
            scenario,
            overrides,
            source[warmup:] or source,
            synthetic_frames,
            SYNTHETIC_HZ,
            log_dir / "synthetic",
            shm,
        )
    # The same frames must have given the same commands (lockstep only: realtime frames
    # are taken at other instants).
    dv, iv = distributed.pop("_velocities"), inprocess.pop("_velocities")
    same = None
    if scenario.run.clock is ClockMode.LOCKSTEP:
        diffs = [
            float(np.max(np.abs(np.subtract(dv[k], iv[k]))))
            for k in dv
            if dv.get(k) is not None and k in iv
        ]
        same = max(diffs) if diffs else None
    inprocess["same_commands_max_abs_diff_rad_s"] = same
    d50, d99 = distributed["latency_ms"]["p50"], distributed["latency_ms"]["p99"]
    i50, i99 = inprocess["per_frame_ms"]["p50"], inprocess["per_frame_ms"]["p99"]
    c50 = inprocess["per_frame_with_codec_ms"]["p50"]

    def ratio(a: float | None, b: float | None) -> float | None:
        return round(a / b, 4) if a is not None and b else None

    def minus(a: float | None, b: float | None) -> float | None:
        return round(a - b, 4) if a is not None and b is not None else None

    # What distribution adds to the in-process loop, and where: per service stage the
    # distributed p50 less the same functions' in-process p50; transports and the sim's
    # publish are all overhead. Medians do not add up exactly: the parts are indicative.
    d_stages, i_stages = distributed["stages_ms"], inprocess["stages_ms"]
    adds_parts = {
        s: minus(d_stages[s]["p50"], i_stages[s]["p50"])
        if s in INPROCESS_STAGES
        else d_stages[s]["p50"]
        for s in LATENCY_STAGES
    }

    return {
        "version": JSON_VERSION,
        "command": command,
        "machine": {
            "host": platform.node(),
            "cpus": os.cpu_count(),
            "processor": platform.processor() or platform.machine(),
            "python": platform.python_version(),
            "zenoh": _zenoh_version(),
            "load_start": distributed["load_before"],
            "load_end": machine_load(),
        },
        "config": {
            "width_px": cam.width_px,
            "height_px": cam.height_px,
            "depth_width_px": cam.depth_intrinsics().width_px,
            "depth_height_px": cam.depth_intrinsics().height_px,
            "rgb_hz": cam.rgb_hz,
            "depth_hz": cam.depth_rate_hz,
            "clock": scenario.run.clock.value,
            "renderer": render["renderers"][scenario.sim.renderer]["renderer"],
            "transport": "shm" if shm else "tcp",
            "frames": frames,
            "warmup": warmup,
            "controller_mode": scenario.controller.mode.value,
            "view": view,
            "overrides": overrides,
        },
        "distributed": distributed,
        "inprocess": inprocess,
        "distribution_adds_ms": {"p50": minus(d50, i50), "parts_p50": adds_parts},
        "render": render,
        "reference_renderer": reference,
        "ratio": {
            "p50": ratio(d50, i50),
            "p99": ratio(d99, i99),
            "vs_with_codec_p50": ratio(d50, c50),
        },
        "synthetic": synthetic,
    }


def median_of_runs(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """One result whose every number is the median of that number over ``runs`` (same
    structure; anything else is taken from the first run), plus ``runs`` (how many) and, since
    one drop matters, ``dropped_max``: the largest count per stage over the runs."""

    def merge(values: list[Any]) -> Any:
        first = values[0]
        if isinstance(first, bool) or first is None:
            return first
        if isinstance(first, int | float):
            numbers = [v for v in values if isinstance(v, int | float)]
            m = float(np.median(numbers))
            return round(m, 4) if isinstance(first, float) or m != int(m) else int(m)
        if isinstance(first, dict):
            return {k: merge([v.get(k) for v in values if isinstance(v, dict)]) for k in first}
        return first

    out = merge(runs)
    for part in ("distributed", "inprocess"):  # frame by frame: in each run, not medians
        out[part].pop("frames_ms", None)
    out["runs"] = len(runs)
    # A p99 over one run's few dozen frames is its slowest frame or two: the tail over all
    # the runs' frames together says more.
    every_frame_s = [
        row["latency_ms"] / 1000.0 for r in runs for row in r["distributed"].get("frames_ms", [])
    ]
    every_handoff_s = [
        (row["publish"] + row["frame_transport"]) / 1000.0
        for r in runs
        for row in r["distributed"].get("frames_ms", [])
    ]
    out["distributed"]["pooled"] = {
        "latency_ms": summary_ms(every_frame_s),
        "frames_over_goal": frames_over_goal(every_frame_s),
        "frame_handoff_ms": summary_ms(every_handoff_s),
    }
    out["dropped_max"] = {
        part: {k: max(r[part]["dropped"][k] for r in runs) for k in runs[0][part]["dropped"]}
        for part in ("distributed", "synthetic")
        if runs[0].get(part)
    }
    return out


def _zenoh_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("eclipse-zenoh")
    except PackageNotFoundError:
        return "unknown"


# --- output ------------------------------------------------------------------------------
def _f(v: float | int | None, fmt: str = ".2f") -> str:
    return "-" if v is None else format(v, fmt)


def format_report(r: dict[str, Any]) -> str:
    """The readable table: per stage p50 / p99 / max (ms), then the summary figures."""
    c, d, i = r["config"], r["distributed"], r["inprocess"]
    m = r["machine"]
    lines = [
        f"umay bench: {c['width_px']}x{c['height_px']} {c['clock']}, renderer {c['renderer']}, "
        f"transport {c['transport']}, {c['frames']} frames after {c['warmup']} warm-up; "
        f"load {m['load_start']} → {m['load_end']} on {m['cpus']} CPUs",
        "",
        f"{'stage':<20} {'p50 ms':>8} {'p99 ms':>8} {'max ms':>8}   in-process p50 ms",
    ]
    inproc = {
        "vision": i["stages_ms"]["vision"],
        "controller": i["stages_ms"]["controller"],
        "actuation": i["stages_ms"]["actuation"],
        "apply": i["stages_ms"]["apply"],
        "render": i["stages_ms"]["render"],
    }
    for s in STAGES:
        st = d["stages_ms"][s]
        extra = _f(inproc[s]["p50"]) if s in inproc else ""
        lines.append(f"{s:<20} {_f(st['p50']):>8} {_f(st['p99']):>8} {_f(st['max']):>8}   {extra}")
        if s == "frame_transport" and "frame_handoff_ms" in d:
            h = d["frame_handoff_ms"]
            lines.append(
                f"{'  publish+transport':<20} {_f(h['p50']):>8} {_f(h['p99']):>8} "
                f"{_f(h['max']):>8}   (the frame's hand-off, frame by frame)"
            )
    lat = d["latency_ms"]
    lines += [
        f"{'latency excl. render':<20} {_f(lat['p50']):>8} {_f(lat['p99']):>8} "
        f"{_f(lat['max']):>8}   {_f(i['per_frame_ms']['p50'])}"
        f" (with codec {_f(i['per_frame_with_codec_ms']['p50'])})",
        f"{'':<20} in-process vision again at once on the same frame (warm): p50 "
        f"{_f(i['stages_ms']['vision_warm']['p50'])} ms",
    ]
    pooled = d.get("pooled")
    if pooled:  # several runs: the tail over all their frames
        pl = pooled["latency_ms"]
        lines.append(
            f"{'latency, all frames':<20} {_f(pl['p50']):>8} {_f(pl['p99']):>8} "
            f"{_f(pl['max']):>8}   ({pl['n']} frames of {r['runs']} runs; "
            f"{pooled['frames_over_goal']} over {LATENCY_GOAL_MS:g} ms)"
        )
        ph = pooled["frame_handoff_ms"]
        lines.append(
            f"{'publish+transport':<20} {_f(ph['p50']):>8} {_f(ph['p99']):>8} {_f(ph['max']):>8}"
            "   (all frames of the runs)"
        )
    else:
        lines.append(
            f"{'':<20} frames over {LATENCY_GOAL_MS:g} ms: {d['frames_over_goal']} of "
            f"{d['latency_ms']['n']}"
        )
    adds = r.get("distribution_adds_ms")
    if adds:
        parts = ", ".join(f"{k} {_f(v)}" for k, v in adds["parts_p50"].items())
        lines.append(f"distribution adds (p50 distributed - in-process): {_f(adds['p50'])} ms")
        lines.append(f"  of which (p50 each, ms): {parts}")
    lines += [
        "",
        f"ratio distributed / in-process (p50): {_f(r['ratio']['p50'], '.3f')}"
        f"   (p99 {_f(r['ratio']['p99'], '.3f')}; vs in-process with codec "
        f"{_f(r['ratio']['vs_with_codec_p50'], '.3f')})",
        f"loop rate {_f(d['loop_rate_hz'])} frames/s, real-time factor "
        f"{_f(d['real_time_factor'], '.3f')}; colour frames by reference "
        f"{d['frames_by_ref']}/{d['frames_received_by_vision']}",
        "dropped: " + ", ".join(f"{k} {v}" for k, v in d["dropped"].items()),
    ]
    if i.get("same_commands_max_abs_diff_rad_s") is not None:
        lines.append(
            "in-process commands vs distributed: max |Δ| "
            f"{i['same_commands_max_abs_diff_rad_s']:.3g} rad/s"
        )
    lines += ["", f"{'service':<11} {'CPU s':>7} {'CPU ms/frame':>13} {'peak RSS MiB':>13}"]
    for name, u in d["services"].items():
        lines.append(
            f"{name:<11} {_f(u['window_cpu_s'], '.2f'):>7} {_f(u['cpu_ms_per_frame'], '.1f'):>13}"
            f" {_f(u['peak_rss_mb'], '.1f'):>13}"
        )
    if r.get("runs", 1) > 1:
        lines[0] += f"; medians of {r['runs']} runs"
        lines.append(
            "largest drops in any run: "
            + "; ".join(
                f"{part}: " + ", ".join(f"{k} {v}" for k, v in d.items())
                for part, d in r["dropped_max"].items()
            )
        )
    if r.get("render"):
        from deploy.bench.render import format_render_report

        lines += ["", *format_render_report(r["render"])]
    ref = r.get("reference_renderer")
    if ref:
        lines.append(
            f"loop with {ref['renderer']}: render p50 {_f(ref['render_ms']['p50'])} ms, "
            f"{_f(ref['loop_rate_hz'])} frames/s, real-time factor "
            f"{_f(ref['real_time_factor'], '.3f')}, latency p50 {_f(ref['latency_ms']['p50'])} ms"
        )
    s = r.get("synthetic")
    if s:
        lat = s["latency_ms"]
        lines += [
            "",
            f"synthetic source at {s['rate_hz']:.0f} Hz ({s['frames']} frames, achieved "
            f"{_f(s['achieved_rate_hz'])} Hz): frame published → command published p50 "
            f"{_f(lat['p50'])} p99 {_f(lat['p99'])} max {_f(lat['max'])} ms",
            "  dropped: " + ", ".join(f"{k} {v}" for k, v in s["dropped"].items()),
        ]
    return "\n".join(lines)


def write_json(result: dict[str, Any], path: str | Path) -> None:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(json.dumps(result, indent=2) + "\n")
