"""``umay bench``'s distributed run: the real four services as separate OS processes (the
:class:`Supervisor` of ``umay run``) under a unique key prefix, multicast off, measured stage by
stage (:mod:`deploy.bench.stages`) from their stamps (:mod:`deploy.bench.trace`).

The camera frame's hand-off, ``frame_handoff`` (publish + frame_transport, frame by frame), is
what frames by reference change: the sim's copy of the depth and colour pixels into its
shared-memory ring, two small puts, and vision's decoding of the references into views of the
slots (no copy), against two whole-frame puts and their copies out of Zenoh's buffers without
the ring (``--no-shm``). Vision's status counts the frames it read by reference. CPU time and
peak RSS per service come from ``/proc/<pid>`` of the supervisor's children. Times come from
``time.time()`` in every process, so all processes must be on one host.
"""

from __future__ import annotations

import contextlib
import os
import time
import uuid
from collections.abc import Callable
from contextlib import AbstractContextManager
from pathlib import Path
from typing import Any

from common.config import ClockMode, Scenario
from common.keys import SERVICES, Keys
from common.session import ENV_SHM, free_tcp_endpoint, open_session
from deploy.bench import BenchError
from deploy.bench.processes import (
    STAMPS_POLL_FRAMES,
    collect_stamps,
    machine_load,
    process_cpu_s,
    service_usage,
    status_counters,
    wait_for_services,
)
from deploy.bench.report import DistributedRun
from deploy.bench.trace import Trace, analyse_trace
from deploy.supervisor import Supervisor

# What ``umay bench --view`` enters once the services are up: (keys, endpoint, log_dir) → a
# context yielding a dict it fills in when left.
Observer = Callable[[Keys, str, Path], AbstractContextManager[dict[str, Any]]]


def run_distributed(
    scenario_path: str | None,
    scenario: Scenario,
    overrides: list[str],
    frames: int,
    warmup: int,
    log_dir: Path,
    shm: bool,
    startup_timeout_s: float = 60.0,
    observer: Observer | None = None,
) -> DistributedRun:
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
    sup = Supervisor(
        scenario_path, keys.prefix, endpoint, log_dir, overrides, env=env,
        config=scenario.supervisor,
    )  # fmt: skip
    realtime = scenario.run.clock is ClockMode.REALTIME
    load_before = machine_load()
    bench_cpu0 = time.process_time()
    observed: dict[str, Any] | None = None
    stack = contextlib.ExitStack()
    try:
        sup.start()
        cpu_wakeup = sup.cpu_wakeup.state  # what the run had (stop() withdraws it)
        wait_for_services(session, keys, sup, SERVICES, startup_timeout_s)
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
        # A frame's timing reports the commands applied after it, out when the next frame
        # starts: frame start+frames's has the last window frame's command even when it came
        # a frame late (realtime).
        per_frame_limit_s = 10.0 + (2.0 if realtime else 5.0)
        end = start + frames
        last_seen, last_progress = -1, time.monotonic()
        last_collected = start
        while not trace.wait_for_frame(end, 0.5):
            with trace.lock:
                newest = max(trace.timings, default=start)
            if newest - last_collected > STAMPS_POLL_FRAMES:
                collect_stamps(session, keys, trace)
                last_collected = newest
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
        usage = service_usage(pids, cpu_start, frames)
        collect_stamps(session, keys, trace)
        counters = status_counters(session, keys)
    finally:
        stack.close()
        sup.stop()
        for s in subs:
            s.undeclare()
        session.close()
        if not shm:
            os.environ.pop(ENV_SHM, None)
    vision_rgb = counters["vision"].received.get("sim/rgb") if "vision" in counters else None
    return DistributedRun(
        **dict(analyse_trace(trace, window)),
        prefix=keys.prefix,
        window=[window[0], window[-1]],
        services=usage,
        status=counters,
        bench_cpu_s=round(time.process_time() - bench_cpu0, 3),
        bench_rejected=trace.rejected,
        frames_by_ref=vision_rgb.by_ref if vision_rgb else None,
        frames_received_by_vision=vision_rgb.count if vision_rgb else None,
        load_before=load_before,
        load_after=machine_load(),
        observer=observed,
        cpu_wakeup_latency=cpu_wakeup,
        velocities={k: trace.velocities.get(k) for k in window},
    )
