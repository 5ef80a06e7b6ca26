"""``umay bench``'s synthetic 30 Hz source: frames of the in-process run replayed at the
camera's 30 Hz (as a recording replayed with ``--speed 1`` would be) into vision → controller →
actuation running as processes, to check that none of them drops a frame at the real camera
rate, which TinyRenderer cannot reach."""

from __future__ import annotations

import os
import time
import uuid
from pathlib import Path
from typing import Any

from common.config import Scenario
from common.keys import Keys
from common.messages import DepthFrame, Header, ImageData, JointState, RgbFrame, SimTiming
from common.publishers import TypedPublisher, typed_publisher
from common.session import ENV_SHM, free_tcp_endpoint, open_session
from deploy.bench import BenchError
from deploy.bench.inprocess import SourceFrame
from deploy.bench.processes import (
    STAMPS_POLL_FRAMES,
    collect_stamps,
    machine_load,
    process_cpu_s,
    service_usage,
    status_counters,
    wait_for_services,
)
from deploy.bench.report import SyntheticRun, summary_ms
from deploy.bench.stages import PIPELINE, SYNTHETIC_STAGES
from deploy.bench.trace import Trace, frame_stages
from deploy.supervisor import Supervisor

SYNTHETIC_HZ = 30.0
MAX_SOURCE_FRAMES = 60  # distinct frames kept for the source (cycled beyond)


def publish_source_frame(
    publishers: dict[str, TypedPublisher[Any]],
    frame: SourceFrame,
    seq: int,
    scenario: Scenario,
    depth_seq: int,
) -> float:
    """Publish one frame as the sim does (the joint state, then depth if any, then colour; the
    images through the same shared-memory writer); returns the colour frame's send time."""
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
) -> SyntheticRun:
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
        config=scenario.supervisor,
    )
    rgb_sent: dict[int, float] = {}
    late = 0
    load_before = machine_load()
    try:
        sup.start()
        wait_for_services(session, keys, sup, PIPELINE, startup_timeout_s)
        time.sleep(0.3)  # let their subscriptions reach this session
        pids = sup.pids()
        cpu_start = {n: process_cpu_s(p) for n, p in pids.items() if p is not None}
        period = 1.0 / rate_hz
        started = time.monotonic()
        depth_seq = -1
        for seq in range(frames):
            if seq and seq % STAMPS_POLL_FRAMES == 0:
                collect_stamps(session, keys, trace)
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
        usage = service_usage(pids, cpu_start, frames)
        collect_stamps(session, keys, trace)
        counters = status_counters(session, keys)
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
    return SyntheticRun(
        rate_hz=rate_hz,
        frames=frames,
        distinct_frames=min(len(source), frames),
        achieved_rate_hz=round((frames - 1) / wall_s, 3) if wall_s > 0 else None,
        late_publications=late,
        stages_ms={s: summary_ms(v) for s, v in per_stage.items()},
        latency_ms=summary_ms(latency),
        dropped={
            "vision": frames - len(have_f),
            "controller": len(have_f) - len(have_t),
            "actuation": len(have_t) - len(have_c),
        },
        services=usage,
        status=counters,
        load_before=load_before,
        load_after=machine_load(),
    )
